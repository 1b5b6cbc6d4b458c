"""bulgekit litho: geometry (walls follow the picture, one centred mid-line as wide as the gap,
nothing outside the body), eq. 2 in the stock file, width mode in the litho file, the cylinder's
seam, the STL, and the CLI's errors. Pictures are drawn here, small, so the tests stay fast."""
from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from bulgekit import litho as lt
from bulgekit import outputs
from bulgekit.litho import paths, thickness
from bulgekit.cli import main
from bulgekit.cli.litho import summary

W, H = 0.4, 0.2


def picture(tmp_path, name="p.png", w=40, h=16, fill=255, boxes=()):
    """A grey picture with rectangles (x0, y0, x1, y1, grey) drawn in."""
    a = np.full((h, w), fill, np.uint8)
    for x0, y0, x1, y1, g in boxes:
        a[y0:y1, x0:x1] = g
    p = tmp_path / name
    Image.fromarray(a).save(p)
    return p


def opts(**kw):
    # the plate alone (feet: test_foot_*), the whole picture stretched onto it (as before issue 37;
    # the aspect rule: test_litho_shapes.py)
    base = dict(width=20.0, height=3.0, pitch=0.4, foot=0.0, stretch=True)
    base.update(kw)
    return lt.LithoOptions(**base)


def moves(path):
    """(x, y, e, f) per G1 with X/Y in a file (relative E, F carried), and the current ;TYPE:."""
    out, f, kind = [], None, None
    for line in open(path):
        if line.startswith(";TYPE:"):
            kind = line[6:].strip()
        if not line.startswith("G1 ") or " X" not in line:
            continue
        w = dict((m[0], float(m[1:])) for m in line.split(";")[0].split()[1:])
        f = w.get("F", f)
        out.append((w["X"], w["Y"], w.get("E", 0.0), f, w.get("W"), kind))
    return out


# --- the thickness field ---------------------------------------------------------------------

def test_dark_is_thick_and_limits_hold(tmp_path):
    p = picture(tmp_path, boxes=[(0, 0, 20, 16, 0)])            # left half black, right white
    f = lt.thickness_field(p, opts())
    assert f.t.shape == (15, 51)                                # 3 mm / 0.2; 20 mm / 0.4 + 1
    assert f.t[:, 5] == pytest.approx(2.4)
    assert f.t[:, -5] == pytest.approx(0.8)
    inv = lt.thickness_field(p, opts(invert=True))
    assert inv.t[:, 5] == pytest.approx(0.8) and inv.t[:, -5] == pytest.approx(2.4)


def test_transmission_curve_is_linear_in_luminance(tmp_path):
    from skimage.color import rgb2xyz

    greys = [0, 64, 128, 192, 255]
    p = picture(tmp_path, w=50, h=10, boxes=[(10 * i, 0, 10 * i + 10, 10, g) for i, g in enumerate(greys)])
    o = opts(width=50.0, height=2.0, curve="transmission", attenuation=1.5, min_line=0.01)
    f = lt.thickness_field(p, o)
    t = np.array([f.t[3, int(round((10 * i + 5) / 0.4))] for i in range(5)])
    T = np.exp(-1.5 * t)
    b = rgb2xyz(np.repeat(np.array(greys, float)[None, :, None] / 255, 3, axis=2))[0, :, 1]   # sRGB -> Y
    T_lo, T_hi = math.exp(-1.5 * 2.4), math.exp(-1.5 * 0.8)
    assert T == pytest.approx(T_lo + b * (T_hi - T_lo), rel=1e-6)


def test_narrow_gaps_are_shared_by_the_walls(tmp_path):
    # --light-gaps walls. Default narrowest line: what 8 mm^3/s lays at 150 mm/s, 8 / (150 x 0.2)
    # = 0.267 mm. darkness 0.05 -> t = 0.88 (gap 0.08), 0.1 -> t = 0.96 (gap 0.16): no mid-line
    # there, the two walls widen by half the gap each and run slower at the walls' rate
    p = picture(tmp_path, w=30, h=10, boxes=[(0, 0, 10, 10, round(255 * 0.95)), (10, 0, 20, 10, round(255 * 0.9))])
    o = opts(width=30.0, height=2.0, curve="linear", light_gaps="walls")
    assert o.line_min() == pytest.approx(8 / (150 * 0.2))
    f = lt.thickness_field(p, o)
    assert f.t[2, 10] == pytest.approx(0.8 + 1.6 * (1 - round(255 * 0.95) / 255))    # not snapped
    assert f.t[2, 40] == pytest.approx(0.8 + 1.6 * (1 - round(255 * 0.9) / 255))
    assert f.shared > 0
    plan = lt.plan_lithophane(p, o)
    L = plan.layers[2]
    for i in (10, 40):
        assert L.wall[i] == pytest.approx(W + (f.t[2, i] - 2 * W) / 2)
        assert L.gap[i] == pytest.approx(0.0, abs=1e-9)
    assert lt.printed_thickness(plan) == pytest.approx(f.t, abs=1e-9)
    loop = L.sections[0]
    x0, x1 = loop.pts[:-1, 0], loop.pts[1:, 0]
    on = (np.minimum(x0, x1) < 2) & (np.maximum(x0, x1) > 2) & (loop.pts[:-1, 1] < 0.3)   # back wall at x = 2
    w_back = np.median(loop.width[on])
    assert w_back == pytest.approx(W + 0.04, rel=0.01)
    assert np.median(loop.v[on]) == pytest.approx(o.wall_flow / (w_back * H), rel=1e-3)
    mids = [s for s in L.sections if s.kind == "mid-line"]
    assert all(s.pts[s.e > 0][:, 0].min() > 7.9 for s in mids)        # laid only right of the 0.96 part
    # the laid volume per sample interval is the body's (the bands add up to it)
    laid, body = lt.laid_area(plan, 2)
    assert laid[2:-2] == pytest.approx(body[2:-2], rel=0.005)


def test_grey_ramp_prints_monotonic_without_jumps(tmp_path):
    """A linear grey ramp, white to black, at the defaults: no sample snapped, the printed
    thickness rises monotonically with no step over 0.02 mm, and the laid volume follows it."""
    a = np.tile(np.arange(255, -1, -1).astype(np.uint8), (12, 1))
    p = tmp_path / "ramp.png"
    Image.fromarray(a).save(p)
    # one sample per tone: 256 samples 0.4 mm apart, each the average of one pixel column
    plan = lt.plan_lithophane(p, lt.LithoOptions(width=255 * 0.4 * 256 / 255, height=2.4, pitch=0.4 * 256 / 255,
                                                foot=0))
    t = lt.printed_thickness(plan)
    assert t == pytest.approx(plan.field.t, abs=1e-9)
    assert plan.field.narrowed > 0 and plan.field.shared == 0      # the light end passes through it
    d = np.diff(t, axis=1)
    assert d.min() >= -1e-9 and d.max() <= 0.02
    for k in (3, 8):
        laid, body = lt.laid_area(plan, k)
        per_mm = laid / np.diff(plan.field.s)
        assert np.all(np.diff(per_mm[3:-3]) > -0.02)               # monotonic within a few hundredths
        assert laid.sum() == pytest.approx(body.sum(), rel=0.005)


def noisy(tmp_path, w=60, h=20, seed=1, sigma=20):
    """A photo-like picture: smooth shading plus noise, every sample a different grey."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, w)[None, :] * np.linspace(0.3, 1, h)[:, None]
    a = np.clip(255 * (0.2 + 0.7 * x) + rng.normal(0, sigma, (h, w)), 0, 255).astype(np.uint8)
    p = tmp_path / "noisy.png"
    Image.fromarray(a).save(p)
    return p


@pytest.fixture(scope="module")
def noisy_made(tmp_path_factory):
    d = tmp_path_factory.mktemp("noisy")
    return lt.make(noisy(d), d / "out", options=lt.LithoOptions(width=24.0, height=4.0), name="noisy")


def shortest_extruding_moves(path):
    prev, short = None, []
    for x, y, e, f, w_, kind in moves(path):
        if prev is not None and (e > 0 or w_):
            L = math.hypot(x - prev[0], y - prev[1])
            if L < 0.075:
                short.append((L, kind))
        prev = (x, y)
    return short


def test_no_extruding_move_shorter_than_the_firmware_runs(noisy_made):
    """6 steps at 80 steps/mm: Marlin drops shorter moves, Klipper plans them; neither file has one,
    and the estimate with every move planned is within 2 % of Marlin's."""
    from bulgekit.gcode import estimate as es

    for key in ("gcode", "stock"):
        ms = moves(noisy_made.paths[key])
        prev = None
        short = []
        for x, y, e, f, w_, kind in ms:
            if prev is not None and (e > 0 or w_):
                L = math.hypot(x - prev[0], y - prev[1])
                if L < 0.075:
                    short.append((L, kind))
            prev = (x, y)
        assert not short, short[:5]
    est = noisy_made.stats["estimate"]
    assert est["estimated_time_s_gcode_every_move_planned"] == pytest.approx(est["estimated_time_s_gcode"], rel=0.02)
    r6 = es.estimate_file(noisy_made.paths["stock"], es.Machine())
    r0 = es.estimate_file(noisy_made.paths["stock"], es.Machine(min_segment_steps=0))
    assert r0.total_s == pytest.approx(r6.total_s, rel=0.02)
    # the JSON's times come from the moves handed over as numbers: the same as parsing the files
    assert est["estimated_time_s_stock"] == pytest.approx(r6.total_s, abs=0.06)
    parsed = es.estimate_file(noisy_made.paths["gcode"], es.Machine(min_segment_steps=0)).total_s
    assert est["estimated_time_s_gcode_every_move_planned"] == pytest.approx(parsed, abs=0.06)
    m = est["machine"]
    assert m["accel_mm_s2"] == 3000 and m["junction_deviation_mm"] == 0.013 and m["lookahead_blocks"] == 16


def test_block_rate_budget(tmp_path):
    """No laid piece is shorter than its speed / block rate (a head only passing through runs no
    faster than that), and merging keeps the volume of every layer."""
    p = noisy(tmp_path)
    plans = {}
    for rate in (200.0, 1000.0):
        plan = plans[rate] = lt.plan_lithophane(p, lt.LithoOptions(width=24.0, height=4.0, block_rate=rate))
        for k, L in enumerate(plan.layers):
            for s in L.sections:
                seg = np.linalg.norm(np.diff(s.pts, axis=0), axis=1)
                laid = s.e > 0
                assert np.all(seg[laid] >= np.maximum(lt.MIN_MOVE, s.v[laid] / rate) - 1e-6), (rate, k, s.kind)
                assert np.all(s.v[~laid] <= seg[~laid] * rate + 1e-6)
            laid_a, body = lt.laid_area(plan, k)
            assert laid_a.sum() == pytest.approx(body.sum(), rel=0.005)
    # without a budget the pieces are shorter, and each sample's volume is the body's
    plan0 = lt.plan_lithophane(p, lt.LithoOptions(width=24.0, height=4.0, block_rate=0))
    n0 = sum(int((s.e > 0).sum()) for L in plan0.layers for s in L.sections)
    n200 = sum(int((s.e > 0).sum()) for L in plans[200.0].layers for s in L.sections)
    assert n200 < n0
    for k in range(1, len(plan0.layers)):
        laid_a, body = lt.laid_area(plan0, k)
        assert laid_a[2:-2] == pytest.approx(body[2:-2], rel=0.005)


def test_merged_pieces_and_the_plain_inner_circle(tmp_path):
    """Pieces that run on straight at one width are one move: a cylinder's inner wall (a plain
    circle) has as few pieces as a 0.01 mm chord tolerance allows, and the whole part has at
    least 40 % fewer extruding moves than one piece per sample per line."""
    a = np.full((16, 120), 255, np.uint8)              # white sky, a dark box, a shaded third
    a[4:12, 10:40] = 40
    a[:, 80:] = np.linspace(150, 20, 40).round().astype(np.uint8)
    p = tmp_path / "scene.png"
    Image.fromarray(a).save(p)
    o = lt.LithoOptions(shape="cylinder", diameter=30.0, height=3.0, light_gaps="walls", stretch=True)
    plan = lt.plan_lithophane(p, o)
    r_in = o.diameter / 2 - o.max_thickness + W / 2
    n = len(plan.field.s)
    per_sample = circles = 0
    for L in plan.layers:
        # the inner wall (its first point may be where the part before it ended: a join)
        inner = [s for s in L.sections if s.kind == "wall" and np.linalg.norm(s.pts[1:], axis=1).max() < r_in + 0.01]
        if inner and np.allclose(L.wall, W):
            chord = 2 * math.sqrt(2 * r_in * lt.CHORD_TOL)           # its sagitta is the tolerance
            assert len(inner[0].e) <= math.ceil(2 * math.pi * r_in / chord * 1.35) + 2
            circles += 1
        per_sample += n * (2 + int(plan.field.lines[0]))
    moves_ = sum(int((s.e > 0).sum()) for L in plan.layers for s in L.sections)
    assert circles == len(plan.layers) and moves_ <= 0.6 * per_sample


def test_frame_is_full_thickness(tmp_path):
    f = lt.thickness_field(picture(tmp_path), opts(frame=1.0))
    assert np.all(f.t[:5] == 2.4) and np.all(f.t[-5:] == 2.4)
    assert np.all(f.t[:, :3] == 2.4) and np.all(f.t[:, -3:] == 2.4)
    assert f.t[7, 25] == pytest.approx(0.8)


# --- planar geometry ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def step_plan(tmp_path_factory):
    """Black left half (2.4 mm), mid-grey right half (1.39 mm by the perceptual curve)."""
    d = tmp_path_factory.mktemp("step")
    p = picture(d, boxes=[(0, 0, 20, 16, 0), (20, 0, 40, 16, 128)])
    return lt.plan_lithophane(p, opts(rate_accel=0))        # the bands as laid out, walls a line wide


def test_walls_follow_the_relief(step_plan):
    loop = step_plan.layers[5].sections[0]
    assert loop.kind == "wall"
    pts = loop.pts
    back = pts[np.abs(pts[:, 1] - W / 2) < 1e-6]
    assert len(back) >= 2                                        # back wall: half a line in
    t = step_plan.field.t[5]
    from shapely.geometry import LineString
    ring = LineString(pts)
    for x0, thick in ((5.0, t[12]), (15.0, t[37])):
        ys = sorted(c.y for c in ring.intersection(LineString([(x0, -1), (x0, 5)])).geoms)
        assert ys == pytest.approx([W / 2, thick - W / 2], abs=1e-6)


def test_one_mid_line_centred_and_as_wide_as_the_gap(step_plan):
    layer = step_plan.layers[5]
    mids = [s for s in layer.sections if s.kind == "mid-line"]
    assert len(mids) == 1
    m = mids[0]
    t = step_plan.field.t[5]
    for x0, thick in ((5.0, t[12]), (15.0, t[37])):
        i = np.flatnonzero((np.minimum(m.pts[:-1, 0], m.pts[1:, 0]) <= x0)
                           & (np.maximum(m.pts[:-1, 0], m.pts[1:, 0]) > x0))[0]
        assert m.pts[i + 1, 1] == pytest.approx(thick / 2, abs=1e-6)   # centre of the plate
        if i == 0:          # it starts from where the loop ended: the same volume over a longer way
            assert m.width[i] == pytest.approx(thick - 2 * W, rel=0.03)
        else:
            assert m.pts[i, 1] == pytest.approx(thick / 2, abs=1e-6)
            assert m.width[i] == pytest.approx(thick - 2 * W, abs=1e-6)
    # the mid-line runs from end wall to end wall (its start joined to the loop's end)
    ends = sorted([m.pts[0, 0], m.pts[-1, 0]])
    assert ends[0] == pytest.approx(W, abs=0.75) and ends[1] == pytest.approx(20.0 - W, abs=1e-6) or \
        ends[0] == pytest.approx(W, abs=1e-6) and ends[1] == pytest.approx(20.0 - W, abs=0.75)


def test_nothing_outside_the_body(step_plan):
    from shapely.geometry import Point

    o, f = step_plan.options, step_plan.field
    for k in (0, 7, 14):
        P = paths._layer_polygon(o, f, k)
        for s in step_plan.layers[k].sections:
            for x, y in s.pts:
                assert P.buffer(1e-6).contains(Point(x, y)), (k, s.kind, x, y)
            # a line's half width stays inside too: walls half a line in across the layer, which
            # on a slope of dt/ds is (W / 2) cos(atan(dt/ds)) from the face (the step's sample
            # between black and grey is their average in linear light: the steepest slope)
            if s.kind == "wall":
                slope = np.abs(np.diff(f.t[k]) / np.diff(f.s)).max()
                d = min(P.exterior.distance(Point(p)) for p in s.pts)
                assert W / 2 / math.hypot(1, slope) - 1e-6 <= d <= W / 2 + 1e-6


def test_head_crosses_merged_walls_in_the_middle(tmp_path):
    """--light-gaps walls. Black, white (walls merge: no mid-line), black: the head crosses the
    white part without laying, along the plate's middle (down the steps' slopes, then straight)."""
    p = picture(tmp_path, boxes=[(0, 0, 10, 16, 0), (30, 0, 40, 16, 0)])
    plan = lt.plan_lithophane(p, opts(light_gaps="walls"))
    m = [s for s in plan.layers[4].sections if s.kind == "mid-line"][0]
    hop = np.flatnonzero(m.e == 0)
    assert np.all(np.diff(hop) == 1) and len(hop) <= 3              # one run of moves across
    long = hop[np.argmax(np.abs(m.pts[hop + 1, 0] - m.pts[hop, 0]))]
    a, b = m.pts[long], m.pts[long + 1]
    assert a[1] == pytest.approx(0.4) and b[1] == pytest.approx(0.4)   # middle of the 0.8 mm plate
    assert abs(b[0] - a[0]) > 9.0


def test_deposited_volume_matches_the_body(step_plan):
    V, F = lt.body_mesh(step_plan)
    stats = lt.plan_stats(step_plan, lt.mesh_volume(V, F))
    assert 0.98 <= stats["fill_ratio"] <= 1.02
    assert stats["mid_line"]["max_lines_per_layer"] == 1


def test_wide_gaps_get_two_mid_lines(tmp_path):
    p = picture(tmp_path, boxes=[(0, 0, 40, 16, 0)])
    plan = lt.plan_lithophane(p, opts(max_thickness=4.0))          # gap 3.2 > 1.6
    mids = [s for s in plan.layers[3].sections if s.kind == "mid-line"]
    assert len(mids) == 2
    assert all(m.width == pytest.approx(1.6, abs=1e-6) for m in mids)   # one straight piece each
    # the back wall at its one width (the mid-line's speed planned), the front wall the rest
    b = lt.back_wall(plan.options)
    assert sorted(m.pts[0, 1] for m in mids) == pytest.approx([b + 0.8, b + 2.4], abs=1e-6)


def test_speed_from_flow_and_cap(step_plan):
    """v = q / (W * H), capped at max_speed (first layer at the first-layer ratio)."""
    o = step_plan.options
    m = [s for s in step_plan.layers[5].sections if s.kind == "mid-line"][0]
    laid = m.e > 0
    v = np.minimum(o.flow / (m.width[laid] * H), o.max_speed)
    assert m.v[laid] == pytest.approx(v, rel=1e-9)


def test_foot_and_frame(tmp_path):
    p = picture(tmp_path, boxes=[(10, 4, 30, 12, 0)])
    res = lt.make(p, tmp_path / "o", options=opts(foot=8.0, foot_height=1.0, frame=1.0))
    plan = res.plan
    assert plan.field.n_foot == 5
    foot_mids = [s for s in plan.layers[2].sections if s.kind == "mid-line"]
    assert len(foot_mids) == 5                                    # 8 - 0.8 = 7.2 mm: five 1.44 mm lines
    assert all(m.width == pytest.approx(1.44, abs=1e-6) for m in foot_mids)
    assert 0.98 <= res.stats["fill_ratio"] <= 1.02
    import trimesh
    m = trimesh.load(res.paths["stl"])
    assert m.is_watertight and m.bounds[1][2] == pytest.approx(4.0)
    assert m.bounds[1][1] - m.bounds[0][1] == pytest.approx(8.0, abs=1e-4)
    # inside the frame: a 1 mm tall window between dark bands, so the scatter costs much here
    assert res.stats["look"]["picture_vs_print"]["mean_abs_dL"] < 15


def stands(stl):
    """(footprint depth across the plate in mm, the angle in degrees the part can lean before its
    centre of mass leaves the footprint) of a watertight STL standing on z = 0."""
    import trimesh
    m = trimesh.load(stl)
    assert m.is_watertight and m.is_winding_consistent and m.is_volume
    base = m.vertices[np.abs(m.vertices[:, 2]) < 1e-6]
    lo, hi = base[:, 1].min(), base[:, 1].max()
    c = m.center_mass
    return hi - lo, math.degrees(math.atan(min(c[1] - lo, hi - c[1]) / c[2]))


def test_foot_by_default_so_the_plate_stands(tmp_path):
    # a 92 mm tall plate 0.8-2.4 mm thick (the case): an eighth of its height, 11.5 mm
    p = picture(tmp_path, w=50, h=46, boxes=[(0, 0, 25, 46, 0), (25, 0, 50, 23, 128)])
    o = lt.LithoOptions(width=100.0, pitch=2.0, layer_height=0.4, line_width=0.8, min_thickness=1.6,
                        max_thickness=2.4)
    assert o.foot is None
    res = lt.make(p, tmp_path / "o", options=o)
    assert res.plan.field.picture_mm[1] == pytest.approx(92.0)
    assert res.plan.options.foot == pytest.approx(11.5) and res.plan.field.n_foot == 8   # 3 mm / 0.4
    depth, lean = stands(res.paths["stl"])                        # what the slicers get
    assert depth == pytest.approx(11.5, abs=1e-3) and lean > 5
    assert json.loads(res.paths["json"].read_text())["options"]["foot"] == pytest.approx(11.5)
    assert "on a foot 11.5 mm deep and 3 mm tall" in summary(res.stats)
    assert 0.98 <= res.stats["fill_ratio"] <= 1.02                # the foot is printed and counted
    off = lt.make(p, tmp_path / "off", options=replace(o, foot=0.0))
    assert off.plan.field.n_foot == 0
    depth, lean = stands(off.paths["stl"])
    assert depth == pytest.approx(2.4, abs=1e-3) and lean < 1.5   # on its edge alone


def test_foot_default_is_at_least_6_mm_and_none_on_a_cylinder(tmp_path):
    p = picture(tmp_path)
    assert lt.thickness_field(p, lt.LithoOptions(width=20.0, height=3.0)).foot == 6.0
    assert lt.thickness_field(p, lt.LithoOptions(width=20.0, height=3.0, max_thickness=7.0)).foot == 7.0
    assert lt.thickness_field(p, lt.LithoOptions(width=20.0, height=3.0, foot=0.0)).n_foot == 0
    cyl = lt.thickness_field(p, lt.LithoOptions(shape="cylinder", diameter=30.0, height=2.0))
    assert cyl.n_foot == 0 and cyl.foot == 0.0


# --- the two G-code files ------------------------------------------------------------------

@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("made")
    p = picture(d, boxes=[(0, 0, 14, 16, 0), (14, 0, 27, 16, 100), (27, 0, 40, 16, 200)])
    return lt.make(p, d / "out", options=opts(), name="steps")


def test_stock_file_keeps_one_extruder_rate_on_the_mid_line(made):
    """Eq. 2: E * v / L is the mid-line rate on every uncapped piece after the first layer."""
    o = made.plan.options
    r = o.flow / o.filament_area
    prev = None
    rates, capped = [], 0
    for x, y, e, f, _, kind in moves(made.paths["stock"]):
        if prev and kind == "mid-line" and e > 0:
            L = math.hypot(x - prev[0], y - prev[1])
            if f / 60 >= o.max_speed - 0.01:
                capped += 1
            else:
                rates.append(e * f / 60 / L)
        prev = (x, y)
    rates = np.array(rates[len(rates) // 15:])                   # skip the first layer's half rate
    assert len(rates) > 30
    assert np.median(rates) == pytest.approx(r, rel=1e-3)
    assert np.mean(np.abs(rates / r - 1) < 0.01) > 0.95            # 5-decimal E, 1-decimal F


def test_litho_file_is_the_stock_motion_in_width_mode(made):
    lit, sto = moves(made.paths["gcode"]), moves(made.paths["stock"])
    assert [(m[0], m[1], m[2]) for m in lit] == [(m[0], m[1], m[2]) for m in sto]
    text = made.paths["gcode"].read_text()
    assert re.search(r"^M723 S1 Q3\.2 D1\.75 H0\.2 L5 U150", text, re.M)
    assert "M723 Q8\n" in text and text.rstrip().count("M723 S0") == 1
    assert "M723" not in made.paths["stock"].read_text()


def test_w_words(tmp_path):
    p = picture(tmp_path, boxes=[(0, 0, 40, 16, 60)])
    res = lt.make(p, tmp_path / "o", options=opts(words="w"))
    ws = [m for m in moves(res.paths["gcode"]) if m[5] == "mid-line" and m[4] is not None]
    assert ws and all(m[2] == 0.0 for m in ws)
    # a mid-line joined from where the loop ended spreads its first piece's volume over the
    # longer way (here one piece across the plate, 19.4 mm instead of 19.2): 1 % narrower
    f = res.plan.field
    assert np.median([m[4] for m in ws]) == pytest.approx(f.t[5, 20] - f.ww[5, 20] - f.wf[5, 20], rel=0.015)


def test_outputs_and_stats(made):
    s = json.loads(made.paths["json"].read_text())
    assert s["layers"] == 15 and s["shape"] == "planar"
    assert 0.98 <= s["fill_ratio"] <= 1.02
    assert s["look"]["picture_vs_print"]["mean_abs_dL"] < 5
    assert made.paths["png"].stat().st_size > 0
    import trimesh
    m = trimesh.load(made.paths["stl"])
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(s["stl_volume_mm3"], rel=1e-4)


def test_start_and_end_gcode_files(tmp_path):
    p = picture(tmp_path)
    (tmp_path / "s.g").write_text("M104 S{temp}\nM140 S{bed_temp}\n; my start\n")
    (tmp_path / "e.g").write_text("; my end\n")
    res = lt.make(p, tmp_path / "o", options=opts(start_gcode=str(tmp_path / "s.g"),
                                                  end_gcode=str(tmp_path / "e.g"), temp=215))
    text = res.paths["gcode"].read_text()
    assert "M104 S215\nM140 S60\n; my start" in text and text.rstrip().endswith("; my end")
    assert ";TYPE:purge" not in text and "G28" not in text


# --- cylinder --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def cyl(tmp_path_factory):
    d = tmp_path_factory.mktemp("cyl")
    # dark stripe at the picture's left edge, light at its right: the seam joins them
    p = picture(d, w=60, h=10, boxes=[(0, 0, 6, 10, 0), (54, 0, 60, 10, 250)])
    return lt.make(p, d / "out", options=lt.LithoOptions(shape="cylinder", diameter=30.0, height=2.0,
                                                         pitch=0.4, stretch=True), name="cyl")


def test_cylinder_layers_are_joined_loops(cyl):
    o = cyl.plan.options
    for L in cyl.plan.layers:
        kinds = [s.kind for s in L.sections]
        assert kinds in (["wall", "mid-line", "wall"],)
        for a, b in zip(L.sections, L.sections[1:]):
            assert np.linalg.norm(a.pts[-1] - b.pts[0]) < 2.0          # joined, no travel
        for prev, s in zip([None] + L.sections, L.sections):
            # closed loops; a loop may start from where the one before ended, when that is too
            # close for a move of its own (a join under the block-rate budget)
            assert np.allclose(s.pts[0], s.pts[-1]) or (
                prev is not None and np.allclose(s.pts[0], prev.pts[-1])
                and np.linalg.norm(s.pts[0] - s.pts[-1]) < o.max_speed / o.block_rate + 1e-6)
    text = cyl.paths["gcode"].read_text()
    body = text[text.index(";LAYER:1"):]
    assert ";TYPE:travel" not in body and "E-" not in body.split("M723 S0")[0]


def test_cylinder_crossings_are_chords_near_the_middle(tmp_path):
    """--light-gaps walls: where the walls merge the head moves on in chords (not in
    single-sample pieces) that stay within the chord tolerance of the plate's middle circle."""
    p = picture(tmp_path, w=60, h=10, boxes=[(0, 0, 6, 10, 0), (54, 0, 60, 10, 250)])
    o = lt.LithoOptions(shape="cylinder", diameter=30.0, height=2.0, pitch=0.4, light_gaps="walls")
    plan = lt.plan_lithophane(p, o)
    r_mid = o.diameter / 2 - o.max_thickness + 0.4          # middle of a 0.8 mm (white) plate
    m = [s for s in plan.layers[4].sections if s.kind == "mid-line"][0]
    hop = np.flatnonzero(m.e == 0)
    assert len(hop) > 5
    lengths = np.linalg.norm(m.pts[hop + 1] - m.pts[hop], axis=1)
    piece = 2 * math.pi * r_mid / len(plan.field.s)        # one sample step on the middle circle
    assert np.median(lengths) > 1.8 * piece
    inner = hop[np.isin(hop - 1, hop) & np.isin(hop + 1, hop)]   # not the joins to laid pieces
    mids = (m.pts[inner + 1] + m.pts[inner]) / 2
    assert np.abs(np.linalg.norm(mids, axis=1) - r_mid).max() < 2 * lt.CHORD_TOL


def test_cylinder_has_no_short_extruding_move(cyl, tmp_path):
    """Layer to layer, wall to mid-line to wall: no join shorter than a move the firmware runs."""
    for key in ("gcode", "stock"):
        assert not shortest_extruding_moves(cyl.paths[key])
    plan = lt.plan_lithophane(noisy(tmp_path, w=90, h=40), lt.LithoOptions(shape="cylinder", diameter=30.0,
                                                                           height=8.0))
    end = None
    for L in plan.layers:
        for s in L.sections:
            if end is not None:
                d = np.linalg.norm(s.pts[0] - end)
                assert d < 1e-9 or d >= lt.MIN_MOVE
            end = s.pts[-1]


def test_cylinder_seam(cyl):
    o, f = cyl.plan.options, cyl.plan.field
    r_in = o.diameter / 2 - o.max_thickness
    # samples start at the back (+Y) and run counter-clockwise: the picture's left edge is at
    # 90 degrees, its right edge just before it; thick on one side of the seam, thin on the other
    assert f.s[0] == pytest.approx(math.pi / 2)
    light = lt.tone.thickness(lt.tone.grey_to_luminance(np.array([250 / 255])), "perceptual", 0.8, 2.4, 1.5)
    assert f.t[3, 0] == pytest.approx(2.4) and f.t[3, -1] == pytest.approx(float(light[0]))
    assert f.t[3, -1] < 0.85
    outer = cyl.plan.layers[3].sections
    ow = [s for s in outer if s.kind == "wall" and np.linalg.norm(s.pts, axis=1).max() > r_in + 1][0]
    rad = np.linalg.norm(ow.pts, axis=1)
    ang = np.arctan2(ow.pts[:, 1], ow.pts[:, 0])
    left = np.abs(ang - (math.pi / 2 + 0.1)) < 0.05
    right = np.abs(ang - (math.pi / 2 - 0.1)) < 0.05
    # the outer wall half its own width in from the face (the front wall's width is planned:
    # one line, or up to wall_max where it takes the picture's steps)
    i = np.abs(f.s - (math.pi / 2 + 0.1)) < 0.05
    assert rad[left].mean() == pytest.approx(r_in + 2.4 - f.wf[3, i].mean() / 2, abs=0.05)
    assert r_in + 2.4 - lt.wall_max(o) / 2 - 0.01 <= rad[left].min() <= r_in + 2.4 - lt.wall_min(o) / 2 + 0.01
    assert rad[right].mean() < r_in + 1.0
    import trimesh
    m = trimesh.load(cyl.paths["stl"])
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert 0.98 <= cyl.stats["fill_ratio"] <= 1.02


# --- all outputs or none ----------------------------------------------------------------------

OUTPUTS = (".litho.gcode", ".stock.gcode", ".stl", ".transmission.png", ".litho.json")


def folder(d):
    """Every file in d with its bytes."""
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_a_failing_last_writer_leaves_the_earlier_outputs(tmp_path, monkeypatch):
    p = picture(tmp_path, boxes=[(0, 0, 20, 16, 0)])
    out = tmp_path / "o"
    lt.make(p, out, options=opts(), name="p")
    before = folder(out)
    assert sorted(before) == sorted(f"p{x}" for x in OUTPUTS)
    p2 = picture(tmp_path, "p2.png", boxes=[(20, 0, 40, 16, 0)])     # other files would come out
    write = outputs.write

    def interrupted(path, *a, **kw):
        if Path(path).name.startswith("p.litho.json"):               # the last of the five
            raise KeyboardInterrupt
        return write(path, *a, **kw)

    monkeypatch.setattr(outputs, "write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        lt.make(p2, out, options=opts(), name="p")
    assert folder(out) == before                                     # nothing new, nothing left over
    monkeypatch.setattr(outputs, "write", write)
    lt.make(p2, out, options=opts(), name="p")
    after = folder(out)
    assert sorted(after) == sorted(before)
    assert all(after[k] != before[k] for k in after if not k.endswith(".json"))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_killed_run_leaves_no_new_file(tmp_path, sig):
    """`bulgekit litho` killed while it writes (its temporary files are there): the earlier
    outputs of the same name stay as they were, and no file is added."""
    p = picture(tmp_path, w=200, h=40, boxes=[(0, 0, 100, 40, 0)])
    out = tmp_path / "o"
    args = [p, "-o", out, "--name", "p", "--width", 100, "--height", 20, "--foot", 0, "-q"]
    assert run(*args).exit_code == 0
    before = folder(out)
    p.write_bytes((tmp_path / picture(tmp_path, "q.png", w=200, h=40, boxes=[(100, 0, 200, 40, 0)]))
                  .read_bytes())                                     # the next run's files differ
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "bulgekit.cli", "litho", *map(str, args)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    t0 = time.monotonic()
    while not any(f.name.endswith(".part") for f in out.iterdir()):
        assert proc.poll() is None, "the run ended before it wrote anything"
        assert time.monotonic() - t0 < 120
        time.sleep(0.002)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0, err
    assert folder(out) == before


# --- CLI ---------------------------------------------------------------------------------------

def run(*args):
    return CliRunner().invoke(main, ["litho", *map(str, args)])


def test_cli_writes_everything(tmp_path):
    p = picture(tmp_path)
    r = run(p, "-o", tmp_path / "out", "--width", 20, "--height", 3)
    assert r.exit_code == 0, r.output
    for ext in (".litho.gcode", ".stock.gcode", ".stl", ".transmission.png", ".litho.json"):
        assert (tmp_path / "out" / f"p{ext}").exists()
    assert "fill ratio" in r.output
    assert "acceleration 3000 mm/s², junction deviation 0.013 mm, look-ahead 16 blocks" in r.output


def test_every_phase_reports_progress(tmp_path):
    """Planning through the callback; reading the picture, writing each file and the estimates
    through bulgekit.progress (what the CLI draws and the studio listens to)."""
    from bulgekit import progress

    heard, planned = [], []
    pic = picture(tmp_path)
    progress.listen(lambda label, done, total: heard.append((label, done, total)))
    try:
        lt.make(pic, tmp_path / "o", options=opts(), name="p",
                progress=lambda done, total: planned.append((done, total)))
    finally:
        progress.listen(None)
    assert planned[-1] == (15, 15)
    labels = {h[0] for h in heard}
    assert {f"reading {pic.name}", "writing p.stl", "writing p.litho.gcode", "writing p.stock.gcode",
            "estimating p.litho.gcode", "estimating p.stock.gcode"} <= labels
    rows = Image.open(pic).size[1]
    assert (f"reading {pic.name}", rows, rows) in heard           # in rows, to the last
    ends = [h for h in heard if h[1] == h[2]]
    assert {h[0] for h in ends} == labels                          # every phase closes


@pytest.mark.parametrize("args, message", [
    (["--min", "2", "--max", "1"], "--max: 1 mm must be more than --min 2 mm"),
    (["--min", "0.6"], "--min: 0.6 mm is thinner than two wall lines"),
    (["--width", "300", "--stretch"], "--bed: the part is 300.0 x 6.0 mm and does not fit a 220 x 220 mm bed"),
    (["--bed", "220,220,2"], "--bed: the part is 6.0 mm tall, more than the printer's 2 mm"),
    (["--bed", "220"], "expected two or three sizes"),
    (["--max", "nan"], "is not a finite number"),
    (["--shape", "cylinder", "--foot", "5"], "--foot: a cylinder stands by itself"),
])
def test_cli_bad_options(tmp_path, args, message):
    # the default foot (6 mm deep, 3 mm tall) counts: 300 x 6 mm, 3 + 3 mm tall
    p = picture(tmp_path)
    r = run(p, "-o", tmp_path / "out", "--width", 20, "--height", 3, *args)
    assert r.exit_code != 0
    assert message in r.output
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_cli_bad_pictures(tmp_path):
    not_image = tmp_path / "x.png"
    not_image.write_text("hello")
    r = run(not_image, "-o", tmp_path / "o")
    assert r.exit_code != 0 and f"{not_image}: cannot read image" in r.output
    tiny = picture(tmp_path, "tiny.png", w=5, h=5)
    r = run(tiny, "-o", tmp_path / "o")
    assert r.exit_code != 0 and "5 x 5 px; a lithophane needs at least 8 x 8" in r.output
    r = run(tmp_path / "missing.png", "-o", tmp_path / "o")
    assert r.exit_code == 2 and "missing.png' does not exist" in r.output


# --- through the firmware core ------------------------------------------------------------------

from test_e2e_bkcore import bkcore, run_core  # noqa: E402,F401  (the fixture builds the core runner)


def g1_kinds(path):
    """The ;TYPE: of every G1 in a file, in order (bkcore prints one line per G1)."""
    kind, layer, out = None, -1, []
    for line in open(path):
        if line.startswith(";TYPE:"):
            kind = line[6:].strip()
        elif line.startswith(";LAYER:"):
            layer = int(line[7:])
        elif line.startswith("G1 "):
            out.append((kind, layer))
    return out


@pytest.mark.parametrize("which", ["gcode", "stock"])
def test_extruder_rate_through_the_core(bkcore, made, which):
    """Width mode (litho file) and eq. 2 (stock file) give the same motion through the firmware
    core: on the mid-line after the first layer, >= 95 % of the extruding time (at cruise) has the
    extruder within 5 % of the set rate; only pieces capped at --max-speed may fall outside, and
    at the defaults (the narrowest line is what the rate lays at --max-speed) there are none."""
    o = made.plan.options
    r = o.flow / o.filament_area
    actions, summary, errors = run_core(bkcore, made.paths[which].read_text())
    assert not errors
    lines = [a for a in actions if a[0] == "line"]
    kinds = g1_kinds(made.paths[which])
    assert len(lines) == len(kinds)
    prev = None
    t_in = t_all = 0.0
    for (kind, layer), (_, x, y, z, e, f) in zip(kinds, lines):
        if prev is not None and kind == "mid-line" and layer >= 1 and e > 0:
            L = math.hypot(x - prev[0], y - prev[1])
            t = L / (f / 60)
            rate = e / t
            t_all += t
            if abs(rate / r - 1) <= 0.05:
                t_in += t
            else:
                assert f / 60 >= o.max_speed - 0.01, (kind, layer, rate, f)   # capped, nothing else
        prev = (x, y)
    assert t_all > 0 and t_in / t_all >= 0.95
    assert t_in == pytest.approx(t_all)
    if which == "gcode":
        assert "M723" in made.paths[which].read_text()


def test_estimate_in_chunks_is_the_whole_plan(noisy_made, monkeypatch):
    """A large file is planned a chunk of blocks at a time (with the braking distance on both
    sides); the speeds are those of planning it at once, with a lookahead or without."""
    from bulgekit.gcode import estimate as es

    for la in (16, None):
        whole = es.estimate_file(noisy_made.paths["gcode"], es.Machine(lookahead=la))
        monkeypatch.setattr(es, "CHUNK", 64)
        part = es.estimate_file(noisy_made.paths["gcode"], es.Machine(lookahead=la))
        monkeypatch.setattr(es, "CHUNK", 1 << 16)
        assert len(whole.blocks) > 10 * 64
        assert part.blocks["entry_speed"] == pytest.approx(whole.blocks["entry_speed"], abs=1e-6)
        assert part.total_s == pytest.approx(whole.total_s, rel=1e-9)


# --- light gaps: a thin mid-line runs on (the default), steady extruder rate -------------------

def test_light_gaps_keep_a_thin_mid_line(tmp_path):
    """White and near-white (gaps narrower than a mid-line) between dark boxes: by default the
    walls narrow and the mid-line runs on unbroken from end wall to end wall, at least
    min_line x (1 + MID_MARGIN) wide; nothing is shared or snapped; thickness and volume as the body."""
    p = picture(tmp_path, w=40, h=16, boxes=[(0, 0, 10, 16, 0), (10, 0, 20, 16, 245), (30, 0, 40, 16, 0)])
    o = opts(block_rate=0)          # pieces as the geometry gives them (the budget averages: its own test)
    plan = lt.plan_lithophane(p, o)
    f = plan.field
    assert f.shared == 0 and f.narrowed > 0
    assert lt.printed_thickness(plan) == pytest.approx(f.t, abs=1e-9)
    assert f.ww.min() >= lt.wall_min(o) - 1e-9 and f.wf.min() >= lt.wall_min(o) - 1e-9
    assert f.ww.max() <= lt.wall_max(o, front=False) + 1e-9 and f.wf.max() <= lt.wall_max(o) + 1e-9
    for k in range(1, f.layers):
        mids = [s for s in plan.layers[k].sections if s.kind == "mid-line"]
        assert len(mids) == 1
        m = mids[0]
        # laid all through the light part (5.6 .. 14.4 mm: samples 14 .. 36); at the two hard
        # steps beside it the walls may take a piece
        lo_u, hi_u = np.minimum(m.u[:-1], m.u[1:]), np.maximum(m.u[:-1], m.u[1:])
        light = (hi_u > 14) & (lo_u < 36)
        assert np.all(m.e[light] > 0) and lo_u[light].min() <= 14 and hi_u[light].max() >= 36
        assert (m.e == 0).sum() <= 2
        assert m.width[light].min() >= o.line_min() * (1 + lt.MID_MARGIN) * 0.97
        xs = sorted([m.pts[0, 0], m.pts[-1, 0]])
        assert xs[0] < W + 0.8 and xs[1] > 20.0 - W - 0.8
        laid, body = lt.laid_area(plan, k)
        assert laid[2:-2] == pytest.approx(body[2:-2], rel=0.005)


def test_mid_line_speed_changes_are_planned(tmp_path):
    """A photo-like picture: with --rate-accel the mid-line's speed changes from sample to
    sample by at most RATE_STEP nearly everywhere (not where a step of the picture is larger
    than the walls can take, between wall_min and wall_max); without it, most steps are larger.
    The walls take the difference: the thickness is the picture's either way."""
    p = noisy(tmp_path, w=120, h=12, sigma=30)

    def field(acc):
        o = opts(width=48.0, height=2.4, rate_accel=acc)
        f = lt.thickness_field(p, o)
        gm = f.t - f.ww - f.wf
        v = o.mid_flow / (gm / f.lines[:, None] * o.layer_height)
        return o, f, gm, np.abs(np.log(v[:, 1:] / v[:, :-1]))

    o, f, gm, step = field(1000.0)
    assert f.ww + f.wf + gm == pytest.approx(f.t, abs=1e-12)
    for w_, front in ((f.ww, False), (f.wf, True)):
        assert w_.min() >= lt.wall_min(o) - 1e-9 and w_.max() <= lt.wall_max(o, front) + 1e-9
    assert f.wf.max() > lt.wall_max(o, front=False) + 0.05        # the front wall takes the steps
    _, f0, gm0, step0 = field(0.0)
    assert f0.t == pytest.approx(f.t)
    over = lambda s_: float((s_ > math.log1p(lt.RATE_STEP) + 1e-9).mean())
    assert over(step) < 0.05 and over(step0) > 0.5
    # the mid-line's centre (back wall + half the gap) turns less
    c, c0 = f.ww + gm / 2, f0.ww + gm0 / 2
    assert np.abs(np.diff(c, axis=1)).mean() < 0.6 * np.abs(np.diff(c0, axis=1)).mean()


def test_back_wall_one_width_and_mid_line_held(tmp_path):
    """With the mid-line's speed planned, the picture's detail goes to the front wall: on a
    photo-like picture the back wall keeps back_wall(o) on most samples (with the walls alike,
    no planning, on none) and the mid-line's width stays the same from sample to sample on
    several times as many steps; the thickness is the picture's."""
    p = noisy(tmp_path, w=120, h=12, sigma=30)
    o = opts(width=48.0, height=2.4)
    f = lt.thickness_field(p, o)
    gm = f.t - f.ww - f.wf
    b = lt.back_wall(o)
    assert lt.wall_min(o) < b < o.line_width
    assert b == pytest.approx(o.min_thickness - o.line_min() * (1 + lt.MID_MARGIN) - lt.wall_min(o) - lt.BACK_SLACK)
    f0 = lt.thickness_field(p, opts(width=48.0, height=2.4, rate_accel=0.0))
    assert np.mean(np.abs(f.ww - b) < 1e-9) > 0.6 and np.mean(np.abs(f0.ww - b) < 1e-9) == 0
    same = lambda g: float((np.abs(np.diff(g, axis=1)) < 1e-9 * g[:, 1:]).mean())
    assert same(gm) > 0.1 and same(gm) > 3 * same(f0.t - f0.ww - f0.wf)
    assert f.ww + f.wf + gm == pytest.approx(f.t, abs=1e-12)
    # the JSON and the summary say the walls' widths
    for acc, back in ((1000.0, b), (0.0, None)):
        res = lt.make(p, tmp_path / f"o{acc:g}", options=opts(width=48.0, height=2.4, rate_accel=acc))
        wl = res.stats["walls"]
        fld = res.plan.field
        assert wl["back_mm"]["median"] == pytest.approx(back if back else float(np.median(fld.ww[fld.n_foot:])), abs=1e-3)
        assert wl["front_mm"]["max"] == pytest.approx(float(fld.wf[fld.n_foot:].max()), abs=1e-3)
        assert f"walls (mm, median and range): back {wl['back_mm']['median']:.3f}" in summary(res.stats)
    assert wl["back_mm"]["median"] != pytest.approx(b, abs=1e-3)        # without planning: not held


def test_held_gap_moves_only_where_it_must():
    """_held_gap: inside the band everywhere; where the value held leaves the band it is clipped
    to the nearer edge (the least change), and otherwise it stays."""
    lo = np.array([[1.0, 1.1, 1.0, 1.5, 1.5, 0.2, 0.2]])
    hi = np.array([[2.0, 2.1, 1.9, 2.5, 2.5, 0.9, 1.2]])
    q = thickness._held_gap(lo, hi)
    assert q.tolist() == [[1.5, 1.5, 1.5, 1.5, 1.5, 0.9, 0.9]]
    rng = np.random.default_rng(3)
    lo = rng.uniform(0, 1, (5, 200))
    hi = lo + rng.uniform(0.05, 0.5, (5, 200))
    q = thickness._held_gap(lo, hi)
    assert np.all(q >= lo) and np.all(q <= hi)
    moved = np.abs(np.diff(q, axis=1)) > 0
    prev_in = (q[:, :-1] >= lo[:, 1:]) & (q[:, :-1] <= hi[:, 1:])
    assert not np.any(moved & prev_in)
    edge = np.isclose(q[:, 1:], lo[:, 1:]) | np.isclose(q[:, 1:], hi[:, 1:])
    assert np.all(edge[moved])


def test_steady_mid_line_keeps_the_extruder_rate(tmp_path):
    """Through the estimator (1000 mm/s^2, the defaults' 16-block look-ahead): more of the
    mid-line's time within +-5 % of the set rate with the default --light-gaps mid-line and
    --rate-accel than with the walls sharing light gaps, and the part takes less time."""
    from bulgekit.gcode import estimate as E

    p = noisy(tmp_path, w=150, h=8, sigma=25)
    ref = 8.0 / (math.pi * 1.75 ** 2 / 4)
    share, time_ = {}, {}
    for mode in ("walls", "mid-line"):
        plan = lt.plan_lithophane(p, opts(width=60.0, height=1.6, light_gaps=mode))
        path = tmp_path / f"{mode}.gcode"
        lt.write_gcode(plan, path, "litho")
        r = E.estimate_file(str(path), E.Machine(accel=1000.0, travel_accel=1000.0))
        b = r.blocks
        mid = E.extruding(r) & (b["layer"] >= 1) & (b["feature"] == r.features.index("mid-line"))
        share[mode] = E.e_rate_share(r, mask=mid, ref=ref)
        time_[mode] = r.moves_s
    assert share["mid-line"] > share["walls"] + 0.05
    assert time_["mid-line"] < time_["walls"]


def test_default_flow_follows_the_printers_acceleration():
    """--accel: 8 mm^3/s at 3000 mm/s^2 and above, 8 x sqrt(a / 3000) below; a given
    --infill-flow and --paper-rate win; --rate-accel is held to --accel."""
    assert lt.LithoOptions().flow == 8.0 and lt.LithoOptions(accel=6000).flow == 8.0
    assert lt.LithoOptions(accel=1000).flow == pytest.approx(8 / math.sqrt(3), abs=0.005)
    assert lt.LithoOptions(accel=750).flow == pytest.approx(4.0)
    assert lt.LithoOptions(accel=1000, infill_flow=6.0).flow == 6.0
    o = lt.LithoOptions(accel=1000, paper_rate=True)
    assert o.mid_flow == pytest.approx(o.wall_flow)
    assert lt.LithoOptions(accel=500).plan_accel == 500 and lt.LithoOptions(accel=5000).plan_accel == 1000
    assert lt.LithoOptions(accel=500, rate_accel=0).plan_accel == 0
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(lt.LithoError, match="--accel"):
            lt.check_options(lt.LithoOptions(accel=bad))


def test_accel_lowers_the_flow_and_holds_the_rate(tmp_path):
    """Through the estimator at 1000 mm/s^2: a band made for --accel 1000 keeps more of its
    mid-line's time within +-5 % of its set rate than the same band made for the default
    3000 (its ramps at the stretch ends are shorter), and the file, the JSON and the estimate
    say so: the rate in M723 Q and the header, the machine's acceleration."""
    import json
    from bulgekit.gcode import estimate as E

    p = noisy(tmp_path, w=150, h=8, sigma=25)
    share, made = {}, {}
    for a in (3000.0, 1000.0):
        res = lt.make(p, tmp_path / str(int(a)), name="band", width=60.0, height=1.6, foot=0.0,
                      purge=False, accel=a)
        made[a] = res
        q = res.plan.options.mid_flow
        r = E.estimate_file(str(res.paths["gcode"]), E.Machine(accel=1000.0, travel_accel=1000.0))
        b = r.blocks
        mid = E.extruding(r) & (b["layer"] >= 1) & (b["feature"] == r.features.index("mid-line"))
        share[a] = E.e_rate_share(r, mask=mid, ref=q / (math.pi * 1.75 ** 2 / 4))
    assert share[1000.0] > share[3000.0] + 0.02
    g = made[1000.0].paths["gcode"].read_text()
    assert "; accel = 1000.0" in g and "; infill_flow = 4.62" in g and "\nM723 Q4.62" in g
    st = json.loads(made[1000.0].paths["json"].read_text())
    assert st["estimate"]["machine"]["accel_mm_s2"] == 1000.0 and st["options"]["infill_flow"] == 4.62
    assert st["rates"]["mid_line_mm3_s"] == pytest.approx(4.62)
    assert made[3000.0].stats["estimate"]["machine"]["accel_mm_s2"] == 3000.0
    # slower: a lower rate, timed at a lower acceleration
    assert st["estimate"]["estimated_time_s_gcode"] > made[3000.0].stats["estimate"]["estimated_time_s_gcode"]


def test_cli_light_gaps_and_rate_accel(tmp_path):
    """`bulgekit litho --light-gaps walls|mid-line --rate-accel A`: the JSON says the mode and
    counts the light gaps, the summary names both; bad values are refused naming the option."""
    import json
    from click.testing import CliRunner
    from bulgekit.cli import main

    p = picture(tmp_path, boxes=[(0, 0, 10, 16, 0), (10, 0, 30, 16, 240), (30, 0, 40, 16, 0)])
    run = lambda *a: CliRunner().invoke(main, ["litho", str(p), "--width", "20", "--height", "3", "--foot", "0",
                                               *map(str, a)])
    seen = {}
    for mode in ("mid-line", "walls"):
        r = run("-o", tmp_path / mode, "--light-gaps", mode)
        assert r.exit_code == 0, r.output
        g = json.loads((tmp_path / mode / "p.litho.json").read_text())["gaps"]
        assert g["light_gaps"] == mode
        seen[mode] = (g["narrowed_share"], g["shared_share"])
        assert "walls narrowed for a thin mid-line" in r.output
    assert seen["mid-line"][0] > 0 and seen["mid-line"][1] == 0
    assert seen["walls"][0] == 0 and seen["walls"][1] > 0
    r = run("-o", tmp_path / "x", "--light-gaps", "middle")
    assert r.exit_code == 2 and "--light-gaps" in r.output
    r = run("-o", tmp_path / "y", "--rate-accel", "-5")
    assert r.exit_code == 2 and "--rate-accel" in r.output
    r = run("-o", tmp_path / "z", "--accel", "0")
    assert r.exit_code == 2 and "--accel" in r.output
    assert not any((tmp_path / d).exists() for d in "xyz")
    r = run("-o", tmp_path / "a1000", "--accel", "1000")
    assert r.exit_code == 0, r.output
    assert "acceleration 1000 mm/s²" in r.output and "mid-line at 4.62 mm^3/s (lowered for --accel 1000" in r.output
    r = run("-o", tmp_path / "a1000f", "--accel", "1000", "--infill-flow", "8")
    assert r.exit_code == 0 and "mid-line at 8 mm^3/s:" in r.output


def test_summary_names_a_classic_jerk_machine():
    """An estimate with classic jerk (API callers' Machine(jerk=...)) is named in the summary."""
    import json
    from bulgekit.cli.litho import summary
    from bulgekit.gcode import estimate
    m = json.loads(json.dumps(lt.machine_words(estimate.Machine(jerk={"X": 10, "Y": 10, "Z": 0.3, "E": 5}))))
    assert m["classic_jerk"] == [10, 10, 0.3, 5]
    s = {"name": "x", "shape": "planar", "layers": 3, "size_mm": {"picture_width": 10, "picture_height": 1},
         "filament_mm": 100.0, "fill_ratio": 1.0, "extruding_moves": 10, "rates": {"mid_line_mm3_s": 8},
         "mid_line": {"capped_time_share": 0.0, "layers_with_two_or_more": 0},
         "gaps": {"narrowed_share": 0.1, "shared_share": 0.0},
         "look": {"plate_L_range": [36, 100], "curve": "perceptual", "picture_vs_print": None},
         "estimate": {"estimated_time_s_gcode": 60.0, "machine": m}}
    assert "classic jerk 10/10/0.3/5 mm/s" in summary(s)
