"""The compiled pass over a chunk of moves that finds the walls' rows (_scan.c wall_rows, which
wall._rows_c calls) gives what numpy's steps give (wall._rows_np), part by part and to the bit:
on random chunks with the state carried from one to the next (breaks, the last row's end, move
numbers with gaps), on edge values (-0.0, NaN and inf coordinates, ends 1e-4 mm apart), and on
whole files in both modes, lean and full scans alike. A row whose z is not finite is left to
numpy's steps."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bulgekit.bulge import wall
from bulgekit.gcode import movescan

DATA = Path(__file__).resolve().parent.parent / "data"


def test_the_compiled_pass_is_built():
    assert wall._wall_rows is not None


def _same(got, want) -> None:
    """Two passes' (breaks, after, outer, parts), arrays compared by their bytes."""
    assert got[:3] == want[:3]
    assert (got[3] is None) == (want[3] is None)
    if got[3] is None:
        return
    for g, w in zip(got[3], want[3]):
        g, w = np.asarray(g), np.asarray(w)
        assert g.dtype == w.dtype and g.shape == w.shape
        assert np.ascontiguousarray(g).tobytes() == np.ascontiguousarray(w).tobytes()


def _chunk(rng: np.random.Generator, n: int) -> np.ndarray:
    """n moves that often join end to start, in runs of one z, with edge values among them."""
    a = np.zeros(n, movescan.RECORD)
    x1 = rng.choice([0.0, 1.0, 2.5, 10.0], n) + rng.integers(0, 3, n) * 1e-4 * rng.choice([0.5, 1, 1.5], n)
    y1 = rng.choice([0.0, -0.0, 3.0, 7.25], n)
    a["x1"], a["y1"] = x1, y1
    # the start mostly at the end before (a chain), sometimes off by about 1e-4 or elsewhere
    a["x0"][1:], a["y0"][1:] = x1[:-1], y1[:-1]
    off = rng.random(n) < 0.2
    a["x0"][off] += rng.choice([1e-4, -1e-4, 0.99e-4, 1.01e-4, 5.0], int(off.sum()))
    a["y0"][rng.random(n) < 0.05] = rng.choice([np.nan, np.inf, -0.0, 1e-4], 1)[0]
    z = np.repeat(rng.choice([0.2, 0.4, 0.4000001, 0.6, 1.005, 0.125, -0.0], max(1, n // 7 + 1)), 7)[:n]
    a["z1"] = z
    a["z0"] = np.where(rng.random(n) < 0.8, z, z - rng.choice([1e-7, 2e-6, 0.2], n))
    a["e"] = rng.choice([0.0, 0.02, -0.5, 0.1], n)
    a["flags"] = rng.integers(0, 16, n)
    still = rng.random(n) < 0.1                       # some moves stand still in XY
    a["x1"][still], a["y1"][still] = a["x0"][still], a["y0"][still]
    return a


# (lean scans are for marked mode only: walls_from_records refuses geometric mode on them)
@pytest.mark.parametrize("geometric, lean", [(False, False), (False, True), (True, False)])
def test_random_chunks_give_numpys_parts(geometric, lean):
    rng = np.random.default_rng(26 + 2 * geometric + lean)
    row = movescan.EXTRUDES | (0 if geometric else movescan.OUTER)
    inside = 0 if geometric else movescan.OUTER
    seen = set()
    for trial in range(60):
        breaks, last, after, done, rows_done = 0, None, -1, 0, 0
        number = 0
        for _ in range(rng.integers(1, 6)):
            a = _chunk(rng, int(rng.integers(1, 300)))
            c, _, _ = movescan.classes(a)
            num = None
            if lean:
                gaps = 1 + rng.choice([0, 0, 0, 1, 5], len(a))        # moves left out between
                num = (number + np.cumsum(gaps)).astype(np.int64)
                number = int(num[-1])
            want = wall._rows_np(a, c, num, row, inside, breaks, last, after, done, rows_done)
            got = wall._rows_c(a, c, num, row, inside, breaks, last, after, done, rows_done)
            if got is None:                 # a row's z not finite: left to numpy
                assert not np.isfinite(a["z1"][(c & row) == row]).all()
                seen.add("left")
                got = want
            _same(got, want)
            breaks, after, _, parts = want
            done += len(a)
            if parts is not None:
                last = (float(parts[0][-1].real), float(parts[0][-1].imag))
                rows_done += len(parts[0])
                seen.add("rows")
                if parts[2].any() and not parts[2].all():
                    seen.add("links")
            else:
                seen.add("none")
    assert {"rows", "links"} <= seen                  # (the cases the test is for came up)


def test_a_row_z_that_is_not_finite_goes_to_numpy():
    a = np.zeros(3, movescan.RECORD)
    a["x1"], a["e"], a["flags"] = [1.0, 2.0, 3.0], 0.1, movescan.OUTER
    a["x0"][1:] = a["x1"][:-1]
    a["z0"] = a["z1"] = [0.2, np.inf, 0.2]
    c, _, _ = movescan.classes(a)
    assert wall._rows_c(a, c, None, movescan.EXTRUDES | movescan.OUTER, movescan.OUTER,
                        0, None, -1, 0, 0) is None


def _model_bytes(m: wall.WallModel) -> list:
    out = [m.layer_height, m.geometric, tuple(m.notes)]
    for w in m.walls:
        out.append((w.z, w.xy.tobytes(), np.asarray(w.s).tobytes(), np.asarray(w.move_index).tobytes(),
                    w.height, w.ccw, w.s_ref, w.centroid, w.closed, w.turn))
    return out


MARKED = ["prusa_cyl.gcode", "prusa_cyl_m83.gcode", "cura_cyl.gcode", "prusa_vase.gcode"]


# (slic3r_cyl.gcode has no feature comments: geometric mode only)
@pytest.mark.parametrize("name, mode", [(n, m) for n in MARKED for m in ("marked-lean", "marked")]
                         + [(n, "geometric") for n in MARKED + ["slic3r_cyl.gcode"]])
def test_files_give_the_same_walls(name, mode, monkeypatch):
    path = DATA / name
    geometric = mode == "geometric"
    with movescan.Scan(path, str(path), lean=mode == "marked-lean").kept():
        compiled = wall.walls_from_gcode(path, geometric=geometric)
        monkeypatch.setattr(wall, "_wall_rows", None)
        steps = wall.walls_from_gcode(path, geometric=geometric)
    assert _model_bytes(compiled) == _model_bytes(steps)
    assert len(compiled.walls) == 33
