"""Tone model of a lithophane: what the picture asks for and what the printed plate shows backlit.

Colour conversions are scikit-image's (`skimage.color`: sRGB with its transfer curve, D65, CIE
1976 L*); nothing here re-derives them.

    Y   relative luminance, linear light, 0 (black) .. 1 (white)
    L*  CIE lightness, 0 .. 100: how light a grey looks (equal steps look equal)

The picture is decoded from sRGB to Y (alpha laid over white as a viewer shows it on a white page)
and averaged in linear light (Y) onto the lithophane's samples (picture.py). A plate t mm thick passes
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

import numpy as np

CURVES = ("perceptual", "linear", "transmission")


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

