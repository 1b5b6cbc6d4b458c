"""Lithophanes keep their picture (issue 37, item 5): the aspect is kept unless --stretch, and
one line says what was cropped or fitted; the arc (a curved panel that stands by itself); a
cylinder's --angle; a height taken from the picture fits the bed."""
from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from bulgekit import litho as lt
from bulgekit.cli import main
from bulgekit.litho import paths


def picture(tmp_path, w=60, h=40, name="p.png"):
    rng = np.random.default_rng(3)
    a = (rng.random((h, w)) * 255).astype(np.uint8)
    a[:, : w // 3] = 20                                   # a dark left third: the picture's own side
    p = tmp_path / name
    Image.fromarray(a).save(p)
    return p


def litho(*args):
    r = CliRunner().invoke(main, ["litho", *map(str, args), "-q", "--no-purge"])
    assert r.exit_code == 0, r.output
    return r.output.splitlines()


def test_both_sizes_crop_to_the_aspect_and_one_line_says_so(tmp_path):
    p = picture(tmp_path)                                 # 60 x 40 px, aspect 1.5
    out = litho(p, "--width", 30, "--height", 10, "--foot", 0, "-o", tmp_path / "o")
    assert out[0].startswith("picture 30.0 x 10.0 mm: cropped to keep its aspect, 20 px off the top and bottom")
    assert "--stretch" in out[0] and not out[1].startswith("picture")
    plan = lt.plan_lithophane(p, lt.LithoOptions(width=30.0, height=10.0, foot=0.0))
    assert plan.field.layout.crop == (0, 10, 60, 30)
    # --stretch: the whole picture, squeezed, as before
    out = litho(p, "--width", 30, "--height", 10, "--foot", 0, "--stretch", "-o", tmp_path / "s")
    assert "stretched to it (--stretch)" in out[0]
    assert lt.plan_lithophane(p, lt.LithoOptions(width=30.0, height=10.0, foot=0.0, stretch=True)
                              ).field.layout.crop == (0, 0, 60, 40)


def test_one_size_keeps_the_aspect(tmp_path):
    p = picture(tmp_path)
    f = lt.thickness_field(p, lt.LithoOptions(width=None, height=12.0, foot=0.0))
    assert f.picture_mm == pytest.approx((18.0, 12.0))    # the width from the aspect
    assert "the width from the picture's aspect" in f.layout.note
    f = lt.thickness_field(p, lt.LithoOptions(width=30.0, foot=0.0))
    assert f.picture_mm == pytest.approx((30.0, 20.0)) and "the height from the picture's aspect" in f.layout.note


def test_cylinder_height_sets_the_angle_not_a_stretch(tmp_path):
    p = picture(tmp_path)
    o = lt.LithoOptions(shape="cylinder", diameter=30.0, height=12.0)
    f = lt.thickness_field(p, o)
    assert f.picture_mm[0] == pytest.approx(18.0)         # 12 mm x 1.5: the aspect kept
    deg = math.degrees(18.0 / 15.0)
    assert f.layout.angle == pytest.approx(deg) and "degrees of the cylinder" in f.layout.note
    cols = f.inside[1]
    n = len(f.s)
    assert (cols.stop - cols.start) == pytest.approx(n * deg / 360, abs=1)
    plain = np.ones(n, bool)
    plain[cols] = False
    assert np.all(f.t[:, plain] == o.min_thickness)       # the rest plain at the thinnest
    front = np.argmin(np.sin(f.s))                        # the picture is centred on the front (-Y)
    assert cols.start <= front < cols.stop


def test_cylinder_angle(tmp_path):
    p = picture(tmp_path)
    res = lt.make(p, tmp_path / "o", options=lt.LithoOptions(shape="cylinder", diameter=30.0, angle=90.0))
    f = res.plan.field
    assert f.picture_mm[0] == pytest.approx(math.pi / 2 * 15.0)
    assert f.picture_mm[1] == pytest.approx(f.picture_mm[0] / 1.5, abs=0.2)     # whole layers
    assert res.stats["picture"]["angle_deg"] == 90.0
    assert 0.98 <= res.stats["fill_ratio"] <= 1.02
    assert res.stats["stands"]["stands"]
    # --angle with --height: both fixed, so cropped
    f = lt.thickness_field(p, lt.LithoOptions(shape="cylinder", diameter=30.0, angle=90.0, height=20.0))
    assert "cropped" in f.layout.note and f.layout.crop[2] - f.layout.crop[0] < 60


@pytest.mark.parametrize("angle", [None, 200.0])
def test_arc_stands_and_fills(tmp_path, angle):
    import shapely
    import trimesh
    p = picture(tmp_path, 90, 60)
    o = lt.LithoOptions(shape="arc", diameter=40.0, angle=angle, layer_height=0.3)
    res = lt.make(p, tmp_path / "o", options=o)
    f, s = res.plan.field, res.stats
    deg = 120.0 if angle is None else angle
    assert f.s[-1] == pytest.approx(math.radians(deg)) and s["picture"]["angle_deg"] == deg
    assert f.picture_mm[0] == pytest.approx(math.radians(deg) * 20.0)
    assert f.picture_mm[1] == pytest.approx(f.picture_mm[0] / 1.5, abs=0.3)
    assert 0.98 <= s["fill_ratio"] <= 1.02
    m = trimesh.load(res.paths["stl"])
    assert m.is_watertight and m.volume == pytest.approx(s["stl_volume_mm3"], rel=1e-4)
    # it stands: the centre of mass over its footprint with margin (for 120 degrees of a 40 mm
    # circle the thin arc's centre of mass lies 20 x (sin 60 / (pi / 3) - 1) = -3.5 mm from the
    # outer face: inside the footprint's hull, a few mm from its edge)
    st = s["stands"]
    assert st["stands"] and st["footprint_margin_mm"] > 2 and st["tip_angle_deg"] > 5
    com = np.array(st["centre_of_mass_mm"])
    assert com[:2] == pytest.approx(m.center_mass[:2], abs=0.05)
    # every path point within the layer's cross-section; the layer's first point is where the
    # layer below ended (the join up: within 0.05 mm)
    for k in range(0, f.layers, 17):
        P = paths._layer_polygon(res.plan.options, f, k)
        for i, sec in enumerate(res.plan.layers[k].sections):
            assert shapely.contains_xy(P.buffer(0.01), sec.pts[1:, 0], sec.pts[1:, 1]).all()
            assert P.buffer(0.05 if i == 0 else 0.01).contains(shapely.Point(sec.pts[0]))
    out = litho(p, "--shape", "arc", "--diameter", 40, "--layer-height", 0.3, "-o", tmp_path / "c")
    assert any(line.startswith("  stands: centre of mass") for line in out)


def test_a_height_from_the_picture_fits_the_bed(tmp_path):
    tall = picture(tmp_path, 20, 90, "tall.png")          # aspect 2 / 9
    f = lt.thickness_field(tall, lt.LithoOptions(shape="cylinder", diameter=60.0, layer_height=0.3,
                                                 bed=(220.0, 220.0, 250.0)))
    assert f.picture_mm[1] <= 250.0 and f.layers * 0.3 <= 250.0
    assert "more than the bed's 250 mm" in f.layout.note and f.layout.angle < 360
    f = lt.thickness_field(tall, lt.LithoOptions(width=100.0, layer_height=0.3, foot=0.0, bed=(220.0, 220.0, 250.0)))
    assert f.picture_mm[1] <= 250.0 and f.picture_mm[0] < 100.0 and "fitted to the bed's height" in f.layout.note
    # the defaults on a picture that fits: the height from the aspect, said
    out = litho(picture(tmp_path), "--width", 30, "--foot", 0, "-o", tmp_path / "o")
    assert out[0] == "picture 30.0 x 20.0 mm: the height from the picture's aspect (60 x 40 px)"


def test_angle_is_for_round_shapes():
    with pytest.raises(lt.LithoError, match="--angle"):
        lt.check_options(lt.LithoOptions(angle=90.0))
    with pytest.raises(lt.LithoError, match="--angle"):
        lt.check_options(lt.LithoOptions(shape="arc", angle=330.0))
