"""The picture: read from its file as relative luminance (sRGB decoded, alpha over white), laid
onto the part's sample grid (one row per layer, one sample per pitch; area average in linear
light) and put through the tone curve. What comes out is the thickness per sample and the
picture's lightness on the same grid (thickness.py builds the field from them)."""
from __future__ import annotations

import math
import os

import numpy as np

from . import tone
from .options import LithoError, LithoOptions, check_options

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


def samples(image, o: LithoOptions) -> tuple:
    """The picture on the part's sample grid: (t, bright, s, picture width) with t the thickness
    per layer and sample (rows from the bottom of the picture), bright its lightness L*/100 on the
    same grid, s the samples' positions (x mm, or angle rad on a cylinder)."""
    check_options(o)
    Y_px = read_luminance(image)
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
    Y = resample(Y_px, (n, rows))[::-1].copy()     # layer order: bottom of the picture first
    t = tone.thickness(Y, o.curve, o.min_thickness, o.max_thickness, o.attenuation, o.gamma, o.invert)
    return t, tone.lightness(Y) / 100.0, s, pic_w


