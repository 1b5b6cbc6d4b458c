"""Slicer integration (issue 12): `bulgekit post-process --placement FILE GCODE` edits the slicer's
file in place, all or nothing; `build --placement` makes the same from the same placement; the
Cura script calls the same command; and the real PrusaSlicer 2.5 CLI runs it as a post-processing
script."""
from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
import types
from pathlib import Path

import pytest
from click.testing import CliRunner

from bulgekit.cli import main

REPO = Path(__file__).resolve().parents[3]
PLACEMENT = """
[[text]]
text = "HI"
at = [10, 3]
size = 3

[bulges]
dwell = 120
extra = 0.12
"""


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture
def work(tmp_path, data_dir):
    g = tmp_path / "part.gcode"
    shutil.copy(data_dir / "prusa_cyl.gcode", g)
    p = tmp_path / "p.toml"
    p.write_text(PLACEMENT)
    return g, p


def test_in_place_and_same_as_build(work, tmp_path, data_dir):
    g, p = work
    r = run("post-process", "--placement", p, g)
    assert r.exit_code == 0, r.output
    text = g.read_text()
    assert text.startswith("; bulgekit:") and "M720 S1 P120 E0.120 T0.250" in text
    r = run("build", data_dir / "prusa_cyl.gcode", "--placement", p, "-o", tmp_path / "b", "--no-preview")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "b" / "prusa_cyl.bulge.gcode").read_bytes() == g.read_bytes()
    assert not [d for d in tmp_path.iterdir() if d.name.startswith(".bulgekit-")]


def test_failure_leaves_the_file_untouched(work, tmp_path):
    g, p = work
    before = g.read_bytes()
    p.write_text(PLACEMENT + "wobble = 3\n")            # a key in [bulges] that does not exist
    r = CliRunner().invoke(main, ["post-process", "--placement", str(p), str(g)])
    assert r.exit_code == 1
    assert f"{p}: bulges: unknown key 'wobble'" in r.stderr and r.stdout == ""
    assert g.read_bytes() == before
    p.write_text(PLACEMENT)
    assert run("post-process", "--placement", p, g).exit_code == 0
    annotated = g.read_bytes()
    r = run("post-process", "--placement", p, g)           # twice would bulge twice: refused
    assert r.exit_code == 1 and "processing it again would bulge twice" in r.output
    assert g.read_bytes() == annotated
    assert not [d for d in tmp_path.iterdir() if d.name.startswith(".bulgekit-")]


@pytest.mark.parametrize("body, message", [
    ("[[text]]\nat = [0, 0]\n", "text[0]: 'text' is missing"),
    ("[[text]]\ntext = 'HI'\nsize = true\n", "text[0].size: expected a number, got True"),
    ("[colour]\nx = 1\n", "unknown table 'colour'"),
    ("[[text]]\ntext = 'HI'\n[bulges]\ndwell = 5000\n", "bulges: dwell 5000 ms outside 0..2000"),
    ("[[text]\n", "not valid TOML"),
    ("", "nothing to draw"),
])
def test_placement_errors(work, body, message):
    g, p = work
    p.write_text(body)
    r = run("post-process", "--placement", p, g)
    assert r.exit_code == 1 and message in r.output, r.output


def test_fallback_rewrites_for_stock_firmware(work):
    g, p = work
    orig = g.read_text()
    p.write_text(PLACEMENT + "fallback = true\n")
    assert run("post-process", "--placement", p, g).exit_code == 0
    text = g.read_text()
    assert text.startswith("; bulgekit fallback") and "M721" not in text
    # stops are E-only moves (issue 25): 120 ms = 2/120 + 5/r s for 6 steps: r = 48.4 steps/s,
    # 48 the nearest whole rate (120.8 ms), F = (48 - 0.5) x 60 / 93 mm/min at 93 steps/mm
    stops = [ln for ln in text.splitlines() if ln.startswith("G1 E") and ln not in orig]
    assert len(stops) == 34 and "G4 P" not in text
    assert all(ln.endswith(" F30.645") for ln in stops)


def test_fallback_stop_settings_from_the_placement(work, tmp_path):
    g, p = work
    keep = g.read_text()
    p.write_text(PLACEMENT + 'fallback = true\nstop = "g4"\n')
    assert run("post-process", "--placement", p, g).exit_code == 0
    assert "\nG4 P120\n" in g.read_text()
    g.write_text(keep)
    # at 415 steps/mm the 0.12 mm extra has 49 steps; 8 of them in each stop
    p.write_text(PLACEMENT + "fallback = true\ne_steps = 415\nstop_e_steps = 8\n")
    assert run("post-process", "--placement", p, g).exit_code == 0
    text = g.read_text()
    stops = [ln for ln in text.splitlines() if ln.startswith("G1 E") and ln not in keep]
    # 2/120 + 7/r = 0.120 s: r = 67.74, 68 steps/s is nearest: F (68 - 0.5) x 60 / 415
    assert len(stops) == 34 and all(ln.endswith(" F9.759") for ln in stops)
    g.write_text(keep)
    p.write_text(PLACEMENT + 'fallback = true\nstop = "pause"\n')
    r = run("post-process", "--placement", p, g)
    assert r.exit_code == 1 and "bulges: stop 'pause' must be 'move' or 'g4'" in r.output
    assert g.read_text() == keep


def test_example_placement_fits_the_example_cylinder(tmp_path):
    g = tmp_path / "cyl.gcode"
    shutil.copy(REPO / "examples" / "cylinder40x20.gcode", g)
    r = run("post-process", "--placement", REPO / "examples" / "placement.toml", g)
    assert r.exit_code == 0, r.output
    assert "annotated into" in r.output


def test_cura_script(work, tmp_path, monkeypatch):
    """The Cura script, imported as Cura imports it (a package beside its Script base class),
    hands back what post-process makes."""
    g, p = work
    pkg = tmp_path / "curapkg"
    (pkg / "scripts").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "Script.py").write_text(
        "class Script:\n"
        "    def __init__(self, values=None): self.values = values or {}\n"
        "    def getSettingValueByKey(self, k): return self.values[k]\n")
    (pkg / "scripts" / "__init__.py").write_text("")
    shutil.copy(REPO / "integrations" / "cura" / "Bulgekit.py", pkg / "scripts" / "Bulgekit.py")
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("curapkg.scripts.Bulgekit")
    cmd = tmp_path / "bulgekit"                            # this checkout's CLI, whatever is installed
    cmd.write_text(f"#!/bin/sh\nPYTHONPATH={REPO / 'host'} exec {sys.executable} -m bulgekit.cli \"$@\"\n")
    cmd.chmod(0o755)
    script = mod.Bulgekit({"placement": str(p), "command": str(cmd)})
    original = g.read_text()
    layers = original.split(";LAYER_CHANGE")
    data = [layers[0]] + [";LAYER_CHANGE" + l for l in layers[1:]]
    out = script.execute(data)
    assert run("post-process", "--placement", p, g).exit_code == 0
    assert "".join(out) == g.read_text()
    bad = mod.Bulgekit({"placement": str(tmp_path / "missing.toml"), "command": str(cmd)})
    with pytest.raises(RuntimeError, match=r"'--placement': File '.*missing.toml' does not exist"):
        bad.execute(data)


def test_prusaslicer_runs_it_as_a_post_processing_script(tmp_path, data_dir):
    """PrusaSlicer 2.5's own CLI with --post-process: the exported file is annotated, the same as
    `build --placement` makes from the file PrusaSlicer exports without the script."""
    exe = shutil.which("prusa-slicer")
    assert exe, "prusa-slicer is needed (tools/install-deps.sh installs it)"
    p = tmp_path / "p.toml"
    p.write_text(PLACEMENT)
    stl = data_dir / "cyl40x10.stl"
    common = ["--export-gcode", "--layer-height", "0.3", "--first-layer-height", "0.3", "--nozzle-diameter",
              "0.4", "--filament-diameter", "1.75", "--center", "100,100", "--gcode-flavor", "marlin2",
              "--perimeters", "2", "--fill-density", "10%", "--top-solid-layers", "2",
              "--bottom-solid-layers", "2", "--skirts", "1"]
    env = dict(os.environ, PYTHONPATH=str(REPO / "host"))
    plain, post = tmp_path / "plain.gcode", tmp_path / "post.gcode"
    r = subprocess.run([exe, *common, "--output", str(plain), str(stl)], capture_output=True, text=True, env=env)
    assert r.returncode == 0 and plain.is_file(), r.stdout[-2000:] + r.stderr[-2000:]
    script = f"{sys.executable} -m bulgekit.cli post-process --placement {p}"
    r = subprocess.run([exe, *common, "--post-process", script, "--output", str(post), str(stl)],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 0 and post.is_file(), r.stdout[-2000:] + r.stderr[-2000:]
    assert post.read_text().startswith("; bulgekit:")
    r = run("build", plain, "--placement", p, "-o", tmp_path / "b", "--no-preview")
    assert r.exit_code == 0, r.output
    # the two exports differ only in PrusaSlicer's timestamp and its own record of the script
    strip = lambda t: [l for l in t.splitlines() if not l.startswith(("; generated by PrusaSlicer",
                                                                      "; post_process = "))]
    assert strip((tmp_path / "b" / "plain.bulge.gcode").read_text()) == strip(post.read_text())
