"""Corners and faces of the wall (wall.corner_positions, Wall.faces), drawings placed on a face
(--face/--align, placement keys face/align: bulge/faces.py), and the warnings: a drawing crossing a
corner, a drawing on the first layer. Sliced boxes: host/tests/data/README.md."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bulgekit.bulge import api, faces, preview
from bulgekit.bulge.strokes import on_face, text_strokes
from bulgekit.bulge.wall import corner_positions
from bulgekit.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
BOXES = ["prusa_box.gcode", "cura_box.gcode"]          # 30 x 20 x 15 mm
CYLINDERS = ["prusa_cyl.gcode", "cura_cyl.gcode"]      # 40 mm, 96 facets


@pytest.fixture(scope="module")
def models():
    return {n: api.walls(DATA / n) for n in BOXES + CYLINDERS + ["prusa_l.gcode"]}


def _loop(xy):
    xy = np.vstack([np.asarray(xy, float), np.asarray(xy[:1], float)])
    return xy, np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])


def _densified(poly, step, noise=0.0):
    pts = []
    for a, b in zip(poly, poly[1:] + poly[:1]):
        a, b = np.array(a, float), np.array(b, float)
        n = max(1, int(np.hypot(*(b - a)) / step))
        pts += [a + (b - a) * k / n for k in range(n)]
    pts = np.array(pts)
    if noise:
        pts[1:] += np.random.default_rng(1).normal(0, noise, pts[1:].shape)
    return _loop(pts)


def _circle(r, n):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return _loop(np.c_[r * np.cos(a), r * np.sin(a)])


BOX = [(0, 0), (30, 0), (30, 20), (0, 20)]


@pytest.mark.parametrize("name", BOXES)
def test_sliced_boxes_have_four_corners_on_every_layer(models, name):
    m = models[name]
    for w in m.walls:
        assert len(w.corners) == 4, w.z
        lengths = sorted(f.length for f in w.faces)
        # the outer wall runs half a line inside the 30 x 20 mm outline
        assert lengths[0] == pytest.approx(19.6, abs=0.3) and lengths[-1] == pytest.approx(29.6, abs=0.3)
    # face 1 holds u = 0, the middle of the front (-Y) face; face 2 is the right (+X) one
    w = m.walls[len(m.walls) // 2]
    f1, f2 = w.faces[:2]
    assert f1.u0 < 0 < f1.u1 and abs(f1.middle) < 0.3
    assert w.xy_of_u(f2.middle)[0, 0] > w.centroid[0] + 14


def test_sliced_l_shape_has_six_corners(models):
    for w in models["prusa_l.gcode"].walls:
        assert len(w.corners) == 6, w.z                # five convex, one concave
        assert len(w.faces) == 6


@pytest.mark.parametrize("name", CYLINDERS)
def test_sliced_cylinders_have_no_corners_and_one_face(models, name):
    for w in models[name].walls:
        assert len(w.corners) == 0
        (f,) = w.faces
        assert f.number == 1 and f.middle == pytest.approx(0) and f.length == pytest.approx(w.length)


@pytest.mark.parametrize("r,n", [(2, 64), (3, 32), (4.5, 32), (6, 64), (7, 200), (20, 96), (100, 400)])
def test_round_walls_have_no_corners_at_any_radius(r, n):
    assert len(corner_positions(*_circle(r, n))) == 0


@pytest.mark.parametrize("step,noise", [(None, 0), (0.1, 0), (0.05, 0.01)])
def test_box_corners_with_tiny_segments_and_noise(step, noise):
    xy, s = _loop(np.array(BOX, float)) if step is None else _densified(BOX, step, noise)
    c = corner_positions(xy, s)
    assert len(c) == 4
    assert np.allclose(c / s[-1], [0, 0.3, 0.5, 0.8], atol=0.005)


def test_rounded_and_d_shaped_walls():
    pts = []
    for cx, cy, a0 in [(29, 1, -90), (29, 19, 0), (1, 19, 90), (1, 1, 180)]:    # 1 mm radius
        pts += [(cx + math.cos(a), cy + math.sin(a)) for a in np.radians(np.linspace(a0, a0 + 90, 10))]
    assert len(corner_positions(*_loop(pts))) == 4
    # a flat side and a half circle: the two ends of the flat are corners, the round side none
    d = [(-10, 0), (10, 0)] + [(10 * math.cos(a), 10 * math.sin(a)) for a in np.linspace(0.05, np.pi - 0.05, 60)]
    xy, s = _loop(d)
    c = corner_positions(xy, s)
    near_start = np.minimum(c, s[-1] - c)
    assert len(c) == 2 and sorted(near_start) == pytest.approx([0, 20], abs=0.1)


def _placed(model, face, align, u=0.0, v=5.0, text="BOX", size=5.0):
    st = on_face(text_strokes(text, size, u0=u, v0=v), face, align, u)
    return api.build_map(model, st)


@pytest.mark.parametrize("name", BOXES)
@pytest.mark.parametrize("face", [1, 2, 3, 4])
def test_a_word_centred_on_a_face(models, name, face):
    m = models[name]
    res = _placed(m, face, "center")
    for p in res.points:
        f = m.walls[p.layer].faces[face - 1]
        u = (p.u - f.u0) % m.walls[p.layer].length + f.u0
        assert f.u0 < u < f.u1
    us = [(p.u - f.u0) % m.walls[p.layer].length + f.u0 for p in res.points
          for f in [m.walls[p.layer].faces[face - 1]]]
    mid = m.walls[res.points[0].layer].faces[face - 1].middle
    assert abs((min(us) + max(us)) / 2 - mid) < 1.0
    assert not res.warnings


def test_left_and_right_with_an_offset(models):
    m = models["prusa_box.gcode"]
    f = m.walls[20].faces[2]                          # face 3, 29.6 mm
    ink = [p[0] for s in text_strokes("HI", 5.0) for p in s.points]
    left = _placed(m, 3, "left", u=2.0, text="HI").strokes
    right = _placed(m, 3, "right", u=-1.5, text="HI").strokes
    assert min(p[0] for s in left for p in s.points) == pytest.approx(f.u0 + 2.0, abs=0.05)
    assert max(p[0] for s in right for p in s.points) == pytest.approx(f.u1 - 1.5, abs=0.05)
    # the drawing keeps its shape: only moved along u
    got = [p[0] for s in left for p in s.points]
    assert np.allclose(np.array(got) - got[0], np.array(ink) - ink[0])


def test_the_face_is_the_one_at_the_drawing_middle_height(models):
    m = models["prusa_box.gcode"]
    w = faces.layer_near(m, 5.0 + 2.5)
    res = _placed(m, 2, "center")
    us = [p[0] for s in res.strokes for p in s.points]
    assert (min(us) + max(us)) / 2 == pytest.approx(w.faces[1].middle, abs=1e-9)


def test_a_face_the_wall_lacks_is_an_error(models):
    with pytest.raises(faces.FaceError, match=r"the text 'BOX': face 5, but the wall .* has 4 face\(s\), 1..4"):
        _placed(models["prusa_box.gcode"], 5, "center")
    with pytest.raises(faces.FaceError, match=r"1 face\(s\), 1..1 \(no corners: a round wall\)"):
        _placed(models["prusa_cyl.gcode"], 2, None, v=2.0)
    # a round wall's one face is centred on u = 0
    res = _placed(models["prusa_cyl.gcode"], 1, None, v=2.0)
    us = [p[0] for s in res.strokes for p in s.points]
    assert (min(us) + max(us)) / 2 == pytest.approx(0, abs=1e-9)


def test_align_without_a_face_and_bad_values_are_refused():
    st = text_strokes("A", 5)
    with pytest.raises(Exception, match="align needs a face"):
        on_face(st, None, "left")
    with pytest.raises(Exception, match="align must be one of left, center, right"):
        on_face(st, 1, "middle")
    assert on_face(st, None, None) is st
    from bulgekit.bulge.strokes import ALIGNS
    from bulgekit.cli._util import ALIGNS as CLI_ALIGNS
    assert CLI_ALIGNS == ALIGNS


def test_corner_crossing_warning(models):
    m = models["prusa_box.gcode"]
    res = api.build_map(m, text_strokes("HELLO", 6.0, u0=5, v0=3))
    (w,) = res.warnings
    assert w.startswith("the text 'HELLO' crosses the corner between faces 1 and 2 at u 14.")
    assert "--face N" in w
    assert not api.build_map(models["prusa_cyl.gcode"], text_strokes("HELLO", 6.0, u0=5, v0=3)).warnings
    # the L's concave corner too
    ml = models["prusa_l.gcode"]
    c = ml.walls[20].faces[3].u0                      # the corner between faces 3 and 4
    res = api.build_map(ml, text_strokes("HI", 5.0, u0=c - 3, v0=3))
    assert any("corner between faces 3 and 4" in x for x in res.warnings)


def test_first_layer_message(models):
    m = models["prusa_box.gcode"]
    res = api.build_map(m, text_strokes("HI", 5.0, u0=-3, v0=0.1))
    assert res.warnings == ["the text 'HI' is on the first layer (z 0.30 mm): bumps there are pressed "
                            "flat on the bed; start it 1 mm up or more (V of --at U,V)"]
    assert not api.build_map(m, text_strokes("HI", 5.0, u0=-3, v0=1.0)).warnings


def test_build_cli_face_warnings_and_default_at(tmp_path):
    box = str(DATA / "prusa_box.gcode")
    r = CliRunner().invoke(main, ["build", box, "--text", "HELLO", "--at", "5,3", "-o", str(tmp_path / "a"),
                                  "--no-preview", "-q"])
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert len(lines) == 1 and "the text 'HELLO' crosses the corner between faces 1 and 2" in lines[0]
    r = CliRunner().invoke(main, ["build", box, "--text", "HELLO", "--face", "3", "-o", str(tmp_path / "b"),
                                  "--no-preview", "-q"])
    assert r.exit_code == 0 and "warning" not in r.stderr, r.output
    # the default --at is 0,1: above the first layers, no message
    r = CliRunner().invoke(main, ["build", box, "--text", "HI", "-o", str(tmp_path / "c"), "--no-preview", "-q"])
    assert r.exit_code == 0 and r.stderr == "", r.output
    r = CliRunner().invoke(main, ["build", box, "--text", "HI", "--at", "-3,0", "-o", str(tmp_path / "d"),
                                  "--no-preview", "-q"])
    assert "warning: the text 'HI' is on the first layer (z 0.30 mm)" in r.stderr
    r = CliRunner().invoke(main, ["build", box, "--text", "HI", "--face", "9", "-o", str(tmp_path / "e"), "-q"])
    assert r.exit_code == 1 and "face 9, but the wall" in r.output and not (tmp_path / "e").exists()


def test_placement_face_keys_give_the_cli_strokes(tmp_path, models):
    from bulgekit.bulge.placement import load_placement
    p = tmp_path / "p.toml"
    p.write_text('[[text]]\ntext = "BOX"\nsize = 5\nat = [1.5, 5]\nface = 2\nalign = "right"\n')
    pl = load_placement(p)
    m = models["prusa_box.gcode"]
    a = api.build_map(m, pl.strokes)
    b = _placed(m, 2, "right", u=1.5)
    assert a.map_bytes == b.map_bytes
    p.write_text('[[text]]\ntext = "BOX"\nalign = "left"\n')
    with pytest.raises(Exception, match=r"p.toml: text\[0\]: align needs a face"):
        load_placement(p)
    p.write_text('[[text]]\ntext = "HELLO"\nat = [5, 3]\n')
    (w,) = api.build_map(m, load_placement(p).strokes).warnings
    assert w.startswith(f"{p}: text[0]: the text 'HELLO' crosses the corner") and "(face = N" in w


def test_preview_marks_corners_and_faces(models):
    m = models["prusa_box.gcode"]
    marks = preview.wall_marks(m)
    assert len(marks["corners"]) == 4 * len(m.walls)
    # one run of layers: faces 1 (at both ends: it holds u = 0), 2, 3, 4
    assert sorted(n for _, _, n in marks["faces"]) == [1, 1, 2, 3, 4]
    assert preview.wall_marks(models["prusa_cyl.gcode"])["corners"] == []


def test_post_process_places_on_a_face_and_warns(tmp_path):
    import shutil
    g = tmp_path / "box.gcode"
    shutil.copy(DATA / "prusa_box.gcode", g)
    p = tmp_path / "p.toml"
    p.write_text('[[text]]\ntext = "BOX"\nsize = 5\nat = [0, 5]\nface = 2\n\n'
                 '[[text]]\ntext = "HI"\nsize = 5\nat = [12, 0.1]\n')
    r = CliRunner().invoke(main, ["post-process", "--placement", str(p), str(g)])
    assert r.exit_code == 0, r.output
    assert r.stderr.splitlines() == [
        f"bulgekit: warning: {p}: text[1]: the text 'HI' crosses the corner between faces 1 and 2 at u 14.8 mm "
        "(z 0.30-5.10 mm): it bends round it (face = N puts it on one face)",
        f"bulgekit: warning: {p}: text[1]: the text 'HI' is on the first layer (z 0.30 mm): bumps there are "
        "pressed flat on the bed; start it 1 mm up or more (V of at = [U, V])"]
    assert "M721" in g.read_text()


def test_preview_cli_takes_a_face(tmp_path):
    box = str(DATA / "prusa_box.gcode")
    r = CliRunner().invoke(main, ["preview", box, "--text", "HELLO", "--face", "3", "-o", str(tmp_path / "p.png")])
    assert r.exit_code == 0 and r.stderr == "" and (tmp_path / "p.png").is_file(), r.output
    r = CliRunner().invoke(main, ["preview", box, "--text", "HELLO", "--at", "5,3", "-o", str(tmp_path / "q.png")])
    assert "warning: the text 'HELLO' crosses the corner between faces 1 and 2" in r.stderr
    r = CliRunner().invoke(main, ["preview", "--text", "HI", "--face", "2", "--wall-length", "50", "--height", "10",
                                  "-o", str(tmp_path / "x.png")])
    assert r.exit_code == 2 and "--face and --align need GCODE" in r.output
