#!/usr/bin/env bash
# Installs what bulgekit's build and tests need, from Debian's packages and PyPI
# only. Idempotent: packages already present are not fetched again.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

APT_PACKAGES=(gcc g++ make pkg-config gcc-avr avr-libc binutils-avr simavr libsimavr-dev libelf-dev
              clang libclang-rt-14-dev
              gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm  # the Cortex-M test targets
              python3-dev     # headers for the host package's compiled G-code scanner (host/setup.py)
              prusa-slicer    # the post-processing test runs the real PrusaSlicer CLI
              chromium)       # the studio's browser tests (driven by Playwright from PyPI)
# PlatformIO pins SCons (tool-scons ~4.41101.0 = SCons 4.11.1 for PlatformIO 6.2.0);
# tools/pio_offline.py checks the pair and installs SCons as PlatformIO's package.
PIP_PACKAGES=("platformio==6.2.0" "scons==4.11.1")

# npm fetches three.js for the studio (host/web/build.py); Debian's package unless one is there
command -v npm >/dev/null || APT_PACKAGES+=(npm)

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

need_pip=0
python3 - "${PIP_PACKAGES[@]}" <<'PY' || need_pip=1
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
if [ $need_pip = 1 ]; then
  echo "install-deps: pip install ${PIP_PACKAGES[*]}"
  python3 -m pip install -q "${PIP_PACKAGES[@]}"
fi
if [ -f host/pyproject.toml ]; then
  python3 host/web/build.py       # the studio's front-end files, from npm (pinned by package-lock.json)
  python3 -m pip install -q -e "host[test]"
fi
echo "install-deps: done"
