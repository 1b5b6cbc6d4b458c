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
export PATH="$BK_ROOT/.build/bin:$PATH"
# This checkout's host package first, for `make demo` and the tests alike: `pip install -e` in
# another clone must not make this one run that clone's code.
export PYTHONPATH="$BK_ROOT/host${PYTHONPATH:+:$PYTHONPATH}"
