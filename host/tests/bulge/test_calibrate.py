"""`bulgekit calibrate` (bulge/calibrate.py): the dwell and extra-E grid, the labels, the files for
bulgekit firmware and for stock firmware, the bed, all-or-nothing."""
from __future__ import annotations

import re

import numpy as np
import pytest
from click.testing import CliRunner

from bulgekit import machine
from bulgekit.bulge import calibrate as cal
from bulgekit.bulge import fallback, mapformat
from bulgekit.cli import main


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal")
    o = cal.CalibrationOptions(printer=machine.PRESETS["ender3"])
    return o, cal.make(o, out), out


def test_the_grid_is_the_papers():
    assert len(cal.DWELLS_MS) >= 8 and min(cal.DWELLS_MS) == 0 and max(cal.DWELLS_MS) == 500
    assert len(cal.EXTRAS_MM) >= 5 and min(cal.EXTRAS_MM) == 0 and max(cal.EXTRAS_MM) == 0.5
    for ms in cal.DWELLS_MS:                   # each dwell is exactly P x w / 255 for a whole w
        w = cal.weight_of(ms)
        assert (cal.DWELL_P_MS * w + 127) // 255 == ms == cal.DWELL_P_MS * w / 255
    with pytest.raises(cal.CalibrationError):
        cal.weight_of(15)


def test_every_value_is_labelled_in_bumps():
    lay = cal.layout(cal.CalibrationOptions())
    labels = {s.source for s in lay.strokes if s.source.startswith("label ")}
    assert {f"label {ms}" for ms in cal.DWELLS_MS} <= labels
    assert {"label 0", "label .05", "label .1", "label .2", "label .5"} <= labels
    # labels sit under their column, and no two labels of the dwell row overlap
    spans = []
    for ms, u in lay.columns:
        us = [p[0] for s in lay.strokes if s.source == f"label {ms}" and s.points[0][1] < 6 for p in s.points]
        assert abs((min(us) + max(us)) / 2 - u) < 1e-6
        spans.append((min(us), max(us)))
    assert all(a[1] + 1.0 < b[0] for a, b in zip(spans, spans[1:]))
    assert min(p[1] for s in lay.strokes for p in s.points) >= 1.0      # nothing on the first layers


def test_the_map_holds_each_columns_dwell(made):
    o, r, out = made
    bm = mapformat.decode_map(r.paths["map"].read_bytes())
    assert bm.has_weights
    # columns: single bumps at v 8, 10, 12 on the layers there; their weights are the dwells'
    pts = mapformat.decode_map(r.paths["map"].read_bytes())
    ws = {w for layer in pts.layers if 7.5 < layer.z_cmm / 100 < 12.5 for w in layer.weights}
    assert {cal.weight_of(ms) for ms in cal.DWELLS_MS if ms} <= ws


def test_the_bulgekit_file_sets_each_bands_extra(made):
    o, r, out = made
    text = r.paths["bulge"].read_text()
    assert re.search(r"^M720 S1 P510 E0\.100 T0\.250", text, re.M)
    z = None
    seen = []
    for ln in text.splitlines():
        if ln.startswith(";Z:"):
            z = float(ln[3:])
        m = re.match(r"M720 E([0-9.]+) ; extra-E band", ln)
        if m:
            seen.append((float(m.group(1)), z))
    assert [e for e, _ in seen] == list(cal.EXTRAS_MM)
    # each before the band's first layer: the layer above the band's bottom
    for (e, zprev), (_, bottom, _) in zip(seen, r.layout.bands):
        assert zprev == pytest.approx(bottom, abs=1e-6)


def _e_by_layer(path):
    """The filament the file lays, per layer (z): its relative E (M83) added up."""
    z, out = 0.0, {}
    for ln in path.read_text().splitlines():
        if ln.startswith(";Z:"):
            z = round(float(ln[3:]), 2)
        m = re.match(r"G1 .*E(-?[0-9.]+)", ln)
        if m:
            out[z] = out.get(z, 0.0) + float(m.group(1))
    return out


def test_the_stock_file_lays_each_bands_extra(made, tmp_path):
    o, r, out = made
    plain = "".join(cal.part_gcode(o, r.layout.height))
    (tmp_path / "p.gcode").write_text(plain)
    base, stock = _e_by_layer(tmp_path / "p.gcode"), _e_by_layer(r.paths["stock"])
    bm = mapformat.decode_map(r.paths["map"].read_bytes())
    points = {round(layer.z_cmm / 100, 2): len(layer.points) for layer in bm.layers}
    for e, lo, hi in r.layout.bands:
        zs = [z for z in points if lo < z <= hi]
        laid = sum(stock[z] - base[z] for z in zs)
        n = sum(points[z] for z in zs)
        # a stop's E-only move lays whole steps from the host's E put on a whole step (M83: G92 E
        # first, fallback.stop_e_lines), and the next piece lays the rest of the extra: the
        # band's extra is each stop's within half a step (here 0.0054 mm), the pieces' 5 decimals
        half = 0.5 / o.printer.e_steps
        assert abs(laid - n * e) <= n * (half + 1e-5) and abs(laid - n * e) < 0.02 * n * max(e, 0.05), \
            (e, laid, n)
    assert r.stops_stock == r.stops_bulge > 2000


def test_it_fits_the_bed_and_says_the_printer(made):
    o, r, out = made
    xs, ys = [], []
    for ln in r.paths["stock"].read_text().splitlines():
        m = re.match(r"G1 X([0-9.]+) Y([0-9.]+)", ln)
        if m:
            xs.append(float(m.group(1)))
            ys.append(float(m.group(2)))
    assert 0 < min(xs) and max(xs) < 180 and 0 < min(ys) and max(ys) < 180
    assert "; bulgekit printer: ender3 (marlin)" in r.paths["stock"].read_text()[:2000]


def test_a_bed_too_small_writes_nothing(tmp_path):
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["calibrate", "-o", str(out), "--bed", "120,120"])
    assert r.exit_code == 1 and "does not fit a 120 x 120 mm bed" in r.output
    assert not out.exists()


def test_the_command(tmp_path):
    r = CliRunner().invoke(main, ["calibrate", "-o", str(tmp_path), "--printer", "marlin", "--stop", "g4"])
    assert r.exit_code == 0, r.output
    for ext in (".bulge.gcode", ".stock.gcode", ".bkm", ".png"):
        assert (tmp_path / f"calibrate{ext}").is_file()
    assert "M720 P<dwell> E<extra> and M500" in r.output
    assert "stops as G4 P<ms>" in r.output
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".calibrate-")]
