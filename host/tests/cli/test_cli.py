import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from bulgekit.bulge import mapformat
from bulgekit.cli import main

REPO = Path(__file__).resolve().parents[3]


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)
    return r


def test_help_lists_the_commands():
    r = run("--help")
    assert r.exit_code == 0
    for cmd in ("build", "annotate", "fallback", "stats", "demo"):
        assert re.search(rf"^\s+{cmd}\s+\S", r.output, re.M), cmd
    assert "u = mm along the wall" in r.output


def test_build_writes_map_gcode_stats_and_fallback(tmp_path, data_dir):
    strokes = tmp_path / "s.json"
    strokes.write_text(json.dumps({"strokes": [{"points": [[3, 1], [3, 5]]}]}))
    r = run("build", data_dir / "prusa_cyl.gcode", "-s", strokes, "--text", "I", "--at", "10,2",
            "-o", tmp_path / "out", "--fallback", "--no-preview", "--dwell", "150")
    assert r.exit_code == 0, r.output
    out = tmp_path / "out"
    m = mapformat.decode_map((out / "prusa_cyl.bkm").read_bytes())
    assert m.point_count > 20
    g = (out / "prusa_cyl.bulge.gcode").read_text()
    assert "M720 S1 P150 E0.100 T0.250" in g and "M722 S1" in g
    stock = (out / "prusa_cyl.stock.gcode").read_text()
    # each stop an E-only move: 8 steps at 53 steps/s, the whole rate whose stillness by Marlin's
    # AVR step timer (stopmodel.avr_ticks: 7 intervals of its table's 53 steps/s) is nearest
    # 150 ms (149.48 ms, as the simulated Marlin held it), F = (53 - 0.5) x 60 / 93
    assert len(re.findall(r"^G1 E[\d.]+ F33\.871$", stock, re.M)) == m.point_count
    assert "G4 P" not in stock
    assert f"stops when printed: {m.point_count} of {m.point_count}" in (out / "prusa_cyl.stats.txt").read_text()
    r = run("fallback", data_dir / "prusa_cyl.gcode", out / "prusa_cyl.bkm", "-o", tmp_path / "g4.gcode",
            "--dwell", "150", "--stop", "g4")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "g4.gcode").read_text().count("G4 P150") == m.point_count
    assert f"stops as G4 P<ms>: {m.point_count} " in r.output
    r = run("fallback", data_dir / "prusa_cyl.gcode", out / "prusa_cyl.bkm", "-o", tmp_path / "x.gcode",
            "--stop", "wait")
    assert r.exit_code == 2 and "'--stop'" in r.output and not (tmp_path / "x.gcode").exists()


def test_build_without_outer_tags_points_to_geometric(tmp_path, data_dir):
    r = run("build", data_dir / "slic3r_cyl.gcode", "--text", "I", "-o", tmp_path, "--no-preview")
    assert r.exit_code == 1
    assert "no outer-wall feature comments" in r.output and "--geometric" in r.output
    r = run("build", data_dir / "slic3r_cyl.gcode", "--text", "I", "-o", tmp_path, "--no-preview",
            "--geometric")
    assert r.exit_code == 0, r.output
    assert "M720 S2" in (tmp_path / "slic3r_cyl.bulge.gcode").read_text()


def test_bad_gcode_line_is_named(tmp_path):
    g = tmp_path / "bad.gcode"
    g.write_text(";TYPE:External perimeter\nG1 Z0.3\nG1 X10 Y0 E1\nG1 X1O Y2 E2\n")
    r = run("build", g, "--text", "I", "-o", tmp_path, "--no-preview")
    assert r.exit_code == 1
    assert f"{g}:4: unparsable value 'X1O' in 'X1O Y2 E2'" in r.output


def test_settings_out_of_range_are_refused(tmp_path, data_dir):
    r = run("build", data_dir / "prusa_cyl.gcode", "--text", "I", "-o", tmp_path, "--dwell", "2500")
    assert r.exit_code == 2 and "dwell 2500 ms outside 0..2000" in r.output


def test_annotate_fallback_and_stats_commands(tmp_path, data_dir):
    g = data_dir / "prusa_cyl.gcode"
    m = tmp_path / "m.bkm"
    m.write_bytes(mapformat.encode_map([(3.0, [(100.0, 80.225)])]))
    r = run("annotate", g, m, "-o", tmp_path / "a.gcode")
    assert r.exit_code == 0, r.output
    assert "33 layers" not in r.output and "markers" in r.output
    r = run("fallback", g, m, "-o", tmp_path / "f.gcode", "--extra", "0.2")
    assert r.exit_code == 0 and "1 stops" in r.output
    r = run("stats", m, "--gcode", g)
    assert r.exit_code == 0 and "stops when printed: 1 of 1 points" in r.output
    bad = tmp_path / "bad.bkm"
    bad.write_bytes(b"BKM\x01\x00\x32\x1e\x00")
    r = run("stats", bad)
    assert r.exit_code == 1 and "header CRC" in r.output


@pytest.mark.skipif(not (REPO / "examples" / "cylinder40x20.gcode").exists(),
                    reason="demo data lives in the repository's examples/")
def test_demo(tmp_path):
    r = run("demo", tmp_path)
    assert r.exit_code == 0, r.output
    for name in ("demo.bkm", "demo.bulge.gcode", "demo.stock.gcode", "demo.stats.txt",
                 "demo.preview.png", "demo.preview3d.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "demo.preview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_mcodes_stream_uploads_the_map(tmp_path):
    from click.testing import CliRunner
    from bulgekit.bulge import mapformat
    from bulgekit.cli import main
    data = mapformat.encode_map([(0.3, [(10.0, 0.0), (0.0, 10.0)]), (0.6, [(10.0, 0.0)])])
    m = tmp_path / "m.bkm"
    m.write_bytes(data)
    res = CliRunner().invoke(main, ["mcodes", str(m), "--dwell", "150"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0] == "M720 S1 P150 E0.100 T0.250"
    assert lines[1].startswith(f"M721 S{len(data)} C")
    assert lines[-1] == "M721 E"
    # the chunks carry exactly the map's bytes
    import base64
    chunks = [ln.split(" D", 1)[1] for ln in lines if " O" in ln]
    raw = b"".join(base64.b32decode(c + "=" * (-len(c) % 8)) for c in chunks)
    assert raw == data
    numbered = CliRunner().invoke(main, ["mcodes", str(m), "--numbered"]).output.splitlines()
    assert numbered[0] == "M110 N0" and numbered[1].startswith("N1 M720")
    assert all(len(ln) <= 95 for ln in numbered)
    for i, ln in enumerate(numbered[1:], start=1):
        body, cs = ln.rsplit("*", 1)
        assert body.startswith(f"N{i} ")
        x = 0
        for ch in body.encode():
            x ^= ch
        assert int(cs) == x


def test_mcodes_refuses_a_corrupt_map(tmp_path):
    from click.testing import CliRunner
    from bulgekit.cli import main
    bad = tmp_path / "bad.bkm"
    bad.write_bytes(b"BKM\x01\x00\x32\x1e\x00")  # wrong header CRC
    res = CliRunner().invoke(main, ["mcodes", str(bad)])
    assert res.exit_code != 0
    assert "bad.bkm" in res.output


def test_mcodes_and_send_refuse_a_map_larger_than_the_arena(tmp_path):
    # 60 layers of 20 points: about 2.7 KB of records, more than 2048
    layers = [(0.3 * (k + 1), [(float(i * 3), float(k % 7)) for i in range(20)]) for k in range(60)]
    data = mapformat.encode_map(layers, quantum_um=100, layer_height_mm=0.3)
    need = len(data) - mapformat.HEADER_BYTES
    assert need > mapformat.ARENA_BYTES
    m = tmp_path / "big.bkm"
    m.write_bytes(data)
    out = tmp_path / "up.txt"
    for args in (["mcodes", m, "-o", out], ["send", "-p", tmp_path / "no-such-port", "--map", m]):
        r = run(*args)
        assert r.exit_code == 1, r.output
        assert f"big.bkm: the map's layer records need {need} bytes" in r.output
        assert f"arena holds {mapformat.ARENA_BYTES}" in r.output and "bulgekit annotate" in r.output
    assert not out.exists()
    # a larger arena (a firmware built with more) takes it; 0 is refused
    assert run("mcodes", m, "--arena", need, "-o", out).exit_code == 0
    r = run("mcodes", m, "--arena", 0)
    assert r.exit_code == 2 and "--arena" in r.output


@pytest.mark.parametrize("args,option", [
    (["--ref-angle", "nan"], "--ref-angle"), (["--ref-angle", "inf"], "--ref-angle"),
    (["--spacing", "0"], "--spacing"), (["--spacing", "nan"], "--spacing"),
    (["--line-width", "0"], "--line-width"), (["--line-width", "-1"], "--line-width"),
    (["--layer-height", "0"], "--layer-height"), (["--layer-height", "2.5"], "--layer-height"),
    (["--text-size", "nan"], "--text-size"), (["--at", "nan,2"], "--at"),
    (["--tolerance", "nan"], "--tolerance"), (["--arena", "-5"], "--arena"),
])
def test_build_refuses_bad_numbers_naming_the_option(tmp_path, data_dir, args, option):
    r = run("build", data_dir / "prusa_cyl.gcode", "--text", "A", "-o", tmp_path / "o", *args)
    assert r.exit_code == 2, r.output
    assert option in r.output
    assert not (tmp_path / "o").exists()


def test_layer_height_option_only_when_the_gcode_does_not_say(tmp_path, data_dir):
    from bulgekit.bulge.mapbuild import build as build_map
    from bulgekit.bulge.strokes import Stroke
    from bulgekit.bulge.wall import WallError, walls_from_gcode
    g = data_dir / "prusa_cyl.gcode"          # says ; layer_height = 0.3
    m = walls_from_gcode(g, layer_height=0.2)
    assert m.layer_height == 0.3
    assert any("0.2 mm given, but the G-code says 0.3 mm" in n for n in m.notes)
    assert mapformat.decode_map(build_map([Stroke(((5.0, 2.0),))], m).map_bytes).layer_height_cmm == 30
    for bad in (0.0, -0.1, 2.01, float("nan")):
        with pytest.raises(WallError, match="layer height"):
            walls_from_gcode(g, layer_height=bad)
    # a file without the setting takes the option
    text = "".join(l for l in g.read_text().splitlines(keepends=True) if "layer_height" not in l)
    g2 = tmp_path / "nohdr.gcode"
    g2.write_text(text)
    assert walls_from_gcode(g2, layer_height=0.25).layer_height == 0.25


def test_build_strokes_and_preview_agree_on_at_and_tolerances(tmp_path, data_dir):
    g = data_dir / "prusa_cyl.gcode"
    s = tmp_path / "s.json"
    s.write_text(json.dumps({"strokes": [{"points": [[3, 1], [3, 5]]}]}))
    maps = []
    for at in ("0,0", "20,1"):
        r = run("build", g, "-s", s, "--at", at, "-o", tmp_path / at, "--no-preview")
        assert r.exit_code == 0, r.output
        maps.append(mapformat.decode_map((tmp_path / at / "prusa_cyl.bkm").read_bytes()))
    # --at moves a stroke file in build as in strokes/preview (it was ignored)
    assert maps[0].layers[0].z_cmm != maps[1].layers[0].z_cmm
    assert maps[0].layers[0].points != maps[1].layers[0].points
    # same default: a text at the default --at lands the same through both paths
    out = tmp_path / "t.json"
    assert run("strokes", "--text", "I", "-o", out).exit_code == 0
    r1 = run("build", g, "-s", out, "-o", tmp_path / "a", "--no-preview")
    r2 = run("build", g, "--text", "I", "-o", tmp_path / "b", "--no-preview")
    assert r1.exit_code == r2.exit_code == 0, r1.output + r2.output
    assert (tmp_path / "a/prusa_cyl.bkm").read_bytes() == (tmp_path / "b/prusa_cyl.bkm").read_bytes()
    # --tolerance is M720 T only; the SVG curve tolerance is --curve-tolerance everywhere
    r = run("strokes", "--text", "I", "--tolerance", "0.1")
    assert r.exit_code == 2 and "No such option" in r.output
    assert run("strokes", "--text", "I", "--curve-tolerance", "0.1").exit_code == 0
    r = run("build", g, "--text", "I", "--curve-tolerance", "0.1", "--tolerance", "0.3",
            "--size", "5", "-o", tmp_path / "c", "--no-preview")
    assert r.exit_code == 0, r.output
    assert "T0.300" in (tmp_path / "c/prusa_cyl.bulge.gcode").read_text()


def test_a_map_without_points_is_refused(tmp_path):
    from click.testing import CliRunner
    from bulgekit.bulge import mapformat
    from bulgekit.cli import main
    m = tmp_path / "hdr.bkm"
    m.write_bytes(mapformat.encode_map([]))
    g = Path(__file__).resolve().parents[3] / "examples" / "cylinder40x20.gcode"
    for cmd in ("annotate", "fallback"):
        out = tmp_path / f"{cmd}.gcode"
        res = CliRunner().invoke(main, [cmd, str(g), str(m), "-o", str(out)])
        assert res.exit_code == 1, res.output
        assert "no points" in res.output
        assert not out.exists()
