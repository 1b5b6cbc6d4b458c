"""More of issue 26's rough edges, each in the user's words: `estimate` refuses what is not
G-code as every other command does; a text or drawing off the wall is said as a whole, with the
option (or placement key) that fixes it; a file missing from inside a placement file is a usage
error like any missing input file."""
from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from bulgekit.cli import main
from bulgekit.gcode import estimate as es

from conftest import REPO


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _png() -> bytes:
    import io
    out = io.BytesIO()
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(out, "PNG")
    return out.getvalue()


SVG = b'<svg xmlns="http://www.w3.org/2000/svg" width="10" height="10">\n<path d="M0 0 L10 10"/>\n</svg>\n'


@pytest.mark.parametrize("name, content, said", [
    ("empty.gcode", b"", "the G-code file is empty"),
    ("blank.gcode", b"\n  \r\n\t\n", "the G-code file has only blank lines, no G-code"),
    ("logo.png", _png(), "not a text G-code file (binary data: a NUL byte at byte "),
    ("logo.svg", SVG, "no move or dwell to time (G0-G3, G4); is it a G-code file?"),
    ("cut.gcode", b"G90\nG1 X10 F600\nG1 X119.5 E9",
     "3: the file does not end with a line end, so its last line 'G1 X119.5 E9' may be cut off"),
], ids=["empty", "blank", "png", "svg", "cut-off"])
def test_estimate_refuses_what_is_not_gcode(tmp_path, name, content, said):
    g = tmp_path / name
    g.write_bytes(content)
    r = run("estimate", g)
    assert r.exit_code == 1, r.output
    assert r.output.startswith(f"Error: {g}:") and said in r.output and r.output.count("\n") == 1
    # both of the estimator's readers: the compiled scanner's records and the text parser's lines
    for scanned in (False, True):
        with pytest.raises(Exception, match=re.escape(said)):
            es.estimate_file(g, scanned=scanned)


def test_estimate_still_times_a_file_of_dwells_and_one_without_a_last_line_end(tmp_path):
    g = tmp_path / "dwell.gcode"
    g.write_text("G4 S2\n; the end, no line end after this comment")
    r = run("estimate", g)
    assert r.exit_code == 0, r.output
    assert "0h 00m 02.0s (2.0 s; 0 moves, dwell 2.0 s" in r.output


# -- a text or drawing off the wall is said as a whole, with the option that fixes it

CYL = REPO / "examples" / "cylinder40x20.gcode"     # wall 0..20.1 mm


def build(tmp_path, *args):
    return run("build", CYL, *args, "-o", tmp_path / "o", "--no-preview")


def tall_svg(tmp_path, name="tall.svg"):
    p = tmp_path / name
    p.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="20mm" height="40mm" viewBox="0 0 20 40">\n'
                 '<path d="M10 1 L10 39"/>\n</svg>\n')
    return p


def test_text_taller_than_the_wall_is_told_its_size(tmp_path):
    r = build(tmp_path, "--text", "HI", "--text-size", 30, "--at", "0,3")
    assert r.exit_code == 1
    assert r.output.strip() == ("Error: the text 'HI' is 30 mm tall at --text-size 30 mm, but the wall is "
                                "only 20.1 mm tall; use a smaller size, 20 mm or less")
    assert not (tmp_path / "o").exists()
    assert build(tmp_path, "--text", "HI", "--text-size", 20, "--at", "0,0").exit_code == 0   # it fits


@pytest.mark.parametrize("text, at, said, fixed", [
    ("HI", "0,17", "reaches from 17 to 23 mm above the bed, but the wall goes from 0 to 20.1 mm; "
                   "move it down by at least 2.9 mm (its baseline start, --at U,V)", "0,14.1"),
    # a descender below the bed
    ("Hgj", "0,0", "reaches from -2 to 6.29 mm above the bed, but the wall goes from 0 to 20.1 mm; "
                   "move it up by at least 2 mm (its baseline start, --at U,V)", "0,2")])
def test_text_off_the_wall_is_told_which_way_and_how_far(tmp_path, text, at, said, fixed):
    r = build(tmp_path, "--text", text, "--at", at)
    assert r.exit_code == 1
    assert r.output.strip() == f"Error: the text {text!r} {said}"
    assert "stroke spans v" not in r.output
    assert build(tmp_path, "--text", text, "--at", fixed).exit_code == 0     # moved that far, it fits


def test_an_svg_taller_than_the_wall_is_told_its_scale(tmp_path):
    svg = tall_svg(tmp_path)
    r = build(tmp_path, "-s", svg)
    assert r.exit_code == 1
    assert r.output.strip() == (f"Error: {svg}: the drawing is 38 mm tall at --scale 1, but the wall is only "
                                "20.1 mm tall; use a smaller scale, 0.52 or less")
    r = build(tmp_path, "-s", svg, "--scale", 0.5, "--at", "0,5")
    assert r.output.strip() == (f"Error: {svg}: the drawing reaches from 5.5 to 24.5 mm above the bed, but the "
                                "wall goes from 0 to 20.1 mm; move it down by at least 4.4 mm (its page's "
                                "lower-left corner, --at U,V)")
    # at the scale it says, it is short enough, and fits once moved (the default --at puts its
    # lower-left corner 1 mm above the bed)
    r = build(tmp_path, "-s", svg, "--scale", 0.52)
    assert r.exit_code == 1 and "move it down by at least 1.18 mm" in r.output
    assert build(tmp_path, "-s", svg, "--scale", 0.52, "--at", "0,-0.18").exit_code == 0


def test_a_json_stroke_list_too_tall_is_told_its_scale(tmp_path):
    j = tmp_path / "line.json"
    j.write_text('{"strokes": [{"points": [[5, 2], [5, 12]]}, {"points": [[8, 2]]}]}\n')
    r = build(tmp_path, "-s", j, "--scale", 3)
    assert r.exit_code == 1
    assert r.output.strip() == (f"Error: {j}: the drawing is 30 mm tall at --scale 3, but the wall is only "
                                "20.1 mm tall; use a smaller scale, 2 or less")


def _placement(tmp_path, body):
    p = tmp_path / "p.toml"
    p.write_text(body)
    return p


@pytest.mark.parametrize("body, said", [
    ('[[text]]\ntext = "HI"\nsize = 30\nat = [0, 3]\n',
     "text[0]: the text 'HI' is 30 mm tall at size = 30 mm, but the wall is only 20.1 mm tall; "
     "use a smaller size, 20 mm or less"),
    ('[[text]]\ntext = "OK"\n\n[[text]]\ntext = "HI"\nat = [0, 17]\n',
     "text[1]: the text 'HI' reaches from 17 to 23 mm above the bed, but the wall goes from 0 to 20.1 mm; "
     "move it down by at least 2.9 mm (its baseline start, at = [U, V])"),
    # turned a quarter about `at`: its letters, 1.9 to 12.38 mm along the baseline, stand above it
    ('[[text]]\ntext = "HI"\nsize = 10\nat = [20, 10]\nrotate = 90\n',
     "text[0]: the text 'HI' reaches from 11.9 to 22.38 mm above the bed, but the wall goes from 0 to "
     "20.1 mm; move it down by at least 2.29 mm (its baseline start, at = [U, V])"),
    ('[[strokes]]\nfile = "tall.svg"\n',
     "strokes[0]: {dir}/tall.svg: the drawing is 38 mm tall at scale = 1, but the wall is only 20.1 mm tall; "
     "use a smaller scale, 0.52 or less"),
    ('[[strokes]]\nfile = "sq.png"\nimage_width = 30\n',
     "strokes[0]: {dir}/sq.png: the picture is 30 mm tall at image_width = 30 mm, but the wall is only "
     "20.1 mm tall; use a smaller width, 19.5 mm or less"),
], ids=["text-tall", "text-high", "text-turned", "svg-tall", "picture-tall"])
def test_in_a_placement_file_the_message_names_its_entry_and_keys(tmp_path, body, said):
    tall_svg(tmp_path)
    Image.fromarray(np.zeros((100, 100), np.uint8)).save(tmp_path / "sq.png")
    p = _placement(tmp_path, body)
    said = said.format(dir=tmp_path)
    g = tmp_path / "part.gcode"
    g.write_bytes(CYL.read_bytes())
    for argv in (["build", CYL, "--placement", p, "-o", tmp_path / "o", "--no-preview"],
                 ["post-process", "--placement", p, g]):
        r = run(*argv)
        assert r.exit_code == 1, (argv, r.output)
        assert said in r.output and r.output.startswith(f"Error: {p}: "), r.output
        assert "--" not in r.output                 # no CLI option named for a placement file
    assert g.read_bytes() == CYL.read_bytes()


# -- a file missing from inside a placement file is a missing input file like any other

@pytest.mark.parametrize("cmd", ["build", "post-process"])
def test_a_file_missing_from_a_placement_is_a_usage_error(tmp_path, cmd):
    p = _placement(tmp_path, '[[text]]\ntext = "HI"\n\n[[strokes]]\nfile = "nothing.svg"\n')
    g = tmp_path / "part.gcode"
    g.write_bytes(CYL.read_bytes())
    argv = (["build", g, "--placement", p, "-o", tmp_path / "o"] if cmd == "build" else
            ["post-process", "--placement", p, g])
    r = run(*argv)
    assert r.exit_code == 2, r.output                 # as click's, for a file named on the command line
    # one line: the command line was right, so click's Usage lines would only mislead
    assert r.output == f"Error: {p}: strokes[0].file: {tmp_path / 'nothing.svg'} not found\n", r.output
    assert g.read_bytes() == CYL.read_bytes() and not (tmp_path / "o").exists()
    assert not [d for d in tmp_path.iterdir() if d.name.startswith(".bulgekit-")]
