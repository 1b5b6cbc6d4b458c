"""The calibration piece: the over-extrusion paper's two test prints (sec. 4) as one part that
the printer makes from bulgekit's own G-code, no slicer.

The right dwell and extra filament depend on the printer, hotend, filament and temperature, so
the paper found its values by printing: a frame with a stop at each side's middle at dwells
of 0-500 ms (the bump grows roughly with the log of the dwell, about 1.8 mm at 500 ms), and a
wall striped with extra E of 0, 0.05, 0.1, 0.2 and 0.5 mm (it chose 0.1). Here both are on the
front face of one box, 140 x 20 mm, two walls thick (drawn narrower):

    v (mm)  40 +-----------------------------------------------------------+
               | .5   ====    | | | | | | | | | |   extra-E bands, 5 mm each:    |
               | .2   ====    | | | | | | | | | |   3 lines along the layers,   |
               | .1   ====    | | | | | | | | | |   10 lines across them, at    |
               | .05  ====    | | | | | | | | | |   the dwell DWELL_BANDS_MS    |
            15 | 0    ====    | | | | | | | | | |                               |
               |  o    o    o    o    o    o    o    o    o   single bumps,    |
               |  o    o    o    o    o    o    o    o    o   3 per column     |
               |  o    o    o    o    o    o    o    o    o                    |
             2 |  0   10   20   50  100  150  200  300  500   (dwell, ms)      |
             0 +-----------------------------------------------------------+
               u = -70 (the front face, seen from the front)            u = +70

Every label is drawn with bumps too, at DWELL_BANDS_MS, so the piece reads without the docs.
One map holds it all: M720 P is DWELL_P_MS (510 ms) and each point's weight w makes its dwell
P x w / 255 = 2 w ms exactly, so every column's dwell is a whole weight. The extra E of the
dwell series is the paper's 0.1 mm; each band sets its own: on the bulgekit firmware an
`M720 E..` line before the band's first layer, in the stock file the same change made by the
reference planner before that layer (its moves are planned as the firmware plans them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from .. import machine
from ..gcode import startend
from ..errors import BulgekitError
from ..machine import PrinterModel
from .strokes import Stroke, text_strokes

DWELLS_MS = (0, 10, 20, 50, 100, 150, 200, 300, 500)
EXTRAS_MM = (0.0, 0.05, 0.1, 0.2, 0.5)
DWELL_P_MS = 510            # M720 P: dwell = P x w / 255 = 2 w ms
DWELL_BANDS_MS = 100        # the bands' stops and every label's: the paper's choice
EXTRA_DWELLS_MM = 0.1       # the dwell series' extra E: the paper's choice
LABEL_SIZE = 3.5            # mm, capital height of the raised digits


class CalibrationError(BulgekitError):
    """A calibration piece that cannot be made for these options (the message says why)."""


@dataclass(frozen=True)
class CalibrationOptions:
    printer: PrinterModel = machine.DEFAULT
    width: float = 140.0            # mm, the front face (X): room for three-digit labels
    depth: float = 20.0             # mm (Y)
    layer_height: float = 0.2
    line_width: float = 0.45
    wall_speed: float = 40.0        # mm/s, both walls
    first_layer_speed: float = 20.0
    travel_speed: float = 120.0
    temp: int = 210
    bed_temp: int = 60
    bed: tuple = (180.0, 180.0)     # X, Y mm: the piece goes in the middle
    tolerance: float = 0.25         # M720 T

    @property
    def filament_area(self) -> float:
        return self.printer.filament_area


@dataclass
class Layout:
    """Where everything is on the front face (u from its middle, v from the bed), and the
    strokes that draw it."""
    strokes: list[Stroke]
    columns: list[tuple[int, float]]                 # (dwell ms, u)
    bands: list[tuple[float, float, float]]          # (extra mm, v bottom, v top)
    height: float                                    # mm, the piece
    notes: list[str] = field(default_factory=list)


def weight_of(ms: int) -> int:
    """The map weight whose dwell under M720 P DWELL_P_MS is ms (whole: ms is even)."""
    w, r = divmod(ms * 255, DWELL_P_MS)
    if r or not 0 <= w <= 255:
        raise CalibrationError(f"dwell {ms} ms is not 2 w ms for a whole weight w")
    return w


def layout(o: CalibrationOptions) -> Layout:
    if o.width < 130 or o.depth < 10:
        raise CalibrationError("the piece needs a front face of 130 mm or more (three-digit labels "
                               "under 9 columns) and a depth of 10 mm or more")
    label_w = weight_of(DWELL_BANDS_MS)
    strokes: list[Stroke] = []
    half = o.width / 2
    pitch = (o.width - 10) / len(DWELLS_MS)          # columns across the face, 5 mm margins
    columns = []
    for i, ms in enumerate(DWELLS_MS):
        u = -half + 5 + pitch * (i + 0.5)
        columns.append((ms, u))
        for v in (8.0, 10.0, 12.0):
            strokes.append(Stroke(((u, v),), weight_of(ms), f"dwell {ms} ms"))
        strokes += _label(str(ms), u, 2.0, label_w, centre=True)
    bands = []
    v0 = 15.0
    for k, e in enumerate(EXTRAS_MM):
        b = v0 + 5.0 * k
        bands.append((e, b, b + 5.0))
        tag = f"extra {e:g} mm"
        strokes += _label(f"{e:g}".lstrip("0") or "0", -half + 3, b + 0.5, label_w, centre=False)
        for dv in (1.5, 2.5, 3.5):                                # 3 lines along the layers,
            # 35 mm: with the 10 lines across and a label, a layer keeps under the 64-point limit
            strokes.append(Stroke(((-half + 17, b + dv), (-half + 52, b + dv)), label_w, tag))
        for j in range(10):                                       # 10 lines across them
            u = 2.0 + j * (half - 6.0) / 9
            strokes.append(Stroke(((u, b + 0.5), (u, b + 4.5)), label_w, tag))
    return Layout(strokes, columns, bands, height=v0 + 5.0 * len(EXTRAS_MM) + 1.0)


def _label(text: str, u: float, v: float, weight: int, centre: bool) -> list[Stroke]:
    st = text_strokes(text, LABEL_SIZE, u0=0.0, v0=v, weight=weight)
    lo = min(p[0] for s in st for p in s.points)
    hi = max(p[0] for s in st for p in s.points)
    du = u - (lo + hi) / 2 if centre else u - lo
    return [replace(s, points=tuple((a + du, b) for a, b in s.points), source=f"label {text}")
            for s in st]


# --- the part's own G-code -------------------------------------------------------------------
START = startend.HEAT_AND_HOME + "G90 ; absolute positions\nM83 ; relative E\n"
END = startend.END


def part_gcode(o: CalibrationOptions, height: float) -> list[str]:
    """The box: per layer an inner wall, then the outer wall (;TYPE:Outer wall), each a closed
    rectangle starting at the back-left corner so that the front face is one straight move;
    three solid bottom layers. Comments as OrcaSlicer writes them, so every reader of the
    package finds the outer wall and the layers."""
    bx, by = o.bed
    x0, y0 = bx / 2 - o.width / 2, by / 2 - o.depth / 2
    if o.width + 20 > bx or o.depth + 20 > by:
        raise CalibrationError(f"the piece ({o.width:g} x {o.depth:g} mm) does not fit a "
                               f"{bx:g} x {by:g} mm bed with 10 mm margins")
    h, w = o.layer_height, o.line_width
    n = int(round(height / h))
    e_mm = w * h / o.filament_area                    # filament per mm of wall
    out = [f"; bulgekit calibrate: {o.width:g} x {o.depth:g} x {n * h:.2f} mm, {n} layers",
           f"; layer_height = {h:g}", f"; printer: {o.printer.describe()}"]
    out += startend.fill(START, o.temp, o.bed_temp).splitlines()
    out.append("M107")
    for k in range(n):
        z = (k + 1) * h
        out += [";LAYER_CHANGE", f";Z:{z:.2f}", f";HEIGHT:{h:g}", f"G1 Z{z:.3f} F600"]
        f = (o.first_layer_speed if k == 0 else o.wall_speed) * 60
        for inset, role in ((1.5 * w, "Inner wall"), (0.5 * w, "Outer wall")):
            rx0, ry0 = x0 + inset, y0 + inset
            rx1, ry1 = x0 + o.width - inset, y0 + o.depth - inset
            # back-left, front-left, front-right (the front face: +X along -Y's side), back-right
            pts = [(rx0, ry1), (rx0, ry0), (rx1, ry0), (rx1, ry1), (rx0, ry1)]
            out.append(f"G1 X{pts[0][0]:.3f} Y{pts[0][1]:.3f} F{o.travel_speed * 60:.0f}")
            out.append(f";TYPE:{role}")
            for (ax, ay), (bx_, by_) in zip(pts, pts[1:]):
                d = math.hypot(bx_ - ax, by_ - ay)
                out.append(f"G1 X{bx_:.3f} Y{by_:.3f} E{d * e_mm:.5f} F{f:.0f}")
        if k < 3:                                     # the bottom: lines across, inside the walls
            out.append(";TYPE:Bottom surface")
            lx0, lx1 = x0 + 2 * w, x0 + o.width - 2 * w
            y, flip = y0 + 2 * w, False
            out.append(f"G1 X{lx0:.3f} Y{y:.3f} F{o.travel_speed * 60:.0f}")
            while y <= y0 + o.depth - 2 * w + 1e-9:
                xa, xb = (lx1, lx0) if flip else (lx0, lx1)
                out.append(f"G1 X{xa:.3f} Y{y:.3f} F{f:.0f}")
                out.append(f"G1 X{xb:.3f} Y{y:.3f} E{(lx1 - lx0) * e_mm:.5f} F{f:.0f}")
                y += w
                flip = not flip
    out += END.splitlines()
    return [ln + "\n" for ln in out]


def band_starts(lines: list[str], bands, layer_height: float) -> dict[int, float]:
    """Line index of each band's first layer change -> its extra E."""
    starts, want = {}, [(round(b / layer_height), e) for e, b, _ in bands]
    layer = 0
    for i, ln in enumerate(lines):
        if ln.startswith(";LAYER_CHANGE"):
            layer += 1
            for first, e in want:
                if layer == first + 1:
                    starts[i] = e
    return starts


# --- the outputs -----------------------------------------------------------------------------
@dataclass
class CalibrationResult:
    paths: dict                  # "bulge", "stock", "png", "map" -> Path
    layout: Layout
    stops_bulge: int             # stops the reference planner makes in each file
    stops_stock: int
    stock_summary: str


def make(o: CalibrationOptions, outdir, name: str = "calibrate",
         stops_kind: str = "move") -> CalibrationResult:
    """Writes NAME.bulge.gcode (bulgekit firmware: M720 P510 and the map, M720 E per band),
    NAME.stock.gcode (the printer model's stock firmware: the stops written into the moves),
    NAME.bkm and NAME.png (what to look for) into outdir: all of them or none."""
    import tempfile

    from . import api, fallback, mapformat
    from .. import outputs

    lay = layout(o)
    lines = part_gcode(o, lay.height)
    settings = fallback.Settings(fallback.MODE_MARKED, DWELL_P_MS, EXTRA_DWELLS_MM, o.tolerance)
    outdir = Path(outdir)
    final = {k: outdir / f"{name}{ext}" for k, ext in
             (("bulge", ".bulge.gcode"), ("stock", ".stock.gcode"), ("map", ".bkm"), ("png", ".png"))}
    # the part and its map are made in a scratch folder; the four outputs go in place together
    # when the run ends, or none does (bulgekit.outputs)
    with tempfile.TemporaryDirectory(prefix="bulgekit-calibrate-") as scratch, outputs.Outputs() as out:
        tmp = Path(scratch)
        out.folder(outdir)
        plain = tmp / f"{name}.part.gcode"
        plain.write_text("".join(lines), encoding="utf-8")
        with outputs.apart():
            built = api.build(plain, lay.strokes, tmp, name=name, line_width=o.line_width,
                              layer_height=o.layer_height, settings=settings, write_fallback=False)
        bmap = mapformat.decode_map(built.map_path.read_bytes())
        # the bulgekit firmware's file: the annotated part with each band's M720 E
        ann = built.gcode_path.read_text(encoding="utf-8").splitlines(keepends=True)
        at = band_starts(ann, lay.bands, o.layer_height)
        outputs.write(final["bulge"], [ln for i, a in enumerate(ann) for ln in
                                       ([f"M720 E{at[i]:.3f} ; extra-E band\n"] if i in at else []) + [a]])
        # the stock file: the same planner, its extra E changed where the bands begin
        starts = band_starts(lines, lay.bands, o.layer_height)
        by_line = sorted((i + 1, e) for i, e in starts.items())        # 1-based line numbers
        planner = fallback.RefPlanner(bmap, settings)

        def on_move(m, acts):
            while by_line and m.line_no >= by_line[0][0]:
                planner.s = replace(planner.s, extra_e=by_line.pop(0)[1])
        res = fallback.RewriteResult()
        outputs.write(final["stock"], list(fallback.rewrite(
            lines, bmap, settings, str(plain), res, fallback.StockStops(stops_kind, printer=o.printer),
            planner, on_move=on_move)))
        outputs.write(final["map"], built.map_path.read_bytes())
        with outputs.part(final["png"]) as p:
            picture(lay, o, p)
        stops_bulge = sum(1 for p in built.result.points if p.weight > 0)
    return CalibrationResult(final, lay, stops_bulge, sum(1 for st in res.stops if st.ms > 0),
                             res.stock.summary())


def picture(lay: Layout, o: CalibrationOptions, path) -> None:
    """The front face as it should come out, with what to look for."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.4), dpi=110)
    half = o.width / 2
    ax.add_patch(plt.Rectangle((-half, 0), o.width, lay.height, fc="#f1efe9", ec="#999"))
    for st in lay.strokes:
        us = [p[0] for p in st.points]
        vs = [p[1] for p in st.points]
        if st.weight == 0:
            ax.plot(us, vs, "o", ms=4, mfc="none", mec="#bbb")
            continue
        # the paper: the bump's size grows about with the log of the dwell (1.8 mm at 500 ms)
        ms = DWELL_P_MS * st.weight / 255
        size = 2 + 4 * math.log1p(ms / 10) / math.log1p(50)
        if len(st.points) == 1:
            ax.plot(us, vs, "o", ms=size, color="#b5533c")
        else:
            ax.plot(us, vs, "-", lw=2.2, color="#b5533c" if st.source.startswith("extra") else "#555")
    ax.text(half + 2, 6.5, "A: dwell (ms).\nThe smallest dwell whose\nbumps you see and feel\n"
            "clearly; a larger one if\nthey should stand out.\nNot one that runs into\nthe layer above.",
            va="center", fontsize=7.5)
    ax.text(half + 2, 30, "B: extra filament (mm),\nat 100 ms stops.\nThe smallest whose lines\n"
            "have no gap after a bump,\nbefore the wall bulges\nbetween them.",
            va="center", fontsize=7.5)
    ax.set_xlim(-half - 2, half + 34)
    ax.set_ylim(-1, lay.height + 1)
    ax.set_aspect("equal")
    ax.set_xlabel("along the front face, mm")
    ax.set_ylabel("height above the bed, mm")
    ax.set_title("bulgekit calibrate: the front face, seen from the front. "
                 "Then M720 P<dwell> E<extra> and M500", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)
