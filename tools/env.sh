# Source me: the environment every bulgekit command runs PlatformIO in.
# Everything PlatformIO writes stays in .build/ (ignored), nothing asks a registry.
BK_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export BK_ROOT
export PLATFORMIO_CORE_DIR="$BK_ROOT/.build/pio-core"
export PLATFORMIO_SETTING_ENABLE_TELEMETRY=No
export PLATFORMIO_SETTING_CHECK_PLATFORMIO_INTERVAL=3650
export PLATFORMIO_SETTING_CHECK_PRUNE_SYSTEM_THRESHOLD=0
export PLATFORMIO_SETTING_ENABLE_PROXY_STRICT_SSL=No
export PLATFORMIO_NO_ANSI=true
# (each only once: bootstrap sources this again after tools/install-deps.sh has made .venv)
case ":$PATH:" in *":$BK_ROOT/.build/bin:"*) ;; *) export PATH="$BK_ROOT/.build/bin:$PATH" ;; esac
# The Python packages are in .venv when tools/install-deps.sh made one (the python3 on PATH could
# not take them: Debian's own is externally managed, PEP 668): its python3, pio and bulgekit first.
if [ -x "$BK_ROOT/.venv/bin/python3" ]; then
  case "$PATH:" in "$BK_ROOT/.venv/bin:"*) ;; *) export PATH="$BK_ROOT/.venv/bin:$PATH" ;; esac
fi
# This checkout's host package first, for `make demo` and the tests alike: `pip install -e` in
# another clone must not make this one run that clone's code.
case "${PYTHONPATH:-}:" in "$BK_ROOT/host:"*) ;; *) export PYTHONPATH="$BK_ROOT/host${PYTHONPATH:+:$PYTHONPATH}" ;; esac
