"""Preview PNGs: they are written, show the bumps, scale them by weight and flag misplaced ones."""
import math

import numpy as np
import pytest
from PIL import Image

from bulgekit.bulge.preview import preview_3d, preview_unrolled
from bulgekit.errors import InputError


def bump_pixels(path):
    """Pixels in the bump colours (orange to dark red, not the grey wall)."""
    a = np.asarray(Image.open(path).convert("RGB")).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    return int(((r - b > 60) & (r > 120)).sum())


def cross_pixels(path):
    a = np.asarray(Image.open(path).convert("RGB")).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    return int(((b - r > 80) & (b > 120)).sum())


def test_unrolled_writes_png_and_counts(tmp_path):
    f = tmp_path / "u.png"
    pts = [(10.0, 5.0, 255), (20.0, 5.0, 128), (200.0, 5.0, 255), (10.0, -1.0, 30)]
    r = preview_unrolled(pts, 125.6, 30.0, f, layer_height=0.5)
    assert r == {"inside": 2, "outside": 2}
    im = Image.open(f)
    assert im.format == "PNG" and im.size[0] >= 1200
    assert cross_pixels(f) > 0  # misplaced points are drawn, in blue


def test_unrolled_bump_size_follows_weight(tmp_path):
    # Same scene, one set of bumps heavier: more bump-coloured area.  The
    # colour bar is identical in both, so the difference is the bumps.
    light, heavy = tmp_path / "l.png", tmp_path / "h.png"
    grid = [(u, v) for u in range(10, 110, 10) for v in (5.0, 15.0, 25.0)]
    preview_unrolled([(u, v, 120) for u, v in grid], 125.0, 30.0, light)
    preview_unrolled([(u, v, 255) for u, v in grid], 125.0, 30.0, heavy)
    empty = tmp_path / "e.png"
    preview_unrolled([], 125.0, 30.0, empty)
    assert bump_pixels(heavy) > bump_pixels(light) > bump_pixels(empty)
    assert cross_pixels(light) == 0


def test_unrolled_bumps_land_where_they_belong(tmp_path):
    # A single bump near the left end vs the right end moves the red blob.
    left, right = tmp_path / "a.png", tmp_path / "b.png"
    preview_unrolled([(5.0, 15.0, 255)], 100.0, 30.0, left, bump_mm=3)
    preview_unrolled([(95.0, 15.0, 255)], 100.0, 30.0, right, bump_mm=3)

    def blob_x(p):
        a = np.asarray(Image.open(p).convert("RGB")).astype(int)
        w = a.shape[1]
        mask = (a[..., 0] - a[..., 2] > 60) & (a[..., 0] > 120)
        mask[:, int(w * 0.85):] = False  # ignore the colour bar
        ys, xs = np.nonzero(mask)
        return xs.mean() / w

    assert blob_x(left) < 0.25 and blob_x(right) > 0.55


def test_unrolled_errors(tmp_path):
    with pytest.raises(InputError, match="wall length and height"):
        preview_unrolled([], 0, 10, tmp_path / "x.png")
    with pytest.raises(InputError, match="rows of 3 numbers"):
        preview_unrolled([(1, 2)], 10, 10, tmp_path / "x.png")
    with pytest.raises(InputError, match="non-finite"):
        preview_unrolled([(1, float("nan"), 3)], 10, 10, tmp_path / "x.png")
    with pytest.raises(InputError, match="cannot write preview"):
        preview_unrolled([(1, 2, 3)], 10, 10, tmp_path / "no" / "such" / "dir.png")


def cylinder_walls(r=20.0, h=10.0, lh=0.2):
    t = np.linspace(0, 2 * np.pi, 120)
    xy = np.column_stack([r * np.cos(t), r * np.sin(t)])
    return [(z, xy) for z in np.arange(lh, h + 1e-9, lh)]


def test_3d_preview_counts_and_far_side(tmp_path):
    walls = cylinder_walls()
    bumps = [(20 * math.cos(a), 20 * math.sin(a), 5.0, 255) for a in np.linspace(-0.5, 0.5, 9)]
    bumps.append((-20.0, 0.0, 5.0, 255))  # opposite side
    f = tmp_path / "p.png"
    r = preview_3d(walls, bumps, f)
    assert r == {"layers_drawn": 50, "layers": 50, "bumps": 10, "far_side": 1, "layers_with_bumps": 1}
    assert Image.open(f).format == "PNG"
    assert bump_pixels(f) > 0
    # Thinning of many layers is reported, bumps are never thinned
    r2 = preview_3d(walls, bumps, tmp_path / "q.png", max_layers=20)
    assert r2["layers_drawn"] == 17 and r2["bumps"] == 10


def test_3d_preview_walls_only_and_errors(tmp_path):
    r = preview_3d(cylinder_walls(h=2.0), [], tmp_path / "w.png")
    assert r["bumps"] == 0 and r["far_side"] == 0
    assert bump_pixels(tmp_path / "w.png") == 0
    with pytest.raises(InputError, match="nothing to draw"):
        preview_3d([], [], tmp_path / "n.png")
    with pytest.raises(InputError, match="wall path 0 must be a"):
        preview_3d([5.0], [], tmp_path / "n.png")
    with pytest.raises(InputError, match="rows of 4 numbers"):
        preview_3d(cylinder_walls(h=1.0), [(1, 2, 3)], tmp_path / "n.png")


_DRAW_BOTH = """
import sys
if sys.argv[2] == "pyplot":
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot  # noqa: F401
import numpy as np
from bulgekit.bulge.preview import preview_3d, preview_unrolled
out = sys.argv[1]
preview_unrolled([(10.0, 5.0, 255), (20.0, 5.0, 128), (200.0, 5.0, 255)], 125.6, 30.0, out + "/u.png",
                 layer_height=0.5)
t = np.linspace(0, 2 * np.pi, 40)
ring = np.column_stack([20 * np.cos(t), 20 * np.sin(t)])
preview_3d([(0.2 * k, ring) for k in range(1, 30)], [(20.0, 0.0, 3.0, 255), (-20.0, 0.0, 4.0, 90)], out + "/d.png")
print("matplotlib.pyplot" in sys.modules)
"""


def test_previews_drawn_without_pyplot_same_bytes(tmp_path):
    """The previews are Figures on an Agg canvas, without pyplot's import (about 0.02 s of build's
    CPU); they are the bytes pyplot's figures gave, and pyplot loaded by the caller changes nothing."""
    import subprocess
    import sys
    got = {}
    for how in ("plain", "pyplot"):
        d = tmp_path / how
        d.mkdir()
        r = subprocess.run([sys.executable, "-c", _DRAW_BOTH, str(d), how], capture_output=True, text=True,
                           check=True)
        assert r.stdout.split()[-1] == ("True" if how == "pyplot" else "False")
        got[how] = ((d / "u.png").read_bytes(), (d / "d.png").read_bytes())
    assert got["plain"] == got["pyplot"]
