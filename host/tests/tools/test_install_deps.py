"""Where tools/install-deps.sh puts the Python packages (issue 26: `make demo` and `make test` on a
fresh Debian 12): into the python3 on PATH when its pip may install there, into .venv in the
checkout when it may not (Debian's own python3 is externally managed, PEP 668, or has no pip), and
tools/env.sh then runs .venv's python3. `install-deps.sh --where` only reports the choice, so nothing
is installed here. The externally managed Python is a real one: this interpreter's binary copied
beside its standard library (linked) and the marker file, which pip itself refuses to install into.
Roles: `--role demo` (make demo, the bulgekit command) plans the host package and its PyPI packages
alone, no toolchain, simulator, slicer or browser; `--role test`, the default, all of it; `--plan`
lists a role's packages without installing."""
from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from conftest import REPO


@pytest.fixture
def checkout(tmp_path):
    root = tmp_path / "bk"
    (root / "tools").mkdir(parents=True)
    for f in ("install-deps.sh", "env.sh"):
        shutil.copy(REPO / "tools" / f, root / "tools" / f)
    return root


def make_python(prefix: Path, externally_managed: bool) -> Path:
    """A Python installation at prefix: it finds its standard library beside its binary."""
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    stdlib = prefix / "lib" / version
    stdlib.mkdir(parents=True)
    for entry in Path(sysconfig.get_path("stdlib")).iterdir():
        if entry.name != "EXTERNALLY-MANAGED":
            (stdlib / entry.name).symlink_to(entry)
    if externally_managed:
        (stdlib / "EXTERNALLY-MANAGED").write_text(
            "[externally-managed]\nError=this Python's packages come from the distribution\n")
    (prefix / "bin").mkdir()
    exe = prefix / "bin" / "python3"
    shutil.copy(os.path.realpath(sys._base_executable), exe)
    return exe


@pytest.fixture
def with_pip(tmp_path):
    """A PYTHONPATH entry holding only pip (this interpreter's), so that every fake Python has it."""
    d = tmp_path / "pip-only"
    d.mkdir()
    spec = importlib.util.find_spec("pip")
    assert spec and spec.origin, "pip is needed for this test"
    (d / "pip").symlink_to(Path(spec.origin).parent)
    return d


def run(cmd, cwd, path, pythonpath=None):
    env = {"HOME": os.environ.get("HOME", "/root"), "PATH": path}
    if pythonpath:
        env["PYTHONPATH"] = str(pythonpath)
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def where(root, path, pythonpath=None):
    r = run(["/bin/bash", "tools/install-deps.sh", "--where"], root, path, pythonpath)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_an_externally_managed_python_gets_a_venv(checkout, tmp_path, with_pip):
    py = make_python(tmp_path / "debian", externally_managed=True)
    # pip itself refuses this Python: the fake is what Debian 12's /usr/bin/python3 is
    r = run([str(py), "-m", "pip", "install", "--dry-run", "--no-index", "six"], checkout, "/usr/bin:/bin", with_pip)
    assert r.returncode != 0 and "externally-managed-environment" in r.stdout + r.stderr, r.stdout + r.stderr
    path = f"{py.parent}:/usr/bin:/bin"
    assert where(checkout, path, with_pip) == \
        f"install-deps: the Python packages go into .venv: the python3 on PATH ({py}) is externally managed (PEP 668)"

    # the same Python without the marker (pyenv's, say): its pip installs, as before
    py = make_python(tmp_path / "pyenv", externally_managed=False)
    assert where(checkout, f"{py.parent}:/usr/bin:/bin", with_pip) == f"install-deps: the Python packages go into {py}"


def test_a_python_without_pip_gets_a_venv(checkout, tmp_path):
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp_path / "bare")], check=True)
    bin_dir = tmp_path / "bare" / "bin"
    assert where(checkout, f"{bin_dir}:/usr/bin:/bin") == \
        f"install-deps: the Python packages go into .venv: the python3 on PATH ({bin_dir / 'python3'}) has no pip"


def test_no_python_yet_gets_a_venv(checkout, tmp_path):
    tools = tmp_path / "only-coreutils"   # a PATH with no python3 on it (a fresh Debian 12 container)
    tools.mkdir()
    (tools / "dirname").symlink_to(shutil.which("dirname"))
    assert where(checkout, str(tools)) == \
        "install-deps: the Python packages go into .venv: there is no python3 on PATH yet (Debian's is externally managed)"


def test_once_there_the_venv_is_what_make_runs(checkout, tmp_path, with_pip):
    py = make_python(tmp_path / "pyenv", externally_managed=False)
    path = f"{py.parent}:/usr/bin:/bin"

    def python3_under_env_sh():
        r = run(["/bin/bash", "-c", "source tools/env.sh && command -v python3 && echo $PATH"], checkout, path)
        assert r.returncode == 0, r.stderr
        return r.stdout.split()

    assert python3_under_env_sh()[0] == str(py)
    venv_bin = checkout / ".venv" / "bin"
    venv_bin.mkdir(parents=True)
    (venv_bin / "python3").symlink_to(py)
    exe, env_path = python3_under_env_sh()
    assert exe == str(venv_bin / "python3")
    assert env_path.startswith(f"{venv_bin}:")
    # install-deps fills the same venv, even though the python3 outside it may take packages
    assert where(checkout, path, with_pip) == "install-deps: the Python packages go into .venv: .venv exists"
    # sourced twice (bootstrap does, after install-deps), PATH holds .venv/bin once
    r = run(["/bin/bash", "-c", "source tools/env.sh && source tools/env.sh && echo $PATH"], checkout, path)
    assert r.stdout.strip().split(":").count(str(venv_bin)) == 1, r.stdout


# What only the tests need: compilers, the AVR simulator, QEMU, clang, the slicer, the browser, npm
# (Debian's), and from PyPI PlatformIO, SCons and the test extras (pytest, Playwright).
TOOLCHAIN_APT = {"gcc", "g++", "make", "pkg-config", "gcc-avr", "avr-libc", "binutils-avr", "simavr",
                 "libsimavr-dev", "libelf-dev", "clang", "libclang-rt-14-dev", "gcc-arm-none-eabi",
                 "libnewlib-arm-none-eabi", "qemu-system-arm", "python3-dev", "prusa-slicer", "python3-louis",
                 "liblouis-data", "libusb-dev", "chromium", "npm"}
# Klipper's klippy for the [bulgekit] module's batch-mode tests: its dependencies unpinned, the
# package itself with --no-deps (its own pins would downgrade the host package's)
TOOLCHAIN_PIP = "platformio==6.2.0 scons==4.11.1 cffi>=1.15 greenlet>=2.0 Jinja2>=3.0 -e host[test]"


def plan(root, role, path, pythonpath=None):
    args = [] if role is None else ["--role", role]
    r = run(["/bin/bash", "tools/install-deps.sh", *args, "--plan"], root, path, pythonpath)
    assert r.returncode == 0, r.stderr
    fields = dict(line.split(":", 1) for line in r.stdout.splitlines())
    return fields["role"].strip(), set(fields["apt"].split()), fields["pip"].strip(), fields["npm"].strip()


def test_the_demo_role_plans_the_host_package_alone(checkout, tmp_path):
    # no python3 and no npm on PATH (a fresh Debian 12): the plan with the most in it
    tools = tmp_path / "only-coreutils"
    tools.mkdir()
    (tools / "dirname").symlink_to(shutil.which("dirname"))
    role, apt, pip, npm = plan(checkout, "demo", str(tools))
    assert role == "demo"
    assert apt == {"python3-venv"}           # to make .venv: Debian's python3 is externally managed
    assert pip == "-e host" and npm == ""

    # the default is the test role (make deps, .ci/run): all of it, npm too when there is none
    role, apt, pip, npm = plan(checkout, None, str(tools))
    assert role == "test"
    assert apt == TOOLCHAIN_APT | {"python3-venv"}
    assert pip == TOOLCHAIN_PIP and npm.startswith("three.js")
    assert plan(checkout, "test", str(tools))[1:] == (apt, pip, npm)


def test_a_python_that_takes_packages_needs_no_apt_for_the_demo(checkout, tmp_path, with_pip):
    py = make_python(tmp_path / "pyenv", externally_managed=False)
    _, apt, pip, _ = plan(checkout, "demo", f"{py.parent}:/usr/bin:/bin", with_pip)
    assert apt == set() and pip == "-e host"


def test_an_unknown_role_is_refused(checkout):
    for args in (["--role", "docs"], ["--role"], ["--roles", "demo"]):
        r = run(["/bin/bash", "tools/install-deps.sh", *args, "--plan"], checkout, "/usr/bin:/bin")
        assert r.returncode == 2 and "install-deps:" in r.stderr and r.stdout == "", (args, r.stderr)
