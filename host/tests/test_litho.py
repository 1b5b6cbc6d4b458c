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
from bulgekit.cli import main
from bulgekit.cli_litho import summary

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
    base = dict(width=20.0, height=3.0, pitch=0.4, foot=0.0)     # the plate alone; feet: test_foot_*
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


def test_transmission_curve_is_linear_in_transmission(tmp_path):
    greys = [0, 64, 128, 192, 255]
    p = picture(tmp_path, w=50, h=10, boxes=[(10 * i, 0, 10 * i + 10, 10, g) for i, g in enumerate(greys)])
    o = opts(width=50.0, height=2.0, curve="transmission", attenuation=1.5, min_line=0.01)
    f = lt.thickness_field(p, o)
    t = np.array([f.t[3, int(round((10 * i + 5) / 0.4))] for i in range(5)])
    T = np.exp(-1.5 * t)
    b = np.array(greys) / 255
    T_lo, T_hi = math.exp(-1.5 * 2.4), math.exp(-1.5 * 0.8)
    assert T == pytest.approx(T_lo + b * (T_hi - T_lo), rel=1e-6)


def test_narrow_gaps_snap_to_merged_walls_or_the_narrowest_line(tmp_path):
    # default narrowest line: what 8 mm^3/s lays at 150 mm/s, 8 / (150 x 0.2) = 0.267 mm.
    # darkness 0.05 -> t = 0.88 (gap 0.08 < 0.133: walls merge); 0.1 -> t = 0.96 (gap 0.16: up)
    p = picture(tmp_path, w=30, h=10, boxes=[(0, 0, 10, 10, round(255 * 0.95)), (10, 0, 20, 10, round(255 * 0.9))])
    o = opts(width=30.0, height=2.0)
    assert o.line_min() == pytest.approx(8 / (150 * 0.2))
    f = lt.thickness_field(p, o)
    assert f.t[2, 10] == pytest.approx(0.8)
    assert f.t[2, 40] == pytest.approx(0.8 + 8 / 30)
    assert f.snapped_down > 0 and f.snapped_up > 0
    gap = f.t - 0.8
    assert not np.any((gap > 1e-9) & (gap < o.line_min() - 1e-9))
    # given, --min-line wins (and below q / (U H) the narrow pieces are capped, and counted)
    f2 = lt.thickness_field(p, opts(width=30.0, height=2.0, min_line=0.1))
    assert f2.t[2, 40] == pytest.approx(0.96, abs=0.01)
    plan = lt.plan_lithophane(p, opts(width=30.0, height=2.0, min_line=0.1))
    V, F = lt.body_mesh(plan)
    assert lt.plan_stats(plan, lt.mesh_volume(V, F))["mid_line"]["capped_time_share"] > 0.5
    # the paper's rate (3.2 mm^3/s) lays 0.107 mm at 150 mm/s: half a line (0.2 mm) is the floor
    assert opts(paper_rate=True).line_min() == pytest.approx(0.2)


def test_frame_is_full_thickness(tmp_path):
    f = lt.thickness_field(picture(tmp_path), opts(frame=1.0))
    assert np.all(f.t[:5] == 2.4) and np.all(f.t[-5:] == 2.4)
    assert np.all(f.t[:, :3] == 2.4) and np.all(f.t[:, -3:] == 2.4)
    assert f.t[7, 25] == pytest.approx(0.8)


# --- planar geometry ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def step_plan(tmp_path_factory):
    """Black left half (2.4 mm), mid-grey right half (1.6 mm)."""
    d = tmp_path_factory.mktemp("step")
    p = picture(d, boxes=[(0, 0, 20, 16, 0), (20, 0, 40, 16, 128)])
    return lt.plan_lithophane(p, opts())


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
        assert m.pts[i:i + 2, 1] == pytest.approx(thick / 2, abs=1e-6)   # centre of the plate
        assert m.width[i] == pytest.approx(thick - 2 * W, abs=1e-6)
    # the mid-line runs from end wall to end wall
    assert {round(m.pts[0, 0], 6), round(m.pts[-1, 0], 6)} == {W, round(20.0 - W, 6)}


def test_nothing_outside_the_body(step_plan):
    from shapely.geometry import Point

    o, f = step_plan.options, step_plan.field
    for k in (0, 7, 14):
        P = lt._layer_polygon(o, f, k)
        for s in step_plan.layers[k].sections:
            for x, y in s.pts:
                assert P.buffer(1e-6).contains(Point(x, y)), (k, s.kind, x, y)
            # a line's half width stays inside too: walls half a line in, mid-line half its width
            if s.kind == "wall":
                assert min(P.exterior.distance(Point(p)) for p in s.pts[::7]) == pytest.approx(W / 2, abs=1e-6)


def test_head_crosses_merged_walls_in_the_middle(tmp_path):
    """Black, white (walls merge: no mid-line), black: the head crosses the white part without
    laying, along the plate's middle."""
    p = picture(tmp_path, boxes=[(0, 0, 10, 16, 0), (30, 0, 40, 16, 0)])
    plan = lt.plan_lithophane(p, opts())
    m = [s for s in plan.layers[4].sections if s.kind == "mid-line"][0]
    hop = np.flatnonzero(m.e == 0)
    assert len(hop) == 1                                          # one straight move across
    a, b = m.pts[hop[0]], m.pts[hop[0] + 1]
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
    assert sorted(m.pts[0, 1] for m in mids) == pytest.approx([0.4 + 0.8, 0.4 + 2.4], abs=1e-6)


def test_speed_from_flow_and_cap(step_plan):
    """v = q / (W * H), capped at max_speed (first layer at the first-layer ratio)."""
    o = step_plan.options
    m = [s for s in step_plan.layers[5].sections if s.kind == "mid-line"][0]
    laid = m.e > 0
    v = np.minimum(o.infill_flow / (m.width[laid] * H), o.max_speed)
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
    assert res.stats["look"]["correlation"] > 0.9                 # measured inside the frame


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
    r = o.infill_flow / o.filament_area
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
    assert len(rates) > 50
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
    assert np.median([m[4] for m in ws]) == pytest.approx(res.plan.field.t[5, 20] - 2 * W, abs=1e-3)


def test_outputs_and_stats(made):
    s = json.loads(made.paths["json"].read_text())
    assert s["layers"] == 15 and s["shape"] == "planar"
    assert 0.98 <= s["fill_ratio"] <= 1.02
    assert s["look"]["correlation"] > 0.9
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
                                                         pitch=0.4), name="cyl")


def test_cylinder_layers_are_joined_loops(cyl):
    for L in cyl.plan.layers:
        kinds = [s.kind for s in L.sections]
        assert kinds in (["wall", "mid-line", "wall"],)
        for a, b in zip(L.sections, L.sections[1:]):
            assert np.linalg.norm(a.pts[-1] - b.pts[0]) < 2.0          # joined, no travel
        for s in L.sections:
            assert np.allclose(s.pts[0], s.pts[-1])                     # closed loops
    text = cyl.paths["gcode"].read_text()
    body = text[text.index(";LAYER:1"):]
    assert ";TYPE:travel" not in body and "E-" not in body.split("M723 S0")[0]


def test_cylinder_crossings_are_chords_near_the_middle(cyl):
    """Where the walls merge the head moves on in chords of 3 samples (about 1.2 mm), not in
    single-sample pieces, and stays within the chord's sagitta of the plate's middle circle."""
    o = cyl.plan.options
    r_mid = o.diameter / 2 - o.max_thickness + 0.4          # middle of a 0.8 mm (white) plate
    m = [s for s in cyl.plan.layers[4].sections if s.kind == "mid-line"][0]
    hop = np.flatnonzero(m.e == 0)
    assert len(hop) > 10
    lengths = np.linalg.norm(m.pts[hop + 1] - m.pts[hop], axis=1)
    piece = 2 * math.pi * r_mid / len(cyl.plan.field.s)   # one sample step on the middle circle
    assert np.median(lengths) == pytest.approx(3 * piece, rel=0.02)
    inner = hop[np.isin(hop - 1, hop) & np.isin(hop + 1, hop)]   # not the joins to laid pieces
    mids = (m.pts[inner + 1] + m.pts[inner]) / 2
    sag = lengths.max() ** 2 / (8 * r_mid)
    assert np.abs(np.linalg.norm(mids, axis=1) - r_mid).max() < sag + 0.01


def test_cylinder_seam(cyl):
    o, f = cyl.plan.options, cyl.plan.field
    r_in = o.diameter / 2 - o.max_thickness
    # samples start at the back (+Y) and run counter-clockwise: the picture's left edge is at
    # 90 degrees, its right edge just before it; thick on one side of the seam, thin on the other
    assert f.s[0] == pytest.approx(math.pi / 2)
    assert f.t[3, 0] == pytest.approx(2.4) and f.t[3, -1] == pytest.approx(0.8)
    outer = cyl.plan.layers[3].sections
    ow = [s for s in outer if s.kind == "wall" and np.linalg.norm(s.pts, axis=1).max() > r_in + 1][0]
    rad = np.linalg.norm(ow.pts, axis=1)
    ang = np.arctan2(ow.pts[:, 1], ow.pts[:, 0])
    left = np.abs(ang - (math.pi / 2 + 0.1)) < 0.05
    right = np.abs(ang - (math.pi / 2 - 0.1)) < 0.05
    assert rad[left].mean() == pytest.approx(r_in + 2.4 - W / 2, abs=0.05)
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
    write = lt._write_atomic

    def interrupted(path, *a, **kw):
        if Path(path).name.startswith("p.litho.json"):               # the last of the five
            raise KeyboardInterrupt
        return write(path, *a, **kw)

    monkeypatch.setattr(lt, "_write_atomic", interrupted)
    with pytest.raises(KeyboardInterrupt):
        lt.make(p2, out, options=opts(), name="p")
    assert folder(out) == before                                     # nothing new, nothing left over
    monkeypatch.setattr(lt, "_write_atomic", write)
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


@pytest.mark.parametrize("args, message", [
    (["--min", "2", "--max", "1"], "--max: 1 mm must be more than --min 2 mm"),
    (["--min", "0.6"], "--min: 0.6 mm is thinner than two wall lines"),
    (["--width", "300"], "--bed: the part is 300.0 x 6.0 mm and does not fit a 220 x 220 mm bed"),
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
    assert r.exit_code != 0 and "image file not found" in r.output


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
    r = o.infill_flow / o.filament_area
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
