"""Stroke inputs for bulge drawings.

A stroke is a polyline on the unrolled outer wall: u runs along the wall
(mm, measured from the seam reference), v is the height above the bed (mm).
A single-point stroke is a dot.  Loaders turn SVG drawings, text (single-
stroke Hershey fonts), JSON stroke lists and grayscale images into strokes;
project_drawing() carries a drawing made in a fixed 2D view onto a mesh
(the paper's fixed-camera drawing mode).

Every error is an InputError whose message names the file and the element,
stroke index or line at fault.  Formats and options: docs/inputs.md.
"""
from __future__ import annotations

import io
import json
import math
import os
import re
import warnings
import xml.etree.ElementTree as ET
import xml.parsers.expat as expat
from dataclasses import dataclass, field, replace
from typing import Iterable, Sequence

from ..errors import BulgekitError, InputError  # noqa: F401  (bulgekit.bulge.strokes.InputError)

MM_PER_PX = 25.4 / 96.0  # CSS px: SVG user units are 96 per inch


@dataclass(frozen=True)
class Stroke:
    points: tuple[tuple[float, float], ...]
    weight: int = 255
    source: str = ""
    # the text, drawing or picture it is part of (Drawing), for messages about the whole
    drawing: "Drawing | None" = field(default=None, compare=False, repr=False)
    # a dot with height (a braille dot): the layers within this many mm of its v each get a point,
    # weighted by a dome, weight x sqrt(1 - (dv / dome)^2) at the layer's middle (mapbuild)
    dome: float = 0.0

    def __post_init__(self):
        if not self.points:
            raise InputError(f"{self.source or 'stroke'}: stroke has no points")
        if self.dome and (len(self.points) != 1 or not (math.isfinite(self.dome) and self.dome > 0)):
            raise InputError(f"{self.source or 'stroke'}: a dome is one point with a radius > 0")
        if not (isinstance(self.weight, int) and 0 <= self.weight <= 255):
            raise InputError(f"{self.source or 'stroke'}: weight {self.weight!r} is not an integer 0..255")
        for k, (u, v) in enumerate(self.points):
            if not (math.isfinite(u) and math.isfinite(v)):  # e.g. an SVG coordinate of 1e400
                raise InputError(f"{self.source or 'stroke'}: point {k} ({u}, {v}) is not a finite number")

    @property
    def is_dot(self) -> bool:
        return len(self.points) == 1

    @property
    def length(self) -> float:
        return sum(math.dist(a, b) for a, b in zip(self.points, self.points[1:]))


class DrawingWarning(UserWarning):
    """Something in a drawing that is drawn otherwise than asked (a filled shape as its outline,
    a skipped <text>): one WARNING line on stderr (cli._util.warning_lines)."""


# --------------------------------------------------------------------------
# Shared helpers


def _weight(value, where: str) -> int:
    if isinstance(value, bool):
        raise InputError(f"{where}: weight must be an integer 0..255, got {value!r}")
    try:
        w = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: weight must be an integer 0..255, got {value!r}") from None
    if not math.isfinite(w) or w != int(w) or not 0 <= w <= 255:
        raise InputError(f"{where}: weight must be an integer 0..255, got {value!r}")
    return int(w)


def _dedupe(points: Sequence[tuple[float, float]], eps: float = 1e-9) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for p in points:
        if not out or math.dist(out[-1], p) > eps:
            out.append(p)
    return out


def resample(stroke: Stroke, pitch_mm: float) -> list[tuple[float, float]]:
    """Points along a stroke, about pitch_mm apart, ends included.

    Each segment run is divided evenly, so a stroke of length L gets
    ceil(L / pitch) + 1 points; a dot stays one point.
    """
    if not pitch_mm > 0:
        raise InputError(f"pitch must be > 0 mm, got {pitch_mm}")
    pts = stroke.points
    if len(pts) == 1:
        return [pts[0]]
    cum = [0.0]
    for a, b in zip(pts, pts[1:]):
        cum.append(cum[-1] + math.dist(a, b))
    total = cum[-1]
    if total == 0:
        return [pts[0]]
    n = max(1, math.ceil(total / pitch_mm - 1e-9))
    out = []
    seg = 0
    for i in range(n + 1):
        s = total * i / n
        while seg < len(pts) - 2 and cum[seg + 1] < s:
            seg += 1
        a, b = pts[seg], pts[seg + 1]
        span = cum[seg + 1] - cum[seg]
        t = 0.0 if span == 0 else (s - cum[seg]) / span
        t = min(1.0, max(0.0, t))
        out.append((a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t))
    return out


def sample_strokes(strokes: Iterable[Stroke], pitch_mm: float) -> list[tuple[float, float, int]]:
    """(u, v, weight) points of all strokes, resampled at pitch_mm."""
    out = []
    for s in strokes:
        out.extend((u, v, s.weight) for u, v in resample(s, pitch_mm))
    return out


def summarize(strokes: Sequence[Stroke]) -> dict:
    """Counts and extent, for `bulgekit strokes` and messages."""
    pts = [p for s in strokes for p in s.points]
    us = [p[0] for p in pts]
    vs = [p[1] for p in pts]
    return {
        "strokes": len(strokes),
        "dots": sum(1 for s in strokes if s.is_dot),
        "points": len(pts),
        "length_mm": sum(s.length for s in strokes),
        "u_range": (min(us), max(us)) if pts else None,
        "v_range": (min(vs), max(vs)) if pts else None,
    }


def transform(strokes: Iterable[Stroke], offset=(0.0, 0.0), scale=1.0, mirror_u: bool = False) -> list[Stroke]:
    """Scale about the origin, optionally mirror u about the strokes' own
    u-extent (for paint rollers: the print reads correctly when rolled), then
    shift by offset."""
    strokes = list(strokes)
    if mirror_u and strokes:
        us = [p[0] for s in strokes for p in s.points]
        lo, hi = min(us), max(us)
        strokes = [replace(s, points=tuple((lo + hi - u, v) for u, v in s.points)) for s in strokes]
    ou, ov = offset
    return [replace(s, points=tuple((u * scale + ou, v * scale + ov) for u, v in s.points)) for s in strokes]


# --------------------------------------------------------------------------
# Drawings: a message about strokes that leave the wall, in the user's terms


def _mm(x: float) -> str:
    return f"{round(x, 2) + 0.0:g}"


def _floor_2(x: float) -> str:
    """x rounded down to two significant digits (a size to suggest that surely fits)."""
    e = math.floor(math.log10(x)) - 1
    return f"{round(math.floor(x / 10 ** e + 1e-9) * 10 ** e, max(0, -e)):g}"


@dataclass(frozen=True, eq=False)
class Drawing:
    """A text, SVG or JSON drawing or a picture as the user asked for it (its size and where it
    goes), shared by its strokes, so that one of them off the wall is reported as the whole:
    taller than the wall at the size given, or reaching above or below it, with the option that
    changes that (or, from a placement file, its key)."""
    what: str                 # "the text 'HI'", "logo.svg: the drawing"
    size: float               # as given: the option's value
    option: str               # the CLI option giving it: "--text-size"
    key: str                  # the placement key giving it: "size"
    word: str                 # its plain name: "size", "scale", "width"
    mm: bool                  # whether it is a length
    corner: str               # the point --at U,V (at = [U, V]) sets: "its baseline start"
    entry: str = ""           # "p.toml: text[0]: ": from a placement file's entry
    # on a face of the wall (bulge/faces.py): its number (None: at u as drawn), how it is
    # aligned there and the U of --at U,V, an offset from that place; aligned once placed
    face: int | None = None
    align: str = "center"
    offset_u: float = 0.0
    aligned: bool = False

    def placed(self, entry: str) -> "Drawing":
        """The same drawing asked for by a placement file's entry ("p.toml: text[0]")."""
        return replace(self, entry=f"{entry}: ")

    @property
    def given(self) -> str:
        """The size as the user gave it: "--text-size 30 mm", from a placement "size = 30 mm"."""
        unit = " mm" if self.mm else ""
        return f"{self.key} = {self.size:g}{unit}" if self.entry else f"{self.option} {self.size:g}{unit}"

    def fit(self, height: float, wall: float) -> str:
        """What size fits a wall `wall` mm tall (the drawing's height is in proportion to it)."""
        return (f"use a smaller {self.word}, {_floor_2(self.size * wall / height)}"
                f"{' mm' if self.mm else ''} or less")

    def extent(self, strokes: Sequence[Stroke]) -> tuple[float, float]:
        """Its lowest and highest v (mm), from its strokes among `strokes`."""
        vs = [v for st in strokes if st.drawing is self for _, v in st.points]
        return min(vs), max(vs)

    def off_the_wall(self, strokes: Sequence[Stroke], lo: float, hi: float) -> str:
        """The message for a drawing not within the wall's height lo..hi (mm)."""
        bottom, top = self.extent(strokes)
        h, wall = top - bottom, hi - lo
        if h > wall + 1e-9:
            return (f"{self.entry}{self.what} is {_mm(h)} mm tall at {self.given}, "
                    f"but the wall is only {_mm(wall)} mm tall; {self.fit(h, wall)}")
        way, by = ("down", top - hi) if top > hi else ("up", lo - bottom)
        at = "at = [U, V]" if self.entry else "--at U,V"
        return (f"{self.entry}{self.what} reaches from {_mm(bottom)} to {_mm(top)} mm above the bed, "
                f"but the wall goes from {_mm(lo)} to {_mm(hi)} mm; move it {way} by at least "
                f"{math.ceil(by * 100 - 1e-7) / 100:g} mm ({self.corner}, {at})")   # (rounded up: enough)


def drawn(strokes: list[Stroke], drawing: Drawing) -> list[Stroke]:
    """The strokes, each knowing the drawing they make up."""
    return [replace(st, drawing=drawing) for st in strokes]


def on_face(strokes: list[Stroke], face: int | None, align: str | None = None,
            offset_u: float = 0.0) -> list[Stroke]:
    """The strokes of one drawing (made at --at U,V), to be placed on a face of the wall: its
    number (1 from u = 0 along u), align left, center (the default) or right, U (offset_u) an
    offset from that place. bulge/faces.py places them once the walls are known. No face and no
    align: the strokes as they are. Strokes of no drawing become one ("the strokes")."""
    if face is None and align is None:
        return strokes
    if face is None:
        raise InputError("align needs a face (--face N, face = N)")
    if isinstance(face, bool) or not isinstance(face, int) or face < 1:
        raise InputError(f"face must be a whole number from 1, got {face!r}")
    align = align or "center"
    if align not in ALIGNS:
        raise InputError(f"align must be one of {', '.join(ALIGNS)}, got {align!r}")
    made: dict = {}
    out = []
    for st in strokes:
        d = st.drawing
        key = id(d)
        if key not in made:
            base = d if d is not None else Drawing(f"the strokes{' ' + st.source if st.source else ''}",
                                                   1.0, "--scale", "scale", "scale", False,
                                                   "their origin")
            made[key] = replace(base, face=face, align=align, offset_u=float(offset_u), aligned=False)
        out.append(replace(st, drawing=made[key]))
    return out


ALIGNS = ("left", "center", "right")


# --------------------------------------------------------------------------
# SVG

_SVG_NS = "http://www.w3.org/2000/svg"
_LINE_ATTR = "data-bk-line"
_WEIGHT_ATTR = "data-bk-weight"

# Arguments per path command; flags of A are single 0/1 characters that may
# be written without separators ("a5 5 0 01 10 10").
_PATH_ARGS = {"M": 2, "L": 2, "H": 1, "V": 1, "C": 6, "S": 4, "Q": 4, "T": 2, "A": 7, "Z": 0}
_NUM_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_SEP_RE = re.compile(r"[\s,]*")


def _check_path_data(d: str) -> str | None:
    """None if d is valid SVG path data, else a short description of the
    first problem.  svgelements stops at bad data without saying so, which
    would quietly lose the rest of the drawing."""
    i, n = 0, len(d)

    def skip(i):
        return _SEP_RE.match(d, i).end()

    i = skip(0)
    if i == n:
        return None
    if d[i] not in "Mm":
        return f"path data must start with M, found {d[i:i + 12]!r}"
    while i < n:
        cmd = d[i]
        if cmd.upper() not in _PATH_ARGS:
            return f"unknown path command near {d[i:i + 12]!r}"
        i = skip(i + 1)
        nargs = _PATH_ARGS[cmd.upper()]
        if nargs == 0:
            continue
        groups = 0
        while True:
            start = i
            for k in range(nargs):
                if cmd.upper() == "A" and k in (3, 4):
                    if i < n and d[i] in "01":
                        i = skip(i + 1)
                        continue
                    m = None
                else:
                    m = _NUM_RE.match(d, i)
                    if m:
                        i = skip(m.end())
                        continue
                if k == 0 and groups > 0:
                    i = start
                    break
                return (f"command {cmd} needs {nargs} numbers; bad or missing number {k + 1} at "
                        f"{(d[i:i + 12] or 'end of data')!r}")
            else:
                groups += 1
                continue
            break
        if i < n and d[i] not in "MmLlHhVvCcSsQqTtAaZz":
            return f"unexpected text near {d[i:i + 12]!r}"
    return None


_TRANSFORM_ARGS = {"matrix": (6,), "translate": (1, 2), "scale": (1, 2), "rotate": (1, 3),
                   "skewX": (1,), "skewY": (1,)}
_TRANSFORM_RE = re.compile(r"\s*,?\s*([A-Za-z]+)\s*\(([^)]*)\)")


def _check_transform(t: str) -> str | None:
    """None if t is a valid SVG transform list, else what is wrong.  (svgelements
    fails on bad ones with bare IndexErrors, or ignores them.)"""
    i, n = 0, len(t)
    while i < n:
        if not t[i:].strip(" \t\r\n,"):
            return None
        m = _TRANSFORM_RE.match(t, i)
        if not m:
            return f"cannot read transform near {t[i:i + 16].strip()!r}"
        name, args = m.group(1), m.group(2)
        if name not in _TRANSFORM_ARGS:
            return f"unknown transform {name}()"
        nums = [a for a in re.split(r"[\s,]+", args.strip()) if a]
        if any(not _NUM_RE.fullmatch(a) or not math.isfinite(float(a)) for a in nums):
            return f"{name}({args.strip()}): not all arguments are numbers"
        if len(nums) not in _TRANSFORM_ARGS[name]:
            want = " or ".join(str(k) for k in _TRANSFORM_ARGS[name])
            return f"{name}() takes {want} numbers, got {len(nums)}"
        i = m.end()
    return None


def _check_svg_attributes(path: str, root) -> None:
    """Transforms and viewBoxes, checked here so the message can name the element."""
    for el in root.iter():
        tag = el.tag.split("}")[-1]
        ident = f" id={el.get('id')!r}" if el.get("id") else ""
        where = f"{path}:{el.get(_LINE_ATTR)} <{tag}{ident}>"
        t = el.get("transform")
        if t is not None:
            problem = _check_transform(t)
            if problem:
                raise InputError(f"{where}: {problem}")
        vb = el.get("viewBox")
        if vb is not None:
            parts = [a for a in re.split(r"[\s,]+", vb.strip()) if a]
            if len(parts) != 4 or not all(_NUM_RE.fullmatch(a) for a in parts):
                raise InputError(f"{where}: viewBox {vb!r} is not four numbers")
            if not (float(parts[2]) > 0 and float(parts[3]) > 0):
                raise InputError(f"{where}: viewBox {vb!r} has a zero or negative width or height")


def _parse_svg_xml(path: str) -> bytes:
    """Re-serialize the SVG with each element's source line in a data
    attribute, so messages can point at file:line.  Raises InputError with
    the parser's line for malformed XML."""
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as e:
        raise InputError(f"{path}: cannot read SVG: {e.strerror or e}") from None
    tb = ET.TreeBuilder()
    p = expat.ParserCreate(namespace_separator=" ")

    def qn(name: str) -> str:
        if " " in name:
            uri, local = name.split(" ", 1)
            return "{%s}%s" % (uri, local)
        return name

    def start(name, attrs):
        a = {qn(k): v for k, v in attrs.items()}
        a[_LINE_ATTR] = str(p.CurrentLineNumber)
        tb.start(qn(name), a)

    p.StartElementHandler = start
    p.EndElementHandler = lambda name: tb.end(qn(name))
    p.CharacterDataHandler = tb.data
    try:
        p.Parse(raw, True)
    except expat.ExpatError as e:
        raise InputError(f"{path}:{e.lineno}: not a valid SVG/XML file: {expat.ErrorString(e.code)} "
                         f"(line {e.lineno}, column {e.offset + 1})") from None
    root = tb.close()
    if root.tag not in ("{%s}svg" % _SVG_NS, "svg"):
        raise InputError(f"{path}:{root.get(_LINE_ATTR)}: root element is <{root.tag.split('}')[-1]}>, not <svg>")
    _check_svg_attributes(path, root)
    # svgelements draws <symbol> contents in place as well as at each <use>;
    # moving them into <defs> leaves only the instances.
    symbols = []
    for parent in root.iter():
        for child in list(parent):
            if child.tag in ("{%s}symbol" % _SVG_NS, "symbol"):
                parent.remove(child)
                symbols.append(child)
    if symbols:
        defs = ET.SubElement(root, "{%s}defs" % _SVG_NS if root.tag.startswith("{") else "defs")
        defs.extend(symbols)
    ET.register_namespace("", _SVG_NS)
    return ET.tostring(root)


def _flatten_segment(seg, to_mm, tol: float, out: list):
    """Append points of a curved segment (excluding its start) so that the
    polyline stays within tol mm of the curve.  Bisection checks three
    interior points, so S-shaped spans whose midpoint lies on the chord are
    still split."""

    def rec(t0, p0, t1, p1, depth):
        ax, ay = p0
        bx, by = p1
        dx, dy = bx - ax, by - ay
        ln = math.hypot(dx, dy)
        worst = 0.0
        for f in (0.25, 0.5, 0.75):
            qx, qy = to_mm(seg.point(t0 + (t1 - t0) * f))
            if ln == 0:
                dev = math.hypot(qx - ax, qy - ay)
            else:
                dev = abs(dx * (qy - ay) - dy * (qx - ax)) / ln
            worst = max(worst, dev)
        if worst <= tol or depth >= 18:
            out.append(p1)
            return
        tm = (t0 + t1) / 2
        pm = to_mm(seg.point(tm))
        rec(t0, p0, tm, pm, depth + 1)
        rec(tm, pm, t1, p1, depth + 1)

    p0 = to_mm(seg.point(0.0))
    p1 = to_mm(seg.point(1.0))
    # Always split once: a closed arc (start == end) has a zero chord.
    pm = to_mm(seg.point(0.5))
    rec(0.0, p0, 0.5, pm, 1)
    rec(0.5, pm, 1.0, p1, 1)


def load_svg(path: str, *, offset: tuple[float, float] = (0.0, 0.0), scale: float = 1.0,
             tolerance_mm: float = 0.05, weight: int = 255, dot_radius_mm: float = 1.0,
             mirror: bool = False, skip_unsupported: bool = False) -> list[Stroke]:
    """Strokes from an SVG drawing.

    Units follow the SVG: width/height in mm, cm, in, pt or px (96 per inch)
    and the viewBox are honoured, so a drawing made on a 100 mm wide page
    comes out 100 mm wide (times `scale`).  The y axis is flipped: the
    bottom edge of the page is v = 0, so the picture keeps its orientation
    on the wall; without a page height the lowest point of the drawing is
    v = 0.  Then u, v are scaled by `scale` and shifted by `offset`.

    Paths, lines, polylines, polygons, rects, circles and ellipses become
    strokes (one per subpath; closed shapes end at their start).  Curves are
    flattened to within tolerance_mm.  Circles and ellipses whose radius is
    at most dot_radius_mm become dots at their centre.  A data-bk-weight
    attribute (0..255) on an element or group sets the weight, else
    `weight`.  <text> and <image> cannot be drawn with bulges: they are an
    error unless skip_unsupported, which warns and skips them.
    """
    import svgelements as se

    path = os.fspath(path)
    weight = _weight(weight, path)
    if not tolerance_mm > 0:
        raise InputError(f"{path}: tolerance must be > 0 mm, got {tolerance_mm}")
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise InputError(f"{path}: scale must be > 0, got {scale}")
    data = _parse_svg_xml(path)
    try:
        doc = se.SVG.parse(io.BytesIO(data), ppi=96.0)
    except Exception as e:  # svgelements raises assorted types on odd attributes
        raise InputError(f"{path}: cannot interpret SVG: {e}") from None

    # svgelements converts lengths to px with its own rounded 1 mm = 3.7795296
    # px; undoing it with the same factor keeps mm drawings exact (px and
    # inch drawings then differ from 25.4/96 by 5e-7, far below a nozzle).
    mm_per_px = 1.0 / float(se.Length("1mm").value(ppi=96.0))
    # The page height fixes where v = 0 is; svgelements reports it in px.
    page_h_mm = None
    try:
        h = float(doc.height)
        if doc.values.get("height") is not None or doc.viewbox is not None:
            page_h_mm = h * mm_per_px
    except (TypeError, ValueError, AttributeError):
        page_h_mm = None

    raw: list[tuple[list[tuple[float, float]], int, str]] = []  # points in page mm, y down
    filled: list[str] = []        # shapes with a fill given: drawn as their outlines

    def where(el, tag):
        line = el.values.get(_LINE_ATTR)
        eid = el.values.get("id")
        s = f"{path}:{line}" if line else path
        return f"{s} <{tag}{' id=' + repr(eid) if eid else ''}>"

    def to_mm(pt):
        return (float(pt[0]) * mm_per_px, float(pt[1]) * mm_per_px)

    for el in doc.elements():
        tag = el.values.get("tag", type(el).__name__.lower())
        if isinstance(el, (se.Text, se.Image)) or tag in ("text", "image"):
            msg = (f"{where(el, tag)}: <{tag}> cannot be drawn with bulges; convert it to paths "
                   f"(for lettering: --text, or a [[text]] table in a placement file)")
            if not skip_unsupported:
                raise InputError(msg)
            warnings.warn(DrawingWarning(msg + " — skipped"), stacklevel=2)
            continue
        if not isinstance(el, se.Shape):
            continue
        loc = where(el, tag)
        if _filled(el, tag):
            filled.append(loc)
        w = _weight(el.values[_WEIGHT_ATTR], loc) if el.values.get(_WEIGHT_ATTR) is not None else weight
        if tag == "path":
            problem = _check_path_data(el.values.get("d", ""))
            if problem:
                raise InputError(f"{loc}: bad path data: {problem}")
        if tag in ("polyline", "polygon"):
            nums = _NUM_RE.findall(el.values.get("points", ""))
            if len(nums) % 2:
                raise InputError(f"{loc}: points has an odd number of coordinates ({len(nums)})")
        if tag in ("circle", "ellipse"):
            for a in ("r", "rx", "ry"):
                v = el.values.get(a)
                if v is not None and _NUM_RE.match(str(v).strip()) and float(_NUM_RE.match(str(v).strip()).group()) < 0:
                    raise InputError(f"{loc}: negative radius {a}={v}")
            bb = el.bbox()
            if bb is not None:
                x0, y0, x1, y1 = (float(c) * mm_per_px for c in bb)
                if max(x1 - x0, y1 - y0) <= 2 * dot_radius_mm:
                    raw.append(([((x0 + x1) / 2, (y0 + y1) / 2)], w, loc))
                    continue
        pieces: list[list[tuple[float, float]]] = []
        current: list[tuple[float, float]] | None = None
        pen = None  # subpath start, where the pen returns after Z
        for seg in se.Path(el).segments():
            if isinstance(seg, se.Move):
                if current is not None:
                    pieces.append(current)
                pen = to_mm(seg.end)
                current = [pen]
            elif isinstance(seg, se.Close):
                if current is not None and pen is not None:
                    # Land exactly on the start: arcs of circles end a few
                    # ulps off it, which would leave the outline open.
                    if len(current) > 1 and math.dist(current[-1], pen) < 1e-9:
                        current[-1] = pen
                    else:
                        current.append(pen)
                    pieces.append(current)
                current = None
            else:
                if current is None:
                    current = [pen if pen is not None else to_mm(seg.start)]
                if isinstance(seg, se.Line):
                    current.append(to_mm(seg.end))
                else:  # curves and arcs
                    _flatten_segment(seg, to_mm, tolerance_mm / scale, current)
        if current is not None:
            pieces.append(current)
        # A subpath that is only "M x y" (or has zero length) is a dot.
        for pc in pieces:
            raw.append((_dedupe(pc), w, loc))

    if filled:
        # bulges follow strokes: a filled area is drawn as its outline. Said, not hidden.
        warnings.warn(DrawingWarning(
            f"{path}: {len(filled)} filled shape(s) drawn as their outlines only (the first: "
            f"{filled[0]}); for a filled area hatch it with strokes, or give a picture (an image "
            "becomes dots)"), stacklevel=2)
    if not raw:
        raise InputError(f"{path}: no usable strokes (no paths, lines, polylines, polygons, rects, "
                         f"circles or ellipses outside <defs>)")
    if page_h_mm is None:
        page_h_mm = max(y for pts, _, _ in raw for _, y in pts)
    strokes = [Stroke(tuple((x, page_h_mm - y) for x, y in pts), w, loc) for pts, w, loc in raw]
    return drawn(transform(strokes, offset=offset, scale=scale, mirror_u=mirror),
                 Drawing(f"{path}: the drawing", scale, "--scale", "scale", "scale", False,
                         "its page's lower-left corner"))


def _filled(el, tag: str) -> bool:
    """A shape whose fill was given (on it, or inherited: a fill other than SVG's default black,
    which a drawing of strokes leaves unset) and not none: its area would be filled on paper."""
    fill = str(el.values.get("fill", "none")).strip().lower()
    given = "fill" in (el.values.get("attributes") or {}) or fill != "black"
    return given and fill not in ("none", "transparent", "") and tag not in ("line", "polyline")


# --------------------------------------------------------------------------
# Text in a single-stroke (Hershey) font


def font_names() -> list[str]:
    from HersheyFonts import HersheyFonts
    return list(HersheyFonts().default_font_names)


class _Composed:
    """A letter the Hershey fonts lack, made of one they have and an accent (see _accented), a
    bar or a second letter (see _more_letters); metrics are the base letter's unless given."""
    __slots__ = ("strokes", "left_offset", "char_width", "cap_line", "base_line")

    def __init__(self, base, strokes, left_offset=None, char_width=None):
        self.strokes = strokes
        self.left_offset = base.left_offset if left_offset is None else left_offset
        self.char_width = base.char_width if char_width is None else char_width
        self.cap_line, self.base_line = base.cap_line, base.base_line


# Accents as strokes in units of 1/21 of the capital height (the Hershey fonts' own: capitals
# are 21 units tall), x from the letter's middle, y upward from the letter's top (or, for the
# cedilla, downward from the baseline). A one-point stroke is a dot (one bump).
_ACCENTS = {
    "\u0300": [[(1.5, 1.5), (-1.5, 4.5)]],                             # grave
    "\u0301": [[(-1.5, 1.5), (1.5, 4.5)]],                             # acute
    "\u0302": [[(-3, 1.5), (0, 4.5), (3, 1.5)]],                       # circumflex
    "\u0303": [[(-3.5, 2), (-1.5, 4), (1.5, 2), (3.5, 4)]],            # tilde
    "\u0308": [[(-2.5, 3)], [(2.5, 3)]],                               # diaeresis
    "\u030a": [[(0, 1.5), (1.4, 2.1), (2, 3.5), (1.4, 4.9), (0, 5.5), (-1.4, 4.9), (-2, 3.5),
                (-1.4, 2.1), (0, 1.5)]],                               # ring
    "\u0327": [[(0, 0), (0, 2), (1.5, 3), (0, 4.5), (-1.5, 4.5)]],     # cedilla (below)
    "\u0304": [[(-3, 3), (3, 3)]],                                     # macron
    "\u0306": [[(-3, 4.5), (-2, 2.5), (0, 1.5), (2, 2.5), (3, 4.5)]],   # breve
    "\u0307": [[(0, 3)]],                                              # dot above
    "\u030b": [[(-2.5, 1.5), (-0.5, 4.5)], [(1, 1.5), (3, 4.5)]],      # double acute
    "\u030c": [[(-3, 4.5), (0, 1.5), (3, 4.5)]],                       # caron
    "\u0328": [[(0, 0), (-2, 2), (-2, 4), (0, 5), (1, 5)]],            # ogonek (below, right)
}


def _accented(hf, ch: str):
    """Latin letters with accents (é, ü, ñ, å, ç ... all of Latin-1's that decompose): the base
    letter of the font with the accent drawn above it (a dotless i or j under it), or None."""
    import unicodedata
    parts = unicodedata.normalize("NFD", ch)
    if len(parts) < 2 or any(m not in _ACCENTS for m in parts[1:]):
        return None
    found = list(hf.glyphs_for_text(parts[0]))
    if not found:
        return None
    base = found[0]
    strokes = [list(st) for st in base.strokes]
    if parts[0] in "ij" and len(strokes) > 1:        # the dot gives way to the accent
        strokes = [st for st in strokes if max(y for _, y in st) > base.cap_line + 3]
    pts = [p for st in strokes for p in st]
    mid = (min(x for x, _ in pts) + max(x for x, _ in pts)) / 2
    top, unit = min(y for _, y in pts), (base.base_line - base.cap_line) / 21
    right = max(x for x, _ in pts)
    for mark in parts[1:]:
        if mark == "\u030c" and parts[0] in "dltL":   # ď ť ľ Ľ: the caron is a comma beside the stem
            tx = min(pts, key=lambda p: p[1])[0]
            strokes.append([(tx + 3 * unit, base.cap_line), (tx + 2 * unit, base.cap_line + 4 * unit)])
            continue
        for st in _ACCENTS[mark]:
            if mark == "\u0327":
                strokes.append([(mid + x * unit, base.base_line + y * unit) for x, y in st])
            elif mark == "\u0328":
                strokes.append([(right - unit + x * unit, base.base_line + y * unit) for x, y in st])
            else:
                strokes.append([(mid + x * unit, top - y * unit) for x, y in st])
        top -= 5 * unit
    return _Composed(base, strokes)


# Letters of German, the Nordic languages, Polish, Croatian, Dutch... that are no accented letter.
# Drawn ones are in the Hershey units of the font they stand in (capitals from y -12 to the
# baseline at 9, x-height -5, descenders to 16): (left_offset, char_width, strokes).
_DRAWN = {
    "ß": (-10, 19, [[(-6, 9), (-6, -7), (-5, -10), (-3, -12), (0, -12), (3, -11), (4, -9), (4, -7),
                     (3, -5), (0, -4), (3, -3), (5, -1), (6, 1), (6, 4), (5, 7), (3, 8.5), (1, 9),
                     (-2, 9)]]),
    "ẞ": (-11, 21, [[(-7, 9), (-7, -5), (-6, -9), (-4, -11), (-1, -12), (7, -12), (1, -4), (3, -4),
                     (5, -3), (6, -2), (7, 1), (7, 3), (6, 6), (4, 8), (1, 9), (-2, 9)]]),
    "Æ": (-12, 25, [[(-10, 9), (1, -12), (11, -12)], [(1, -12), (1, 9), (11, 9)], [(1, -2), (9, -2)],
                    [(-6, 2), (1, 2)]]),
    "Œ": (-11, 27, [[(13, -12), (-2, -12), (-4, -11), (-6, -9), (-7, -7), (-8, -4), (-8, 1), (-7, 4),
                     (-6, 6), (-4, 8), (-2, 9), (13, 9)], [(2, -12), (2, 9)], [(2, -2), (10, -2)]]),
    "ð": (-9, 19, [[(6, -1), (4, -4), (2, -5), (-1, -5), (-3, -4), (-5, -2), (-6, 1), (-6, 3), (-5, 6),
                    (-3, 8), (-1, 9), (2, 9), (4, 8), (6, 6), (7, 3), (7, -1), (6, -5), (4, -8),
                    (1, -11), (-2, -13)], [(-3, -7), (5, -11)]]),
    "þ": (-10, 19, [[(-6, -12), (-6, 16)], [(-6, -2), (-4, -4), (-2, -5), (1, -5), (3, -4), (5, -2),
                    (6, 1), (6, 3), (5, 6), (3, 8), (1, 9), (-2, 9), (-4, 8), (-6, 6)]]),
    "Þ": (-11, 21, [[(-7, -12), (-7, 9)], [(-7, -7), (2, -7), (5, -6), (6, -5), (7, -3), (7, 0), (6, 2),
                    (5, 3), (2, 4), (-7, 4)]]),
}
# A font's own letter with a stroke across it, the stroke in units of 1/21 of the capital height
# relative to the letter's box (x from its left edge "l", right edge "r" or middle "m"; y upward
# from the cap line "c", x-height "x", baseline "b" or mid-height "h").
_BARRED = {
    "ø": ("o", [[("l", -1, "b", -1), ("r", 1, "x", 1)]]),
    "Ø": ("O", [[("l", -1, "b", -1), ("r", 1, "c", 1)]]),
    "ł": ("l", [[("m", -3, "h", -2.5), ("m", 3, "h", 2.5)]]),
    "Ł": ("L", [[("l", -3, "h", -3), ("l", 4, "h", 3)]]),
    "đ": ("d", [[("r", -4, "c", -3), ("r", 2, "c", -3)]]),
    "Đ": ("D", [[("l", -3, "h", 0), ("l", 4, "h", 0)]]),
    "Ð": ("D", [[("l", -3, "h", 0), ("l", 4, "h", 0)]]),
    "ħ": ("h", [[("l", -3, "c", -3), ("l", 4, "c", -3)]]),
    "Ħ": ("H", [[("l", -2, "c", -4), ("r", 2, "c", -4)]]),
    "ŧ": ("t", [[("m", -3, "h", -1), ("m", 3, "h", -1)]]),
    "Ŧ": ("T", [[("m", -4, "h", 0), ("m", 4, "h", 0)]]),
}
# Two of the font's letters as one: a ligature (the second moved left onto the first's right
# edge) or, for the Dutch ij, side by side
_JOINED = {"æ": ("ae", True), "œ": ("oe", True), "ĳ": ("ij", False), "Ĳ": ("IJ", False)}


def _more_letters(hf, ch: str):
    """ß æ ø Æ Ø œ Œ ð þ Þ đ ł ı ... (see _DRAWN, _BARRED, _JOINED) in the loaded font, or None."""
    def glyph(c):
        found = list(hf.glyphs_for_text(c))
        return found[0] if found else None

    ref = glyph("H")
    if ref is None:
        return None
    unit = (ref.base_line - ref.cap_line) / 21
    if ch in _DRAWN:
        left, width, strokes = _DRAWN[ch]
        return _Composed(ref, [[(x * unit, ref.cap_line + (y + 12) * unit) for x, y in st] for st in strokes],
                         left * unit, width * unit)
    if ch == "ı":                                      # dotless i: the i's dot left out
        base = glyph("i")
        if base is None:
            return None
        stem = [list(st) for st in base.strokes if max(y for _, y in st) > base.cap_line + 3 * unit]
        return _Composed(base, stem)
    if ch in _BARRED:
        letter, bars = _BARRED[ch]
        base = glyph(letter)
        if base is None:
            return None
        strokes = [list(st) for st in base.strokes]
        xs = [x for st in strokes for x, _ in st]
        ax = {"l": min(xs), "r": max(xs), "m": (min(xs) + max(xs)) / 2}
        c, b = base.cap_line, base.base_line
        ay = {"c": c, "b": b, "x": c + 7 * unit, "h": (c + b) / 2}
        for bar in bars:
            strokes.append([(ax[xa] + dx * unit, ay[ya] - dy * unit) for xa, dx, ya, dy in bar])
        return _Composed(base, strokes)
    if ch in _JOINED:
        pair, ligature = _JOINED[ch]
        first, second = (glyph(c) for c in pair)
        if first is None or second is None:
            return None
        if ligature:
            shift = (max(x for st in first.strokes for x, _ in st)
                     - min(x for st in second.strokes for x, _ in st))
        else:
            shift = first.left_offset + first.char_width - second.left_offset
        strokes = [list(st) for st in first.strokes] + [[(x + shift, y) for x, y in st]
                                                        for st in second.strokes]
        end = second.left_offset + second.char_width + shift
        return _Composed(first, strokes, first.left_offset, end - first.left_offset)
    return None


def text_strokes(text: str, size_mm: float, spacing: float = 0.0, u0: float = 0.0, v0: float = 0.0,
                 mirror: bool = False, font: str = "futural", line_spacing: float = 1.6,
                 weight: int = 255) -> list[Stroke]:
    """Lettering as strokes in a single-stroke Hershey font.

    size_mm is the capital height.  (u0, v0) is the left end of the baseline
    of the LAST line, so text placed at v0 rises from there and earlier lines
    of a multi-line text sit above it (descenders such as g, j, p dip below
    v0).  spacing adds that many mm between characters; line_spacing is the
    baseline distance in multiples of size_mm.  mirror flips each line left
    to right, for paint rollers that should print readable text.
    """
    from HersheyFonts import HersheyFonts

    if not isinstance(text, str) or not text.strip():
        raise InputError("text: nothing to write (empty text)")
    if not (size_mm > 0 and math.isfinite(size_mm)):
        raise InputError(f"text: size must be > 0 mm, got {size_mm}")
    weight = _weight(weight, "text")
    hf = HersheyFonts()
    if font not in hf.default_font_names:
        raise InputError(f"text: unknown font {font!r}; available: {', '.join(hf.default_font_names)}")
    hf.load_default_font(font)
    glyphs = {}
    for col, g_char in enumerate(text):                 # in text order: the first missing one is named
        if g_char == "\n" or g_char in glyphs:
            continue
        found = list(hf.glyphs_for_text(g_char))
        glyph = found[0] if found else (_accented(hf, g_char) or _more_letters(hf, g_char))
        if glyph is None:
            raise InputError(f"text: character {g_char!r} (position {col + 1}) is not in font {font!r}")
        glyphs[g_char] = glyph
    any_glyph = next(iter(glyphs.values()))
    cap, base = any_glyph.cap_line, any_glyph.base_line
    k = size_mm / float(base - cap)  # font units → mm; font y grows downward

    lines = text.split("\n")
    strokes: list[Stroke] = []
    for li, line in enumerate(lines):
        baseline_v = v0 + (len(lines) - 1 - li) * line_spacing * size_mm
        x = 0.0
        line_strokes = []
        for ci, ch in enumerate(line):
            g = glyphs[ch]
            for st in g.strokes:
                pts = tuple((x + (gx - g.left_offset) * k, (base - gy) * k) for gx, gy in st)
                line_strokes.append(Stroke(pts, weight, f"text line {li + 1} char {ci + 1} {ch!r}"))
            x += g.char_width * k + spacing
        width = x - spacing if line else 0.0
        for s in line_strokes:
            pts = tuple(((width - u) if mirror else u, v) for u, v in s.points)
            pts = tuple((u0 + u, baseline_v + v) for u, v in pts)
            strokes.append(Stroke(tuple(_dedupe(pts)), s.weight, s.source))
    if not strokes:
        raise InputError("text: nothing to write (only spaces)")
    said = text if len(text) <= 24 else text[:20] + "..."
    return drawn(strokes, Drawing(f"the text {said!r}", size_mm, "--text-size", "size", "size", True,
                                  "its last line's baseline start" if len(lines) > 1 else "its baseline start"))


# --------------------------------------------------------------------------
# JSON stroke lists


def load_json(path: str, *, offset: tuple[float, float] = (0.0, 0.0), scale: float = 1.0,
              mirror: bool = False) -> list[Stroke]:
    """Strokes from JSON: {"strokes": [{"points": [[u, v], ...], "weight": 255}, ...]}.

    u, v in mm; weight optional (default 255); an optional "source" string
    per stroke is kept for messages.  A one-point stroke is a dot.  Then
    scaled, mirrored and shifted as transform() does.
    """
    path = os.fspath(path)
    try:
        with open(path, "r", encoding="utf-8") as f:
            doc = json.load(f)
    except OSError as e:
        raise InputError(f"{path}: cannot read JSON: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}:{e.lineno}: invalid JSON: {e.msg} (line {e.lineno}, column {e.colno})") from None
    if not isinstance(doc, dict) or "strokes" not in doc:
        raise InputError(f'{path}: expected an object with a "strokes" list')
    if not isinstance(doc["strokes"], list):
        raise InputError(f'{path}: "strokes" must be a list')
    out = []
    for i, s in enumerate(doc["strokes"]):
        where = f"{path}: stroke {i}"
        if not isinstance(s, dict):
            raise InputError(f"{where}: must be an object with \"points\"")
        if "points" not in s:
            raise InputError(f'{where}: missing key "points"')
        unknown = set(s) - {"points", "weight", "source"}
        if unknown:
            raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
        pts = s["points"]
        if not isinstance(pts, list) or not pts:
            raise InputError(f'{where}: "points" must be a non-empty list of [u, v]')
        clean = []
        for j, p in enumerate(pts):
            if (not isinstance(p, list) or len(p) != 2
                    or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in p)
                    or not all(math.isfinite(c) for c in p)):
                raise InputError(f"{where} point {j}: expected [u, v] with two finite numbers, got {p!r}")
            clean.append((float(p[0]), float(p[1])))
        w = _weight(s.get("weight", 255), where)
        src = s.get("source")
        if src is not None and not isinstance(src, str):
            raise InputError(f'{where}: "source" must be a string')
        out.append(Stroke(tuple(clean), w, src or f"{path}: stroke {i}"))
    if not out:
        raise InputError(f"{path}: no strokes")
    if offset != (0.0, 0.0) or scale != 1.0 or mirror:
        out = transform(out, offset=offset, scale=scale, mirror_u=mirror)
    return drawn(out, Drawing(f"{path}: the drawing", scale, "--scale", "scale", "scale", False,
                              "its point 0,0"))


def save_json(strokes: Sequence[Stroke], path: str) -> None:
    """Write strokes in the load_json() format (6 decimals = 1 nm)."""
    doc = {"strokes": [{"points": [[round(u, 6), round(v, 6)] for u, v in s.points],
                        "weight": s.weight, **({"source": s.source} if s.source else {})}
                       for s in strokes]}
    from .. import outputs
    outputs.write(path, json.dumps(doc, indent=1) + "\n")


# --------------------------------------------------------------------------
# Images


@dataclass(frozen=True, eq=False, kw_only=True)
class Picture(Drawing):
    """A picture's Drawing: its size is the grid image_dots laid, so its height and the widths
    that fit follow the pitch, not the dots that happen to be dark."""
    path: str
    pitch_mm: float
    size_px: tuple[int, int]
    u0: float
    v0: float

    @classmethod
    def of(cls, path: str, width_mm: float, pitch_mm: float, size_px: tuple[int, int], u0: float,
           v0: float) -> "Picture":
        return cls(what=f"{path}: the picture", size=width_mm, option="--image-width", key="image_width",
                   word="width", mm=True, corner="its lower-left corner", path=path,
                   pitch_mm=pitch_mm, size_px=size_px, u0=u0, v0=v0)

    @property
    def width_mm(self) -> float:
        return self.size

    def rows_at(self, width_mm: float) -> int:
        cols = max(1, round(width_mm / self.pitch_mm))
        return max(1, round(cols * self.size_px[1] / self.size_px[0]))

    @property
    def height_mm(self) -> float:
        return self.rows_at(self.width_mm) * self.pitch_mm

    def holds(self, u: float, v: float) -> bool:
        """Whether (u, v) lies on the picture as image_dots laid it (not turned since)."""
        cols = max(1, round(self.width_mm / self.pitch_mm))
        return (self.u0 - 1e-6 <= u <= self.u0 + cols * self.pitch_mm + 1e-6
                and self.v0 - 1e-6 <= v <= self.v0 + self.height_mm + 1e-6)

    def extent(self, strokes: Sequence[Stroke]) -> tuple[float, float]:
        return self.v0, self.v0 + self.height_mm

    def fit(self, height: float, wall: float) -> str:
        cols = max(1, round(self.width_mm / self.pitch_mm))
        while cols > 1 and self.rows_at(cols * self.pitch_mm) * self.pitch_mm > wall + 1e-9:
            cols -= 1
        return (f"use a smaller width, {cols * self.pitch_mm:g} mm or less"
                if self.rows_at(cols * self.pitch_mm) * self.pitch_mm <= wall + 1e-9 else
                "use a smaller pitch")


def read_gray(path):
    """A picture as an 8-bit grayscale PIL image (any format Pillow reads);
    transparent pixels count as white. Errors name the file."""
    from PIL import Image

    from ..errors import reading_picture

    path = os.fspath(path)
    with reading_picture(path), Image.open(path) as im:
        im.load()
        if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
            rgba = im.convert("RGBA")
            bg = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
            im = Image.alpha_composite(bg, rgba)
        gray = im.convert("L")
    return gray


def image_dots(path: str, width_mm: float, u0: float = 0.0, v0: float = 0.0, pitch_mm: float = 1.5,
               threshold: float = 0.1, invert: bool = False, min_weight: int = 1,
               mirror: bool = False) -> list[Stroke]:
    """Dots on a square grid from a grayscale picture (halftone by dwell).

    The picture is scaled to width_mm (height follows the aspect ratio) and
    averaged over cells of pitch_mm; (u0, v0) is its bottom-left corner.
    Each cell whose darkness (0 white .. 1 black, after `invert`) is at
    least `threshold` becomes a dot of weight round(darkness * 255) (never
    below min_weight).  Transparent pixels count as white.
    """
    from PIL import Image

    path = os.fspath(path)
    if not (width_mm > 0 and pitch_mm > 0):
        raise InputError(f"{path}: width and pitch must be > 0 mm (got {width_mm}, {pitch_mm})")
    if not 0 <= threshold <= 1:
        raise InputError(f"{path}: threshold must be within 0..1, got {threshold}")
    min_weight = _weight(min_weight, path)
    gray = read_gray(path)
    w_px, h_px = gray.size
    cols = max(1, round(width_mm / pitch_mm))
    rows = max(1, round(cols * h_px / w_px))
    # BOX resampling averages all pixels of a cell.
    cells = gray.resize((cols, rows), Image.Resampling.BOX)
    px = cells.load()
    pic = Picture.of(path, width_mm, pitch_mm, (w_px, h_px), u0, v0)
    dots = []
    for r in range(rows):
        v = v0 + (rows - 1 - r) * pitch_mm + pitch_mm / 2
        for c in range(cols):
            dark = 1.0 - px[c, r] / 255.0
            if invert:
                dark = 1.0 - dark
            if dark < threshold or dark <= 0:
                continue
            cc = (cols - 1 - c) if mirror else c
            u = u0 + cc * pitch_mm + pitch_mm / 2
            dots.append(Stroke(((u, v),), max(min_weight, round(dark * 255)),
                               f"{path}: pixel cell row {r} col {c}", pic))
    return dots


# --------------------------------------------------------------------------
# Drawing on a mesh from a fixed view, and cylinder unrolling


@dataclass(frozen=True)
class Stroke3D:
    points: "object"  # numpy (N, 3) array, mm
    weight: int = 255
    source: str = ""


@dataclass
class Projection:
    strokes: list  # list[Stroke3D]
    missed: list  # (source, point index, (a, b)) of drawn points whose ray missed the mesh


def _view_frame(view_dir, up):
    import numpy as np
    d = np.asarray(view_dir, dtype=float)
    upv = np.asarray(up, dtype=float)
    if d.shape != (3,) or not np.linalg.norm(d) > 0:
        raise InputError(f"view direction must be a non-zero 3-vector, got {view_dir!r}")
    d = d / np.linalg.norm(d)
    right = np.cross(d, upv)
    if np.linalg.norm(right) < 1e-9:
        raise InputError(f"view direction {tuple(view_dir)} is parallel to up {tuple(up)}; give another up vector")
    right /= np.linalg.norm(right)
    up2 = np.cross(right, d)
    return d, right, up2


def project_drawing(mesh, strokes_2d: Sequence[Stroke], view_dir, up=(0.0, 0.0, 1.0),
                    origin=None, allow_miss: bool = False) -> Projection:
    """Project strokes drawn in a fixed orthographic view onto a mesh.

    The viewer looks along view_dir with `up` pointing up on the screen;
    2D coordinate a runs to the viewer's right, b upward.  Unless `origin`
    (the 3D point where a = b = 0) is given, (0, 0) is the lower-left corner
    of the mesh's outline in that view, so a drawing on a page the size of
    the silhouette lines up with it; with up = +Z and a mesh standing on
    z = 0, b is then the height above the bed.  Each point is carried along
    the viewing ray to the first surface it meets (the one nearest the
    viewer, as in the paper's fixed-camera mode).  Points whose ray misses
    the mesh are an error unless allow_miss; then they are left out, the
    stroke is split there, and they are listed in .missed.

    `mesh` is a path to a mesh file (STL, OBJ, PLY, ...) or a trimesh.Trimesh.
    """
    import numpy as np
    import trimesh

    if isinstance(mesh, (str, os.PathLike)):
        mpath = os.fspath(mesh)
        try:
            mesh = trimesh.load_mesh(mpath)
        except Exception as e:
            raise InputError(f"{mpath}: cannot read mesh: {e}") from None
        if isinstance(mesh, trimesh.Scene):
            mesh = mesh.dump(concatenate=True)
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise InputError(f"{mpath}: no triangles in mesh")
    d, right, up2 = _view_frame(view_dir, up)
    verts = np.asarray(mesh.vertices)
    if origin is None:
        a_min = float((verts @ right).min())
        b_min = float((verts @ up2).min())
        depth = float((verts @ d).min())
        origin3 = right * a_min + up2 * b_min + d * depth
    else:
        origin3 = np.asarray(origin, dtype=float)
    # Start rays in front of the whole mesh.
    back = float(((verts - origin3) @ d).min()) - 1.0
    flat = [(si, pi, p) for si, s in enumerate(strokes_2d) for pi, p in enumerate(s.points)]
    if not flat:
        raise InputError("project_drawing: no strokes to project")
    ab = np.array([p for _, _, p in flat], dtype=float)
    origins = origin3 + np.outer(ab[:, 0], right) + np.outer(ab[:, 1], up2) + d * back
    dirs = np.tile(d, (len(flat), 1))
    locs, idx_ray, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    # Keep the hit nearest the viewer for each ray.
    hit = np.full((len(flat), 3), np.nan)
    best = np.full(len(flat), np.inf)
    for loc, r in zip(locs, idx_ray):
        t = float((loc - origins[r]) @ d)
        if t < best[r]:
            best[r] = t
            hit[r] = loc
    missed = [(strokes_2d[si].source or f"stroke {si}", pi, tuple(p))
              for (si, pi, p), h in zip(flat, hit) if not np.isfinite(h[0])]
    if missed and not allow_miss:
        src, pi, p = missed[0]
        raise InputError(f"{src} point {pi} at ({p[0]:.2f}, {p[1]:.2f}) mm in the view misses the mesh "
                         f"({len(missed)} point(s) miss in all)")
    out = []
    k = 0
    for s in strokes_2d:
        run = []
        for _ in s.points:
            h = hit[k]
            k += 1
            if np.isfinite(h[0]):
                run.append(h)
            elif run:
                out.append(Stroke3D(np.array(run), s.weight, s.source))
                run = []
        if run:
            out.append(Stroke3D(np.array(run), s.weight, s.source))
    return Projection(out, missed)


def cylinder_uv(points3d, axis_point=(0.0, 0.0, 0.0), axis_dir=(0.0, 0.0, 1.0),
                seam_dir=(1.0, 0.0, 0.0), radius: float | None = None):
    """(u, v) of 3D surface points of a cylinder-like part.

    v is the distance along the axis from axis_point (with the default
    vertical axis through the bed origin: the height above the bed).  u is
    the arc length counter-clockwise (seen from the axis tip looking down)
    from the half-plane through seam_dir, in [0, 2*pi*r), at the point's own
    distance r from the axis, or at `radius` if given.  Exact for a round
    wall centred on the axis; for other cross-sections it is an
    approximation, and the host should rather snap the 3D points to the
    sliced walls directly.
    """
    import numpy as np

    p = np.atleast_2d(np.asarray(points3d, dtype=float))
    a = np.asarray(axis_dir, dtype=float)
    a = a / np.linalg.norm(a)
    s = np.asarray(seam_dir, dtype=float)
    s = s - a * (s @ a)
    if np.linalg.norm(s) < 1e-9:
        raise InputError("seam direction is parallel to the axis")
    s /= np.linalg.norm(s)
    t = np.cross(a, s)
    rel = p - np.asarray(axis_point, dtype=float)
    v = rel @ a
    x = rel @ s
    y = rel @ t
    theta = np.mod(np.arctan2(y, x), 2 * math.pi)
    r = np.hypot(x, y) if radius is None else np.full(len(p), float(radius))
    return np.column_stack([r * theta, v])
