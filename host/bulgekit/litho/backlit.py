"""The predicted backlit look: the printed thickness through Beer-Lambert, as L*, and the
transmission picture."""
from __future__ import annotations

import numpy as np

from . import tone
from .. import outputs
from .paths import Plan, end_unit


# --- predicted look and statistics ---------------------------------------------------------

def printed_thickness(plan: Plan) -> np.ndarray:
    """Thickness as laid down, per image layer and sample: the two walls' bands (a line width
    each, more where they share a narrow gap) plus the mid-line's band. A planar plate's end
    columns, closer to the end than a line width, are the end walls: solid through the plate."""
    o, fld = plan.options, plan.field
    t = np.array([2 * L.wall + L.gap for L in plan.layers[fld.n_foot:]])
    if o.shape != "cylinder":
        e = o.line_width * end_unit(o)
        ends = (fld.s < e - 1e-9) | (fld.s > fld.s[-1] - e + 1e-9)
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
    pad, top, line = 10, 22, 11
    measure = ImageDraw.Draw(Image.new("L", (1, 1)))
    labels = [_wrapped(label, size[0], measure) for _, label in panels]   # a narrow panel's label
    top += line * (max(len(ls) for ls in labels) - 1)                     # in lines, not over the next
    canvas = Image.new("L", (3 * size[0] + 4 * pad, size[1] + top + pad), 128)
    d = ImageDraw.Draw(canvas)
    for i, (im, ls) in enumerate(zip(ims, labels)):
        x = pad + i * (size[0] + pad)
        canvas.paste(im, (x, top))
        for k, text in enumerate(ls):
            d.text((x, 5 + k * line), text, fill=255)
    buf = __import__("io").BytesIO()
    canvas.save(buf, format="PNG")
    outputs.write(path, buf.getvalue())


def _wrapped(label: str, width: int, draw) -> list[str]:
    """The label in lines no wider than width px (words kept whole; one line when it fits)."""
    lines: list[str] = []
    for word in label.split(" "):
        if lines and draw.textlength(f"{lines[-1]} {word}") <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return lines


SCATTER_MM = 0.5        # sigma of the light's scatter in the plate, mm: an assumption, not measured


def likeness(plan: Plan) -> dict | None:
    """The picture against the print as this plan makes it: the picture (cropped as used, at up
    to picture.REF_MM per pixel) on the plate's L* range, against the predicted backlit L* of the
    printed thickness as sampled (linear along the layer between samples, one value per layer)
    with the light's scatter in the plate as a Gaussian blur of SCATTER_MM (in linear light).
    What it measures is what sampling at the pitch and layer height, the tone range and the
    scatter lose; not what a printer gets wrong. Inside the frame; None for the calibration plate."""
    from scipy.ndimage import gaussian_filter

    o, fld = plan.options, plan.field
    lay = fld.layout
    if lay is None or lay.reference is None:
        return None
    ref = np.asarray(lay.reference, dtype=float)
    Hr, Wr = ref.shape
    rows, cols = fld.inside
    t = printed_thickness(plan)[:, fld.inside[1] if o.shape == "cylinder" else slice(None)]
    n_rows, m = t.shape
    # the reference's pixel centres on the sample grid (a sample is a cell's centre, as resampled)
    xc = (np.arange(Wr) + 0.5) / Wr * m - 0.5
    yc = np.minimum(((np.arange(Hr) + 0.5) / Hr * n_rows).astype(int), n_rows - 1)
    top = t[::-1]                                        # the picture's top row first
    j0 = np.clip(np.floor(xc).astype(int), 0, m - 1)
    j1 = np.clip(j0 + 1, 0, m - 1)
    f = np.clip(xc - j0, 0.0, 1.0)
    tt = top[yc][:, j0] * (1 - f) + top[yc][:, j1] * f
    Y = tone.plate_luminance(tt, o.attenuation, o.min_thickness)
    px = lay.width / Wr
    Y = gaussian_filter(Y, sigma=(SCATTER_MM / (lay.height / Hr), SCATTER_MM / px), mode="nearest")
    L_lo, _ = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
    pred = tone.lightness(Y)
    target = tone.target_lightness(tone.lightness(ref), L_lo, o.invert)
    # inside the frame: the same share of the picture as fld.inside of the samples
    c0, c1 = (0, m) if o.shape == "cylinder" else (cols.start or 0, cols.stop if cols.stop is not None else m)
    r0, r1 = n_rows - (rows.stop if rows.stop is not None else n_rows), n_rows - (rows.start or 0)
    cut = (slice(int(r0 / n_rows * Hr), int(np.ceil(r1 / n_rows * Hr))),
           slice(int(c0 / m * Wr), int(np.ceil(c1 / m * Wr))))
    sim = tone.similarity(target[cut], pred[cut])
    return {"mean_abs_dL": round(sim["mean_abs_dL"], 2),
            "ssim_L": round(sim["ssim_L"], 3) if np.isfinite(sim["ssim_L"]) else None,
            "grid_mm": [round(lay.width / Wr, 3), round(lay.height / Hr, 3)],
            "sampled_mm": [o.pitch, o.layer_height], "scatter_sigma_mm": SCATTER_MM}
