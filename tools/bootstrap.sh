#!/usr/bin/env bash
# Prepares what `make test` (--role test, the default) or `make demo` (--role demo) runs.
# Idempotent and quick when already done:
#  1. checks what the role needs: for the demo, the host package's Python dependencies and the
#     bulgekit command; for the tests also avr-gcc, avr-libc, libsimavr, arm-none-eabi-gcc, newlib,
#     clang, prusa-slicer, qemu-system-arm, g++, Python's headers, PlatformIO, chromium and the
#     studio's three.js,
#  2. (test) installs SCons from PyPI's wheel as PlatformIO's local `tool-scons` package
#     (the version PlatformIO pins), so PlatformIO never downloads it,
#  3. builds the simulator harness bksim (test) and the core runner bkcore into .build/bin (the
#     demo's: only when there is a g++), and the host's compiled helpers when there is a C compiler.
# Anything missing is installed first by tools/install-deps.sh with the same role (apt + pip + npm;
# the demo role: pip alone), so `make demo` and `make test` work on a fresh machine;
# BK_NO_INSTALL=1 stops with the list instead. Where the python3 on PATH may not take pip's
# packages (Debian's own: PEP 668) they go into .venv, which tools/env.sh puts first on PATH.
set -euo pipefail
role=test
case "${1:-}" in
  --role) role=${2:-} ;;
  --role=*) role=${1#--role=} ;;
  "") ;;
  *) echo "bootstrap: usage: bootstrap.sh [--role demo|test]" >&2; exit 2 ;;
esac
case $role in demo|test) ;; *) echo "bootstrap: --role is demo or test, not '$role'" >&2; exit 2 ;; esac
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$BK_ROOT"

missing_now() {  # prints what this checkout's role (demo, or build and tests) still needs
  local missing=()
  if [ $role = test ]; then
    for tool in gcc g++ avr-gcc avr-g++ avr-size pkg-config arm-none-eabi-gcc qemu-system-arm clang prusa-slicer npm; do
      command -v "$tool" >/dev/null || missing+=("$tool")
    done
    [ -f /usr/lib/avr/include/avr/io.h ] || missing+=("avr-libc")
    [ -f /usr/lib/arm-none-eabi/lib/librdimon.a ] || missing+=("libnewlib-arm-none-eabi")
    pkg-config --exists simavr 2>/dev/null || missing+=("libsimavr-dev")
    python3 -c "import platformio, SCons" 2>/dev/null || missing+=("python: platformio scons")
    command -v chromium >/dev/null || missing+=("chromium")
  fi
  local modules="numpy, click, svgelements, HersheyFonts, PIL, matplotlib, serial, trimesh, rtree, tqdm, shapely, skimage, aiohttp"
  [ $role = demo ] || modules+=", pytest, playwright"
  python3 -c "import $modules" 2>/dev/null || missing+=("python: the host package's dependencies")
  # the test extras' setuptools builds wheels itself (host/tests/tools/test_without_compiler.py)
  [ $role = demo ] || python3 -c "from importlib.metadata import version
raise SystemExit(tuple(int(x) for x in version('setuptools').split('.')[:2]) < (70, 1))" 2>/dev/null ||
    missing+=("python: setuptools>=70.1")
  if [ $role = test ]; then
    python3 -c "import os, sysconfig; assert os.path.isfile(os.path.join(sysconfig.get_paths()['include'], 'Python.h'))" \
      2>/dev/null || missing+=("python3-dev")
  fi
  command -v bulgekit >/dev/null || missing+=("the bulgekit command")
  [ $role = demo ] || python3 host/web/build.py --check >/dev/null 2>&1 || missing+=("studio front-end files")
  echo "${missing[*]}"
}

missing=$(missing_now)
if [ -n "$missing" ]; then
  # `make demo` and `make test` are the two commands a new user runs: install what is missing
  # here rather than send them to another target first. BK_NO_INSTALL=1 only reports it.
  echo "bootstrap: missing: $missing" >&2
  if [ "${BK_NO_INSTALL:-0}" = 1 ]; then
    if [ $role = demo ]; then how=" --role demo' (pip"; else how="' (apt-get + pip + npm"; fi
    echo "bootstrap: BK_NO_INSTALL=1: run 'bash tools/install-deps.sh$how) yourself" >&2
    exit 1
  fi
  if [ $role = demo ]; then
    echo "bootstrap: installing them now with tools/install-deps.sh --role demo (the host package's" \
         "PyPI packages; Debian's python3-venv with apt-get when missing). This happens once." >&2
  else
    echo "bootstrap: installing them now with tools/install-deps.sh (Debian packages with apt-get," \
         "through sudo when not root; PyPI; npm). This happens once." >&2
  fi
  bash tools/install-deps.sh --role $role
  source tools/env.sh  # again: install-deps may have made .venv, whose bin/ comes first now
  hash -r
  missing=$(missing_now)
  if [ -n "$missing" ]; then
    echo "bootstrap: still missing after tools/install-deps.sh: $missing" >&2
    exit 1
  fi
fi

[ $role = demo ] || python3 tools/pio_offline.py

mkdir -p .build/bin
build_if_stale() {  # output, then sources..., then -- compiler command
  local out=$1; shift
  local srcs=()
  while [ "$1" != "--" ]; do srcs+=("$1"); shift; done
  shift
  local stale=0
  [ -x "$out" ] || stale=1
  for s in "${srcs[@]}"; do [ "$s" -nt "$out" ] && stale=1; done
  if [ $stale = 1 ]; then
    echo "bootstrap: building $out"
    "$@"
  fi
}
if [ $role = test ]; then
  build_if_stale .build/bin/bksim tools/sim/bksim.c -- \
    gcc -O2 -Wall -Wextra -o .build/bin/bksim tools/sim/bksim.c $(pkg-config --cflags --libs simavr) -lelf -lutil
fi
# the firmware core, natively: the tests need it; the demo runs it when there is a g++ (tools/demo.sh)
if [ -f tools/bkcore/main.cpp ] && { [ $role = test ] || command -v g++ >/dev/null; }; then
  core_srcs=(tools/bkcore/main.cpp src/*.cpp src/*.h config/*.h)
  build_if_stale .build/bin/bkcore "${core_srcs[@]}" -- \
    g++ -std=gnu++11 -O2 -Wall -Wextra -Isrc -Iconfig -o .build/bin/bkcore tools/bkcore/main.cpp src/*.cpp
fi

# The host's compiled helpers (G-code scanner, planner passes, reach check): built again when their source is
# newer than the build in the package (after a pull), since a stale scanner is not used and large
# files then read many times slower. Without a C compiler (the demo role installs none) the
# package's Python code does their work, to the same results.
for c in host/bulgekit/gcode/_scan.c host/bulgekit/gcode/_plan.c host/bulgekit/bulge/_reach.c; do
  [ -f "$c" ] || continue
  so=$(ls "${c%.c}".*.so 2>/dev/null | head -1 || true)
  if [ -z "$so" ] || [ "$c" -nt "$so" ]; then
    if ! python3 -c "import os, shutil, sysconfig
cc = (os.environ.get('CC') or sysconfig.get_config_var('CC') or 'cc').split()[0]  # what setuptools calls
raise SystemExit(shutil.which(cc) is None)" 2>/dev/null; then
      echo "bootstrap: no C compiler: the host's Python code does the compiled helpers' work (slower on large files)" >&2
      break
    fi
    echo "bootstrap: building the host's compiled helpers (host/setup.py build_ext)"
    (cd host && python3 setup.py build_ext --inplace --force -q >/dev/null 2>&1) || true
    [ "$(ls host/bulgekit/gcode/_scan.*.so host/bulgekit/gcode/_plan.*.so host/bulgekit/bulge/_reach.*.so 2>/dev/null | wc -l)" = 3 ] ||
      echo "bootstrap: not all of them built (Python's headers missing?); the slower Python paths will do their work" >&2
    touch host/bulgekit/gcode/*.so host/bulgekit/bulge/*.so 2>/dev/null || true
    break
  fi
done
