"""Tone model of a lithophane: what the picture asks for and what the printed plate shows backlit.

Colour conversions are scikit-image's (`skimage.color`: sRGB with its transfer curve, D65, CIE
1976 L*); nothing here re-derives them.

    Y   relative luminance, linear light, 0 (black) .. 1 (white)
    L*  CIE lightness, 0 .. 100: how light a grey looks (equal steps look equal)

The picture is decoded from sRGB to Y (alpha laid over white as a viewer shows it on a white page)
and averaged in linear light (Y) onto the lithophane's samples. A plate t mm thick passes
exp(-mu t) of the backlight (Beer-Lambert, mu = --attenuation), so relative to the thinnest plate
it shows Y = exp(-mu (t - t_min)); the thickest plate's L* is the darkest the plate can show.

Tone curves (t from the picture; every curve runs from t_min for white to t_max for black):
    perceptual    predicted L* linear in the picture's L*, over L*(thickest) .. 100 (default)
    linear        thickness linear in darkness = 1 - sRGB code (Jang & Hong 2017)
    transmission  predicted Y linear in the picture's Y
--invert and --gamma act on each curve's own tone scale (code, L*/100 or Y): darkness
d = 1 - tone (tone = 1 - tone with --invert), then d ** gamma (gamma > 1 lightens mid-tones).
"""
from __future__ import annotations

import math
import os

import numpy as np

CURVES = ("perceptual", "linear", "transmission")
_ROWS = 256                     # picture rows converted at a time (bounded memory on large photos)


def _white():
    """XYZ of sRGB white (1, 1, 1): a grey of luminance Y is Y times it, and comes back from
    xyz2rgb as R = G = B (the D65 tristimulus table differs from the sRGB matrix's white in the
    fifth digit, which would make white 0.99999)."""
    from skimage.color import rgb2xyz
    return rgb2xyz(np.ones((1, 1, 3)))[0, 0]


def srgb_to_luminance(rgb) -> np.ndarray:
    """Relative luminance Y of sRGB values 0..1, shape (..., 3)."""
    from skimage.color import rgb2xyz

    rgb = np.asarray(rgb, dtype=float)
    return rgb2xyz(rgb.reshape(-1, 1, 3)).reshape(rgb.shape)[..., 1]


def grey_to_luminance(v) -> np.ndarray:
    """Relative luminance Y of sRGB grey values 0..1 (any shape)."""
    v = np.asarray(v, dtype=float)
    return srgb_to_luminance(np.repeat(v[..., None], 3, axis=-1))


def grey_xyz(Y: np.ndarray) -> np.ndarray:
    """XYZ of a neutral grey of luminance Y."""
    return np.asarray(Y, dtype=float)[..., None] * _white()


def lightness(Y) -> np.ndarray:
    """CIE L* (0..100) of relative luminance Y (0..1)."""
    from skimage.color import xyz2lab

    Y = np.clip(np.asarray(Y, dtype=float), 0.0, None)
    return xyz2lab(grey_xyz(Y).reshape(-1, 1, 3)).reshape(Y.shape + (3,))[..., 0]


def luminance(L) -> np.ndarray:
    """Relative luminance Y of CIE L* (inverse of lightness)."""
    from skimage.color import lab2xyz

    L = np.asarray(L, dtype=float)
    lab = np.stack([L, np.zeros_like(L), np.zeros_like(L)], axis=-1)
    return lab2xyz(lab.reshape(-1, 1, 3)).reshape(L.shape + (3,))[..., 1]


def to_srgb(Y) -> np.ndarray:
    """sRGB value 0..1 of a grey of luminance Y (what a screen shows for it)."""
    from skimage.color import xyz2rgb

    Y = np.clip(np.asarray(Y, dtype=float), 0.0, 1.0)
    return np.clip(xyz2rgb(grey_xyz(Y).reshape(-1, 1, 3)).reshape(Y.shape + (3,))[..., 1], 0.0, 1.0)


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
            out[r:r + _ROWS] = srgb_to_luminance(a) if a.ndim == 3 else grey_to_luminance(a)
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


# --- the plate ---------------------------------------------------------------------------------

def plate_luminance(t, mu: float, t_min: float) -> np.ndarray:
    """Y of a plate t mm thick relative to the thinnest plate (t_min) in the same light."""
    return np.exp(-mu * (np.asarray(t, dtype=float) - t_min))


def plate_range(mu: float, t_min: float, t_max: float) -> tuple[float, float]:
    """The L* the plate can show: (L* of the thickest plate, 100 for the thinnest)."""
    return float(lightness(plate_luminance(t_max, mu, t_min))), 100.0


def tone(Y: np.ndarray, curve: str) -> np.ndarray:
    """The curve's own tone scale 0 (black) .. 1 (white): sRGB code (linear), L*/100
    (perceptual) or Y (transmission)."""
    Y = np.clip(np.asarray(Y, dtype=float), 0.0, 1.0)
    if curve == "linear":
        return to_srgb(Y)
    if curve == "perceptual":
        return lightness(Y) / 100.0
    return Y


def thickness(Y: np.ndarray, curve: str, t_min: float, t_max: float, mu: float,
              gamma: float = 1.0, invert: bool = False) -> np.ndarray:
    """Thickness (mm) for picture luminance Y by a tone curve (module docstring)."""
    v = tone(Y, curve)
    d = np.clip(v if invert else 1.0 - v, 0.0, 1.0) ** gamma
    if curve == "linear":
        return t_min + d * (t_max - t_min)
    y_lo = math.exp(-mu * (t_max - t_min))                     # the thickest plate's Y
    if curve == "perceptual":
        L_lo = float(lightness(y_lo))
        y = luminance(100.0 - d * (100.0 - L_lo))
    else:
        y = 1.0 - d * (1.0 - y_lo)
    y = np.clip(y, y_lo, 1.0)
    return np.clip(t_min - np.log(y) / mu, t_min, t_max)


def target_lightness(L_picture: np.ndarray, L_lo: float, invert: bool = False) -> np.ndarray:
    """What the plate should show: the picture's L* (its negative with invert) scaled onto the
    plate's range L_lo .. 100. The perceptual curve aims at exactly this (at gamma 1)."""
    L = np.asarray(L_picture, dtype=float)
    if invert:
        L = 100.0 - L
    return L_lo + (100.0 - L_lo) * L / 100.0


def similarity(target: np.ndarray, predicted: np.ndarray) -> dict:
    """Mean |dL*| and SSIM on L* (skimage, 7 x 7 windows, data range 100) of two L* maps."""
    from skimage.metrics import structural_similarity

    d = float(np.abs(predicted - target).mean())
    ssim = (float(structural_similarity(target, predicted, data_range=100.0))
            if min(target.shape) >= 7 else float("nan"))
    return {"mean_abs_dL": d, "ssim_L": ssim}


# --- calibration plate ---------------------------------------------------------------------------

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
