"""The calibration plate (`--calibration`): a planar step wedge from --min to --max, each step's
planned thickness written under it in raised digits; it stands in for a picture (a thickness
field of its own)."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from . import tone
from .options import LithoError, LithoOptions, check_options
from .thickness import Field, _field

CAL_STEPS = 10                  # steps of the calibration wedge, --min .. --max
CAL_COLS = 5                    # steps per row
CAL_STEP = (18.0, 10.0)         # one step, width x height, mm
CAL_LABEL = 7.0                 # the label strip under each row of steps, mm
CAL_TEXT = 5.0                  # digit height, mm
CAL_STROKE = 1.2                # digit stroke width, mm (three samples, six layers: solid when printed)
CAL_FRAME = 3.0                 # border, mm


def calibration_size() -> tuple[float, float]:
    """(width, height) of the calibration plate, mm."""
    rows = math.ceil(CAL_STEPS / CAL_COLS)
    return (CAL_COLS * CAL_STEP[0] + 2 * CAL_FRAME, rows * (CAL_STEP[1] + CAL_LABEL) + 2 * CAL_FRAME)


def calibration_steps(t_min: float, t_max: float) -> np.ndarray:
    """The wedge's thicknesses: CAL_STEPS from t_min to t_max, to 0.01 mm."""
    return np.round(np.linspace(t_min, t_max, CAL_STEPS), 2)


def calibration_layout():
    """Per step: (x0, x1, y0, y1) of the step and of its label strip, mm from the plate's
    bottom-left; the thinnest step top left, thicker to the right and in the next row down."""
    W, Hh = calibration_size()
    rows = math.ceil(CAL_STEPS / CAL_COLS)
    out = []
    for i in range(CAL_STEPS):
        r, c = divmod(i, CAL_COLS)
        x0 = CAL_FRAME + c * CAL_STEP[0]
        top = Hh - CAL_FRAME - r * (CAL_STEP[1] + CAL_LABEL)
        out.append(((x0, x0 + CAL_STEP[0], top - CAL_STEP[1], top),
                    (x0, x0 + CAL_STEP[0], top - CAL_STEP[1] - CAL_LABEL, top - CAL_STEP[1])))
    assert rows * (CAL_STEP[1] + CAL_LABEL) + 2 * CAL_FRAME == Hh
    return out


def calibration_map(s: np.ndarray, z: np.ndarray, steps, t_min: float, t_max: float,
                    labels=None) -> np.ndarray:
    """Thickness (len(z), len(s)) of the calibration plate at x = s and height z (mm): frame at
    t_max, each step at its thickness, label strips at t_min with the labels' digits raised to
    t_max (dark when backlit, raised when lit from the front)."""
    import shapely
    from shapely.geometry import LineString, Point

    from ..bulge.strokes import text_strokes

    X, Z = np.meshgrid(s, z)
    t = np.full(X.shape, t_max)
    for i, ((a0, a1, b0, b1), (c0, c1, d0, d1)) in enumerate(calibration_layout()):
        t[(X >= a0) & (X < a1) & (Z >= b0) & (Z < b1)] = steps[i]
        t[(X >= c0) & (X < c1) & (Z >= d0) & (Z < d1)] = t_min
        if labels is None:
            continue
        strokes = text_strokes(labels[i], CAL_TEXT)
        pts = np.array([p for st in strokes for p in st.points])
        dx = (c0 + c1) / 2 - (pts[:, 0].min() + pts[:, 0].max()) / 2
        dy = (d0 + d1) / 2 - CAL_TEXT / 2
        shifted = [[(u + dx, v + dy) for u, v in st.points] for st in strokes]
        ink = shapely.union_all([(Point(p[0]) if len(p) == 1 else LineString(p)).buffer(CAL_STROKE / 2)
                                 for p in shifted])
        t[shapely.contains_xy(ink, X, Z)] = t_max
    return t


def calibration_field(o: LithoOptions) -> tuple[Field, dict]:
    """The calibration plate (`--calibration`): a planar step wedge from --min to --max, each
    step's planned thickness written under it in raised digits (calibration_map), and
    the steps' figures for the JSON. The labels give the thickness as planned, after the gap
    handling, so they are what is printed."""
    check_options(o)
    if o.shape != "planar":
        raise LithoError("--calibration: the calibration plate is planar; leave out --shape cylinder")
    pic_w, pic_h = calibration_size()
    n = int(round(pic_w / o.pitch)) + 1
    s = np.linspace(0.0, pic_w, n)
    rows = int(round(pic_h / o.layer_height))
    z = (np.arange(rows) + 0.5) * o.layer_height            # field row 0 is the bottom layer
    steps = calibration_steps(o.min_thickness, o.max_thickness)
    centres = [((a0 + a1) / 2, (b0 + b1) / 2) for (a0, a1, b0, b1), _ in calibration_layout()]
    ij = [(int(np.argmin(np.abs(z - zc))), int(np.argmin(np.abs(s - xc)))) for xc, zc in centres]

    def field(labels):
        t = calibration_map(s, z, steps, o.min_thickness, o.max_thickness, labels)
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
