import math
import warnings

import pytest

from bulgekit.gcode import (GcodeError, GcodeState, feature_of_comment, header_layer_height,
                            is_outer, iter_moves, parse_lines)


def moves(text, source="t.gcode"):
    return list(iter_moves(text.splitlines(keepends=True), source))


def test_absolute_and_relative_extrusion_follow_marlin():
    ms = moves("G90\nM83\nG1 X10 E1\nG1 X20 E1\nG90\nG1 X30 E5\nG91\nG1 X1 E0.5\n")
    assert [m.e for m in ms] == pytest.approx([1, 1, 3, 0.5])  # G90 made E absolute again
    assert ms[2].e_start == pytest.approx(2)
    assert (ms[3].x0, ms[3].x1) == (30, 31)


def test_g92_sets_only_named_axes():
    ms = moves("G1 X5 Y5 Z0.2 E3\nG92 E0\nG1 X6 E0.4\n")
    assert ms[1].e == pytest.approx(0.4)
    assert ms[1].e_start == 0
    assert (ms[1].x0, ms[1].y0, ms[1].z0) == (5, 5, 0.2)


def test_line_numbers_checksums_and_comments_are_stripped():
    ms = moves("N7 G1 X1 Y2 E0.1*45 ; move\nG01 X2\n")
    assert (ms[0].x1, ms[0].y1, ms[0].e) == (1, 2, pytest.approx(0.1))
    assert ms[1].x1 == 2


def test_unparsable_value_names_file_and_line():
    with pytest.raises(GcodeError, match=r"part\.gcode:3: unparsable value 'X1\.2\.3'"):
        moves("G28\nG1 X1\nG1 X1.2.3 Y4\n", "part.gcode")


@pytest.mark.parametrize("comment,role,outer", [
    ("TYPE:External perimeter", "external perimeter", True),   # PrusaSlicer
    ("TYPE:Perimeter", "perimeter", False),
    ("TYPE:Outer wall", "outer wall", True),                   # OrcaSlicer
    (" FEATURE: Outer wall", "outer wall", True),              # BambuStudio / Orca
    (" FEATURE: Inner wall", "inner wall", False),
    ("TYPE:WALL-OUTER", "wall-outer", True),                   # Cura, ideaMaker
    ("TYPE:WALL-INNER", "wall-inner", False),
    (" outer perimeter", "outer perimeter", True),             # Simplify3D
    (" inner perimeter", "inner perimeter", False),
    (" layer 3, Z = 0.9", None, False),                        # S3D layer line: no feature
    ("Z:0.3", None, False),
])
def test_feature_comments(comment, role, outer):
    assert feature_of_comment(comment) == role
    assert is_outer(feature_of_comment(comment)) is outer


def test_outer_flag_follows_feature_sections():
    text = (";TYPE:Perimeter\nG1 X1 E1\n;TYPE:External perimeter\nG1 X2 E2\nG1 X3 E3\n"
            ";TYPE:Solid infill\nG1 X4 E4\n")
    assert [m.outer for m in moves(text)] == [False, True, True, False]


def test_arc_ij_is_linearised_on_the_circle_with_proportional_e():
    # quarter circle, centre (10, 0), radius 10, counter-clockwise from (20, 0) to (10, 10)
    ms = moves("G1 X20 Y0 E0\nG3 X10 Y10 I-10 J0 E1.5\n")[1:]
    assert len(ms) > 10 and all(m.arc for m in ms)
    for m in ms:
        assert math.hypot(m.x1 - 10, m.y1) == pytest.approx(10, abs=1e-9)
    assert (ms[-1].x1, ms[-1].y1) == (10, 10)
    assert sum(m.e for m in ms) == pytest.approx(1.5)
    lens = [m.xy_len for m in ms]
    for m, l in zip(ms, lens):
        assert m.e / l == pytest.approx(ms[0].e / lens[0], rel=1e-6)


def test_arc_r_picks_the_short_arc_on_the_right_side():
    # clockwise from (0,0) to (10,0) with R5: a half circle through (5, 5)
    ms = moves("G2 X10 Y0 R5 E1\n")
    ys = [m.y1 for m in ms]
    assert max(ys) == pytest.approx(5, abs=0.05)
    ms = moves("G3 X10 Y0 R5 E1\n")
    assert min(m.y1 for m in ms) == pytest.approx(-5, abs=0.05)


def test_arc_without_centre_is_an_error():
    with pytest.raises(GcodeError, match=r"t\.gcode:1: arc without I/J or R"):
        moves("G2 X10 Y0 E1\n")


def test_header_layer_height_dialects():
    assert header_layer_height("; layer_height = 0.25\n") == 0.25
    assert header_layer_height(";Layer height: 0.3\n") == 0.3
    assert header_layer_height(";   layerHeight,0.2\n") == 0.2
    assert header_layer_height("G1 X1\n") is None


def test_real_slices_parse(data_dir):
    for name in ("prusa_cyl.gcode", "prusa_cyl_m83.gcode", "cura_cyl.gcode", "slic3r_cyl.gcode"):
        st = GcodeState()
        lines = (data_dir / name).read_text().splitlines(keepends=True)
        n = sum(len(l.moves) for l in parse_lines(lines, name, st))
        assert n > 3000
        assert st.outer_seen == (0 if name.startswith("slic3r") else 33)


def test_a_cut_off_last_line_is_refused_by_every_reader(tmp_path, data_dir):
    import pytest
    from bulgekit.bulge import mapformat
    from bulgekit.bulge.annotate import annotate_file
    from bulgekit.bulge.fallback import Settings, rewrite_file
    from bulgekit.gcode import GcodeError, check_complete
    from bulgekit.printer.sender import read_gcode
    from bulgekit.bulge.stats import print_stats
    from bulgekit.bulge.wall import walls_from_gcode
    full = (data_dir / "prusa_cyl.gcode").read_text()
    cut = full[:full.rfind("\n", 0, len(full) // 2) + 9]   # ends in "G1 X1..." mid-line
    p = tmp_path / "cut.gcode"
    p.write_text(cut)
    nline = cut.count("\n") + 1
    bm = mapformat.encode_map([(1.2, [(100.0, 100.0)])], quantum_um=100, layer_height_mm=0.3)
    calls = [lambda: walls_from_gcode(p),
             lambda: annotate_file(p, tmp_path / "a.gcode", bm, Settings()),
             lambda: rewrite_file(p, tmp_path / "f.gcode", mapformat.decode_map(bm), Settings()),
             lambda: print_stats(p, bm, Settings()),
             lambda: read_gcode(p)]
    for call in calls:
        with pytest.raises(GcodeError, match=rf"cut\.gcode:{nline}: .*does not end with a line end"):
            call()
    assert not (tmp_path / "a.gcode").exists() and not (tmp_path / "f.gcode").exists()
    # a last line that is only a comment, or a complete file, is fine
    check_complete("G1 X1\n; end", "x")
    check_complete(b"G1 X1\r\n", "x")
    with pytest.raises(GcodeError, match="'G1 X1'"):
        check_complete(b"G28\nG1 X1", "x")


def cut_at_a_line_end(src, dst, share=0.5):
    """dst: src cut at the line end nearest `share` of its bytes, as a download that stopped."""
    data = src.read_bytes()
    dst.write_bytes(data[:data.rfind(b"\n", 0, int(len(data) * share)) + 1])
    return dst


@pytest.mark.parametrize("name, slicer", [("prusa_cyl.gcode", "PrusaSlicer"), ("cura_cyl.gcode", "Cura"),
                                          ("slic3r_cyl.gcode", "Slic3r")])
def test_a_slicers_file_cut_at_a_line_end_is_warned_of_by_every_reader(tmp_path, data_dir, name, slicer):
    """Issue 37: a real file cut between two lines (no end G-code) is read, with a warning that
    names it and its slicer, from every reader (the same check of its two ends); the whole file
    and a cut file of no known slicer get none."""
    from bulgekit.gcode import CutOffWarning, check_complete, estimate, movescan
    from bulgekit.bulge.wall import walls_from_gcode
    from bulgekit.printer.sender import read_gcode
    p = cut_at_a_line_end(data_dir / name, tmp_path / "cut.gcode")
    readers = [lambda q: check_complete(q.read_bytes(), str(q)), lambda q: check_complete(q.read_text(), str(q)),
               lambda q: movescan.Scan(q, str(q)).close(), lambda q: estimate.estimate_file(q),
               lambda q: read_gcode(q)]
    if name != "slic3r_cyl.gcode":                      # (no outer-wall comments)
        readers.append(lambda q: walls_from_gcode(q))
    for read in readers:
        with pytest.warns(CutOffWarning) as got:
            read(p)
        said = [str(w.message) for w in got if w.category is CutOffWarning]
        assert said and all(m.startswith(f"{p}: ends without {slicer}'s end block") for m in said)
        assert "cut off?" in said[0] and "\n" not in said[0]
    plain = tmp_path / "plain.gcode"                    # no slicer's header: not judged
    plain.write_bytes(b"".join(ln for ln in p.read_bytes().splitlines(keepends=True)
                               if not ln.startswith((b"; generated by", b";Generated with"))))
    for q in (data_dir / name, plain):
        with warnings.catch_warnings():
            warnings.simplefilter("error", CutOffWarning)
            for read in readers[:-1]:
                read(q)


def test_the_cli_says_a_cut_file_in_one_line(tmp_path, data_dir):
    import os
    import subprocess
    import sys
    p = cut_at_a_line_end(data_dir / "prusa_cyl.gcode", tmp_path / "cut.gcode", 0.9)
    r = subprocess.run([sys.executable, "-m", "bulgekit", "build", p, "--text", "HI", "--at", "5,1",
                        "--text-size", "3", "-o", tmp_path / "out", "--no-preview"],
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(data_dir.parents[1])))
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines() == [f"WARNING: {p}: ends without PrusaSlicer's end block ('; filament "
                                     "used [' or '; prusaslicer_config = end' after its end G-code): was "
                                     "the file cut off? Check it, or slice again"]


@pytest.mark.parametrize("tag", [";TYPE:Overhang perimeter", ";TYPE:Overhang wall", "; FEATURE: Overhang wall"])
def test_overhang_sections_of_the_outer_wall_count_as_outer_wall(tag):
    from bulgekit.bulge.annotate import annotate_bytes
    from bulgekit.bulge.fallback import Settings
    from bulgekit.gcode import parse_lines
    from bulgekit.bulge import mapformat
    text = ("G90\nM83\nG1 X0 Y0 Z0.2 F1200\n;TYPE:External perimeter\nG1 X10 Y0 E0.5\n"
            f"{tag}\nG1 X10 Y10 E0.5\n;TYPE:Perimeter\nG1 X0 Y10 E0.5\n")
    outer = [m.outer for ln in parse_lines(text.splitlines(keepends=True)) for m in ln.moves]
    assert outer == [False, True, True, False]
    bm = mapformat.encode_map([(0.2, [(10.0, 5.0)])], quantum_um=100, layer_height_mm=0.2)
    out = annotate_bytes(text.encode(), bm, Settings()).decode()
    # the marker stays on through the overhang and goes off at the inner perimeter
    body = out[out.index(";TYPE:External"):]
    assert body.count("M722 S1") == 1 and body.count("M722 S0") == 1
    assert body.index("M722 S0") > body.index("G1 X10 Y10 E0.5")


def test_flag_counts_hold_every_line_the_regexes_match(tmp_path, monkeypatch):
    """The compiled scanner's count of the lines check_not_processed's and scan_m92's regexes
    may match (gcode._flag_counts) holds every line they do match, so that with a count of 0
    the regexes are skipped; with it or without it, the checks find the same."""
    import random
    from bulgekit import gcode
    assert gcode._flag_counts(b"") == (0, 0)
    heads = ["", " ", "\t", "N12 ", "n3\t", "N ", "\x0b"]
    cmds = ["M720 S1", "m0721", "M722", "M7220", "M72.5", "M92 E415", "M092 E93", "m92 X1",
            "M920", "; bulgekit: x", ";  bulgekit", "; bulgekit fallback: y", "G1 X1", "; M720",
            "M72", "M9", "\xe9M720"]
    ends = ["\n", "\r\n", "\r"]
    rng = random.Random(26)
    for trial in range(400):
        lines = [rng.choice(heads) + rng.choice(cmds) + rng.choice(ends) for _ in range(rng.randint(1, 6))]
        data = "".join(lines).encode()
        ours, m92 = gcode._flag_counts(data)
        if gcode._OURS_RX.search(data):
            assert ours > 0, data
        if gcode._M92_RX.search(data):
            assert m92 > 0, data
        if trial < 60:                                  # the checks agree with and without it
            p = tmp_path / f"t{trial}.gcode"
            p.write_bytes(data)

            def checks():
                try:
                    gcode.check_not_processed(data, "t")
                    refused = None
                except gcode.GcodeError as e:
                    refused = str(e)
                return [gcode.scan_m92(p), refused]

            got = checks()
            with monkeypatch.context() as m:
                m.setattr(gcode, "_flag_counts", lambda d: None)
                want = checks()
            assert got == want
    assert gcode._flag_counts(b"G1 X1\n; bulgekit: 3\nN1 M092 E5\r\nm721\n") == (2, 1)


def test_a_scanner_built_from_an_older_source_is_not_used(monkeypatch):
    """A compiled scanner built before _scan.c gained what the code now calls (no VERSION, or
    another one) is left alone: the Python paths do the work until it is built again."""
    import sys
    import types
    from bulgekit import gcode
    assert gcode.compiled_scanner() is not None and gcode.compiled_scanner().VERSION == gcode.SCAN_VERSION
    stale = types.ModuleType("bulgekit.gcode._scan")
    monkeypatch.setitem(sys.modules, "bulgekit.gcode._scan", stale)
    monkeypatch.setattr(gcode, "_scan", stale, raising=False)
    monkeypatch.setattr(gcode, "_STALE_SAID", set())
    assert gcode.scanner_state() == "stale"
    with pytest.warns(RuntimeWarning, match="out of date|older source.*setup.py build_ext"):
        assert gcode.compiled_scanner() is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")                   # said once, not on every call
        assert gcode._flag_counts(b"M720 S1\n") is None
    from bulgekit.cli import _scanner_words
    assert "out of date" in _scanner_words() and "build_ext" in _scanner_words()
    stale.VERSION = gcode.SCAN_VERSION
    assert gcode.compiled_scanner() is stale and gcode.scanner_state() == "compiled"
