"""More of issue 26's rough edges, each in the user's words: `estimate` refuses what is not
G-code as every other command does."""
from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from bulgekit.cli import main
from bulgekit.gcode import estimate as es


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
