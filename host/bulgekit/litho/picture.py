"""The picture: read from its file as relative luminance (sRGB decoded, alpha over white), laid
onto the part's sample grid (one row per layer, one sample per pitch; area average in linear
light) and put through the tone curve. What comes out is the thickness per sample and the
picture's lightness on the same grid (thickness.py builds the field from them)."""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from . import tone
from .options import ARC_ANGLE, LithoError, LithoOptions, check_options

_ROWS = 256                     # picture rows converted at a time (bounded memory on large photos)


def read_luminance(path) -> np.ndarray:
    """A picture file as relative luminance Y (rows, columns), float32, row 0 at the top.

    8- and 16-bit grey, grey + alpha, RGB(A), palette and CMYK pictures: alpha is laid over white
    in sRGB values (as a viewer shows the picture on a white page). 16-bit grey keeps its 16 bits;
    Pillow hands 16-bit colour over as 8 bits per channel. Errors name the file."""
    from PIL import Image

    from .. import progress as pg
    from ..errors import reading_picture

    path = os.fspath(path)
    with reading_picture(path):
        im = Image.open(path)                            # (its header: the size)
    # a phase of its own, in rows converted (a 10 Mpx photo takes some 2 s)
    with im, pg.phase(f"reading {os.path.basename(path)}", max(im.size[1], 1), unit="rows"):
        with reading_picture(path):
            raw, scale, alpha = _decoded(im)
        out = np.empty(raw.shape[:2], dtype=np.float32)
        for r in range(0, raw.shape[0], _ROWS):          # in bands of rows: a few MB at a time
            a = np.clip(raw[r:r + _ROWS].astype(float) / scale, 0.0, 1.0)
            if alpha is not None:
                al = alpha[r:r + _ROWS].astype(float) / 255.0
                al = al[..., None] if a.ndim == 3 else al
                a = a * al + (1.0 - al)                      # over white
            out[r:r + _ROWS] = tone.srgb_to_luminance(a) if a.ndim == 3 else tone.grey_to_luminance(a)
            pg.tick(r + len(a))
    return out


def _decoded(im):
    """The picture's values as an array (grey or RGB), their full scale, and alpha (or None)."""
    im.load()
    alpha = None
    if im.mode.startswith("I;16") or im.mode == "I":
        # 16-bit grey (I;16 from PNG, I from some TIFFs): full scale is 65535
        raw, scale = np.asarray(im), 65535.0
    elif im.mode == "F":
        raw, scale = np.asarray(im), 1.0
    else:
        has_alpha = "A" in im.getbands() or "transparency" in im.info
        grey = im.mode in ("1", "L", "LA") or (im.mode == "P" and not has_alpha and _grey_palette(im))
        if grey:
            raw = np.asarray(im.convert("LA") if has_alpha else im.convert("L"))
        else:
            raw = np.asarray(im.convert("RGBA" if has_alpha else "RGB"))
        scale = 255.0
        if has_alpha:
            raw, alpha = raw[..., :-1], raw[..., -1]
            raw = raw[..., 0] if grey else raw
    return raw, scale, alpha


def _grey_palette(im) -> bool:
    pal = im.getpalette() or []
    rgb = np.asarray(pal[:len(pal) // 3 * 3]).reshape(-1, 3)
    return bool(len(rgb)) and bool(np.all(rgb == rgb[:, :1]))


def resample(Y: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Y averaged over the pixels under each of size = (columns, rows) cells (area average in
    linear light, so a fine pattern looks as bright as it does from afar)."""
    from PIL import Image

    im = Image.fromarray(np.ascontiguousarray(Y, dtype=np.float32), mode="F")
    return np.asarray(im.resize(size, Image.Resampling.BOX), dtype=float)


PLANAR_WIDTH = 100.0    # mm, a plate's width when neither --width nor --height says
BED_MARGIN = 2.0        # mm left free at each side of the bed (paths._check_fits)
REF_MM = 0.1            # mm per pixel of the picture kept to compare the print with (backlit.likeness)


@dataclass
class Layout:
    """How the picture lies on the part: the picture's size on it (width along the layer: the
    plate's width, or the arc it covers on the outer face; height), the pixels used (x0, y0, x1,
    y1: all of them unless cropped), the degrees of the circle it covers (cylinder, arc), and one
    line saying how the size was chosen and what was cropped or fitted."""
    width: float
    height: float
    crop: tuple
    angle: float | None
    note: str
    reference: object = None    # the picture used (cropped), Y, top row first, at most REF_MM per px


def _mm(v: float) -> str:
    return f"{v:.1f}"


def layout(o: LithoOptions, w_px: int, h_px: int) -> Layout:
    """The picture's aspect is kept unless o.stretch: a size the options fix in both directions
    crops the picture (centred) to it; a size left open follows from the aspect, fitted to the
    bed's height (and a plate's width to the bed). The note says what was chosen."""
    a = w_px / h_px
    z_max = o.bed[2] if len(o.bed) == 3 else math.inf
    if o.shape == "planar":
        z_max -= o.foot_height if (o.foot is None or o.foot > 0) else 0.0
    picture = f"{w_px} x {h_px} px"
    fitted = ""
    if o.shape == "planar":
        w_max = o.bed[0] - 2 * BED_MARGIN
        if o.height is None:
            W = PLANAR_WIDTH if o.width is None else o.width
            H = W * h_px / w_px
            how = f"the height from the picture's aspect ({picture})"
            if H > z_max:
                H, W = z_max, z_max * a
                fitted = f"; fitted to the bed's height: {_mm(W)} mm wide instead of {_mm(o.width or PLANAR_WIDTH)}"
            return Layout(W, H, (0, 0, w_px, h_px), None, f"picture {_mm(W)} x {_mm(H)} mm: {how}{fitted}")
        H = o.height
        if o.width is None:
            W = H * a
            if W <= w_max:
                return Layout(W, H, (0, 0, w_px, h_px), None,
                              f"picture {_mm(W)} x {_mm(H)} mm: the width from the picture's aspect ({picture})")
            W = w_max
            fitted = f" (the aspect's {_mm(H * a)} mm is wider than the bed)"
        else:
            W = o.width
        return _cropped(o, W, H, w_px, h_px, None, fitted)
    # cylinder, arc: the picture on the outer face
    r = o.diameter / 2
    full = 360.0 if o.shape == "cylinder" else (ARC_ANGLE if o.angle is None else o.angle)
    if o.shape == "cylinder" and o.angle is not None:
        full = o.angle
    arc_of = lambda deg: math.radians(deg) * r if deg < 360 else 2 * math.pi * r
    if o.height is None:
        W = arc_of(full)
        H = W * h_px / w_px
        what = "the picture all round" if full >= 360 else f"the picture over {full:g} degrees"
        how = f"the height from the picture's aspect ({picture}, {what})"
        if H > z_max:
            H0, H = H, z_max
            W = H * a
            deg = math.degrees(W / r)
            how = (f"the height from the picture's aspect would be {_mm(H0)} mm, more than the bed's "
                   f"{z_max:g} mm: {_mm(H)} mm, the picture over {deg:.0f} degrees")
            if o.shape == "cylinder":
                how += " (the rest plain at --min)"
            return Layout(W, H, (0, 0, w_px, h_px), deg, f"picture {_mm(W)} x {_mm(H)} mm: {how}")
        return Layout(W, H, (0, 0, w_px, h_px), min(full, 360.0), f"picture {_mm(W)} x {_mm(H)} mm: {how}")
    H = o.height
    if o.shape == "cylinder" and o.angle is None and not o.stretch:
        W = H * a                                      # the aspect sets the angle covered
        if W < 2 * math.pi * r:
            deg = math.degrees(W / r)
            return Layout(W, H, (0, 0, w_px, h_px), deg,
                          f"picture {_mm(W)} x {_mm(H)} mm: over {deg:.0f} degrees of the cylinder from "
                          f"the picture's aspect ({picture}; the rest plain at --min; --angle to choose)")
        full = 360.0
        fitted = " (the aspect would wrap more than once round)"
    return _cropped(o, arc_of(full), H, w_px, h_px, min(full, 360.0), fitted)


def _cropped(o: LithoOptions, W: float, H: float, w_px: int, h_px: int, angle, why: str) -> Layout:
    """A size fixed both ways: the picture cropped to its aspect, centred (or stretched)."""
    if o.stretch:
        return Layout(W, H, (0, 0, w_px, h_px), angle,
                      f"picture {_mm(W)} x {_mm(H)} mm: stretched to it (--stretch)")
    want = W / H
    if abs(w_px / h_px - want) <= 0.005 * want:
        return Layout(W, H, (0, 0, w_px, h_px), angle, f"picture {_mm(W)} x {_mm(H)} mm{why}")
    if w_px / h_px > want:                             # too wide: cut the sides
        keep = max(1, int(round(h_px * want)))
        x0 = (w_px - keep) // 2
        box, cut = (x0, 0, x0 + keep, h_px), f"{w_px - keep} px off the sides"
    else:
        keep = max(1, int(round(w_px / want)))
        y0 = (h_px - keep) // 2
        box, cut = (0, y0, w_px, y0 + keep), f"{h_px - keep} px off the top and bottom"
    return Layout(W, H, box, angle,
                  f"picture {_mm(W)} x {_mm(H)} mm{why}: cropped to keep its aspect, {cut} "
                  f"({w_px} x {h_px} -> {box[2] - box[0]} x {box[3] - box[1]} px; --stretch to stretch it)")


def samples(image, o: LithoOptions) -> tuple:
    """The picture on the part's sample grid: (t, bright, s, layout, cols) with t the thickness
    per layer and sample (rows from the bottom of the picture), bright its lightness L*/100 on the
    same grid, s the samples' positions (x mm on a plate, angle rad on a cylinder, angle from
    the arc's start on an arc), the Layout and the samples the picture covers (a slice; a
    cylinder's others are plain at --min)."""
    check_options(o)
    Y_px = read_luminance(image)
    h_px, w_px = Y_px.shape
    if w_px < 8 or h_px < 8:
        raise LithoError(f"{image}: picture is {w_px} x {h_px} px; a lithophane needs at least 8 x 8")
    lay = layout(o, w_px, h_px)
    x0, y0, x1, y1 = lay.crop
    Y_px = Y_px[y0:y1, x0:x1]
    pic_w = lay.width
    lay.reference = resample(Y_px, (min(x1 - x0, max(8, int(round(pic_w / REF_MM)))),
                                    min(y1 - y0, max(8, int(round(lay.height / REF_MM))))))
    if o.shape == "planar":
        n = int(round(pic_w / o.pitch)) + 1            # samples include both ends
        s = np.linspace(0.0, pic_w, n)
        cols = slice(0, n)
    elif o.shape == "arc":
        n = int(round(pic_w / o.pitch)) + 1
        s = np.linspace(0.0, math.radians(lay.angle), n)
        cols = slice(0, n)
    else:
        r_out = o.diameter / 2
        circ = 2 * math.pi * r_out                      # the picture on the outer face
        n = max(16, int(round(circ / o.pitch)))
        s = math.pi / 2 + 2 * math.pi * np.arange(n) / n   # seam at the back (+Y), CCW = left to right
        m = n if lay.angle >= 360 else max(2, min(n, int(round(n * lay.angle / 360))))
        c0 = (n - m) // 2                                   # centred on the front (-Y)
        cols = slice(c0, c0 + m)
    pic_h = lay.height
    rows = int(round(pic_h / o.layer_height))
    if rows < 2:
        raise LithoError(f"{image}: the picture would be {pic_h:.2f} mm tall, less than two layers")
    # the note names the height printed: whole layers
    lay.note = lay.note.replace(f"x {_mm(pic_h)} mm", f"x {_mm(rows * o.layer_height)} mm", 1)
    m = cols.stop - cols.start
    if m > 8 * (x1 - x0) and rows > 8 * (y1 - y0):
        raise LithoError(f"{image}: picture is {x1 - x0} x {y1 - y0} px, too small for {m} x {rows} samples "
                         "(use a larger picture or a larger --pitch)")
    # the pixels under each sample averaged in linear light; row 0 is the picture's top
    Y = resample(Y_px, (m, rows))[::-1].copy()     # layer order: bottom of the picture first
    if m < n:                                      # a cylinder's plain part: white, at --min
        full = np.ones((rows, n))
        full[:, cols] = Y
        Y = full
    t = tone.thickness(Y, o.curve, o.min_thickness, o.max_thickness, o.attenuation, o.gamma, o.invert)
    if m < n:
        plain = np.ones(n, bool)
        plain[cols] = False
        t[:, plain] = o.min_thickness
    return t, tone.lightness(Y) / 100.0, s, lay, cols


def picture_words(lay: Layout) -> dict:
    """The layout as the JSON has it."""
    return {"note": lay.note, "used_px": list(lay.crop),
            "angle_deg": None if lay.angle is None else round(lay.angle, 2)}
