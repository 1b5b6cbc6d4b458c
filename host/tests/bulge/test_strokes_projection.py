"""Fixed-view drawing projected onto a synthetic cylinder, and cylinder unrolling."""
import math

import numpy as np
import pytest
import trimesh

from bulgekit.errors import InputError
from bulgekit.bulge.strokes import Stroke, cylinder_uv, project_drawing

R, H = 20.0, 30.0


@pytest.fixture(scope="module")
def cylinder():
    # Fine tessellation so the facets sit within 0.02 mm of the true circle.
    m = trimesh.creation.cylinder(radius=R, height=H, sections=512)
    m.apply_translation((0, 0, H / 2))  # stand on the bed, z = 0 .. 30
    return m


def test_front_view_lands_on_near_side(cylinder):
    # Looking along +y at the cylinder: a runs along +x, b is z.  With the
    # default origin the drawing's (0, 0) is the silhouette's lower-left
    # corner, i.e. x = -R, z = 0.
    a_vals = [5.0, 12.0, 20.0, 28.0, 35.0]
    s = Stroke(tuple((a, 10.0) for a in a_vals), 200, "front")
    res = project_drawing(cylinder, [s], view_dir=(0, 1, 0))
    assert res.missed == [] and len(res.strokes) == 1
    p = res.strokes[0].points
    assert p.shape == (5, 3) and res.strokes[0].weight == 200
    for (a, _), (x, y, z) in zip(s.points, p):
        assert x == pytest.approx(a - R, abs=1e-6)
        assert z == pytest.approx(10.0, abs=1e-6)
        # the side facing the viewer (y < 0), on the surface
        assert y == pytest.approx(-math.sqrt(R * R - x * x), abs=0.05)


def test_side_view_with_explicit_origin(cylinder):
    # Looking along -x from +x: the viewer's right is +y.
    s = Stroke(((0.0, 5.0), (10.0, 25.0)))
    res = project_drawing(cylinder, [s], view_dir=(-1, 0, 0), origin=(0, 0, 0))
    (x0, y0, z0), (x1, y1, z1) = res.strokes[0].points
    assert (y0, z0) == pytest.approx((0.0, 5.0), abs=1e-6)
    assert x0 == pytest.approx(R, abs=0.01)
    assert (y1, z1) == pytest.approx((10.0, 25.0), abs=1e-6)
    assert x1 == pytest.approx(math.sqrt(R * R - 100), abs=0.05)


def test_misses_are_errors_or_split_strokes(cylinder):
    s = Stroke(((10.0, 10.0), (20.0, 10.0), (50.0, 10.0), (30.0, 10.0), (25.0, 10.0)), 255, "sketch.svg:7")
    with pytest.raises(InputError, match=r"sketch\.svg:7 point 2 at \(50\.00, 10\.00\) mm in the view misses"):
        project_drawing(cylinder, [s], view_dir=(0, 1, 0))
    res = project_drawing(cylinder, [s], view_dir=(0, 1, 0), allow_miss=True)
    assert [len(x.points) for x in res.strokes] == [2, 2]
    assert res.missed == [("sketch.svg:7", 2, (50.0, 10.0))]


def test_bad_view_and_mesh(tmp_path, cylinder):
    with pytest.raises(InputError, match="parallel to up"):
        project_drawing(cylinder, [Stroke(((1.0, 1.0),))], view_dir=(0, 0, -1))
    bad = tmp_path / "junk.stl"
    bad.write_bytes(b"solid x\nthis is not an stl\n")
    with pytest.raises(InputError, match="junk.stl"):
        project_drawing(bad, [Stroke(((1.0, 1.0),))], view_dir=(0, 1, 0))


def test_mesh_from_file(tmp_path, cylinder):
    f = tmp_path / "cyl.stl"
    cylinder.export(f)
    res = project_drawing(f, [Stroke(((20.0, 3.0),))], view_dir=(0, 1, 0))
    assert res.strokes[0].points[0] == pytest.approx((0.0, -R, 3.0), abs=0.01)


def test_cylinder_uv_arc_length_and_seam():
    pts = np.array([
        [R, 0, 1.0],                      # on the seam
        [0, R, 2.0],                      # quarter turn counter-clockwise
        [-R, 0, 3.0],
        [0, -R, 4.0],                     # three quarters
        [R * math.cos(-1e-3), R * math.sin(-1e-3), 5.0],  # just before the seam
    ])
    uv = cylinder_uv(pts)
    circ = 2 * math.pi * R
    assert uv[:, 0] == pytest.approx([0, circ / 4, circ / 2, 3 * circ / 4, circ - R * 1e-3], abs=1e-9)
    assert uv[:, 1] == pytest.approx([1, 2, 3, 4, 5])
    # seam along +y: the +y point is now u = 0 and +x is three quarters on
    uv2 = cylinder_uv(pts[:2], seam_dir=(0, 1, 0))
    assert uv2[:, 0] == pytest.approx([3 * circ / 4, 0], abs=1e-9)
    # fixed radius: u scales with it, not with the point's own distance
    assert cylinder_uv([[2 * R, 0.0, 0.0], [0.0, 2 * R, 0.0]], radius=R)[1, 0] == pytest.approx(circ / 4)
    with pytest.raises(InputError):
        cylinder_uv(pts, seam_dir=(0, 0, 1))


def test_front_drawing_unrolls_onto_the_wall(cylinder):
    # A horizontal line drawn across the front maps to an arc; its u values
    # follow R * angle, increasing left to right as seen by the viewer.
    s = Stroke(tuple((a, 12.0) for a in np.linspace(2.0, 38.0, 10)))
    res = project_drawing(cylinder, [s], view_dir=(0, 1, 0))
    uv = cylinder_uv(res.strokes[0].points, radius=R)
    x = np.linspace(2.0, 38.0, 10) - R
    expected = R * np.mod(np.arctan2(-np.sqrt(R * R - x * x), x), 2 * math.pi)
    assert uv[:, 0] == pytest.approx(expected, abs=0.2)
    assert np.all(np.diff(uv[:, 0]) > 0)
    assert uv[:, 1] == pytest.approx(12.0)
