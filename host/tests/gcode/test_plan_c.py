"""The compiled planner passes (bulgekit/gcode/_plan.c) give the numbers of their pure-Python
fallback (estimate._plan_segment_np, _junctions and the limits in _Planner.add, _drop_tiny) to the
bit: on the test files under several machines, on odd lines, and on random blocks and moves (zero
and tiny junction speeds, look-ahead windows of every size, lone blocks, chains of dropped moves)."""
from __future__ import annotations


import numpy as np
import pytest

from bulgekit.gcode import estimate as es

from test_estimate_unchanged import FILES, odd_gcode


@pytest.fixture(autouse=True)
def _built():
    assert es._plan is not None, "the compiled planner is not built: cd host && python3 setup.py build_ext --inplace"

MACHINES = [es.Machine(), es.Machine(lookahead=None), es.Machine(lookahead=3), es.Machine(lookahead=80),
            es.Machine(min_segment_steps=0, jd_small_segments=False),
            es.Machine(honour_file_limits=True, junction_deviation=0.05, min_planner_speed=0.0)]


def _blocks(path, m, monkeypatch, compiled: bool):
    with monkeypatch.context() as mp:
        if not compiled:
            mp.setattr(es, "_plan", None)
        mp.setattr(es, "CHUNK", 256)                    # long runs planned in windows, too
        return es.estimate_file(path, m)


@pytest.mark.parametrize("path", FILES + ["odd"], ids=lambda p: getattr(p, "name", p))
def test_compiled_planner_gives_the_fallbacks_blocks(path, tmp_path, monkeypatch):
    if path == "odd":
        path = tmp_path / "odd.gcode"
        path.write_text(odd_gcode(seed=7), encoding="utf-8")
    for m in MACHINES:
        a = _blocks(path, m, monkeypatch, compiled=False)
        b = _blocks(path, m, monkeypatch, compiled=True)
        assert (a.total_s, a.by_feature, a.filament) == (b.total_s, b.by_feature, b.filament)
        for k in a.blocks.dtype.names:
            assert np.array_equal(a.blocks[k], b.blocks[k]), k


@pytest.mark.parametrize("seed", range(4))
def test_segment_on_random_blocks(seed):
    from bulgekit.gcode import _plan
    r = np.random.default_rng(seed)
    for n in (1, 2, 3, 17, 500):
        a = r.choice([500.0, 1000.0, 3000.0], n)
        L = np.where(r.random(n) < 0.3, r.uniform(0.001, 0.05, n), r.uniform(0.05, 40, n))
        vn = r.uniform(1, 300, n)
        me2 = np.where(r.random(n) < 0.2, 0.0, r.uniform(0, 300, n) ** 2)
        for la in (None, 1, 2, 3, 5, 16, 66, n + 2):
            m = es.Machine(lookahead=la, min_planner_speed=r.choice([0.0, 0.05]))
            want = es._plan_segment_np(a, L, vn, me2, m)
            lo, hi = (0, n) if n < 3 else (1, n - 1)           # a window inside the arrays
            if lo:
                want = es._plan_segment_np(a[lo:hi], L[lo:hi], vn[lo:hi], me2[lo:hi], m)
            W = -1 if la is None or la - 2 >= hi - lo else max(1, la - 2)
            got = [np.full(n, np.nan) for _ in range(7)]
            _plan.segment(a, L, vn, me2, m.min_planner_speed ** 2, W, lo, hi, lo, hi, *got)
            t = want[3] + want[4] + want[5]
            assert np.array_equal(got[0][lo:hi], t)
            for g, w in zip(got[1:], want):
                assert np.array_equal(g[lo:hi], w)
            assert np.isnan(got[0][:lo]).all() and np.isnan(got[0][hi:]).all()    # nothing else written


def test_blocks_on_random_moves():
    """_plan.blocks against the fallback's limits and junctions, with the axis limits given per
    block, as one broadcast row, and moves of E alone, travel and reversals among them."""
    from bulgekit.gcode import _plan
    r = np.random.default_rng(26)
    n = 3000
    d = r.uniform(-5, 5, (n, 4)) * (r.random((n, 4)) < 0.8)
    d[r.random(n) < 0.1, :3] = 0.0                          # E alone
    d[np.all(d == 0, axis=1), 3] = 0.3
    d[1::7] = -d[0::7][:len(d[1::7])]                        # reversals
    small = r.random(n) < 0.3
    d[small] *= 0.05
    v = r.uniform(5, 400, n)
    accel = r.choice([800.0, 3000.0], n)
    jd = np.full(n, 0.02)
    per_block = np.column_stack([r.uniform(50, 5000, n) for _ in range(4)])
    marlin = np.array([3000.0, 3000, 100, 10000]), np.array([300.0, 300, 5, 25])
    for amax, vmax in ((per_block, per_block / 10), marlin):
        rows = np.broadcast_to(amax, (n, 4)), np.broadcast_to(vmax, (n, 4))
        for segs in (True, False):
            m = es.Machine(jd_small_segments=segs)
            # the fallback: add's numpy path on the whole array
            xyz = es._norm(d[:, 0], d[:, 1], d[:, 2])
            L = np.where(xyz > 0, xyz, np.abs(d[:, 3]))
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = [np.abs(d[:, i]) / L for i in range(4)]
                vlim = es._row_min(*(np.where(q > 0, rows[1][:, i] / q, np.inf) for i, q in enumerate(ratio)))
                alim = es._row_min(*(np.where(q > 0, rows[0][:, i] / q, np.inf) for i, q in enumerate(ratio)))
            vn = np.minimum(v, vlim)
            acc = np.where(xyz > 0, np.minimum(accel, alim), accel)
            me2 = es._junctions(d, L, vn, acc, jd, None, rows[0], m)
            # compiled, in two parts (the second continuing from the first's last block)
            prev = np.zeros(6)
            got = [np.empty(n) for _ in range(4)]
            for s in (slice(0, 1234), slice(1234, n)):
                out = [np.empty(s.stop - s.start) for _ in range(4)]
                _plan.blocks(d[s, 0], d[s, 1], d[s, 2], d[s, 3], v[s], accel[s], jd[s],
                             amax if amax.ndim == 1 else amax[s], vmax if vmax.ndim == 1 else vmax[s],
                             prev, segs, m.min_planner_speed ** 2, *out)
                for g, o in zip(got, out):
                    g[s] = o
            for g, w in zip(got, (L, vn, acc, me2)):
                assert np.array_equal(g, w)


@pytest.mark.parametrize("seed", range(6))
def test_moves_on_random_tiny_moves(seed):
    """_plan.moves against the fallback (_drop_tiny): chains of dropped moves, a distance carried
    in and out, G92s resetting the E steps, moves of E alone, signed zeros."""
    from bulgekit.gcode import _plan
    r = np.random.default_rng(seed)
    k = 4000
    step = np.where(r.random((k, 1)) < 0.5, 0.01, 2.0) * r.uniform(-1, 1, (k, 4))
    step[r.random(k) < 0.2, :3] = 0.0                        # E alone (or nothing)
    step[r.random(k) < 0.1] = 0.0                            # a lone F word
    step[r.random(k) < 0.02, 0] = -0.0
    p1 = np.cumsum(np.vstack([[50.0, 50.0, 0.2, 0.0], step]), axis=0)
    x0, y0, z0 = (np.ascontiguousarray(p1[:-1, i]) for i in range(3))
    x1, y1, z1 = (np.ascontiguousarray(p1[1:, i]) for i in range(3))
    de = np.ascontiguousarray(step[:, 3])
    m = es.Machine()
    p = es._Parser(m, "<test>")
    se = p.spm["E"]
    e_to = es._lround_array(p1[1:, 3] * se)
    e_prev = np.concatenate([[int(r.integers(-5, 5))], e_to[:-1]])
    reset = r.random(k) < 0.01
    e_prev[reset] = r.integers(-50, 50, int(reset.sum()))
    for pending in ([0.0, 0.0, 0.0, 0.0], [0.01, -0.02, 0.0, 0.001]):
        p.pending = list(pending)
        want = es._drop_tiny(p, k, x0, y0, z0, x1, y1, z1, de, e_to, e_prev, reset)
        want_pending = p.pending
        D, ne, emitted = np.empty((k, 4)), np.empty(k), np.empty(k, bool)
        pend = np.array(pending, float)
        _plan.moves(x0, y0, z0, x1, y1, z1, de, e_to, e_prev, reset, np.array([p.spm[a] for a in "XYZE"], float),
                    float(m.min_segment_steps), pend, D, ne, emitted)
        assert (~emitted).sum() > 100                        # chains were taken
        assert np.array_equal(emitted, want[2]) and np.array_equal(ne[emitted], want[1][emitted])
        assert np.array_equal(D.view(np.int64), want[0].view(np.int64))      # the bits, signed zeros too
        assert pend.tolist() == want_pending


def test_a_planner_built_from_an_older_source_is_not_used(monkeypatch):
    """A compiled planner without this code's VERSION is said once (RuntimeWarning naming the
    rebuild) and left alone: numpy plans, to the same bits."""
    import sys
    import types
    from bulgekit.gcode import estimate as E
    assert E._compiled_planner() is not None and E._compiled_planner().VERSION == E.PLAN_VERSION
    stale = types.ModuleType("bulgekit.gcode._plan")
    monkeypatch.setitem(sys.modules, "bulgekit.gcode._plan", stale)
    import bulgekit.gcode as g
    monkeypatch.setattr(g, "_plan", stale, raising=False)
    monkeypatch.setattr(g, "_STALE_SAID", set())
    with pytest.warns(RuntimeWarning, match="older source.*build_ext"):
        assert E._compiled_planner() is None
    stale.VERSION = E.PLAN_VERSION
    assert E._compiled_planner() is stale
