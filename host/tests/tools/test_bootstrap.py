"""`make demo` and `make test` on a machine that lacks something (issue 26): tools/bootstrap.sh
says what is missing and runs tools/install-deps.sh itself; BK_NO_INSTALL=1 only says it. Run on
a copy of the checkout whose install-deps.sh is a stand-in that records its call and puts the
missing piece (the studio's three.js) in place, so nothing is installed on this machine."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import REPO

VENDOR = Path("host/bulgekit/studio/static/vendor")


@pytest.fixture
def checkout(tmp_path):
    assert (REPO / VENDOR).is_dir(), "the studio's front-end files are needed (python3 host/web/build.py)"
    root = tmp_path / "bk"
    for d in ("tools", "src", "config", "platforms", "host/web"):
        shutil.copytree(REPO / d, root / d, ignore=shutil.ignore_patterns("node_modules", "__pycache__"))
    shutil.copy(REPO / "platformio.ini", root)
    static = root / VENDOR.parent
    static.mkdir(parents=True)
    for f in (REPO / VENDOR.parent).iterdir():
        if f.is_file():
            shutil.copy(f, static)
    (root / "tools" / "install-deps.sh").write_text(
        "#!/usr/bin/env bash\necho \"install-deps ran\" >> calls.txt\n"
        f"cp -r {REPO / VENDOR} {VENDOR}\n")
    return root


def bootstrap(root, *args, **env):
    e = {k: v for k, v in os.environ.items() if k != "BK_NO_INSTALL"} | env
    return subprocess.run(["bash", "tools/bootstrap.sh", *args], cwd=root, env=e, capture_output=True, text=True,
                          timeout=600)


def test_bootstrap_installs_what_is_missing_itself(checkout):
    r = bootstrap(checkout, BK_NO_INSTALL="1")
    assert r.returncode == 1
    assert "bootstrap: missing: studio front-end files" in r.stderr
    assert "run 'bash tools/install-deps.sh'" in r.stderr
    assert not (checkout / "calls.txt").exists()

    r = bootstrap(checkout)
    assert r.returncode == 0, r.stderr
    assert "bootstrap: missing: studio front-end files" in r.stderr
    assert "installing them now with tools/install-deps.sh" in r.stderr
    assert (checkout / "calls.txt").read_text() == "install-deps ran\n"
    assert (checkout / ".build" / "bin" / "bksim").is_file()
    # done: the next run installs nothing
    r = bootstrap(checkout)
    assert r.returncode == 0 and "missing" not in r.stderr
    assert (checkout / "calls.txt").read_text() == "install-deps ran\n"


def test_bootstrap_stops_when_the_install_did_not_help(checkout):
    (checkout / "tools" / "install-deps.sh").write_text("#!/usr/bin/env bash\ntrue\n")
    r = bootstrap(checkout)
    assert r.returncode == 1
    assert "bootstrap: still missing after tools/install-deps.sh: studio front-end files" in r.stderr


def test_the_demo_role_needs_no_test_toolchain(checkout):
    """`make demo` (bootstrap --role demo): the studio's three.js, PlatformIO and the simulator are
    the tests' needs, not the demo's: none is asked for, installed or built."""
    (checkout / "tools" / "install-deps.sh").write_text(
        "#!/usr/bin/env bash\necho \"install-deps ran $*\" >> calls.txt\n")
    r = bootstrap(checkout, BK_NO_INSTALL="1")
    assert r.returncode == 1 and "bootstrap: missing: studio front-end files" in r.stderr
    r = bootstrap(checkout, "--role", "demo", BK_NO_INSTALL="1")
    assert r.returncode == 0, r.stderr
    assert "missing" not in r.stderr and not (checkout / "calls.txt").exists()
    assert not (checkout / ".build" / "bin" / "bksim").exists()
    assert (checkout / ".build" / "bin" / "bkcore").is_file()      # g++ is here: the demo runs the core
    r = bootstrap(checkout)                                         # the test role installs, by role
    assert (checkout / "calls.txt").read_text() == "install-deps ran --role test\n"
