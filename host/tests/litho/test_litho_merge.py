"""bulgekit litho: how neighbouring pieces merge (issue 24, clean paths). A merged piece strays no
more than CHORD_TOL from the points it replaces, its width and its area per sample stay within
WIDTH_TOL of every piece it replaces, so each sample gets the volume it got before; plain areas
merge into long pieces; the move text is what Python's repr of the rounded numbers gives."""
from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from PIL import Image

from bulgekit import litho as lt
from bulgekit.litho import gcode, paths


def photo(tmp_path, w=60, h=20, seed=3):
    """Photo-like: shading, a plain patch (one grey), and noise elsewhere."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, w)[None, :] * np.linspace(0.4, 1, h)[:, None]
    a = np.clip(255 * (0.15 + 0.7 * x) + rng.normal(0, 12, (h, w)), 0, 255)
    a[:, : w // 4] = 150                                     # a plain area
    p = tmp_path / "photo.png"
    Image.fromarray(a.astype(np.uint8)).save(p)
    return p


def plan(p, monkeypatch=None, merge=True, **kw):
    o = lt.LithoOptions(**{**dict(width=24.0, height=4.0, foot=0.0), **kw})
    if not merge:                                   # every sample's piece on its own
        alone = lambda pts, area, laid, u: (np.ones(len(pts), bool), pts)
        monkeypatch.setattr(paths, "_keep_straight", alone)
    try:
        return lt.plan_lithophane(p, o)
    finally:
        if monkeypatch is not None:
            monkeypatch.undo()


@pytest.mark.parametrize("shape", ["planar", "cylinder"])
def test_merge_keeps_each_samples_volume(tmp_path, monkeypatch, shape):
    """At --block-rate 0 (only these merges and the 6-step rule): every sample interval gets the
    volume it gets with no merging, within 0.5 % of the body there, and the merge takes moves off."""
    p = photo(tmp_path)
    kw = dict(block_rate=0, shape=shape, diameter=30.0)
    merged, single = plan(p, **kw), plan(p, monkeypatch, merge=False, **kw)
    count = lambda pl: sum(int((s.e > 0).sum()) for L in pl.layers for s in L.sections)
    assert count(merged) < 0.8 * count(single)
    worst = 0.0
    for k in range(1, len(merged.layers)):                   # the first layer runs slower only
        a, body = lt.laid_area(merged, k)
        b, _ = lt.laid_area(single, k)
        worst = max(worst, float(np.max(np.abs(a - b) / body)))
    assert 0 < worst <= 0.005


def test_a_plain_area_is_few_pieces(tmp_path):
    """One grey: every line runs straight at one width, so a layer is a handful of moves."""
    a = np.full((10, 50), 120, np.uint8)
    p = tmp_path / "plain.png"
    Image.fromarray(a).save(p)
    pl = plan(p, block_rate=0)
    n = len(pl.field.s)
    for L in pl.layers[1:]:
        laid = [int((s.e > 0).sum()) for s in L.sections]
        assert sum(laid) <= 8 < n, laid                       # loop: 2 long sides + 2 ends; mid-line: 1


def recorded(monkeypatch, p, **kw):
    """Every _keep_straight call of a plan: its input and what it kept."""
    calls = []
    real = paths._keep_straight

    def spy(pts, area, laid, u):
        keep, out = real(pts, area, laid, u)
        calls.append((pts.copy(), area.copy(), laid.copy(), u.copy(), keep.copy(), out.copy()))
        return keep, out

    monkeypatch.setattr(paths, "_keep_straight", spy)
    plan(p, **kw)
    monkeypatch.undo()
    return calls


@pytest.mark.parametrize("shape", ["planar", "cylinder"])
def test_merged_pieces_stay_within_the_tolerances(tmp_path, monkeypatch, shape):
    """Each merged piece passes within CHORD_TOL of every point it replaces (its ends may lie off
    the points, the path's own ends do not), and its width (area / length) and area per sample
    interval are within WIDTH_TOL of each replaced piece's; a piece left alone beside a moved end
    keeps its width within WIDTH_TOL too."""
    calls = recorded(monkeypatch, photo(tmp_path), shape=shape, diameter=30.0)
    moved = dropped = 0
    for pts, area, laid, u, keep, out in calls:
        k = np.flatnonzero(keep)
        assert k[0] == 0 and k[-1] == len(pts) - 1
        assert np.array_equal(out[[0, -1]], pts[[0, -1]])
        moved += int((np.linalg.norm(out[k] - pts[k], axis=1) > 1e-9).sum())
        assert np.all(np.linalg.norm(out[k] - pts[k], axis=1) <= lt.CHORD_TOL + 1e-9)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        du = np.abs(np.diff(u))
        for a, b in zip(k[:-1], k[1:]):
            if b - a < 2:                                     # alone: its width as it was
                if laid[a]:
                    w = area[a] / np.linalg.norm(out[b] - out[a])
                    assert abs(w / (area[a] / seg[a]) - 1) <= lt.WIDTH_TOL + 1e-9
                continue
            dropped += b - a - 1
            piece = shapely.LineString(out[[a, b]])
            d = shapely.distance(shapely.points(pts[a + 1:b]), piece)
            assert d.max() <= lt.CHORD_TOL + 1e-9, (a, b, d.max())
            assert len(set(laid[a:b].tolist())) == 1          # laid or not, never both
            if laid[a]:
                A = area[a:b].sum()
                w = A / np.linalg.norm(out[b] - out[a])
                assert np.all(np.abs(w / (area[a:b] / seg[a:b]) - 1) <= lt.WIDTH_TOL + 1e-9)
                per_sample = A / du[a:b].sum()
                assert np.all(np.abs(per_sample / (area[a:b] / du[a:b]) - 1) <= lt.WIDTH_TOL + 1e-9)
    assert dropped > 0 and moved > 0                           # the test saw merges, and free ends


def test_width_runs_are_not_split_at_a_bin_edge():
    """Widths 0.4 and 0.4 x 1.0001 merge wherever they lie (a fixed log bin split them when they
    straddled its edge); 0.4 and 0.41 do not."""
    seg = np.full(6, 0.4)
    du = np.ones(6)
    laid = np.ones(6, bool)
    for w0 in (0.4, 0.4 * (1 + lt.WIDTH_TOL) ** 7, 0.3):     # anywhere on the scale
        area = np.array([w0, w0, w0 * 1.0001, w0 * 1.0001, w0, w0]) * seg
        assert paths._width_runs(seg, area, laid, du).tolist() == [0, 6]
        area = np.array([w0, w0, w0, w0 * 1.025, w0 * 1.025, w0 * 1.025]) * seg
        assert paths._width_runs(seg, area, laid, du).tolist() == [0, 3, 6]


def test_move_text_is_the_rounded_numbers_repr():
    """_word_chars writes what f"{letter}{value!r}" writes for a value rounded to nd decimals (no
    exponent: small values in full, zero as "0")."""
    rng = np.random.default_rng(5)
    for nd in (1, 3, 4, 5):
        odd = [0.0, -0.0, 1.0, -1.0, 10.0, 0.5, 1e-5, -1e-5, 99.999, 1234.5]
        a = np.round(np.concatenate([rng.normal(0, 80, 3000), rng.normal(0, 2e-4, 500), odd]), nd) + 0.0
        chars, mask = gcode._word_chars("X", a, nd)
        got = [bytes(c[m]).decode() for c, m in zip(chars, mask)]
        want = []
        for v in a.tolist():
            r = repr(v)
            if v == 0:
                r = "0"
            elif "e" in r:
                r = f"{v:.{nd}f}".rstrip("0")
            want.append(" X" + r)
        assert got == want
    on = np.array([True, False])
    texts = gcode._move_texts(np.array([1.5, 2.0]), np.array([-3.25, 4.0]), ("E", np.array([0.0123, 0.0]), 5),
                           np.array([2400.0, 2400.0]), on, on, [1, 1])
    assert texts == ["G1 X1.5 Y-3.25 E0.0123 F2400.0", "G1 X2.0 Y4.0"]
