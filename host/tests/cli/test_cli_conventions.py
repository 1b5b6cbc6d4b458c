"""One convention across the subcommands (issue 26): every command writing several files takes
its folder as -o/--outdir (default bulgekit-out; the old spellings still parse), and a missing
input file is a usage error, exit status 2, naming the file."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from bulgekit.bulge import mapformat
from bulgekit.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture
def inputs(tmp_path, data_dir):
    m = tmp_path / "x.bkm"
    m.write_bytes(mapformat.encode_map([(0.6, [(100.0, 80.0)])], layer_height_mm=0.3))
    return {"gcode": data_dir / "prusa_cyl.gcode", "map": m, "missing": tmp_path / "no-such.gcode"}


# (command line with MISSING where the absent file goes)
MISSING_INPUT = [
    ("build", "MISSING", "--text", "I"),
    ("build", "GCODE", "-s", "MISSING"),
    ("build", "GCODE", "--placement", "MISSING"),
    ("post-process", "--placement", "MISSING", "GCODE"),
    ("post-process", "--placement", "MAP", "MISSING"),
    ("annotate", "MISSING", "MAP", "-o", "OUT"),
    ("annotate", "GCODE", "MISSING", "-o", "OUT"),
    ("fallback", "MISSING", "MAP", "-o", "OUT"),
    ("mcodes", "MISSING"),
    ("stats", "MISSING"),
    ("stats", "MAP", "-g", "MISSING"),
    ("strokes", "MISSING"),
    ("preview", "MISSING", "-o", "OUT"),
    ("preview", "-s", "MISSING", "-o", "OUT", "--wall-length", "50", "--height", "10"),
    ("send", "-p", "/dev/null", "MISSING"),
    ("litho", "MISSING"),
    ("litho", "GCODE", "--start-gcode", "MISSING"),
    ("estimate", "MISSING"),
    ("studio", "MISSING", "--no-browser"),
]


@pytest.mark.parametrize("argv", MISSING_INPUT, ids=lambda a: " ".join(a))
def test_a_missing_input_file_is_a_usage_error_naming_it(argv, inputs, tmp_path):
    out = tmp_path / "out.gcode"
    subst = {"MISSING": inputs["missing"], "GCODE": inputs["gcode"], "MAP": inputs["map"], "OUT": out}
    r = run(*(subst.get(a, a) for a in argv))
    assert r.exit_code == 2, r.output
    assert f"'{inputs['missing']}' does not exist" in r.output
    assert r.output.startswith("Usage: ")
    assert not out.exists()


@pytest.mark.parametrize("cmd", ["build", "litho", "demo"])
def test_the_folder_option_is_the_same_everywhere(cmd):
    r = run(cmd, "--help")
    assert r.exit_code == 0
    assert "-o, --outdir DIRECTORY" in r.output
    assert "[default: bulgekit-out]" in r.output
    assert "--out " not in r.output and "--out," not in r.output     # old spelling not shown
    assert "OLD_OUTDIR" not in r.output                                # nor demo's old argument


def test_litho_writes_into_outdir_and_the_old_spelling_still_works(tmp_path):
    p = tmp_path / "p.png"
    Image.fromarray(np.full((16, 40), 120, np.uint8)).save(p)
    for spelling, folder in (("--outdir", "new"), ("--out", "old")):
        r = run("litho", p, spelling, tmp_path / folder, "--width", 20, "--height", 3)
        assert r.exit_code == 0, r.output
        assert (tmp_path / folder / "p.litho.gcode").is_file()


def test_demo_takes_outdir_and_its_old_positional_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = run("demo", "-o", "a")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "a" / "demo.bkm").is_file()
    r = run("demo", "b")                                  # `bulgekit demo DIR` from before
    assert r.exit_code == 0, r.output
    assert (tmp_path / "b" / "demo.bkm").read_bytes() == (tmp_path / "a" / "demo.bkm").read_bytes()
    r = run("demo", "c", "-o", "d")
    assert r.exit_code == 2 and "give the output folder once" in r.output
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()
