"""Annotate sliced G-code for the bulgekit firmware.

The host's moves are left exactly as the slicer wrote them, but for the G2/G3 arcs on which map
points lie (fallback.ArcLines): those are written as G1 chords, Marlin's own segments
(gcode.arc_segments), as the stock file writes them, since the firmware splits only G0/G1 moves.
Added:
  * at the top: M720 (settings), M721 X, then the M721 upload of the map
    (all of it, or as many layer records as the arena takes);
  * M722 S1 / M722 S0 after each slicer feature comment that enters / leaves
    the outer wall (marked mode; none in geometric mode, M720 S2);
  * M721 ... A1 appends of the next layer records just before the first
    layer that needs one that is not on the printer yet;
  * at the end: M722 S0 (if still inside), M720 S0 and M721 X.

Streaming model (mirrors src/bulge_planner.cpp): when the nozzle first
extrudes in a new record's layer window the firmware releases the records
below it.  At an append point the host therefore counts as resident every
record sent whose z is at or above the record of the layer printed last,
and sends only what fits in the rest of the arena (BK_MAP_ARENA_BYTES).

The feature comment lines and layer changes are found by the compiled scanner's
line walkers (_scan.feature_lines, _scan.z_events, both in one pass: _scan.line_marks), or
without it by the regular expressions they mirror (no per-line Python work either way), and the
output is the file's own bytes between the added lines, written by os.writev.  The check that
every map point is reached (check_reach, on by default) runs the reference planner on the moves
that can stop or change its state (fallback.Skipper), read by the compiled scanner
(movescan: in marked mode only the records the lazy planning can plan); its scan also tells
whether check_not_processed has anything to look at.  100 MB annotate in about 0.8 s of CPU
(docs/host.md).
"""
from __future__ import annotations

import functools
import gc
import mmap
import os
import re
from dataclasses import dataclass, field
from operator import itemgetter

import numpy as np

from . import mapformat
from .fallback import MODE_GEOMETRIC, MODE_MARKED, ArcCount, Settings
from ..gcode import check_complete, check_not_processed, feature_of_comment, is_outer
from .. import progress
from ..errors import BulgekitError
from ..outputs import part as output_part
from ..parallel import Forked

ARENA_BYTES = mapformat.ARENA_BYTES


class AnnotateError(BulgekitError):
    pass


# The scans look for a literal first (';', 'Z', 'G9') so the regex engine can
# skip through the file at C speed, then check the line around each hit.
# feature_of_comment() has the final word on a feature comment, so the
# annotator and the parser (fallback, walls) agree on every line.
_FEATURE_RX = re.compile(
    rb";[ \t]*(?:TYPE:|FEATURE:|outer perimeter|inner perimeter|infill|solid layer|"
    rb"support|dense support|skirt|raft|bridge|gap fill|prime pillar|ooze shield)[^\n]*")
_Z_RX = re.compile(rb"Z[ \t]*([-+]?[0-9]*\.?[0-9]+)")
_G9X_RX = re.compile(rb"G9([01])\b")
# A move that extrudes in XY (X or Y and E on a G0/G1 line), at a line start.
_EXTRUDE_RX = re.compile(rb"\n[ \t]*G0?[01][ \t](?=[^\n;]*[XY])[^\n;]*E")
_MOVE_HEAD = re.compile(rb"[ \t]*G0?[01][ \t]")


def _line_start(data: bytes, pos: int) -> int:
    return data.rfind(b"\n", 0, pos) + 1


def _scanner():
    from ..gcode import movescan
    return movescan._scan


def _feature_comments(data: bytes, lines: list | None = None) -> list[tuple[int, str]]:
    """(end of line offset, role) of every whole-line feature comment: the compiled scanner
    finds the lines (_scan.feature_lines; lines: found already), else the regular expression.
    Each distinct comment is read once: a file repeats a few comments thousands of times."""
    sc = _scanner()
    if lines is None and sc is None:
        return list(_feature_comments_rx(data))
    if lines is None:
        lines = sc.feature_lines(data)
    roles = {c: feature_of_comment(c.decode("utf-8", "replace")) for c in {c for _, c in lines}}
    return [(end, role) for end, c in lines if (role := roles[c]) is not None]


def _feature_marks(data: bytes, lines: list | None = None) -> list[tuple[int, bool]]:
    """(end of line offset, whether its role is an outer wall) of every whole-line feature
    comment with a role (_feature_comments), each role asked once. lines:
    _scan.feature_lines(data) found already."""
    found = _feature_comments(data, lines)
    outer_of = {role: is_outer(role) for role in {role for _, role in found}}
    return [(end, outer_of[role]) for end, role in found]


def _feature_comments_rx(data: bytes):
    for mt in _FEATURE_RX.finditer(data):
        ls = _line_start(data, mt.start())
        if data[ls:mt.start()].strip(b" \t"):
            continue  # a comment after a command, not a feature tag
        role = feature_of_comment(mt.group(0).decode("utf-8", "replace")[1:])
        if role is not None:
            yield mt.end(), role


def _gc_paused(fn):
    """fn run with the cyclic garbage collector off (as it was after): annotate's tens of
    thousands of small tuples hold no cycles, and the collector's passes while they are made
    cost about 0.02 s on 100 MB (docs/host.md)."""
    @functools.wraps(fn)
    def run(*args, **kw):
        if not gc.isenabled():
            return fn(*args, **kw)
        gc.disable()
        try:
            return fn(*args, **kw)
        finally:
            gc.enable()
    return run


@dataclass
class AnnotateResult:
    lines_added: int = 0
    markers: int = 0
    initial_records: int = 0
    appends: list[tuple[float, int, int]] = field(default_factory=list)  # (at z, records, bytes)
    outer_sections: int = 0
    features_seen: int = 0
    notes: list[str] = field(default_factory=list)
    arcs: ArcCount = field(default_factory=ArcCount)      # G2/G3 written as G1 chords


def _z_events(data: bytes):
    """[(offset, z_cmm)] for each G0/G1 Z move followed by XY extrusion
    before the next Z move (real layer changes; z-hops are skipped): from the compiled
    scanner (_scan.z_events, the same in C), else the regular expressions."""
    sc = _scanner()
    return _z_events_rx(data) if sc is None else sc.z_events(data)


def _z_events_rx(data: bytes):
    # G90/G91 switch Z between absolute and relative (end G-code often lifts
    # with G91 / G1 Z10 / G90)
    modes = [(m.start(), m.group(1) == b"0") for m in _G9X_RX.finditer(data)
             if not data[_line_start(data, m.start()):m.start()].strip(b" \t")]
    mi = 0
    absolute = True
    z = 0.0
    zlines = []
    for mt in _Z_RX.finditer(data):
        pos = mt.start()
        ls = _line_start(data, pos)
        if not _MOVE_HEAD.match(data, ls):
            continue
        if data.find(b";", ls, pos) >= 0:
            continue  # Z inside a comment
        while mi < len(modes) and modes[mi][0] < pos:
            absolute = modes[mi][1]
            mi += 1
        v = float(mt.group(1))
        z = v if absolute else z + v
        zlines.append((ls, mt.end(), z))
    zs = []
    n = len(zlines)
    for k, (start, end, zz) in enumerate(zlines):
        stop = zlines[k + 1][0] if k + 1 < n else len(data)
        # the Z line itself, or a later line before the next Z move, extrudes
        if _EXTRUDE_RX.match(data, start - 1 if start else 0) or \
                _EXTRUDE_RX.search(data, end, stop):
            zc = round(zz * 100)
            if not zs or zs[-1][1] != zc:
                zs.append((start, zc))
    return zs


def annotate_bytes(data: bytes, map_bytes: bytes, settings: Settings,
                   arena: int = ARENA_BYTES, stream: bool = True, source: str = "<gcode>",
                   result: AnnotateResult | None = None) -> bytes:
    bm = mapformat.decode_map(map_bytes, source="map")
    arcs = arc_lines(data, bm, settings, source)
    return b"".join(_annotated(data, map_bytes, settings, arena, stream, source, result, bm, arcs))


@_gc_paused
def _annotated(data: bytes, map_bytes: bytes, settings: Settings, arena: int, stream: bool,
               source: str, result: AnnotateResult | None,
               bm: mapformat.BulgeMap | None = None, arcs: list | None = None) -> list:
    """annotate_bytes' output as pieces: slices of data (memoryviews, not copies) with the
    inserted lines between them, to be joined or written one after the other. bm: map_bytes
    decoded already; arcs: the arcs to write as chords (arc_lines)."""
    res = result if result is not None else AnnotateResult()
    bm = bm if bm is not None else mapformat.decode_map(map_bytes, source="map")
    geometric = settings.mode == MODE_GEOMETRIC
    recs = mapformat.record_bytes(map_bytes)
    zrec = [l.z_cmm for l in bm.layers]
    h = bm.layer_height_cmm
    header = bytes(map_bytes[:mapformat.HEADER_BYTES])
    eol = b"\r\n" if b"\r\n" in data[:4096] else b"\n"
    inserts: list[tuple[int, int, bytes]] = []   # (offset, order, text)
    skip = _arc_inserts(data, arcs, eol, source, res, inserts) if arcs else {}

    # ---- initial upload: the header (kept beside the arena by the firmware)
    # and as many records as the arena takes
    k = 0
    size = 0
    while k < len(recs) and size + len(recs[k]) <= arena:
        size += len(recs[k])
        k += 1
    if k < len(recs) and not stream:
        over = ", ".join(f"z {zrec[i] / 100:.2f} mm" for i in range(k, len(recs)))
        raise AnnotateError(
            f"the map's layer records need {sum(map(len, recs))} bytes but the printer's arena "
            f"holds {arena}: layers {over} do not fit. Annotate with streaming (the default) to "
            "send them as appends while printing.")
    res.initial_records = k
    first = header + b"".join(recs[:k])
    top = [f"; bulgekit: {len(recs)} layers, {bm.point_count} points, "
           f"{len(header) + sum(map(len, recs))} bytes, arena {arena}"
           + ("" if k == len(recs) else f", {len(recs) - k} layers streamed") , settings.m720(),
           "M721 X"]
    if res.arcs.arcs:
        top.insert(1, f"; bulgekit: {res.arcs.text()}")
    top += mapformat.upload_lines(first, checked=True)
    inserts.append((0, 0, eol.join(t.encode() for t in top) + eol))

    # the feature lines and the layer changes from one pass over the data when both are wanted
    # (an older build of the scanner has no line_marks)
    both = getattr(_scanner(), "line_marks", None) if not geometric and k < len(recs) else None
    comment_lines, layer_changes = both(data) if both is not None else (None, None)

    # ---- markers
    if not geometric:
        inside = False
        marks = _feature_marks(data, comment_lines)
        res.features_seen = len(marks)
        on, off = b"M722 S1" + eol, b"M722 S0" + eol
        n = len(data)
        add = inserts.append
        markers = sections = 0                # (into res once, not per marker)
        for eol_at, outer in marks:
            if outer != inside:
                inside = outer
                # (eol_at is the comment's '\n', or the end of data: the line after it, or a
                # line end first)
                if eol_at < n:
                    add((eol_at + 1, 1, on if outer else off))
                else:
                    add((n, 1, eol + (on if outer else off)))
                markers += 1
                sections += outer
        res.markers += markers
        res.outer_sections += sections
        if res.features_seen == 0:
            raise AnnotateError(
                f"{source}: no slicer feature comments found, so the outer wall cannot be "
                "marked. Slice with feature comments (;TYPE:...), or annotate with --geometric "
                "(M720 S2: every extruding move near a map point bulges, no markers).")
        if res.outer_sections == 0:
            raise AnnotateError(
                f"{source}: feature comments found but none marks the outer wall "
                "(;TYPE:External perimeter, ;TYPE:Outer wall, ;TYPE:WALL-OUTER, ; outer perimeter). "
                "Use --geometric (M720 S2) to annotate without markers.")
        tail_inside = inside
    else:
        tail_inside = False

    # ---- appends before the layers that need records not yet sent
    if k < len(recs):
        sent_until = k                 # records [0, sent_until) were sent
        last_layer_z = None            # z (cmm) of the layer printed last
        for off, zc in layer_changes if layer_changes is not None else _z_events(data):
            if sent_until < len(recs) and 2 * (zrec[sent_until] - zc) <= h:
                # resident: sent records at or above the record found for the
                # layer printed last (or everything when none was found yet)
                floor = None
                if last_layer_z is not None:
                    for i in range(sent_until - 1, -1, -1):
                        if 2 * (zrec[i] - last_layer_z) <= h:
                            floor = zrec[i]
                            break
                resident = sum(len(recs[i]) for i in range(sent_until)
                               if floor is None or zrec[i] >= floor)
                free = arena - resident
                j = sent_until
                size = 0
                while j < len(recs) and size + len(recs[j]) <= free:
                    size += len(recs[j])
                    j += 1
                if j == sent_until:
                    raise AnnotateError(
                        f"record z {zrec[j] / 100:.2f} mm ({len(recs[j])} bytes) does not fit the "
                        f"{free} bytes free at z {zc / 100:.2f} mm")
                payload = b"".join(recs[sent_until:j])
                txt = [f"; bulgekit: layers {zrec[sent_until] / 100:.2f}..{zrec[j - 1] / 100:.2f} mm"]
                txt += mapformat.upload_lines(payload, append=True, has_weights=bm.has_weights,
                                              checked=True)
                inserts.append((off, 2, eol.join(t.encode() for t in txt) + eol))
                res.appends.append((zc / 100, j - sent_until, len(payload)))
                sent_until = j
            last_layer_z = zc
        if sent_until < len(recs):
            raise AnnotateError(
                f"{source}: the print never reaches z {zrec[sent_until] / 100:.2f} mm; "
                "the map does not belong to this G-code")

    tail = []
    if tail_inside:
        tail.append(b"M722 S0")
    tail += [b"; bulgekit: end", b"M720 S0", b"M721 X"]
    pre = b"" if not len(data) or data[-1:] == b"\n" else eol
    inserts.append((len(data), 3, pre + eol.join(tail) + eol))

    inserts.sort(key=itemgetter(0, 1))
    parts = []
    add = parts.append
    pos = lines = 0
    view = memoryview(data)
    for off, order, txt in inserts:
        add(view[pos:off])
        add(txt)
        lines += txt.count(b"\n")
        pos = off
        if order == _ARC_ORDER:                 # in place of an arc's line
            pos += skip[off]
            lines -= 1
    res.lines_added += lines
    parts.append(view[pos:])
    return parts


_ARC_ORDER = 4          # an arc's chords, in place of its line (after a marker at its start)


def _arc_inserts(data, arcs: list, eol: bytes, source: str, res: AnnotateResult,
                 inserts: list) -> dict[int, int]:
    """The chords of each arc of arcs (arc_lines) as inserts in place of its line, as the stock
    file writes them (fallback.arc_text); counted in res.arcs. Returns {offset: the line's
    length} of the lines they replace."""
    from .fallback import StockStops, StopWriter, arc_text
    sw = StopWriter(StockStops())
    sw.arcs = res.arcs
    starts = None
    skip = {}
    for rows in arcs:
        at = int(rows[0]["offset"])
        if at < 0:                            # (the Python parser's records: no offsets)
            if starts is None:
                starts = np.concatenate(([0], np.flatnonzero(np.frombuffer(data, np.uint8) == 10) + 1))
            at = int(starts[int(rows[0]["line_no"]) - 1])
        end = data.find(b"\n", at)
        end = len(data) if end < 0 else end + 1
        text = arc_text(bytes(data[at:end]).decode("utf-8"), rows, sw, source)
        inserts.append((at, _ARC_ORDER, text.replace("\n", eol.decode()).encode()))
        skip[at] = end - at
    return skip


def arc_lines(gcode, bm: mapformat.BulgeMap, settings: Settings, source: str) -> list:
    """The G2/G3 lines of a G-code file (a path, or its bytes) the annotated file writes as
    chords, with their chord records (fallback.ArcLines.found): none for a file without arcs
    (its scan counts them: build's one scan has, others scan the file first)."""
    from ..gcode import movescan
    kept = movescan.kept(gcode)
    n = kept.arcs if kept is not None else movescan.run(gcode, _arc_count, source)
    return _arc_run(gcode, bm, settings, source)[1] if n else []


def _arc_count(chunks) -> int:
    for _ in chunks:
        pass
    return chunks.arcs


def _arc_run(gcode, bm: mapformat.BulgeMap, settings: Settings, source: str) -> tuple[str | None, list]:
    """The reference planner over the file with every arc's chords planned as G0/G1 moves, as the
    firmware sees the written file (fallback.ArcLines): the message naming the map points it
    does not reach (or None), and the arcs to write as chords."""
    from ..gcode import movescan
    from .fallback import ArcLines, RefPlanner, plan_records, unreached_message

    def run(chunks):
        planner = RefPlanner(bm, settings)
        arcs = ArcLines(planner)
        plan_records(planner, chunks, arcs, on_chunk=arcs.collect)
        return unreached_message(planner, source), arcs.found
    # in marked mode the outer-wall moves, their followers and every arc chord (lean 2)
    return movescan.run(gcode, run, source, lean=2 if settings.mode == MODE_MARKED else 0)


def check_reach(gcode, map_bytes: bytes, settings: Settings, source: str) -> str | None:
    """Run the G-code (a path, or its bytes) through the reference planner: a message naming
    the map points no move reaches (the map is for another file?), or None. The G2/G3 arcs on
    which points lie count as the chords annotate writes for them (arc_lines); the others for
    nothing, as in the firmware. Only the moves that can change the planner's work go through
    its Python code (fallback.Skipper)."""
    return _reach(gcode, map_bytes, settings, source)[0]


def _reach(gcode, map_bytes: bytes, settings: Settings, source: str,
           bm: mapformat.BulgeMap | None = None) -> tuple[str | None, int | None, list]:
    """check_reach's message, the lines the compiled scanner flagged on the way (None when
    it did not read the file): none means check_not_processed would find nothing; and the arcs
    to write as chords (arc_lines). bm: map_bytes decoded already."""
    from ..gcode import movescan
    from .fallback import RefPlanner, plan_records, unreached_message
    bm = bm if bm is not None else mapformat.decode_map(map_bytes, source="map")

    def run(chunks):
        planner = RefPlanner(bm, settings)
        # (arcs as the firmware sees the slicer's file: not at all; a file with arcs is planned
        # again below, its arcs as the chords written where points lie on them)
        plan_records(planner, chunks, arcs_bypass=True, lazy=True)
        return unreached_message(planner, source), chunks.flagged, chunks.arcs
    # in marked mode the scanner gives only the records the lazy planning can plan
    msg, flagged, n_arcs = movescan.run(gcode, run, source, lean=settings.mode == MODE_MARKED)
    if not n_arcs:
        return msg, flagged, []
    msg, found = _arc_run(gcode, bm, settings, source)
    return msg, flagged, found


def annotate_file(src, dst, map_bytes: bytes, settings: Settings, arena: int = ARENA_BYTES,
                  stream: bool = True, check: bool = True,
                  allow_unreached: bool = False, *,
                  decoded: mapformat.BulgeMap | None = None) -> AnnotateResult:
    """Annotate src into dst.  With check (default) the file is also run
    through the reference planner, and map points no move reaches are an
    error unless allow_unreached (then the message is in result.notes).
    decoded: map_bytes decoded already (the CLI's check of the map file). The arcs on which
    points lie are written as chords (arc_lines): found by the check's planner run, or without
    the check by a run of their own when the file has arcs."""
    from ..gcode import movescan
    kept = movescan.kept(src) is not None     # build's one scan checked it already
    msg = flagged = failed = None
    arcs: list = []
    try:                                      # (decoded once for both passes)
        bm = decoded if decoded is not None else mapformat.decode_map(map_bytes, source="map")
        bad_map = None
    except mapformat.MapFormatError as e:
        bm, bad_map = None, e
    res = AnnotateResult()
    out = made = wrote = None                 # the markers, or what making or writing them raised
    job = None
    try:
        with output_part(dst) as tmp:         # in place once every check passed (bulgekit.outputs)
            if check and bad_map is None and not kept:
                # the reach check in a child on the second core (bulgekit.parallel), reading the
                # file itself, while it is read here and the markers are made and written: a 100 MB
                # file's 0.65-0.75 s in one process became 0.45-0.5 s. What either finds wrong is
                # said below in the order the checks always had.
                job = Forked.running(lambda: _reach(src, map_bytes, settings, str(src), bm))
            with open(src, "rb") as f:
                size = os.fstat(f.fileno()).st_size
                # in build, mapped rather than read (its scan checked the file; the output is
                # slices of it): 100 MB read into memory cost 0.1-0.2 s and its size in memory
                # again while the stock fallback reads it beside (bulgekit.parallel)
                data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if kept and size else f.read()
            if not kept:
                check_complete(data, str(src))
            # the markers made and written first (while a forked check runs beside); what making
            # or writing them raised is said in its turn below
            if bad_map is None:
                made, out = _attempt(_annotated, data, map_bytes, settings, arena, stream, str(src),
                                     res, bm)
                if made is None:
                    wrote = _attempt(_write_file, tmp, out)[0]
            if check:
                # the reach check's scan comes first, as it also tells where check_not_processed
                # can find something
                try:
                    if bad_map is not None:
                        raise bad_map
                    msg, flagged, arcs = (job.result() if job is not None and job.forked
                                          else _reach(src if kept else data, map_bytes, settings, str(src), bm))
                except (BulgekitError, mapformat.MapFormatError) as e:
                    failed = e
            elif bad_map is None and made is None:
                arcs = arc_lines(src if kept else data, bm, settings, str(src))
            if arcs and made is None and failed is None:
                # the arcs on which points lie, as chords: made and written again (files with
                # arcs only; the markers were made beside the check, which finds them)
                res = AnnotateResult()
                made, out = _attempt(_annotated, data, map_bytes, settings, arena, stream, str(src),
                                     res, bm, arcs)
                if made is None:
                    wrote = _attempt(_write_file, tmp, out)[0]
            if not kept and flagged != 0:
                check_not_processed(data, str(src))
            if bad_map is not None:
                raise bad_map
            if made is not None:
                raise made
            if failed is not None:
                raise failed
            if check:
                if msg and not allow_unreached:
                    raise AnnotateError(msg)
                if msg:
                    res.notes.append(msg)
            if wrote is not None:
                raise wrote
    finally:
        if job is not None:
            job.close()
    return res


def _attempt(fn, *args):
    """(None, fn(*args)), or (the exception it raised, None): raised later, in its turn."""
    try:
        return None, fn(*args)
    except Exception as e:
        return e, None


def _write_file(path, pieces: list) -> None:
    with open(path, "wb") as f:
        _write_pieces(f, pieces)              # the file's own bytes between the lines added


def annotate_gcode(gcode, map_bytes: bytes, out, settings: Settings = Settings(), *,
                   stream: bool = True, arena: int = ARENA_BYTES, check: bool = True,
                   allow_unreached: bool = False,
                   _decoded: mapformat.BulgeMap | None = None) -> AnnotateResult:
    """Map points no move reaches are an error unless allow_unreached
    (check=False skips the reference-planner run that finds them). _decoded: map_bytes decoded
    already (the CLI's check of the map file)."""
    with progress.phase("annotating", path=gcode):
        return annotate_file(gcode, out, map_bytes, settings, arena, stream, check,
                             allow_unreached, decoded=_decoded)


try:
    _IOV_MAX = os.sysconf("SC_IOV_MAX")
except (AttributeError, ValueError, OSError):
    _IOV_MAX = 16                             # POSIX's least


def _write_pieces(f, pieces: list) -> None:
    """Write pieces (bytes, memoryviews) to the binary file f one after the other. By os.writev,
    up to IOV_MAX pieces a call, where there is one: f.writelines copies each piece into the
    file's buffer first, for annotate's 100 MB and 58,000 pieces about 0.06 s more
    (docs/host.md)."""
    if not hasattr(os, "writev") or _IOV_MAX < 1:
        f.writelines(pieces)
        return
    f.flush()
    fd = f.fileno()
    i, n = 0, len(pieces)
    while i < n:
        batch = pieces[i:i + _IOV_MAX]
        done = os.writev(fd, batch)
        if done == sum(map(len, batch)):
            i += len(batch)
            continue
        # a short write (a signal; a full disk is an error): on from the first byte not written
        for p in batch:
            if done < len(p):
                pieces = [memoryview(p)[done:]] + pieces[i + 1:]
                i, n = 0, len(pieces)
                break
            done -= len(p)
            i += 1
