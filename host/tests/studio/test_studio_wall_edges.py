"""The studio's wall tab as a new user found it (issue 26): new items go to free space, choices
are not cut off, exports are named after the G-code, and a design made on one G-code is laid on
another only when the user says so. Browser parts use Debian's chromium (test_studio_browser.py)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from bulgekit.bulge.mapformat import LAYER_POINTS_MAX
from studio_util import GCODE, call, open_gcode, start, wait_job
from test_studio_browser import browser, open_sample, page_for, settled  # noqa: F401 (fixture)

SVG = """<svg xmlns="http://www.w3.org/2000/svg" width="16mm" height="8mm" viewBox="0 0 16 8">
<path d="M 1 1 L 15 7 M 1 7 L 15 1" fill="none" stroke="black"/></svg>"""


@pytest.fixture
def studio(tmp_path):
    run = start(tmp_path / "work")
    yield run
    run.stop()


def boxes(pg):
    """Each item's box (u0, v0, u1, v1) from the strokes of the last preview."""
    return pg.evaluate("""() => { const s = window.studio.S; return s.items.map((it) => {
        const b = [1e9, 1e9, -1e9, -1e9];
        for (const f of s.preview.items[it.id].strokes) for (let i = 0; i < f.length; i += 2) {
          b[0] = Math.min(b[0], f[i]); b[2] = Math.max(b[2], f[i]);
          b[1] = Math.min(b[1], f[i + 1]); b[3] = Math.max(b[3], f[i + 1]); }
        return b; }); }""")


def apart(a, b):
    return a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1]


def test_new_items_go_to_free_space(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    for k in range(4):                                   # four texts, one after the other
        pg.click("#add-text")
        pg.wait_for_function(f"() => window.studio.S.items.length === {k + 1}")
        settled(pg)
    svg = tmp_path / "mark.svg"
    svg.write_text(SVG)
    pg.set_input_files("#add-file", str(svg))
    pg.wait_for_function("() => window.studio.S.items.length === 5")
    settled(pg)
    b = boxes(pg)
    lo, hi = pg.evaluate("() => window.studio.S.gcode.walls.v_range")
    length = pg.evaluate("() => window.studio.S.gcode.length_max")
    for i in range(len(b)):
        # (a letter's strokes may start a few µm before its baseline's start)
        assert lo <= b[i][1] and b[i][3] <= hi and -0.01 <= b[i][0] and b[i][2] <= length, b[i]
        for j in range(i):
            assert apart(b[i], b[j]), (i, j, b)
    # the first sits in the middle of the view (the whole wall: a cylinder has no corners, so no
    # face; issue 38), the next ones on its row where it is free, a word space apart
    assert (b[0][0] + b[0][2]) / 2 == pytest.approx(length / 2, abs=0.5)
    assert pg.evaluate("() => window.studio.S.items[0].at")[1] == pytest.approx(7.05, abs=0.01)
    assert "face" not in pg.evaluate("() => window.studio.S.items[0]")
    assert b[1][1] == pytest.approx(b[0][1], abs=0.01)
    assert b[1][2] + 3 <= b[0][0] or b[1][0] >= b[0][2] + 3
    # no field is left over in the design the server gets, nor in Undo's states
    assert "placing" not in str(pg.evaluate("() => window.studio.design()"))
    assert "centreOn" not in str(pg.evaluate("() => window.studio.design()"))
    assert not errors, errors


def test_a_full_wall_says_so(browser, studio):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.click("#add-text")
    pg.fill("#item-form input[name=v]", "0.5")
    pg.fill("#item-form input[name=size]", "19")          # one text filling the wall's height ...
    pg.fill("#item-form textarea[name=text]", "WWWWW")    # ... and most of its length
    pg.fill("#item-form input[name=u]", "5")
    settled(pg)
    assert pg.locator("#items li.overlap").count() == 0
    pg.click("#add-text")
    pg.wait_for_function("() => window.studio.S.items.length === 2")
    settled(pg)
    # it could go nowhere free: both items say which one they overlap
    warn = pg.locator("#items li.overlap").all_inner_texts()
    assert warn == ["overlaps Text “TEXT”: their bumps mix", "overlaps Text “WWWWW”: their bumps mix"]
    # moved apart, the warnings go
    pg.fill("#item-form textarea[name=text]", "T")
    pg.fill("#item-form input[name=u]", "115")
    settled(pg)
    assert pg.locator("#items li.overlap").count() == 0
    assert not errors, errors


def layer_points(pg):
    """Points per layer (z) of the last preview, and those on layers left out of the map."""
    pts = pg.evaluate("() => window.studio.S.preview.points")
    per = {}
    for q in pts:
        per[q[4]] = per.get(q[4], 0) + 1
    return per, [q for q in pts if len(q) > 8 and q[8]]


def test_added_texts_keep_every_layer_within_the_limit(browser, studio):
    # a default text puts 17 points on one layer (its top bars): a fourth beside three on
    # its row would make 68, over the firmware's 64
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    for k in range(6):
        pg.click("#add-text")
        pg.wait_for_function(f"() => window.studio.S.items.length === {k + 1}")
        settled(pg)
    per, left_out = layer_points(pg)
    assert per, pg.locator("#global-msgs").inner_text()          # bumps at all
    assert max(per.values()) <= LAYER_POINTS_MAX and not left_out, per
    assert pg.locator("#global-msgs li.error").all_inner_texts() == []
    assert "bumps on" in pg.inner_text("#summary")
    # every item keeps its strokes and its bumps
    n = pg.evaluate("""() => window.studio.S.items.map((it) => [
        window.studio.S.preview.items[it.id].strokes.length,
        window.studio.S.preview.points.filter((q) => q[6].includes(it.id)).length])""")
    assert all(st > 0 and b > 0 for st, b in n), n
    info = pg.locator("#items > li > .info").all_inner_texts()
    assert len(info) == 6 and all(t.endswith(" bumps") and int(t.split()[0]) > 0 for t in info), info
    # the fourth and fifth went to the next row up (a layer higher), beside the first three
    b = boxes(pg)
    assert [round(x[1], 2) for x in b[:5]] == [7.05, 7.05, 7.05, 7.35, 7.35]
    for i in range(5):
        for j in range(i):
            assert apart(b[i], b[j]), (i, j, b)
    # the sixth finds no free place (the wall is 124 mm around): the list says what it overlaps
    crossed = [j for j in range(5) if not apart(b[5], b[j])]
    assert pg.locator("#items > li").nth(5).locator("li.overlap").count() == len(crossed) > 0
    assert not errors, errors


def test_a_text_over_the_limit_anywhere_says_so_and_keeps_its_other_bumps(browser, studio):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.fill("#bulge-form input[name=spacing]", "0.15")      # the text's top bars alone make 81
    settled(pg)
    pg.click("#add-text")
    pg.wait_for_function("() => window.studio.S.items.length === 1")
    settled(pg)
    assert ("no free place on the wall keeps every layer within 64 points with Text “TEXT”: it is placed anyway"
            in pg.inner_text("#status-text"))
    assert pg.locator("#global-msgs li.error").all_inner_texts() == [
        "too many points in 1 layer(s) (at most 64 per layer): z 13.20 mm: 81. Increase Spacing (now 0.15 mm) or "
        "simplify the strokes. Until they fit, those layers get no bumps (drawn red) and Export refuses the design; "
        "the items on them say so."]
    assert pg.locator("#items li.error").all_inner_texts() == [
        "on 1 layer(s) over the printer's 64 points per layer (z 13.20 mm: 81 points, 81 its own); those layers "
        "get no bumps: move it to another height, make it smaller or increase Spacing"]
    per, left_out = layer_points(pg)
    assert len(left_out) == 81 and per[13.2] == 81
    info = pg.inner_text("#items > li > .info")
    assert info == f"{sum(per.values()) - 81} bumps, 81 left out (layers over the limit)", info
    assert "1 layer over 64 points left out" in pg.inner_text("#summary")
    assert not errors, errors


def test_choices_are_not_cut_off(browser, studio):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.click("#add-text")                                 # the item form's font choice shows too
    cut_off = """() => { const c = document.createElement("canvas").getContext("2d");
        const out = [];
        for (const s of document.querySelectorAll("#page-wall select")) {
          if (!s.offsetParent) continue;
          const st = getComputedStyle(s);
          c.font = `${st.fontWeight} ${st.fontSize} ${st.fontFamily}`;
          const text = Math.max(...[...s.options].map((o) => c.measureText(o.text).width));
          const r = s.getBoundingClientRect(), aside = s.closest("aside").getBoundingClientRect();
          // room for the text beside the padding and the drop-down arrow (about 20 px), inside the panel
          if (r.width < text + parseFloat(st.paddingLeft) + parseFloat(st.paddingRight) + 20 || r.right > aside.right)
            out.push([s.name || s.id, r.width, text]);
        }
        return out; }"""
    shown = "() => [...document.querySelectorAll('#page-wall select')].filter((s) => s.offsetParent).length"
    assert pg.evaluate(cut_off) == []
    assert pg.evaluate(shown) == 4               # font, align, mode, firmware
    # stock firmware: its printer model, the firmware it runs and the stops' form too
    pg.select_option("#sec-printer select[name=fallback]", "true")
    assert pg.evaluate(cut_off) == []
    assert pg.evaluate(shown) == 7
    assert not errors, errors


def test_exports_are_named_after_the_gcode(studio, tmp_path):
    open_gcode(studio)
    d = {"items": [{"id": "t", "kind": "text", "text": "HI", "at": [5, 5], "size": 5, "font": "futural",
                    "letter_spacing": 0, "mirror": False, "rotate": 0}], "bulges": {}}
    keys = []
    for name in (None, None, "Part", "part"):
        dd = dict(d, name=name) if name else d
        job = wait_job(studio, call(studio, "/api/export", {"design": dd})[1])
        assert job["state"] == "done", job["error"]
        keys.append(job["result"]["key"])
    assert keys == ["cylinder40x20", "cylinder40x20-2", "Part", "part-2"]   # unique, without case
    ex = studio.studio.workdir / "exports"
    assert sorted(p.name for p in ex.iterdir()) == sorted(keys + [k + ".zip" for k in keys])
    # a later session in the same working folder goes on counting
    studio.stop()
    again = start(studio.studio.workdir)
    try:
        open_gcode(again)
        job = wait_job(again, call(again, "/api/export", {"design": d})[1])
        assert job["result"]["key"] == "cylinder40x20-3"
    finally:
        again.stop()
        studio.stop = lambda: None


def test_another_gcode_asks_before_taking_the_design(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.click("#add-text")
    pg.fill("#item-form textarea[name=text]", "HELLO")
    settled(pg)
    other = tmp_path / "other.gcode"
    shutil.copyfile(GCODE, other)
    asked = []

    def answer(yes):
        def on_dialog(dlg):
            asked.append(dlg.message)
            dlg.accept() if yes else dlg.dismiss()
        return on_dialog

    # Cancel: an empty wall (Undo brings the design back)
    pg.once("dialog", answer(False))
    pg.set_input_files("#gcode-file", str(other))
    pg.wait_for_function("() => window.studio.S.gcode.name === 'other.gcode'")
    assert len(asked) == 1 and "other.gcode is another G-code than cylinder40x20.gcode" in asked[0]
    assert "(1 item)" in asked[0]
    assert pg.evaluate("() => window.studio.S.items.length") == 0
    settled(pg)
    pg.click("#undo")
    pg.wait_for_function("() => window.studio.S.items.length === 1")
    settled(pg)
    # OK: the design stays
    pg.once("dialog", answer(True))
    pg.set_input_files("#gcode-file", str(GCODE))
    pg.wait_for_function("() => window.studio.S.gcode.name === 'cylinder40x20.gcode'")
    assert len(asked) == 2
    assert pg.evaluate("() => window.studio.S.items.map((i) => i.text)") == ["HELLO"]
    settled(pg)
    # the same G-code again: nothing to ask
    pg.set_input_files("#gcode-file", str(GCODE))
    pg.wait_for_function("() => window.studio.S.gcode !== null && window.studio.idle()")
    settled(pg)
    assert len(asked) == 2 and pg.evaluate("() => window.studio.S.items.length") == 1
    assert not errors, errors


def test_a_reload_asks_when_the_design_was_made_on_another_gcode(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.click("#add-text")
    settled(pg)
    # another G-code opened outside this page (a second tab), before this one previews again
    other = tmp_path / "other.gcode"
    shutil.copyfile(GCODE, other)
    assert open_gcode(studio, other)["state"] == "done"
    asked = []
    pg.on("dialog", lambda dlg: (asked.append(dlg.message), dlg.dismiss()))
    pg.reload()
    pg.wait_for_selector("body[data-ready='1']")
    assert len(asked) == 1 and "Keep the design made on cylinder40x20.gcode (1 item)" in asked[0]
    assert pg.evaluate("() => window.studio.S.items.length") == 0
    assert not errors, errors


def test_a_picture_too_tall_is_said_in_the_pages_words(studio, tmp_path):
    import numpy as np
    from PIL import Image
    open_gcode(studio)
    img = tmp_path / "sq.png"
    Image.fromarray(np.zeros((100, 100), np.uint8)).save(img)
    status, pic = call(studio, "/api/asset?name=sq.png", img.read_bytes())
    assert status == 200, pic
    for width, said in ((30, "sq.png: the picture is 30 mm tall at a width on the wall of 30 mm, but the "
                             "wall is only 20.1 mm tall; use a smaller width, 19.5 mm or less"),
                        (10, "sq.png: the picture reaches from 15 to 25.5 mm above the bed, but the wall "
                             "goes from 0 to 20.1 mm; move it down by at least 5.4 mm (its lower-left corner, u, v)")):
        d = {"items": [{"id": "p", "kind": "file", "asset": pic["name"], "at": [5, 15 if width == 10 else 0],
                        "image_width": width, "rotate": 0}], "bulges": {}}
        status, p = call(studio, "/api/preview", {"design": d})
        assert status == 200 and p["items"]["p"]["errors"] == [said]


def test_an_empty_gcode_is_called_empty(studio):
    open_gcode(studio)
    status, job = call(studio, "/api/gcode?name=blank.gcode", b"")
    job = wait_job(studio, job)
    assert job["state"] == "error" and job["error"] == "blank.gcode: the G-code file is empty"
    assert call(studio, "/api/state")[1]["gcode"]["name"] == "cylinder40x20.gcode"   # still open


BOX = Path(__file__).resolve().parents[1] / "data" / "prusa_box.gcode"


def test_corners_drawn_and_add_text_centred_on_the_face_in_view(browser, studio):
    """Issue 38: the unrolled view draws the wall's corners and numbers its faces, and Add text
    lands centred on the face in the middle of the view (on a box: the back face, 3, when the whole
    wall shows; face 2 once the view is panned to it)."""
    pg, errors = page_for(browser, studio)
    pg.set_input_files("#gcode-file", str(BOX))
    pg.wait_for_function("() => window.studio.S.gcode !== null", timeout=60_000)
    marks = pg.evaluate("() => window.studio.S.gcode.walls.marks")
    layers = pg.evaluate("() => window.studio.S.gcode.walls.layers.length")
    assert len(marks["corners"]) == 4 * layers
    assert sorted(n for _, _, n in marks["faces"]) == [1, 1, 2, 3, 4]
    # a corner line is on the canvas: its green at the corner's u, half way up
    u, a, b = marks["corners"][len(marks["corners"]) // 2]
    rgb = pg.evaluate(f"""() => {{ const [x, y] = window.studio.view2d.toPx({u}, {(a + b) / 2});
        const d = document.getElementById("unrolled").getContext("2d").getImageData(Math.round(x), Math.round(y), 1, 1).data;
        return [d[0], d[1], d[2]]; }}""")
    assert rgb[1] > rgb[0] + 40 and rgb[1] > rgb[2] + 30, rgb
    runs = marks["runs"]

    def centred(k, face):
        it = pg.evaluate(f"() => window.studio.S.items[{k}]")
        assert it["face"] == face and it["align"] == "center" and it["at"][0] == 0
        b = boxes(pg)[k]
        v = (b[1] + b[3]) / 2
        fs = next(r[2] for r in runs if r[0] <= v <= r[1])
        f = next(f for f in fs if f[0] == face)
        # (the run's faces are its first layer's; the server centres it on its own layer's)
        assert (b[0] + b[2]) / 2 == pytest.approx((f[1] + f[2]) / 2, abs=0.5)
        assert f[1] < b[0] and b[2] < f[2]                # wholly on it

    pg.click("#add-text")
    pg.wait_for_function("() => window.studio.S.items.length === 1")
    settled(pg)
    centred(0, 3)
    assert pg.input_value("#item-form input[name=face]") == "3"
    assert pg.locator("#items li.warning").count() == 0       # on one face: no corner crossed
    # pan: face 2's middle to the middle of the view, then another text goes there
    f2 = next(f for f in runs[len(runs) // 2][2] if f[0] == 2)
    mid = pg.evaluate("() => { const [a, b] = window.studio.view2d.uInView(); return (a + b) / 2; }")
    box = pg.locator("#unrolled").bounding_box()
    x0, y0 = box["x"] + box["width"] / 2, box["y"] + 8           # the background above the wall
    dx = pg.evaluate(f"() => window.studio.view2d.toPx({mid}, 0)[0] - window.studio.view2d.toPx({(f2[1] + f2[2]) / 2}, 0)[0]")
    pg.mouse.move(x0, y0)
    pg.mouse.down()
    pg.mouse.move(x0 + dx, y0, steps=6)
    pg.mouse.up()
    pg.click("#add-text")
    pg.wait_for_function("() => window.studio.S.items.length === 2")
    settled(pg)
    centred(1, 2)
    # moved across a corner, the text says which corner it crosses
    pg.fill("#item-form input[name=u]", "9")
    settled(pg)
    warn = [w for w in pg.locator("#items li.warning").all_inner_texts() if "corner" in w]
    assert warn == ["the text 'TEXT' crosses the corner between faces 2 and 3 at u 34.3 mm "
                    "(z 5.10-10.20 mm): it bends round it (face = N puts it on one face)"], warn
    assert not errors, errors
