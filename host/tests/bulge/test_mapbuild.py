import math

import numpy as np
import pytest

from bulgekit.bulge import mapformat
from bulgekit.bulge.mapbuild import BuildError, build, sample_strokes
from bulgekit.bulge.strokes import Stroke
from bulgekit.bulge.wall import walls_from_gcode


@pytest.fixture(scope="module")
def model(request):
    from pathlib import Path
    return walls_from_gcode(Path(__file__).parents[1] / "data" / "prusa_cyl.gcode")


def test_vertical_stroke_gives_one_point_per_layer(model):
    r = build([Stroke(((10.0, 1.0), (10.0, 4.0)))], model)
    zs = [p.z for p in r.points]
    assert zs == pytest.approx([1.2, 1.5, 1.8, 2.1, 2.4, 2.7, 3.0, 3.3, 3.6, 3.9, 4.2])
    assert len(set(zs)) == len(zs)
    for p in r.points:
        assert p.u == pytest.approx(10.0, abs=1e-6)


def test_horizontal_stroke_gives_points_every_spacing(model):
    r = build([Stroke(((0.0, 5.0), (9.0, 5.0)))], model, spacing=1.0)
    assert len(r.points) == 10
    assert {p.z for p in r.points} == {5.1}
    us = sorted(p.u for p in r.points)
    assert np.diff(us) == pytest.approx([1.0] * 9)
    # default spacing is twice the line width
    r = build([Stroke(((0.0, 5.0), (9.0, 5.0)))], model, line_width=0.5)
    assert len(r.points) == 10


def test_points_lie_on_the_outer_wall_toolpath_in_print_order(model):
    r = build([Stroke(((-20.0, 3.0), (30.0, 3.2)))], model)
    q = r.quantum_um / 1000
    bm = r.bulge_map
    for layer in bm.layers:
        wall = next(w for w in model.walls if round(w.z * 100) == layer.z_cmm)
        ss = []
        for x, y in layer.points:
            s, d = wall.project(x * q, y * q)
            assert d < q  # quantisation only
            ss.append(s)
        assert ss == sorted(ss)


def test_dot_and_merge_of_close_points(model):
    r = build([Stroke(((7.0, 2.0),)), Stroke(((7.2, 2.0),), weight=100),
               Stroke(((9.0, 2.0),))], model)
    assert len(r.points) == 2
    merged = min(r.points, key=lambda p: p.u)
    assert merged.weight == 255 and len(merged.sources) == 2


def test_u_wraps_around_the_wall(model):
    L = model.walls[10].length
    a = build([Stroke(((-3.0, 3.0),))], model).points[0]
    b = build([Stroke(((L - 3.0, 3.0),))], model).points[0]
    assert (a.x, a.y) == pytest.approx((b.x, b.y), abs=1e-6)


def test_weights_go_into_the_map_only_when_used(model):
    r = build([Stroke(((5.0, 2.0),))], model)
    assert not r.bulge_map.has_weights
    r = build([Stroke(((5.0, 2.0),), weight=128), Stroke(((9.0, 2.0),))], model)
    assert r.bulge_map.has_weights
    assert sorted(r.bulge_map.layers[0].weights) == [128, 255]


def test_too_many_points_names_the_layer(model):
    with pytest.raises(BuildError, match=r"z 5\.10 mm: 70.*--spacing"):
        build([Stroke(((0.0, 5.0), (69.0, 5.0)))], model, spacing=1.0)


def test_not_strict_leaves_full_layers_out_and_keeps_the_rest(model):
    strokes = [Stroke(((0.0, 5.0), (69.0, 5.0))), Stroke(((80.0, 2.0), (80.0, 3.0)))]
    r = build(strokes, model, spacing=1.0, strict=False)
    assert r.too_many == [(pytest.approx(5.1), 70)]
    assert len(r.over_points) == 70 and {round(p.z, 2) for p in r.over_points} == {5.1}
    # the other stroke's layers are in the map, and only they
    assert r.points and all(p.u == pytest.approx(80.0, abs=0.01) for p in r.points)
    assert [round(l.z_cmm / 100, 2) for l in r.bulge_map.layers] == sorted({round(p.z, 2) for p in r.points})


def test_stroke_outside_the_wall_height_names_the_stroke(model):
    with pytest.raises(BuildError, match=r"logo\.svg#path3: stroke spans v 8\.00\.\.12\.00 mm, outside.*0\.00\.\.9\.90"):
        build([Stroke(((0.0, 8.0), (0.0, 12.0)), source="logo.svg#path3")], model)


def test_bad_spacing_and_no_strokes(model):
    with pytest.raises(BuildError, match="spacing"):
        build([Stroke(((0.0, 5.0),))], model, spacing=0)
    with pytest.raises(BuildError, match="no strokes"):
        build([], model)


def test_overflow_lists_layers_beyond_the_arena(model):
    strokes = [Stroke(((u, 0.5), (u, 9.8))) for u in range(0, 120, 3)]
    r = build(strokes, model)
    assert len(r.map_bytes) > 2048
    over = r.overflow()
    assert over and over[-1][0] == pytest.approx(9.9)
    fits = sum(r.record_sizes[: len(r.record_sizes) - len(over)])
    arena = mapformat.ARENA_BYTES  # overflow()'s default: the firmware's
    assert fits <= arena < fits + r.record_sizes[len(r.record_sizes) - len(over)]


def test_strokes_longer_than_the_wall_are_refused_not_wrapped(model):
    L = model.walls[int(model.layer_of_v(3.0)[0])].length
    # a horizontal stroke 10 mm longer than the wall: its end would land on its start
    with pytest.raises(BuildError) as ei:
        build([Stroke(((0.0, 3.0), (L + 10.0, 3.0)), source="long line")], model)
    msg = str(ei.value)
    assert "long line" in msg and f"{L:.1f} mm around" in msg and "span" in msg
    # two strokes, each shorter than the wall, that together pass a full turn
    with pytest.raises(BuildError, match="second"):
        build([Stroke(((-5.0, 3.0), (5.0, 3.0)), source="first"),
               Stroke(((L - 10.0, 3.0), (L + 2.0, 3.0)), source="second")], model)
    # exactly one turn is fine (the ends coincide and merge into one point)
    r = build([Stroke(((0.0, 3.0), (L, 3.0)))], model, spacing=2.0)
    us = sorted(p.u for p in r.points)
    assert len(us) == int(L / 2) and us[0] == pytest.approx(0.0, abs=1e-6)
    assert np.diff(us).min() > 1.0


def test_open_top_turn_of_a_vase_takes_only_the_u_it_covers():
    from pathlib import Path
    m = walls_from_gcode(Path(__file__).parents[1] / "data" / "prusa_vase.gcode")
    top = m.walls[-1]
    assert not top.closed and top.turn > top.length
    a, b = top.u_covered()
    # a point on the part of the top turn that was printed: same place as
    # the same u one turn later
    r = build([Stroke(((a + 10.0, 9.8),))], m)
    r2 = build([Stroke(((a + 10.0 + top.turn, 9.8),))], m)
    assert (r.points[0].x, r.points[0].y) == pytest.approx((r2.points[0].x, r2.points[0].y))
    assert top.project(r.points[0].x, r.points[0].y)[1] < 1e-6
    # the half turn that is not printed is an error naming the layer, not a
    # point wrapped onto some other place of the chain
    with pytest.raises(BuildError, match=r"dot.*z 9\.90 mm.*open chain"):
        build([Stroke(((b + 10.0, 9.8),), source="dot")], m)


def test_bad_line_width_or_spacing_is_named(model):
    st = [Stroke(((5.0, 2.0),))]
    with pytest.raises(BuildError, match="line width 0 mm"):
        build(st, model, line_width=0)
    with pytest.raises(BuildError, match="point spacing nan mm"):
        build(st, model, spacing=float("nan"))
