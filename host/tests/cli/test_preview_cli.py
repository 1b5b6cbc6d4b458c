"""`bulgekit preview`: strokes on a plain wall, on a sliced file, 3D, and from a map."""
from pathlib import Path

from click.testing import CliRunner
from PIL import Image

from bulgekit.cli import main

DATA = Path(__file__).parents[1] / "data_inputs"
GCODE = Path(__file__).parents[1] / "data" / "prusa_cyl.gcode"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_plain_wall(tmp_path):
    png = tmp_path / "p.png"
    r = run("preview", "-s", DATA / "strokes.json", "--wall-length", "30", "--height", "10", "-o", png)
    assert r.exit_code == 0, r.output
    # strokes.json at 1 mm: the 20 mm polyline gives 21 points, 5 of them above the
    # 10 mm wall (v 11..15); the dot is inside; the 7.8 mm stroke at u 30..35 gives
    # 9 points of which only its start (u = 30) is on the 30 mm wall.
    assert "18 points on the wall, 13 OUTSIDE it" in r.output
    assert Image.open(png).format == "PNG"


def test_on_sliced_file_unrolled_3d_and_map(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    r = run("preview", GCODE, "--text", "BK", "--size", "5", "--at", "60,2", "-o", a)
    assert r.exit_code == 0, r.output
    n = int(r.output.split(": ")[1].split()[0])
    assert n > 20
    r = run("preview", GCODE, "--text", "BK", "--size", "5", "--at", "60,2", "--3d", "-o", b)
    assert r.exit_code == 0 and f"{n} bulges on" in r.output
    out = tmp_path / "bo"
    r = run("build", GCODE, "--text", "BK", "--text-size", "5", "--at", "60,2", "-o", out, "--no-preview")
    assert r.exit_code == 0, r.output
    c = tmp_path / "c.png"
    r = run("preview", GCODE, "--map", out / "prusa_cyl.bkm", "-o", c)
    assert r.exit_code == 0 and f"{n} bulges" in r.output


def test_usage_errors(tmp_path):
    png = tmp_path / "x.png"
    r = run("preview", "-s", DATA / "strokes.json", "-o", png)
    assert r.exit_code == 2 and "--wall-length" in r.output
    r = run("preview", "-s", DATA / "strokes.json", "--3d", "--wall-length", "3", "--height", "3", "-o", png)
    assert r.exit_code == 2 and "--3d needs GCODE" in r.output
    r = run("preview", "-s", DATA / "bad_path.svg", "--wall-length", "3", "--height", "3", "-o", png)
    assert r.exit_code == 1 and "bad_path.svg:3" in r.output
    assert not png.exists()
