"""The G-code reader: moves of a file as numpy record arrays (RECORD, the one definition of the
move records every pass reads), chunk by chunk: the compiled scanner (_scan.c) when it is built and
takes the file, gcode.parse_lines otherwise. Both give the same numbers (host/tests/gcode/test_movescan.py).
Walls, statistics, the stock fallback, annotate's reach check and the studio read them here; the
estimator reads the scanner's records in its events mode (estimate.estimate_file).

    run(path, consume)      # consume(chunks) gets an iterator of RECORD arrays and the role names
    with Scan(path).kept(): # build: the file checked and scanned once, every run() above replays it
                            # (lean=True, build in marked mode: only the records its passes need)
    classes(a)              # what the passes ask of every move of a chunk, one byte each

consume must start from nothing each time it is called: when the compiled scanner meets a line it
leaves to the Python parser (a command with non-ASCII bytes, a value or arc gcode/__init__.py refuses),
consume is called again with the Python parser's chunks, which give the moves or the error
message naming the file and line.

On 2+ cores, files over AHEAD_BYTES are read and scanned one part ahead on a worker thread
(_ahead) while consume works on the part before; BULGEKIT_SCAN_THREAD=0 turns that off.

`bulgekit --version` says which scanner is in use.
"""
from __future__ import annotations

import contextlib
import io
import os
import queue
import tempfile
import threading
from typing import Callable, Iterator, TypeVar

import numpy as np

from .. import gcode, progress

# None without a C compiler (or built from an older _scan.c): the Python parser does all the work
_scan = gcode.compiled_scanner()

RECORD = np.dtype([
    ("x0", "<f8"), ("y0", "<f8"), ("z0", "<f8"), ("x1", "<f8"), ("y1", "<f8"), ("z1", "<f8"),
    ("e", "<f8"), ("e_start", "<f8"), ("f", "<f8"),
    ("offset", "<i8"),       # byte offset of the move's line in the file (-1 from the Python parser)
    ("line_no", "<i4"), ("role", "<i2"), ("flags", "u1"), ("pad", "u1"),
])
OUTER = 1                    # flags: inside an outer-wall feature
ARC = 2                      # flags: a chord of a linearised G2/G3
ABS_XYZ = 4                  # flags: G90 in force (else G91)
ABS_E = 8                    # flags: absolute E in force (M82/G90; else M83/G91)

# movescan.classes: one byte per move of what the passes ask of every move (OUTER and ARC as in flags)
MOVED = 4                    # moves in XY (x0 != x1 or y0 != y1)
EXTRUDES = 8                 # moves in XY with e > 0
NULL = 16                    # moves nothing (no XY, no Z, no E)
EXTRUDES_F32 = 32            # extrudes in XY in float32, as the firmware sees it (RefPlanner._eligible)

CHUNK_BYTES = 2 << 20        # 2 MB of G-code: about 7 MB of records at a time
T = TypeVar("T")


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


# Read and scan the next part of a file on a second thread while the passes work on this one
# (_ahead): with 2+ cores and files of more than AHEAD_BYTES. BULGEKIT_SCAN_THREAD=0 turns it off.
READ_AHEAD = os.environ.get("BULGEKIT_SCAN_THREAD", "1") != "0" and _cores() > 1
AHEAD_BYTES = 2 * CHUNK_BYTES


def _use_ahead(size: int) -> bool:
    return READ_AHEAD and size > AHEAD_BYTES


def _ahead(parts: Iterator[T]) -> Iterator[T]:
    """The items of the generator parts, made on a worker thread one item ahead of the caller
    (memory: the item taken, one queued and one being made). An exception in parts is raised
    here when its turn comes; the worker stops when the caller stops (or drops) this iterator."""
    q: queue.Queue = queue.Queue(maxsize=1)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return True
            except queue.Full:
                pass
        return False

    def work():
        try:
            for item in parts:
                if not put((True, item)):
                    return
            put((False, None))
        except BaseException as e:         # the caller's to raise, in its thread
            put((False, e))
        finally:
            parts.close()

    t = threading.Thread(target=work, name="bulgekit-scan-ahead", daemon=True)
    t.start()
    try:
        while True:
            ok, item = q.get()
            if ok:
                yield item
            elif item is None:
                return
            else:
                raise item
    finally:
        stop.set()
        t.join()


def _file_parts(f, feed: Callable) -> Iterator:
    """The open binary file f read CHUNK_BYTES at a time, each read after the bytes the feed
    before left unused (a line cut by the read): feed(data, part, final, base) gets the bytes
    read, the part (unused bytes, then data), whether it is the last and the part's file offset,
    and returns (item, bytes of the part used). Yields the items."""
    base, buf = 0, b""
    while True:
        data = f.read(CHUNK_BYTES)
        final = not data
        buf = buf + data if buf else data
        item, used = feed(data, buf, final, base)
        yield item
        base += used
        buf = buf[used:]
        if final:
            return


class Unsupported(Exception):
    """The compiled scanner left the file to the Python parser, and the caller asked for the
    compiled one only (it needs the byte offsets)."""


class Chunks:
    """What consume gets: iterate for RECORD arrays (moves in file order); `roles` names the
    role indices seen so far (complete once iteration ends); `lines` counts the lines read;
    `flagged` the lines read that gcode.check_not_processed's or scan_m92's regexes may match
    (the compiled scanner's count, a superset; None from the Python parser or a kept Scan);
    `arcs` the G2/G3 lines read. A line's moves (an arc's chords) are all in one chunk."""

    def __init__(self, it: Iterator[np.ndarray], roles: list[str], lines: Callable[[], int],
                 flagged: Callable[[], int] | None = None, tops: list | None = None,
                 numbers: list | None = None, arcs: Callable[[], int] = lambda: 0,
                 all_arcs: bool = True):
        self._it, self.roles, self._lines, self._flagged = it, roles, lines, flagged
        self._arcs = arcs
        # lean chunks hold every arc chord (run(..., lean=2), a kept Scan's), or (lean=1) only
        # the extruding ones and no travel arc after the outer wall: what a run that bypasses
        # arcs (fallback.plan_records' arcs_bypass) needs, and no more
        self.all_arcs = all_arcs
        # lean chunks (run(..., lean=True) with the compiled scanner): the records annotate's
        # lazy reach check can plan only, and per part of the file read, what classes() would
        # give as top_not_arc on all its moves (filled as iteration goes); else None
        self.tops = tops
        # a kept lean Scan's chunks (Scan(..., lean=True)): lean records and every arc chord,
        # and per chunk given, the move number of each record (counting every move; appended
        # as iteration goes, numbers[-1] is the chunk in hand); else None
        self.numbers = numbers

    def __iter__(self):
        return self._it

    def close(self) -> None:
        """Stops the reading (and its read-ahead thread) if consume did not read to the end."""
        close = getattr(self._it, "close", None)
        if close is not None:
            close()

    @property
    def lines(self) -> int:
        return self._lines()

    @property
    def flagged(self) -> int | None:
        return None if self._flagged is None else self._flagged()

    @property
    def arcs(self) -> int:
        return self._arcs()


def _consume(consume: Callable[[Chunks], T], chunks: Chunks) -> T:
    # closed here, not when the chunks are collected: an exception the caller keeps holds them
    try:
        return consume(chunks)
    finally:
        chunks.close()


def z_cmm(z: np.ndarray) -> np.ndarray:
    """Move z (mm) as the firmware reads it: 0.01 mm, rounded in float32, half away from zero
    (bulge_planner.cpp; fallback.RefPlanner._cmm and wall._z_cmm one at a time)."""
    z = np.asarray(z)
    if z.ndim == 1 and len(z) > 64:
        # a file's moves come in runs of one z (its layers): each run's value once
        starts, values = runs(z)
        if 4 * len(starts) < len(z):
            return np.repeat(_z_cmm(values), np.diff(np.append(starts, len(z))))
    return _z_cmm(z)


def runs(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the runs of equal values of the 1-D array v start, and their values."""
    if not len(v):
        return np.empty(0, np.int64), v
    st = np.flatnonzero(np.concatenate(([True], v[1:] != v[:-1])))
    return st, v[st]


def _z_cmm(z: np.ndarray) -> np.ndarray:
    v = (z.astype(np.float32) * np.float32(100.0)).astype(np.float64)
    return np.where(v >= 0, np.floor(v + 0.5), -np.floor(0.5 - v)).astype(np.int64)


# A kept Scan's replay: (the chunk it gave last, its chunk number, the Scan), so that classes()
# of that chunk is computed on the first pass over the file only (build's walls, reach check and
# fallback each ask for every chunk's)
_REPLAYED: tuple | None = None


def classes(a: np.ndarray) -> tuple[np.ndarray, float | None, float | None]:
    """The class bits of each move of a RECORD array (OUTER | ARC | MOVED | EXTRUDES | NULL |
    EXTRUDES_F32), and the highest z1 of the moves that extrude in XY, and of those not on an
    arc (None: none). From the compiled scanner in one pass over the records (the numpy way
    reads the records' memory once per field); both the same (host/tests/gcode/test_movescan.py).
    A chunk a kept Scan replays has them from its first replay on."""
    r = _REPLAYED                             # (read once: another thread may replay too)
    if r is not None and r[0] is a:
        _, k, scan = r
        got = scan._classes.get(k)
        if got is None:
            got = scan._classes[k] = _classes(a)
        return got
    return _classes(a)


def _classes(a: np.ndarray) -> tuple[np.ndarray, float | None, float | None]:
    if _scan is not None:
        c, top, top_line = _scan.move_classes(np.ascontiguousarray(a, dtype=RECORD))
        return np.frombuffer(c, np.uint8), top, top_line
    return _classes_np(a)


def _classes_np(a: np.ndarray) -> tuple[np.ndarray, float | None, float | None]:
    x0, y0, x1, y1, e, fl = a["x0"], a["y0"], a["x1"], a["y1"], a["e"], a["flags"]
    moved = (x0 != x1) | (y0 != y1)
    ext = (e > 0) & moved
    null = ~moved & (a["z0"] == a["z1"]) & (e == 0)
    f = np.float32
    with np.errstate(over="ignore"):           # beyond float32: inf, as the C cast gives
        ext32 = (e.astype(f) > 0) & ((x0.astype(f) != x1.astype(f)) | (y0.astype(f) != y1.astype(f)))
    c = ((fl & (OUTER | ARC)) | (moved * MOVED) | (ext * EXTRUDES) | (null * NULL)
         | (ext32 * EXTRUDES_F32)).astype(np.uint8)
    line = ext & ((fl & ARC) == 0)
    top = float(a["z1"][ext].max()) if ext.any() else None
    top_line = float(a["z1"][line].max()) if line.any() else None
    return c, top, top_line


def available() -> bool:
    return _scan is not None


def _classify(text: str):
    code, comment = gcode.split_code(text)
    if code:
        return True, None
    return False, gcode.feature_of_comment(comment) if comment is not None else None


def _fast(path, lean: int = 0) -> Chunks:
    assert _scan is not None and _scan.RECORD_SIZE == RECORD.itemsize
    sc = _scan.Scanner(sorted(gcode.OUTER_ROLES), sorted(gcode._S3D_ROLES), _classify,
                       lean=lean)
    # the role names, lines and flagged lines as of the part the caller has: the scanner (on the
    # read-ahead thread, _ahead) may be a part further on
    roles: list[str] = []
    tops: list | None = [] if lean else None
    seen = [0, 0, 0]                          # lines, flagged, arcs

    def part(data, final: bool, base: int):
        """One feed of the scanner: (its records (None: none), the scanner's counts after it),
        and the bytes it used."""
        recs, used = sc.feed(data, final, base)
        a = np.frombuffer(recs, dtype=RECORD) if recs else None   # read-only, not copied
        return (a, (sc.lines, sc.flagged, len(sc.roles), sc.top if lean else None, sc.arcs)), used

    def parts_bytes():
        # G-code in memory: windows of it, not copies (a line longer than a window widens it)
        view = memoryview(path)
        base, size = 0, CHUNK_BYTES
        while True:
            stop = min(base + size, len(view))
            final = stop == len(view)
            item, used = part(view[base:stop], final, base)
            yield item
            base += used
            if final:
                return
            size = CHUNK_BYTES if used else 2 * size

    def gen():
        with contextlib.ExitStack() as stack:
            if isinstance(path, (bytes, bytearray)):
                size, parts = len(path), parts_bytes()
            else:
                f = stack.enter_context(open(path, "rb"))
                size = os.fstat(f.fileno()).st_size
                parts = _file_parts(f, lambda data, buf, final, base: part(buf, final, base))
            if _use_ahead(size):
                parts = _ahead(parts)
                stack.callback(parts.close)   # (the worker stopped before the file is closed)
            for a, (lines, flagged, n_roles, top, arcs) in parts:
                seen[:] = lines, flagged, arcs
                roles.extend(sc.roles[len(roles):n_roles])
                if lean:
                    tops.append(top)
                if a is not None:
                    yield a
                progress.tick(lines)
    return Chunks(gen(), roles, lambda: seen[0], lambda: seen[1], tops, arcs=lambda: seen[2],
                  all_arcs=lean != 1)


def from_moves(moves, roles: list[str] | None = None,
               state: gcode.GcodeState | None = None) -> Iterator[np.ndarray]:
    """gcode.Move objects as RECORD arrays (role indices into `roles`, which it fills; the
    G90/M82 flags from `state`, the parser's state as each move is made, else absolute). A
    line's moves (an arc's chords) are not cut between two arrays."""
    roles = [] if roles is None else roles
    role_ix = {r: i for i, r in enumerate(roles)}
    rows = []
    for m in moves:
        r = -1
        if m.role is not None:
            r = role_ix.get(m.role)
            if r is None:
                r = role_ix[m.role] = len(roles)
                roles.append(m.role)
        modes = ABS_XYZ | ABS_E if state is None else (
            (ABS_XYZ if state.abs_xyz else 0) | (ABS_E if state.abs_e else 0))
        if len(rows) >= 65536 and m.line_no != rows[-1][10]:
            yield np.array(rows, dtype=RECORD)
            rows = []
        rows.append((m.x0, m.y0, m.z0, m.x1, m.y1, m.z1, m.e, m.e_start, m.f, -1,
                     m.line_no, r, (OUTER if m.outer else 0) | (ARC if m.arc else 0) | modes, 0))
    if rows:
        yield np.array(rows, dtype=RECORD)


def _slow(path, source: str) -> Chunks:
    roles: list[str] = []
    count = [0, 0]                            # lines, arcs
    st = gcode.GcodeState()

    def moves(f):
        for ln in gcode.parse_lines(f, source, st):
            count[0] = ln.line_no
            if ln.moves and ln.moves[0].arc:
                count[1] += 1
            yield from ln.moves

    def gen():
        if isinstance(path, (bytes, bytearray)):
            f = io.StringIO(bytes(path).decode("utf-8", "replace"), newline="")
        else:
            f = open(path, "r", encoding="utf-8", errors="replace", newline="")
        with f:
            yield from from_moves(moves(f), roles, st)
    return Chunks(gen(), roles, lambda: count[0], arcs=lambda: count[1])


ENDS = 1 << 21                 # bytes of each end kept as text (gcode.open_checked's default)
# a lean Scan's records held in memory up to this; more go to the temporary file: 100 MB of
# G-code (140 MB of lean records) in memory took build's peak from 355 to 480 MB for no time
# saved (the file's pages stay in the page cache: docs/host.md)
LEAN_MEMORY = 64 << 20


class Scan:
    """One reading of a G-code file that every pass of `build` works from: the checks
    (gcode.check_complete: text, not cut off; gcode.check_not_processed) and the move records,
    made in one pass over the file, 2 MB at a time, and read back in the same chunks by each
    run(). All the records (88 bytes a move: 100 MB of G-code gives about 300 MB of them) go to
    an unnamed temporary file, kept out of memory. lean=True (build in marked mode, with the
    compiled scanner): only the lean records (run(..., lean=True)'s) and every arc chord, each
    with its move number, and the tops of the moves left out (Chunks.tops, Chunks.numbers):
    what marked-mode walls, the planner runs (plan_records, in marked mode) and the stock
    fallback need; held in memory up to LEAN_MEMORY bytes, past that (100 MB of G-code gives
    about 140 MB) in the temporary file. Also kept: the text of the file's two ends
    (gcode.open_checked's), whether its lines suit fallback's byte path (gcode._plain_lines)
    and its M92 E words (gcode.scan_m92).

        with movescan.Scan(path).kept():      # movescan.run, gcode.open_checked and
            ...                               # check_input_file on path use it
    """

    def __init__(self, path, source: str | None = None, lean: bool = False):
        self.path = os.fspath(path)
        self.source = source or self.path
        self.fast = _scan is not None          # records from the compiled scanner (with offsets)
        self.lean = lean and self.fast         # (the Python parser gives every record)
        self.roles: list[str] = []
        self.chunks: list[tuple[int, int]] = []     # (records, lines read so far) per chunk
        self.tops: list = []                   # lean: Chunks.tops, per chunk
        self.m92: list[tuple[int, float]] = []
        self.lines = 0
        self.arcs = 0                          # G2/G3 lines
        self._classes: dict[int, tuple] = {}       # classes() of chunk k (non-empty ones), once
        self._held: list[bytes] | None = [] if self.lean else None   # lean, in memory: per
        self._held_bytes = 0                   # chunk its records' bytes, then its numbers'
        self._store = None if self.lean else tempfile.TemporaryFile()
        try:
            self._read()
        except BaseException:
            self.close()
            raise

    def _keep(self, recs: bytes, nums: bytes | None = None) -> None:
        """One chunk's records (and lean: their numbers), in memory or in the temporary file."""
        if self._held is not None:
            self._held.append(recs)
            self._held.append(nums)
            self._held_bytes += len(recs) + len(nums)
            if self._held_bytes <= LEAN_MEMORY:
                return
            self._store = tempfile.TemporaryFile()       # too many for memory: all to the file
            self._store.writelines(self._held)
            self._held = None
            return
        if recs:
            self._store.write(recs)
        if nums:
            self._store.write(nums)

    def _read(self) -> None:
        sc = None
        if self.fast:
            sc = _scan.Scanner(sorted(gcode.OUTER_ROLES), sorted(gcode._S3D_ROLES), _classify,
                               lean=2 if self.lean else 0)
            self.roles = sc.roles
        n_cr = n_crlf = nl = 0
        plain = True
        last = b""

        live = sc                              # the scanner as the reading goes (_ahead's thread)

        def feed(data, buf, final, base):
            """One part read (_file_parts): its new bytes, whether it is the last, the part with
            the bytes left from the one before, the bytes used and the scanner's take on it:
            None (no scanner), False (it left the file to the Python parser), else (records,
            whether a line may be flagged, the line ends consumed, lines so far, and lean: the
            records' move numbers and the part's top). Read and scanned ahead on a thread
            (_ahead) for large files."""
            nonlocal live
            used = len(buf)
            fed = None
            if live is not None:
                flagged, ends0 = live.flagged, live.line_ends
                try:
                    recs, used = live.feed(buf, final, base)
                except _scan.ScanUnsupported:
                    live, fed = None, False
                else:
                    # (a line with a byte >= 0x80 is flagged too: an unflagged part is ASCII)
                    fed = (recs, live.flagged != flagged,
                           [b - a for a, b in zip(ends0, live.line_ends)], live.lines,
                           live.numbers, live.top)
            if live is None and not final:             # checks only: whole lines still
                used = buf.rfind(b"\n") + 1
            return (data, final, buf, used, fed), used

        with open(self.path, "rb") as f, contextlib.ExitStack() as stack:
            size = os.fstat(f.fileno()).st_size
            first = True
            read = _file_parts(f, feed)
            if _use_ahead(size):
                read = _ahead(read)
                stack.callback(read.close)     # (the worker stopped before the file is closed)
            for data, final, buf, used, fed in read:
                if first:
                    gcode.check_text(data[:65537] if size > 65536 else data, self.source)
                    head = b""
                    whole = data if size <= len(data) else None
                    first = False
                if len(head) < ENDS:
                    head += data[:ENDS - len(head)]
                look = True                            # whether the part may hold what the regexes find
                ends = None                            # the part's line ends, counted by the scanner
                if fed is False:
                    sc, self.fast = None, False        # the Python parser does it below
                elif fed is not None:
                    recs, look, ends, lines, nums, top = fed
                    if self.lean:
                        self._keep(recs, nums)
                        self.tops.append(top)
                    elif recs:
                        self._store.write(recs)
                    self.chunks.append((len(recs) // RECORD.itemsize, lines))
                    progress.tick(lines)
                part = buf[:used] if look or ends is None else None
                # the checks, on whole lines (a \r\n cut between two parts counted once)
                # (a part after a lone \r does not start a line for the regexes' ^, as in one piece)
                at = 0 if not last or last == b"\n" else 1
                if look:
                    gcode._refuse_processed(part, self.source, nl, at)
                if ends is not None:
                    d_nl, d_cr, d_crlf = ends
                else:
                    d_nl, d_cr = part.count(b"\n"), part.count(b"\r")
                    d_crlf = part.count(b"\r\n") + (last[-1:] == b"\r" and part[:1] == b"\n")
                n_cr += d_cr
                n_crlf += d_crlf
                if plain and part is not None and not part.isascii():
                    try:                               # parts end at line ends: no character cut
                        part.decode("utf-8")
                    except UnicodeDecodeError:
                        plain = False
                if look and gcode.might_hold(part, (b"M92", b"m92")):
                    for mt in gcode._M92_RX.finditer(part, at):
                        e = gcode._m92_e(mt.group(1))
                        if e is not None:
                            self.m92.append((nl + part.count(b"\n", 0, mt.start()) + 1, e))
                nl += d_nl
                if used:
                    last = buf[used - 1:used]
            read.close()                               # (done reading: the tail is read below)
            tail = whole[-ENDS:] if whole is not None else b""
            if whole is None:
                f.seek(max(0, size - ENDS))
                tail = f.read(ENDS)
        self.plain_lines = plain and n_cr == n_crlf
        self.nl = nl
        self.ends = head.decode("utf-8", "replace") + "\n" + (tail.decode("utf-8", "replace") if size > ENDS else "")
        self._complete(head, tail)
        if sc is not None:
            self.lines, self.arcs = sc.lines, sc.arcs
        else:                                  # the Python parser's records (no offsets)
            if self._store is None:
                self._store = tempfile.TemporaryFile()
            self._store.seek(0)
            self._store.truncate()
            self.chunks, self.tops, self._held, self.lean = [], [], None, False
            ch = _slow(self.path, self.source)
            for a in ch:
                self._store.write(a.tobytes())
                self.chunks.append((len(a), ch.lines))
            self.roles, self.lines, self.arcs = ch.roles, ch.lines, ch.arcs

    def _complete(self, head: bytes, tail: bytes) -> None:
        """gcode.check_complete's checks of the file's ends, on its first and last bytes."""
        last = gcode.check_ends(head[:gcode.ENDS_CHECKED], tail[-gcode.ENDS_CHECKED:], self.source)
        if last is not None:
            gcode.refuse_cut_off(last, self.nl + 1, self.source)

    def run(self, consume: Callable[[Chunks], T], fast: bool | None = None) -> T:
        """As movescan.run on the file, from the kept records."""
        if fast and not self.fast:
            raise Unsupported("the compiled scanner left the file to the Python parser")
        done = [0]
        numbers: list | None = [] if self.lean else None

        def gen():
            global _REPLAYED
            held, store = self._held, self._store
            # read by position, not from the file's offset: a child forked to work beside this
            # process (bulgekit.parallel: build's stock fallback) shares the offset with it
            if held is None:
                store.flush()
                fd, at = store.fileno(), 0
            for i, (k, lines) in enumerate(self.chunks):
                if held is not None:
                    recs, nums = held[2 * i], held[2 * i + 1]
                else:
                    recs = _pread(fd, k * RECORD.itemsize, at)
                    at += len(recs)
                    nums = None
                    if numbers is not None:
                        nums = _pread(fd, 8 * k, at)
                        at += len(nums)
                a = np.frombuffer(recs, dtype=RECORD)
                done[0] = lines
                progress.tick(lines)
                if k:
                    if numbers is not None:
                        numbers.append(np.frombuffer(nums, dtype="<i8"))
                    _REPLAYED = (a, i, self)
                    yield a
            _REPLAYED = None
            done[0] = self.lines
        return consume(Chunks(gen(), list(self.roles), lambda: done[0],
                              tops=list(self.tops) if self.lean else None, numbers=numbers,
                              arcs=lambda: self.arcs))

    def text_lines(self) -> Iterator[str]:
        """The file's lines as text (what gcode.open_checked's iterator gives), opened lazily."""
        with open(self.path, "r", encoding="utf-8", errors="replace", newline="") as f:
            yield from f

    def close(self) -> None:
        global _REPLAYED
        r = _REPLAYED
        if r is not None and r[2] is self:
            _REPLAYED = None
        self._classes.clear()
        self._held = None
        if self._store is not None:
            self._store.close()

    def kept(self):
        """Context: while in it, passes over this file use this scan (see the class comment)."""

        @contextlib.contextmanager
        def ctx():
            key = _key(self.path)
            prev = _KEPT.get(key)
            _KEPT[key] = self
            try:
                yield self
            finally:
                if prev is None:
                    _KEPT.pop(key, None)
                else:
                    _KEPT[key] = prev
                self.close()
        return ctx()


_KEPT: dict[str, Scan] = {}


def _pread(fd: int, n: int, at: int) -> bytes:
    """n bytes of the file fd from offset at (fewer at its end; os.pread may give fewer)."""
    parts, got = [], 0
    while got < n:
        b = os.pread(fd, n - got, at + got)
        if not b:
            break
        parts.append(b)
        got += len(b)
    return parts[0] if len(parts) == 1 else b"".join(parts)


def _key(path) -> str:
    return os.path.realpath(os.fspath(path))


def kept(path) -> Scan | None:
    """The Scan in force for the file at path, if any (bytes given in place of a path: None)."""
    if not _KEPT or isinstance(path, (bytes, bytearray)):
        return None
    return _KEPT.get(_key(path))


def run(path, consume: Callable[[Chunks], T], source: str | None = None,
        fast: bool | None = None, lean: int = 0) -> T:
    """consume(chunks) over the moves of the file at path (or of G-code bytes); see the module
    comment. fast=False forces the Python parser (tests compare the two); fast=True the compiled
    one only (Unsupported when it leaves the file to the Python parser). A file a Scan in force
    has read is not read again (fast=False still reads it with the Python parser). lean: the
    compiled scanner gives only the records annotate's lazy reach check plans (Chunks.tops;
    lean=2: and every arc chord, Chunks.all_arcs); the Python parser gives them all, a kept Scan
    those it holds (Scan's lean)."""
    sc = kept(path)
    if sc is not None and fast is not False:
        return sc.run(consume, fast)
    source = source or ("<gcode>" if isinstance(path, (bytes, bytearray)) else str(path))
    if fast is None:
        use = _scan is not None
    else:
        use = fast
        if fast and _scan is None:
            raise Unsupported("bulgekit.gcode._scan is not built")
    if use:
        try:
            return _consume(consume, _fast(path, int(lean)))
        except _scan.ScanUnsupported as e:
            if fast:
                raise Unsupported(f"line {e.args[0]}") from None
    return _consume(consume, _slow(path, source))
