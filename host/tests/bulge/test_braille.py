"""Braille (bulge/braille.py): liblouis translation, the standard's cell geometry, the dot's dome,
the readable-dot check, and braille built onto real sliced walls, read back from the map's points
alone: dot and cell spacing measured along the wall, and liblouis's back-translation of the cells
found there."""
from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bulgekit.bulge import braille as br
from bulgekit.cli import main

REPO = Path(__file__).resolve().parents[3]
CYL = REPO / "examples" / "cylinder40x20.gcode"
PANGRAM = "The quick brown fox jumps over the lazy dog"


def test_pangram_grade_1_letter_by_letter():
    (cells,) = br.translate(PANGRAM, "en-ueb-g1.ctb")
    # a capital sign (dot 6) and one cell per letter and space: nothing contracted in grade 1
    assert cells[0] == br.cell_of([6])
    assert len(cells) == 1 + len(PANGRAM)
    assert cells[1:4] == "".join(br.cell_of(d) for d in ([2, 3, 4, 5], [1, 2, 5], [1, 5]))   # t h e
    assert br.back_translate([cells], "en-ueb-g1.ctb") == PANGRAM


def test_pangram_grade_2_contracts():
    (g1,) = br.translate(PANGRAM, "en-ueb-g1.ctb")
    (g2,) = br.translate(PANGRAM, br.table_for(2))
    assert len(g2) < len(g1)
    assert br.cell_of([2, 3, 4, 6]) in g2        # "the" as one cell
    assert br.back_translate([g2], br.table_for(2)) == PANGRAM
    assert br.back_translate(br.translate("and for with", br.table_for(2)), br.table_for(2)) == "and for with"
    assert len(br.translate("and for with", br.table_for(2))[0]) == 5     # three words, two spaces


def test_table_and_grade_errors():
    with pytest.raises(br.BrailleError, match="table 'xx-none.ctb' not found"):
        br.translate("hi", "xx-none.ctb")
    with pytest.raises(br.BrailleError, match="grade 3"):
        br.table_for(3)
    with pytest.raises(br.BrailleError, match="no text"):
        br.braille_strokes("  ")


def test_layout_is_the_standard_spacing():
    dots = br.layout(["⠿⠿", "⠿"], 10.0, 20.0)         # full cells: dots 1-6
    at = {(d.line, d.cell, d.dot): (d.u, d.v) for d in dots}
    assert at[(0, 0, 3)] == (10.0, 20.0)               # dot 3 of the first cell on v0
    assert at[(0, 0, 1)] == (10.0, 25.0)
    assert at[(0, 0, 4)][0] - at[(0, 0, 1)][0] == br.DOT_PITCH == 2.5
    assert at[(0, 0, 1)][1] - at[(0, 0, 2)][1] == 2.5
    assert at[(0, 1, 1)][0] - at[(0, 0, 1)][0] == br.CELL_PITCH == 6.0
    assert at[(0, 0, 1)][1] - at[(1, 0, 1)][1] == br.LINE_PITCH == 10.0


def test_a_dot_is_a_dome_over_the_layers(tmp_path):
    """One dot on the example cylinder's 0.3 mm layers: a point on each layer whose middle lies
    within 0.75 mm of the dot's v, at its u, weighted 255 sqrt(1 - (dv / 0.75)^2)."""
    from bulgekit.bulge import api, mapbuild
    st = br.dome(br.Dot(5.0, 8.0, 0, 0, 1), "t")
    assert st.dome == br.DOT_BASE / 2 and st.points == ((5.0, 8.0),)
    model = api.walls(CYL)
    res = api.build_map(model, [st])
    got = sorted((round(model.walls[p.layer].z - model.walls[p.layer].height / 2, 3), p.weight)
                 for p in res.points)
    want = sorted((round(w.z - w.height / 2, 3), round(255 * math.sqrt(1 - ((w.z - w.height / 2 - 8.0) / 0.75) ** 2)))
                  for w in model.walls if abs(w.z - w.height / 2 - 8.0) < 0.75)
    want = [x for x in want if x[1] >= mapbuild.DOME_MIN_WEIGHT]
    assert got == want and len(got) >= 3
    assert max(abs(p.u - 5.0) for p in res.points) < 0.05          # snapped onto the toolpath


def test_readable_check():
    assert br.readable(0.2, 100, 0.9) == []
    why = br.readable(0.6, 100, 0.9)
    assert len(why) == 1 and "too thick" in why[0]
    assert "run together" in br.readable(0.2, 600, 0.9)[0]
    assert "too small to feel" in br.readable(0.2, 10, 0.9)[0]
    assert "would become one" in br.readable(0.2, 100, 5.2)[0]


def test_build_refuses_an_unreadable_dot_and_writes_nothing(tmp_path):
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["build", str(CYL), "--braille", "Hi", "--at", "3,5", "--dwell", "900",
                                  "-o", str(out), "--no-preview"])
    assert r.exit_code == 1 and "cannot make a readable dot" in r.output and "500 ms or less" in r.output
    assert not out.exists()


def decode(points, u0: float, v0: float, table: str, length: float) -> tuple[str, list]:
    """Cells read from map points alone: points within a dot's radius are one dot (its centre the
    weighted mean of their u and v), each dot put in its cell and place by the grid from (u0, v0).
    u is taken round the wall (0..length): unwrapped from just before u0."""
    pts = sorted(((u0 + (u - u0 + 1) % length - 1, v, w) for u, v, w in points),
                 key=lambda p: (p[0], p[1]))
    dots: list[list] = []
    for u, v, w in pts:
        for d in dots:
            if abs(d[0][0] - u) < 0.6 and abs(d[0][1] - v) < br.DOT_BASE:
                d.append((u, v, w))
                break
        else:
            dots.append([(u, v, w)])
    centres = []
    for d in dots:
        a = np.array(d)
        centres.append((float((a[:, 0] * a[:, 2]).sum() / a[:, 2].sum()),
                        float((a[:, 1] * a[:, 2]).sum() / a[:, 2].sum())))
    lines: dict[int, dict[int, set]] = {}
    for u, v in centres:
        x, top = u - u0, v0 + 2 * br.DOT_PITCH
        line = math.floor((top - v + br.DOT_PITCH) / br.LINE_PITCH)
        row = round((top - line * br.LINE_PITCH - v) / br.DOT_PITCH)
        cell = math.floor((x + 1.75) / br.CELL_PITCH)
        side = round((x - cell * br.CELL_PITCH) / br.DOT_PITCH)
        lines.setdefault(line, {}).setdefault(cell, set()).add(side * 3 + row + 1)
    text = []
    for line in sorted(lines):
        cells = lines[line]
        text.append("".join(br.cell_of(cells.get(c, ())) for c in range(max(cells) + 1)))
    return br.back_translate(text, table), centres


def spacing_errors(centres, u0, v0):
    """|measured - standard| of every pair of neighbouring dots along u (2.5 mm within a cell,
    6.0 mm between a cell's dot and the same dot of the next) and along v (2.5 mm)."""
    errs = []
    c = np.array(centres)
    for i, (u, v) in enumerate(c):
        for j, (u2, v2) in enumerate(c):
            du, dv = u2 - u, v2 - v
            if abs(dv) < 0.5 and 2.0 < du < 3.0:
                errs.append(abs(du - br.DOT_PITCH))
            if abs(dv) < 0.5 and 5.5 < du < 6.5:
                errs.append(abs(du - br.CELL_PITCH))
            if abs(du) < 0.5 and 2.0 < -dv < 3.0:
                errs.append(abs(-dv - br.DOT_PITCH))
    return errs


def _built_points(gcode: Path, args: list[str], tmp: Path):
    from bulgekit.bulge import api
    from bulgekit.bulge.placement import load_placement
    p = tmp / "p.toml"
    p.write_text(args[0])
    pl = load_placement(p)
    out = api.build(gcode, pl.strokes, tmp / "o", write_fallback=False)
    model = out.result.model
    pts = [(bp.u, bp.z - model.walls[bp.layer].height / 2, bp.weight) for bp in out.result.points]
    return pts, model.walls[out.result.points[0].layer].length


@pytest.mark.parametrize("grade", [1, 2])
def test_braille_on_a_sliced_cylinder_reads_back(tmp_path, grade):
    text = "Hello bulge"
    pts, length = _built_points(CYL, [f'[[braille]]\ntext = "{text}"\nat = [3, 5]\ngrade = {grade}\n'], tmp_path)
    got, centres = decode(pts, 3, 5, br.table_for(grade), length)
    assert got == text
    errs = spacing_errors(centres, 3, 5)
    assert len(errs) > 10 and max(errs) <= 0.1, max(errs)


def _slice_box(tmp: Path) -> Path:
    import trimesh
    exe = shutil.which("prusa-slicer")
    assert exe, "prusa-slicer is needed (tools/install-deps.sh installs it)"
    stl = tmp / "box.stl"
    trimesh.creation.box((60, 30, 20)).apply_translation((0, 0, 10)).export(stl)
    g = tmp / "box.gcode"
    r = subprocess.run([exe, "--export-gcode", "--layer-height", "0.2", "--first-layer-height", "0.2",
                        "--nozzle-diameter", "0.4", "--center", "100,100", "--gcode-flavor", "marlin2",
                        "--perimeters", "2", "--fill-density", "10%", "--output", str(g), str(stl)],
                       capture_output=True, text=True)
    assert r.returncode == 0 and g.is_file(), r.stdout[-2000:] + r.stderr[-2000:]
    return g


def test_braille_on_a_sliced_box_reads_back(tmp_path):
    """A 60 x 30 mm box at 0.2 mm layers, PrusaSlicer 2.5: braille on its long front face."""
    g = _slice_box(tmp_path)
    pts, length = _built_points(g, [f'[[braille]]\ntext = "{PANGRAM[:19]}"\nat = [-25, 6]\n'], tmp_path)
    # u runs from the middle of the front face (-Y): u in -25..+25 stays on that 60 mm face
    got, centres = decode(pts, -25, 6, br.table_for(1), length)
    assert got == PANGRAM[:19]
    errs = spacing_errors(centres, -25, 6)
    assert len(errs) > 20 and max(errs) <= 0.1, max(errs)
