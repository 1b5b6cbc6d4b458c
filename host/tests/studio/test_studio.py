"""`bulgekit studio` without a browser: its HTTP API, its guard, its handling of bad input, the
placement file it writes, per-item messages, sending through the existing sender, and the
byte-for-byte match of its export with `bulgekit build --placement` (the browser tests are in
test_studio_browser.py)."""
import hashlib
import json
import time
import urllib.request
from pathlib import Path

import pytest
from PIL import Image

from bulgekit.bulge.placement import dump_placement, load_placement
from studio_util import GCODE, call, cli_build, fake_printer, open_gcode, start, wait_job

SVG = """<svg xmlns="http://www.w3.org/2000/svg" width="20mm" height="10mm" viewBox="0 0 20 10">
<path d="M 1 1 L 19 9 M 1 9 L 19 1" fill="none" stroke="black"/></svg>"""


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    run = start(tmp_path_factory.mktemp("studio"), image_pixels=4_000_000)
    job = open_gcode(run)
    assert job["state"] == "done", job
    yield run
    run.stop()


def text_item(iid="t1", **kw):
    return {"id": iid, "kind": "text", "text": "HELLO", "at": [4, 7], "size": 6, "font": "futural",
            "letter_spacing": 0, "mirror": False, "rotate": 0} | kw


def design(*items, **bulges):
    return {"name": "part", "items": list(items),
            "bulges": {"dwell": 100, "extra": 0.1, "tolerance": 0.25, "line_width": 0.45,
                       "geometric": False, "fallback": False} | bulges}


# -- the guard

def test_page_has_token_and_csp(studio):
    status, html = call(studio, "/", token=False, raw=True)
    assert status == 200 and studio.studio.token.encode() in html
    with urllib.request.urlopen(studio.url) as r:
        csp = r.headers["Content-Security-Policy"]
    assert "default-src 'self'" in csp and "'unsafe-eval'" not in csp and "sha256-" in csp


@pytest.mark.parametrize("headers,token,why", [
    ({}, False, "token"),
    ({"Origin": "http://evil.example"}, True, "another origin"),
    ({"Sec-Fetch-Site": "cross-site"}, True, "another site"),
    ({"Host": "attacker.example:80"}, True, "Host"),
    ({"Host": "192.168.1.5"}, True, "Host"),
])
def test_guard_refuses_other_origins_and_missing_token(studio, headers, token, why):
    status, body = call(studio, "/api/state", headers=headers, token=token)
    assert status == 403 and why in body["error"]
    status, body = call(studio, "/api/preview", {"design": design(text_item())}, headers=headers,
                        token=token)
    assert status == 403


def test_guard_lets_the_page_in(studio):
    port = studio.url.split(":")[2].rstrip("/")
    for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}"):
        status, body = call(studio, "/api/state", headers={"Origin": origin,
                                                           "Sec-Fetch-Site": "same-origin"})
        assert status == 200 and body["gcode"]["layers"] == 67


def test_files_stay_inside_the_working_folder(studio, tmp_path):
    secret = studio.studio.workdir.parent / "secret.txt"
    secret.write_text("no")
    for path in ("/files/exports/../../secret.txt", "/files/exports/%2e%2e/%2e%2e/secret.txt",
                 "/files/gcode/1-cylinder40x20.gcode", "/files/litho/../exports"):
        status, body = call(studio, path, raw=True)
        assert status == 404, path
    assert call(studio, "/files/exports/x", token=False)[0] == 403


# -- bad input: clear messages, the server keeps running, the open G-code stays

@pytest.mark.parametrize("name,data,message", [
    ("photo.gcode", b"\x89PNG\r\n\x1a\n\0\0\0", "not a text G-code file"),
    ("empty.gcode", b"G28\nM104 S200\nG1 X10 Y10 F3000\n", "outer wall"),
    ("notes.txt", b"shopping list\nmilk\n", "outer wall"),
])
def test_bad_gcode_is_refused_clearly(studio, name, data, message):
    status, job = call(studio, f"/api/gcode?name={name}", data)
    job = wait_job(studio, job)
    assert job["state"] == "error" and message in job["error"] and name in job["error"]
    st = call(studio, "/api/state")[1]
    assert st["gcode"]["name"] == "cylinder40x20.gcode"      # what was open stays open
    assert [p.name for p in (studio.studio.workdir / "gcode").iterdir()] == ["1-cylinder40x20.gcode"]


def test_only_the_open_upload_is_kept(tmp_path):
    run = start(tmp_path)
    try:
        open_gcode(run)
        open_gcode(run, name="again.gcode")
        assert [p.name for p in (tmp_path / "gcode").iterdir()] == ["3-again.gcode"]
    finally:
        run.stop()


def test_gcode_over_the_limit_is_refused_before_reading(tmp_path):
    run = start(tmp_path, gcode_bytes=1 << 20)
    try:
        status, body = call(run, "/api/gcode?name=huge.gcode", b";" * ((1 << 20) + 10))
        assert status == 413 and "huge.gcode" in body["error"] and "--max-upload" in body["error"]
        assert not list((tmp_path / "gcode").iterdir())          # nothing kept
        assert open_gcode(run)["state"] == "done"                # and the server still works
    finally:
        run.stop()


def test_already_annotated_gcode_is_refused(studio, tmp_path):
    data = GCODE.read_bytes().replace(b";LAYER_CHANGE", b"M720 S1\n;LAYER_CHANGE", 1)
    job = wait_job(studio, call(studio, "/api/gcode?name=twice.gcode", data)[1])
    assert job["state"] == "error" and "bulge twice" in job["error"]


def test_oversized_and_broken_pictures_are_refused(studio, tmp_path):
    big = tmp_path / "big.png"
    Image.new("L", (2100, 2000), 128).save(big)          # 4.2 MP, over this studio's 4 MP
    status, body = call(studio, "/api/asset?name=big.png", big.read_bytes())
    assert status == 400 and "2100 x 2000 pixels" in body["error"] and "scale it down" in body["error"]
    status, body = call(studio, "/api/asset?name=fake.png", b"not a picture")
    assert status == 400 and "fake.png" in body["error"] and "Pillow" in body["error"]
    status, body = call(studio, "/api/asset?name=run.exe", b"MZ")
    assert status == 400 and "not a drawing file" in body["error"]
    status, body = call(studio, "/api/asset?name=bad.svg", b"<svg><path d='M 1 1 L'/></svg>")
    assert status == 400 and body["error"].startswith("bad.svg")
    status, body = call(studio, "/api/asset?name=deep.json", b"[" * 100_000 + b"]" * 100_000)
    assert status == 400 and body["error"].startswith("deep.json")
    for msg in (call(studio, "/api/asset?name=x.svg", b"<svg")[1]["error"],):
        assert str(studio.studio.workdir) not in msg and msg.startswith("x.svg")
    assert "big.png" not in call(studio, "/api/state")[1]["assets"]


def test_asset_names_cannot_leave_the_folder(studio):
    status, info = call(studio, "/api/asset?name=../../evil.svg", SVG.encode())
    assert status == 200 and info["name"] == "evil.svg"
    assert (studio.studio.workdir / "assets" / "evil.svg").is_file()


def test_bad_requests_get_json_errors(studio):
    assert call(studio, "/api/preview", b"{nope", headers={"Content-Type": "application/json"})[0] == 400
    status, body = call(studio, "/api/preview", {"design": {"items": [{"kind": "circle"}]}})
    assert status == 400 and "unknown kind" in body["error"]
    status, body = call(studio, "/api/preview", {"design": design(text_item(at=[1, "x"]))})
    assert status == 400 and body["error"] == "item t1: at: expected a number, got 'x'"


# -- preview: strokes and messages per item

def test_preview_places_points_and_names_items(studio):
    status, p = call(studio, "/api/preview", {"design": design(text_item("a"), text_item("b", text="X", at=[60, 3])),
                                              "check": True})
    assert status == 200 and not p["errors"]
    owners = {o for pt in p["points"] for o in pt[6]}
    assert owners == {"a", "b"} and p["items"]["a"]["strokes"] and p["items"]["b"]["strokes"]
    assert p["summary"]["checked"] and p["summary"]["stops"] == p["summary"]["points"] > 0


def test_messages_go_beside_the_item_at_fault(studio):
    d = design(text_item("ok"), text_item("euro", text="5 €", at=[60, 5]),
               text_item("high", text="UP", at=[80, 19]))
    status, p = call(studio, "/api/preview", {"design": d})
    assert status == 200 and not p["errors"]
    assert "'€'" in p["items"]["euro"]["errors"][0] and "not in font" in p["items"]["euro"]["errors"][0]
    assert p["items"]["high"]["errors"][0].startswith("the text 'UP' reaches from 19 to 25 mm above the bed")
    assert not p["items"]["ok"]["errors"] and p["points"]          # the good one still builds
    assert {o for pt in p["points"] for o in pt[6]} == {"ok"}


def test_unreached_points_are_counted_beside_their_item(studio):
    # a tolerance under the map's 0.1 mm quantum: some points fall off their moves
    status, p = call(studio, "/api/preview", {"design": design(text_item("t"), tolerance=0.01), "check": True})
    assert status == 200
    missed = p["summary"]["missed"]
    assert missed > 0 and sum(pt[7] for pt in p["points"]) == missed
    assert f"{missed} point(s) not within 0.01 mm" in p["items"]["t"]["warnings"][0]


def test_a_layer_over_the_limit_is_said_and_the_rest_still_shows(studio):
    # four default texts on one row: their top bars put 4 x 17 points on the layer at z 13.20,
    # more than the firmware's 64; the other layers' bumps stay, and the export refuses
    texts = [text_item(f"t{k}", text="TEXT", at=[5 + 23 * k, 7.05]) for k in range(4)]
    status, p = call(studio, "/api/preview", {"design": design(*texts), "check": True})
    assert status == 200
    assert p["errors"] == ["too many points in 1 layer(s) (at most 64 per layer): z 13.20 mm: 68. Increase "
                           "Spacing (now 0.90 mm) or simplify the strokes. Until they fit, those layers get no "
                           "bumps (drawn red) and Export refuses the design; the items on them say so."]
    for t in texts:
        it = p["items"][t["id"]]
        assert it["strokes"] and it["errors"] == [
            "on 1 layer(s) over the printer's 64 points per layer (z 13.20 mm: 68 points, 17 its own); "
            "those layers get no bumps: move it to another height, make it smaller or increase Spacing"]
        mine = [pt for pt in p["points"] if t["id"] in pt[6]]
        assert sum(not pt[8] for pt in mine) > 80 and sum(pt[8] for pt in mine) == 17
    assert {pt[4] for pt in p["points"] if pt[8]} == {13.2}
    s = p["summary"]
    assert s["over"] == 1 and s["points"] == sum(not pt[8] for pt in p["points"]) and not s["checked"]
    job = wait_job(studio, call(studio, "/api/export", {"design": design(*texts)})[1])
    assert job["state"] == "error" and "z 13.20 mm: 68. Increase Spacing" in job["error"]


def test_arena_warning(tmp_path):
    run = start(tmp_path, arena=64)
    try:
        open_gcode(run)
        status, p = call(run, "/api/preview", {"design": design(text_item())})
        assert status == 200 and any("64-byte arena" in w for w in p["warnings"])
    finally:
        run.stop()


def test_bad_settings_are_reported(studio):
    status, p = call(studio, "/api/preview", {"design": design(text_item(), dwell=-5)})
    assert status == 200 and p["errors"] and "dwell" in p["errors"][0]


# -- placement files

def test_dump_placement_reads_back(tmp_path):
    (tmp_path / "w.svg").write_text(SVG)
    text = dump_placement([{"text": 'say "hi"\\ \u00e9\n2', "at": [1.5, 2], "size": 5, "rotate": 30.0}],
                          [{"file": "w.svg", "at": [10, 3], "scale": 0.5, "rotate": -90}],
                          {"dwell": 80, "extra": 0.05, "geometric": False})
    p = tmp_path / "p.toml"
    p.write_text(text)
    pl = load_placement(p)
    assert pl.bulges == {"dwell": 80, "extra": 0.05, "geometric": False}
    assert pl.entries == ["text[0]", "strokes[0]"]
    assert all(s.source.startswith(("text[0]", "strokes[0]")) for s in pl.strokes)


def test_rotate_turns_strokes_about_at(tmp_path):
    (tmp_path / "w.svg").write_text(SVG)
    base = [{"file": "w.svg", "at": [10, 3]}]
    p0, p90 = tmp_path / "a.toml", tmp_path / "b.toml"
    p0.write_text(dump_placement([], base, {}))
    p90.write_text(dump_placement([], [base[0] | {"rotate": 90}], {}))
    a, b = load_placement(p0).strokes, load_placement(p90).strokes
    for sa, sb in zip(a, b):
        for (u, v), (ru, rv) in zip(sa.points, sb.points):
            assert ru == pytest.approx(10 - (v - 3)) and rv == pytest.approx(3 + (u - 10))


# -- export = CLI, byte for byte

def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_export_is_byte_identical_to_the_cli(studio, tmp_path):
    status, svg = call(studio, "/api/asset?name=cross.svg", SVG.encode())
    img = tmp_path / "dot.png"
    Image.new("L", (8, 4), 0).save(img)
    status, pic = call(studio, "/api/asset?name=dot.png", img.read_bytes())
    d = design(text_item("t", text="Hi!", at=[3.25, 6.5], rotate=12.5, letter_spacing=0.3),
               {"id": "s", "kind": "file", "asset": svg["name"], "at": [45, 5], "scale": 0.6, "rotate": -20},
               {"id": "p", "kind": "file", "asset": pic["name"], "at": [80, 8], "image_width": 6},
               dwell=120, extra=0.08, spacing=1.0, e_steps=415, stop_e_steps=7)
    d["name"] = "mine"
    job = wait_job(studio, call(studio, "/api/export", {"design": d})[1])
    assert job["state"] == "done", job["error"]
    folder = Path(job["result"]["folder"])
    names = {f["name"] for f in job["result"]["files"]}
    made = {"mine.bkm", "mine.bulge.gcode", "mine.stock.gcode", "mine.stats.txt", "mine.preview.png",
            "mine.preview3d.png"}
    assert names == made | {"placement.toml", svg["name"], pic["name"]}
    cli = cli_build(GCODE, folder / "placement.toml", tmp_path / "cli", "mine")
    assert {p.name for p in cli} == made
    for p in cli:
        assert _sha(p) == _sha(folder / p.name), p.name
    # the stock file's stops are E-only moves with the design's E steps (issue 25)
    stock = (folder / "mine.stock.gcode").read_text()
    assert "at 415 E steps/mm" in stock.splitlines()[0] and ", 7 E steps each" in stock.splitlines()[0]
    assert "\nG4 P" not in stock
    # the downloads are those files, and the zip holds them all
    status, body = call(studio, f"/files/exports/{job['result']['key']}/mine.bkm", raw=True)
    assert status == 200 and body == (folder / "mine.bkm").read_bytes()
    status, body = call(studio, job["result"]["zip"], raw=True)
    assert status == 200 and body[:2] == b"PK"
    # and the placement endpoint writes the same file text
    status, text = call(studio, "/api/placement", {"design": d}, raw=True)
    assert text == (folder / "placement.toml").read_bytes()


def test_export_failure_leaves_nothing(studio):
    before = set((studio.studio.workdir / "exports").iterdir())
    job = wait_job(studio, call(studio, "/api/export", {"design": design(text_item(text="€"))})[1])
    assert job["state"] == "error" and "not in font" in job["error"]
    assert set((studio.studio.workdir / "exports").iterdir()) == before


# -- sending through the existing sender

def test_send_streams_the_export_with_progress(studio, tmp_path):
    job = wait_job(studio, call(studio, "/api/export", {"design": design(text_item())})[1])
    key = job["result"]["key"]
    with fake_printer(arena=1024) as (port, printer):
        status, j = call(studio, "/api/send", {"export": key, "which": "bulge", "port": port,
                                               "baud": 115200})
        assert status == 200
        j = wait_job(studio, j, timeout=120)
        assert j["state"] == "done", j["error"]
        sent = [ln for ln in (Path(job["result"]["folder"]) / "part.bulge.gcode").read_text().splitlines()
                if ln.split(";")[0].strip()]
        assert j["done"] == j["total"] == len(sent)
        assert printer.executed[-len(sent):] == [ln.split(";")[0].strip() for ln in sent]
        assert any(m.startswith("echo:BulgeMap") for m in j["log"])       # the arena check (M721)


def test_send_errors_are_clear(studio):
    status, body = call(studio, "/api/send", {"export": "nope", "port": "", "which": "bulge"})
    assert status == 400 and "port" in body["error"]
    status, j = call(studio, "/api/send", {"export": "nope", "port": "/dev/null-none", "which": "bulge"})
    j = wait_job(studio, j)
    assert j["state"] == "error" and "export first" in j["error"]


# -- lithophanes

def make_litho(studio, tmp_path, options, size=(40, 30)):
    img = tmp_path / "grad.png"
    Image.linear_gradient("L").resize(size).save(img)       # black at the top, white at the bottom
    status, info = call(studio, "/api/asset?name=grad.png", img.read_bytes())
    assert status == 200, info
    return info, wait_job(studio, call(studio, "/api/litho", {"asset": info["name"], "options": options})[1])


def test_litho_job_makes_the_cli_files(studio, tmp_path):
    info, job = make_litho(studio, tmp_path, {"width": 20})
    assert job["state"] == "done", job["error"]
    res = job["result"]
    names = {f["name"] for f in res["files"]}
    assert names == {"grad.litho.gcode", "grad.stock.gcode", "grad.stl", "grad.transmission.png",
                     "grad.litho.json"}
    # the figures in the page's words: no CLI options or ASCII units, no working folder
    figures = dict(res["figures"])
    assert {"Print time", "Filament", "Fastest head speed", "Mid-line flow"} <= set(figures)
    assert "SSIM" in figures["Picture vs the print as sampled (a model)"] and figures["Mid-line flow"] == "8 mm³/s"
    assert figures["How the picture lies"].startswith("picture 20.0 x 15.0 mm: the height from the picture's aspect")
    text = repr(res)
    assert "--" not in text and "mm^3" not in text and str(studio.studio.workdir) not in text
    status, body = call(studio, res["look"], raw=True)
    assert status == 200 and body[:4] == b"\x89PNG"
    # the printer's acceleration: the times assume it and the automatic mid-line flow follows it
    slow = wait_job(studio, call(studio, "/api/litho", {"asset": info["name"], "options": {"width": 20, "accel": 1000}})[1])
    assert slow["state"] == "done", slow["error"]
    fig = dict(slow["result"]["figures"])
    assert fig["Mid-line flow"].startswith("4.62 mm³/s (lowered for a printer at 1000") and "1000" in fig["Times assume"]
    bad = wait_job(studio, call(studio, "/api/litho", {"asset": info["name"],
                                                       "options": {"min_thickness": 3, "max_thickness": 1}})[1])
    assert bad["state"] == "error" and "'Thickest (black)'" in bad["error"] and "--" not in bad["error"]
    bad = wait_job(studio, call(studio, "/api/litho", {"asset": info["name"], "options": {"colour": 1}})[1])
    assert bad["state"] == "error" and "colour" in bad["error"]


def test_litho_figures_show_the_look_block_they_are_given():
    from bulgekit.studio.server import litho_figures
    # a toolkit with lightness figures: those are shown, the plain SSIM gives way to the one on L*
    f = dict(litho_figures({"look": {"curve": "perceptual", "L_range": [38.2, 100.0], "new_figure": 0.25,
                                     "picture_vs_print": {"mean_abs_dL": 2.94, "ssim_L": 0.853,
                                                          "sampled_mm": [0.4, 0.2], "scatter_sigma_mm": 0.5}}}))
    assert f == {"Picture vs the print as sampled (a model)":
                 "mean 2.9 ΔL*, SSIM 0.85 (sampled 0.4 x 0.2 mm, light scatter 0.5 mm)",
                 "Lightness range the plate shows": "38–100 L*", "new figure": "0.25"}
    assert litho_figures({}) == []
    f = dict(litho_figures({"options": {"max_speed": 150}, "estimate": {
        "estimated_time_s_gcode": 3720, "machine": {"new_setting_mm": 3}}}))
    assert f == {"Print time": "1 h 02 min (bulgekit firmware)", "Fastest head speed": "150 mm/s",
                 "Times assume": "new setting mm 3"}


def test_litho_figures_word_what_the_toolkit_writes():
    """The machine and look blocks as `bulgekit litho` writes them, in the page's words."""
    from bulgekit import litho as lt
    from bulgekit.gcode import estimate
    from bulgekit.studio.server import litho_figures
    f = dict(litho_figures({"estimate": {"estimated_time_s_gcode": 60, "machine": lt.machine_words(estimate.Machine())},
                            "gaps": {"narrowed_share": 0.187}}))
    assert f["Times assume"] == "acceleration 3000 mm/s², junction deviation 0.013 mm, look-ahead of 16 moves"
    assert f["Light tones"] == "a thin mid-line between narrower walls, 18.7 % of the samples"
    w = {"back_mm": {"min": 0.2, "median": 0.257, "max": 0.4}, "front_mm": {"min": 0.2, "median": 0.338, "max": 0.8}}
    assert dict(litho_figures({"walls": w}))["Walls"] == "back mostly 0.26 mm wide (0.20–0.40), front 0.20–0.80 mm"
    m = lt.machine_words(estimate.Machine(accel=1000, travel_accel=3000, jerk={"X": 10, "Y": 10, "Z": 0.3, "E": 5},
                                          lookahead=None))
    assert dict(litho_figures({"machine": m}))["Times assume"] == \
        "acceleration 1000 mm/s² (travel 3000), classic jerk 10/10/0.3/5 mm/s, look-ahead over the whole file"


def test_litho_view_is_the_relief_and_its_look(studio, tmp_path):
    """The 3D view's data: the printed relief on a grid of at most VIEW_CELLS a side (the last
    row and column kept), the predicted look as a texture."""
    import base64
    import numpy as np
    from bulgekit.studio.server import VIEW_CELLS
    _, job = make_litho(studio, tmp_path, {"width": 110, "height": 10, "curve": "linear", "stretch": True})
    assert job["state"] == "done", job["error"]
    status, v = call(studio, job["result"]["view"])
    assert status == 200 and v["shape"] == "planar"
    assert v["cols"] <= VIEW_CELLS < 276 and v["s"][0] == 0 and v["s"][-1] == 110
    assert len(v["s"]) == len(v["u"]) == v["cols"] and len(v["z"]) == len(v["v"]) == v["rows"] == 50
    t = np.frombuffer(base64.b64decode(v["thickness_um"]), "<u2").reshape(v["rows"], v["cols"]) / 1000
    assert 0.8 - 1e-3 <= t.min() and t.max() <= 2.4 + 1e-3
    # the picture is white at the bottom: thin there, thick at the top (rows go up)
    assert t[:5].mean() < 1.2 < 2.0 < t[-5:].mean()
    lk = v["look"]
    look = np.frombuffer(base64.b64decode(lk["data"]), np.uint8).reshape(lk["height"], lk["width"])
    assert lk["width"] == 276 and lk["height"] == 50          # the texture keeps every sample
    assert look[:5].mean() - look[-5:].mean() > 80             # light where the picture is
    assert np.corrcoef(look.mean(axis=1), -t.mean(axis=1))[0, 1] > 0.9       # (both 50 rows here)
    status, body = call(studio, "/api/litho/nope/view")
    assert status == 404


def test_litho_light_gaps_from_the_form(studio, tmp_path):
    """The form's "Light tones" and "Plan for acceleration" reach the toolkit."""
    for mode in ("walls", "mid-line"):
        _, job = make_litho(studio, tmp_path, {"width": 12, "light_gaps": mode, "rate_accel": 3000}, size=(24, 12))
        assert job["state"] == "done", job["error"]
        plan = studio.studio.lithos[job["result"]["key"]]
        j = json.loads(plan["paths"]["json"].read_text())
        assert j["gaps"]["light_gaps"] == mode and j["options"]["rate_accel"] == 3000


def test_litho_form_choices_come_from_the_toolkit(studio):
    from bulgekit import litho as lt
    status, st = call(studio, "/api/state")
    c = st["litho"]
    assert c["curves"] == list(lt.CURVES) and c["shapes"] == list(lt.SHAPES)
    assert c["light_gaps"] == list(lt.LIGHT_GAPS)
    assert c["defaults"]["curve"] == lt.LithoOptions().curve and c["defaults"]["foot"] == lt.LithoOptions().foot
    assert c["defaults"]["light_gaps"] == "mid-line" and c["defaults"]["rate_accel"] == lt.LithoOptions().rate_accel


def test_send_a_lithophane_to_the_printer(studio, tmp_path):
    _, job = make_litho(studio, tmp_path, {"width": 12}, size=(24, 12))
    assert job["state"] == "done", job["error"]
    key = job["result"]["key"]
    with fake_printer(arena=1024) as (port, printer):
        status, j = call(studio, "/api/send", {"litho": key, "which": "stock", "port": port, "baud": 115200})
        assert status == 200
        j = wait_job(studio, j, timeout=300)
        assert j["state"] == "done", j["error"]
        sent = [ln.split(";")[0].strip() for ln in studio.studio.lithos[key]["paths"]["stock"].read_text().splitlines()
                if ln.split(";")[0].strip()]
        assert j["done"] == j["total"] == len(sent) and j["result"]["file"].endswith(".stock.gcode")
        assert printer.executed[-len(sent):] == sent
    for body, message in (({"litho": "nope", "which": "litho"}, "make it first"),
                          ({"litho": key, "which": "bulge"}, "'litho' or 'stock'")):
        status, j = call(studio, "/api/send", {**body, "port": "/dev/null-none"})
        j = wait_job(studio, j)
        assert j["state"] == "error" and message in j["error"]


# -- the command

def test_studio_command_prints_its_address_and_stops_on_ctrl_c(tmp_path):
    import signal
    import subprocess
    import sys
    p = subprocess.Popen([sys.executable, "-m", "bulgekit.cli", "studio", str(GCODE), "--no-browser",
                          "--port", "0", "--workdir", str(tmp_path / "w")], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        assert line.startswith("bulgekit studio: http://127.0.0.1:"), line
        url = line.split()[2]
        with urllib.request.urlopen(url) as r:
            assert r.status == 200 and b"bulgekit studio" in r.read()
        # taken: the same port again is a one-line error
        port = url.rstrip("/").rsplit(":", 1)[1]
        r2 = subprocess.run([sys.executable, "-m", "bulgekit.cli", "studio", "--no-browser", "--port", port,
                             "--workdir", str(tmp_path / "w2")], capture_output=True, text=True, timeout=60)
        assert r2.returncode == 1 and f"cannot listen on 127.0.0.1:{port}" in r2.stderr
    finally:
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    assert p.returncode == 0 and "stopped" in out, err


def test_missing_front_end_files_are_a_clear_error(tmp_path, monkeypatch):
    from bulgekit.studio import server
    from bulgekit.errors import BulgekitError
    (tmp_path / "static" / "vendor").mkdir(parents=True)
    monkeypatch.setattr(server, "STATIC", tmp_path / "static")
    with pytest.raises(BulgekitError, match=r"three\.module\.min\.js.*host/web/build\.py"):
        server.serve(server.Studio(tmp_path / "w"), 0)


# -- opening a placement file

def _upload(run, path):
    status, info = call(run, f"/api/asset?name={Path(path).name}", Path(path).read_bytes())
    assert status == 200, info
    return info["name"]


def test_import_of_the_example_placement_exports_the_same_files(studio, tmp_path):
    ex = GCODE.parent
    wave = _upload(studio, ex / "wave.json")
    status, d = call(studio, "/api/import", {"toml": (ex / "placement.toml").read_text(),
                                             "files": {"wave.json": wave}})
    assert status == 200, d
    assert [i["kind"] for i in d["items"]] == ["text", "file"] and d["items"][0]["text"] == "HELLO"
    d["name"] = "ex"
    job = wait_job(studio, call(studio, "/api/export", {"design": d})[1])
    assert job["state"] == "done", job["error"]
    folder = Path(job["result"]["folder"])
    original = cli_build(GCODE, ex / "placement.toml", tmp_path / "orig", "ex")
    assert original and all(_sha(p) == _sha(folder / p.name) for p in original)


@pytest.mark.parametrize("toml,files,message", [
    ("[[strokes]]\nfile = 'art/wave.json'\n", {}, "strokes[0].file: art/wave.json was not chosen with it"),
    ("[[text]\ntext = 'x'\n", {}, "not valid TOML"),
    ("[[text]]\ntext = 'x'\ncolour = 'red'\n", {}, "text[0]: unknown key 'colour'"),
    ("[[text]]\ntext = 'x'\nfont = 'nope'\n", {}, "unknown font 'nope'"),
    ("[[text]]\ntext = 'x'\n[extras]\n", {}, "unknown table 'extras'"),
    ("[bulges]\ndwell = 'long'\n", {}, "bulges.dwell: expected a whole number"),
])
def test_import_errors_name_the_entry(studio, toml, files, message):
    status, body = call(studio, "/api/import", {"toml": toml, "files": files})
    assert status == 400 and message in body["error"] and body["error"].startswith("placement file")


# -- found in review: names, paths, modes, partial files

def test_names_with_dots_and_drawings_named_like_outputs(studio, tmp_path):
    clash = _upload(studio, _png(tmp_path / "bracket.v2.preview.png"))
    d = design(text_item(), {"id": "p", "kind": "file", "asset": clash, "at": [60, 5], "image_width": 6})
    d["name"] = "bracket.v2"
    job = wait_job(studio, call(studio, "/api/export", {"design": d})[1])
    assert job["state"] == "done", job["error"]
    assert call(studio, job["result"]["zip"], raw=True)[0] == 200
    folder = Path(job["result"]["folder"])
    assert (folder / "drawing-bracket.v2.preview.png").read_bytes() == (tmp_path / "bracket.v2.preview.png").read_bytes()
    cli = cli_build(GCODE, folder / "placement.toml", tmp_path / "cli", "bracket.v2")
    assert all(_sha(p) == _sha(folder / p.name) for p in cli)


def _png(path, size=(8, 4)):
    Image.new("L", size, 0).save(path)
    return path


def test_item_messages_name_the_users_files_and_fields(studio, tmp_path):
    pic = _upload(studio, _png(tmp_path / "dot.png"))
    d = design(text_item(), {"id": "p", "kind": "file", "asset": pic, "at": [60, 5]})
    status, p = call(studio, "/api/preview", {"design": d})
    assert status == 200 and not p["errors"]
    msg = p["items"]["p"]["errors"][0]
    assert msg == f"{pic} is a picture: give image_width (its width on the wall, mm)"


def test_preview_follows_the_mode_setting(studio):
    marked = call(studio, "/api/preview", {"design": design(text_item()), "check": True})[1]
    geo = call(studio, "/api/preview", {"design": design(text_item(), geometric=True), "check": True})[1]
    assert marked["summary"]["stops"] == marked["summary"]["points"] > 0 and "walls" not in marked
    assert geo["summary"]["stops"] == geo["summary"]["points"] > 0 and not geo["errors"]
    assert geo["walls"]["geometric"] is True                   # the page redraws the walls it uses
    back = call(studio, "/api/preview", {"design": design(text_item())})[1]
    assert back["walls"]["geometric"] is False
    assert call(studio, "/api/state")[1]["gcode"]["walls"]["geometric"] is False


def test_a_file_without_outer_wall_comments_asks_for_geometric_mode(tmp_path):
    data = b"\n".join(l for l in GCODE.read_bytes().split(b"\n") if not l.startswith(b";TYPE:"))
    src = tmp_path / "plain.gcode"
    src.write_bytes(data)
    run = start(tmp_path / "w")
    try:
        job = open_gcode(run, src)
        assert job["state"] == "done" and job["result"]["geometric"]
        assert any("geometric" in m for m in job["log"])
        p = call(run, "/api/preview", {"design": design(text_item())})[1]       # marked mode asked
        assert "plain.gcode: no outer-wall feature comments" in p["errors"][0]
        assert "choose Mode: geometric" in p["errors"][0] and str(tmp_path) not in p["errors"][0]
        p = call(run, "/api/preview", {"design": design(text_item(), geometric=True), "check": True})[1]
        assert not p["errors"] and p["summary"]["stops"] == p["summary"]["points"] > 0
    finally:
        run.stop()


def test_an_upload_cut_off_leaves_nothing(studio):
    import socket
    host, port = studio.url.split("//")[1].rstrip("/").split(":")
    s = socket.create_connection((host, int(port)))
    s.sendall((f"POST /api/gcode?name=cut.gcode HTTP/1.1\r\nHost: {host}:{port}\r\n"
               f"X-Studio-Token: {studio.studio.token}\r\nContent-Length: 1200000\r\n\r\n").encode()
              + b";" * 600_000)
    time.sleep(0.5)
    s.close()
    time.sleep(0.5)
    assert not [p.name for p in (studio.studio.workdir / "gcode").iterdir() if "cut" in p.name]
    assert call(studio, "/api/state")[0] == 200


def test_progress_listeners_hear_only_their_own_thread():
    import threading
    from bulgekit import progress
    heard_a, heard_b = [], []

    def a():
        progress.listen(lambda *x: heard_a.append(x))
        with progress.phase("walls A", 10):
            progress.tick(5)
        progress.listen(None)

    def b():
        progress.listen(lambda *x: heard_b.append(x))
        time.sleep(0.2)
        progress.listen(None)
    tb = threading.Thread(target=b)
    tb.start()
    ta = threading.Thread(target=a)
    ta.start()
    ta.join()
    tb.join()
    assert heard_a and all(x[0] == "walls A" for x in heard_a) and not heard_b


def test_file_names_keep_their_extension_and_differ_beyond_case(studio):
    from bulgekit.studio.design import safe_name
    assert safe_name("логотип.svg") == "file.svg" and safe_name("../a b.v2.json") == "a_b.v2.json"
    assert safe_name("my part.v2 \u00fcn\u00ef", "part") == "my_part.v2_n"
    assert _upload_bytes(studio, "логотип.svg", SVG.encode()) == "file.svg"
    assert _upload_bytes(studio, "Sign.svg", SVG.encode()) == "Sign.svg"
    assert _upload_bytes(studio, "sign.svg", SVG.encode()) == "sign-2.svg"


def _upload_bytes(run, name, data):
    import urllib.parse
    status, info = call(run, f"/api/asset?name={urllib.parse.quote(name)}", data)
    assert status == 200, info
    return info["name"]


def test_downloads_are_sandboxed_attachments(studio):
    job = wait_job(studio, call(studio, "/api/export", {"design": design(text_item())})[1])
    url = studio.url.rstrip("/") + job["result"]["files"][0]["url"] + "?t=" + studio.studio.token
    with urllib.request.urlopen(url) as r:
        assert r.headers["Content-Disposition"].startswith("attachment;")
        assert r.headers["Content-Security-Policy"].startswith("sandbox")


def test_import_messages_name_the_users_files(studio, tmp_path):
    pic = _upload(studio, _png(tmp_path / "spot.png"))
    status, body = call(studio, "/api/import", {"toml": "[[strokes]]\nfile = 'spot.png'\n", "files": {"spot.png": pic}})
    assert status == 400 and str(studio.studio.workdir) not in body["error"]
    assert body["error"] == "placement file: strokes[0]: spot.png is a picture: give image_width (its width on the wall, mm)"
    status, body = call(studio, "/api/import", {"toml": "[[strokes]]\nfile = 'spot.png'\nimage_width = -2\n",
                                                "files": {"spot.png": pic}})
    assert status == 400 and str(studio.studio.workdir) not in body["error"] and "--" not in body["error"]


def test_litho_arc_view_and_figures(tmp_path):
    """The arc (issue 37): the view places its samples on the arc, the figures say how the
    picture lies and whether the part stands."""
    import numpy as np
    from PIL import Image
    from bulgekit import litho as lt
    from bulgekit.studio.server import litho_figures, litho_view
    Image.fromarray((np.arange(40 * 30).reshape(30, 40) % 251).astype(np.uint8)).save(tmp_path / "p.png")
    res = lt.make(tmp_path / "p.png", tmp_path / "o", options=lt.LithoOptions(shape="arc", diameter=30.0))
    v = litho_view(res.plan)
    assert v["shape"] == "arc" and v["r_in"] == 15.0 - 2.4
    assert v["arc_start"] == pytest.approx(-np.pi / 2 - np.radians(120) / 2, abs=1e-5)
    f = dict(litho_figures(res.stats))
    assert f["How the picture lies"] == res.stats["picture"]["note"]
    assert f["Stands by itself"].startswith("yes: centre of mass")
    assert "arc" in lt.SHAPES


# -- issue 37/38: braille items, the printer model, names of pictures chosen again

def braille_item(iid="b", **kw):
    return {"id": iid, "kind": "braille", "text": "Hello", "at": [70, 4]} | kw


def test_dump_placement_writes_braille_that_reads_back(tmp_path):
    text = dump_placement([{"text": "HI", "at": [1, 6]}], [],
                          {"dwell": 100}, braille=[{"text": "Hello", "at": [5, 3], "grade": 2},
                                                   {"text": "Gruß", "at": [5, 12], "table": "de-g1.ctb",
                                                    "face": 1, "align": "left"}])
    assert text.index("[[text]]") < text.index("[[braille]]")
    p = tmp_path / "p.toml"
    p.write_text(text)
    pl = load_placement(p)
    assert pl.entries == ["text[0]", "braille[0]", "braille[1]"]
    # what load refuses, dump refuses, naming the entry
    from bulgekit.bulge.placement import PlacementError
    with pytest.raises(PlacementError, match=r"braille\[0\]: unknown key 'size'"):
        dump_placement([], [], {}, braille=[{"text": "x", "size": 6}])
    with pytest.raises(PlacementError, match=r"braille\[0\].grade: expected a whole number"):
        dump_placement([], [], {}, braille=[{"text": "x", "grade": "2"}])


def test_braille_item_previews_and_exports_as_the_cli(studio, tmp_path):
    d = design(text_item(), braille_item(grade=2), dwell=120)
    status, p = call(studio, "/api/preview", {"design": d})
    assert status == 200 and not p["errors"], p
    assert p["items"]["b"]["strokes"] and not p["items"]["b"]["errors"]
    assert any("b" in q[6] for q in p["points"])
    # a table by name instead of a grade; a bad one is said beside the item
    status, p = call(studio, "/api/preview", {"design": design(braille_item(table="nope.ctb"))})
    assert status == 200 and p["items"]["b"]["errors"] and "nope.ctb" in p["items"]["b"]["errors"][0]
    # what this print cannot make readable is said beside it too (as build refuses it)
    status, p = call(studio, "/api/preview", {"design": design(text_item(), braille_item(), dwell=600)})
    assert p["items"]["b"]["errors"] and "readable dot" in p["items"]["b"]["errors"][0]
    assert p["items"]["t1"]["strokes"]
    d["name"] = "dots"
    job = wait_job(studio, call(studio, "/api/export", {"design": d})[1])
    assert job["state"] == "done", job["error"]
    folder = Path(job["result"]["folder"])
    assert '[[braille]]\ntext = "Hello"\nat = [70, 4]\ngrade = 2\n' in (folder / "placement.toml").read_text()
    cli = cli_build(GCODE, folder / "placement.toml", tmp_path / "cli", "dots")
    assert len(cli) == 6 and all(_sha(p) == _sha(folder / p.name) for p in cli)
    # and a placement file with braille comes in as braille items
    status, back = call(studio, "/api/import", {"toml": (folder / "placement.toml").read_text(), "files": {}})
    assert status == 200 and [i["kind"] for i in back["items"]] == ["text", "braille"]


def test_printer_model_reaches_the_stock_file_as_the_cli(studio, tmp_path):
    stock = {}
    for printer in (None, "prusa-mk3s"):
        d = design(text_item(), fallback=True, **({"printer": printer} if printer else {}))
        d["name"] = f"pm-{printer}"
        job = wait_job(studio, call(studio, "/api/export", {"design": d})[1])
        assert job["state"] == "done", job["error"]
        folder = Path(job["result"]["folder"])
        cli = cli_build(GCODE, folder / "placement.toml", tmp_path / str(printer), d["name"])
        assert all(_sha(p) == _sha(folder / p.name) for p in cli)
        stock[printer] = (folder / f"{d['name']}.stock.gcode").read_text()
    assert "bulgekit printer: prusa-mk3s (prusa)" in stock["prusa-mk3s"]
    assert stock["prusa-mk3s"].split("\n", 2)[2] != stock[None].split("\n", 2)[2]
    # a profile file by its path (made absolute in the placement file), and one not there
    prof = tmp_path / "mine.toml"
    from click.testing import CliRunner
    from bulgekit.cli import main
    r = CliRunner().invoke(main, ["printer", "show", "ender3", "--toml"])
    prof.write_text(r.output)
    status, text = call(studio, "/api/placement", {"design": design(text_item(), printer=str(prof))}, raw=True)
    assert f'printer = "{prof}"'.encode() in text
    status, p = call(studio, "/api/preview", {"design": design(text_item(), printer=str(prof))})
    assert not p["errors"], p["errors"]
    status, p = call(studio, "/api/preview", {"design": design(text_item(), printer=str(tmp_path / "gone.cfg"))})
    assert p["errors"] and "neither a file nor a preset" in p["errors"][0] and "--" not in p["errors"][0]


def test_a_picture_chosen_again_keeps_its_name(studio, tmp_path):
    img = tmp_path / "face.png"
    Image.linear_gradient("L").resize((30, 24)).save(img)
    first = _upload_bytes(studio, "face.png", img.read_bytes())
    assert first == "face.png"
    # the same picture again: the same file, not face-2.png
    assert _upload_bytes(studio, "face.png", img.read_bytes()) == "face.png"
    job = wait_job(studio, call(studio, "/api/litho", {"asset": "face.png", "options": {"width": 20}})[1])
    assert job["state"] == "done", job["error"]
    assert {f["name"] for f in job["result"]["files"]} >= {"face.litho.gcode", "face.stl"}
    # another picture of that name: kept apart (a design may use the first), but its
    # lithophane is still named after the picture
    Image.linear_gradient("L").rotate(90).resize((30, 24)).save(img)
    second = _upload_bytes(studio, "face.png", img.read_bytes())
    assert second == "face-2.png"
    job = wait_job(studio, call(studio, "/api/litho", {"asset": second, "options": {"width": 20}})[1])
    assert job["state"] == "done", job["error"]
    assert {f["name"] for f in job["result"]["files"]} >= {"face.litho.gcode", "face.stl"}
    # the last lithophane is in the state a reloaded page reads
    status, st = call(studio, "/api/state")
    last = st["litho_last"]
    assert last["key"] == job["result"]["key"] and last["picture"]["name"] == "face-2.png"
    assert last["options"] == {"width": 20} and last["figures"] == job["result"]["figures"]
