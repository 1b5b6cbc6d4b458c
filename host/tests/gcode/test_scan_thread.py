"""movescan's read-ahead thread (_ahead): the records, roles, lines, lean tops and progress ticks
are the same with it and without it, errors part-way through a file come out the same, and a
consumer that stops early leaves no thread running."""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from bulgekit.gcode import GcodeError, movescan

DATA = Path(__file__).parents[1] / "data"
FILES = sorted(DATA.glob("*.gcode"))


def _ahead_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "bulgekit-scan-ahead"]


@pytest.fixture
def small_parts(monkeypatch):
    """Parts of 8 kB, so that a test file is many parts, each read ahead when on."""
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 8192)
    monkeypatch.setattr(movescan, "AHEAD_BYTES", 0)

    def read(path, ahead: bool, lean: bool = False, fast=None):
        monkeypatch.setattr(movescan, "READ_AHEAD", ahead)
        ticks: list[int] = []
        monkeypatch.setattr(movescan.progress, "tick", ticks.append)
        seen = []

        def consume(chunks):
            parts = []
            for a in chunks:
                # what a pass sees as it goes: the counts as of the part it has
                seen.append((len(chunks.roles), chunks.lines, chunks.flagged))
                parts.append(np.array(a))
            return parts, list(chunks.roles), chunks.lines, chunks.flagged, chunks.tops
        before = threading.active_count()
        out = movescan.run(path, consume, fast=fast, lean=lean)
        assert threading.active_count() == before and not _ahead_threads()
        return out, seen, ticks
    return read


@pytest.mark.parametrize("lean", [False, True])
@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_threaded_reader_gives_the_same_records_counts_and_ticks(small_parts, path, lean):
    if not movescan.available():
        pytest.fail("bulgekit.gcode._scan is not built")
    for src in (path, path.read_bytes()):
        (parts, roles, lines, flagged, tops), seen, ticks = small_parts(src, True, lean)
        (parts0, roles0, lines0, flagged0, tops0), seen0, ticks0 = small_parts(src, False, lean)
        assert len(parts) == len(parts0) and len(ticks) > 3        # (a tick a part)
        for a, b in zip(parts, parts0):
            assert a.tobytes() == b.tobytes()
        assert (roles, lines, flagged, seen, ticks) == (roles0, lines0, flagged0, seen0, ticks0)
        assert tops == tops0 and (tops is not None) == lean
        assert ticks[-1] == lines


def test_a_line_left_to_python_part_way_falls_back_the_same(small_parts, tmp_path):
    # the compiled scanner refuses the last line, parts after the consumer started: the Python
    # parser's error, with file and line, or Unsupported when only the compiled one is asked for
    text = FILES[0].read_bytes()
    bad = tmp_path / "bad.gcode"
    bad.write_bytes(text + b"G1 X1O Y2\n")
    n = text.count(b"\n") + 1
    for ahead in (True, False):
        with pytest.raises(GcodeError, match=rf"bad.gcode:{n}: unparsable value 'X1O'"):
            small_parts(bad, ahead)
        with pytest.raises(movescan.Unsupported, match=rf"line {n}"):
            small_parts(bad, ahead, fast=True)
        assert not _ahead_threads()
    # a command with a non-ASCII byte late in the file: the Python parser reads it, same records
    odd = tmp_path / "odd.gcode"
    odd.write_bytes(text + "G1 X2\u00a0Y3 E1\n".encode())
    (parts, *rest), _, ticks = small_parts(odd, True)
    (parts0, *rest0), _, ticks0 = small_parts(odd, False)
    assert b"".join(a.tobytes() for a in parts) == b"".join(a.tobytes() for a in parts0)
    assert rest == rest0 and ticks == ticks0
    assert parts[-1]["y1"][-1] == 3.0


def test_a_consumer_that_stops_early_stops_the_worker(monkeypatch):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 4096)
    monkeypatch.setattr(movescan, "AHEAD_BYTES", 0)
    monkeypatch.setattr(movescan, "READ_AHEAD", True)
    before = threading.active_count()

    def first(chunks):
        for a in chunks:
            assert _ahead_threads()               # (the worker runs while the caller has a part)
            return len(a)
    assert movescan.run(FILES[0], first) > 0
    assert threading.active_count() == before and not _ahead_threads()

    class Stop(Exception):
        pass

    def fail(chunks):
        next(iter(chunks))
        raise Stop
    for src in (FILES[0], FILES[0].read_bytes()):
        try:
            movescan.run(src, fail)
        except Stop as e:
            kept = e                          # (its traceback holds the consumer's chunks)
            assert threading.active_count() == before and not _ahead_threads()
        assert kept.__traceback__ is not None


def test_an_interrupt_on_the_main_thread_stops_the_worker(monkeypatch):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 4096)
    monkeypatch.setattr(movescan, "AHEAD_BYTES", 0)
    monkeypatch.setattr(movescan, "READ_AHEAD", True)

    def interrupted(chunks):
        for i, _ in enumerate(chunks):
            if i == 2:
                raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        movescan.run(FILES[0], interrupted)
    assert not _ahead_threads()


def test_a_scanner_feeds_one_thread_at_a_time():
    # feed() lets the GIL go while it parses: a second feed meanwhile would share its state. A
    # feed made from inside a feed (the classifier, which feed calls for a non-ASCII comment)
    # finds the scanner busy, as another thread's would; the outer feed then goes on.
    if not movescan.available():
        pytest.fail("bulgekit.gcode._scan is not built")
    errors: list[BaseException] = []

    def classify(text):
        try:
            sc.feed(b"G1 X1\n", False, 0)
        except RuntimeError as e:
            errors.append(e)
        return movescan._classify(text)
    sc = movescan._scan.Scanner([], [], classify)
    recs, used = sc.feed("G1 X1 Y1 E1\n; caf\u00e9\nG1 X2 Y2 E1\n".encode(), True, 0)
    assert len(recs) // movescan.RECORD.itemsize == 2 and sc.lines == 3
    assert errors and "in use by another thread" in str(errors[0])
    sc.feed(b"G1 X3\n", True, 0)             # (not busy after it)


def _kept_scan(path, ahead: bool, monkeypatch):
    """A build's Scan of path: what it kept, or the error it raised (type and message)."""
    monkeypatch.setattr(movescan, "READ_AHEAD", ahead)
    ticks: list[int] = []
    monkeypatch.setattr(movescan.progress, "tick", ticks.append)
    try:
        sc = movescan.Scan(path)
    except Exception as e:                    # noqa: BLE001 (compared between both ways)
        assert not _ahead_threads()
        return type(e), str(e)
    with sc.kept():
        records = movescan.run(path, lambda ch: b"".join(a.tobytes() for a in ch))
        got = (sc.fast, sc.chunks, sc.roles, sc.lines, sc.m92, sc.nl, sc.plain_lines, sc.ends,
               records, ticks)
    assert not _ahead_threads()
    return got


@pytest.mark.parametrize("tail", [b"", b"M720 S1\n", b"G1 X1 Y", b"G1 X2\xc2\xa0Y3 E1\n",
                                  b"; bulgekit: bulge map\n", b"M92 E415\nG1 X1 Y1\r\n"],
                         ids=["plain", "processed", "cut-off", "non-ASCII command", "our comment",
                              "M92 and CRLF"])
def test_a_builds_scan_is_the_same_threaded(monkeypatch, tmp_path, tail):
    # the checks' errors part-way (a processed or cut-off file), the Python parser taking over,
    # what the checks keep: the same with the part after read and scanned ahead
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 8192)
    monkeypatch.setattr(movescan, "AHEAD_BYTES", 0)
    g = tmp_path / "t.gcode"
    g.write_bytes(FILES[0].read_bytes() + tail)
    on, off = _kept_scan(g, True, monkeypatch), _kept_scan(g, False, monkeypatch)
    assert on == off
    if tail in (b"M720 S1\n", b"G1 X1 Y", b"; bulgekit: bulge map\n"):
        assert on[0].__name__.endswith("Error") and "t.gcode" in on[1]
    else:
        assert on[0] == (tail != b"G1 X2\xc2\xa0Y3 E1\n")      # (the Python parser's: no offsets)
        assert on[3] > 1000 and (len(on[1]) > 3 or not on[0])


def test_a_non_text_file_is_refused_the_same_threaded(monkeypatch, tmp_path):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 8192)
    monkeypatch.setattr(movescan, "AHEAD_BYTES", 0)
    g = tmp_path / "t.gcode"
    g.write_bytes(b"\x00\x01\x02\xff" * 10000)
    on, off = _kept_scan(g, True, monkeypatch), _kept_scan(g, False, monkeypatch)
    assert on == off and "t.gcode" in on[1]
