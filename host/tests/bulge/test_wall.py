import math

import numpy as np
import pytest

from bulgekit.gcode import iter_moves
from bulgekit.bulge.wall import WallError, extract_walls, walls_from_gcode

R_OUTER = 20 - 0.45 / 2  # outer-wall centreline of the 40 mm cylinder


@pytest.mark.parametrize("name", ["prusa_cyl.gcode", "prusa_cyl_m83.gcode", "cura_cyl.gcode"])
def test_cylinder_walls(data_dir, name):
    m = walls_from_gcode(data_dir / name)
    assert len(m.walls) == 33
    assert m.layer_height == pytest.approx(0.3)
    assert [w.z for w in m.walls] == pytest.approx([0.3 * (i + 1) for i in range(33)])
    assert m.v_range == pytest.approx((0.0, 9.9))
    for w in m.walls[1:]:
        assert w.length == pytest.approx(2 * math.pi * R_OUTER, rel=0.01)
        assert w.ccw
        # u = 0 faces the front (-Y) of the part centred at (100, 100)
        x, y = w.xy_of_u(0.0)[0]
        assert x == pytest.approx(100, abs=0.05) and y < 100 - 19
        # a quarter turn counter-clockwise is the +X side (right, seen from the front)
        x, y = w.xy_of_u(w.length / 4)[0]
        assert x > 100 + 19 and y == pytest.approx(100, abs=0.3)


def test_same_u_lands_on_the_same_spot_every_layer(data_dir):
    m = walls_from_gcode(data_dir / "prusa_cyl.gcode")
    pts = np.array([w.xy_of_u(17.0)[0] for w in m.walls[1:]])
    assert np.ptp(pts[:, 0]) < 0.1 and np.ptp(pts[:, 1]) < 0.1


def test_vase_mode_windows(data_dir):
    m = walls_from_gcode(data_dir / "prusa_vase.gcode")
    zs = [w.z for w in m.walls]
    assert zs == pytest.approx([0.3 * (i + 1) for i in range(33)])
    # spiral windows are whole turns, except the half turn at the top
    for w in m.walls[3:-1]:
        assert w.length == pytest.approx(2 * math.pi * R_OUTER, rel=0.02)
    assert m.walls[-1].length < 0.6 * m.walls[-2].length
    assert any("9.90" in n for n in m.notes)


def test_no_outer_wall_comments_suggests_geometric(data_dir):
    with pytest.raises(WallError, match=r"slic3r_cyl\.gcode: no outer-wall feature comments.*--geometric"):
        walls_from_gcode(data_dir / "slic3r_cyl.gcode")


def test_geometric_mode_skips_the_skirt(data_dir):
    m = walls_from_gcode(data_dir / "slic3r_cyl.gcode", geometric=True)
    assert len(m.walls) == 33
    # first layer: the skirt is the largest loop, but the wall is the one under layer 2
    assert m.walls[0].length == pytest.approx(2 * math.pi * 19.78, rel=0.01)
    tagged = walls_from_gcode(data_dir / "prusa_cyl.gcode", geometric=True)
    assert tagged.walls[0].length == pytest.approx(m.walls[0].length, rel=0.01)


def _square(ccw=True, z=0.2, layers=3):
    out = ["G90", "M83"]
    for k in range(layers):
        zz = z + 0.2 * k
        pts = [(0, 0), (10, 0), (10, 10), (0, 10), (0, 0)]
        if not ccw:
            pts = pts[::-1]
        out += [f"G1 Z{zz:.2f}", f"G1 X{pts[0][0]} Y{pts[0][1]}", ";TYPE:External perimeter"]
        out += [f"G1 X{x} Y{y} E0.5" for x, y in pts[1:]]
        out += [";TYPE:Solid infill", "G1 X5 Y5 E0.2"]
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("ccw", [True, False])
def test_u_runs_counter_clockwise_whatever_the_print_direction(ccw):
    m = extract_walls(iter_moves(_square(ccw).splitlines()), layer_height=0.2)
    w = m.walls[0]
    assert w.ccw is ccw
    assert w.length == pytest.approx(40)
    # front middle of the square is u = 0, then right along the front edge
    assert w.xy_of_u(0)[0] == pytest.approx([5, 0])
    assert w.xy_of_u(2)[0] == pytest.approx([7, 0])
    assert w.xy_of_u(10)[0] == pytest.approx([10, 5])
    # and back: s <-> u round trip
    s = w.s_of_u(np.array([0.0, 3.0, 39.0]))
    assert w.u_of_s(s) == pytest.approx([0, 3, 39])


def test_layer_of_v_uses_the_bead_each_layer_covers():
    m = extract_walls(iter_moves(_square().splitlines()), layer_height=0.2)
    assert list(m.layer_of_v([0.0, 0.1, 0.2, 0.21, 0.4, 0.59, 0.6, 0.61])) == [0, 0, 0, 1, 1, 2, 2, -1]


def test_walls_computed_together_are_each_walls_own_on_random_walls():
    """_walls_geometry computes thousands of walls at once: every number is, to the bit, what one
    wall's own arrays give (_area_centroid, cumsum of hypot, _ray_hit): walls of 3 to 700
    vertices (sums of one block of 8 and of several halvings), many of one length in a row,
    loops and open chains the ray misses (its fallback), a crossing at a vertex shared by two
    segments (equal t: the first), walls of zero area (back and forth: np.dot decides the
    orientation, the centroid is the mean), directions along the axes."""
    from bulgekit.bulge.wall import _area_centroid, _ray_hit, _walls_geometry
    rng = np.random.default_rng(26)
    xys = []
    for i in range(460):
        n = int(rng.integers(3, 40)) if i % 5 else int(rng.integers(40, 600))
        if i >= 400:
            n = 700                                      # walls of one length in a row
        a = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = rng.uniform(5, 20) * (1 + 0.2 * rng.random(n))
        xy = np.stack([r * np.cos(a), r * np.sin(a)], axis=1) + rng.uniform(-50, 50, 2)
        if i % 3 == 0 or i >= 400:
            xy = np.concatenate([xy, xy[:1]])            # closed
        if i >= 400:
            xys.append(xy)
            continue
        if i % 7 == 0:
            xy = xy[: max(3, n // 4)]                    # a short open arc: the ray may miss
        if i % 11 == 0:
            xy = np.array([[0.0, 1.0], [0.0, -1.0], [2.0, -1.0], [2.0, 1.0], [0.0, 1.0]]) + i
        if i % 13 == 0:
            xy = np.array([[0.0, 0.0], [3.0, 1.0], [6.0, 2.0], [3.0, 1.0]]) + 0.1 * i   # no area
        if i % 17 in (0, 1):
            # a diamond round (i, i), its centroid to the bit: the ray towards -Y meets its lowest
            # vertex, the end of one segment and the start of the next (at the loop's seam or not)
            xy = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
            xy = (xy if i % 17 == 0 else np.concatenate([xy[1:], xy[1:2]])) + i
        xys.append(xy)
    # the walls' moves' ends x1 y1, in another order than the walls, with moves between
    rows, r0 = [], np.empty(len(xys), np.int64)
    for i in rng.permutation(len(xys)):
        rows.append(rng.uniform(-9, 9, (int(rng.integers(0, 3)), 2)))
        r0[i] = sum(map(len, rows))
        rows.append(xys[i][1:])
    ends = np.concatenate(rows)
    index = np.arange(len(ends)) * 3 + 7
    r1 = r0 + np.array([len(xy) - 1 for xy in xys])
    first = np.array([xy[0] for xy in xys])
    for d in ((0.0, -1.0), (1.0, 0.0), (0.6, 0.8)):
        got = _walls_geometry(first, ends, index, r0, r1, d)
        for i, (xy, s, mi, ccw, cen, s_ref) in enumerate(zip(*got)):
            assert xy.tobytes() == xys[i].tobytes()
            want_s = np.empty(len(xy))
            want_s[0] = 0.0
            np.cumsum(np.hypot(xy[1:, 0] - xy[:-1, 0], xy[1:, 1] - xy[:-1, 1]), out=want_s[1:])
            assert s.tobytes() == want_s.tobytes()
            assert mi.tolist() == index[r0[i]:r1[i]].tolist()
            area, want_cen = _area_centroid(np.array(xy))
            assert (ccw, cen) == (area >= 0, want_cen)
            assert np.float64(s_ref).tobytes() == np.float64(_ray_hit(xy, want_s, want_cen, d)).tobytes()


@pytest.mark.parametrize("name,geometric", [("prusa_cyl.gcode", False), ("prusa_vase.gcode", False),
                                            ("cura_cyl.gcode", False), ("slic3r_cyl.gcode", True)])
def test_walls_computed_together_are_each_walls_own(data_dir, name, geometric):
    """The arc lengths, areas (ccw) and centroids that walls_from_records computes for all walls
    at once are, to the bit, what one wall's own arrays give (_area_centroid, cumsum of hypot),
    and closed is whether its last vertex lies within max(2 mm, 3 layers) of its first."""
    from bulgekit.bulge.wall import _area_centroid
    m = walls_from_gcode(data_dir / name, geometric=geometric)
    assert len(m.walls) > 10
    for w in m.walls:
        xy = np.array(w.xy)                              # an array of its own
        area, cen = _area_centroid(xy)
        assert (area >= 0, cen) == (w.ccw, w.centroid)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(xy[1:, 0] - xy[:-1, 0], xy[1:, 1] - xy[:-1, 1]))])
        assert s.tobytes() == np.asarray(w.s).tobytes()
        gap = max(2.0, 3 * m.layer_height)
        assert w.closed == (math.hypot(*(xy[-1] - xy[0])) <= gap)


def _median_distance_every_segment(pts, poly):
    """wall._median_distance as it was: every point projected on every segment."""
    if len(pts) > 64:
        pts = pts[np.linspace(0, len(pts) - 1, 64).astype(int)]
    a = poly[:-1][None, :, :]
    d = (poly[1:] - poly[:-1])[None, :, :]
    p = pts[:, None, :]
    l2 = np.maximum((d * d).sum(-1), 1e-18)
    t = np.clip(((p - a) * d).sum(-1) / l2, 0, 1)
    q = a + t[..., None] * d
    return float(np.median(np.sqrt(((q - p) ** 2).sum(-1)).min(axis=1)))


def test_median_distance_is_that_of_every_segment():
    """Geometric mode's distance from a loop to the wall above projects each point only on the
    segments that can be nearest: to the bit the median of projecting on all of them, on loops
    near and far, closed and open, noisy, with repeated vertices and long straight sides."""
    from bulgekit.bulge.wall import _median_distance
    rng = np.random.default_rng(7)
    for k in range(1500):
        m = int(rng.integers(2, 300))
        th = np.sort(rng.uniform(0, 2 * np.pi, m))
        r = rng.uniform(2, 80)
        poly = np.c_[r * np.cos(th), r * np.sin(th)] + rng.normal(0, [0, 0.01, 1][k % 3], (m, 2))
        if k % 4 == 0:
            poly = np.vstack([poly, poly[:1]])                  # closed
        if k % 5 == 0:
            poly = np.round(poly, 0)                            # repeats, zero-length segments
        if k % 11 == 0:
            poly = np.array([[-r, -r], [r, -r], [r, r], [-r, r], [-r, -r]])   # long sides
        n = int(rng.integers(1, 150))
        near = poly[rng.integers(0, len(poly), n)] + rng.normal(0, 0.6, (n, 2))
        pts = near if k % 2 else rng.normal(0, r, (n, 2))
        want = _median_distance_every_segment(pts, poly)
        assert np.float64(_median_distance(pts, poly)).tobytes() == np.float64(want).tobytes(), k
