"""Moves of a G-code file as numpy record arrays, chunk by chunk, for the passes that need only
moves (walls, statistics, the stock fallback, annotate's reach check): the compiled scanner (_scan.c) when it is built and takes the file,
gcode.parse_lines otherwise. Both give the same numbers (host/tests/test_movescan.py).

    run(path, consume)      # consume(chunks) gets an iterator of RECORD arrays and the role names

consume must start from nothing each time it is called: when the compiled scanner meets a line it
leaves to the Python parser (a command with non-ASCII bytes, a value or arc gcode.py refuses),
consume is called again with the Python parser's chunks, which give the moves or the error
message naming the file and line.

`bulgekit --version` says which scanner is in use.
"""
from __future__ import annotations

import io
from typing import Callable, Iterator, TypeVar

import numpy as np

from . import gcode, progress

try:
    from . import _scan
except ImportError:          # built without a C compiler: the Python parser does all the work
    _scan = None

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

CHUNK_BYTES = 2 << 20        # 2 MB of G-code: about 7 MB of records at a time
T = TypeVar("T")


class Unsupported(Exception):
    """The compiled scanner left the file to the Python parser, and the caller asked for the
    compiled one only (it needs the byte offsets)."""


class Chunks:
    """What consume gets: iterate for RECORD arrays (moves in file order); `roles` names the
    role indices seen so far (complete once iteration ends); `lines` counts the lines read."""

    def __init__(self, it: Iterator[np.ndarray], roles: list[str], lines: Callable[[], int]):
        self._it, self.roles, self._lines = it, roles, lines

    def __iter__(self):
        return self._it

    @property
    def lines(self) -> int:
        return self._lines()


def z_cmm(z: np.ndarray) -> np.ndarray:
    """Move z (mm) as the firmware reads it: 0.01 mm, rounded in float32, half away from zero
    (bulge_planner.cpp; fallback.RefPlanner._cmm and wall._z_cmm one at a time)."""
    v = (np.asarray(z).astype(np.float32) * np.float32(100.0)).astype(np.float64)
    return np.where(v >= 0, np.floor(v + 0.5), -np.floor(0.5 - v)).astype(np.int64)


def available() -> bool:
    return _scan is not None


def _classify(text: str):
    code, comment = gcode.split_code(text)
    if code:
        return True, None
    return False, gcode.feature_of_comment(comment) if comment is not None else None


def _fast(path) -> Chunks:
    assert _scan is not None and _scan.RECORD_SIZE == RECORD.itemsize
    sc = _scan.Scanner(sorted(gcode.OUTER_ROLES), sorted(gcode._S3D_ROLES), _classify,
                       gcode.ARC_CHORD_MM)
    roles: list[str] = sc.roles              # the scanner's own list, filled as it reads

    def gen():
        base = 0                              # file offset of buf[0]
        buf = b""
        with (io.BytesIO(path) if isinstance(path, (bytes, bytearray)) else open(path, "rb")) as f:
            while True:
                data = f.read(CHUNK_BYTES)
                final = not data
                buf = buf + data if buf else data
                recs, used = sc.feed(buf, final, base)
                if recs:
                    yield np.frombuffer(recs, dtype=RECORD)         # read-only, not copied
                progress.tick(sc.lines)
                base += used
                buf = buf[used:]
                if final:
                    return
    return Chunks(gen(), roles, lambda: sc.lines)


def from_moves(moves, roles: list[str] | None = None,
               state: gcode.GcodeState | None = None) -> Iterator[np.ndarray]:
    """gcode.Move objects as RECORD arrays (role indices into `roles`, which it fills; the
    G90/M82 flags from `state`, the parser's state as each move is made, else absolute)."""
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
        rows.append((m.x0, m.y0, m.z0, m.x1, m.y1, m.z1, m.e, m.e_start, m.f, -1,
                     m.line_no, r, (OUTER if m.outer else 0) | (ARC if m.arc else 0) | modes, 0))
        if len(rows) >= 65536:
            yield np.array(rows, dtype=RECORD)
            rows = []
    if rows:
        yield np.array(rows, dtype=RECORD)


def _slow(path, source: str) -> Chunks:
    roles: list[str] = []
    count = [0]
    st = gcode.GcodeState()

    def moves(f):
        for ln in gcode.parse_lines(f, source, st):
            count[0] = ln.line_no
            yield from ln.moves

    def gen():
        if isinstance(path, (bytes, bytearray)):
            f = io.StringIO(bytes(path).decode("utf-8", "replace"), newline="")
        else:
            f = open(path, "r", encoding="utf-8", errors="replace", newline="")
        with f:
            yield from from_moves(moves(f), roles, st)
    return Chunks(gen(), roles, lambda: count[0])


def run(path, consume: Callable[[Chunks], T], source: str | None = None,
        fast: bool | None = None) -> T:
    """consume(chunks) over the moves of the file at path (or of G-code bytes); see the module
    comment. fast=False forces the Python parser (tests compare the two); fast=True the compiled
    one only (Unsupported when it leaves the file to the Python parser)."""
    source = source or ("<gcode>" if isinstance(path, (bytes, bytearray)) else str(path))
    if fast is None:
        use = _scan is not None
    else:
        use = fast
        if fast and _scan is None:
            raise Unsupported("bulgekit._scan is not built")
    if use:
        try:
            return consume(_fast(path))
        except _scan.ScanUnsupported as e:
            if fast:
                raise Unsupported(f"line {e.args[0]}") from None
    return consume(_slow(path, source))
