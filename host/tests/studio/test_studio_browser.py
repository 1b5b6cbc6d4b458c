"""`bulgekit studio` in a real browser: Debian's chromium, headless, driven by Playwright.

The page is used as a user would: a G-code dropped on it, text added, typed, moved, turned and
scaled with the mouse, a drawing added, exported; the exported files are compared byte for
byte with `bulgekit build --placement` run on the placement file the page exported. Bad input
shows its message in the page and the server keeps working. With BULGEKIT_STUDIO_SHOTS=DIR the
main states are saved as screenshots there (docs/studio.md's pictures come from that).
"""
import hashlib
import os
import shutil
import time
from pathlib import Path

import pytest
from PIL import Image
from playwright.sync_api import sync_playwright

from studio_util import GCODE, big_gcode, cli_build, fake_printer, start

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
SHOTS = os.environ.get("BULGEKIT_STUDIO_SHOTS")
SVG = """<svg xmlns="http://www.w3.org/2000/svg" width="16mm" height="8mm" viewBox="0 0 16 8">
<path d="M 1 1 L 15 7 M 1 7 L 15 1" fill="none" stroke="black"/><circle cx="8" cy="4" r="3" fill="none" stroke="black"/></svg>"""


@pytest.fixture(scope="module")
def browser():
    assert CHROMIUM, "Debian's chromium is needed (apt-get install chromium; tools/install-deps.sh does)"
    with sync_playwright() as p:
        # SwiftShader gives headless chromium WebGL without a GPU (the 3D view)
        b = p.chromium.launch(executable_path=CHROMIUM, args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
        yield b
        b.close()


def page_for(browser, run):
    # Playwright's waits evaluate strings, which the page's CSP forbids: bypassed for the test
    # driver only (test_studio.py checks the header itself)
    ctx = browser.new_context(viewport={"width": 1400, "height": 900}, bypass_csp=True,
                              accept_downloads=True)
    pg = ctx.new_page()
    errors = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.goto(run.url)
    pg.wait_for_selector("body[data-ready='1']")
    return pg, errors


def shot(pg, name):
    if SHOTS:
        import io
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        im = Image.open(io.BytesIO(pg.screenshot())).convert("RGB")
        # 128 colours: the page's flat colours survive, the file is a quarter the size
        im.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(Path(SHOTS) / f"{name}.png", optimize=True)


def drop_file(pg, selector, path, name=None):
    data = Path(path).read_bytes()
    dt = pg.evaluate_handle("""([bytes, name]) => { const dt = new DataTransfer();
        dt.items.add(new File([new Uint8Array(bytes)], name)); return dt; }""", [list(data), name or Path(path).name])
    pg.dispatch_event(selector, "drop", {"dataTransfer": dt})


def settled(pg, timeout=120_000):
    """Wait until the last edit's preview, and its check against the G-code, are back."""
    pg.wait_for_function("() => window.studio.idle()", timeout=timeout)
    return pg.inner_text("#summary")


def item(pg, k=-1):
    return pg.evaluate(f"() => window.studio.S.items.at({k})")


def px(pg, u, v):
    x, y = pg.evaluate(f"() => window.studio.view2d.toPx({u}, {v})")
    box = pg.locator("#unrolled").bounding_box()
    return box["x"] + x, box["y"] + y


def open_sample(pg):
    """Open the sample G-code from the file picker and wait until its walls are in."""
    pg.set_input_files("#gcode-file", str(GCODE))
    pg.wait_for_function("() => window.studio.S.gcode !== null", timeout=60_000)


def frame(pg):
    """Page coordinates (left, top, right, bottom) of the last item's strokes, as last computed."""
    u0, v0, u1, v1 = pg.evaluate("""() => { const s = window.studio.S, it = s.items.at(-1);
        const b = [1e9, 1e9, -1e9, -1e9];
        for (const f of s.preview.items[it.id].strokes) for (let i = 0; i < f.length; i += 2) {
          b[0] = Math.min(b[0], f[i]); b[2] = Math.max(b[2], f[i]);
          b[1] = Math.min(b[1], f[i + 1]); b[3] = Math.max(b[3], f[i + 1]); }
        return b; }""")
    (x0, y0), (x1, y1) = px(pg, u0, v1), px(pg, u1, v0)
    return x0, y0, x1, y1


def drag(pg, a, b, steps=8):
    pg.mouse.move(*a)
    pg.mouse.down()
    pg.mouse.move(*b, steps=steps)
    pg.mouse.up()


@pytest.fixture
def studio(tmp_path):
    run = start(tmp_path / "work", image_pixels=2_000_000)
    yield run
    run.stop()


def test_place_move_export_matches_cli(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    drop_file(pg, "#drop", GCODE)
    pg.wait_for_function("() => window.studio.S.gcode !== null", timeout=60_000)
    assert "67 layers" in pg.inner_text("#gcode-info")
    assert pg.locator("#view3d canvas").count() == 1, "no WebGL canvas: the 3D view did not start"

    pg.click("#add-text")
    pg.fill("#item-form textarea[name=text]", "HELLO")
    settled(pg)
    it = item(pg)
    assert it["text"] == "HELLO"
    n_hello = pg.evaluate("() => window.studio.S.preview.points.length")
    assert n_hello > 50 and "bumps" in pg.inner_text("#items")

    # move: drag the text 20 mm along the wall and 2 mm up
    u0, v0 = it["at"]
    a = px(pg, u0 + 3, v0 + 3)
    b = px(pg, u0 + 23, v0 + 5)
    drag(pg, a, b)
    moved = item(pg)
    assert moved["at"][0] == pytest.approx(u0 + 20, abs=0.6)
    assert moved["at"][1] == pytest.approx(v0 + 2, abs=0.6)
    assert float(pg.input_value("#item-form input[name=u]")) == pytest.approx(moved["at"][0], abs=0.01)
    settled(pg)
    shot(pg, "1-text-placed")

    # turn with the round handle (shift: 15 degree steps), then scale with the square one
    x0, y0, x1, y1 = frame(pg)
    rot = ((x0 + x1) / 2, y0 - 22)              # the round handle, above the frame's middle
    at = px(pg, *moved["at"])
    pg.keyboard.down("Shift")
    drag(pg, rot, (at[0] - 60, at[1] - 40))
    pg.keyboard.up("Shift")
    turned = item(pg)
    assert turned["rotate"] != 0 and turned["rotate"] % 15 == 0
    settled(pg)
    pg.fill("#item-form input[name=rotate]", "10")
    settled(pg)
    size0 = item(pg)["size"]
    corner = tuple(c + 4 for c in frame(pg)[2:])   # the square handle, at the lower right
    drag(pg, corner, (corner[0] - (corner[0] - at[0]) * 0.25, corner[1] - (corner[1] - at[1]) * 0.25))
    scaled = item(pg)
    assert scaled["size"] < size0 * 0.95
    settled(pg)

    # a drawing from the file picker
    svg = tmp_path / "mark.svg"
    svg.write_text(SVG)
    pg.set_input_files("#add-file", str(svg))
    pg.wait_for_function("() => window.studio.S.items.length === 2")
    pg.fill("#item-form input[name=u]", "70")
    pg.fill("#item-form input[name=v]", "6")
    txt = settled(pg)
    owners = pg.evaluate("() => [...new Set(window.studio.S.preview.points.flatMap(p => p[6]))].sort()")
    assert owners == sorted(i["id"] for i in pg.evaluate("() => window.studio.S.items"))
    assert "stops" in txt
    pg.fill("#bulge-form input[name=dwell]", "120")
    pg.fill("#export-name", "studio-test")
    settled(pg)
    shot(pg, "2-text-and-drawing")

    pg.click("#export")
    pg.wait_for_selector("#export-zip", timeout=120_000)
    shot(pg, "3-exported")
    key = pg.evaluate("() => window.studio.S.exportKey")
    folder = studio.studio.workdir / "exports" / key
    placement = (folder / "placement.toml").read_text()
    assert "dwell = 120" in placement and 'text = "HELLO"' in placement and "rotate = 10" in placement
    cli = cli_build(GCODE, folder / "placement.toml", tmp_path / "cli", "studio-test")
    assert len(cli) == 6
    for p in cli:
        assert hashlib.sha256(p.read_bytes()).digest() == hashlib.sha256((folder / p.name).read_bytes()).digest(), p.name
    # a download link hands over the same bytes
    with pg.expect_download() as dl:
        pg.click("#export-out a.export-file >> text=studio-test.bkm")
    assert Path(dl.value.path()).read_bytes() == (folder / "studio-test.bkm").read_bytes()
    assert not errors, errors


def test_bad_input_shows_messages_and_keeps_working(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    junk = tmp_path / "picture.gcode"
    junk.write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR")
    pg.set_input_files("#gcode-file", str(junk))
    pg.wait_for_selector("#gcode-error:not([hidden])")
    assert "not a text G-code file" in pg.inner_text("#gcode-error")
    nowall = tmp_path / "travel-only.gcode"
    nowall.write_text("G28\nG1 X10 Y10 F3000\nG1 X20 Y10\n")
    pg.set_input_files("#gcode-file", str(nowall))
    pg.wait_for_function("() => document.querySelector('#gcode-error').textContent.includes('travel-only')")
    assert "no outer wall found" in pg.inner_text("#gcode-error")
    shot(pg, "5-not-gcode")

    # the server still works: a real G-code opens, the error goes
    open_sample(pg)
    assert pg.is_hidden("#gcode-error")
    # a character the font lacks: the message sits beside the text item
    pg.click("#add-text")
    pg.fill("#item-form textarea[name=text]", "A€B")
    pg.wait_for_function("() => document.querySelector('#items li.error') !== null", timeout=60_000)
    assert "'€'" in pg.inner_text("#items li.error") and "not in font" in pg.inner_text("#items li.error")
    shot(pg, "6-item-error")
    pg.fill("#item-form textarea[name=text]", "AB")
    pg.wait_for_function("() => document.querySelector('#items li.error') === null", timeout=60_000)

    # a picture over the pixel limit
    big = tmp_path / "huge.png"
    Image.new("L", (1600, 1400), 200).save(big)
    pg.set_input_files("#add-file", str(big))
    pg.wait_for_selector("#asset-error:not([hidden])")
    assert "1600 x 1400 pixels" in pg.inner_text("#asset-error")
    assert pg.evaluate("() => window.studio.S.items.length") == 1
    assert not errors, errors


def test_large_gcode_shows_progress_and_the_page_stays_responsive(browser, tmp_path):
    big = big_gcode(tmp_path / "tall.gcode", 100_000_000)
    assert big.stat().st_size >= 100_000_000
    # over the limit the page says so before uploading anything
    small = start(tmp_path / "w1", gcode_bytes=64_000_000)
    try:
        pg, _ = page_for(browser, small)
        pg.set_input_files("#gcode-file", str(big))
        pg.wait_for_selector("#gcode-error:not([hidden])")
        assert "100.2 MB is more than the studio takes" in pg.inner_text("#gcode-error")
        assert not list((tmp_path / "w1" / "gcode").iterdir())
        pg.context.close()
    finally:
        small.stop()
    # within it, the file loads while the page shows progress and answers
    run = start(tmp_path / "w2")
    try:
        pg, errors = page_for(browser, run)
        # every text the status line shows, as the page sets it: a local upload can pass in
        # less time than one look by polling
        pg.evaluate("""() => {
            const el = document.querySelector('#status-text');
            window.statusSeen = [el.textContent];
            new MutationObserver(() => window.statusSeen.push(el.textContent))
                .observe(el, {childList: true, characterData: true, subtree: true});
        }""")
        pg.set_input_files("#gcode-file", str(big))
        seen, slowest = set(), 0.0
        t0 = time.monotonic()
        while not pg.evaluate("() => window.studio.S.gcode !== null"):
            t = time.monotonic()
            seen.add(pg.inner_text("#status-text"))
            slowest = max(slowest, time.monotonic() - t)
            assert time.monotonic() - t0 < 240, "the 100 MB file did not load in 4 min"
            time.sleep(0.05)
        shot(pg, "4-large-file")
        seen |= {t.strip() for t in pg.evaluate("() => window.statusSeen")}
        assert any(s.startswith("uploading tall.gcode") and "%" in s for s in seen), seen
        walls = [int(s.split()[-2]) for s in seen if s.startswith("tall.gcode: reading the walls") and s.endswith(" %")]
        assert any(0 < w < 100 for w in walls), seen          # the job's own progress, mid-way
        assert slowest < 2.0, f"the page took {slowest:.2f} s to answer while loading"
        assert "10586 layers" in pg.inner_text("#gcode-info")
        assert not errors, errors
    finally:
        run.stop()


def test_send_to_printer(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.click("#add-text")
    settled(pg)
    pg.click("#export")
    pg.wait_for_selector("#export-zip", timeout=120_000)
    with fake_printer(arena=1024) as (port, printer):
        pg.fill("#port", port)
        pg.click("#send")
        pg.wait_for_function("() => document.querySelector('#status-text').textContent.startsWith('sent ')",
                             timeout=120_000)
        log = pg.inner_text("#send-log")
        # the arena check's reply (the banner may come before the port is open, and be dropped)
        assert "echo:BulgeMap" in log and "lines" in log
        assert pg.evaluate("() => document.querySelector('#send-bar').value") == 1
        assert any(c.startswith("M721") for c in printer.executed) and printer.executed[-1] == "M721 X"
        shot(pg, "7-sent")

    assert not errors, errors


def canvas_pixels(pg, selector):
    import io
    import numpy as np
    return np.asarray(Image.open(io.BytesIO(pg.locator(selector).screenshot())).convert("L"), dtype=float)


def test_lithophane_tab(browser, studio, tmp_path):
    """The picture shows as soon as it is chosen; the fields follow the shape; Make shows the part
    in 3D with its look, the figures in plain words; the file goes to the (fake) printer."""
    import numpy as np
    from skimage import data            # a real photograph, as scikit-image's wheel ships it
    pg, errors = page_for(browser, studio)
    pg.click("#tab-litho")
    form = "#litho-form "
    assert pg.is_visible(form + "input[name=width]") and pg.is_visible(form + "input[name=foot]")
    assert not pg.is_visible(form + "input[name=diameter]")
    pg.select_option(form + "select[name=shape]", "cylinder")
    assert pg.is_visible(form + "input[name=diameter]")
    assert not pg.is_visible(form + "input[name=width]") and not pg.is_visible(form + "input[name=foot]")
    pg.select_option(form + "select[name=shape]", "arc")           # the curved panel (issue 37)
    assert pg.is_visible(form + "input[name=diameter]") and pg.is_visible(form + "input[name=angle]")
    assert not pg.is_visible(form + "input[name=width]") and not pg.is_visible(form + "input[name=foot]")
    pg.select_option(form + "select[name=shape]", "planar")
    assert pg.is_visible(form + "input[name=width]") and not pg.is_visible(form + "input[name=diameter]")
    assert not pg.is_visible(form + "input[name=angle]")
    # the curves are the toolkit's
    from bulgekit import litho as lt
    assert pg.eval_on_selector(form + "select[name=curve]", "s => [...s.options].map(o => o.value)") == list(lt.CURVES)
    assert pg.eval_on_selector(form + "select[name=light_gaps]", "s => [...s.options].map(o => o.value)") == \
        list(lt.LIGHT_GAPS)
    assert pg.eval_on_selector(form + "select[name=light_gaps]", "s => s.value") == lt.LithoOptions().light_gaps
    assert pg.input_value(form + "input[name=rate_accel]") == "1000"

    pic = tmp_path / "astronaut.png"
    Image.fromarray(data.astronaut()).resize((90, 82)).save(pic)
    pg.set_input_files("#litho-file", str(pic))
    # shown before Make
    pg.wait_for_function("() => { const i = document.querySelector('#litho-src'); return i.complete && i.naturalWidth === 90; }")
    assert pg.is_visible("#litho-src")
    pg.wait_for_function("() => !document.querySelector('#litho-make').disabled")
    assert "90 × 82 pixels" in pg.inner_text("#litho-pic")
    pg.fill(form + "input[name=width]", "40")
    pg.click("#litho-make")
    pg.wait_for_selector("#litho-figures", timeout=240_000)
    pg.wait_for_function("() => { const i = document.querySelector('#litho-look'); return i && i.complete && i.naturalWidth > 0; }")
    # the 3D view draws the part: light and dark texels of the look on a dark background
    px = canvas_pixels(pg, "#litho-3d canvas")
    bg = np.median(px[:5])                       # the top rows: background
    part = px[np.abs(px - bg) > 8]
    assert part.size > 0.1 * px.size, part.size / px.size
    assert np.percentile(part, 95) - np.percentile(part, 5) > 80
    out = pg.inner_text("#litho-out")
    assert "Print time" in out and "Filament" in out and "Fastest head speed" in out and "mm³/s" in out
    assert "--" not in out and "mm^3" not in out and str(studio.studio.workdir) not in pg.inner_text("body")
    assert "astronaut.litho.gcode" in out and "astronaut.stl" in out
    shot(pg, "8-lithophane")
    pg.click("#litho-light button[data-light=day]")           # the relief, lit from the front
    day = canvas_pixels(pg, "#litho-3d canvas")
    assert np.abs(day - px).mean() > 5
    shot(pg, "9-lithophane-daylight")
    pg.click("#litho-light button[data-light=back]")

    with fake_printer(arena=1024) as (port, printer):
        pg.fill("#litho-port", port)
        pg.select_option("#litho-which", "stock")
        pg.click("#litho-send")
        pg.wait_for_function("() => document.querySelector('#status-text').textContent.startsWith('sent ')",
                             timeout=300_000)
        key = pg.evaluate("() => window.studio.lithoKey()")
        path = studio.studio.lithos[key]["paths"]["stock"]
        sent = [ln.split(";")[0].strip() for ln in path.read_text().splitlines() if ln.split(";")[0].strip()]
        assert printer.executed[-len(sent):] == sent
        assert "astronaut.stock.gcode" in pg.inner_text("#litho-send-log")
        assert pg.evaluate("() => document.querySelector('#litho-send-bar').value") == 1

    # a reload keeps it: the tab, the figures, the files, the 3D view and the form it was made with
    key = pg.evaluate("() => window.studio.lithoKey()")
    figures = pg.inner_text("#litho-figures")
    pg.reload()
    pg.wait_for_selector("body[data-ready='1']")
    pg.wait_for_selector("#litho-figures", timeout=60_000)
    assert pg.is_visible("#page-litho") and pg.is_hidden("#page-wall")
    assert pg.evaluate("() => window.studio.lithoKey()") == key
    assert pg.inner_text("#litho-figures") == figures and "astronaut.stl" in pg.inner_text("#litho-out")
    assert pg.input_value(form + "input[name=width]") == "40" and "90 × 82 pixels" in pg.inner_text("#litho-pic")
    pg.wait_for_function("() => !document.querySelector('#litho-send').disabled")
    again = canvas_pixels(pg, "#litho-3d canvas")
    assert (np.abs(again - np.median(again[:5])) > 8).mean() > 0.1

    # a bad setting is said in the page's own words
    pg.fill(form + "input[name=min_thickness]", "3")
    pg.click("#litho-make")
    pg.wait_for_selector("#litho-error:not([hidden])", timeout=60_000)
    assert "'Thickest (black)'" in pg.inner_text("#litho-error")
    assert not errors, errors


def test_open_placement_file_and_nudge_with_keys(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    ex = GCODE.parent
    pg.set_input_files("#open-placement", [str(ex / "placement.toml"), str(ex / "wave.json")])
    pg.wait_for_function("() => window.studio.S.items.length === 2")
    settled(pg)
    items = pg.evaluate("() => window.studio.S.items")
    assert items[0]["text"] == "HELLO" and items[0]["letter_spacing"] == 0.5 and items[1]["asset"] == "wave.json"
    assert pg.input_value("#bulge-form input[name=dwell]") == "100"
    owners = pg.evaluate("() => [...new Set(window.studio.S.preview.points.flatMap(p => p[6]))].length")
    assert owners == 2
    # arrows nudge the selected item (not while typing in a field); Delete removes it
    pg.click("#unrolled", position={"x": 5, "y": 5})          # the background: focus leaves the form
    at = items[0]["at"]
    pg.keyboard.press("ArrowRight")
    pg.keyboard.press("Shift+ArrowUp")
    assert item(pg, 0)["at"] == pytest.approx([at[0] + 0.5, at[1] + 5])
    pg.keyboard.press("Delete")
    assert pg.evaluate("() => window.studio.S.items.length") == 1
    # values the page would never make come back unchanged: export = the CLI on the original
    odd = tmp_path / "odd.toml"
    odd.write_text('[[text]]\ntext = "Odd"\nat = [3.14159, 6.0004]\nsize = 5.12345\nrotate = 7.77\n'
                   '[[strokes]]\nfile = "wave.json"\nat = [0.333, 0.1]\ncurve_tolerance = 0.02\n'
                   '[bulges]\ndwell = 90\nextra = 0.0725\ne_steps = 415.5\nstop_e_steps = 8\n')
    pg.set_input_files("#open-placement", [str(odd), str(ex / "wave.json")])
    pg.wait_for_function("() => window.studio.S.items.length === 2 && window.studio.S.items[0].text === 'Odd'")
    settled(pg)
    # the stock file's stop settings come in with it (issue 25) and go out with the export
    assert pg.input_value("#sec-printer input[name=e_steps]") == "415.5"
    assert pg.input_value("#sec-printer input[name=stop_e_steps]") == "8"
    pg.fill("#export-name", "odd")
    pg.click("#export")
    pg.wait_for_selector("#export-zip", timeout=120_000)
    folder = studio.studio.workdir / "exports" / pg.evaluate("() => window.studio.S.exportKey")
    (tmp_path / "wave.json").write_bytes((ex / "wave.json").read_bytes())
    cli = cli_build(GCODE, odd, tmp_path / "cli", "odd")
    for p in cli:
        assert p.read_bytes() == (folder / p.name).read_bytes(), p.name
    # editing one field leaves the others' exact values alone (the form shows them rounded)
    pg.click("#items li >> nth=0")
    pg.fill("#item-form textarea[name=text]", "Odd!")
    odd_item = item(pg, 0)
    assert odd_item["text"] == "Odd!" and odd_item["at"] == [3.14159, 6.0004] and odd_item["size"] == 5.12345
    assert odd_item["rotate"] == 7.77
    # a placement naming a file that was not chosen with it
    pg.set_input_files("#open-placement", [str(ex / "placement.toml")])
    pg.wait_for_selector("#asset-error:not([hidden])")
    assert "wave.json was not chosen with it" in pg.inner_text("#asset-error")
    assert pg.evaluate("() => window.studio.S.items.length") == 2     # the design is kept
    assert not errors, errors


def test_undo_redo_and_a_reload_keeps_the_design(browser, studio):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    pg.click("#add-text")
    pg.keyboard.press("Delete")                  # the button has the focus: no item is deleted
    assert pg.evaluate("() => window.studio.S.items.length") == 1
    settled(pg)
    pg.wait_for_timeout(500)                     # each state resting 400 ms is kept
    pg.fill("#item-form textarea[name=text]", "AB")
    settled(pg)
    at0 = item(pg)["at"]
    pg.click("#unrolled", position={"x": 5, "y": 5})
    pg.keyboard.press("Shift+ArrowRight")
    settled(pg)
    assert item(pg)["at"][0] == pytest.approx(at0[0] + 5)
    pg.keyboard.press("Control+z")
    assert item(pg)["at"][0] == pytest.approx(at0[0])
    pg.keyboard.press("Control+z")
    assert item(pg)["text"] == "TEXT"            # before the typing
    pg.click("#undo")
    assert pg.evaluate("() => window.studio.S.items.length") == 0 and pg.is_disabled("#undo")
    for _ in range(3):
        pg.click("#redo")
    assert item(pg)["text"] == "AB" and item(pg)["at"][0] == pytest.approx(at0[0] + 5)
    assert pg.is_disabled("#redo")
    settled(pg)
    pg.fill("#bulge-form input[name=dwell]", "150")
    settled(pg)
    n = pg.evaluate("() => window.studio.S.preview.points.length")
    pg.reload()
    pg.wait_for_selector("body[data-ready='1']")
    settled(pg)
    assert item(pg)["text"] == "AB" and item(pg)["at"][0] == pytest.approx(at0[0] + 5)
    assert pg.input_value("#bulge-form input[name=dwell]") == "150"
    assert pg.evaluate("() => window.studio.S.preview.points.length") == n
    pg.wait_for_timeout(500)
    assert pg.is_disabled("#undo")                # nothing to undo into: not an empty design
    assert not errors, errors


def export_and_compare(pg, run, tmp_path, name):
    """Export from the page and compare every file with `bulgekit build --placement` on the
    placement file it wrote; the export's folder."""
    settled(pg)
    pg.fill("#export-name", name)           # (not a change a preview waits for)
    pg.click("#export")
    pg.wait_for_selector("#export-zip", timeout=120_000)
    folder = run.studio.workdir / "exports" / pg.evaluate("() => window.studio.S.exportKey")
    cli = cli_build(GCODE, folder / "placement.toml", tmp_path / f"cli-{name}", name)
    assert len(cli) == 6
    for p in cli:
        assert p.read_bytes() == (folder / p.name).read_bytes(), p.name
    return folder


def test_braille_item_added_previewed_and_exported(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    # the unrolled view fits the wall: from the bed (a margin for the labels), not from v = -15
    bottom = pg.evaluate("() => window.studio.view2d.toMm(0, document.querySelector('#unrolled').height)[1]")
    assert -3 < bottom <= 0
    pg.click("#add-braille")
    settled(pg)
    it = item(pg)
    assert it["kind"] == "braille" and it["text"] == "hello" and it["grade"] == 1
    assert "Braille “hello”" in pg.inner_text("#items") and "bumps" in pg.inner_text("#items")
    # its fields: text and grade, no size, font or turn (braille keeps the standard's size)
    assert pg.is_visible("#item-form select[name=grade]") and pg.is_visible("#item-form textarea[name=text]")
    for f in ("input[name=size]", "select[name=font]", "input[name=rotate]", "input[name=table]"):
        assert pg.is_hidden("#item-form " + f), f
    n1 = pg.evaluate("() => window.studio.S.preview.points.length")
    pg.fill("#item-form textarea[name=text]", "the bulge")
    pg.select_option("#item-form select[name=grade]", "2")
    settled(pg)
    assert item(pg)["grade"] == 2 and pg.evaluate("() => window.studio.S.preview.points.length") != n1
    assert not pg.evaluate("() => window.studio.S.preview.items[window.studio.S.items.at(-1).id].errors")
    shot(pg, "10-braille")
    folder = export_and_compare(pg, studio, tmp_path, "dots")
    assert '[[braille]]\ntext = "the bulge"' in (folder / "placement.toml").read_text()
    assert "grade = 2" in (folder / "placement.toml").read_text()
    assert not errors, errors


def test_one_printer_control_and_the_printer_model(browser, studio, tmp_path):
    pg, errors = page_for(browser, studio)
    open_sample(pg)
    assert pg.locator("h2", has_text="Printer").count() == 1     # one place says what printer
    stock_fields = ["select[name=printer_choice]", "select[name=firmware]", "select[name=stop]",
                    "input[name=e_steps]", "input[name=stop_e_steps]"]
    # bulgekit firmware: no stock-file fields
    assert pg.input_value("#sec-printer select[name=fallback]") == "false"
    for f in stock_fields:
        assert pg.is_hidden("#sec-printer " + f), f
    assert "bulgekit firmware" in pg.inner_text("#send-what")
    pg.click("#add-text")
    settled(pg)
    default = export_and_compare(pg, studio, tmp_path, "plain")
    # stock firmware: they show; a preset makes another stock file, still the CLI's
    pg.select_option("#sec-printer select[name=fallback]", "true")
    for f in stock_fields:
        assert pg.is_visible("#sec-printer " + f), f
    assert pg.is_hidden("#sec-printer input[name=printer_file]")
    assert "stock firmware" in pg.inner_text("#send-what")
    from bulgekit.machine import PRESETS
    assert pg.eval_on_selector("#sec-printer select[name=printer_choice]",
                               "s => [...s.options].map(o => o.value)") == [*PRESETS, "file"]
    pg.select_option("#sec-printer select[name=printer_choice]", "prusa-mk3s")
    assert "280" in pg.get_attribute("#sec-printer input[name=e_steps]", "placeholder")
    assert "prusa" in pg.inner_text("#printer-describe")
    folder = export_and_compare(pg, studio, tmp_path, "prusa")
    placement = (folder / "placement.toml").read_text()
    assert 'printer = "prusa-mk3s"' in placement and "fallback = true" in placement
    a = (default / "plain.stock.gcode").read_text().splitlines()
    b = (folder / "prusa.stock.gcode").read_text().splitlines()
    assert "prusa-mk3s (prusa)" in b[1] and a[2:] != b[2:]
    # a profile file by its path; one not there is said below the views
    pg.select_option("#sec-printer select[name=printer_choice]", "file")
    assert pg.is_visible("#sec-printer input[name=printer_file]")
    pg.fill("#sec-printer input[name=printer_file]", str(tmp_path / "nowhere.cfg"))
    pg.wait_for_function("() => document.querySelector('#global-msgs').textContent.includes('nowhere.cfg')",
                         timeout=60_000)
    assert "neither a file nor a preset" in pg.inner_text("#global-msgs")
    # back to bulgekit firmware: the stock fields go again
    pg.select_option("#sec-printer select[name=fallback]", "false")
    assert pg.is_hidden("#sec-printer select[name=printer_choice]")
    assert not errors, errors
