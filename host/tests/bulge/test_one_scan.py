"""build checks the G-code once and scans it once (movescan.Scan); every pass works from that scan."""
from __future__ import annotations

import builtins
import io
import os
from pathlib import Path

import numpy as np
import pytest

import bulgekit.bulge.api as api
from bulgekit.bulge import fallback
from bulgekit import gcode
from bulgekit.gcode import movescan
from bulgekit.bulge.strokes import text_strokes

DATA = Path(__file__).parents[1] / "data"


def test_build_opens_the_file_three_times_and_scans_it_once(tmp_path, monkeypatch):
    src = tmp_path / "part.gcode"
    src.write_bytes((DATA / "prusa_cyl.gcode").read_bytes())
    opened = []
    real_open = builtins.open
    me = os.getpid()
    # build's stock fallback may run in a forked child (bulgekit.parallel): what a child does
    # is counted in a file, as the list here is the child's own copy
    in_child = tmp_path / "in_child.txt"

    def child_did(what):
        fd = os.open(in_child, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
        os.write(fd, what.encode() + b"\n")
        os.close(fd)

    def counting_open(file, *a, **k):
        if isinstance(file, (str, os.PathLike)) and os.path.realpath(file) == str(src):
            mode = a[0] if a else k.get("mode", "r")
            if os.getpid() == me:
                opened.append(mode)
            else:
                child_did(f"open {mode}")
        return real_open(file, *a, **k)
    monkeypatch.setattr(builtins, "open", counting_open)
    monkeypatch.setattr(io, "open", counting_open)
    scanned = []                                  # bytes the compiled scanner consumed, per scanner
    python_scans = []
    real_slow = movescan._slow
    monkeypatch.setattr(movescan, "_slow", lambda *a: (python_scans.append(a) if os.getpid() == me
                                                       else child_did("python scan"))
                        or real_slow(*a))
    if movescan.available():
        real = movescan._scan

        class Counting:
            def __init__(self, *a, **kw):
                self._s = real.Scanner(*a, **kw)
                scanned.append(0)

            def feed(self, buf, final=False, base=0):
                recs, used = self._s.feed(buf, final, base)
                scanned[-1] += used
                if os.getpid() != me:
                    child_did("scan")
                return recs, used

            roles = property(lambda self: self._s.roles)
            lines = property(lambda self: self._s.lines)
            flagged = property(lambda self: self._s.flagged)
            line_ends = property(lambda self: self._s.line_ends)
            top = property(lambda self: self._s.top)
            numbers = property(lambda self: self._s.numbers)
            arcs = property(lambda self: self._s.arcs)

        class Proxy:
            Scanner = Counting
            ScanUnsupported = real.ScanUnsupported
            RECORD_SIZE = real.RECORD_SIZE
            # annotate's line marks, on the bytes it copies (no move records), and the class
            # bits of records already made
            feature_lines = staticmethod(real.feature_lines)
            z_events = staticmethod(real.z_events)
            move_classes = staticmethod(real.move_classes)
        monkeypatch.setattr(movescan, "_scan", Proxy)
    out = api.build(src, text_strokes("HI", 6.0, u0=5, v0=3), tmp_path / "out", write_fallback=True)
    assert out.fallback_path.exists() and out.stats.points > 0
    # one reading for the checks and the scan, then the two outputs' copies of the text (the
    # stock file's in a child, or here); a child scans nothing
    child = in_child.read_text().split("\n")[:-1] if in_child.exists() else []
    assert len(opened) + len(child) == 3 and all(c.startswith("open") for c in child), (opened, child)
    if movescan.available():
        assert scanned == [src.stat().st_size] and python_scans == []
    else:
        assert len(python_scans) == 1


def _records(path):
    return movescan.run(path, lambda ch: (np.concatenate(list(ch)), list(ch.roles), ch.lines))


@pytest.mark.parametrize("name", ["prusa_cyl.gcode", "cura_cyl.gcode", "slic3r_cyl.gcode"])
def test_scan_keeps_what_the_passes_would_read(name, tmp_path, monkeypatch):
    """In small chunks (many boundaries): the kept records, roles and lines are a fresh scan's,
    and the kept ends, M92s and line-end verdict are what open_checked, scan_m92 and
    _plain_lines give on the whole file."""
    src = tmp_path / name
    data = (DATA / name).read_bytes()
    # an M92 E late in the file (past many chunks) and CR LF line ends in half of it
    cut = data.index(b"\n", len(data) // 2) + 1
    data = data[:cut] + b"M92 E415.5 ; late\n" + data[cut:]
    src.write_bytes(data)
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 4099)
    fresh = _records(src)
    sc = movescan.Scan(src)
    with sc.kept():
        kept = _records(src)
        ends, _ = gcode.open_checked(src)
    assert np.array_equal(kept[0], fresh[0]) and kept[1] == fresh[1] and kept[2] == fresh[2]
    assert ends == gcode.open_checked(src)[0]
    assert sc.m92 == fallback.scan_m92(src) and (len(sc.m92) >= 1)
    assert sc.plain_lines == fallback._plain_lines(data) is True
    for half, plain in ((b"\r\n", True), (b"\r", False)):      # (CR LF pairs cut by chunks count once)
        mixed = data[:cut].replace(b"\n", half) + data[cut:]
        src.write_bytes(mixed)
        assert movescan.Scan(src).plain_lines is fallback._plain_lines(mixed) is plain


@pytest.mark.parametrize("case", ["processed-late", "processed-comment", "processed-numbered", "processed-accent",
                                  "cut-off", "empty", "blank", "binary"])
def test_scan_refuses_as_the_checks_do(case, tmp_path, monkeypatch):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 4096)
    body = (DATA / "prusa_cyl.gcode").read_bytes()
    data = {"processed-late": body + b"G1 X1\nM721 X\n",
            "processed-comment": body + b"; bulgekit: start\nG1 X1\n",
            "processed-numbered": body + b"N12 M0722 S1\nG1 X1\n",
            "processed-accent": body + "\tM720 S1 ; é\n".encode(),
            "cut-off": body + b"G1 X119.5 E9",
            "empty": b"", "blank": b"\n  \n",
            "binary": b"G1 X1\n\0\0\n" + body}[case]
    src = tmp_path / "f.gcode"
    src.write_bytes(data)
    with pytest.raises(gcode.GcodeError) as old:
        gcode.check_complete(data, str(src))
        gcode.check_not_processed(data, str(src))
    with pytest.raises(gcode.GcodeError) as new:
        movescan.Scan(src)
    assert str(new.value) == str(old.value)


def _build_hashes(src, out):
    import hashlib
    from test_build_identical import _without_printer_line      # (the reference's hashes leave it out)
    api.build(src, text_strokes("HI", 6.0, u0=5, v0=3), out, write_fallback=True)
    return {p.name.split(".", 1)[1]: hashlib.sha256(_without_printer_line(p.read_bytes())).hexdigest()
            for p in sorted(out.iterdir())}


def test_a_file_the_scanner_leaves_to_python_builds_as_without_the_one_scan(tmp_path, monkeypatch):
    import contextlib
    src = (DATA / "prusa_cyl.gcode").read_bytes()
    i = src.index(b"\nG1 ", len(src) // 2) + 1
    odd = tmp_path / "odd.gcode"
    odd.write_bytes(src[:i] + "G1 F1800 (vitesse é)\n".encode() + src[i:])    # non-ASCII command line
    sc = movescan.Scan(odd)
    assert not sc.fast                                     # the Python parser's records
    sc.close()
    one = _build_hashes(odd, tmp_path / "one")
    monkeypatch.setattr(movescan.Scan, "kept", lambda self: (self.close(), contextlib.nullcontext())[1])
    assert _build_hashes(odd, tmp_path / "each") == one    # every pass reading the file itself


def test_without_the_compiled_scanner_build_writes_the_same_bytes(tmp_path, monkeypatch):
    import json
    ref = json.loads((DATA / "build_outputs.json").read_text())["prusa_cyl-move"]
    monkeypatch.setattr(movescan, "_scan", None)
    got = _build_hashes(DATA / "prusa_cyl.gcode", tmp_path / "out")
    assert got == {k.split(".", 1)[1]: v for k, v in ref.items()}


def test_a_replayed_chunks_classes_are_computed_once():
    """movescan.classes of a chunk a kept Scan replays: the first replay computes them, later
    replays (build's walls, reach check, fallback) get the same ones; another array (a copy of
    the chunk) is computed afresh, and a closed Scan leaves nothing behind."""
    scan = movescan.Scan(DATA / "prusa_cyl.gcode")
    with scan.kept():
        def first(chunks):
            return [(a.tobytes(), movescan.classes(a)) for a in chunks]
        got = movescan.run(DATA / "prusa_cyl.gcode", first)
        assert got
        for b, (c, top, top_line) in got:
            want = movescan._classes(np.frombuffer(b, movescan.RECORD))
            assert (c.tobytes(), top, top_line) == (want[0].tobytes(), want[1], want[2])

        def again(chunks):
            return [movescan.classes(a) for a in chunks]
        assert all(x is y[1] for x, y in zip(movescan.run(DATA / "prusa_cyl.gcode", again), got))

        def copies(chunks):
            return [movescan.classes(a.copy()) for a in chunks]
        assert not any(x is y[1] for x, y in zip(movescan.run(DATA / "prusa_cyl.gcode", copies), got))
    assert movescan._REPLAYED is None and not scan._classes
