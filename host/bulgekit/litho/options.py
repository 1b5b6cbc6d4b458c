"""The options of a lithophane (LithoOptions, one field per `bulgekit litho` option), their
checks, and the error every stage raises."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from .. import machine
from ..errors import BulgekitError
from ..machine import PrinterModel
from . import tone


SHAPES = ("planar", "cylinder", "arc")
ARC_ANGLE = 120.0       # degrees: an arc's default angle
CURVES = tone.CURVES
WORDS = ("e", "w")
LIGHT_GAPS = ("mid-line", "walls")

# The mid-line's default rate. Where a layer's mid-line starts and stops, the head ramps its speed
# and the extruder's rate with it; those ramps take a share of the mid-line's time that grows as
# v^2 / (a L) (v = q / (W H), a the acceleration, L the stretch). 8 mm^3/s keeps >= 85 % of a
# photo band's mid-line time within 5 % of the set rate at 3000 mm/s^2 (Marlin's default M204 P);
# a printer that accelerates less gets q x sqrt(a / 3000), which keeps that share
# (docs/verification/lithophane.md, "Extruder rate on the mid-line, verified").
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
    width: float | None = 100.0     # planar: plate width, mm (None: from --height and the aspect, else 100)
    diameter: float = 54.8          # cylinder, arc: outer diameter at the thickest point, mm
    height: float | None = None     # picture height, mm (None: from the picture's aspect ratio)
    angle: float | None = None      # degrees of the circle the picture covers: an arc's (None: 120),
                                    # or on a cylinder (None: all round, or what --height leaves)
    stretch: bool = False           # the picture stretched to the size given, not cropped
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
    positive = {"width": 100.0 if o.width is None else o.width, "diameter": o.diameter, "layer-height": o.layer_height,
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
    if o.angle is not None:
        if o.shape == "planar":
            bad("angle", "is for --shape cylinder or arc")
        if not (math.isfinite(o.angle) and 0 < o.angle <= (360 if o.shape == "cylinder" else 300)):
            bad("angle", f"must be more than 0 and at most {360 if o.shape == 'cylinder' else 300} "
                         f"degrees, got {o.angle:g}")
    if o.shape in ("cylinder", "arc"):
        if o.diameter / 2 - o.max_thickness < 5 * o.line_width:
            bad("diameter", f"{o.diameter:g} mm leaves no room inside a {o.max_thickness:g} mm wall")
        if o.foot:
            bad("foot", f"a{'n' if o.shape == 'arc' else ''} {o.shape} stands by itself; --foot is for planar plates")
    if o.shape == "planar" and o.foot and o.foot < o.max_thickness:
        bad("foot", f"{o.foot:g} mm must be at least --max {o.max_thickness:g} mm deep")
    if len(o.bed) not in (2, 3) or not all(math.isfinite(b) and b > 0 for b in o.bed):
        bad("bed", f"expected X,Y[,Z] in mm > 0, got {o.bed}")


def options_dict(o: LithoOptions) -> dict:
    d = asdict(o)
    d["infill_flow"] = o.flow                  # the rate used, also where the default chose it
    d["bed"] = list(o.bed)
    d["printer"] = o.printer.describe()         # the model, as the stock file's header names it
    return d
