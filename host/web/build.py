#!/usr/bin/env python3
"""Puts the studio's front-end libraries into the package: `npm ci` here (versions pinned by
package-lock.json), then copies the files the page imports into
bulgekit/studio/static/vendor/ with three.js's licence. Run by tools/install-deps.sh and by
setup.py's build step; --check only says whether they are there and current (exit 1 if not).
Nothing is fetched while the studio runs."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
VENDOR = HERE.parent / "bulgekit" / "studio" / "static" / "vendor"
FILES = {  # what the page imports -> where npm puts it
    "three.module.min.js": "three/build/three.module.min.js",
    "OrbitControls.js": "three/examples/jsm/controls/OrbitControls.js",
    "three.LICENSE": "three/LICENSE",
}


def wanted_version() -> str:
    lock = json.loads((HERE / "package-lock.json").read_text())
    return lock["packages"]["node_modules/three"]["version"]


def current() -> bool:
    stamp = VENDOR / "VERSION"
    return all((VENDOR / f).is_file() for f in FILES) and stamp.is_file() \
        and stamp.read_text().strip() == f"three {wanted_version()}"


def main() -> int:
    if "--check" in sys.argv:
        ok = current()
        print(f"studio assets: {'present' if ok else 'missing or stale'} in {VENDOR}")
        return 0 if ok else 1
    if current():
        return 0
    npm = shutil.which("npm")
    if npm is None:
        print("web/build.py: npm is needed to fetch three.js for the studio "
              "(Debian: apt-get install npm)", file=sys.stderr)
        return 1
    # (no "new major version of npm" notice in the middle of `make demo`: it is not ours to act on)
    subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--no-update-notifier", "--loglevel=error"],
                   cwd=HERE, check=True, env={**os.environ, "NPM_CONFIG_UPDATE_NOTIFIER": "false"})
    tmp = VENDOR.with_name("vendor.part")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name, src in FILES.items():
        shutil.copyfile(HERE / "node_modules" / src, tmp / name)
    (tmp / "VERSION").write_text(f"three {wanted_version()}\n")
    shutil.rmtree(VENDOR, ignore_errors=True)
    tmp.replace(VENDOR)
    print(f"web/build.py: three {wanted_version()} -> {VENDOR}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
