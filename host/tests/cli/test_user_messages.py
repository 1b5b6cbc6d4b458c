"""Errors said in the user's words (issue 26): an empty G-code file is reported as empty, and a
picture that does not fit the wall is described by its size and place, not by one cell's v."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from bulgekit.bulge import mapformat
from bulgekit.cli import main

from conftest import REPO

CYL = REPO / "examples" / "cylinder40x20.gcode"     # wall 0..20.1 mm


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.mark.parametrize("content, said", [(b"", "the G-code file is empty"),
                                           (b"\n  \r\n\t\n", "the G-code file has only blank lines, no G-code")])
def test_an_empty_gcode_file_is_called_empty(tmp_path, content, said):
    g = tmp_path / "part.gcode"
    g.write_bytes(content)
    m = tmp_path / "x.bkm"
    m.write_bytes(mapformat.encode_map([(0.6, [(100.0, 80.0)])], layer_height_mm=0.3))
    out = tmp_path / "out"
    for argv in (["build", g, "--text", "HI", "-o", out],
                 ["annotate", g, m, "-o", out],
                 ["fallback", g, m, "-o", out],
                 ["stats", m, "-g", g],
                 ["preview", g, "--text", "HI", "-o", out],
                 ["post-process", "--placement", REPO / "examples" / "placement.toml", g]):
        r = run(*argv)
        assert r.exit_code == 1, (argv, r.output)
        assert r.output.strip() == f"Error: {g}: {said}", argv
        assert not out.exists()
    assert g.read_bytes() == content                     # post-process left it alone


def square(tmp_path, name="sq.png"):
    p = tmp_path / name
    Image.fromarray(np.zeros((100, 100), np.uint8)).save(p)    # black: a dot in every cell
    return p


def test_a_picture_taller_than_the_wall_is_said_in_its_own_size(tmp_path):
    p = square(tmp_path)
    r = run("build", CYL, "-s", p, "--image-width", 30, "-o", tmp_path / "o", "--no-preview")
    assert r.exit_code == 1
    assert r.output.strip() == (
        f"Error: {p}: the picture is 30 mm tall at --image-width 30 mm, "
        "but the wall is only 20.1 mm tall; use a smaller width, 19.5 mm or less")
    assert "pixel cell" not in r.output and not (tmp_path / "o").exists()
    # the width it suggests fits
    r = run("build", CYL, "-s", p, "--image-width", 19.5, "-o", tmp_path / "o", "--no-preview")
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("at, said", [("0,15", "reaches from 15 to 25.5 mm above the bed, but the wall goes "
                                                "from 0 to 20.1 mm; move it down by at least 5.4 mm"),
                                      ("0,-3", "reaches from -3 to 7.5 mm above the bed, but the wall goes "
                                                "from 0 to 20.1 mm; move it up by at least 3 mm")])
def test_a_picture_that_fits_but_sits_off_the_wall_is_told_to_move(tmp_path, at, said):
    p = square(tmp_path)
    r = run("build", CYL, "-s", p, "--image-width", 10, "--at", at, "-o", tmp_path / "o", "--no-preview")
    assert r.exit_code == 1
    assert f"{p}: the picture {said} (its lower-left corner, --at U,V)" in r.output


def test_a_turned_picture_is_not_described_by_its_unturned_size(tmp_path):
    from bulgekit.bulge import api
    from bulgekit.bulge.mapbuild import BuildError
    from bulgekit.bulge.placement import _rotated
    from bulgekit.bulge.strokes import image_dots
    p = square(tmp_path)
    dots = _rotated(image_dots(str(p), 15, u0=20, v0=2), 45, (20, 2))   # turned: taller than 15 mm
    with pytest.raises(BuildError) as e:
        api.build_map(api.walls(CYL), dots)
    assert "stroke spans v" in str(e.value) and "the picture is" not in str(e.value)
