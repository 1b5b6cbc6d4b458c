"""The invariants tools/fuzz/fuzz_planner.cpp checks on the firmware core, on
the host's mirror of it (RefPlanner), over random maps and move streams: the
host-side half of issue 14's property test (the two are compared action for
action in test_e2e_bkcore.py)."""
import math
import random

import numpy as np
import pytest

from bulgekit.bulge import mapformat
from bulgekit.bulge.fallback import MIN_PIECE_MM, RefPlanner, Settings
from bulgekit.gcode import Move
from planner_streams import random_stream

f32 = np.float32


def stream(seed):
    """The differential test's stream of this seed (planner_streams), with what
    only the host side can vary as well: mode 1 or 2, the outer-wall marker per
    move, and moves that do not move (E only, or nothing)."""
    layers, settings, moves, lh = random_stream(random.Random(seed))
    rng = random.Random(-1 - seed)
    settings = Settings(rng.choice([1, 2, 2]), settings.dwell_ms, settings.extra_e, settings.tolerance)
    out = []
    for x1, y1, z1, e in moves:
        if out and rng.random() < 0.1:  # stand still: E only or nothing
            px, py, pz = out[-1][:3]
            out.append((px, py, pz, rng.choice([0.0, 0.2]), rng.random() < 0.7))
        out.append((x1, y1, z1, e, rng.random() < 0.7))
    return layers, settings, out, lh


@pytest.mark.parametrize("seed", range(int(__import__("os").environ.get("BK_PROP_SEEDS", "150"))))
def test_reference_planner_invariants(seed):
    layers, settings, moves, lh = stream(seed)
    data = mapformat.encode_map(layers, quantum_um=100, layer_height_mm=lh)
    bm = mapformat.decode_map(data)
    ref = RefPlanner(bm, settings)
    q = bm.quantum_um / 1000
    pts = [(l.z_cmm / 100, x * q, y * q) for l in bm.layers for x, y in l.points]
    bound = math.hypot(settings.tolerance, MIN_PIECE_MM) + 2e-3
    x = y = 0.0
    z = moves[0][2]
    prev_qualified = False
    must = set()  # (layer z cmm, point) a qualifying move passed well within T of
    for k, (x1, y1, z1, e, outer) in enumerate(moves):
        m = Move(k, k + 1, x, y, z, x1, y1, z1, e, 0.0, 1800.0, True, None)
        qualifies = ((settings.mode == 2 or (settings.mode == 1 and outer)) and f32(e) > 0
                     and (f32(x) != f32(x1) or f32(y) != f32(y1)))
        applied0, fired0 = ref.stats.extra_applied, ref.stats.points_fired
        acts = ref.plan(m, outer)
        lines = [a for a in acts if a.kind == "line"]
        assert lines, acts
        # the last piece ends where the host said, exactly (in float32)
        last = lines[-1]
        assert (f32(last.x), f32(last.y), f32(last.z)) == (f32(x1), f32(y1), f32(z1))
        # pieces on the segment, in order
        dx, dy = x1 - x, y1 - y
        l2 = dx * dx + dy * dy
        t_prev = -1.0
        hx, hy, hz = x, y, z
        for a in acts:
            if a.kind == "dwell":
                # the layer of the move's end z (a stop at its start may take
                # a point of the layer it climbs to), or of where the head is
                near = min((math.hypot(px - hx, py - hy) for pz, px, py in pts
                            if min(abs(pz - hz), abs(pz - z1)) <= lh + 1e-3), default=math.inf)
                assert near <= bound, (seed, k, a, near)
                continue
            t = ((a.x - x) * dx + (a.y - y) * dy) / l2 if l2 else 0.0
            t = min(max(t, 0.0), 1.0)
            assert math.hypot(x + t * dx - a.x, y + t * dy - a.y) <= 1e-3
            assert t >= t_prev - 1e-4
            t_prev = t
            hx, hy, hz = a.x, a.y, a.z
        # filament: the host's plus the extra the planner says it added
        added = ref.stats.extra_applied - applied0
        assert sum(a.e for a in lines) == pytest.approx(e + added, abs=1e-4 * (1 + abs(e) + added))
        if not qualifies:
            # the move itself, after stops deferred from the wall move before it
            assert len(lines) == 1
            assert all(a.kind == "line" for a in acts) or prev_qualified
        assert ref.stats.points_fired <= len(pts)
        # Reached => stopped: a qualifying move at a layer's own z (no other
        # layer as near, and not one released because printing went above it)
        # passing a point of it with a margin (0.02 mm inside T, its foot away
        # from the ends, where the corner rule and the minimum piece decide)
        # makes it stop, on this move or an earlier one.
        zc = round(z1 * 100)
        lay = [l for l in bm.layers if l.z_cmm == zc]
        released = ref.floor is not None and zc < ref.floor  # printing went up past it
        if qualifies and lay and z == z1 and l2 > 0.25 and not released:
            others = [abs(l.z_cmm - zc) for l in bm.layers if l.z_cmm != zc]
            if not others or min(others) * 2 > bm.layer_height_cmm:
                for px, py in lay[0].points:
                    t = ((px * q - x) * dx + (py * q - y) * dy) / l2
                    d = math.hypot(x + t * dx - px * q, y + t * dy - py * q)
                    if 0.1 < t < 0.9 and d <= settings.tolerance - 0.02:
                        must.add((zc, (px, py)))
        if not (x == x1 and y == y1 and z == z1 and e == 0):
            prev_qualified = qualifies
        x, y, z = x1, y1, z1
    fired = {(st.layer_z_cmm, st.point) for st in ref.stops}
    assert must <= fired, sorted(must - fired)
