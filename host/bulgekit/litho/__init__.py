"""Lithophanes printed with one variable-width mid-line per layer (Jang & Hong 2017, Algorithm 1).

The part stands on the bed and every layer is one row of the picture. Per layer there is the back
face (a straight line for `planar`, a circle for `cylinder`), the front face carrying the relief
(thickness from the picture: dark = thick), one wall line inside each face, and between the walls a
single mid-line whose width is the gap at every point. That width is set by head speed at one
extruder rate (firmware width mode, M723: v = q / (W * H)), so the gap fills in one pass.

    plan = litho.plan_lithophane("cat.png", LithoOptions(shape="cylinder"))
    out = litho.make("cat.png", "out/")      # .litho.gcode .stock.gcode .stl .transmission.png .json

Geometry per layer, on the sample grid (no polygon offsets): every sample has a probe across
the layer (vertical for planar, radial for cylinder) from the back face to the relief at
thickness t. Along it lie three bands: the back wall [0, wb], the mid-line [wb, t - wf] and the
front wall [t - wf, t], wb = wf = one line width unless said below. The bands between two
samples are trapezoids (in polar form for the cylinder), so together they are exactly the body
the STL holds, and each piece lays its band's area (width = area / length: the filament is the
body's volume). Only the split between the lines changes below, never the thickness.

  - A gap t - 2 w narrower than a printable mid-line (`min_line`, by default the narrowest line
    the mid-line's rate lays at `max_speed`, q / (U * H), but at least half a line) is not
    snapped. light_gaps "mid-line" (default): the walls narrow (to wall_min at least) so that a
    mid-line of min_line x (1 + MID_MARGIN) runs on unbroken. light_gaps "walls": the two walls
    widen by half of it each (ww = w + gap / 2) and lay it at their own rate (width by feedrate:
    v = q_wall / (W * H)). Mid-line pieces narrower than min_line give their area to the walls.
  - With `rate_accel` (light_gaps "mid-line") the mid-line's width, so its speed, is planned
    along the layer as a planner plans speeds (_steady_walls): small steps from sample to sample,
    a centre line that turns little; the walls (wall_min .. wall_max, back and front apart) take
    what the picture changes faster than that, so the extruder runs at its set rate through
    the planner's ramps.
  - A wall along a slope is longer than its band is wide; it keeps its width (so its speed) and
    takes what it lays beyond its band from the mid-line beside it.
  - Wider than `max_line`: the layer gets n = ceil(gap / max_line) mid-lines of gap / n each.
  - Pieces merge where they run on straight (a line within CHORD_TOL of every point they
    replace, its ends free) at one width (the merged width and area per sample within WIDTH_TOL
    of every piece's), none is shorter than MIN_MOVE (6 steps), and with `block_rate` none is
    shorter than its speed / block_rate: short pieces merge with their neighbours (area summed:
    the volume is kept).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from . import tone
from .. import machine
from .. import outputs
from ..errors import BulgekitError
from ..machine import PrinterModel

SHAPES = ("planar", "cylinder")
CURVES = tone.CURVES
WORDS = ("e", "w")
LIGHT_GAPS = ("mid-line", "walls")

# The mid-line's default rate. Where a layer's mid-line starts and stops, the head ramps its speed
# and the extruder's rate with it; those ramps take a share of the mid-line's time that grows as
# v^2 / (a L) (v = q / (W H), a the acceleration, L the stretch). 8 mm^3/s keeps >= 85 % of a
# photo band's mid-line time within 5 % of the set rate at 3000 mm/s^2 (Marlin's default M204 P);
# a printer that accelerates less gets q x sqrt(a / 3000), which keeps that share
# (docs/lithophane.md, "Extruder rate on the mid-line, verified").
INFILL_FLOW = 8.0       # mm^3/s
FLOW_ACCEL = 3000.0     # mm/s^2


def default_flow(accel: float) -> float:
    """The mid-line's rate when infill_flow is not given, for a printer accelerating at accel."""
    if not (isinstance(accel, (int, float)) and math.isfinite(accel) and accel > 0):
        return INFILL_FLOW                  # check_options names --accel
    return round(INFILL_FLOW * min(1.0, math.sqrt(accel / FLOW_ACCEL)), 2)


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
    curve: str = "perceptual"       # tone curve (litho_tone): perceptual, linear, transmission
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
    light_gaps: str = "mid-line"    # a gap narrower than a mid-line: "mid-line" (the walls narrow and
                                    # a thin mid-line runs on) or "walls" (the walls widen and share it)
    rate_accel: float = 1000.0      # mm/s^2 the mid-line's speed changes are planned for (light_gaps
                                    # "mid-line"): the walls take faster changes (0: off); at most accel
    accel: float = FLOW_ACCEL       # mm/s^2, the printer's print acceleration (M204 P): the estimate's,
                                    # and below FLOW_ACCEL it lowers the default infill_flow (default_flow)
    block_rate: float = 120.0       # blocks/s the board plans: no piece shorter than speed / rate (0: off)
    filament: float = 1.75
    wall_speed: float = 40.0        # mm/s
    infill_flow: float | None = None  # mm^3/s, the mid-line's volumetric rate (None: default_flow(accel))
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
    printer: PrinterModel = machine.DEFAULT   # the printer the estimate plans for (its accelerations
                                    # at `accel`)

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
    def flow(self) -> float:
        """The mid-line's rate unless paper_rate: infill_flow, or default_flow(accel)."""
        if self.infill_flow is not None:
            return self.infill_flow
        return default_flow(self.accel)

    @property
    def plan_accel(self) -> float:
        """What the mid-line's speed changes are planned for: rate_accel, but no more than the
        printer's acceleration (0: not planned)."""
        return min(self.rate_accel, self.accel) if self.rate_accel > 0 else 0.0

    @property
    def wall_flow(self) -> float:
        return self.line_width * self.layer_height * self.wall_speed

    @property
    def mid_flow(self) -> float:
        return self.wall_flow if self.paper_rate else self.flow


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
    if o.light_gaps not in LIGHT_GAPS:
        bad("light-gaps", f"{o.light_gaps!r} is not one of {', '.join(LIGHT_GAPS)}")
    positive = {"width": o.width, "diameter": o.diameter, "layer-height": o.layer_height,
                "line-width": o.line_width, "pitch": o.pitch, "filament": o.filament,
                "wall-speed": o.wall_speed, "infill-flow": o.flow, "accel": o.accel, "max-speed": o.max_speed,
                "min-speed": o.min_speed, "first-layer-speed": o.first_layer_speed,
                "travel-speed": o.travel_speed, "z-speed": o.z_speed, "gamma": o.gamma,
                "attenuation": o.attenuation, "min-line": o.line_min(), "max-line": o.max_line,
                "min": o.min_thickness, "max": o.max_thickness}
    for k, v in positive.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            bad(k, f"must be a number > 0, got {v}")
    if o.height is not None and not (math.isfinite(o.height) and o.height > 0):
        bad("height", f"must be a number > 0, got {o.height}")
    for k, v in {"block-rate": o.block_rate, "rate-accel": o.rate_accel, "frame": o.frame, "foot": 0.0 if o.foot is None else o.foot,
                 "foot-height": o.foot_height, "retract": o.retract, "retract-min": o.retract_min}.items():
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
    t: np.ndarray            # (layers, samples) mm; foot layers hold the foot depth
    bright: np.ndarray       # (image layers, samples) the picture's lightness L*/100 (0 black, 1 white;
                             # area average in linear light, before --invert) on the same grid
    s: np.ndarray            # sample positions: x mm (planar) or angle rad (cylinder)
    n_foot: int              # layers of foot at the bottom (planar)
    lines: np.ndarray        # mid-lines per layer
    shared: int              # picture samples whose gap is narrower than a mid-line: the walls share it
    narrowed: int            # ... where instead the walls narrow so that a thin mid-line runs on
    ww: np.ndarray           # (layers, samples) back wall's width, mm (wall_widths)
    wf: np.ndarray           # ... the front wall's
    picture_mm: tuple        # (width or circumference, height) of the picture, mm
    inside: tuple            # (rows, samples) slices of the picture inside the frame
    foot: float = 0.0        # depth of the foot, mm (0: none)

    @property
    def layers(self) -> int:
        return self.t.shape[0]


def thickness_field(image, o: LithoOptions) -> Field:
    check_options(o)
    Y_px = tone.read_luminance(image)
    h_px, w_px = Y_px.shape
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
    # the pixels under each sample averaged in linear light; row 0 is the picture's top
    Y = tone.resample(Y_px, (n, rows))[::-1].copy()     # layer order: bottom of the picture first
    t = tone.thickness(Y, o.curve, o.min_thickness, o.max_thickness, o.attenuation, o.gamma, o.invert)
    return _field(t, tone.lightness(Y) / 100.0, s, o, pic_w)


MID_MARGIN = 0.1        # a kept mid-line is this much wider than min_line: slopes and the
                        # walls' share (_layer_paths) narrow it a little, and it must stay laid


RATE_STEP = 0.06        # the mid-line's speed changes by at most this share from sample to sample
CENTRE_SLOPE = 0.2      # the mid-line's centre moves at most this much across per mm along
RATE_ACCEL_SHARE = 0.3  # ... and by at most what this share of rate_accel gains over the piece
BACK_SLACK = 0.05       # mm the front wall keeps above wall_min on the thinnest plate (back_wall)
FRONT_HOLD = 1.25       # line widths: the mid-line holds its width while the front wall stays
                        # between wall_min and this (_held_gap)


def wall_min(o: LithoOptions) -> float:
    """The narrowest wall line: half a line width (what the nozzle still lays as a line)."""
    return o.line_width / 2


def wall_max(o: LithoOptions, front: bool = True) -> float:
    """The widest wall line when the walls take what the mid-line cannot follow: the front wall
    (along the relief) two line widths, the back wall one. A back wall never wider than a line
    keeps the plain back face in few pieces and leaves the mid-line's centre its room on the
    back's side; the front wall, slower when wide (width by feedrate), takes the picture's steps.
    Measured on the astronaut band (estimator, share of mid-line time within +-5 %, 1000 / 3000
    mm/s^2): both walls up to 1.5 line widths 74.5 / 92.5 %, back 1 and front 2: 80.3 / 93.6 %,
    and 5 % fewer moves on astro.png (docs/lithophane.md)."""
    return (2.0 if front else 1.0) * o.line_width


def _steady(zt, lo, hi, d, closed):
    """A sequence z (per row, along the samples) near the target zt, within [lo, hi], that changes
    by at most d[i] between samples i and i + 1 where the band allows (log widths: the bound is on
    the speed's ratio). The band is first narrowed to what a sequence so limited can follow
    (forward and backward passes, as a planner limits speeds), then the target is followed from
    the left and from the right and the two averaged: both lie in the narrowed band and keep the
    steps, so their mean does too (it is convex in log width), and a step of the target becomes
    a ramp centred on it. Closed (cylinder) rows wrap: they are run three times round and the
    middle turn kept."""
    if closed:
        n = zt.shape[1]
        tile = lambda a: np.concatenate([a, a, a], axis=1)
        return _steady(tile(zt), tile(lo), tile(hi), np.concatenate([d, d, d], axis=1), False)[:, n:2 * n]
    U, L = hi.copy(), lo.copy()
    m = zt.shape[1]
    for i in range(1, m):
        U[:, i] = np.minimum(U[:, i], U[:, i - 1] + d[:, i - 1])
        L[:, i] = np.maximum(L[:, i], L[:, i - 1] - d[:, i - 1])
    for i in range(m - 2, -1, -1):
        U[:, i] = np.minimum(U[:, i], U[:, i + 1] + d[:, i])
        L[:, i] = np.maximum(L[:, i], L[:, i + 1] - d[:, i])
    ok = L <= U
    L, U = np.where(ok, L, lo), np.where(ok, U, hi)          # no room: the band as it is
    f, b = zt.copy(), zt.copy()
    f[:, 0] = np.clip(zt[:, 0], L[:, 0], U[:, 0])
    for i in range(1, m):
        f[:, i] = np.clip(np.clip(zt[:, i], f[:, i - 1] - d[:, i - 1], f[:, i - 1] + d[:, i - 1]), L[:, i], U[:, i])
    b[:, -1] = np.clip(zt[:, -1], L[:, -1], U[:, -1])
    for i in range(m - 2, -1, -1):
        b[:, i] = np.clip(np.clip(zt[:, i], b[:, i + 1] - d[:, i], b[:, i + 1] + d[:, i]), L[:, i], U[:, i])
    return np.clip((f + b) / 2, lo, hi)


def wall_widths(t: np.ndarray, lines, o: LithoOptions, steps=None) -> tuple:
    """Back and front wall widths per sample of thickness t with `lines` mid-lines, and where the
    gap g = t - 2 w is narrower than those lines (n x min_line): (wb, wf, shared, narrowed).
    light_gaps "walls": the two walls widen by g / 2 each and share the gap (shared).
    light_gaps "mid-line": the walls narrow (not below wall_min) so that the mid-line keeps
    n x min_line x (1 + MID_MARGIN) and runs on unbroken through light areas (narrowed); the
    layer's thickness is the same either way, only the split between the lines differs. Where
    even the narrowest walls leave no room, they widen and share as with "walls". With
    rate_accel and `steps` (t 2-D) the widths are then planned for a steady mid-line
    (_steady_walls); otherwise the two walls are equal."""
    w = o.line_width
    g = np.maximum(t - 2 * w, 0.0)
    need = lines * o.line_min()
    short = g < need - 1e-9
    narrowed = np.zeros(t.shape, bool)
    ww = np.full(t.shape, w, dtype=float)
    if o.light_gaps == "mid-line":
        wn = w - (need * (1 + MID_MARGIN) - g) / 2
        narrowed = short & (wn >= wall_min(o) - 1e-9)
        ww = np.where(narrowed, wn, ww)
    shared = short & ~narrowed & (g > 1e-9)
    ww = np.where(shared, w + g / 2, ww)
    wf = ww
    if o.light_gaps == "mid-line" and o.plan_accel > 0 and steps is not None and t.ndim == 2:
        ww, wf = _steady_walls(t, ww, shared, np.broadcast_to(lines, t.shape[:1] + (1,)), o, steps)
    return ww, wf, shared, narrowed


def back_wall(o: LithoOptions) -> float:
    """The back wall's one width when the mid-line's speed is planned: as wide as the thinnest
    plate (--min) allows beside a thin mid-line (min_line x (1 + MID_MARGIN)) and a front wall
    BACK_SLACK wider than wall_min, never wider than a line nor narrower than wall_min; at the
    defaults 0.257 mm. One width keeps the plain back face in few pieces, and a narrow back wall
    leaves the mid-line and the front wall the room to take the picture (docs/lithophane.md:
    with the held mid-line, astro.png's moves 163,050 -> 139,438 and its print 3 % shorter)."""
    need = o.line_min() * (1 + MID_MARGIN)
    return float(np.clip(o.min_thickness - need - wall_min(o) - BACK_SLACK, wall_min(o), o.line_width))


def _held_gap(lo, hi):
    """Per row, a sequence inside [lo, hi] that changes only where it must, and then no more
    than it must (it is clipped into the band): the mid-line's width held while the front wall
    beside it can take the picture's changes. Starts mid-band."""
    q = np.empty_like(lo)
    p = (lo[:, 0] + hi[:, 0]) / 2
    for i in range(lo.shape[1]):
        p = np.clip(p, lo[:, i], hi[:, i])
        q[:, i] = p
    return q


def _steady_walls(t, ww, shared, lines, o: LithoOptions, steps):
    """Wall widths that let the mid-line keep a steady extruder rate, in few pieces.

    The back wall keeps one width (back_wall). The mid-line's width is held while the front wall
    beside it stays between wall_min and FRONT_HOLD line widths (_held_gap), so the picture's
    detail goes to the front wall, which follows the relief and is cut at every sample anyway;
    the held mid-line and the plain back wall merge into long pieces. Then the mid-line's speed
    (q / (W H), W the gap per line) is limited to change from sample to sample by at most
    RATE_STEP, and by no more than RATE_ACCEL_SHARE of what `rate_accel` gains over the piece
    (v2^2 - v1^2 <= 2 a L), so the planner's ramps between pieces stay inside the +-5 % band.
    Its centre moves across by at most CENTRE_SLOPE per mm (every turn costs speed at a
    junction); where that or a step of the picture does not fit, the back wall gives way (within
    wall_min .. one line) and the front wall (wall_min .. wall_max) takes the rest of each
    sample's thickness. The layer's thickness is unchanged; only the split between the lines
    moves. `steps`: the mid-line's length per sample interval, mm (rows, samples - 1, or
    samples when closed)."""
    H, q = o.layer_height, o.mid_flow
    nl = lines.astype(float)
    wmin, back_max, front_max = wall_min(o), wall_max(o, front=False), wall_max(o)
    lo = np.maximum(t - back_max - front_max, nl * o.line_min() * (1 + MID_MARGIN))
    hi = np.minimum(t - 2 * wmin, nl * o.max_line)
    free = (lo < hi) & ~shared
    lo, hi = np.where(free, lo, t - 2 * ww), np.where(free, hi, t - 2 * ww)
    back = back_wall(o)
    # the mid-line's width, held while the front wall can take the picture
    h_lo = np.maximum(lo, t - back - FRONT_HOLD * o.line_width)
    h_hi = np.minimum(hi, t - back - wmin)
    held = free & (h_lo < h_hi)
    gm = np.where(held, _held_gap(np.where(held, h_lo, lo), np.where(held, h_hi, hi)),
                  np.clip(t - 2 * ww, lo, hi))
    closed = o.shape == "cylinder"
    nxt = np.roll(gm, -1, axis=1) if closed else gm[:, 1:]
    v = q * nl / (np.minimum(gm if closed else gm[:, :-1], nxt) * H)   # the faster of the two pieces
    d = np.minimum(math.log1p(RATE_STEP), RATE_ACCEL_SHARE * o.plan_accel * steps / np.maximum(v, 1e-9) ** 2)
    gm = np.where(free, np.exp(_steady(np.log(gm), np.log(lo), np.log(hi), d, closed)), gm)
    # The mid-line's centre c = back + gm / 2 where it can (the back wall at its width); with a
    # slope of at most CENTRE_SLOPE.
    c_lo = np.maximum(wmin + gm / 2, t - gm / 2 - front_max)
    c_hi = np.minimum(back_max + gm / 2, t - gm / 2 - wmin)
    c0 = np.clip(back + gm / 2, c_lo, c_hi)
    okc = free & (c_lo <= c_hi)
    c_lo, c_hi = np.where(okc, c_lo, c0), np.where(okc, c_hi, c0)
    c = _steady(c0, c_lo, c_hi, np.broadcast_to(CENTRE_SLOPE * steps, d.shape), closed)
    wb = np.where(free, c - gm / 2, ww)
    wf = np.where(free, t - c - gm / 2, ww)
    return wb, wf


def _field(t: np.ndarray, bright: np.ndarray, s: np.ndarray, o: LithoOptions, pic_w: float) -> Field:
    """The field from the picture's thickness (rows, samples): frame, gaps, foot."""
    rows, n = t.shape
    tmax = o.max_thickness
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
    # Gaps narrower than a printable mid-line are not snapped: the two walls widen and share them
    # (_layer_paths). The per-layer line count comes first: a layer whose widest gap needs two
    # lines lays a mid-line only where the gap is at least 2 * min_line.
    w2 = 2 * o.line_width
    gap = np.maximum(t - w2, 0.0)
    lines = np.maximum(1, np.ceil(gap.max(axis=1) / o.max_line - 1e-9)).astype(int)
    if o.shape == "planar":
        steps = np.broadcast_to(np.diff(s), (rows, n - 1))
    else:                                              # along the mid-line's circle
        r_mid = o.diameter / 2 - o.max_thickness + t / 2
        steps = r_mid * (2 * math.pi / n)
    ww, wf, shared, narrowed = wall_widths(t, lines[:, None], o, steps)
    n_foot = 0
    foot = foot_depth(o, rows * o.layer_height)
    if o.shape == "planar" and foot > 0 and o.foot_height > 0:
        n_foot = max(1, int(round(o.foot_height / o.layer_height)))
        t = np.vstack([np.full((n_foot, n), foot), t])
        foot_lines = max(1, math.ceil((foot - w2) / o.max_line - 1e-9))
        lines = np.concatenate([np.full(n_foot, foot_lines), lines])
    if n_foot:
        ww = np.vstack([np.full((n_foot, n), o.line_width), ww])
        wf = np.vstack([np.full((n_foot, n), o.line_width), wf])
    return Field(t=t, bright=bright, s=s, n_foot=n_foot, lines=lines, shared=int(shared.sum()),
                 narrowed=int(narrowed.sum()), ww=ww, wf=wf, picture_mm=(pic_w, rows * o.layer_height), inside=inside, foot=foot if n_foot else 0.0)


def calibration_field(o: LithoOptions) -> tuple[Field, dict]:
    """The calibration plate (`--calibration`): a planar step wedge from --min to --max, each
    step's planned thickness written under it in raised digits (litho_tone.calibration_map), and
    the steps' figures for the JSON. The labels give the thickness as planned, after the gap
    handling, so they are what is printed."""
    check_options(o)
    if o.shape != "planar":
        raise LithoError("--calibration: the calibration plate is planar; leave out --shape cylinder")
    pic_w, pic_h = tone.calibration_size()
    n = int(round(pic_w / o.pitch)) + 1
    s = np.linspace(0.0, pic_w, n)
    rows = int(round(pic_h / o.layer_height))
    z = (np.arange(rows) + 0.5) * o.layer_height            # field row 0 is the bottom layer
    steps = tone.calibration_steps(o.min_thickness, o.max_thickness)
    centres = [((a0 + a1) / 2, (b0 + b1) / 2) for (a0, a1, b0, b1), _ in tone.calibration_layout()]
    ij = [(int(np.argmin(np.abs(z - zc))), int(np.argmin(np.abs(s - xc)))) for xc, zc in centres]

    def field(labels):
        t = tone.calibration_map(s, z, steps, o.min_thickness, o.max_thickness, labels)
        # the picture each thickness stands for: what the plate shows, on the look's scale
        L_lo, _ = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
        L = tone.lightness(tone.plate_luminance(t, o.attenuation, o.min_thickness))
        return _field(t, (L - L_lo) / (100.0 - L_lo), s, replace(o, frame=0.0), pic_w)   # its own frame

    planned = [float(field(None).t[i, j]) for i, j in ij]
    fld = field([f"{t:.2f}" for t in planned])
    assert [float(fld.t[i, j]) for i, j in ij] == planned
    y = tone.plate_luminance(np.array(planned), o.attenuation, o.min_thickness)
    info = {"steps": [{"step": k + 1, "thickness_mm": float(steps[k]), "planned_mm": round(planned[k], 3),
                       "relative_luminance": round(float(y[k]), 4),
                       "predicted_L": round(float(tone.lightness(y[k])), 2)} for k in range(len(steps))],
            "attenuation_per_mm": o.attenuation,
            "size_mm": [pic_w, rows * o.layer_height]}
    return fld, info


# --- per-layer paths -----------------------------------------------------------------------

CHORD_TOL = 0.01       # mm: how far a merged piece may stray from the points it replaces
WIDTH_TOL = 0.005      # pieces merge only where their widths agree within this share
MIN_MOVE = 0.075       # mm: 6 steps at 80 steps/mm, the shortest move Marlin executes
ROUNDING = 0.0015      # mm: a move written to 0.001 mm in X and Y is up to this much shorter


@dataclass
class Section:
    """One continuous extrusion path: points (k, 2) in part coordinates (mm), filament per piece
    (k - 1,) in mm, head speed per piece (mm/s), and the kind: wall, mid-line, connector.
    `u` is each point's place along the layer in samples (for volume checks)."""
    kind: str
    pts: np.ndarray
    e: np.ndarray
    v: np.ndarray
    width: np.ndarray          # line width per piece (mm): deposited area / length
    u: np.ndarray | None = None


@dataclass
class Layer:
    z: float
    sections: list
    gap: np.ndarray            # the mid-line band's extent across the layer per sample (mm)
    wall: np.ndarray           # each wall's band across the layer per sample (mm): line width + share


@dataclass
class Plan:
    options: LithoOptions
    field: Field
    layers: list = field(default_factory=list)
    origin: tuple = (0.0, 0.0)     # bed position of the part's (0, 0)
    counts: dict = field(default_factory=dict)


def _layer_polygon(o: LithoOptions, fld: Field, k: int):
    """The layer's cross-section (shapely), as the STL has it."""
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


def _speeds(width, o: LithoOptions, flow):
    """Head speed for a line of width W at volumetric rate q: v = q / (W * H) (eq. 1), capped."""
    with np.errstate(divide="ignore"):
        v = flow / np.maximum(width * o.layer_height, 1e-12)
    return np.clip(v, o.min_speed, o.max_speed)


def _capped(s: Section, o: LithoOptions, flow) -> np.ndarray:
    """Laid pieces whose speed was capped: their volumetric rate W * H * v is below the flow."""
    return (s.e > 0) & (s.width * o.layer_height * s.v < flow * (1 - 1e-6))


class _Band:
    """Points across the layer on each sample's probe (planar: vertical lines at x; cylinder:
    radial lines at angle s), and the area of a band between two probes. Everything in a layer
    is a band between two offsets from the back face, so the bands add up to the body exactly
    (the STL is linear between samples too)."""

    def __init__(self, o: LithoOptions, fld: Field, k: int, x=None):
        self.o, self.closed = o, o.shape == "cylinder"
        if self.closed:
            self.r_in = o.diameter / 2 - o.max_thickness
            self.c, self.sn = np.cos(fld.s), np.sin(fld.s)
            self.dth = 2 * math.pi / len(fld.s)
        else:
            self.x = fld.s if x is None else x
            self.y0 = (o.max_thickness - o.foot) / 2 if k < fld.n_foot else 0.0

    def points(self, off):
        """Points at `off` mm from the back face (per sample); a closed band repeats its first."""
        if self.closed:
            r = self.r_in + off
            p = np.column_stack([r * self.c, r * self.sn])
            return np.vstack([p, p[:1]])
        return np.column_stack([self.x, self.y0 + off])

    def area(self, lo, hi):
        """Area (mm^2) of the band between offsets lo and hi, per piece between samples."""
        h = hi - lo
        if self.closed:
            hr = h * (self.r_in + (lo + hi) / 2)             # exact for an annulus sector
            hr = np.append(hr, hr[:1])
            return (hr[:-1] + hr[1:]) / 2 * self.dth
        return (h[:-1] + h[1:]) / 2 * np.abs(np.diff(self.x))


def _width_runs(seg, area, laid, du) -> np.ndarray:
    """Where runs of pieces that may merge start (and the end): a run is all laid or all not, and
    in a laid run the merged piece's width (area / length) and its area per sample interval
    (area / du, what each sample it spans gets) stay within WIDTH_TOL of every member's,
    greedily as long as they can. Neighbours that differ a little merge wherever they lie, not
    only inside a fixed bin. A piece across the layer (du = 0: a planar plate's end) stands
    alone."""
    n = len(seg)
    with np.errstate(divide="ignore", invalid="ignore"):
        wd = np.where(seg > 1e-12, area / seg, 0.0)
        pu = np.where(du > 1e-9, area / du, -1.0)
    # runs of one width and one area per sample (the plain wall, flat areas) are taken as one
    # item: the loop below sees only where they change
    step = np.flatnonzero((laid[1:] != laid[:-1]) | (np.abs(wd[1:] - wd[:-1]) > 1e-9 * wd[1:])
                          | (np.abs(pu[1:] - pu[:-1]) > 1e-9 * np.abs(pu[1:])) | (pu[1:] < 0))
    first = np.concatenate([[0], step + 1])
    A, L, U = (np.add.reduceat(x, first).tolist() for x in (area, seg, du))
    W, P, on = wd[first].tolist(), pu[first].tolist(), laid[first].tolist()
    lo_tol, hi_tol = 1 - WIDTH_TOL, 1 + WIDTH_TOL
    starts = [0]
    a = l_ = u_ = wlo = whi = plo = phi = 0.0
    state = None
    for i, (ai, li, ui, wi, pi, oi) in enumerate(zip(A, L, U, W, P, on)):
        if oi != state or pi < 0 or plo < 0:
            starts.append(i)
            state, a, l_, u_, wlo, whi, plo, phi = oi, ai, li, ui, wi, wi, pi, pi
            continue
        if not oi:
            continue
        a2, l2, u2 = a + ai, l_ + li, u_ + ui
        wlo2 = wi if wi < wlo else wlo
        whi2 = wi if wi > whi else whi
        plo2 = pi if pi < plo else plo
        phi2 = pi if pi > phi else phi
        w, pm = a2 / (l2 if l2 > 1e-12 else 1e-12), a2 / u2
        if w > wlo2 * hi_tol or w < whi2 * lo_tol or pm > plo2 * hi_tol or pm < phi2 * lo_tol:
            starts.append(i)
            a, l_, u_, wlo, whi, plo, phi = ai, li, ui, wi, wi, pi, pi
        else:
            a, l_, u_, wlo, whi, plo, phi = a2, l2, u2, wlo2, whi2, plo2, phi2
    b = first[np.unique(starts)]
    return np.append(b, n)


def _line_end(px, py, sx, sy, th, j, last):
    """Where a merged piece from (sx, sy) at angle th ends beside point j: on its line within
    CHORD_TOL of the point, and there as far from point j + 1 as point j is (the next piece keeps
    its length, so its width, if it stays alone), else as near that as the tolerance allows."""
    c, sn = math.cos(th), math.sin(th)
    ox, oy = px[j] - sx, py[j] - sy
    d = ox * c + oy * sn                            # point j's foot on the line
    h2 = (ox * sn - oy * c) ** 2
    if j == last or h2 >= CHORD_TOL ** 2:
        return sx + d * c, sy + d * sn
    room = math.sqrt(CHORD_TOL ** 2 - h2)          # the line's stretch within the tolerance
    qx, qy = sx - px[j + 1], sy - py[j + 1]
    L2 = (px[j + 1] - px[j]) ** 2 + (py[j + 1] - py[j]) ** 2
    b = qx * c + qy * sn                            # |E - point j + 1|^2 = (t + b)^2 + const
    disc = b * b - (qx * qx + qy * qy) + L2
    if disc >= 0:                                   # the root nearer point j's foot
        r = math.sqrt(disc)
        t = -b - r if abs(-b - r - d) < abs(-b + r - d) else -b + r
    else:                                           # no such place: the nearest approach
        t = -b
    if t < d - room:
        t = d - room
    elif t > d + room:
        t = d + room
    return sx + t * c, sy + t * sn


def _sleeve(px, py, runs, last, keep, ox, oy):
    """Merged pieces over each run (i0, i1) of points (lists px, py), each within CHORD_TOL of
    every point it replaces: from its start, the longest run of points that one line can pass
    within the tolerance of (the directions each point allows, intersected), ending on that line
    beside its last point (so not always on a point: _line_end). Ends are written to ox, oy
    (the points' places, given as px, py) and marked in `keep`; the path's last point (`last`)
    stays where it is. A run starts from ox[i0], oy[i0] (where the run before it ended)."""
    tol, inf, pi, two_pi = CHORD_TOL, math.inf, math.pi, 2 * math.pi
    hypot, atan2, asin = math.hypot, math.atan2, math.asin
    for i0, i1 in runs:
        sx, sy = ox[i0], oy[i0]
        lo, hi = -inf, inf
        ref = None
        j = i0 + 1
        while j <= i1:
            qx, qy = px[j] - sx, py[j] - sy
            r = hypot(qx, qy)
            if r > tol:
                phi = atan2(qy, qx)
                if ref is not None:                 # the same turn as the cone
                    if phi - ref > pi:
                        phi -= two_pi
                    elif ref - phi > pi:
                        phi += two_pi
                da = 0.0 if j == last else asin(tol / r)
                nlo, nhi = phi - da, phi + da
                if nlo < lo:
                    nlo = lo
                if nhi > hi:
                    nhi = hi
                if nlo > nhi:
                    # (a fresh cone takes any point: here at least one lies between start and j)
                    # the line ends beside point j - 1; the next one starts there
                    e = _line_end(px, py, sx, sy, (lo + hi) / 2, j - 1, last)
                    sx, sy = ox[j - 1], oy[j - 1] = e
                    keep[j - 1] = True
                    lo, hi, ref = -inf, inf, None
                    continue
                lo, hi = nlo, nhi
                if ref is None:
                    ref = phi
            j += 1
        # the run's end: on the line beside point i1 (the path's last point: on it)
        if i1 != last and ref is not None:
            ox[i1], oy[i1] = _line_end(px, py, sx, sy, (lo + hi) / 2, i1, last)
        keep[i1] = True


def _keep_straight(pts, area, laid, u):
    """Points to keep when neighbouring pieces merge, and where they are: pieces run on as one
    where they are laid at one width (the merged width within WIDTH_TOL of every piece's,
    _width_runs) or not laid, and the path strays no more than CHORD_TOL from the points it
    drops (_sleeve). Returns (keep, points)."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    bounds = _width_runs(seg, area, laid, np.abs(np.diff(u)))
    keep = np.zeros(len(pts), bool)
    keep[bounds] = True
    multi = np.flatnonzero(np.diff(bounds) > 1)
    if not len(multi):
        return keep, pts
    px, py = pts[:, 0].tolist(), pts[:, 1].tolist()
    ox, oy = px[:], py[:]                           # where the points are after the merge
    last = len(pts) - 1
    _sleeve(px, py, zip(bounds[multi].tolist(), bounds[multi + 1].tolist()), last, keep, ox, oy)
    orig, pts = pts, np.column_stack([ox, oy])
    k = np.flatnonzero(keep)
    # A merged piece's width is its area over its chord, a little shorter than the path, and a
    # run the chord split has widths of its own: where a merged piece is off a member by more
    # than the tolerance, it keeps all its points.
    chord = np.linalg.norm(pts[k[1:]] - pts[k[:-1]], axis=1)
    on = laid[k[:-1]] & (np.diff(k) > 1)
    if on.any():
        du = np.abs(np.diff(u))
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.add.reduceat(area, k[:-1])
            bad = np.zeros(len(a), bool)
            # the width on the chord, and the area per sample interval, against every member's
            for per, merged in ((seg, chord), (du, np.add.reduceat(du, k[:-1]))):
                each = np.where(laid, area / np.maximum(per, 1e-12), 0.0)
                m = a / np.maximum(merged, 1e-12)
                lo, hi = np.minimum.reduceat(each, k[:-1]), np.maximum.reduceat(each, k[:-1])
                bad |= (m > lo * (1 + WIDTH_TOL)) | (m < hi * (1 - WIDTH_TOL))
        bad = np.flatnonzero(on & bad)
        for j in bad.tolist():
            keep[k[j]:k[j + 1]] = True
    # A piece left on its own beside a moved end is longer or shorter by the move: where that
    # puts its width off by more than the tolerance, the end goes back to its point, and the
    # merged pieces that end also ends keep all their points (so they stay on the tolerance).
    with np.errstate(divide="ignore", invalid="ignore"):
        wd = area / np.maximum(seg, 1e-12)
    moved = np.any(pts != orig, axis=1)
    while moved.any():
        k = np.flatnonzero(keep)
        i = k[:-1][(np.diff(k) == 1) & laid[k[:-1]]]
        w = area[i] / np.maximum(np.linalg.norm(pts[i + 1] - pts[i], axis=1), 1e-12)
        bad = i[np.abs(w - wd[i]) > WIDTH_TOL * wd[i]]
        ends = np.union1d(bad, bad + 1)
        ends = ends[moved[ends]]
        if not len(ends):
            break
        for e in ends.tolist():
            pts[e], moved[e] = orig[e], False
            pos = int(np.searchsorted(k, e))
            if pos > 0:
                keep[k[pos - 1]:e] = True
            if pos < len(k) - 1:
                keep[e:k[pos + 1]] = True
    return keep, pts


def _long_enough(pts, area, laid, o: LithoOptions, flow, rate):
    """Points to keep so that every laid piece is at least MIN_MOVE long as written (ROUNDING)
    and, with a block-rate budget, no shorter than its speed / rate: short pieces merge with
    their laid neighbours (the areas add up, width = area / length, so the volume is kept). Also
    the pieces of laid runs that cannot be made long enough at all (too short in total)."""
    n = len(area)
    keep = np.ones(n + 1, bool)
    lonely = np.zeros(n, bool)
    L = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    H = o.layer_height
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.clip(flow * L / np.maximum(area * H, 1e-12), o.min_speed, o.max_speed)
    need = np.maximum(MIN_MOVE + ROUNDING, v / rate) if rate else np.full(n, MIN_MOVE + ROUNDING)
    short = laid & (L < need - 1e-9)
    if not short.any():
        return keep, lonely
    # runs of laid pieces that hold a short one
    edge = np.diff(np.concatenate([[0], laid.astype(np.int8), [0]]))
    r0, r1 = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
    has = np.add.reduceat(short.astype(int), r0) > 0 if len(r0) else []
    px, py, al = pts[:, 0].tolist(), pts[:, 1].tolist(), area.tolist()
    lo, hi, inv_rate = o.min_speed, o.max_speed, (1.0 / rate if rate else 0.0)
    for i, j in zip(r0[has], r1[has]):
        groups, s, acc = [], i, 0.0
        for q in range(i, j):
            acc += al[q]
            ln = math.hypot(px[q + 1] - px[s], py[q + 1] - py[s])
            sp = min(max(flow * ln / max(acc * H, 1e-12), lo), hi)
            if ln >= max(MIN_MOVE + ROUNDING, sp * inv_rate) - 1e-9:
                groups.append((s, q + 1))
                s, acc = q + 1, 0.0
        if s < j:                                   # a short tail joins the group before it
            if not groups:
                lonely[i:j] = True
                continue
            groups[-1] = (groups[-1][0], j)
        for g0, g1 in groups:
            keep[g0 + 1:g1] = False
    return keep, lonely


def _pieces(kind, pts, area, laid, u, o: LithoOptions, flow, merge=True) -> tuple:
    """A section from points and the area each piece lays: straight runs merged, short pieces
    merged (block-rate budget). Returns (section or None if nothing is laid, lonely) where
    lonely marks laid pieces that could not be made long enough (the caller gives them away)."""
    if merge:
        keep, pts = _keep_straight(pts, area, laid, u)
        k1 = np.flatnonzero(keep)
        pts, area, laid, u = pts[k1], np.add.reduceat(area, k1[:-1]), laid[k1[:-1]], u[k1]
        back = k1
    else:
        back = np.arange(len(pts))
    keep, lonely = _long_enough(pts, area, laid, o, flow, o.block_rate)
    if lonely.any():                                # in the caller's piece numbering
        out = np.zeros(int(back[-1]), bool)
        for i in np.flatnonzero(lonely):
            out[back[i]:back[i + 1]] = True
        return None, out
    k2 = np.flatnonzero(keep)
    pts, area, laid, u = pts[k2], np.add.reduceat(area, k2[:-1]), laid[k2[:-1]], u[k2]
    if not laid.any():
        return None, None
    L = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    width = np.where(laid, area / np.maximum(L, 1e-12), 0.0)
    v = np.where(laid, _speeds(width, o, flow), o.travel_speed)
    if o.block_rate:                                # a head only passing through: slower, not cut up
        v = np.where(laid, v, np.minimum(v, np.maximum(L * o.block_rate, o.min_speed)))
    e = np.where(laid, area * o.layer_height / o.filament_area, 0.0)
    return Section(kind, pts, e, v, width, u), None


def _trim(s: Section) -> Section:
    """An open path without its unlaid ends."""
    on = np.flatnonzero(s.e > 0)
    a, b = on[0], on[-1] + 1
    return Section(s.kind, s.pts[a:b + 1], s.e[a:b], s.v[a:b], s.width[a:b], s.u[a:b + 1])


def _layer_paths(o: LithoOptions, fld: Field, k: int, wall_q, mid_q, counts: dict):
    """Walls and mid-line(s) of layer k, each a band between offsets from the back face on every
    sample's probe: back wall [0, wb], mid-line [wb, t - wf], front wall [t - wf, t], with the
    walls' widths from the field (wall_widths: a line width, narrowed for a thin mid-line or
    widened to share a light gap, and planned for a steady mid-line). A mid-line piece narrower
    than min_line gives its area to the two walls, half each, and the head moves on along the
    middle there. Returns (walls, mids, gm, mean wall width)."""
    t = fld.t[k].astype(float)
    n = len(t)
    w, nl = o.line_width, int(fld.lines[k])
    lmin = o.line_min()
    planar = o.shape == "planar"
    wb, wf = fld.ww[k], fld.wf[k]                  # back and front wall widths
    ww = (wb + wf) / 2
    gm = t - wb - wf
    if planar:
        # the mid-line runs between the end walls (x = w .. X - w), the walls' centre lines from
        # x = w / 2 to X - w / 2: the samples inside, and the ends
        X = fld.s[-1]
        ends = lambda a: np.concatenate([[a], fld.s[(fld.s > a + 1e-9) & (fld.s < X - a - 1e-9)], [X - a]])
        xm = ends(w)
        um = xm / (X / (n - 1))
        wwm = np.interp(xm, fld.s, wb)
        gmm = np.interp(xm, fld.s, t) - wwm - np.interp(xm, fld.s, wf)
        band = _Band(o, fld, k, xm)
    else:
        wwm, gmm, band = wb, gm, _Band(o, fld, k)
        um = np.arange(n + 1, dtype=float)
    # the walls: centre lines half their band in from each face
    if planar:
        xw = ends(w / 2)
        uw = xw / (X / (n - 1))
        tw, wbv, wfv = np.interp(xw, fld.s, t), np.interp(xw, fld.s, wb), np.interp(xw, fld.s, wf)
        bw = _Band(o, fld, k, xw)
        move_w = lambda a: np.diff(np.interp(xw, xm, np.concatenate([[0.0], np.cumsum(a)])))
        move_m = lambda a: np.diff(np.interp(xm, xw, np.concatenate([[0.0], np.cumsum(a)])))
    else:
        uw, tw, wbv, wfv, bw = um, t, wb, wf, band
        move_w = move_m = lambda a: a
    back_p, front_p = bw.points(wbv / 2), bw.points(tw - wfv / 2)
    back_a, front_a = bw.area(np.zeros(len(wbv)), wbv), bw.area(tw - wfv, tw)
    # A wall along a slope is longer than its band is wide: at its own width it lays a little
    # more than the band, taken from the mid-line beside it, so that the walls keep one speed.
    bar = lambda a: (a + np.roll(a, -1))[: len(back_a)] / 2
    want = [np.maximum(bar(w_) * np.linalg.norm(np.diff(p_, axis=0), axis=1) - a_, 0.0)
            for p_, a_, w_ in ((back_p, back_a, wbv), (front_p, front_a, wfv))]
    mid_w = move_w(band.area(wwm, wwm + gmm))
    take = want[0] + want[1]
    scale = np.where(take > mid_w, mid_w / np.maximum(take, 1e-12), 1.0)
    back_a, front_a = back_a + want[0] * scale, front_a + want[1] * scale
    taken = move_m(take * scale)
    given = np.zeros(len(um) - 1)                   # mid-line area per piece given to the walls
    mids = []
    for i in range(nl):
        lo, hi = wwm + gmm * i / nl, wwm + gmm * (i + 1) / nl
        pts = band.points((lo + hi) / 2)
        area = np.maximum(band.area(lo, hi) - taken / nl, 0.0)
        L = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        laid = area >= lmin * L * (1 - 1e-6)
        while True:
            sec, lonely = _pieces("mid-line", pts, area, laid, um, o, mid_q)
            if lonely is None:
                break
            laid = laid & ~lonely                   # runs too short for the block rate: to the walls
        given += np.where(laid, 0.0, area)
        if sec is None:                             # the walls merge all along
            continue
        if not band.closed:
            sec = _trim(sec)
            if i % 2:                               # serpentine: odd lines run back
                sec = _reverse(sec)
        mids.append(sec)
    counts["shared_mm3"] += float(given.sum() * o.layer_height)
    g_w = move_w(given)
    back_a, front_a = back_a + g_w / 2, front_a + g_w / 2
    if planar:
        # one loop, counter-clockwise: back left to right, up the right end, front right to
        # left, down the left end; the ends are plain lines of one line width
        nw = len(xw)
        pts = np.vstack([back_p, front_p[::-1], back_p[:1]])
        end_a = np.linalg.norm(pts[[nw, 2 * nw]] - pts[[nw - 1, 2 * nw - 1]], axis=1) * w
        area = np.concatenate([back_a, [end_a[0]], front_a[::-1], [end_a[1]]])
        uu = np.concatenate([uw, uw[::-1], uw[:1]])
        walls, _ = _pieces("wall", pts, area, np.ones(len(area), bool), uu, o, wall_q)
        walls = [walls]
    else:
        lay = np.ones(n, bool)
        outer, _ = _pieces("wall", front_p, front_a, lay, uw, o, wall_q)
        if np.all(wb == w) and np.all(g_w == 0):
            # a plain circle: chords of as many samples as the chord tolerance allows
            r, step = band.r_in + w / 2, 1
            # a chord over k samples strays from the points it drops by r (cos(a) - cos(k dth / 2)),
            # a the angle of the point nearest its middle
            while step < n // 3 and r * (math.cos(((step + 1) % 2) * band.dth / 2)
                                         - math.cos((step + 1) * band.dth / 2)) <= CHORD_TOL:
                step += 1
            keep = np.unique(np.append(np.arange(0, n + 1, step), n))
            inner, _ = _pieces("wall", back_p[keep][::-1], np.add.reduceat(back_a, keep[:-1])[::-1],
                               np.ones(len(keep) - 1, bool), uw[keep][::-1], o, wall_q, merge=False)
        else:
            inner, _ = _pieces("wall", back_p[::-1], back_a[::-1], lay, uw[::-1], o, wall_q)
        walls = [outer, inner]                      # outer counter-clockwise, inner clockwise
    return walls, mids, gm, ww


def _reverse(s: Section) -> Section:
    u = None if s.u is None else s.u[::-1].copy()
    return Section(s.kind, s.pts[::-1].copy(), s.e[::-1].copy(), s.v[::-1].copy(), s.width[::-1].copy(), u)


def _rotate_loop(s: Section, near, o: LithoOptions | None = None) -> Section:
    """A closed loop started at its point nearest `near`: a vertex, or a new one on a long piece
    (split in two, each part laying its share), so that the way there is short."""
    a, b = s.pts[:-1], s.pts[1:]
    d = b - a
    L2 = np.maximum((d * d).sum(axis=1), 1e-24)
    f = np.clip(((near - a) * d).sum(axis=1) / L2, 0.0, 1.0)
    q = a + d * f[:, None]
    j = int(np.argmin(np.linalg.norm(q - near, axis=1)))
    Lj = math.sqrt(L2[j])
    need = MIN_MOVE + ROUNDING
    if o is not None and o.block_rate:
        need = max(need, s.v[j] / o.block_rate)
    if f[j] * Lj >= need and (1 - f[j]) * Lj >= need:         # split piece j at q
        fj = f[j]
        pts = np.vstack([s.pts[:j + 1], q[j:j + 1], s.pts[j + 1:]])
        ins = lambda x, y0, y1: np.concatenate([x[:j], [y0, y1], x[j + 1:]])
        e = ins(s.e, s.e[j] * fj, s.e[j] * (1 - fj))
        s = Section(s.kind, pts, e, ins(s.v, s.v[j], s.v[j]), ins(s.width, s.width[j], s.width[j]),
                    None if s.u is None else np.concatenate([s.u[:j + 1], [s.u[j] + (s.u[j + 1] - s.u[j]) * fj],
                                                              s.u[j + 1:]]))
        i = j + 1
    else:
        i = j if f[j] < 0.5 else j + 1
    pts = s.pts[:-1]
    i %= len(pts)
    if i == 0:
        return s
    pts = np.vstack([pts[i:], pts[:i], pts[i:i + 1]])
    roll = lambda x: np.concatenate([x[i:], x[:i]])
    u = None if s.u is None else np.concatenate([s.u[i:-1], s.u[:i], s.u[i:i + 1]])
    return Section(s.kind, pts, roll(s.e), roll(s.v), roll(s.width), u)


def _orient(s: Section, near) -> Section:
    """An open path started at the end nearer `near`."""
    if np.linalg.norm(s.pts[-1] - near) < np.linalg.norm(s.pts[0] - near):
        return _reverse(s)
    return s


def _join(s: Section, at, o: LithoOptions, flow) -> Section:
    """A section started from `at` when the way there is too short for a move of its own (under
    MIN_MOVE, or under its speed / block rate): its first piece begins at `at` and lays the same
    volume over the longer way (no extra filament at the join)."""
    d = float(np.linalg.norm(s.pts[0] - at))
    if d <= 1e-6 or d >= o.retract_min:
        return s
    need = max(MIN_MOVE + ROUNDING, s.v[0] / o.block_rate if o.block_rate else 0.0)
    if d >= need:
        return s                                    # a connector of its own (_Writer)
    pts = s.pts.copy()
    pts[0] = at
    e, v, width = s.e.copy(), s.v.copy(), s.width.copy()
    L = float(np.linalg.norm(pts[1] - pts[0]))
    if e[0] > 0:
        width[0] = width[0] * np.linalg.norm(s.pts[1] - s.pts[0]) / max(L, 1e-12)
        v[0] = float(_speeds(np.array([width[0]]), o, flow)[0])
    return Section(s.kind, pts, e, v, width, s.u)


def plan_lithophane(image, o: LithoOptions | None = None, progress=None) -> Plan:
    """Paths for every layer. `progress(done, total)` is called now and then."""
    o = o or LithoOptions()
    fld = image if isinstance(image, Field) else thickness_field(image, o)   # a Field: calibration_field
    o = replace(o, foot=fld.foot)          # the plan and its files carry the depth in use
    _check_fits(o, fld)
    plan = Plan(o, fld)
    plan.counts.update(shared_mm3=0.0)
    H = o.layer_height
    pos = None
    capped = 0
    for k in range(fld.layers):
        ratio = o.first_layer_speed / o.wall_speed if k == 0 else 1.0
        wall_q, mid_q = o.wall_flow * ratio, o.mid_flow * ratio
        walls, mids, gm, ww = _layer_paths(o, fld, k, wall_q, mid_q, plan.counts)
        if pos is None:
            pos = walls[0].pts[0]
        secs = []
        flows = []
        if o.shape == "planar":
            # one loop round the plate, then the mid-line(s) from the end nearer the loop's start
            secs.append(_rotate_loop(walls[0], pos, o))
            flows.append(wall_q)
            for m in mids:
                secs.append(_orient(m, secs[-1].pts[-1]))
                flows.append(mid_q)
        else:
            # inner wall, mid-line loop(s), outer wall (odd layers outside in): each loop starts at
            # the seam, next to where the last one ended, so a layer needs no travel
            order = [(walls[1], wall_q)] + [(m, mid_q) for m in mids] + [(walls[0], wall_q)]
            if k % 2:
                order = order[::-1]
            for s, q in order:
                secs.append(_rotate_loop(s, pos if not secs else secs[-1].pts[-1], o))
                flows.append(q)
        # the first part joins where the layer below ended, the others the part before them
        ends = [pos] + [p.pts[-1] for p in secs[:-1]]
        secs = [_join(s, at, o, q) for s, at, q in zip(secs, ends, flows)]
        plan.layers.append(Layer(z=(k + 1) * H, sections=secs, gap=gm, wall=ww))
        pos = secs[-1].pts[-1]
        capped += sum(int(np.sum(_capped(s, o, mid_q))) for s in secs if s.kind == "mid-line")
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


def _word_chars(letter: str, a: np.ndarray, nd: int, on=None) -> tuple[np.ndarray, np.ndarray]:
    """The words `letter` + each value to nd decimals (Python's shortest repr of the rounded
    value: no trailing zeros but a whole number's ".0"; zero as "0"), as a character matrix and
    which of its characters are written, computed on the whole array at once. Each word starts
    with a space; `on`: which rows have the word at all."""
    k = np.rint(np.asarray(a, float) * 10 ** nd).astype(np.int64)
    neg, m = k < 0, np.abs(k)
    ip, fp = np.divmod(m, 10 ** nd)
    D = max(1, len(str(int(ip.max())))) if len(m) else 1
    n = len(k)
    digits = lambda v, count: (v[:, None] // 10 ** np.arange(count - 1, -1, -1)) % 10 + ord("0")
    # trailing zeros of the fraction: written up to its last non-zero digit, at least one
    tz = np.zeros(n, int)
    rest = fp.copy()
    for _ in range(nd):
        z = (rest % 10 == 0) & (rest > 0)
        tz += z
        rest = np.where(z, rest // 10, rest)
    shown_f = np.where(fp > 0, nd - tz, 1)
    chars = np.empty((n, 4 + D + nd), np.uint8)
    chars[:, 0], chars[:, 1], chars[:, 2] = ord(" "), ord(letter), ord("-")
    chars[:, 3:3 + D] = digits(ip, D)
    chars[:, 3 + D] = ord(".")
    chars[:, 4 + D:] = digits(fp, nd)
    mask = np.zeros((n, 4 + D + nd), bool)
    mask[:, :2] = True
    mask[:, 2] = neg
    mask[:, 3:3 + D] = ip[:, None] >= 10 ** np.arange(D - 1, -1, -1)
    mask[:, 2 + D] = True                               # the units digit
    mask[:, 3 + D:] = (m[:, None] > 0) & (np.arange(nd + 1) <= shown_f[:, None])
    if on is not None:
        mask &= np.asarray(on, bool)[:, None]
    return chars, mask


def _move_texts(x, y, amount, f, laid, newf, sizes) -> list:
    """Lines "G1 X Y [E|W] [F]" for rounded columns (X, Y to 3 decimals, E 5 or W 4, F 1), where
    `amount` is (letter, values, decimals), one text per group of `sizes` lines (without its
    last newline). Built as one character matrix: the writer's hot loop (a cylinder has half a
    million moves per file)."""
    n = len(x)
    parts = [(np.frombuffer(b"G1", np.uint8)[None, :].repeat(n, 0), None),
             _word_chars("X", x, 3), _word_chars("Y", y, 3),
             _word_chars(amount[0], amount[1], amount[2], on=laid), _word_chars("F", f, 1, on=newf),
             (np.full((n, 1), ord("\n"), np.uint8), None)]
    chars = np.hstack([c for c, _ in parts])
    mask = np.hstack([np.ones_like(c, bool) if m is None else m for c, m in parts])
    text = chars[mask].tobytes().decode("ascii")
    ends = np.cumsum(mask.sum(axis=1))[np.cumsum(sizes) - 1].tolist()
    return [text[a:b - 1] for a, b in zip([0] + ends[:-1], ends)]


class _Writer:
    """Writes one of the two G-code files. `mode`: "litho" (width mode: M723 sets the extruder
    rate, the firmware picks each piece's speed) or "stock" (eq. 2: explicit F per piece so that
    E * F / L is the same rate, for stock firmware). `items` holds the file as lines, and each
    section's moves as (text, estimate.MoveBlock), so the estimate need not parse them again."""

    def __init__(self, plan: Plan, mode: str):
        self.p, self.o, self.mode = plan, plan.options, mode
        self.items: list = []
        self.x = self.y = None
        self.f = None
        self.retracted = False
        self.flow = None
        self.pending: list = []       # sections whose text is still to be made

    def flush(self):
        """Make the text of the sections written since the last flush."""
        if not self.pending:
            return
        idx, *cols = zip(*self.pending)
        X, Y, A, F, laid, newf = (np.concatenate(c) for c in cols)
        amount = ("W", A, 4) if self.mode == "litho" and self.o.words == "w" else ("E", A, 5)
        for i, text in zip(idx, _move_texts(X, Y, amount, F, laid, newf, [len(c) for c in cols[0]])):
            self.items[i][0] = text
        self.pending = []

    def out(self, s):
        self.items.append(s)

    def text(self):
        """The file's text in pieces (one per line or section)."""
        for it in self.items:
            yield (it if isinstance(it, str) else it[0]) + "\n"

    def lines(self):
        """The file for the estimator: lines, and MoveBlocks for the sections' moves."""
        for it in self.items:
            if isinstance(it, str):
                yield from it.split("\n")
            else:
                yield it[1]

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
        from ..gcode.estimate import MoveBlock

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
        # every piece at once: X Y, E (or W) where laid, F where it changes
        ox, oy = self.p.origin
        X, Y = np.round(s.pts[1:, 0] + ox, 3), np.round(s.pts[1:, 1] + oy, 3)
        laid = s.e > 0
        F = np.round(s.v * 60, 1)
        use_w = self.mode == "litho" and o.words == "w"
        E = np.where(laid, np.round(s.e, 5), 0.0)
        Wd = np.where(laid, np.round(s.width, 4), 0.0) if use_w else None
        prev = np.concatenate([[self.f if self.f is not None else -1.0], F[:-1]])
        newf = np.abs(F - prev) > 1e-6
        # the text is made with the next sections' (flush): fewer, larger array steps
        self.pending.append((len(self.items), X, Y, Wd if use_w else E, F, laid, newf))
        self.items.append([None, MoveBlock(X, Y, E, F, Wd)])
        self.f = float(F[-1])
        self.x, self.y = s.pts[-1]

    def _piece(self, x, y, e, v, width):
        if self.mode == "stock":
            self.move(x, y, e=e, f=v)
        elif self.o.words == "w" and width is not None:
            self.move(x, y, w=width)
        else:
            # E per width; F is the same speed the firmware will choose, so the file also
            # prints right on firmware without width mode (the firmware ignores F here)
            self.move(x, y, e=e, f=v)


def write_gcode(plan: Plan, path, mode: str, name: str = "lithophane", estimate_with=()) -> list:
    """Write one G-code file, and return its estimated print time (s, from the moves as
    written) for every estimate.Machine in `estimate_with`."""
    from .. import progress as pg

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
    n = len(plan.layers)
    with pg.phase(f"writing {Path(path).name}", n, unit="layers"):
        for k, L in enumerate(plan.layers):
            w.out(f";LAYER:{k}")
            w.out(f"G1 Z{_fmt(L.z, 3)} F{_fmt(o.z_speed * 60, 1)}")
            w.f = o.z_speed * 60
            wall_q = o.wall_flow * (ratio if k == 0 else 1.0)
            mid_q = o.mid_flow * (ratio if k == 0 else 1.0)
            for s in L.sections:
                w.section(s, wall_q, mid_q)
            if sum(len(q[1]) for q in w.pending) > 16384:
                w.flush()
            if k % 16 == 0:
                pg.tick(k)
        if mode == "litho":
            w.out("M723 S0 ; width mode off")
        if o.retract > 0:
            w.out(f"G1 E-{_fmt(o.retract, 4)} F{_fmt(o.retract_speed * 60, 1)}")
        w.out(fill(end).rstrip("\n"))
        w.flush()
        outputs.write(path, w.text())
    for it in w.items:                              # the estimate needs the moves' numbers only
        if not isinstance(it, str):
            it[0] = None
    from ..gcode import estimate

    out = []
    for m in estimate_with:
        every = "" if m.min_segment_steps else ", every move planned"
        with pg.phase(f"estimating {Path(path).name}{every}", 1, unit="estimates"):
            out.append(estimate.estimate_lines(w.lines(), m, source=os.fspath(path), blocks=False).total_s)
    return out


def _read_text(path, opt):
    try:
        return Path(path).read_text()
    except OSError as e:
        raise LithoError(f"--{opt} {path}: {e.strerror or e}") from None


def _options_dict(o: LithoOptions) -> dict:
    d = asdict(o)
    d["infill_flow"] = o.flow                  # the rate used, also where the default chose it
    d["bed"] = list(o.bed)
    d["printer"] = o.printer.describe()         # the model, as the stock file's header names it
    return d


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
        # the back is a plain cylinder: its bottom and top rows are all it needs
        zb = np.broadcast_to(zs[[0, -1], None], (2, C))
        back = np.stack([np.broadcast_to(r_in * c, (2, C)), np.broadcast_to(r_in * sn, (2, C)), zb], axis=-1)
        closed = True
    V = np.concatenate([front.reshape(-1, 3), back.reshape(-1, 3)])
    nf = R * C
    idx_f = np.arange(nf).reshape(R, C)
    idx_b = np.arange(nf, len(V)).reshape(-1, C)
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
    outputs.write(path, [head, np.uint32(len(F)).tobytes(), memoryview(rec).cast("B")])


# --- predicted look and statistics ---------------------------------------------------------

def printed_thickness(plan: Plan) -> np.ndarray:
    """Thickness as laid down, per image layer and sample: the two walls' bands (a line width
    each, more where they share a narrow gap) plus the mid-line's band. A planar plate's end
    columns, closer to the end than a line width, are the end walls: solid through the plate."""
    o, fld = plan.options, plan.field
    t = np.array([2 * L.wall + L.gap for L in plan.layers[fld.n_foot:]])
    if o.shape == "planar":
        ends = (fld.s < o.line_width - 1e-9) | (fld.s > fld.s[-1] - o.line_width + 1e-9)
        t[:, ends] = fld.t[fld.n_foot:, ends]
    return t


def laid_area(plan: Plan, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Area (mm^2) laid by layer k's walls and mid-line(s) over each interval between
    neighbouring samples, and the body's area there (as the STL has it). A merged piece is spread
    over the stretch along the layer it spans (in samples, Section.u), a piece across the layer
    (a planar end wall) goes to the interval it stands in; joins laid as connectors of their own
    are not counted."""
    o, fld = plan.options, plan.field
    t = fld.t[k]
    n = len(t)
    closed = o.shape == "cylinder"
    m = n if closed else n - 1
    lo_all, hi_all, a_all = [], [], []
    for s in plan.layers[k].sections:
        on = s.e > 0
        a = (s.e * o.filament_area / o.layer_height)[on]
        ua, ub = s.u[:-1][on], s.u[1:][on]
        if closed:                                  # across the seam: unwrap
            ub = np.where(ub - ua > n / 2, ub - n, np.where(ua - ub > n / 2, ub + n, ub))
        lo_all.append(np.minimum(ua, ub)), hi_all.append(np.maximum(ua, ub)), a_all.append(a)
    lo, hi, a = (np.concatenate(x) for x in (lo_all, hi_all, a_all))
    if closed:
        lo, hi = lo % n, lo % n + (hi - lo)
    laid = np.zeros(m + (1 if not closed else n))
    point = hi - lo < 1e-9
    np.add.at(laid, np.minimum(np.floor(lo[point]).astype(int), m - 1), a[point])
    lo, hi, a = lo[~point], hi[~point], a[~point]
    # each piece lays evenly along [lo, hi]: the laid area up to u is piecewise linear in u
    ev = np.concatenate([lo, hi])
    slope = np.concatenate([a / (hi - lo), -a / (hi - lo)])
    order = np.argsort(ev, kind="stable")
    ev, slope = ev[order], np.cumsum(slope[order])
    cum = np.concatenate([[0.0], np.cumsum(slope[:-1] * np.diff(ev))])
    q = np.arange(len(laid) + 1, dtype=float)
    F = np.interp(q, ev, cum, left=0.0, right=cum[-1])
    laid = laid + np.diff(F)
    if closed:
        laid = laid[:n] + np.concatenate([laid[n:], np.zeros(n - len(laid[n:]))])
        r_in = o.diameter / 2 - o.max_thickness
        r2 = (r_in + t) ** 2 - r_in ** 2
        body = (r2 + np.roll(r2, -1)) / 4 * (2 * math.pi / n)
    else:
        laid = laid[:m]
        body = (t[:-1] + t[1:]) / 2 * np.diff(fld.s)
        if k < fld.n_foot:
            body = np.full(m, o.foot) * np.diff(fld.s)
    return laid, body


def laid_deviations(plan: Plan, first: int | None = None) -> tuple[list[float], list[np.ndarray]]:
    """What the pieces lay (laid_area, from their E) against the body, on layers first.. (the
    picture's first by default): per layer its total's deviation (laid / body - 1), and the
    deviation |laid / body - 1| of each interval between neighbouring samples."""
    fld = plan.field
    totals, dev = [], []
    for k in range(fld.n_foot if first is None else first, len(plan.layers)):
        laid, body = laid_area(plan, k)
        totals.append(float(laid.sum() / body.sum() - 1))
        dev.append(np.abs(laid / np.maximum(body, 1e-12) - 1))
    return totals, dev


def laid_volume(plan: Plan) -> dict:
    """How the filament the pieces lay follows the body's volume, on the picture's layers
    (laid_deviations): the largest deviation of a layer's total, and per interval between
    neighbouring samples the median, 99th percentile and largest (a merged piece averages the
    intervals it spans: the block-rate budget's price), the planar plate's end intervals apart."""
    totals, per = laid_deviations(plan)
    if not per:
        return {}
    dev = np.concatenate(per)
    ends = [max(d[0], d[-1]) for d in per] if plan.options.shape == "planar" else []
    r = lambda v: round(float(v), 4)
    return {"layer_total_max_dev": r(max(map(abs, totals))), "interval_median_dev": r(np.median(dev)),
            "interval_p99_dev": r(np.percentile(dev, 99)), "interval_max_dev": r(dev.max()),
            "end_intervals_max_dev": r(max(ends)) if ends else None}


def look(plan: Plan):
    """(target L*, predicted L*) on the layer x sample grid, 0..100. Predicted: the printed
    plate's luminance relative to the thinnest plate, exp(-mu (t - t_min)), as L*. Target: the
    picture's L* (its negative with --invert) scaled onto what the plate can show (L* of the
    thickest plate .. 100); the perceptual curve at gamma 1 aims at exactly this."""
    o = plan.options
    L_lo, _ = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
    pred = tone.lightness(tone.plate_luminance(printed_thickness(plan), o.attenuation, o.min_thickness))
    return tone.target_lightness(100.0 * plan.field.bright, L_lo, o.invert), pred


def write_transmission_png(plan: Plan, path) -> None:
    """Three panels, sRGB: the picture as it is; the predicted backlit look (the thinnest plate
    white, every other tone as bright as the plate will be: what the print shows); the same
    stretched so that the thickest plate is black (labelled: contrast the print does not have)."""
    from PIL import Image, ImageDraw

    o = plan.options
    _, pred = look(plan)
    L_lo, _ = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
    picture = 100.0 * plan.field.bright
    stretched = np.clip((pred - L_lo) / (100.0 - L_lo), 0.0, 1.0) * 100.0
    # one sample is `pitch` wide and one layer high: resize to the physical aspect
    scale = 4.0                                   # px per mm
    pw, ph = plan.field.picture_mm
    size = (max(8, int(pw * scale)), max(8, int(ph * scale)))
    panels = [(picture, "picture"),
              (pred, f"predicted, backlit (mu {o.attenuation:g}/mm, L* {L_lo:.0f}-100)"),
              (stretched, "predicted, STRETCHED (thickest = black)")]
    ims = [Image.fromarray(np.round(tone.to_srgb(tone.luminance(a[::-1])) * 255).astype(np.uint8))
           .resize(size, Image.Resampling.BILINEAR) for a, _ in panels]
    pad, top = 10, 22
    canvas = Image.new("L", (3 * size[0] + 4 * pad, size[1] + top + pad), 128)
    d = ImageDraw.Draw(canvas)
    for i, (im, (_, label)) in enumerate(zip(ims, panels)):
        x = pad + i * (size[0] + pad)
        canvas.paste(im, (x, top))
        d.text((x, 5), label, fill=255)
    buf = __import__("io").BytesIO()
    canvas.save(buf, format="PNG")
    outputs.write(path, buf.getvalue())


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
            d = by_kind.setdefault(s.kind, {"length_mm": 0.0, "filament_mm": 0.0, "time_no_accel_s": 0.0,
                                            "moves": 0})
            d["length_mm"] += float(seg[laid].sum())
            d["filament_mm"] += float(s.e.sum())
            d["time_no_accel_s"] += (float((seg[laid] / s.v[laid]).sum())
                                     + float((seg[~laid] / o.travel_speed).sum()))
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
    sim = tone.similarity(src, pred)
    L_lo, L_hi = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
    pic = fld.t[fld.n_foot:]
    samples = pic.size
    laid = laid_volume(plan)
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
        "time_no_accel_s": round(sum(d["time_no_accel_s"] for d in by_kind.values()), 1),
        "by_kind": {k: {kk: round(vv, 3) for kk, vv in d.items()} for k, d in by_kind.items()},
        "rates": {"wall_mm3_s": round(o.wall_flow, 4), "mid_line_mm3_s": round(o.mid_flow, 4),
                  "mid_line_e_mm_s": round(o.mid_flow / area, 5), "paper_rate": o.paper_rate,
                  # the default rate lowered for a printer that accelerates less (default_flow)
                  "mid_line_lowered_for_accel_mm_s2": o.accel if (o.infill_flow is None and not o.paper_rate
                                                                  and o.flow < INFILL_FLOW) else None},
        "mid_line": {
            "capped_time_share": round(capped_t / total_mid_t, 4) if total_mid_t else 0.0,
            "capped_length_share": round(capped_len / mid_len, 4) if mid_len else 0.0,
            "capped_pieces": plan.counts.get("capped_pieces", 0),
            "given_to_walls_mm3": round(plan.counts.get("shared_mm3", 0.0), 2),
            "layers_with_two_or_more": int((fld.lines > 1).sum()),
            "max_lines_per_layer": int(fld.lines.max()),
        },
        "walls": {name: {"min": round(float(w_.min()), 3), "median": round(float(np.median(w_)), 3),
                         "max": round(float(w_.max()), 3)}
                  for name, w_ in (("back_mm", fld.ww[fld.n_foot:]), ("front_mm", fld.wf[fld.n_foot:]))},
        "gaps": {
            "shared_by_walls": fld.shared,
            "shared_share": round(fld.shared / samples, 4),
            "narrowed_by_walls": fld.narrowed,
            "narrowed_share": round(fld.narrowed / samples, 4),
            "light_gaps": o.light_gaps,
            "min_line_mm": round(o.line_min(), 4), "max_line_mm": o.max_line,
        },
        "laid_volume": laid,
        "look": {"attenuation_per_mm": o.attenuation, "curve": o.curve,
                 "plate_L_range": [round(L_lo, 2), round(L_hi, 2)],
                 "mean_abs_dL": round(sim["mean_abs_dL"], 3),
                 # None when the picture has fewer than 7 rows or samples (no 7 x 7 window)
                 "ssim_L": round(sim["ssim_L"], 4) if math.isfinite(sim["ssim_L"]) else None,
                 "correlation": round(r, 4)},
    }


@dataclass
class LithoResult:
    plan: Plan
    paths: dict
    stats: dict


def make(image, outdir, name: str | None = None, progress=None, machine=None, **opts) -> LithoResult:
    """Everything `bulgekit litho` writes, from a picture: NAME.litho.gcode, NAME.stock.gcode,
    NAME.stl, NAME.transmission.png, NAME.litho.json. Options: the fields of LithoOptions.
    image None: the calibration plate (calibration_field), NAME "calibration" by default.
    `progress(done, total)` hears the planning; the later phases (writing each file, the
    estimate) are reported through bulgekit.progress. `machine`: the estimate's
    estimate.Machine (default: machine_for(options), Marlin's RAMPS defaults at `accel`)."""
    from ..gcode import estimate
    from .. import progress as pg

    o = opts.pop("options", None) or LithoOptions(**opts)
    calibration = None
    if image is None:                                   # the calibration plate
        image, calibration = calibration_field(o)
    name = name or ("calibration" if calibration else Path(os.fspath(image)).stem)
    out = Path(outdir)
    plan = plan_lithophane(image, o, progress=progress)
    final = {"gcode": out / f"{name}.litho.gcode", "stock": out / f"{name}.stock.gcode",
             "stl": out / f"{name}.stl", "png": out / f"{name}.transmission.png",
             "json": out / f"{name}.litho.json"}
    m = machine or machine_for(o)
    with outputs.Outputs() as staged:                 # all five files or none (bulgekit.outputs)
        staged.folder(out)
        with pg.phase(f"writing {final['stl'].name}", 1, unit="files"):
            V, F = body_mesh(plan)
            write_stl(V, F, final["stl"], name=f"bulgekit lithophane {name}")
            stl_volume = mesh_volume(V, F)
            del V, F
        times = {}
        # the litho file also with every move planned (Klipper, RepRapFirmware): nothing dropped
        every = dataclasses.replace(m, min_segment_steps=0)
        times["gcode"], times["every"] = write_gcode(plan, final["gcode"], "litho", name, estimate_with=[m, every])
        times["stock"], = write_gcode(plan, final["stock"], "stock", name, estimate_with=[m])
        write_transmission_png(plan, final["png"])
        stats = plan_stats(plan, stl_volume)
        stats["name"] = name
        stats["image"] = None if calibration else os.fspath(image)
        if calibration:
            stats["calibration"] = calibration
        stats["options"] = _options_dict(plan.options)
        stats["estimate"] = {"estimated_time_s_gcode": round(times["gcode"], 1),
                             "estimated_time_s_stock": round(times["stock"], 1),
                             "estimated_time_s_gcode_every_move_planned": round(times["every"], 1),
                             "machine": machine_words(m)}
        outputs.write(final["json"], json.dumps(stats, indent=2) + "\n")
    return LithoResult(plan, final, stats)


def machine_for(o: LithoOptions):
    """The estimate's machine: the printer model's (o.printer; by default Marlin's defaults) at
    the acceleration `accel` for printing, travel and retraction (its axes' M201 limits raised
    to it where it is higher, so that what the user states is what is timed)."""
    from ..gcode import estimate
    m = estimate.Machine.from_model(o.printer)
    top = {k: max(v, o.accel) if k in ("X", "Y") else v for k, v in m.max_accel.items()}
    return replace(m, accel=o.accel, travel_accel=o.accel, retract_accel=o.accel, max_accel=top)


def machine_words(m) -> dict:
    """What an estimate assumes, as the JSON and the CLI name it."""
    jerk = None if m.jerk is None else [m.jerk[a] for a in "XYZE"]      # mm/s, X Y Z E
    return {"accel_mm_s2": m.accel, "travel_accel_mm_s2": m.travel_accel,
            "junction_deviation_mm": m.junction_deviation, "classic_jerk": jerk,
            "lookahead_blocks": m.lookahead, "min_segment_steps": m.min_segment_steps}
