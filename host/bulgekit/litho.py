"""Lithophanes printed with one variable-width mid-line per layer (Jang & Hong 2017, Algorithm 1).

The part stands on the bed and every layer is one row of the picture. Per layer there is the back
face (a straight line for `planar`, a circle for `cylinder`), the front face carrying the relief
(thickness from the picture: dark = thick), one wall line inside each face, and between the walls a
single mid-line whose width is the gap at every point. That width is set by head speed at one
extruder rate (firmware width mode, M723: v = q / (W * H)), so the gap fills in one pass.

    plan = litho.plan_lithophane("cat.png", LithoOptions(shape="cylinder"))
    out = litho.make("cat.png", "out/")      # .litho.gcode .stock.gcode .stl .transmission.png .json

Geometry per layer (shapely): the layer's cross-section P; the walls run on P shrunk by half a line
(their centre line); the mid-line fills R = P shrunk by a whole line. R is probed across the layer
at every sample (vertical probes for planar, radial for cylinder): the probe's extent is the gap g,
its middle the mid-line's centre. A mid-line piece between two samples deposits the area of R
between them (trapezoid rule), so the filament equals the gap's volume; its width is area / length.

Gaps the method cannot fill as asked are handled, and counted in the stats:
  - narrower than `min_line`: the thickness is snapped to two walls (gap 0: the walls merge) or
    up to two walls plus `min_line`, whichever is nearer. By default min_line is the narrowest
    line the mid-line's rate lays at `max_speed`, q / (U * H), but at least 0.2 mm (half a line),
    so that no piece is capped and the extruder keeps its one rate everywhere. The STL, the
    G-code and the predicted transmission all use the snapped thickness: nothing is under-filled.
  - wider than `max_line`: the layer gets n = ceil(gap / max_line) mid-lines of gap / n each.
  - head speed above `max_speed` (very narrow lines): capped; the extruder then runs slower there.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .strokes import BulgekitError, read_gray

SHAPES = ("planar", "cylinder")
CURVES = ("linear", "transmission")
WORDS = ("e", "w")


class LithoError(BulgekitError):
    """A lithophane could not be made from these inputs (message names the input or option)."""


@dataclass
class LithoOptions:
    shape: str = "planar"
    width: float = 100.0            # planar: plate width, mm
    diameter: float = 54.8          # cylinder: outer diameter at the thickest point, mm
    height: float | None = None     # picture height, mm (None: from the picture's aspect ratio)
    min_thickness: float = 0.8      # mm, white (paper: 2.4 mm plate)
    max_thickness: float = 2.4      # mm, black
    invert: bool = False            # light = thick
    curve: str = "linear"           # thickness linear in darkness, or transmission linear in brightness
    gamma: float = 1.0              # darkness ** gamma before the curve (contrast)
    attenuation: float = 1.5        # Beer-Lambert attenuation of the filament, 1/mm
    frame: float = 0.0              # border at full thickness, mm (0: none)
    foot: float | None = None       # planar: depth of a foot block, mm (0: none; None: foot_depth())
    foot_height: float = 3.0        # mm
    layer_height: float = 0.2
    line_width: float = 0.4
    pitch: float = 0.4              # mm between samples along a layer
    min_line: float | None = None   # narrowest mid-line, mm (None: the narrowest line_min())
    max_line: float = 1.6           # widest single mid-line, mm
    filament: float = 1.75
    wall_speed: float = 40.0        # mm/s
    infill_flow: float = 8.0        # mm^3/s, the mid-line's volumetric rate
    paper_rate: bool = False        # mid-line at the walls' rate (w * H * wall_speed), the paper's setting
    max_speed: float = 150.0        # M723 U: cap for narrow lines
    min_speed: float = 5.0          # M723 L
    first_layer_speed: float = 20.0  # walls on layer 1; its mid-line flow scales by the same ratio
    travel_speed: float = 150.0
    z_speed: float = 5.0
    retract: float = 0.8            # mm of filament, for travels longer than retract_min
    retract_speed: float = 35.0
    retract_min: float = 2.0        # mm of travel
    temp: int = 210
    bed_temp: int = 60
    bed: tuple = (220.0, 220.0, 250.0)   # X, Y, Z size of the printer, mm
    words: str = "e"                # litho file: mid-line width as E (previewable) or as W words
    start_gcode: str | None = None  # file replacing the default start G-code
    end_gcode: str | None = None
    purge: bool = True              # a purge line in the default start G-code

    @property
    def filament_area(self) -> float:
        return math.pi * self.filament ** 2 / 4

    def line_min(self) -> float:
        """The narrowest mid-line: `min_line`, or by default the narrowest line the mid-line's
        rate lays at max_speed (8 / (150 x 0.2) = 0.27 mm), but at least half a wall line."""
        if self.min_line is not None:
            return self.min_line
        return max(self.line_width / 2, self.mid_flow / (self.max_speed * self.layer_height))

    @property
    def wall_flow(self) -> float:
        return self.line_width * self.layer_height * self.wall_speed

    @property
    def mid_flow(self) -> float:
        return self.wall_flow if self.paper_rate else self.infill_flow


def check_options(o: LithoOptions) -> None:
    """Refuse option values that cannot make a printable part; messages name the CLI option."""
    def bad(opt, msg):
        raise LithoError(f"--{opt}: {msg}")

    if o.shape not in SHAPES:
        bad("shape", f"{o.shape!r} is not one of {', '.join(SHAPES)}")
    if o.curve not in CURVES:
        bad("curve", f"{o.curve!r} is not one of {', '.join(CURVES)}")
    if o.words not in WORDS:
        bad("words", f"{o.words!r} is not one of {', '.join(WORDS)}")
    positive = {"width": o.width, "diameter": o.diameter, "layer-height": o.layer_height,
                "line-width": o.line_width, "pitch": o.pitch, "filament": o.filament,
                "wall-speed": o.wall_speed, "infill-flow": o.infill_flow, "max-speed": o.max_speed,
                "min-speed": o.min_speed, "first-layer-speed": o.first_layer_speed,
                "travel-speed": o.travel_speed, "z-speed": o.z_speed, "gamma": o.gamma,
                "attenuation": o.attenuation, "min-line": o.line_min(), "max-line": o.max_line,
                "min": o.min_thickness, "max": o.max_thickness}
    for k, v in positive.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            bad(k, f"must be a number > 0, got {v}")
    if o.height is not None and not (math.isfinite(o.height) and o.height > 0):
        bad("height", f"must be a number > 0, got {o.height}")
    for k, v in {"frame": o.frame, "foot": 0.0 if o.foot is None else o.foot, "foot-height": o.foot_height,
                 "retract": o.retract, "retract-min": o.retract_min}.items():
        if not (math.isfinite(v) and v >= 0):
            bad(k, f"must be a number >= 0, got {v}")
    if o.retract > 0 and not (o.retract_speed > 0):
        bad("retract-speed", f"must be > 0, got {o.retract_speed}")
    if o.max_thickness <= o.min_thickness:
        bad("max", f"{o.max_thickness:g} mm must be more than --min {o.min_thickness:g} mm")
    if o.min_thickness < 2 * o.line_width - 1e-9:
        bad("min", f"{o.min_thickness:g} mm is thinner than two wall lines "
                   f"(2 x --line-width {o.line_width:g} mm)")
    if o.max_thickness > 20:
        bad("max", f"{o.max_thickness:g} mm: a lithophane thicker than 20 mm lets no light through")
    if o.layer_height > 0.8 * o.line_width:
        bad("layer-height", f"{o.layer_height:g} mm is more than 0.8 x --line-width {o.line_width:g} mm")
    if o.line_min() >= o.max_line:
        bad("min-line", f"{o.line_min():g} mm must be less than --max-line {o.max_line:g} mm")
    if o.min_speed >= o.max_speed:
        bad("min-speed", f"{o.min_speed:g} must be less than --max-speed {o.max_speed:g}")
    if o.shape == "cylinder":
        if o.diameter / 2 - o.max_thickness < 5 * o.line_width:
            bad("diameter", f"{o.diameter:g} mm leaves no room inside a {o.max_thickness:g} mm wall")
        if o.foot:
            bad("foot", "a cylinder stands by itself; --foot is for planar plates")
    if o.shape == "planar" and o.foot and o.foot < o.max_thickness:
        bad("foot", f"{o.foot:g} mm must be at least --max {o.max_thickness:g} mm deep")
    if len(o.bed) not in (2, 3) or not all(math.isfinite(b) and b > 0 for b in o.bed):
        bad("bed", f"expected X,Y[,Z] in mm > 0, got {o.bed}")


FOOT_MIN = 6.0          # mm, the shallowest default footprint
FOOT_SLOPE = 1 / 8      # default footprint depth per mm of plate height


def foot_depth(o: LithoOptions, picture_height: float) -> float:
    """The foot's depth: --foot, or by default (None) for a planar plate an eighth of its height
    but at least FOOT_MIN and --max. The part's weight sits at about half its height, so it tips
    only when leaned by atan(depth / height) = 7 degrees; a cylinder stands by itself (0)."""
    if o.foot is not None:
        return o.foot
    if o.shape != "planar":
        return 0.0
    return max(FOOT_MIN, o.max_thickness, round(picture_height * FOOT_SLOPE, 1))


# --- the thickness field -------------------------------------------------------------------

@dataclass
class Field:
    """Thickness per layer and sample, and how the picture maps onto the part."""
    t: np.ndarray            # (layers, samples) mm, after snapping; foot layers hold the foot depth
    bright: np.ndarray       # (image layers, samples) source brightness 0..1 on the same grid
    s: np.ndarray            # sample positions: x mm (planar) or angle rad (cylinder)
    n_foot: int              # layers of foot at the bottom (planar)
    lines: np.ndarray        # mid-lines per layer
    snapped_down: int        # samples whose gap was below min_line and went to 0 (walls merge)
    snapped_up: int          # samples whose gap was raised to min_line
    picture_mm: tuple        # (width or circumference, height) of the picture, mm
    inside: tuple            # (rows, samples) slices of the picture inside the frame
    foot: float = 0.0        # depth of the foot, mm (0: none)

    @property
    def layers(self) -> int:
        return self.t.shape[0]


def thickness_field(image, o: LithoOptions) -> Field:
    from PIL import Image

    check_options(o)
    gray = read_gray(image)
    w_px, h_px = gray.size
    if w_px < 8 or h_px < 8:
        raise LithoError(f"{image}: picture is {w_px} x {h_px} px; a lithophane needs at least 8 x 8")
    if o.shape == "planar":
        pic_w = o.width
        n = int(round(pic_w / o.pitch)) + 1            # samples include both ends
        s = np.linspace(0.0, pic_w, n)
    else:
        r_out = o.diameter / 2
        pic_w = 2 * math.pi * r_out                     # picture wraps the outer face
        n = max(16, int(round(pic_w / o.pitch)))
        s = math.pi / 2 + 2 * math.pi * np.arange(n) / n   # seam at the back (+Y), CCW = left to right
    pic_h = o.height if o.height is not None else pic_w * h_px / w_px
    rows = int(round(pic_h / o.layer_height))
    if rows < 2:
        raise LithoError(f"{image}: the picture would be {pic_h:.2f} mm tall, less than two layers")
    if n > 8 * w_px and rows > 8 * h_px:
        raise LithoError(f"{image}: picture is {w_px} x {h_px} px, too small for {n} x {rows} samples "
                         "(use a larger picture or a larger --pitch)")
    # BOX resampling averages the pixels under each sample; row 0 is the picture's top.
    cells = np.asarray(gray.resize((n, rows), Image.Resampling.BOX), dtype=float) / 255.0
    bright = cells[::-1].copy()                         # layer order: bottom of the picture first
    dark = bright if o.invert else 1.0 - bright
    dark = np.clip(dark, 0.0, 1.0) ** o.gamma
    tmin, tmax = o.min_thickness, o.max_thickness
    if o.curve == "linear":
        t = tmin + dark * (tmax - tmin)
    else:
        # Transmission linear in brightness: T = exp(-mu t) from T(tmin) (white) to T(tmax) (black).
        T_hi, T_lo = math.exp(-o.attenuation * tmin), math.exp(-o.attenuation * tmax)
        t = -np.log(T_hi - dark * (T_hi - T_lo)) / o.attenuation
    inside = (slice(0, rows), slice(0, n))
    if o.frame > 0:
        fr = int(math.ceil(o.frame / o.layer_height))
        t[:fr] = tmax
        t[-fr:] = tmax
        cols = slice(0, n)
        if o.shape == "planar":
            edge = (s <= o.frame + 1e-9) | (s >= pic_w - o.frame - 1e-9)
            t[:, edge] = tmax
            cols = slice(int(np.argmin(edge)), n - int(np.argmin(edge[::-1])))
        inside = (slice(fr, max(fr, rows - fr)), cols)
    # Gaps narrower than a printable mid-line: snap to the nearer of "walls merge" (gap 0) and
    # "one narrowest line per mid-line". The per-layer line count comes first: a layer whose
    # widest gap needs two lines can only lay 2 * min_line.
    w2 = 2 * o.line_width
    gap = np.maximum(t - w2, 0.0)
    lines = np.maximum(1, np.ceil(gap.max(axis=1) / o.max_line - 1e-9)).astype(int)
    thr = (lines * o.line_min())[:, None]
    low = (gap > 1e-9) & (gap < thr - 1e-9)
    down = low & (gap < thr / 2)
    up = low & ~down
    t = np.where(down, w2, np.where(up, w2 + thr, t))
    n_foot = 0
    foot = foot_depth(o, rows * o.layer_height)
    if o.shape == "planar" and foot > 0 and o.foot_height > 0:
        n_foot = max(1, int(round(o.foot_height / o.layer_height)))
        t = np.vstack([np.full((n_foot, n), foot), t])
        foot_lines = max(1, math.ceil((foot - w2) / o.max_line - 1e-9))
        lines = np.concatenate([np.full(n_foot, foot_lines), lines])
    return Field(t=t, bright=bright, s=s, n_foot=n_foot, lines=lines, snapped_down=int(down.sum()),
                 snapped_up=int(up.sum()), picture_mm=(pic_w, rows * o.layer_height), inside=inside,
                 foot=foot if n_foot else 0.0)


# --- per-layer paths -----------------------------------------------------------------------

@dataclass
class Section:
    """One continuous extrusion path: points (k, 2) in part coordinates (mm), filament per piece
    (k - 1,) in mm, head speed per piece (mm/s), and the kind: wall, mid-line, connector."""
    kind: str
    pts: np.ndarray
    e: np.ndarray
    v: np.ndarray
    width: np.ndarray          # line width per piece (mm): deposited area / length


@dataclass
class Layer:
    z: float
    sections: list
    gap: np.ndarray            # mid-line probe extents per sample (mm), 0 where no mid-line
    probe_mid: np.ndarray      # where the probes' middles are (k, 2)


@dataclass
class Plan:
    options: LithoOptions
    field: Field
    layers: list = field(default_factory=list)
    origin: tuple = (0.0, 0.0)     # bed position of the part's (0, 0)
    counts: dict = field(default_factory=dict)


def _layer_polygon(o: LithoOptions, fld: Field, k: int):
    from shapely.geometry import Polygon

    t = fld.t[k]
    if o.shape == "planar":
        if k < fld.n_foot:                                  # the foot block, centred on the plate
            y0 = (o.max_thickness - o.foot) / 2
            return Polygon([(0, y0), (fld.s[-1], y0), (fld.s[-1], y0 + o.foot), (0, y0 + o.foot)])
        front = np.column_stack([fld.s, t])[::-1]
        return Polygon(np.vstack([[(0.0, 0.0), (fld.s[-1], 0.0)], front]))
    r_in = o.diameter / 2 - o.max_thickness
    c, sn = np.cos(fld.s), np.sin(fld.s)
    outer = np.column_stack([(r_in + t) * c, (r_in + t) * sn])
    inner = np.column_stack([r_in * c, r_in * sn])[::-1]
    return Polygon(outer, [inner])


def _probes(o: LithoOptions, fld: Field, k: int):
    """Probe segments across the layer at every sample: (start, end) arrays (k, 2)."""
    if o.shape == "planar":
        reach = max(o.max_thickness, o.foot)                # the foot is centred on the plate
        lo, hi = -reach - 1.0, 2 * reach + 1.0
        x = fld.s.copy()
        x[0], x[-1] = o.line_width, fld.s[-1] - o.line_width   # the ends touch the end walls
        return np.column_stack([x, np.full_like(x, lo)]), np.column_stack([x, np.full_like(x, hi)])
    r_in = o.diameter / 2 - o.max_thickness
    c, sn = np.cos(fld.s), np.sin(fld.s)
    r0, r1 = r_in - 1.0, o.diameter / 2 + 1.0
    return np.column_stack([r0 * c, r0 * sn]), np.column_stack([r1 * c, r1 * sn])


def _plate_middle(o: LithoOptions, fld: Field, k: int, a, b):
    """The middle of the plate on each probe: half the thickness from the back face."""
    d = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    t = fld.t[k]
    if o.shape == "planar":
        y0 = (o.max_thickness - o.foot) / 2 if k < fld.n_foot else 0.0
        return np.column_stack([a[:, 0], y0 + t / 2])
    r_in = o.diameter / 2 - o.max_thickness
    return d * (r_in + t / 2)[:, None]


def _gap_along(region, a, b, centre):
    """Length of each probe inside `region`, and the middle of its extent (between the first and
    last point inside). Where the probe misses the region (the walls merge) the middle is
    `centre`, the plate's own middle, so that the head crosses there inside the part."""
    import shapely

    lines = shapely.linestrings(np.stack([a, b], axis=1))
    inter = shapely.intersection(region, lines)
    length = shapely.length(inter)
    mid = np.array(centre, dtype=float)
    empty = shapely.is_empty(inter)
    d = b - a
    dn = d / np.linalg.norm(d, axis=1, keepdims=True)
    for i in np.flatnonzero(~empty):
        xy = shapely.get_coordinates(inter[i])
        proj = (xy - a[i]) @ dn[i]
        lo, hi = proj.min(), proj.max()
        mid[i] = a[i] + dn[i] * (lo + hi) / 2
    return np.where(empty, 0.0, length), mid


def _speeds(area_per_mm, o: LithoOptions, flow):
    """Head speed for a line of cross-section A at volumetric rate q: v = q / A (eq. 1), capped."""
    with np.errstate(divide="ignore"):
        v = flow / np.maximum(area_per_mm, 1e-12)
    return np.clip(v, o.min_speed, o.max_speed)


def _capped(s: Section, o: LithoOptions, flow) -> np.ndarray:
    """Laid pieces whose speed was capped: their volumetric rate W * H * v is below the flow."""
    return (s.e > 0) & (s.width * o.layer_height * s.v < flow * (1 - 1e-6))


def _wall_section(ring, o: LithoOptions, speed) -> Section:
    pts = np.asarray(ring.coords)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-6])
    pts = pts[keep]
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    e = seg * o.line_width * o.layer_height / o.filament_area
    n = len(seg)
    return Section("wall", pts, e, np.full(n, speed), np.full(n, o.line_width))


def _mid_sections(o: LithoOptions, fld: Field, k: int, region, flow, counts: dict):
    """The layer's mid-line(s) from probes across R: (sections, gap per sample, probe middles).
    Next to a steep step R can be narrower than the thickness says (the wall bends round the
    step). Such slivers narrower than the narrowest line are laid at that width (a little more
    filament, so the rate stays one) when they are at least half of it, and otherwise not laid
    (the head moves on); both areas are added up in `counts` (mm^2 per layer, x H = mm^3)."""
    a, b = _probes(o, fld, k)
    g, mid = _gap_along(region, a, b, _plate_middle(o, fld, k, a, b))
    nl = int(fld.lines[k])
    out = []
    d = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    base = mid - d * (g / 2)[:, None]                       # the gap's inner edge (back side)
    closed = o.shape == "cylinder"
    for i in range(nl):
        c = base + d * (g * (2 * i + 1) / (2 * nl))[:, None]    # centre of line i
        gi = g / nl
        if closed:
            c = np.vstack([c, c[:1]])
            gi = np.concatenate([gi, gi[:1]])
        seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
        if closed:
            # area of the band between two radial probes: mean of (gap * centre radius) * dtheta
            rr = np.linalg.norm(c, axis=1)
            dth = 2 * math.pi / len(fld.s)
            area = (gi[:-1] * rr[:-1] + gi[1:] * rr[1:]) / 2 * dth
        else:
            area = (gi[:-1] + gi[1:]) / 2 * np.abs(np.diff(c[:, 0]))
        with np.errstate(divide="ignore", invalid="ignore"):
            width = np.where(seg > 1e-9, area / np.maximum(seg, 1e-12), 0.0)
        lmin = o.line_min()
        laid = width >= lmin / 2
        widen = laid & (width < lmin)
        counts["sliver_added_mm3"] += float(((lmin - width[widen]) * seg[widen]).sum() * o.layer_height)
        counts["sliver_left_mm3"] += float(area[~laid].sum() * o.layer_height)
        width = np.where(widen, lmin, width)
        area = np.where(widen, lmin * seg, area)
        e = np.where(laid, area * o.layer_height / o.filament_area, 0.0)
        speed_of = lambda wd: _speeds(wd * o.layer_height, o, flow)
        sec = _simplify(Section("mid-line", c, e, speed_of(width), np.where(laid, width, 0.0)),
                        closed, speed_of, chord=3 * o.pitch)
        if sec is None:                                     # the walls merge all along
            continue
        if i % 2 and not closed:                            # serpentine: odd lines run back
            sec = _reverse(sec)
        out.append(sec)
    return out, g, mid


def _simplify(s: Section, closed: bool, speed_of, chord: float, rel_width=0.005,
              sin_tol=1e-3) -> Section | None:
    """Fewer, longer pieces: neighbours that run on in the same direction merge when both are
    laid at the same width (within rel_width) or both are not laid, and where nothing is laid
    on a curve the head moves on in chords of about `chord` mm (_straighten_crossings). An open path
    loses its unlaid ends; a path with nothing laid is None. Filament and area are kept
    exactly; a merged piece's speed is `speed_of(width)` of its merged width."""
    laid = s.e > 0
    if not laid.any():
        return None
    d = np.diff(s.pts, axis=0)
    seg = np.linalg.norm(d, axis=1)
    keep = [0]
    for i in range(1, len(seg)):
        j = keep[-1]
        # the running piece is pts[j] -> pts[i]; piece i is pts[i] -> pts[i + 1]
        a, b = s.pts[i] - s.pts[j], d[i]
        straight = abs(a[0] * b[1] - a[1] * b[0]) <= sin_tol * np.linalg.norm(a) * seg[i] and a @ b > 0
        same = (laid[i] == laid[i - 1]) and (not laid[i] or abs(s.width[i] - s.width[i - 1])
                                              <= rel_width * s.width[i - 1])
        if not (straight and same):
            keep.append(i)
    keep.append(len(seg))
    idx = np.array(keep)
    pts = s.pts[idx]
    e = np.add.reduceat(s.e, idx[:-1])
    area_len = np.add.reduceat(s.width * seg, idx[:-1])       # width x length = area per layer
    length = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    width = np.where(e > 0, area_len / np.maximum(length, 1e-12), 0.0)
    v = s.v[idx[:-1]].copy()
    v[width > 0] = speed_of(width[width > 0])
    out = _straighten_crossings(Section(s.kind, pts, e, v, width), chord)
    if not closed:
        on = np.flatnonzero(out.e > 0)
        a, b = on[0], on[-1] + 1
        out = Section(s.kind, out.pts[a:b + 1], out.e[a:b], out.v[a:b], out.width[a:b])
    return out


def _straighten_crossings(s: Section, chord: float) -> Section:
    """Where nothing is laid (the walls merge) the head only has to get through. Along a curve
    (a cylinder's middle, 0.4 mm pieces) a run of unlaid pieces is thinned to pieces of about
    `chord` mm: Marlin plans 14 blocks ahead, so 0.4 mm pieces cap the head at
    sqrt(2 a 14 x 0.4) (106 mm/s at 1000 mm/s^2), while longer chords turn by more at each
    junction, where junction deviation allows about sqrt(8 a JD) R / chord. Both exceed a
    150 mm/s travel at about 1.2 mm on a 26 mm radius, whatever the acceleration; such a chord
    strays 0.007 mm from the circle."""
    laid = s.e > 0
    if laid.all():
        return s
    seg = np.linalg.norm(np.diff(s.pts, axis=0), axis=1)
    keep = np.ones(len(s.pts), bool)
    i, n = 0, len(laid)
    while i < n:
        if laid[i]:
            i += 1
            continue
        j = i
        while j < n and not laid[j]:
            j += 1
        step = max(1, int(round(chord / max(float(seg[i:j].mean()), 1e-9))))
        if step > 1 and j - i > 1:                       # pieces i..j-1, points i..j
            keep[i + 1:j] = False
            keep[i + step:j:step] = True
        i = j
    if keep.all():
        return s
    idx = np.flatnonzero(keep)
    # each kept piece starts at a kept point; the unlaid pieces between kept points become one
    return Section(s.kind, s.pts[idx], s.e[idx[:-1]], s.v[idx[:-1]], s.width[idx[:-1]])


def _reverse(s: Section) -> Section:
    return Section(s.kind, s.pts[::-1].copy(), s.e[::-1].copy(), s.v[::-1].copy(), s.width[::-1].copy())


def _rotate_loop(s: Section, near) -> Section:
    """A closed loop started at its vertex nearest `near`."""
    pts = s.pts[:-1]
    i = int(np.argmin(np.linalg.norm(pts - near, axis=1)))
    if i == 0:
        return s
    pts = np.vstack([pts[i:], pts[:i], pts[i:i + 1]])
    roll = lambda x: np.concatenate([x[i:], x[:i]])
    return Section(s.kind, pts, roll(s.e), roll(s.v), roll(s.width))


def _orient(s: Section, near) -> Section:
    """An open path started at the end nearer `near`."""
    if np.linalg.norm(s.pts[-1] - near) < np.linalg.norm(s.pts[0] - near):
        return _reverse(s)
    return s


def plan_lithophane(image, o: LithoOptions | None = None, progress=None) -> Plan:
    """Paths for every layer. `progress(done, total)` is called now and then."""
    from shapely.geometry.polygon import orient

    o = o or LithoOptions()
    fld = thickness_field(image, o)
    o = replace(o, foot=fld.foot)          # the plan and its files carry the depth in use
    _check_fits(o, fld)
    plan = Plan(o, fld)
    plan.counts.update(sliver_added_mm3=0.0, sliver_left_mm3=0.0)
    H, w = o.layer_height, o.line_width
    pos = None
    capped = 0
    for k in range(fld.layers):
        first = k == 0
        wall_v = o.first_layer_speed if first else o.wall_speed
        flow = o.mid_flow * (o.first_layer_speed / o.wall_speed if first else 1.0)
        P = _layer_polygon(o, fld, k)
        # bevel joins: GEOS's mitre joins lost the hole of some rings (a cylinder layer came out
        # as one polygon without its inside)
        walls = orient(P.buffer(-w / 2, join_style="bevel"), 1.0)
        region = P.buffer(-w, join_style="bevel")
        holes = 1 if o.shape == "cylinder" else 0
        if walls.geom_type != "Polygon" or walls.is_empty or len(walls.interiors) != holes:
            raise LithoError(f"layer {k + 1}: the walls' centre line is not one {'ring pair' if holes else 'loop'} "
                             f"({walls.geom_type}, {len(getattr(walls, 'interiors', []))} holes)")
        rings = [walls.exterior] + list(walls.interiors)
        wall_secs = [_wall_section(r, o, wall_v) for r in rings]
        mids, g, pm = _mid_sections(o, fld, k, region, flow, plan.counts)
        if pos is None:
            pos = wall_secs[0].pts[0]
        secs = []
        if o.shape == "planar":
            # one loop round the plate, then the mid-line(s) from the end nearer the loop's start
            loop = _rotate_loop(wall_secs[0], pos)
            secs.append(loop)
            for m in mids:
                m = _orient(m, secs[-1].pts[-1])
                secs.append(m)
        else:
            # inner wall, mid-line loop(s), outer wall (odd layers outside in): each loop starts at
            # the seam, next to where the last one ended, so a layer needs no travel
            inner, outer = wall_secs[1], wall_secs[0]
            order = [inner] + mids + [outer]
            if k % 2:
                order = order[::-1]
            for s in order:
                s = _rotate_loop(s, pos if not secs else secs[-1].pts[-1])
                secs.append(s)
        plan.layers.append(Layer(z=(k + 1) * H, sections=secs, gap=g, probe_mid=pm))
        pos = secs[-1].pts[-1]
        capped += sum(int(np.sum(_capped(s, o, flow))) for s in mids)
        if progress and (k % 25 == 0 or k == fld.layers - 1):
            progress(k + 1, fld.layers)
    plan.counts["capped_pieces"] = capped
    _place(plan)
    return plan


def _check_fits(o: LithoOptions, fld: Field) -> None:
    """Refuse a part larger than the bed (with the purge line at the front), before any planning."""
    if o.shape == "planar":
        size = (fld.s[-1], max(o.max_thickness, o.foot))
    else:
        size = (o.diameter, o.diameter)
    bx, by = o.bed[0], o.bed[1]
    margin = 2.0
    if size[0] + 2 * margin > bx or size[1] + 2 * margin + (12 if o.purge else 0) > by:
        raise LithoError(f"--bed: the part is {size[0]:.1f} x {size[1]:.1f} mm and does not fit a "
                         f"{bx:g} x {by:g} mm bed (with {margin:g} mm margins"
                         f"{' and the purge line' if o.purge else ''})")
    height = fld.layers * o.layer_height
    if len(o.bed) == 3 and height > o.bed[2]:
        raise LithoError(f"--bed: the part is {height:.1f} mm tall, more than the printer's "
                         f"{o.bed[2]:g} mm")


def _place(plan: Plan) -> None:
    """Centre the part on the bed."""
    o = plan.options
    pts = np.vstack([s.pts for L in plan.layers for s in L.sections])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    plan.origin = (o.bed[0] / 2 - (lo[0] + hi[0]) / 2, o.bed[1] / 2 - (lo[1] + hi[1]) / 2)


# --- G-code --------------------------------------------------------------------------------

DEFAULT_START = """\
; default start (replace with --start-gcode FILE, where the words temp and bed_temp in braces
; are filled in)
G21 ; millimetres
M140 S{bed_temp}
M104 S{temp}
G28 ; home
M190 S{bed_temp}
M109 S{temp}
"""
DEFAULT_END = """\
; default end (replace with --end-gcode FILE)
M104 S0
M140 S0
M107
G91
G1 Z5 F300
G90
M84
"""


def _fmt(v: float, nd: int) -> str:
    s = f"{v:.{nd}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


class _Writer:
    """Writes one of the two G-code files. `mode`: "litho" (width mode: M723 sets the extruder
    rate, the firmware picks each piece's speed) or "stock" (eq. 2: explicit F per piece so that
    E * F / L is the same rate, for stock firmware)."""

    def __init__(self, plan: Plan, mode: str):
        self.p, self.o, self.mode = plan, plan.options, mode
        self.lines: list[str] = []
        self.x = self.y = None
        self.f = None
        self.retracted = False
        self.flow = None

    def out(self, s):
        self.lines.append(s)

    def move(self, x, y, e=None, f=None, w=None):
        ox, oy = self.p.origin
        words = [f"G1 X{_fmt(x + ox, 3)} Y{_fmt(y + oy, 3)}"]
        if w is not None:
            words.append(f"W{_fmt(w, 4)}")
        elif e is not None and e != 0:
            words.append(f"E{_fmt(e, 5)}")
        if f is not None:
            fm = f * 60
            if self.f is None or abs(fm - self.f) > 1e-6:
                words.append(f"F{_fmt(fm, 1)}")
                self.f = float(_fmt(fm, 1))
        self.out(" ".join(words))
        self.x, self.y = x, y

    def travel(self, x, y):
        o = self.o
        if self.x is not None and math.hypot(x - self.x, y - self.y) < 1e-6:
            return
        far = self.x is None or math.hypot(x - self.x, y - self.y) >= o.retract_min
        if far and o.retract > 0 and not self.retracted:
            self.out(f"G1 E-{_fmt(o.retract, 4)} F{_fmt(o.retract_speed * 60, 1)}")
            self.f = o.retract_speed * 60
            self.retracted = True
        self.move(x, y, f=o.travel_speed)

    def prime(self):
        if self.retracted:
            self.out(f"G1 E{_fmt(self.o.retract, 4)} F{_fmt(self.o.retract_speed * 60, 1)}")
            self.f = self.o.retract_speed * 60
            self.retracted = False

    def set_flow(self, q):
        if self.mode == "litho" and (self.flow is None or abs(q - self.flow) > 1e-9):
            self.out(f"M723 Q{_fmt(q, 4)}")
            self.flow = q

    def section(self, s: Section, wall_flow, mid_flow):
        o = self.o
        start = s.pts[0]
        if self.x is None or math.hypot(start[0] - self.x, start[1] - self.y) > 1e-6:
            d = math.inf if self.x is None else math.hypot(start[0] - self.x, start[1] - self.y)
            if d < o.retract_min and not self.retracted:
                # a short join inside the part: laid at this section's width, so no travel
                self.out(";TYPE:connector")
                self.set_flow(wall_flow if s.kind == "wall" else mid_flow)
                e = d * s.width[0] * o.layer_height / o.filament_area if s.width[0] > 0 else 0.0
                self._piece(start[0], start[1], e, s.v[0], s.width[0] if e > 0 else None)
            else:
                self.out(";TYPE:travel")
                self.travel(start[0], start[1])
        self.prime()
        self.out(f";TYPE:{s.kind}")
        self.set_flow(wall_flow if s.kind == "wall" else mid_flow)
        for i in range(len(s.e)):
            x, y = s.pts[i + 1]
            if s.e[i] > 0:
                self._piece(x, y, s.e[i], s.v[i], s.width[i])
            else:                                        # no line here: the head moves on
                self.move(x, y, f=o.travel_speed)

    def _piece(self, x, y, e, v, width):
        if self.mode == "stock":
            self.move(x, y, e=e, f=v)
        elif self.o.words == "w" and width is not None:
            self.move(x, y, w=width)
        else:
            # E per width; F is the same speed the firmware will choose, so the file also
            # prints right on firmware without width mode (the firmware ignores F here)
            self.move(x, y, e=e, f=v)


def write_gcode(plan: Plan, path, mode: str, name: str = "lithophane") -> None:
    o = plan.options
    w = _Writer(plan, mode)
    fill = lambda text: text.replace("{temp}", str(o.temp)).replace("{bed_temp}", str(o.bed_temp))
    start = DEFAULT_START if o.start_gcode is None else _read_text(o.start_gcode, "start-gcode")
    end = DEFAULT_END if o.end_gcode is None else _read_text(o.end_gcode, "end-gcode")
    w.out(f"; bulgekit litho: {name}, {o.shape}, {len(plan.layers)} layers, "
          f"{'width mode (M723)' if mode == 'litho' else 'stock firmware (eq. 2: F per piece)'}")
    for k, v in sorted(_options_dict(o).items()):          # one short line each (firmware line limits)
        w.out(f"; {k} = {json.dumps(v)}")
    w.out(fill(start).rstrip("\n"))
    w.out("G90 ; absolute positions")
    w.out("M83 ; relative E")
    if o.start_gcode is None and o.purge:
        w.out(";TYPE:purge")
        y = 5.0 - plan.origin[1]
        x0, x1 = 10.0 - plan.origin[0], o.bed[0] - 10.0 - plan.origin[0]
        w.out(f"G1 Z{_fmt(o.layer_height, 3)} F{_fmt(o.z_speed * 60, 1)}")
        w.move(x0, y, f=o.travel_speed)
        purge_e = (x1 - x0) * o.line_width * 1.5 * o.layer_height / o.filament_area
        w.move(x1, y, e=purge_e, f=o.first_layer_speed)
    if mode == "litho":
        w.out(f"M723 S1 Q{_fmt(o.wall_flow, 4)} D{_fmt(o.filament, 4)} H{_fmt(o.layer_height, 4)} "
              f"L{_fmt(o.min_speed, 3)} U{_fmt(o.max_speed, 3)} ; width mode: extruder at one rate")
        w.flow = o.wall_flow
    ratio = o.first_layer_speed / o.wall_speed
    for k, L in enumerate(plan.layers):
        w.out(f";LAYER:{k}")
        w.out(f"G1 Z{_fmt(L.z, 3)} F{_fmt(o.z_speed * 60, 1)}")
        w.f = o.z_speed * 60
        wall_q = o.wall_flow * (ratio if k == 0 else 1.0)
        mid_q = o.mid_flow * (ratio if k == 0 else 1.0)
        for s in L.sections:
            w.section(s, wall_q, mid_q)
    if mode == "litho":
        w.out("M723 S0 ; width mode off")
    if o.retract > 0:
        w.out(f"G1 E-{_fmt(o.retract, 4)} F{_fmt(o.retract_speed * 60, 1)}")
    w.out(fill(end).rstrip("\n"))
    _write_atomic(path, "\n".join(w.lines) + "\n")


def _read_text(path, opt):
    try:
        return Path(path).read_text()
    except OSError as e:
        raise LithoError(f"--{opt} {path}: {e.strerror or e}") from None


def _options_dict(o: LithoOptions) -> dict:
    d = asdict(o)
    d["bed"] = list(o.bed)
    return d


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


@contextlib.contextmanager
def _held():
    """SIGINT and SIGTERM held back (delivered at the end) in this thread, where available."""
    import signal
    block = getattr(signal, "pthread_sigmask", None)
    old = block(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM}) if block else None
    try:
        yield
    finally:
        if block:
            block(signal.SIG_SETMASK, old)


def _write_atomic(path, data, binary=False):
    """Write all of it or nothing: a temporary file in the same folder, renamed over the target."""
    path = Path(path)
    tmp = None
    try:
        with _held():                                 # the file is made and its name kept
            fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".part", dir=path.parent)
        with os.fdopen(fd, "wb" if binary else "w") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        try:
            if tmp is not None:
                os.unlink(tmp)
        except OSError:
            pass
        raise


# --- the body as an STL --------------------------------------------------------------------

def body_mesh(plan: Plan) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (mm, bed coordinates) and triangles of the printed body, watertight.

    Rows of vertices lie at the layers' mid-heights, so a slicer cutting there (as Cura and
    PrusaSlicer do) gets exactly the layers planned here; the first and last rows are repeated at
    the bottom and the top. A foot is a separate closed box under the plate (the two shells touch).
    """
    o, fld = plan.options, plan.field
    H = o.layer_height
    t = fld.t[fld.n_foot:]
    z0 = fld.n_foot * H
    zs = np.concatenate([[z0], z0 + (np.arange(t.shape[0]) + 0.5) * H, [z0 + t.shape[0] * H]])
    T = np.vstack([t[:1], t, t[-1:]])
    ox, oy = plan.origin
    R, C = T.shape
    if o.shape == "planar":
        X = np.broadcast_to(fld.s, (R, C))
        front = np.stack([X, T, np.broadcast_to(zs[:, None], (R, C))], axis=-1)
        back = np.stack([X, np.zeros((R, C)), np.broadcast_to(zs[:, None], (R, C))], axis=-1)
        closed = False
    else:
        r_in = o.diameter / 2 - o.max_thickness
        c, sn = np.cos(fld.s), np.sin(fld.s)
        Z = np.broadcast_to(zs[:, None], (R, C))
        front = np.stack([(r_in + T) * c, (r_in + T) * sn, Z], axis=-1)
        back = np.stack([np.broadcast_to(r_in * c, (R, C)), np.broadcast_to(r_in * sn, (R, C)), Z], axis=-1)
        closed = True
    V = np.concatenate([front.reshape(-1, 3), back.reshape(-1, 3)])
    nf = R * C
    idx_f = np.arange(nf).reshape(R, C)
    idx_b = idx_f + nf
    faces = []

    def grid(idx, flip):
        a = idx[:-1, :-1]; b = idx[:-1, 1:]; c_ = idx[1:, 1:]; d = idx[1:, :-1]
        if closed:
            a = idx[:-1]; b = np.roll(idx[:-1], -1, axis=1); c_ = np.roll(idx[1:], -1, axis=1); d = idx[1:]
        t1 = np.stack([a, b, c_], -1).reshape(-1, 3)
        t2 = np.stack([a, c_, d], -1).reshape(-1, 3)
        tri = np.concatenate([t1, t2])
        return tri[:, ::-1] if flip else tri

    # The outward normal follows the winding; planar front faces +Y, cylinder front faces outwards.
    faces.append(grid(idx_f, flip=not closed))
    faces.append(grid(idx_b, flip=closed))

    def strip(top_idx, bot_idx, flip):
        """Quads between two vertex rows (a cap or an end), as triangles."""
        a = top_idx[:-1]; b = top_idx[1:]; c_ = bot_idx[1:]; d = bot_idx[:-1]
        if closed:
            a = top_idx; b = np.roll(top_idx, -1); c_ = np.roll(bot_idx, -1); d = bot_idx
        tri = np.concatenate([np.stack([a, b, c_], -1), np.stack([a, c_, d], -1)])
        return tri[:, ::-1] if flip else tri

    faces.append(strip(idx_f[0], idx_b[0], flip=closed))        # bottom cap
    faces.append(strip(idx_f[-1], idx_b[-1], flip=not closed))  # top cap
    if not closed:                                              # the two ends of the plate
        faces.append(strip(idx_f[:, 0], idx_b[:, 0], flip=True))
        faces.append(strip(idx_f[:, -1], idx_b[:, -1], flip=False))
    F = np.concatenate(faces)
    V = V + np.array([ox, oy, 0.0])
    if fld.n_foot:
        y0 = (o.max_thickness - o.foot) / 2
        bx = np.array([[0, y0, 0], [fld.s[-1], y0, 0], [fld.s[-1], y0 + o.foot, 0], [0, y0 + o.foot, 0]], float)
        box = np.vstack([bx, bx + [0, 0, z0]]) + [ox, oy, 0.0]
        q = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5),
             (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
        F = np.concatenate([F, np.array(q) + len(V)])
        V = np.concatenate([V, box])
    return V, F


def mesh_volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def write_stl(V: np.ndarray, F: np.ndarray, path, name="bulgekit lithophane") -> None:
    tri = V[F].astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    rec = np.zeros(len(F), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"], rec["v"] = n, tri
    head = name.encode()[:80].ljust(80, b" ")
    _write_atomic(path, head + np.uint32(len(F)).tobytes() + rec.tobytes(), binary=True)


# --- predicted look and statistics ---------------------------------------------------------

def printed_thickness(plan: Plan) -> np.ndarray:
    """Thickness as laid down, per image layer and sample: two walls plus the mid-line's probe
    extent where a mid-line was laid (0 where the walls merge)."""
    o, fld = plan.options, plan.field
    return np.array([2 * o.line_width + L.gap for L in plan.layers[fld.n_foot:]])


def transmission(t: np.ndarray, mu: float) -> np.ndarray:
    """Beer-Lambert: share of the backlight that passes t mm."""
    return np.exp(-mu * t)


def _ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean structural similarity over 7 x 7 windows (Wang et al. 2004, constants for range 1)."""
    from numpy.lib.stride_tricks import sliding_window_view as win

    if min(a.shape) < 7:
        return float("nan")
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    wa, wb = win(a, (7, 7)), win(b, (7, 7))
    ma, mb = wa.mean(axis=(-1, -2)), wb.mean(axis=(-1, -2))
    va, vb = wa.var(axis=(-1, -2)), wb.var(axis=(-1, -2))
    cov = (wa * wb).mean(axis=(-1, -2)) - ma * mb
    s = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma ** 2 + mb ** 2 + c1) * (va + vb + c2))
    return float(s.mean())


def look(plan: Plan):
    """(intended brightness, predicted brightness), both 0..1 on the layer x sample grid: the
    picture (its negative with invert), and the transmission scaled so that the thinnest allowed
    plate shows white and the thickest black."""
    o = plan.options
    T = transmission(printed_thickness(plan), o.attenuation)
    t_lo, t_hi = transmission(o.min_thickness, o.attenuation), transmission(o.max_thickness, o.attenuation)
    pred = np.clip((T - t_hi) / (t_lo - t_hi), 0.0, 1.0)
    return (1.0 - plan.field.bright if o.invert else plan.field.bright), pred


def write_transmission_png(plan: Plan, path) -> None:
    from PIL import Image, ImageDraw

    o = plan.options
    src, pred = look(plan)
    # one sample is `pitch` wide and one layer high: resize to the physical aspect
    scale = 4.0                                   # px per mm
    pw, ph = plan.field.picture_mm
    size = (max(8, int(pw * scale)), max(8, int(ph * scale)))
    ims = [Image.fromarray((a[::-1] * 255).astype(np.uint8)).resize(size, Image.Resampling.BILINEAR)
           for a in (src, pred)]
    pad, top = 10, 22
    canvas = Image.new("L", (2 * size[0] + 3 * pad, size[1] + top + pad), 128)
    d = ImageDraw.Draw(canvas)
    for i, (im, label) in enumerate(zip(ims, ("source", f"predicted, backlit (mu {o.attenuation:g}/mm)"))):
        x = pad + i * (size[0] + pad)
        canvas.paste(im, (x, top))
        d.text((x, 5), label, fill=255)
    buf = __import__("io").BytesIO()
    canvas.save(buf, format="PNG")
    _write_atomic(path, buf.getvalue(), binary=True)


def plan_stats(plan: Plan, stl_volume: float) -> dict:
    """Figures of the plan (the G-code follows it piece by piece)."""
    o, fld = plan.options, plan.field
    area = o.filament_area
    by_kind: dict[str, dict] = {}
    moves = 0
    capped_t = total_mid_t = capped_len = mid_len = 0.0
    for k, L in enumerate(plan.layers):
        for s in L.sections:
            seg = np.linalg.norm(np.diff(s.pts, axis=0), axis=1)
            laid = s.e > 0
            d = by_kind.setdefault(s.kind, {"length_mm": 0.0, "filament_mm": 0.0, "time_s": 0.0, "moves": 0})
            d["length_mm"] += float(seg[laid].sum())
            d["filament_mm"] += float(s.e.sum())
            d["time_s"] += float((seg[laid] / s.v[laid]).sum()) + float((seg[~laid] / o.travel_speed).sum())
            d["moves"] += int(laid.sum())
            moves += int(laid.sum())
            if s.kind == "mid-line" and laid.any():
                tm = seg[laid] / s.v[laid]
                flow = o.mid_flow * (o.first_layer_speed / o.wall_speed if k == 0 else 1.0)
                cap = _capped(s, o, flow)[laid]
                capped_t += float(tm[cap].sum()); total_mid_t += float(tm.sum())
                capped_len += float(seg[laid][cap].sum()); mid_len += float(seg[laid].sum())
    filament = sum(d["filament_mm"] for d in by_kind.values())
    src, pred = (a[fld.inside] for a in look(plan))               # the frame is not the picture
    r = float(np.corrcoef(src.ravel(), pred.ravel())[0, 1]) if src.std() > 0 and pred.std() > 0 else float("nan")
    t_print = printed_thickness(plan)
    pic = fld.t[fld.n_foot:]
    samples = pic.size
    return {
        "shape": o.shape,
        "layers": len(plan.layers),
        "samples_per_layer": int(len(fld.s)),
        "size_mm": {"picture_width": round(fld.picture_mm[0], 3), "picture_height": round(fld.picture_mm[1], 3),
                    "height": round(plan.layers[-1].z, 3)},
        "extruding_moves": moves,
        "filament_mm": round(filament, 2),
        "deposited_mm3": round(filament * area, 2),
        "stl_volume_mm3": round(stl_volume, 2),
        "fill_ratio": round(filament * area / stl_volume, 4),
        "time_no_accel_s": round(sum(d["time_s"] for d in by_kind.values()), 1),
        "by_kind": {k: {kk: round(vv, 3) for kk, vv in d.items()} for k, d in by_kind.items()},
        "rates": {"wall_mm3_s": round(o.wall_flow, 4), "mid_line_mm3_s": round(o.mid_flow, 4),
                  "mid_line_e_mm_s": round(o.mid_flow / area, 5), "paper_rate": o.paper_rate},
        "mid_line": {
            "capped_time_share": round(capped_t / total_mid_t, 4) if total_mid_t else 0.0,
            "capped_length_share": round(capped_len / mid_len, 4) if mid_len else 0.0,
            "capped_pieces": plan.counts.get("capped_pieces", 0),
            "slivers_widened_to_min_line_mm3": round(plan.counts.get("sliver_added_mm3", 0.0), 2),
            "slivers_left_open_mm3": round(plan.counts.get("sliver_left_mm3", 0.0), 2),
            "layers_with_two_or_more": int((fld.lines > 1).sum()),
            "max_lines_per_layer": int(fld.lines.max()),
        },
        "gaps": {
            "snapped_to_walls": fld.snapped_down,
            "snapped_up_to_min_line": fld.snapped_up,
            "snapped_share": round((fld.snapped_down + fld.snapped_up) / samples, 4),
            "min_line_mm": round(o.line_min(), 4), "max_line_mm": o.max_line,
            "printed_vs_planned_thickness_max_mm": round(float(np.abs(t_print - pic).max()), 3),
        },
        "look": {"attenuation_per_mm": o.attenuation, "curve": o.curve,
                 "correlation": round(r, 4), "ssim": round(_ssim(src, pred), 4)},
    }


@dataclass
class LithoResult:
    plan: Plan
    paths: dict
    stats: dict


def make(image, outdir, name: str | None = None, progress=None, **opts) -> LithoResult:
    """Everything `bulgekit litho` writes, from a picture: NAME.litho.gcode, NAME.stock.gcode,
    NAME.stl, NAME.transmission.png, NAME.litho.json. Options: the fields of LithoOptions."""
    o = opts.pop("options", None) or LithoOptions(**opts)
    name = name or Path(os.fspath(image)).stem
    out = Path(outdir)
    plan = plan_lithophane(image, o, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    final = {"gcode": out / f"{name}.litho.gcode", "stock": out / f"{name}.stock.gcode",
             "stl": out / f"{name}.stl", "png": out / f"{name}.transmission.png",
             "json": out / f"{name}.litho.json"}
    with _Staged(final) as paths:                     # all five files or none
        V, F = body_mesh(plan)
        write_stl(V, F, paths["stl"], name=f"bulgekit lithophane {name}")
        write_gcode(plan, paths["gcode"], "litho", name)
        write_gcode(plan, paths["stock"], "stock", name)
        write_transmission_png(plan, paths["png"])
        stats = plan_stats(plan, mesh_volume(V, F))
        stats["name"] = name
        stats["image"] = os.fspath(image)
        stats["options"] = _options_dict(plan.options)
        stats.update(_estimated(paths))
        _write_atomic(paths["json"], json.dumps(stats, indent=2) + "\n")
    return LithoResult(plan, final, stats)


class _Staged:
    """Outputs written under temporary names beside their targets (NAME.EXT.xxxx.part) and
    renamed over them together at the end, with SIGINT and SIGTERM held back while renaming: a
    run that fails or is interrupted leaves no new file and the earlier ones intact."""

    def __init__(self, final: dict):
        self.final, self.tmp = final, {}

    def __enter__(self) -> dict:
        try:
            with _held():                             # no file made and not yet recorded
                for k, p in self.final.items():
                    fd, t = tempfile.mkstemp(prefix=p.name + ".", suffix=".part", dir=p.parent)
                    os.close(fd)
                    self.tmp[k] = Path(t)
        except BaseException:
            self._discard()
            raise
        return dict(self.tmp)

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            self._discard()
            return False
        try:
            with _held():
                for k in list(self.tmp):
                    os.replace(self.tmp[k], self.final[k])
                    del self.tmp[k]
        except BaseException:
            self._discard()
            raise
        return False

    def _discard(self) -> None:
        for t in self.tmp.values():
            try:
                os.unlink(t)
            except OSError:
                pass
        self.tmp.clear()


def _estimated(paths) -> dict:
    """Print time of both files by the Marlin-style estimator, when it is there."""
    try:
        from . import estimate
    except ImportError:
        return {}
    m = estimate.Machine()
    out = {}
    for key in ("gcode", "stock"):
        r = estimate.estimate_file(paths[key], m)
        out[f"estimated_time_s_{key}"] = round(r.total_s, 1)
    return {"estimate": out}
