"""walls_from_records computes the walls of thousands of layers at once, on arrays: its walls are,
field by field and to the bit, those of the rules stated one move and one wall at a time
(reference_walls below: a chain of outer-wall moves per layer bucket, the closed one of largest
area, _area_centroid, the cumsum of hypot, _ray_hit), on every test file, in marked and
geometric mode, from every record or from a kept lean Scan, in chunks of 997 bytes or 2 MB."""
from __future__ import annotations

import bisect
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from bulgekit.bulge import wall
from bulgekit.gcode import header_layer_height, movescan, open_checked
from test_build_lean import arcs_gcode

HERE = Path(__file__).resolve().parents[1]
FILES = [HERE / "data" / n for n in ("cura_cyl.gcode", "prusa_cyl.gcode", "prusa_cyl_m83.gcode",
                                     "prusa_vase.gcode", "slic3r_cyl.gcode")]


def reference_walls(path, geometric=False, layer_height=None, ref_angle_deg=-90.0):
    """(walls as dicts of Wall's fields, layer height, notes) of the file, one move at a time."""
    recs = movescan.run(path, lambda ch: np.concatenate(list(ch)), fast=False)
    c, _, _ = movescan.classes(recs)
    rows, broken = [], False                 # (x0, y0, x1, y1, z0, z1, move number, broken before)
    for i, (r, k) in enumerate(zip(recs.tolist(), c.tolist())):
        outer = bool(k & movescan.OUTER)
        ok = bool(k & movescan.EXTRUDES) and (outer or geometric)
        if ok:
            rows.append((r[0], r[1], r[3], r[4], r[2], r[5], i, broken))
            broken = False
        elif (k & movescan.MOVED) or (not outer and not geometric):
            broken = True
    # layer height: the header's, the one given, else the commonest step of the planar layers
    planar = Counter(wall._z_cmm(r[5]) for r in rows if abs(r[5] - r[4]) < 1e-6)
    zsp = sorted(z for z, n in planar.items() if n >= 4)
    header = header_layer_height(open_checked(path)[0])
    notes = []
    if header and layer_height is not None and abs(header - layer_height) > 1e-6:
        notes.append(f"layer height {layer_height:g} mm given, but the G-code says "
                     f"{header:g} mm: using the G-code's")
    h = header or layer_height
    if not h:
        steps = Counter(b - a for a, b in zip(zsp, zsp[1:]) if b - a >= 5)
        # the commonest step, the smallest of equally common ones
        h = min(s for s, n in steps.items() if n == max(steps.values())) / 100 if steps else 0.2
    hc = max(1, round(h * 100))

    def bucket(r):
        z = wall._z_cmm(r[5])
        if abs(r[5] - r[4]) < 1e-6 and z in zsp:
            return z
        i = bisect.bisect_right(zsp, z) - 1
        base = zsp[i] if i >= 0 else 0
        return base - ((hc - 2 * (z - base)) // (2 * hc)) * hc

    chains = []                              # [bucket, rows]
    for r in rows:
        last = chains[-1][1][-1] if chains else None
        if (last is None or r[7] or bucket(r) != chains[-1][0]
                or not (abs(last[2] - r[0]) <= 1e-4 and abs(last[3] - r[1]) <= 1e-4)):
            chains.append([bucket(r), [r]])
        else:
            chains[-1][1].append(r)
    gap = max(2.0, 3 * h)
    by_bucket = {}
    for b, rs in chains:
        if len(rs) >= 2:
            pts = np.array([rs[0][:2]] + [r[2:4] for r in rs])
            closed = math.hypot(*(pts[-1] - pts[0]).tolist()) <= gap
            by_bucket.setdefault(b, []).append((pts, closed, rs))
    direction = (math.cos(math.radians(ref_angle_deg)), math.sin(math.radians(ref_angle_deg)))
    chosen, upper = {}, None
    for b in sorted(by_bucket, reverse=geometric):
        cands = by_bucket[b]
        pool = [cd for cd in cands if cd[1]] or cands
        if not any(cd[1] for cd in cands):
            notes.append(f"layer z {b / 100:.2f}: no closed outer loop, using the largest open one")
        if geometric and upper is not None:
            pool = [cd for cd in pool if wall._median_distance(cd[0], upper) <= max(1.0, 3 * h)] or pool
        best = max(pool, key=lambda cd: abs(wall._signed_area(cd[0])))    # (the first of the largest)
        chosen[b] = best
        if geometric:
            upper = best[0]
    walls, prev = [], None
    for b in sorted(chosen):
        xy, closed, rs = chosen[b]
        s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xy[:, 0]), np.diff(xy[:, 1])))])
        area, cen = wall._area_centroid(xy)
        z = b / 100
        height = min(z, h) if prev is None else (z - prev if z - prev <= 1.5 * h else h)
        prev = z
        walls.append(dict(z=z, xy=xy, s=s, move_index=np.array([r[6] for r in rs]), height=height,
                          ccw=area >= 0, s_ref=wall._ray_hit(xy, s, cen, direction), centroid=cen,
                          closed=closed, turn=0.0))
    loops = [w for w in walls if w["closed"]]
    for w in walls:
        if not w["closed"] and loops:
            w["turn"] = float(min(loops, key=lambda c: abs(c["z"] - w["z"]))["s"][-1])
    return walls, hc / 100, notes


# (slic3r_cyl has no feature comments: geometric mode only, which lean chunks cannot give)
CASES = [(p, mode) for p in [*FILES, "arcs"] for mode in ("marked", "lean", "geometric", "height 0.3")
         if not (isinstance(p, Path) and p.name == "slic3r_cyl.gcode" and mode != "geometric")]


@pytest.mark.parametrize("chunk", [997, 1 << 21])
@pytest.mark.parametrize("path, mode", CASES,
                         ids=lambda v: v if isinstance(v, str) else v.name)
def test_walls_are_those_of_the_rules_one_move_at_a_time(path, mode, chunk, monkeypatch, tmp_path):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", chunk)
    path = arcs_gcode(tmp_path) if path == "arcs" else path
    geometric = mode == "geometric"
    lh = 0.3 if mode == "height 0.3" else None
    want, height, notes = reference_walls(path, geometric, lh)
    with movescan.Scan(path, lean=mode == "lean").kept():
        got = wall.walls_from_gcode(path, layer_height=lh, geometric=geometric)
    assert (got.layer_height, got.notes, len(got.walls)) == (height, notes, len(want))
    assert len(want) > 5
    for g, w in zip(got.walls, want):
        for name, v in w.items():
            x = getattr(g, name)
            if isinstance(v, np.ndarray):
                assert x.dtype == v.dtype and np.array_equal(x, v) and x.tobytes() == v.tobytes(), name
            else:
                assert type(x) is type(v) and x == v, (name, x, v)
