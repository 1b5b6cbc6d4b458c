"""G-code stream parser: positions, extrusion modes and slicer feature tags.

The parser follows Marlin's reading of G0/G1/G2/G3/G92/G90/G91/M82/M83:
G90/G91 set every axis including E, M82/M83 then override E alone, G92 sets
only the axes it names.  Arcs are read as the chords Marlin 2.1 cuts them into
(arc_segments; flagged on the moves), so walls printed with arc fitting have a
toolpath, and the planner runs see what the printer does.

Feature tags tell whether a move belongs to the outer wall.  Recognised:
  PrusaSlicer/SuperSlicer/Slic3r PE  ;TYPE:External perimeter  ;TYPE:Overhang perimeter
  OrcaSlicer/BambuStudio             ;TYPE:Outer wall   ; FEATURE: Outer wall  (and Overhang wall)
  Cura, ideaMaker                    ;TYPE:WALL-OUTER
  Simplify3D                         ; outer perimeter
Any other tag of the same family ends the outer wall.
"""
from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from typing import Iterable, Iterator

from .. import progress
from ..errors import BulgekitError


class GcodeError(BulgekitError):
    """A G-code line could not be understood (message names file and line)."""


class CutOffWarning(UserWarning):
    """A slicer's file that ends without the block that slicer writes at its end: cut off at a
    line end, as a download or copy that stopped may be (check_ends)."""


# Role names (normalised to lower case) that mean "outer wall".
OUTER_ROLES = frozenset({
    "external perimeter",  # PrusaSlicer, SuperSlicer
    "overhang perimeter",  # PrusaSlicer: outer-wall stretches over air (also the outer wall)
    "outer wall",          # OrcaSlicer, BambuStudio
    "overhang wall",       # OrcaSlicer, BambuStudio: overhanging outer-wall stretch
    "wall-outer",          # Cura, ideaMaker
    "outer perimeter",     # Simplify3D
})

# Simplify3D writes bare comments; only these exact ones are feature tags.
_S3D_ROLES = frozenset({
    "outer perimeter", "inner perimeter", "infill", "solid layer", "support",
    "dense support", "skirt", "raft", "bridge", "gap fill", "prime pillar",
    "ooze shield",
})



def feature_of_comment(comment: str) -> str | None:
    """Role named by a whole-line comment (text after ';'), lower case, or None.

    Tags are matched exactly as slicers write them (case included), so the
    fast annotator scan and this parser always agree."""
    c = comment.strip()
    if c.startswith("TYPE:"):
        return c[5:].strip().lower()
    if c.startswith("FEATURE:"):
        return c[8:].strip().lower()
    if c in _S3D_ROLES:
        return c
    return None


def is_outer(role: str | None) -> bool:
    return role is not None and role in OUTER_ROLES


@dataclass(slots=True)
class Move:
    """One linear piece of motion in host coordinates (mm, mm/min)."""
    index: int       # running number of the move in the file (0-based)
    line_no: int     # 1-based source line
    x0: float
    y0: float
    z0: float
    x1: float
    y1: float
    z1: float
    e: float         # filament of this move (end E - start E, host terms)
    e_start: float   # host E at the start (absolute, whatever the mode)
    f: float
    outer: bool      # inside an outer-wall feature section
    role: str | None
    arc: bool = False  # a chord of a linearised G2/G3

    @property
    def xy_len(self) -> float:
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)

    @property
    def extruding(self) -> bool:
        return self.e > 0.0 and (self.x0 != self.x1 or self.y0 != self.y1)


_WORD = re.compile(r"([A-Z])([^A-Z\s]*)")
_NUM = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)$")

# How Marlin 2.1.x cuts a G2/G3 into straight segments (plan_arc, gcode/motion/G2_G3.cpp), with
# its Configuration_adv.h defaults (ARC_SEGMENTS_PER_SEC off): arc_segments. Every reader of arcs
# takes its chords from here (the parser, so walls, planner runs and the stock file; the compiled
# scanner's twin; the estimator), and the chords bulgekit writes in place of an arc are these.
MAX_ARC_SEGMENT_MM = 1.0
MIN_ARC_SEGMENT_MM = 0.1
MIN_CIRCLE_SEGMENTS = 72
# The farthest such a chord strays from its arc: a segment of at most 1 mm and 5 degrees (72 a
# circle) has its largest sagitta, r (1 - cos 2.5 deg), where the two meet, r = 1 mm / 5 deg.
ARC_CHORD_DEVIATION_MM = (MAX_ARC_SEGMENT_MM / math.radians(360 / MIN_CIRCLE_SEGMENTS)
                          * (1 - math.cos(math.radians(180 / MIN_CIRCLE_SEGMENTS))))
ARC_SEGMENTS_MAX = 10_000_000   # an arc longer than this many shortest segments: an error naming its line


def parse_words(code: str, where: str, bare: bool = False) -> dict[str, float]:
    """X10 Y-2.5 ... -> {'X': 10.0, ...}.  Raises GcodeError naming `where`. bare: a letter
    without a value is taken as None (G28 X Y, M84 E) rather than refused."""
    # Fast path: float() takes every value _NUM takes; of what it takes besides, only '_'
    # digit separators can come out of _WORD (letters such as 'inf' split into words), so a
    # value with '_' or one float() refuses goes the checked way, which names the bad word.
    out: dict[str, float] = {}
    try:
        for letter, val in _WORD.findall(code.upper()):
            if letter == "N" and not out:
                continue
            if "_" in val:
                raise ValueError(val)
            out[letter] = None if bare and not val else float(val)
        return out
    except ValueError:
        return _parse_words_checked(code, where, bare)


def _parse_words_checked(code: str, where: str, bare: bool = False) -> dict[str, float]:
    out: dict[str, float] = {}
    up = code.upper()
    for mt in _WORD.finditer(up):
        letter, val = mt.group(1), mt.group(2)
        if letter == "N" and not out:
            continue
        if bare and not val:
            out[letter] = None
            continue
        if not _NUM.match(val):
            # name the whole word as written: "X1O" rather than "O"
            a = up.rfind(" ", 0, mt.start()) + 1
            b = up.find(" ", mt.start())
            word = code[a:b if b >= 0 else len(code)]
            raise GcodeError(f"{where}: unparsable value {word!r} in {code.strip()!r}")
        out[letter] = float(val)
    return out


def command_of(token: str) -> str:
    """A line's command as every reader names it: upper case, G01 -> G1, M082 -> M82."""
    cmd = token.upper()
    if len(cmd) > 1 and cmd[0] in "GM" and cmd[1:].isdigit():
        cmd = cmd[0] + str(int(cmd[1:]))
    return cmd


def split_code(raw: str) -> tuple[str, str | None]:
    """Code part (without comment and checksum) and whole-line comment text."""
    s = raw.strip()
    if s.startswith(";"):
        return "", s[1:]
    i = s.find(";")
    if i >= 0:
        s = s[:i]
    i = s.find("*")
    if i >= 0:
        s = s[:i]
    i = s.find("(")  # parenthesised comments (rare in FDM output)
    if i >= 0:
        s = s[:i]
    s = s.strip()
    if s[:1] in ("N", "n"):
        parts = s.split(None, 1)
        s = parts[1] if len(parts) > 1 else ""
    return s, None


class GcodeState:
    """Machine state as the G-code drives it (Marlin semantics)."""

    def __init__(self) -> None:
        self.x = self.y = self.z = self.e = 0.0
        self.f = 1500.0
        self.abs_xyz = True
        self.abs_e = True
        self.role: str | None = None
        self.outer = False
        self.n_moves = 0
        self.features_seen = 0
        self.outer_seen = 0


@dataclass(slots=True)
class Line:
    """One source line with what it did."""
    line_no: int
    raw: str
    cmd: str | None              # 'G1', 'G92', 'M83', ... (None: comment/blank)
    words: dict | None
    moves: list                  # Move objects (several for a linearised arc)
    role_change: str | None      # feature role named by this line's comment


def parse_lines(lines: Iterable[str], source: str = "<gcode>",
                state: GcodeState | None = None) -> Iterator[Line]:
    """Parse a G-code stream; yields one Line per input line."""
    st = state or GcodeState()
    for no, raw in enumerate(lines, 1):
        if not no & 0x3FFF:                 # every 16,384 lines: progress (a no-op unless shown)
            progress.tick(no)
        code, comment = split_code(raw)
        if not code:
            role = None
            if comment is not None:
                role = feature_of_comment(comment)
                if role is not None:
                    st.role = role
                    st.outer = is_outer(role)
                    st.features_seen += 1
                    if st.outer:
                        st.outer_seen += 1
            yield Line(no, raw, None, None, [], role)
            continue
        head = code.split(None, 1)
        cmd = command_of(head[0])
        where = f"{source}:{no}"
        rest = head[1] if len(head) > 1 else ""
        moves: list[Move] = []
        words = None
        if cmd in ("G0", "G1"):
            words = parse_words(rest, where)
            moves.append(_linear(st, words, no))
        elif cmd in ("G2", "G3"):
            words = parse_words(rest, where)
            moves.extend(_arc(st, words, no, cmd == "G2", where))
        elif cmd == "G92":
            words = parse_words(rest, where)
            for k in ("X", "Y", "Z", "E"):
                if k in words:
                    setattr(st, k.lower(), words[k])
        elif cmd == "G90":
            st.abs_xyz = st.abs_e = True
        elif cmd == "G91":
            st.abs_xyz = st.abs_e = False
        elif cmd == "M82":
            st.abs_e = True
        elif cmd == "M83":
            st.abs_e = False
        yield Line(no, raw, cmd, words, moves, None)


def _target(st: GcodeState, w: dict) -> tuple[float, float, float, float]:
    if st.abs_xyz:
        x = w.get("X", st.x)
        y = w.get("Y", st.y)
        z = w.get("Z", st.z)
    else:
        x = st.x + w.get("X", 0.0)
        y = st.y + w.get("Y", 0.0)
        z = st.z + w.get("Z", 0.0)
    e = w.get("E", st.e) if st.abs_e else st.e + w.get("E", 0.0)
    return x, y, z, e


def _linear(st: GcodeState, w: dict, no: int) -> Move:
    x, y, z, e = _target(st, w)
    if "F" in w:
        st.f = w["F"]
    m = Move(st.n_moves, no, st.x, st.y, st.z, x, y, z, e - st.e, st.e, st.f,
             st.outer, st.role)
    st.n_moves += 1
    st.x, st.y, st.z, st.e = x, y, z, e
    return m


def _arc(st: GcodeState, w: dict, no: int, cw: bool, where: str) -> list[Move]:
    x, y, z, e = _target(st, w)
    if "F" in w:
        st.f = w["F"]
    cx, cy, r0, a0, sweep, n = arc_geometry(st.x, st.y, x, y, w, cw, where)
    out = []
    zs, es = st.z, st.e
    for i in range(1, n + 1):
        t = i / n
        if i == n:
            px, py = x, y
        else:
            px, py = arc_point(cx, cy, r0, a0, sweep, t)
        pz = zs + (z - zs) * t
        pe = es + (e - es) * t
        m = Move(st.n_moves, no, st.x, st.y, st.z, px, py, pz, pe - st.e, st.e,
                 st.f, st.outer, st.role, arc=True)
        st.n_moves += 1
        st.x, st.y, st.z, st.e = px, py, pz, pe
        out.append(m)
    st.x, st.y, st.z, st.e = x, y, z, e
    return out


def arc_geometry(x0: float, y0: float, x: float, y: float, w: dict, cw: bool,
                 where: str) -> tuple[float, float, float, float, float, int]:
    """A G2 (cw) or G3 from (x0, y0) to (x, y) with the words w (I/J, or R: the shorter arc for
    R > 0, the longer for R < 0, as Marlin): its centre, radius, start angle, sweep (radians,
    negative clockwise; a whole turn when it ends where it starts) and how many segments Marlin
    cuts it into (arc_segments). The chord ends are arc_point's at i/n, the last the end itself."""
    if "R" in w:
        r = w["R"]
        dx, dy = x - x0, y - y0
        d = math.hypot(dx, dy)
        if d == 0 or abs(r) < d / 2 - 1e-6:
            raise GcodeError(f"{where}: arc radius R{r} cannot reach the end point")
        h = math.sqrt(max(r * r - d * d / 4, 0.0))
        # R>0: the shorter arc; the centre side depends on the direction
        s = (-1 if cw else 1) * (1 if r > 0 else -1)
        cx = x0 + dx / 2 - s * h * dy / d
        cy = y0 + dy / 2 + s * h * dx / d
    elif "I" in w or "J" in w:
        cx, cy = x0 + w.get("I", 0.0), y0 + w.get("J", 0.0)
    else:
        raise GcodeError(f"{where}: arc without I/J or R")
    r0 = math.hypot(x0 - cx, y0 - cy)
    a0 = math.atan2(y0 - cy, x0 - cx)
    a1 = math.atan2(y - cy, x - cx)
    sweep = a1 - a0
    if cw:
        if sweep >= -1e-9:
            sweep -= 2 * math.pi
    else:
        if sweep <= 1e-9:
            sweep += 2 * math.pi
    if not abs(r0 * sweep) <= ARC_SEGMENTS_MAX * MIN_ARC_SEGMENT_MM:     # (also inf, nan)
        raise GcodeError(f"{where}: arc of radius {r0:g} mm is too long to cut into segments")
    return cx, cy, r0, a0, sweep, arc_segments(r0, sweep)


def arc_segments(radius: float, sweep: float) -> int:
    """How many segments Marlin 2.1's plan_arc cuts an arc of `radius` (mm) turning `sweep`
    (radians, finite) into, with its default settings: whole segments of MAX_ARC_SEGMENT_MM
    (1 mm) and at least MIN_CIRCLE_SEGMENTS (72) to a whole turn; more when that leaves them
    longer than 1 mm, fewer when shorter than MIN_ARC_SEGMENT_MM (0.1 mm). In double where Marlin
    computes in float (an arc within about 1e-6 mm of a whole number of millimetres may get one
    segment more or less there). _scan.c's arc_segments is this, operation for operation."""
    a = abs(sweep)
    flat = radius * a
    min_seg = max(1, math.ceil(MIN_CIRCLE_SEGMENTS * (a / (2 * math.pi))))
    nominal = max(math.floor(flat / MAX_ARC_SEGMENT_MM), min_seg)
    nominal_mm = flat / nominal
    if nominal_mm > MAX_ARC_SEGMENT_MM:
        return math.ceil(flat / MAX_ARC_SEGMENT_MM)
    if nominal_mm < MIN_ARC_SEGMENT_MM:
        return max(1, math.floor(flat / MIN_ARC_SEGMENT_MM))
    return nominal


def arc_point(cx: float, cy: float, r0: float, a0: float, sweep: float, t: float) -> tuple[float, float]:
    """The point a fraction t of the way along an arc (arc_geometry's centre, radius, start angle
    and sweep): where Marlin's segment i of n ends, t = i / n."""
    a = a0 + sweep * t
    return cx + r0 * math.cos(a), cy + r0 * math.sin(a)


def check_text(data, source: str = "<gcode>") -> None:
    """Refuse a file that is not text (a program, an image, a zip passed by mistake): G-code has
    no NUL bytes, and reading such a file as lines would only produce nonsense errors."""
    head = data[:65536]
    if len(data) <= len(head) and not head.strip():
        # said as it is, not as the first thing a pass misses (its outer-wall comments, its moves)
        raise GcodeError(f"{source}: the G-code file is empty" if not data else
                         f"{source}: the G-code file has only blank lines, no G-code")
    i = head.find(b"\0" if isinstance(head, (bytes, bytearray)) else "\0")
    if i >= 0:
        raise GcodeError(f"{source}: not a text G-code file (binary data: a NUL byte at byte {i})")


def check_complete(text, source: str = "<gcode>") -> None:
    """Refuse a file that is not text (check_text), or whose last line has a command but no line
    end: that is how a cut-off download or copy looks ("G1 X119.5 E9" for "E9.8731"), and
    its last move would be taken as written. A slicer's file cut at a line end is warned of
    (check_ends)."""
    check_text(text, source)
    if isinstance(text, str):
        head, tail = text[:ENDS_CHECKED].encode("utf-8", "replace"), text[-ENDS_CHECKED:].encode("utf-8", "replace")
    else:
        head, tail = bytes(text[:ENDS_CHECKED]), bytes(text[-ENDS_CHECKED:])
    last = check_ends(head, tail, source)
    if last is not None:
        nl = b"\n" if isinstance(text, (bytes, bytearray)) else "\n"
        refuse_cut_off(last, text.count(nl) + 1, source)


def check_file_ends(path, source: str) -> str | None:
    """check_complete for a pass that reads the file itself, once (estimate): check_text on its
    first 64 KB and check_ends, here, and its last line when that has no line end, returned for
    refuse_cut_off once the pass has counted the lines (None: it ends with one). Reads 64 KB at
    each end only, so the checks add no second pass over a large file."""
    with open(path, "rb") as f:
        head = f.read(ENDS_CHECKED + 1)       # one byte more: the blank-file verdict is for small files only
        check_text(head, source)
        f.seek(0, 2)
        size = f.tell()
        f.seek(max(0, size - ENDS_CHECKED))
        tail = f.read(ENDS_CHECKED)
    return check_ends(head, tail, source)


ENDS_CHECKED = 65536        # bytes at each end of a file that check_ends looks at

# What each slicer writes at the top of its file, and (any of) what it writes after the print's
# end G-code, within the last 64 KB (host/tests/data: PrusaSlicer 2.5, Slic3r 1.3, CuraEngine
# 4.13; OrcaSlicer and Bambu Studio end with their config block). Other slicers (Simplify3D,
# ideaMaker, ...) are not judged.
SLICER_ENDS = (
    ("PrusaSlicer", re.compile(rb"^; generated by PrusaSlicer", re.M),
     (b"; filament used [", b"; prusaslicer_config = end")),
    ("SuperSlicer", re.compile(rb"^; generated by SuperSlicer", re.M),
     (b"; filament used [", b"; superslicer_config = end")),
    ("OrcaSlicer", re.compile(rb"^; generated by OrcaSlicer", re.M),
     (b"; EXECUTABLE_BLOCK_END", b"; CONFIG_BLOCK_END")),
    ("Bambu Studio", re.compile(rb"^; generated by BambuStudio", re.M),
     (b"; EXECUTABLE_BLOCK_END", b"; CONFIG_BLOCK_END")),
    ("Slic3r", re.compile(rb"^; generated by Slic3r", re.M), (b"; filament used =",)),
    ("Cura", re.compile(rb"^;Generated with Cura_SteamEngine", re.M), (b";End of Gcode",)),
)


def check_ends(head: bytes, tail: bytes, source: str) -> str | None:
    """The checks on a file's first and last bytes (ENDS_CHECKED of each): its last line when
    that has no line end (for refuse_cut_off, once the lines are counted; None when it has
    one); and, unless that line is refused, a CutOffWarning (one line, naming the file) when
    the file's slicer is known from its head and the tail lacks that slicer's end block."""
    last = unended_line(tail)
    if last is None or not split_code(last.rstrip("\r"))[0]:
        for name, made_by, ends in SLICER_ENDS:
            if made_by.search(head, 0, ENDS_CHECKED) and not any(e in tail for e in ends):
                said = " or ".join(repr(e.decode()) for e in ends)
                warnings.warn(f"{source}: ends without {name}'s end block ({said} after its end "
                              "G-code): was the file cut off? Check it, or slice again",
                              CutOffWarning, stacklevel=1)
                break
    return last


def unended_line(tail: bytes) -> str | None:
    """The last line of a file whose last bytes are `tail`, when it has no line end (for
    refuse_cut_off); None when the file ends with one."""
    if not tail or tail.endswith(b"\n"):
        return None
    return tail[tail.rfind(b"\n") + 1:].decode("utf-8", "replace")


def refuse_cut_off(last: str, nlines: int, source: str) -> None:
    """check_complete's verdict on a file whose line `nlines`, `last`, has no line end."""
    code, _ = split_code(last.rstrip("\r"))
    if not code:
        return  # a comment or blank: nothing would be misread
    raise GcodeError(
        f"{source}:{nlines}: the file does not end with a line end, so its last line "
        f"{last.strip()!r} may be cut off (truncated download or copy?). Check the file; "
        "if it is complete, add a newline at its end.")


_OURS_RX = re.compile(rb"^(?:; bulgekit(?: fallback)?:|[ \t]*(?:[Nn]\d+[ \t]+)?[Mm]0*72[0-2](?![0-9.]))",
                      re.M)


def check_not_processed(data, source: str = "<gcode>") -> None:
    """Refuse G-code that bulgekit already annotated or rewrote: a second pass
    would bulge twice (a fallback's G4/extra E stay in the file, and annotated
    M720-M722 would switch the firmware's bulges on as well)."""
    if isinstance(data, str):
        data = data.encode("utf-8", "replace")
    _refuse_processed(data, source, 0)


def might_hold(data: bytes, words) -> bool:
    """Whether `data` may hold a command or comment starting with one of `words` (b"M72" ...)
    by the regexes here, which also take M072: a quick look before the regex, which at each
    line's start is several times slower than bytes' own search."""
    return any(w in data for w in words) or b"M0" in data or b"m0" in data


SCAN_VERSION = 11     # the compiled scanner's VERSION this code calls (_scan.c's module init)


SCAN_REBUILD = "cd host && python3 setup.py build_ext --inplace (or make deps)"


def _built(name: str, version: int, package: str = __name__):
    """("compiled" | "stale" | "missing", the module or None) for the compiled helper
    <package>.<name>: stale when built from an older source, whose VERSION is not the one
    this code calls."""
    import importlib
    try:
        mod = importlib.import_module(f"{package}.{name}")
    except ImportError:
        return "missing", None
    return ("compiled", mod) if getattr(mod, "VERSION", 0) == version else ("stale", None)


def compiled_helper(name: str, version: int, what: str, slower: str, package: str = __name__):
    """The compiled helper <package>.<name> (bulgekit.gcode's _scan and _plan, bulgekit.bulge's
    _reach), or None: not built (no C compiler), or built from an older source that lacks what
    this code calls; the Python paths then do the work, slower. A stale build is said once per
    helper (a RuntimeWarning: an update of the source without a rebuild would otherwise only
    show as slowness)."""
    state, mod = _built(name, version, package)
    if state == "stale" and name not in _STALE_SAID:
        _STALE_SAID.add(name)
        import warnings
        warnings.warn(f"bulgekit: the compiled {what} was built from older source and is not used "
                      f"({slower}); rebuild it: {SCAN_REBUILD}", RuntimeWarning, stacklevel=3)
    return mod


_STALE_SAID: set = set()


def scanner_state() -> str:
    """"compiled", "stale" (built from an older _scan.c: not used) or "missing"."""
    return _built("_scan", SCAN_VERSION)[0]


def compiled_scanner():
    """The compiled scanner module (bulgekit.gcode._scan), or None (compiled_helper)."""
    return compiled_helper("_scan", SCAN_VERSION, "G-code scanner", "large files read many times slower")


def _flag_counts(data) -> tuple[int, int] | None:
    """(ours, m92): how many lines of data (bytes, mmap) _OURS_RX and _M92_RX may match, counted
    by the compiled scanner in one pass (_scan.flag_lines, a superset: the regexes decide); None
    without it. A count of 0: the regex, at every line start, need not run."""
    sc = compiled_scanner()
    return None if sc is None else sc.flag_lines(data)


def _refuse_processed(data: bytes, source: str, lines_before: int, at: int = 0) -> None:
    """check_not_processed on a file's whole lines from `data[at]`, `lines_before` lines in."""
    counts = _flag_counts(data)
    if counts is not None and counts[0] == 0:
        return
    if not might_hold(data, (b"; bulgekit", b"M72", b"m72")):
        return
    mt = _OURS_RX.search(data, at)
    if mt is None:
        return
    line = lines_before + data.count(b"\n", 0, mt.start()) + 1
    end = data.find(b"\n", mt.start())
    text = data[mt.start():end if end >= 0 else len(data)].decode("utf-8", "replace").strip()
    what = ("was already rewritten for stock firmware by `bulgekit fallback`"
            if text.startswith("; bulgekit fallback") else
            "already carries bulgekit M-codes (annotated, or M720-M722 from the slicer's "
            "custom G-code)")
    raise GcodeError(
        f"{source}:{line}: {text!r}: this file {what}; processing it again would bulge twice. "
        "Start from the slicer's original G-code (or remove the M720/M721/M722 lines).")


def check_input_file(path, source: str) -> None:
    """The checks every pass over a slicer's file starts with: text (check_text), and not
    already processed by bulgekit (check_not_processed). Reads the file once; not at all when
    it is the file a movescan.Scan in force checked (build: one check, one scan)."""
    from . import movescan
    if movescan.kept(path) is not None:
        return
    with open(path, "rb") as f:
        data = f.read()
    check_text(data, source)
    check_not_processed(data, source)


def open_checked(path, ends: int = 1 << 21, checks=()) -> tuple[str, "Iterator[str]"]:
    """Check a G-code file (check_complete: text, not cut off; and `checks`, each called with
    the bytes and the name), then stream it: returns the text of its two ends (`ends` bytes each,
    where slicers write their settings and time) and an iterator over its lines. The whole file
    is never held as lines, only briefly as bytes. The file a movescan.Scan in force checked is
    not read again: its ends come from the scan, and `checks` are ones it ran (build's)."""
    from . import movescan
    sc = movescan.kept(path)
    if sc is not None and ends == movescan.ENDS:
        return sc.ends, sc.text_lines()
    data = open(path, "rb").read()
    check_complete(data, str(path))
    for check in checks:
        check(data, str(path))
    head = data[:ends].decode("utf-8", "replace")
    tail = data[-ends:].decode("utf-8", "replace") if len(data) > ends else ""
    del data

    def lines():
        with open(path, "r", encoding="utf-8", errors="replace", newline="") as f:
            yield from f
    return head + "\n" + tail, lines()


def iter_moves(lines: Iterable[str], source: str = "<gcode>") -> Iterator[Move]:
    for ln in parse_lines(lines, source):
        yield from ln.moves


_HEADER_HEIGHT = (
    re.compile(r"^;\s*layer_height\s*=\s*([0-9.]+)", re.M),      # Prusa/Orca/Slic3r
    re.compile(r"^;Layer height:\s*([0-9.]+)", re.M),            # Cura
    re.compile(r"^;\s*layerHeight,([0-9.]+)", re.M),             # Simplify3D
    re.compile(r"^;Layer Height:\s*([0-9.]+)", re.M | re.I),     # ideaMaker
)


# the words each of _HEADER_HEIGHT's patterns has after its ";" and blanks (None: the case-blind
# one): a match holds them, so its search starts at the line they first occur on, not at the
# start of the 4 MB of a file's ends (about 20 ms a pattern)
_HEADER_HEIGHT_WORDS = ("layer_height", "Layer height:", "layerHeight,", None)


def header_layer_height(text: str) -> float | None:
    """Layer height the slicer wrote in its settings comments, if any."""
    for rx, word in zip(_HEADER_HEIGHT, _HEADER_HEIGHT_WORDS):
        start = 0
        if word is not None:
            at = text.find(word)
            if at < 0:
                continue
            # a match there begins at the ";" before the blanks (\s, str.isspace) before it;
            # any later one after it: from the line of the last non-blank before the word on
            j = at - 1
            while j >= 0 and text[j].isspace():
                j -= 1
            start = text.rfind("\n", 0, j) + 1 if j >= 0 else 0
        v = header_height_of(rx.search(text, start))
        if v is not None:
            return v
    return None


def header_height_of(m: re.Match | None) -> float | None:
    """The layer height a match of one of _HEADER_HEIGHT's patterns gives: its number, if it
    reads as one and is > 0 (else the next pattern is tried)."""
    if m is None:
        return None
    try:
        v = float(m.group(1))
    except ValueError:
        return None
    return v if v > 0 else None


_M92_RX = re.compile(rb"^[ \t]*(?:[Nn]\d+[ \t]+)?[Mm]0*92(?![0-9.])([^\n;]*)", re.M)
_M92_E_RX = re.compile(rb"[Ee]\s*([-+]?(?:\d+\.?\d*|\.\d+))")


def _m92_e(args: bytes) -> float | None:
    e = _M92_E_RX.search(args)
    return float(e.group(1)) if e and float(e.group(1)) > 0 else None


def scan_m92(path) -> list[tuple[int, float]]:
    """(line number, E) of every M92 with an E word in a file, in order."""
    import mmap
    out = []
    with open(path, "rb") as f:
        try:
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:                    # an empty file
            return out
        with data:
            # a quick look first: the regex, at every line start, is far slower
            counts = _flag_counts(data)
            if counts is not None and counts[1] == 0:
                return out
            if not any(data.find(w) >= 0 for w in (b"M92", b"m92", b"M0", b"m0")):   # (might_hold)
                return out
            line, pos = 1, 0
            for mt in _M92_RX.finditer(data):
                line += data[pos:mt.start()].count(b"\n")     # (mmap has no count before 3.13)
                pos = mt.start()
                e = _m92_e(mt.group(1))
                if e is not None:
                    out.append((line, e))
    return out


def _plain_lines(data) -> bool:
    """rewrite_file's byte path needs \n or \r\n line ends and UTF-8 (else rewrite() runs)."""
    n_cr = data.count(b"\r")
    if n_cr and n_cr != data.count(b"\r\n"):
        return False
    if data.isascii():                                # (ASCII is UTF-8: no decoding needed)
        return True
    import codecs
    dec = codecs.getincrementaldecoder("utf-8")()
    try:
        for i in range(0, len(data), 1 << 23):        # in slices: no second copy of the file
            dec.decode(data[i:i + (1 << 23)], final=i + (1 << 23) >= len(data))
    except UnicodeDecodeError:
        return False
    return True
