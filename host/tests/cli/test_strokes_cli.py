"""`bulgekit strokes`: conversion to a strokes JSON, summary, errors naming the file."""
import json
from pathlib import Path

from click.testing import CliRunner

from bulgekit.cli import main
from bulgekit.bulge.strokes import load_json

DATA = Path(__file__).parents[1] / "data_inputs"


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_svg_and_text_to_json(tmp_path):
    out = tmp_path / "s.json"
    r = run("strokes", DATA / "units_mm.svg", "--text", "Hi", "--size", "5", "--at", "5,5", "-o", out)
    assert r.exit_code == 0, r.output
    assert "10 strokes (1 dots)" in r.output and "weight 64..255" in r.output
    strokes = load_json(out)
    assert len(strokes) == 10
    # the SVG's top line (v = 50 on its page) moved up by --at
    assert any(s.points[0] == (5.0, 55.0) for s in strokes)
    # text source survives the round trip
    assert any(s.source.startswith("text line 1") for s in strokes)


def test_image_needs_width_and_converts(tmp_path):
    r = run("strokes", DATA / "gradient_8x4.png")
    assert r.exit_code == 1 and "gradient_8x4.png: an image needs its width" in r.output
    out = tmp_path / "d.json"
    r = run("strokes", DATA / "gradient_8x4.png", "--image-width", "8", "--pitch", "1", "-o", out)
    assert r.exit_code == 0, r.output
    assert "29 strokes (29 dots)" in r.output
    assert len(json.loads(out.read_text())["strokes"]) == 29


def test_errors_are_one_line_with_file(tmp_path):
    r = run("strokes", DATA / "broken.svg")
    assert r.exit_code == 1 and "broken.svg:4:" in r.output and "Traceback" not in r.output
    r = run("strokes", DATA / "missing_points.json")
    assert r.exit_code == 1 and 'stroke 1: missing key "points"' in r.output
    r = run("strokes", "--text", "  ")
    assert r.exit_code == 1 and "empty text" in r.output
    (tmp_path / "strokes.txt").write_text("HI")
    r = run("strokes", tmp_path / "strokes.txt")
    assert r.exit_code == 1 and "unknown input type '.txt'" in r.output
    r = run("strokes")
    assert r.exit_code == 2 and "--text" in r.output
