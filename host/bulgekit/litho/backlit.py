"""The predicted backlit look: the printed thickness through Beer-Lambert, as L*, and the
transmission picture."""
from __future__ import annotations

import numpy as np

from . import tone
from .atomic import _write_atomic
from .paths import Plan


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
    _write_atomic(path, buf.getvalue(), binary=True)
