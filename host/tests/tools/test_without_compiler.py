"""The package alone, without a C compiler: its compiled helpers (the G-code scanner gcode/_scan.c,
the estimator's planner passes gcode/_plan.c, the reach check bulge/_reach.c) are optional, and the
numpy/Python code that does their work when they are not built gives the same results.

- With the three hidden (an import of each fails, as when they were never built), `bulgekit build`,
  `annotate` and `estimate` on the shipped sample write the same bytes and say the same as with
  them; the run with them must really load all three, and the one without must load none.
- `pip wheel` with no compiler and no npm on PATH builds a wheel all the same (no helpers, no
  three.js); installed alone, it does the same work, and `bulgekit studio` says what it lacks.
- With a compiler the wheel carries the three, and its run loads them.

The wheels are built from a copy of host/ without build isolation (no index is asked: the
test extras bring a setuptools that builds wheels)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO

HOST = REPO / "host"
SAMPLE = REPO / "examples" / "cylinder40x20.gcode"
HELPERS = ("bulgekit.gcode._scan", "bulgekit.gcode._plan", "bulgekit.bulge._reach")

# Runs the commands in one process and prints what they wrote and said, and which helpers loaded.
# argv: hide|use, the sample, an empty output folder.
RUNNER = r'''
import hashlib, json, sys
from pathlib import Path
HELPERS = %r
hide, sample, out = sys.argv[1] == "hide", sys.argv[2], Path(sys.argv[3])
if hide:
    for m in HELPERS:
        sys.modules[m] = None          # `import` raises ImportError, as when it was never built
from click.testing import CliRunner
import bulgekit
from bulgekit.cli import main
stem = Path(sample).stem
said = []
for args in (["build", sample, "--text", "HI", "--at", "5,3", "-o", str(out / "build"), "--fallback",
              "--no-preview", "--quiet"],
             ["annotate", sample, str(out / "build" / (stem + ".bkm")), "-o", str(out / "annotated.gcode"), "--quiet"],
             ["estimate", sample]):
    r = CliRunner().invoke(main, args, catch_exceptions=False)
    assert r.exit_code == 0, (args, r.output)
    said.append(r.output.replace(str(out), "OUT"))
print(json.dumps({"package": bulgekit.__file__,
                  "loaded": sorted(m for m in HELPERS if sys.modules.get(m) is not None),
                  "said": said,
                  "files": {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
                            for p in sorted(out.rglob("*")) if p.is_file()}}))
''' % (HELPERS,)


def run_sample(tmp_path: Path, name: str, pythonpath: Path, hide: bool = False) -> dict:
    out = tmp_path / name
    out.mkdir()
    # (no forked child: the reach check then runs, and loads its helper, in this process)
    env = {**os.environ, "PYTHONPATH": str(pythonpath), "BULGEKIT_FORK": "0"}
    r = subprocess.run([sys.executable, "-c", RUNNER, "hide" if hide else "use", str(SAMPLE), str(out)],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert got["package"].startswith(str(pythonpath) + os.sep), got["package"]
    # only the clock differs between two runs
    got["said"] = [re.sub(r"\d+\.\d+ s\b", "T s", s) for s in got["said"]]
    return got


@pytest.fixture(scope="module")
def compiled(tmp_path_factory) -> dict:
    got = run_sample(tmp_path_factory.mktemp("compiled"), "out", HOST)
    assert got["loaded"] == sorted(HELPERS), \
        "the compiled helpers are not built here: cd host && python3 setup.py build_ext --inplace (make test does)"
    return got


def test_the_python_code_gives_the_compiled_helpers_results(compiled, tmp_path):
    py = run_sample(tmp_path, "out", HOST, hide=True)
    assert py["loaded"] == []
    assert py["files"] == compiled["files"]
    assert py["said"] == compiled["said"]
    assert sorted(py["files"]) == ["annotated.gcode", "build/cylinder40x20.bkm", "build/cylinder40x20.bulge.gcode",
                                   "build/cylinder40x20.stats.txt", "build/cylinder40x20.stock.gcode"]


def host_copy(dst: Path, vendor: bool) -> Path:
    """host/ without its tests and without what a build leaves (compiled helpers, build/, npm's
    files); the studio's three.js only when vendor."""
    skip = shutil.ignore_patterns("tests", "build", "*.egg-info", "*.so", "node_modules", "__pycache__",
                                  "vendor", "vendor.part")
    shutil.copytree(HOST, dst, ignore=skip)
    if vendor:
        src = HOST / "bulgekit" / "studio" / "static" / "vendor"
        assert src.is_dir(), "the studio's three.js is needed here: python3 host/web/build.py (make test does)"
        shutil.copytree(src, dst / "bulgekit" / "studio" / "static" / "vendor")
    return dst


def build_wheel(src: Path, dist: Path, path: str) -> tuple[Path, str]:
    env = {**os.environ, "PATH": path}
    env.pop("CC", None)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", "--no-index", "--no-build-isolation",
                        "--no-cache-dir", "-w", str(dist), str(src)],
                       env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    wheels = list(dist.glob("bulgekit-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0], r.stdout + r.stderr


def install(wheel: Path, target: Path) -> Path:
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--target", str(target),
                    str(wheel)], check=True, capture_output=True, timeout=300)
    return target


def helpers_in(wheel: Path) -> list[str]:
    names = zipfile.ZipFile(wheel).namelist()
    assert "bulgekit/cli/__init__.py" in names
    return sorted(n.split(".")[0].replace("/", ".") for n in names if n.endswith(".so"))


def test_a_wheel_without_a_compiler_or_npm(compiled, tmp_path):
    bare = tmp_path / "bin"      # a PATH with no cc, gcc or npm on it
    bare.mkdir()
    wheel, log = build_wheel(host_copy(tmp_path / "host", vendor=False), tmp_path / "dist", str(bare))
    assert "building without the studio's three.js" in log
    assert helpers_in(wheel) == []
    assert not [n for n in zipfile.ZipFile(wheel).namelist() if "/vendor/" in n]

    site = install(wheel, tmp_path / "site")
    alone = run_sample(tmp_path, "out", site)
    assert alone["loaded"] == []
    assert alone["files"] == compiled["files"] and alone["said"] == compiled["said"]

    r = subprocess.run([sys.executable, "-c", "from bulgekit.studio.server import check_assets; check_assets()"],
                       cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(site)}, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1 and "the studio's front-end files are missing" in r.stderr, r.stderr


def test_a_wheel_with_a_compiler_carries_the_helpers(compiled, tmp_path):
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.fail("a C compiler is needed (make test installs gcc)")
    wheel, _ = build_wheel(host_copy(tmp_path / "host", vendor=True), tmp_path / "dist", os.environ["PATH"])
    assert helpers_in(wheel) == sorted(HELPERS)
    assert [n for n in zipfile.ZipFile(wheel).namelist() if n.endswith("/vendor/three.module.min.js")]
    with_c = run_sample(tmp_path, "out", install(wheel, tmp_path / "site"))
    assert with_c["loaded"] == sorted(HELPERS)
    assert with_c["files"] == compiled["files"] and with_c["said"] == compiled["said"]
