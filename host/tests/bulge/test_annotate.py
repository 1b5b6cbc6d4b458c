import base64
import re
import zlib

import pytest

from bulgekit.bulge import mapformat
from bulgekit.bulge.annotate import AnnotateError, annotate_bytes
from bulgekit.bulge.fallback import Settings
from bulgekit.gcode import iter_moves
from bulgekit.bulge.mapbuild import build
from bulgekit.bulge.strokes import Stroke
from bulgekit.bulge.wall import walls_from_gcode

INSERTED = re.compile(r"^(M72[0-2]\b.*|; bulgekit.*)$")


def strip_inserted(text):
    return "".join(l for l in text.splitlines(keepends=True) if not INSERTED.match(l.rstrip("\r\n")))


class FirmwareModel:
    """What the firmware's map store and layer window do with an annotated file
    (src/bulge_map.cpp, map_upload.cpp, bulge_planner.cpp), in a few lines."""

    def __init__(self, full_map: bytes, arena=2048):
        self.arena = arena
        self.full = mapformat.decode_map(full_map)
        self.records = []          # [(z, size)]
        self.loaded = False
        self.stage = None
        self.layer_z = None
        self.marker = False
        self.mode = 0
        self.errors = []
        self.found = []

    def used(self):
        return sum(s for _, s in self.records)

    def command(self, line):
        w = line.split()
        if w[0] == "M720":
            self.mode = int(w[1][1:])
        elif w[0] == "M722":
            self.marker = w[1] == "S1"
        elif w[0] == "M721":
            args = {x[0]: x[1:] for x in w[1:]}
            if "X" in args:
                self.records, self.loaded, self.layer_z = [], False, None
            elif "S" in args:
                size = int(args["S"])
                # a full map's 8-byte header is kept beside the arena
                need = size if "A" in args else size - mapformat.HEADER_BYTES
                if need > self.arena - self.used():
                    self.errors.append(f"no room for {size} bytes at {self.used()} used")
                self.stage = dict(size=size, crc=int(args["C"]), append="A" in args, data=bytearray())
            elif "O" in args:
                d = args["D"]
                chunk = base64.b32decode(d + "=" * (-len(d) % 8))
                assert int(args["O"]) == len(self.stage["data"])
                self.stage["data"] += chunk
            elif "E" in args:
                st, self.stage = self.stage, None
                data = bytes(st["data"])
                assert len(data) == st["size"] and zlib.crc32(data) == st["crc"]
                if st["append"]:
                    recs = mapformat.decode_records(data, self.full.has_weights,
                                                    self.records[-1][0] if self.records else -1)
                    self.records += [(r.z_cmm, len(mapformat.encode_record(r, self.full.has_weights)))
                                     for r in recs]
                else:
                    m = mapformat.decode_map(data)
                    self.records = [(r.z_cmm, len(mapformat.encode_record(r, m.has_weights)))
                                    for r in m.layers]
                    self.loaded = True

    def move(self, m):
        if self.mode == 0 or (self.mode == 1 and not self.marker) or not m.extruding:
            return
        zc = round(m.z1 * 100)
        h = self.full.layer_height_cmm
        if self.layer_z is not None and 2 * abs(zc - self.layer_z) <= h:
            return
        want = [r.z_cmm for r in self.full.layers if 2 * abs(r.z_cmm - zc) <= h]
        have = [z for z, _ in self.records if 2 * abs(z - zc) <= h]
        if want and not have:
            self.errors.append(f"record z {want[0]} not on the printer at z {zc}")
            return
        if have:
            z = min(have, key=lambda z: (abs(z - zc), z))
            if self.layer_z is None or z > self.layer_z:
                self.records = [r for r in self.records if r[0] >= z]   # release_below
            self.layer_z = z
            self.found.append(z)

    def run(self, text):
        from bulgekit.gcode import parse_lines
        for ln in parse_lines(text.splitlines(keepends=True), "annotated"):
            if ln.cmd in ("M720", "M721", "M722"):
                self.command(ln.raw.split(";")[0].strip())
            for m in ln.moves:
                self.move(m)


@pytest.fixture(scope="module")
def prusa(request):
    from pathlib import Path
    p = Path(__file__).parents[1] / "data" / "prusa_cyl_m83.gcode"
    return p.read_bytes(), walls_from_gcode(p)


def test_moves_are_untouched_and_markers_follow_the_feature_comments(prusa):
    data, model = prusa
    r = build([Stroke(((5.0, 1.0), (5.0, 8.0)))], model)
    out = annotate_bytes(data, r.map_bytes, Settings()).decode()
    assert strip_inserted(out) == data.decode()
    lines = out.splitlines()
    assert lines[1] == "M720 S1 P100 E0.100 T0.250"
    assert out.count("M722 S1") == out.count(";TYPE:External perimeter") == 33
    for i, l in enumerate(lines):
        if l == "M722 S1":
            assert lines[i - 1] == ";TYPE:External perimeter"
        if l == "M722 S0":
            assert lines[i - 1].startswith(";TYPE:") and lines[i - 1] != ";TYPE:External perimeter"
    assert lines[-2:] == ["M720 S0", "M721 X"]


def test_upload_carries_the_map_exactly(prusa):
    data, model = prusa
    r = build([Stroke(((5.0, 1.0), (25.0, 8.0)))], model)
    out = annotate_bytes(data, r.map_bytes, Settings()).decode()
    fw = FirmwareModel(r.map_bytes)
    fw.run(out)
    assert fw.errors == []
    assert sorted(set(fw.found)) == [l.z_cmm for l in r.bulge_map.layers]


def test_large_map_is_streamed_within_the_arena(prusa):
    data, model = prusa
    strokes = [Stroke(((u, 0.5), (u, 9.8))) for u in range(0, 120, 3)]
    r = build(strokes, model)
    assert len(r.map_bytes) > 2048
    from bulgekit.bulge.annotate import AnnotateResult
    res = AnnotateResult()
    out = annotate_bytes(data, r.map_bytes, Settings(), arena=2048, result=res).decode()
    assert res.appends and res.initial_records < len(r.bulge_map.layers)
    fw = FirmwareModel(r.map_bytes)
    fw.run(out)
    assert fw.errors == []
    assert sorted(set(fw.found)) == [l.z_cmm for l in r.bulge_map.layers]
    # the default arena (1024, the firmware's AVR default) needs more appends and still works
    res2 = AnnotateResult()
    out2 = annotate_bytes(data, r.map_bytes, Settings(), result=res2).decode()
    assert len(res2.appends) > len(res.appends)
    fw = FirmwareModel(r.map_bytes, arena=1024)
    fw.run(out2)
    assert fw.errors == []


def test_z_hops_do_not_trigger_appends_early(prusa):
    data, model = prusa
    assert b"G1 Z.7 F7800" in data  # this slice lifts 0.4 mm on travels
    strokes = [Stroke(((u, 0.5), (u, 9.8))) for u in range(0, 120, 3)]
    r = build(strokes, model)
    out = annotate_bytes(data, r.map_bytes, Settings(), arena=700).decode().splitlines()
    for i, l in enumerate(out):
        if l.startswith("; bulgekit: layers"):
            nxt = out[i + 1 + next(k for k, x in enumerate(out[i + 1:]) if not x.startswith("M721"))]
            z = float(re.search(r"Z([0-9.]+)", nxt).group(1))
            first = float(l.split()[3].split("..")[0])
            assert abs(z - first) < 0.151, (nxt, l)


def test_no_stream_refuses_a_map_larger_than_the_arena(prusa):
    data, model = prusa
    r = build([Stroke(((u, 0.5), (u, 9.8))) for u in range(0, 120, 3)], model)
    with pytest.raises(AnnotateError, match=r"do not fit.*streaming"):
        annotate_bytes(data, r.map_bytes, Settings(), stream=False)


def test_no_feature_comments_suggests_geometric(data_dir):
    data = (data_dir / "slic3r_cyl.gcode").read_bytes()
    model = walls_from_gcode(data_dir / "slic3r_cyl.gcode", geometric=True)
    r = build([Stroke(((5.0, 2.0),))], model)
    with pytest.raises(AnnotateError, match=r"slic3r_cyl\.gcode: no slicer feature comments.*--geometric"):
        annotate_bytes(data, r.map_bytes, Settings(), source=str(data_dir / "slic3r_cyl.gcode"))
    out = annotate_bytes(data, r.map_bytes, Settings(mode=2)).decode()
    assert "M720 S2" in out and "M722" not in out
    fw = FirmwareModel(r.map_bytes)
    fw.run(out)
    assert fw.errors == [] and fw.found


@pytest.mark.parametrize("tag_in,tag_out", [
    (";TYPE:WALL-OUTER", ";TYPE:WALL-INNER"),               # Cura, ideaMaker
    ("; FEATURE: Outer wall", "; FEATURE: Inner wall"),     # BambuStudio, OrcaSlicer
    (";TYPE:Outer wall", ";TYPE:Sparse infill"),            # OrcaSlicer
    ("; outer perimeter", "; infill"),                      # Simplify3D
])
def test_dialects(tag_in, tag_out):
    g = ("G90\nM83\nG1 Z0.3\n" + tag_out + "\nG1 X1 Y1 E1\n" + tag_in + "\nG1 X10 Y0 E1\n"
         + tag_out + "\nG1 X0 Y0 E1\n")
    m = mapformat.encode_map([(0.3, [(5.0, 0.0)])])
    out = annotate_bytes(g.encode(), m, Settings()).decode().splitlines()
    i = out.index(tag_in)
    assert out[i + 1] == "M722 S1"
    assert out[out.index(tag_out, i) + 1] == "M722 S0"
    assert out.count("M722 S1") == 1


def test_comment_after_a_command_is_not_a_feature_tag():
    g = "G90\nM83\nG1 Z0.3\n;TYPE:Perimeter\nG1 X10 Y0 E1 ;TYPE:External perimeter\n"
    m = mapformat.encode_map([(0.3, [(5.0, 0.0)])])
    with pytest.raises(AnnotateError, match="none marks the outer wall"):
        annotate_bytes(g.encode(), m, Settings())


def test_open_marker_is_closed_at_the_end_and_crlf_kept():
    g = "G90\r\nM83\r\nG1 Z0.3\r\n;TYPE:External perimeter\r\nG1 X10 Y0 E1\r\n"
    m = mapformat.encode_map([(0.3, [(5.0, 0.0)])])
    out = annotate_bytes(g.encode(), m, Settings()).decode()
    assert out.endswith("M722 S0\r\n; bulgekit: end\r\nM720 S0\r\nM721 X\r\n")
    assert "\n" not in out.replace("\r\n", "")


def test_map_for_another_print_is_refused():
    g = "G90\nM83\nG1 Z0.3\n;TYPE:External perimeter\nG1 X10 Y0 E1\n"
    layers = [(0.3 * k, [(5.0, 0.0)] * 1) for k in range(1, 400)]
    m = mapformat.encode_map(layers)
    with pytest.raises(AnnotateError, match="never reaches z"):
        annotate_bytes(g.encode(), m, Settings())


def test_points_on_arcs_are_reached_through_the_chords_annotate_writes():
    # The firmware does not split G2/G3 (Marlin cuts arcs past our hook): the arc through a
    # point is written as G1 chords, so both points are reached, as in the stock fallback; the
    # arc that carries none stays an arc.
    from bulgekit.bulge.annotate import check_reach
    from bulgekit.bulge.fallback import RewriteResult, rewrite
    g = ("G90\nM83\nG1 Z0.3 F600\n;TYPE:External perimeter\nG1 X0 Y0 F1800\n"
         "G2 X20 Y0 I10 J0 E2\nG1 X0 Y0 E1.5\nG2 X20 Y0 I10 J0 E2\n")
    m = mapformat.encode_map([(0.3, [(10.0, 10.0), (5.0, 0.0)])])
    assert check_reach(g.encode(), m, Settings(), "t.gcode") is None
    out = annotate_bytes(g.encode(), m, Settings(), source="t.gcode").decode()
    assert [l for l in out.splitlines() if l.startswith("G2")] == ["G2 X20 Y0 I10 J0 E2"]
    assert "; bulgekit: 1 G2/G3 arc through map points written as 36 G1 chords" in out
    res = RewriteResult()
    "".join(rewrite(g.splitlines(keepends=True), mapformat.decode_map(m), Settings(), "t.gcode", res))
    assert res.stats.points_fired == 2


def test_arc_after_a_wall_edge_takes_the_point_deferred_to_it():
    # (10.2, 0) lies beyond the first edge's end: deferred. Were the arc left an arc, the
    # firmware would never see it (the next G1 starts elsewhere, so the point waits for a move
    # that passes it, line 9); the deferral crosses the arc, so annotate writes it as chords
    # and its first chord, which passes within the tolerance, stops the point.
    from bulgekit.bulge.annotate import check_reach
    from bulgekit.bulge.fallback import RefPlanner
    from bulgekit.gcode import parse_lines
    g = ("G90\nM83\nG1 Z0.3 F600\n;TYPE:External perimeter\nG1 X0 Y0 F1800\n"
         "G1 X10 Y0 E1\nG2 X30 Y0 I10 J0 E2\nG1 X10.2 Y-5\nG1 X10.2 Y5 E1\n")
    m = mapformat.encode_map([(0.3, [(10.2, 0.0)])])
    assert check_reach(g.encode(), m, Settings(), "t.gcode") is None

    def stops(text):
        ref = RefPlanner(mapformat.decode_map(m), Settings())
        for ln in parse_lines(text.splitlines(keepends=True), "t.gcode"):
            for mv in ln.moves:
                if not mv.arc:                 # (the firmware never sees an arc)
                    ref.plan(mv)
        return [(s.line_no, round(s.x, 4), round(s.y, 4)) for s in ref.stops]
    assert stops(g) == [(9, 10.2, 0.0)]
    out = annotate_bytes(g.encode(), m, Settings(), source="t.gcode").decode()
    assert not re.search(r"^G2", out, re.M)
    got = stops(out)
    # (its foot is 0.01 mm along the chord: the stop is where the head already is, the chord's start)
    assert len(got) == 1 and got[0][1:] == (10.0, 0.0)
    assert out.splitlines()[got[0][0] - 1].startswith("G1 X10.03805 Y0.87156 ")


@pytest.mark.parametrize("name", ["prusa_cyl.gcode", "prusa_cyl_m83.gcode", "cura_cyl.gcode",
                                  "prusa_vase.gcode", "slic3r_cyl.gcode"])
def test_fast_reach_check_says_what_the_reference_planner_says(name):
    """annotate's reach check reads only the outer-wall sections near map
    layers (vectorised); it must name the same missed points as running the
    reference planner over the whole file, for a right and a wrong map."""
    from pathlib import Path
    from bulgekit.bulge import api, mapformat
    from bulgekit.bulge.annotate import check_reach
    from bulgekit.bulge.fallback import RefPlanner, unreached_message
    from bulgekit.gcode import parse_lines
    from bulgekit.bulge.strokes import text_strokes
    g = Path(__file__).parents[1] / "data" / name
    data = g.read_bytes()
    geometric = name.startswith("slic3r")
    settings = Settings(2 if geometric else 1)
    good = api.build_map(api.walls(g, geometric=geometric), text_strokes("BULGE", 4.0, u0=4.0, v0=3.0)).map_bytes
    bm = mapformat.decode_map(good)
    q = bm.quantum_um / 1000
    layers = [(l.z_cmm / 100, [(x * q + (5.0 if i % 3 == 0 else 0.0), y * q) for x, y in l.points])
              for i, l in enumerate(bm.layers)]
    layers.append((layers[-1][0] + 30.0, [(1.0, 1.0)]))
    wrong = mapformat.encode_map(layers, quantum_um=bm.quantum_um, layer_height_mm=bm.layer_height_cmm / 100)
    for m in (good, wrong):
        ref = RefPlanner(mapformat.decode_map(m), settings)
        for ln in parse_lines(data.decode().splitlines(keepends=True), str(g)):
            for mv in ln.moves:
                if not mv.arc:
                    ref.plan(mv)
        assert check_reach(data, m, settings, str(g)) == unreached_message(ref, str(g))
    assert check_reach(data, good, settings, str(g)) is None
    assert check_reach(data, wrong, settings, str(g)) is not None


@pytest.mark.parametrize("compiled", [True, False], ids=["scanner", "python-parser"])
def test_annotate_looks_for_earlier_bulgekit_lines_where_its_scan_flags_one(tmp_path, data_dir,
                                                                            monkeypatch, compiled):
    """annotate's reach-check scan counts the lines check_not_processed could refuse: with none
    flagged the regexes are not run over the file; with one (or no count: the Python parser
    read it) they are, and refuse it before anything else annotate finds wrong; a bad line
    the scan stops at is still reported after annotate's own findings."""
    from bulgekit import gcode
    from bulgekit.bulge import annotate
    from bulgekit.gcode import GcodeError, movescan
    if not compiled:
        monkeypatch.setattr(movescan, "_scan", None)
    g = data_dir / "prusa_cyl.gcode"
    bm = build([Stroke(((10.0, 1.0), (10.0, 4.0)))], walls_from_gcode(g)).map_bytes
    calls = []
    real = annotate.check_not_processed
    monkeypatch.setattr(annotate, "check_not_processed", lambda d, s: (calls.append(s), real(d, s)))
    annotate.annotate_file(g, tmp_path / "a.gcode", bm, Settings())
    assert len(calls) == (0 if compiled else 1)
    text = g.read_text().splitlines(keepends=True)
    custom = tmp_path / "custom.gcode"
    # an M721 in the middle, and no outer-wall comments: the M721 is named, not the comments
    custom.write_text("".join(l.replace("External perimeter", "Perimeter")
                              for l in text[:50] + ["N7 M721 X\n"] + text[50:]))
    with pytest.raises(GcodeError, match=r"custom\.gcode:51: 'N7 M721 X'.*bulge twice"):
        annotate.annotate_file(custom, tmp_path / "o.gcode", bm, Settings())
    # a line no parser reads, and no outer-wall comments: annotate's own finding first
    bad = tmp_path / "bad.gcode"
    bad.write_text("".join(l.replace("External perimeter", "Perimeter")
                           for l in text[:50] + ["G1 X1O Y2\n"] + text[50:]))
    with pytest.raises(AnnotateError, match="none marks the outer wall"):
        annotate.annotate_file(bad, tmp_path / "o.gcode", bm, Settings())
    bad.write_text("".join(text[:50] + ["G1 X1O Y2\n"] + text[50:]))
    with pytest.raises(GcodeError, match=r"bad\.gcode:51: unparsable value 'X1O'"):
        annotate.annotate_file(bad, tmp_path / "o.gcode", bm, Settings())
    assert not (tmp_path / "o.gcode").exists()


ODD_MARKS = (b"G1 Z5 X1 Y1 E1\n;TYPE:External perimeter\r\n  \t; TYPE:Perimeter\nG1 X1 ;TYPE:Skirt\n"
             b";infill2\n; outer perimeter  \n;\xc2\xa0TYPE:x\n; TYPE:\xe2\x80\x94 wall\n"
             b"G0 Z1\nG00 Z1.\nG01\tZ-.5 X1 E1\nG10 Z7\nG1Z3\n  G1 Z.\nG1 Z+ Z2 ; Z9\nG1 X2 E1\n"
             b"G91\nG1 Z0.2\nG1 X1 E.1\nG90_\nG1 Z0.4\nG1 Y1 E1\nG900\nG1 Z1 Z2\nG1 X3 E3\n"
             b"G90\nG1 Z0.015\nG1 X1 E1\nG1 Z0.025\nG1 X1 E1\nG1 Z1.5e3\nG1 X1 E1\n"
             b"G1 Z" + b"1" * 80 + b"\nG1 X1 E1\rG1 Z4\rG1 X1 E1\nG1 Z6\nG1 E1 ;X\nG1 Z8\nG1 X1 E1")


# the compiled walkers look only at the lines around a ';', a 'Z' or a "G9": such bytes where
# they do not count (comments, other commands, mid-line G9x, blanks before G90)
ODD_HITS = (b"G91\nG1 Z1 X1 E1 ; G90\n;Z:0.3\nM117 Z5 G90\n \tG90\nG1 Z2\nG92 Z0 ;TYPE:Skirt\n"
            b"G1 X1 E1 ;; TYPE:Skirt\nG1 Z3 Z4 ; Z5\n\t;\tTYPE:External perimeter;x\nG1 Y1 E1\n"
            b"G90 G91\nG1 Z5\nG91;\nG1 Z1\nG1 X2 Y2 E2\nG9\nG1 ZZ6\nG1 X1 E1 Z7\n;")


def _mark_lines(rng, odd: bool = False):
    words = ["G1", "G0", "G01", "G00", "G10", " G1", "\tG1", "G90", "G91", "G92 E0", ";TYPE:Outer wall",
             "; TYPE:Internal infill", ";FEATURE: Outer wall", " ; skirt", ";LAYER_CHANGE", "M83"]
    parts = ["X1.5", "Y-2", "E.3", "Z0.2", "Z.45", "Z 1", "Z-0.1", "F1200", "; Z5", ";c", "E", "Z", "X"]
    if odd:
        words += [" G90", "\tG91", "G90;", "M117 Z5", ";Z:0.3", "G92 Z0", "G9", " ;TYPE:Skirt", "G1 X1 ;G91"]
        parts += ["Z1Z2", "G91", ";TYPE:Skirt", "Z", "ZZ.5"]
    out = []
    for _ in range(400):
        w = rng.choice(words)
        if w.lstrip().startswith("G") and not w.startswith("G9"):
            w += " " + " ".join(rng.sample(parts, rng.randint(0, 4)))
        out.append(w + rng.choice(["\n", "\n", "\r\n", "\r"]))
    return "".join(out).encode()


def test_compiled_marks_are_the_regular_expressions(data_dir, monkeypatch):
    """annotate's feature comments and layer changes from the compiled scanner (_scan.feature_lines,
    _scan.z_events, both at once: _scan.line_marks) are the regular expressions' (the fallback
    without it), on every test file, on odd lines (blanks, G00/G10, G90/G91 and their word ends,
    Z without a number, Z after a ';', long and rounding-edge numbers, lone \\r, no line end at
    the end) and on random ones."""
    import random
    from pathlib import Path
    from bulgekit.bulge import annotate
    from bulgekit.gcode import is_outer, movescan
    assert movescan._scan is not None
    files = sorted(data_dir.glob("*.gcode")) + sorted((Path(__file__).parents[3] / "examples").glob("*.gcode"))
    rng = random.Random(26)
    datas = [p.read_bytes() for p in files] + [ODD_MARKS, ODD_MARKS[1:], b"", b"\n", ODD_HITS,
                                                ODD_HITS[3:], b"Z1", b";TYPE:Skirt", b"G1 Z1\n",
                                                b"G1 " + b"Z1" * 5000 + b" X1 E1\nG1 X2 E1\n"]
    datas += [_mark_lines(rng) for _ in range(60)] + [_mark_lines(rng, True) for _ in range(60)]
    seen_z = seen_f = 0
    for d in datas:
        z = annotate._z_events(d)
        assert z == annotate._z_events_rx(d)
        f = list(annotate._feature_comments(d))
        assert f == list(annotate._feature_comments_rx(d))
        # both from one pass (annotate's way when it wants both), as each alone
        assert movescan._scan.line_marks(d) == (movescan._scan.feature_lines(d), z)
        assert annotate._feature_marks(d) == [(end, is_outer(role)) for end, role in f]
        seen_z += len(z)
        seen_f += len(f)
    assert seen_z > 1000 and seen_f > 1000
    marks = [annotate._feature_marks(d) for d in datas]
    monkeypatch.setattr(annotate, "_scanner", lambda: None)     # the regular expressions' way
    assert [annotate._feature_marks(d) for d in datas] == marks
    monkeypatch.undo()
    z = annotate._z_events(ODD_MARKS)
    assert (ODD_MARKS.index(b"G1 Z0.015"), 2) in z       # round(1.5) is 2, half to even
    assert (ODD_MARKS.index(b"G1 Z1.5e3"), 150) in z     # "1.5", as the regex reads it


def test_pieces_are_written_whole_after_short_writes(tmp_path, monkeypatch):
    """annotate_file's writer (_write_pieces) goes on where os.writev stopped, in the middle of a
    piece too, takes no more pieces a call than IOV_MAX, and writes them all without writev."""
    import os
    from bulgekit.bulge import annotate
    data = bytes(range(256)) * 40
    pieces = [memoryview(data)[i:i + i % 23] for i in range(0, 5000, 7)] + [b"", b"tail\n"]
    whole = b"".join(bytes(p) for p in pieces)
    real, calls = os.writev, []

    def half(fd, bufs):                       # writes half of what it is given (a byte at least)
        assert len(bufs) <= annotate._IOV_MAX
        calls.append(len(bufs))
        given = b"".join(bytes(b) for b in bufs)
        return real(fd, [given[:max(1, len(given) // 2)] if given else b""])
    monkeypatch.setattr(annotate, "_IOV_MAX", 64)
    monkeypatch.setattr(os, "writev", half)
    with open(tmp_path / "a", "wb") as f:
        f.write(b"head ")                     # buffered: written before the pieces
        annotate._write_pieces(f, list(pieces))
    assert (tmp_path / "a").read_bytes() == b"head " + whole
    assert len(calls) > len(pieces) / 64 and max(calls) == 64
    monkeypatch.delattr(os, "writev")
    with open(tmp_path / "b", "wb") as f:
        annotate._write_pieces(f, list(pieces))
    assert (tmp_path / "b").read_bytes() == whole
