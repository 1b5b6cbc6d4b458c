"""Stroke loaders: SVG units and placement, flattening, text, JSON, images, errors."""
import json
import math
from pathlib import Path

import pytest

from bulgekit.errors import InputError
from bulgekit.bulge.strokes import (Stroke, load_json, load_svg, resample, sample_strokes, save_json,
                                    summarize, text_strokes, image_dots, transform)

DATA = Path(__file__).parents[1] / "data_inputs"


def by_source(strokes, fragment):
    found = [s for s in strokes if fragment in s.source]
    assert found, f"no stroke from {fragment}"
    return found


def close(a, b, tol=1e-6):
    return all(abs(x - y) <= tol for x, y in zip(a, b))


# ---------------------------------------------------------------- model

def test_stroke_rejects_empty_and_bad_weight():
    with pytest.raises(InputError, match="no points"):
        Stroke((), 10, "x")
    with pytest.raises(InputError, match="weight 256"):
        Stroke(((0.0, 0.0),), 256, "x")
    assert Stroke(((1.0, 2.0),)).is_dot


def test_resample_spacing_and_ends():
    s = Stroke(((0.0, 0.0), (10.0, 0.0), (10.0, 5.0)))
    pts = resample(s, 1.0)
    assert len(pts) == 16  # 15 mm long → 15 gaps
    assert pts[0] == (0.0, 0.0) and close(pts[-1], (10.0, 5.0))
    gaps = [math.dist(a, b) for a, b in zip(pts, pts[1:])]
    # gaps across the corner are chords, so at most the pitch
    assert max(gaps) <= 1.0 + 1e-9 and min(gaps) > 0.7
    assert resample(Stroke(((3.0, 4.0),)), 1.0) == [(3.0, 4.0)]
    assert len(resample(s, 100.0)) == 2
    with pytest.raises(InputError):
        resample(s, 0)


def test_sample_strokes_carries_weight():
    pts = sample_strokes([Stroke(((0.0, 0.0), (2.0, 0.0)), 7), Stroke(((5.0, 5.0),), 9)], 1.0)
    assert pts == [(0.0, 0.0, 7), (1.0, 0.0, 7), (2.0, 0.0, 7), (5.0, 5.0, 9)]


def test_transform_mirror_scale_offset():
    s = [Stroke(((0.0, 0.0), (4.0, 1.0))), Stroke(((1.0, 2.0),))]
    t = transform(s, offset=(10.0, 20.0), scale=2.0, mirror_u=True)
    # mirrored about u in [0, 4]: 0→4, 4→0, 1→3; then ×2 and shifted
    assert t[0].points == ((18.0, 20.0), (10.0, 22.0))
    assert t[1].points == ((16.0, 24.0),)


# ---------------------------------------------------------------- SVG

def test_svg_mm_units_viewbox_and_y_flip():
    strokes = load_svg(DATA / "units_mm.svg")
    top = by_source(strokes, "id='top'")[0]
    # 200 user units on a 100 mm page; y = 0 is the top of a 50 mm page
    assert close(top.points[0], (0.0, 50.0)) and close(top.points[1], (100.0, 50.0))
    zig = by_source(strokes, "id='zig'")[0]
    # translate(20,80) → (20,80),(30,70),(40,80) user units → mm, y flipped
    assert [tuple(round(c, 6) for c in p) for p in zig.points] == [(10.0, 10.0), (15.0, 15.0), (20.0, 10.0)]
    assert zig.weight == 128  # inherited from the group
    box = by_source(strokes, "id='box'")[0]
    assert box.weight == 64
    assert len(box.points) == 5 and box.points[0] == box.points[-1]  # closed
    tri = by_source(strokes, "id='tri'")[0]
    assert tri.points[0] == tri.points[-1] and len(tri.points) == 4
    # source names file and line
    assert top.source.startswith(str(DATA / "units_mm.svg") + ":4 ")
    assert not any("unused" in s.source for s in strokes)


def test_svg_small_circle_is_dot_at_centre():
    strokes = load_svg(DATA / "units_mm.svg")
    dot = by_source(strokes, "id='dot'")[0]
    assert dot.is_dot and close(dot.points[0], (50.0, 25.0))
    # with a smaller dot radius the 0.5 mm circle is drawn as a ring
    ring = by_source(load_svg(DATA / "units_mm.svg", dot_radius_mm=0.2), "id='dot'")[0]
    assert len(ring.points) > 8
    assert all(abs(math.dist(p, (50.0, 25.0)) - 0.5) < 0.01 for p in ring.points)


def test_svg_px_units_96_dpi():
    strokes = load_svg(DATA / "px_units.svg")
    # 96 px = 1 in = 25.4 mm; page 48 px = 12.7 mm high (svgelements rounds mm/px: 5e-7 relative)
    assert close(strokes[0].points[0], (0.0, 0.0), 5e-5) and close(strokes[0].points[1], (25.4, 0.0), 5e-5)
    assert close(strokes[1].points[0], (12.7, 12.7), 5e-5) and close(strokes[1].points[1], (12.7, 6.35), 5e-5)


def test_svg_without_page_height_puts_lowest_point_at_zero():
    s = load_svg(DATA / "no_page.svg")[0]
    vs = [p[1] for p in s.points]
    assert min(vs) == pytest.approx(0.0, abs=1e-9)
    # y = 10 px is the top → v = 20 px in mm
    assert max(vs) == pytest.approx(20 * 25.4 / 96, rel=1e-5)


@pytest.mark.parametrize("tol", [0.2, 0.05, 0.01])
def test_svg_flattening_stays_within_tolerance(tol):
    strokes = load_svg(DATA / "curves.svg", tolerance_mm=tol)
    ring = by_source(strokes, "id='ring'")[0]
    centre = (30.0, 30.0)
    assert ring.points[0] == ring.points[-1]
    for a, b in zip(ring.points, ring.points[1:]):
        assert abs(math.dist(a, centre) - 20.0) < 1e-6
        mid = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
        assert 20.0 - math.dist(mid, centre) <= tol + 1e-9  # sagitta
    # S-curve: every true curve point is within tol of the polyline
    s = by_source(strokes, "id='s-curve'")[0]

    def bez(t):
        p = [(5, 55), (25, 35), (35, 75), (55, 55)]
        x = sum(c[0] * w for c, w in zip(p, [(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t * t * (1 - t), t ** 3]))
        y = sum(c[1] * w for c, w in zip(p, [(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t * t * (1 - t), t ** 3]))
        return (x, 60 - y)

    def seg_dist(p, a, b):
        ax, ay, bx, by = *a, *b
        dx, dy = bx - ax, by - ay
        t = max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / (dx * dx + dy * dy)))
        return math.dist(p, (ax + t * dx, ay + t * dy))

    for i in range(201):
        q = bez(i / 200)
        assert min(seg_dist(q, a, b) for a, b in zip(s.points, s.points[1:])) <= tol + 1e-6
    assert len(s.points) > 3


def test_svg_finer_tolerance_gives_more_points():
    coarse = by_source(load_svg(DATA / "curves.svg", tolerance_mm=0.5), "ring")[0]
    fine = by_source(load_svg(DATA / "curves.svg", tolerance_mm=0.01), "ring")[0]
    assert len(fine.points) > 3 * len(coarse.points)


def test_svg_arc_compact_flags_and_dots_from_moves():
    strokes = load_svg(DATA / "curves.svg")
    arc = by_source(strokes, "id='arc'")[0]
    # half circle radius 5 over the top of (15, 10) user units → v = 50 .. 55
    assert close(arc.points[0], (10.0, 50.0)) and close(arc.points[-1], (20.0, 50.0))
    assert max(p[1] for p in arc.points) == pytest.approx(55.0, abs=0.05)
    small = by_source(strokes, "id='small'")[0]
    assert small.is_dot and close(small.points[0], (50.0, 50.0))
    dots = by_source(strokes, "id='dots'")
    assert [d.points for d in dots] == [((2.0, 58.0),), ((4.0, 58.0),)]


def test_svg_offset_scale_mirror():
    base = by_source(load_svg(DATA / "units_mm.svg"), "id='top'")[0]
    placed = by_source(load_svg(DATA / "units_mm.svg", offset=(5.0, 1.0), scale=0.5), "id='top'")[0]
    assert close(placed.points[0], (base.points[0][0] * 0.5 + 5, base.points[0][1] * 0.5 + 1))
    mir = load_svg(DATA / "units_mm.svg", mirror=True)
    zig = by_source(mir, "id='zig'")[0]
    # extent of all strokes is u 0..100, so u → 100 - u
    assert close(zig.points[0], (90.0, 10.0)) and close(zig.points[1], (85.0, 15.0))


def test_svg_broken_xml_names_file_and_line():
    with pytest.raises(InputError) as e:
        load_svg(DATA / "broken.svg")
    msg = str(e.value)
    assert "broken.svg:4:" in msg and "line 4" in msg


def test_svg_bad_path_data_names_element():
    with pytest.raises(InputError) as e:
        load_svg(DATA / "bad_path.svg")
    msg = str(e.value)
    assert "bad_path.svg:3 <path id='typo'>" in msg and "'x 5'" in msg


def test_svg_without_strokes():
    with pytest.raises(InputError, match=r"no_strokes\.svg: no usable strokes"):
        load_svg(DATA / "no_strokes.svg")


def test_svg_text_element_is_error_or_warned_skip():
    with pytest.raises(InputError, match=r"with_text\.svg:3 <text id='label'>"):
        load_svg(DATA / "with_text.svg")
    with pytest.warns(UserWarning, match="skipped"):
        strokes = load_svg(DATA / "with_text.svg", skip_unsupported=True)
    assert len(strokes) == 1


def test_svg_missing_file_and_bad_options(tmp_path):
    with pytest.raises(InputError, match="nope.svg: cannot read SVG"):
        load_svg(tmp_path / "nope.svg")
    with pytest.raises(InputError, match="tolerance"):
        load_svg(DATA / "units_mm.svg", tolerance_mm=0)


@pytest.mark.parametrize("snippet,expect", [
    ('<path d="L 1 1"/>', "must start with M"),
    ('<path d="M 0 0 C 1 1 2 2"/>', "command C needs 6 numbers"),
    ('<path d="M 0 0 A 5 5 0 2 1 3 3"/>', "command A needs 7 numbers"),
    ('<polyline points="0,0 1"/>', "odd number of coordinates"),
    ('<circle cx="1" cy="1" r="-3"/>', "negative radius"),
    ('<line x1="0" y1="0" x2="1" y2="1" data-bk-weight="300"/>', "weight must be an integer 0..255"),
    ('<image href="x.png" width="3" height="3"/>', "<image> cannot be drawn"),
])
def test_svg_element_errors(tmp_path, snippet, expect):
    f = tmp_path / "e.svg"
    f.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="9mm" height="9mm">\n'
                 '<line x1="0" y1="0" x2="1" y2="1"/>\n' + snippet + "\n</svg>\n")
    with pytest.raises(InputError) as e:
        load_svg(f)
    assert f"{f}:3 <" in str(e.value) and expect in str(e.value)


def test_svg_non_svg_root(tmp_path):
    f = tmp_path / "x.svg"
    f.write_text("<html><body/></html>")
    with pytest.raises(InputError, match="not <svg>"):
        load_svg(f)


# ---------------------------------------------------------------- text

def test_text_cap_height_and_baseline():
    strokes = text_strokes("H", 10.0, u0=5.0, v0=20.0)
    vs = [p[1] for s in strokes for p in s.points]
    assert min(vs) == pytest.approx(20.0) and max(vs) == pytest.approx(30.0)
    assert all(u >= 5.0 for s in strokes for u, _ in s.points)
    assert len(strokes) == 3  # two stems and the bar


def test_text_size_and_spacing_scale_width():
    w10 = summarize(text_strokes("HIH", 10.0))["u_range"]
    w20 = summarize(text_strokes("HIH", 20.0))["u_range"]
    assert (w20[1] - w20[0]) == pytest.approx(2 * (w10[1] - w10[0]))
    spaced = summarize(text_strokes("HIH", 10.0, spacing=3.0))["u_range"]
    assert (spaced[1] - spaced[0]) == pytest.approx(w10[1] - w10[0] + 6.0)


def test_text_mirror_flips_left_right():
    plain = text_strokes("L", 10.0)
    mirrored = text_strokes("L", 10.0, mirror=True)
    # The L's foot points right; mirrored it points left: foot end u < stem u
    foot = lambda ss: [s for s in ss if abs(s.points[0][1] - s.points[-1][1]) < 1e-9][0]
    stem_u = lambda ss: [s for s in ss if abs(s.points[0][0] - s.points[-1][0]) < 1e-9][0].points[0][0]
    fp, fm = foot(plain), foot(mirrored)
    assert max(u for u, _ in fp.points) > stem_u(plain)
    assert min(u for u, _ in fm.points) < stem_u(mirrored)


def test_text_multiline_stacks_upward_from_last_baseline():
    strokes = text_strokes("I\nI", 10.0, v0=0.0, line_spacing=2.0)
    lines = sorted({round(min(p[1] for p in s.points), 6) for s in strokes})
    assert lines == [0.0, 20.0]
    assert any("line 1" in s.source and min(p[1] for p in s.points) == pytest.approx(20.0) for s in strokes)


def test_text_errors():
    with pytest.raises(InputError, match="empty text"):
        text_strokes("   ", 10)
    with pytest.raises(InputError, match="empty text"):
        text_strokes("", 10)
    with pytest.raises(InputError, match=r"character '€' \(position 3\)"):
        text_strokes("ab€", 10)
    with pytest.raises(InputError, match="unknown font 'comic'"):
        text_strokes("a", 10, font="comic")
    with pytest.raises(InputError, match="size"):
        text_strokes("a", 0)


def test_text_other_font_differs():
    a = text_strokes("R", 10.0, font="futural")
    b = text_strokes("R", 10.0, font="scripts")
    assert [s.points for s in a] != [s.points for s in b]


# ---------------------------------------------------------------- JSON

def test_json_load_defaults_and_sources():
    s = load_json(DATA / "strokes.json")
    assert [x.weight for x in s] == [200, 255, 0]
    assert s[1].is_dot and s[1].points == ((20.0, 10.0),)
    assert s[2].source == "hand drawn" and s[0].source.endswith("strokes.json: stroke 0")


def test_json_roundtrip(tmp_path):
    orig = text_strokes("Ab", 7.0, u0=3.0, v0=2.0) + [Stroke(((1.5, 2.5),), 17, "dot")]
    f = tmp_path / "s.json"
    save_json(orig, f)
    back = load_json(f)
    assert len(back) == len(orig)
    for a, b in zip(orig, back):
        assert a.weight == b.weight and a.source == b.source
        assert all(close(p, q, 1e-6) for p, q in zip(a.points, b.points))


def test_json_missing_points_names_index():
    with pytest.raises(InputError, match=r'missing_points\.json: stroke 1: missing key "points"'):
        load_json(DATA / "missing_points.json")


@pytest.mark.parametrize("doc,expect", [
    ({"lines": []}, 'object with a "strokes" list'),
    ({"strokes": {}}, '"strokes" must be a list'),
    ({"strokes": []}, "no strokes"),
    ({"strokes": [{"points": []}]}, "stroke 0: \"points\" must be a non-empty list"),
    ({"strokes": [{"points": [[0, 0]]}, {"points": [[0, 0], [1]]}]}, r"stroke 1 point 1: expected \[u, v\]"),
    ({"strokes": [{"points": [[0, "a"]]}]}, "stroke 0 point 0"),
    ({"strokes": [{"points": [[0, 1]], "weight": 256}]}, "stroke 0: weight must be an integer 0..255"),
    ({"strokes": [{"points": [[0, 1]], "weight": 1.5}]}, "stroke 0: weight"),
    ({"strokes": [{"points": [[0, 1]], "wieght": 1}]}, "unknown key"),
])
def test_json_errors(tmp_path, doc, expect):
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=expect) as e:
        load_json(f)
    assert str(f) in str(e.value)


def test_json_syntax_error_line(tmp_path):
    f = tmp_path / "syn.json"
    f.write_text('{"strokes": [\n  {"points": [[0, 0]]},\n  {"points": [[1, 1]]\n]}\n')
    with pytest.raises(InputError, match=r"syn\.json:4: invalid JSON"):
        load_json(f)


# ---------------------------------------------------------------- images

def test_image_dots_grid_and_weights():
    # 8 x 4 px picture, pitch 1 mm, 8 mm wide → one cell per pixel
    dots = image_dots(DATA / "gradient_8x4.png", width_mm=8.0, u0=10.0, v0=5.0, pitch_mm=1.0, threshold=0.1)
    assert all(d.is_dot for d in dots)
    by_pos = {(round(d.points[0][0], 6), round(d.points[0][1], 6)): d.weight for d in dots}
    # column x has darkness 32x/255; threshold 0.1 drops x = 0 (except the black pixel)
    assert len(dots) == 7 * 4 + 1
    # top-left black pixel: row 0 is the top → highest v
    assert by_pos[(10.5, 8.5)] == 255
    assert (10.5, 7.5) not in by_pos  # white
    for x in range(1, 8):
        assert by_pos[(10.5 + x, 5.5)] == round(32 * x / 255 * 255)
    assert max(v for _, v in by_pos) == 8.5 and min(v for _, v in by_pos) == 5.5


def test_image_dots_coarser_pitch_averages_cells():
    dots = image_dots(DATA / "gradient_8x4.png", width_mm=8.0, pitch_mm=2.0, threshold=0.0)
    assert len(dots) == 4 * 2
    w = sorted({d.weight for d in dots if d.points[0][1] < 2})
    # bottom row cells average columns (0,1), (2,3), ...: darkness 16, 80, 144, 208
    assert w == [16, 80, 144, 208]


def test_image_invert_and_mirror():
    plain = image_dots(DATA / "gradient_8x4.png", width_mm=8.0, pitch_mm=1.0, threshold=0.5)
    inv = image_dots(DATA / "gradient_8x4.png", width_mm=8.0, pitch_mm=1.0, threshold=0.5, invert=True)
    assert len(plain) + len(inv) == 32  # nothing sits exactly at 0.5
    mir = image_dots(DATA / "gradient_8x4.png", width_mm=8.0, pitch_mm=1.0, threshold=0.5, mirror=True)
    assert sorted((8 - d.points[0][0], d.points[0][1], d.weight) for d in mir) == \
        sorted((d.points[0][0], d.points[0][1], d.weight) for d in plain)


def test_image_transparency_counts_as_white(tmp_path):
    from PIL import Image
    im = Image.new("RGBA", (2, 1), (0, 0, 0, 0))
    im.putpixel((1, 0), (0, 0, 0, 255))
    f = tmp_path / "a.png"
    im.save(f)
    dots = image_dots(f, width_mm=2.0, pitch_mm=1.0)
    assert [(d.points[0], d.weight) for d in dots] == [((1.5, 0.5), 255)]


def test_image_errors(tmp_path):
    with pytest.raises(InputError, match=r"not_an_image\.png: cannot read image"):
        image_dots(DATA / "not_an_image.png", width_mm=10)
    with pytest.raises(InputError, match=r"gone\.png: image file not found"):
        image_dots(tmp_path / "gone.png", width_mm=10)
    with pytest.raises(InputError, match="threshold"):
        image_dots(DATA / "gradient_8x4.png", width_mm=10, threshold=2)


def test_non_finite_coordinates_are_refused(tmp_path):
    from bulgekit.errors import InputError
    from bulgekit.bulge.strokes import Stroke, load_svg
    with pytest.raises(InputError, match="not a finite number"):
        Stroke(((0.0, 0.0), (float("inf"), 1.0)), source="x.json stroke 0")
    svg = tmp_path / "inf.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="50mm" height="20mm" '
                   'viewBox="0 0 50 20">\n  <path id="big" d="M 1 1 L 1e400 5"/>\n</svg>\n')
    with pytest.raises(InputError, match=r"inf\.svg.*big|big.*inf\.svg|not a finite"):
        load_svg(str(svg))


@pytest.mark.parametrize("transform, message", [
    ("skewX(foo)", "skewX(foo): not all arguments are numbers"),
    ("matrix(1 2)", "matrix() takes 6 numbers, got 2"),
    ("rotate()", "rotate() takes 1 or 3 numbers, got 0"),
    ("frob(1)", "unknown transform frob()"),
])
def test_bad_transforms_name_the_element(tmp_path, transform, message):
    from bulgekit.errors import InputError
    from bulgekit.bulge.strokes import load_svg
    svg = tmp_path / "t.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="50mm" height="20mm" viewBox="0 0 50 20">\n'
                   f'<g id="grp" transform="{transform}">\n<path d="M 1 1 L 10 5"/></g>\n</svg>\n')
    with pytest.raises(InputError) as e:
        load_svg(str(svg))
    assert f"t.svg:2 <g id='grp'>: {message}" in str(e.value)


def test_zero_viewbox_is_named(tmp_path):
    from bulgekit.errors import InputError
    from bulgekit.bulge.strokes import load_svg
    svg = tmp_path / "v.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="50mm" height="20mm" viewBox="0 0 0 10">\n'
                   '<path d="M 1 1 L 10 5"/>\n</svg>\n')
    with pytest.raises(InputError, match="viewBox '0 0 0 10' has a zero or negative width"):
        load_svg(str(svg))


def test_valid_transform_list_still_loads(tmp_path):
    from bulgekit.bulge.strokes import load_svg
    svg = tmp_path / "ok.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="50mm" height="20mm" viewBox="0 0 50 20">\n'
                   '<g transform="translate(3,4) scale(2) rotate(0 1 1) skewX(0)">\n'
                   '<path d="M 1 1 L 10 5"/></g>\n</svg>\n')
    assert len(load_svg(str(svg))) == 1
