"""Installs SCons (from the PyPI wheel already in this Python) as PlatformIO's
core package `tool-scons`, at the version this PlatformIO pins, inside
PLATFORMIO_CORE_DIR. PlatformIO then finds it by its package metadata (owner
`platformio`) and never asks the registry for it."""
import json
import os
import sys

from platformio.dependencies import get_core_dependencies
from semantic_version import SimpleSpec, Version
import SCons

core_dir = os.environ["PLATFORMIO_CORE_DIR"]
pkg_dir = os.path.join(core_dir, "packages", "tool-scons")
requirement = get_core_dependencies()["tool-scons"]  # e.g. "~4.41101.0"

# PlatformIO versions SCons a.b.c as a.(40000 + b*100 + c).0: 4.11.1 -> 4.41101.0
major, minor, patch = (int(x) for x in SCons.__version__.split(".")[:3])
pio_version = "%d.%d.0" % (major, 40000 + minor * 100 + patch)
if not SimpleSpec(requirement).match(Version(pio_version)):
    sys.exit(
        f"pio_offline: SCons {SCons.__version__} (= tool-scons {pio_version}) does not satisfy "
        f"PlatformIO's pin {requirement}; install the matching scons wheel (see tools/install-deps.sh)"
    )

meta_path = os.path.join(pkg_dir, ".piopm")
meta = {
    "type": "tool",
    "name": "tool-scons",
    "version": pio_version,
    "spec": {"owner": "platformio", "id": None, "name": "tool-scons", "requirements": requirement, "uri": None},
}
try:
    with open(meta_path, encoding="utf8") as fp:
        if json.load(fp) == meta:
            sys.exit(0)  # already in place
except (OSError, ValueError):
    pass

os.makedirs(pkg_dir, exist_ok=True)
with open(os.path.join(pkg_dir, "package.json"), "w", encoding="utf8") as fp:
    json.dump({"name": "tool-scons", "version": pio_version, "description": "SCons from the PyPI wheel"}, fp)
with open(os.path.join(pkg_dir, "scons.py"), "w", encoding="utf8") as fp:
    fp.write(
        "# Runs the SCons installed in this Python (PyPI wheel); placed by tools/pio_offline.py\n"
        "import sys\n"
        "from SCons.Script.Main import main\n"
        "sys.exit(main())\n"
    )
with open(meta_path, "w", encoding="utf8") as fp:
    json.dump(meta, fp)
print(f"pio_offline: tool-scons {pio_version} -> {pkg_dir}")
