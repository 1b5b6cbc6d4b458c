"""Annotate sliced G-code for the bulgekit firmware.

The host's moves are left exactly as the slicer wrote them.  Added:
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

The scan is a few regular-expression passes over the whole file (no per-line
Python work), so 100 MB annotate in a few seconds.  The check that every map
point is reached (check_reach, on by default) runs the reference planner over
every move and costs about 0.5 s per MB.
"""
from __future__ import annotations

import bisect
import re
from dataclasses import dataclass, field

from . import mapformat
from .fallback import MODE_GEOMETRIC, Settings, StopRecord, near_segments
from .gcode import GcodeState, check_complete, check_not_processed, feature_of_comment, is_outer
from .strokes import BulgekitError

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


def _feature_comments(data: bytes):
    """(end of line offset, role) of every whole-line feature comment."""
    for mt in _FEATURE_RX.finditer(data):
        ls = _line_start(data, mt.start())
        if data[ls:mt.start()].strip(b" \t"):
            continue  # a comment after a command, not a feature tag
        role = feature_of_comment(mt.group(0).decode("utf-8", "replace")[1:])
        if role is not None:
            yield mt.end(), role


@dataclass
class AnnotateResult:
    lines_added: int = 0
    markers: int = 0
    initial_records: int = 0
    appends: list[tuple[float, int, int]] = field(default_factory=list)  # (at z, records, bytes)
    outer_sections: int = 0
    features_seen: int = 0
    notes: list[str] = field(default_factory=list)


def _record_bytes(bm: mapformat.BulgeMap) -> list[bytes]:
    return [mapformat.encode_record(l, bm.has_weights) for l in bm.layers]


def _z_events(data: bytes):
    """[(offset, z_cmm)] for each G0/G1 Z move followed by XY extrusion
    before the next Z move (real layer changes; z-hops are skipped)."""
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
    res = result if result is not None else AnnotateResult()
    bm = mapformat.decode_map(map_bytes, source="map")
    geometric = settings.mode == MODE_GEOMETRIC
    recs = _record_bytes(bm)
    zrec = [l.z_cmm for l in bm.layers]
    h = bm.layer_height_cmm
    header = bytes(map_bytes[:mapformat.HEADER_BYTES])
    eol = b"\r\n" if b"\r\n" in data[:4096] else b"\n"

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
    top += mapformat.upload_lines(first)
    inserts: list[tuple[int, int, bytes]] = []   # (offset, order, text)
    inserts.append((0, 0, eol.join(t.encode() for t in top) + eol))

    # ---- markers
    if not geometric:
        inside = False
        for eol_at, role in _feature_comments(data):
            res.features_seen += 1
            outer = is_outer(role)
            if outer != inside:
                inside = outer
                end = data.find(b"\n", eol_at)
                pos = len(data) if end < 0 else end + 1
                txt = b"M722 S1" if outer else b"M722 S0"
                if end < 0:
                    txt = eol + txt
                inserts.append((pos, 1, txt + eol))
                res.markers += 1
                res.outer_sections += outer
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
        for off, zc in _z_events(data):
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
                txt += mapformat.upload_lines(payload, append=True, has_weights=bm.has_weights)
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
    pre = b"" if data.endswith(b"\n") or not data else eol
    inserts.append((len(data), 3, pre + eol.join(tail) + eol))

    inserts.sort(key=lambda t: (t[0], t[1]))
    parts = []
    pos = 0
    for off, _, txt in inserts:
        parts.append(data[pos:off])
        parts.append(txt)
        res.lines_added += txt.count(b"\n")
        pos = off
    parts.append(data[pos:])
    return b"".join(parts)


# The last value of an axis word on a motion line before a point of the file
# (G92 included, so "G92 E0" counts for E).
_AXIS_RX = {a: re.compile(rb"(?m)^[ \t]*G(?:0?[0-3]|92)(?=[ \t])[^\n;]*?[ \t]" + a + rb"[ \t]*([-+]?[0-9]*\.?[0-9]+)")
            for a in (b"X", b"Y", b"Z", b"E")}
_MODE_RX = re.compile(rb"(?m)^[ \t]*(M8[23]|G9[01]|G28)\b")


def _last_axis(data: bytes, end: int, axis: bytes):
    """(value, offset) of the axis's last value on a motion line before end,
    looking back in growing windows (a layer's Z can be some way back), or None."""
    rx = _AXIS_RX[axis]
    win = 4096
    while True:
        start = max(0, end - win)
        last = None
        for last in rx.finditer(data, start, end):
            pass
        if last is not None and (start == 0 or last.start() > start):
            return float(last.group(1)), last.start()
        if start == 0:
            return None
        win *= 8


def _outer_sections(data: bytes):
    """(start, end) byte ranges from an outer-wall feature comment to the next
    feature comment."""
    marks = list(_feature_comments(data))
    for k, (pos, role) in enumerate(marks):
        if is_outer(role):
            ls = _line_start(data, pos - 1)
            yield ls, marks[k + 1][0] if k + 1 < len(marks) else len(data)


def _mode_events(data: bytes) -> list[tuple[int, bytes]]:
    """(offset, code) of every M82/M83/G90/G91/G28 line, in file order."""
    return [(mt.start(), mt.group(1)) for mt in _MODE_RX.finditer(data)]


def _state_before(data: bytes, pos: int, events: list[tuple[int, bytes]]) -> GcodeState | None:
    """The machine state at pos, read backwards; None where that is not
    reliable (relative XYZ, a homing after the last coordinates)."""
    modes = {}
    for off, code in events[:bisect.bisect_left(events, (pos, b""))]:
        modes[code[:2]] = (code, off)
    if modes.get(b"G9", (b"G90", 0))[0] == b"G91":
        return None
    homed = modes.get(b"G2", (None, -1))[1]
    st = GcodeState()
    st.abs_e = modes.get(b"M8", (b"M82", 0))[0] == b"M82"
    for axis in (b"X", b"Y", b"Z", b"E"):
        if axis == b"E" and not st.abs_e:
            continue
        found = _last_axis(data, pos, axis)
        if found is None or found[1] < homed:
            if axis == b"E":
                continue  # no E yet: 0, as at power-on
            return None
        setattr(st, axis.decode().lower(), found[0])
    return st


_MOTION_RX = re.compile(rb"(?m)^[ \t]*G0?([0-3])(?=[ \t\r\n;]|$)([^\n;]*)")
_WORD_RX = re.compile(rb"([XYZEF])[ \t]*([-+]?[0-9]*\.?[0-9]+)")


def _reach_section(data: bytes, a: int, b: int, st: GcodeState, planner, zs, points_mm) -> bool:
    """Mark the map points within tolerance of this outer-wall section's
    extruding moves: the vectorised equivalent of running the reference planner
    over it (each move matched against the map layer nearest its end z, the
    lower on a tie). False where it cannot (arcs); the caller then runs the
    planner. points_mm: layer z -> (x, y) arrays of its points in mm, and the points."""
    import numpy as np
    x, y, z, e = st.x, st.y, st.z, st.e
    seg: dict[int, list] = {}  # end z (0.01 mm) -> [x0, y0, x1, y1] of extruding moves
    for mt in _MOTION_RX.finditer(data, a, b):
        if mt.group(1) in (b"2", b"3"):
            return False
        words = dict(_WORD_RX.findall(mt.group(2)))
        x1 = float(words.get(b"X", x))
        y1 = float(words.get(b"Y", y))
        z = float(words.get(b"Z", z))
        de = 0.0
        if b"E" in words:
            ev = float(words[b"E"])
            de = ev - e if st.abs_e else ev
            e = ev if st.abs_e else e + ev
        if de > 0 and (x1 != x or y1 != y):
            zc = int(z * 100 + 0.5) if z >= 0 else -int(0.5 - z * 100)
            seg.setdefault(zc, []).append((x, y, x1, y1))
            if planner.top_z is None or z > planner.top_z:
                planner.top_z = z
        x, y = x1, y1
    half = planner.lh / 2
    for zc, moves in seg.items():
        k = bisect.bisect_left(zs, zc - half)
        cands = [v for v in zs[k:k + 2] if abs(v - zc) <= half]
        if not cands:
            continue
        layer_z = min(cands, key=lambda v: (abs(v - zc), v))  # nearest, the lower on a tie
        px, py, pts = points_mm[layer_z]
        hit = near_segments(px, py, np.array(moves, dtype=np.float64), planner.s.tolerance).any(axis=1)
        for i in np.nonzero(hit)[0]:
            planner.stops.append(StopRecord(0, 0.0, 0.0, 0.0, 0, tuple(pts[i]), layer_z))
    return True


def check_reach(data: bytes, map_bytes: bytes, settings: Settings, source: str) -> str | None:
    """Run the G-code through the reference planner: a message naming the
    map points no move reaches (the map is for another file? arcs?), or None.
    G2/G3 arcs count for nothing, as in the firmware (RefPlanner.bypass).

    In marked mode only outer-wall moves can stop, so only the outer-wall
    sections are parsed, each from the machine state read backwards at its
    start (position, Z and E of the last motion lines; M82/M83). That keeps
    the check at a few seconds per 100 MB; files it cannot read that way
    (relative XYZ, G28 in the middle, geometric mode) are parsed whole."""
    from .fallback import MODE_MARKED, RefPlanner, unreached_message
    from .gcode import parse_lines
    planner = RefPlanner(mapformat.decode_map(map_bytes, source="map"), settings)
    sections = list(_outer_sections(data)) if settings.mode == MODE_MARKED else []
    events = _mode_events(data)
    states = [_state_before(data, a, events) for a, _ in sections]
    if sections and all(st is not None for st in states):
        # A section at one z with no map layer within half a layer height of
        # it cannot stop anywhere: skip it (most of a print, for text maps).
        zs = sorted(l.z_cmm for l in planner.map.layers)
        half = planner.lh / 2
        import numpy as np
        q = planner.q_um / 1000  # each layer's points in mm, once for all sections
        points_mm = {l.z_cmm: (np.array([p[0] for p in l.points], dtype=np.float64) * q,
                               np.array([p[1] for p in l.points], dtype=np.float64) * q, l.points)
                     for l in planner.map.layers}
        for (a, b), st in zip(sections, states):
            near = False
            for zv in [st.z] + [float(m.group(1)) for m in _AXIS_RX[b"Z"].finditer(data, a, b)]:
                zc = round(zv * 100)
                k = bisect.bisect_left(zs, zc - half)
                if k < len(zs) and zs[k] <= zc + half:
                    near = True
                    break
            if not near:
                continue
            if not _reach_section(data, a, b, st, planner, zs, points_mm):
                # arcs or an odd line: the reference planner reads it
                text = data[a:b].decode("utf-8", "replace").splitlines(keepends=True)
                for ln in parse_lines(text, source, st):
                    for m in ln.moves:
                        planner.bypass(m) if m.arc else planner.plan(m)
        # The message names the print's last extrusion: read it off the file.
        end = len(data)
        win = 65536
        last = None
        while last is None and end > 0:
            for last in _EXTRUDE_RX.finditer(data, max(0, end - win), end):
                pass
            end, win = max(0, end - win), win * 8
        if last is not None:
            line_end = data.find(b"\n", last.end())
            found = _last_axis(data, line_end if line_end >= 0 else len(data), b"Z")
            if found is not None and (planner.top_z is None or found[0] > planner.top_z):
                planner.top_z = found[0]
    else:
        lines = data.decode("utf-8", "replace").splitlines(keepends=True)
        for ln in parse_lines(lines, source):
            for m in ln.moves:
                planner.bypass(m) if m.arc else planner.plan(m)
    return unreached_message(planner, source)


def annotate_file(src, dst, map_bytes: bytes, settings: Settings, arena: int = ARENA_BYTES,
                  stream: bool = True, check: bool = True,
                  allow_unreached: bool = False) -> AnnotateResult:
    """Annotate src into dst.  With check (default) the file is also run
    through the reference planner, and map points no move reaches are an
    error unless allow_unreached (then the message is in result.notes)."""
    with open(src, "rb") as f:
        data = f.read()
    check_complete(data, str(src))
    check_not_processed(data, str(src))
    res = AnnotateResult()
    out = annotate_bytes(data, map_bytes, settings, arena, stream, str(src), res)
    if check:
        msg = check_reach(data, map_bytes, settings, str(src))
        if msg and not allow_unreached:
            raise AnnotateError(msg)
        if msg:
            res.notes.append(msg)
    with open(dst, "wb") as f:
        f.write(out)
    return res
