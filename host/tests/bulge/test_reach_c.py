"""The compiled reach check (bulgekit/bulge/_reach.c) makes the stops of the Python one
(fallback.Skipper's picking and _plan_lazily's planning) to the bit: the stops' lines, places,
dwells and points, the statistics, the highest extruding z and the extra still owed. On the test
files with random maps and settings, in chunks small enough that moves are owed across them, and
on random walls made to hit the planner's corners: points beyond a move's end (deferred), merged
points past the dwell limit, extra filament past its cap, tiny pieces, -0.0, layers without
points, many points per layer. test_movescan.py compares lazy runs with planning every move."""
from __future__ import annotations

import random

import numpy as np
import pytest

from bulgekit.bulge import fallback, mapformat
from bulgekit.bulge.fallback import RefPlanner, Settings, plan_records
from bulgekit.gcode import movescan

from test_movescan import FILES, _random_map


@pytest.fixture(autouse=True)
def _built():
    assert fallback._compiled_reach() is not None, \
        "the compiled reach check is not built: cd host && python3 setup.py build_ext --inplace"


def _scanned(gcode, consume, compiled: bool, monkeypatch, chunk=None, lean=False):
    """movescan.run(gcode, consume) with the compiled reach check or without it, in chunks of
    chunk bytes."""
    with monkeypatch.context() as mp:
        if not compiled:
            mp.setattr(fallback, "_reach_c", None)
        if chunk:
            mp.setattr(movescan, "CHUNK_BYTES", chunk)
        movescan.run(gcode, consume, lean=lean)


def _run(gcode, bm, settings, compiled: bool, monkeypatch, bypass=True, lean=False, chunk=None):
    p = RefPlanner(bm, settings)
    _scanned(gcode, lambda ch: plan_records(p, ch, arcs_bypass=bypass, lazy=True), compiled, monkeypatch,
             chunk, lean)
    return p


def _same(a: RefPlanner, b: RefPlanner):
    assert [vars(s) for s in a.stops] == [vars(s) for s in b.stops]
    assert a.stats == b.stats
    assert a.top_z == b.top_z
    assert (a.carry, a.stop_ms) == (b.carry, b.stop_ms)


def _compare(gcode, bm, settings, monkeypatch, **kw) -> RefPlanner:
    ref = _run(gcode, bm, settings, False, monkeypatch, **kw)
    got = _run(gcode, bm, settings, True, monkeypatch, **kw)
    _same(got, ref)
    return got


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_the_compiled_check_stops_where_the_python_one_does(path, monkeypatch):
    rng = random.Random("reach-c" + path.name)
    stops = 0
    for trial in range(4):
        geometric = trial % 2 == 1 or path.name.startswith("slic3r")
        settings = Settings(mode=2 if geometric else 1, dwell_ms=rng.choice([0, 100, 700, 2000]),
                            extra_e=rng.choice([0.0, 0.1, 0.9]), tolerance=rng.choice([0.05, 0.15, 0.6]))
        bm = _random_map(path, rng, geometric)
        for bypass in (False, True):
            lean = bypass and not geometric and trial == 0
            got = _compare(path, bm, settings, monkeypatch, bypass=bypass, lean=lean,
                           chunk=rng.choice([None, 4096]))
            stops += len(got.stops)
    assert stops > 0, "the maps must make stops for this test to mean something"


def _wall_file(rng: random.Random, layers: int = 12):
    """G-code of outer walls (closed polygons with tiny, null and travel moves between) and map
    points on and near them, many per layer: exactly at ends, a hair beyond them, merged."""
    lines = ["G21\nG90\nM82\nG92 E0\n"]
    pts: dict[int, list] = {}
    e = 0.0
    for k in range(layers):
        z = round(0.2 + 0.2 * k, 2)
        lines.append(f"G1 Z{z:.2f} F600\n;TYPE:External perimeter\n")
        n = rng.randint(3, 40)
        cx, cy, r = rng.uniform(20, 40), rng.uniform(20, 40), rng.uniform(2, 15)
        ring = [(cx + r * np.cos(2 * np.pi * i / n), cy + r * np.sin(2 * np.pi * i / n)) for i in range(n)]
        ring.append(ring[0])
        if rng.random() < 0.2:
            ring = [(0.0 if abs(x) < 1 else x, y) for x, y in ring] + [(-0.0, 5.0), (0.0, 6.0)]
        lines.append(f"G0 X{ring[0][0]:.4f} Y{ring[0][1]:.4f}\n")
        zc = int(round(z * 100))
        hit = rng.random() < 0.7                # (else no point of this layer: the window may load one half a layer above)
        for (x0, y0), (x1, y1) in zip(ring, ring[1:]):
            kind = rng.random()
            if kind < 0.05:
                lines.append("G1 F1800\n")                      # a null move
            elif kind < 0.1:
                lines.append(f"G1 X{x0 + 0.03:.4f} Y{y0:.4f} E{e + 0.0001:.5f}\n")   # a tiny piece
                e += 0.0001
                lines.append(f"G1 X{x0:.4f} Y{y0:.4f}\n")
            elif kind < 0.13:
                lines.append(";TYPE:Perimeter\n")               # not the outer wall
            e += 0.05
            lines.append(f"G1 X{x1:.4f} Y{y1:.4f} E{e:.5f}\n")
            if kind >= 0.1 and kind < 0.13:
                lines.append(";TYPE:External perimeter\n")
            for _ in range(rng.choice([0, 0, 1, 1, 2, 5]) if hit else 0):
                t = rng.choice([0.0, 1.0, 1.0, 1.003, 0.5, rng.random(), -0.002])
                x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
                jit = rng.choice([0.0, 0.0, 0.02, 0.1])
                pts.setdefault(zc, []).append((x + rng.uniform(-jit, jit), y + rng.uniform(-jit, jit)))
        if zc not in pts and rng.random() < 0.5:
            pts[zc + 15] = [(90.0, 90.0)]       # half a layer height (0.3 mm) above, far from the wall
        lines.append(";TYPE:Solid infill\nG1 X5 Y5 E%.5f\n" % (e + 0.1))
        e += 0.1
    if rng.random() < 0.5:
        pts[int(round((0.2 + 0.2 * layers + 3) * 100))] = [(10.0, 10.0)]   # above the print
    layer_list = sorted((z / 100, [p for p in ps if p[0] >= 0 and p[1] >= 0]) for z, ps in pts.items())
    layer_list = [(z, ps[:64]) for z, ps in layer_list if ps]      # (a map layer holds 64 at most)
    weights = [[rng.randint(1, 255) for _ in ps] for _, ps in layer_list]
    bm = mapformat.decode_map(mapformat.encode_map(layer_list, weights=weights))
    return "".join(lines).encode(), bm


def test_random_walls_give_the_same_stops(monkeypatch):
    rng = random.Random(26)
    stops = merged = 0
    flushed = []                              # the Python runs' deferred points, when flushed
    flush = RefPlanner._flush
    monkeypatch.setattr(RefPlanner, "_flush", lambda p, *a: (flushed.append(len(p.deferred)), flush(p, *a))[1])
    for trial in range(40):
        data, bm = _wall_file(rng)
        settings = Settings(mode=rng.choice([0, 1, 1, 2]), dwell_ms=rng.choice([100, 900, 2000]),
                            extra_e=rng.choice([0.1, 0.6, 1.0]), tolerance=rng.choice([0.01, 0.05, 0.3]))
        got = _compare(data, bm, settings, monkeypatch, bypass=rng.random() < 0.5,
                       chunk=rng.choice([None, 700]))
        stops += len(got.stops)
        merged += sum(1 for a, b in zip(got.stops, got.stops[1:]) if (a.line_no, a.x, a.y) == (b.line_no, b.x, b.y))
    assert stops > 500 and merged > 20 and sum(flushed) > 20


def test_points_at_the_tolerance_to_the_bit(monkeypatch):
    """A quantum of 0.25 mm and a wall along the axes make every float32 step exact: a point
    exactly the tolerance from the wall is stopped at (<=), one a quantum further is not. A
    perturbation of the foot's arithmetic by one part in ten million moves the first out."""
    square = [(10, 10), (20, 10), (20, 20), (10, 20), (10, 10)]
    data = "G21\nG90\nM82\nG92 E0\nG1 Z0.20\n;TYPE:External perimeter\nG0 X10 Y10\n"
    data += "".join(f"G1 X{x} Y{y} E{k + 1}\n" for k, (x, y) in enumerate(square[1:]))
    near = [(15.0, 10.25), (20.25, 15.0), (12.5, 19.75), (9.75, 17.5)]
    far = [(15.0, 10.5), (20.5, 12.0), (14.0, 20.5), (9.5, 12.5)]
    bm = mapformat.decode_map(mapformat.encode_map([(0.2, near + far)], quantum_um=250))
    got = _compare(data.encode(), bm, Settings(tolerance=0.25), monkeypatch)
    assert sorted(s.point for s in got.stops) == sorted((round(x * 4), round(y * 4)) for x, y in near)


def test_a_map_out_of_order_or_a_used_planner_is_planned_in_python(monkeypatch):
    """The compiled twin is made for a fresh planner of a map in strictly ascending z only; the
    Python planner takes the others, with the same stops."""
    rng = random.Random(7)
    data, bm = _wall_file(rng, layers=4)
    s = Settings()
    assert fallback._native(RefPlanner(bm, s), fallback.Skipper(RefPlanner(bm, s))) is not None
    swapped = mapformat.BulgeMap(bm.quantum_um, bm.layer_height_cmm, bm.has_weights, bm.layers[::-1])
    assert fallback._native(RefPlanner(swapped, s), fallback.Skipper(RefPlanner(swapped, s))) is None
    used = RefPlanner(bm, s)
    movescan.run(data, lambda ch: plan_records(used, ch, arcs_bypass=True, lazy=True))
    assert used.stops and fallback._native(used, fallback.Skipper(used)) is None
    _compare(data, swapped, s, monkeypatch)


def test_bad_buffers_are_refused_by_name():
    c = fallback._compiled_reach()
    i8, f8 = np.zeros(0, np.int64), np.zeros(0, np.float64)
    offs = tuple(range(0, 72, 8))
    args = [np.array([30, 20], np.int64), np.array([0, 0, 0], np.int64), i8, i8, i8, 50, 30, 1, 100, 0.1,
            0.15, offs, 88, i8, i8, f8, f8, 0.2, True]
    with pytest.raises(ValueError, match="strictly ascending"):
        c.new(*args)
    args[0] = np.array([20, 30], np.int32)
    with pytest.raises(ValueError, match="zs must be int64"):
        c.new(*args)
    args[0] = np.array([20, 30], np.int64)
    st = c.new(*args)
    with pytest.raises(ValueError, match="whole records"):
        c.run(st, np.zeros(100, np.uint8), np.zeros(1, np.uint8), False)


def _picked(gcode, bm, settings, compiled: bool, monkeypatch, bypass: bool, chunk=None):
    """The rows a planner handed every planned move plans (as the stock rewrite's), per chunk,
    and the planner."""
    rows = []
    p = RefPlanner(bm, settings)
    _scanned(gcode, lambda ch: plan_records(
        p, ch, on_chunk=lambda a, done, planned: rows.append(sorted(done + i for i in planned)),
        arcs_bypass=bypass), compiled, monkeypatch, chunk)
    return rows, p


def test_the_compiled_picking_picks_the_rows_the_skipper_does(monkeypatch):
    """_reach.pick (Skipper.select with the first moving move after each picked one, and the one
    owed across chunks) on the test files and random walls: the same rows, the same stops."""
    rng = random.Random("pick")
    cases = []
    for path in FILES:
        geometric = path.name.startswith("slic3r")
        cases.append((path, _random_map(path, rng, geometric), Settings(mode=2 if geometric else 1)))
    for _ in range(15):
        data, bm = _wall_file(rng)
        cases.append((data, bm, Settings(mode=rng.choice([0, 1, 2]), tolerance=rng.choice([0.05, 0.3]))))
    picked = 0
    for gcode, bm, settings in cases:
        for bypass in (False, True):
            chunk = rng.choice([None, 700, 4096])
            assert fallback._native(RefPlanner(bm, settings), fallback.Skipper(RefPlanner(bm, settings)),
                                    fresh=False) is not None
            got, p = _picked(gcode, bm, settings, True, monkeypatch, bypass, chunk)
            ref, q = _picked(gcode, bm, settings, False, monkeypatch, bypass, chunk)
            assert got == ref
            _same(p, q)
            picked += sum(map(len, got))
    assert picked > 1000
