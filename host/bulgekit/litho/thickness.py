"""The thickness field: per layer and sample, how thick the plate is (the picture through the tone
curve), its frame and foot, and how the thickness is split between the two walls and the
mid-line (the walls' widths, planned for a steady extruder rate)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import picture
from .options import LithoOptions


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
    layout: object = None    # picture.Layout: how the picture lies on the part (None: calibration)

    @property
    def layers(self) -> int:
        return self.t.shape[0]


def thickness_field(image, o: LithoOptions) -> Field:
    """The field of a picture file: the picture on the sample grid through the tone curve
    (picture.samples), then frame, walls and foot (_field)."""
    t, bright, s, lay, cols = picture.samples(image, o)
    fld = _field(t, bright, s, o, lay.width, cols)
    fld.layout = lay
    return fld


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


def _field(t: np.ndarray, bright: np.ndarray, s: np.ndarray, o: LithoOptions, pic_w: float,
           cols: slice | None = None) -> Field:
    """The field from the picture's thickness (rows, samples): frame, gaps, foot. `cols`: the
    samples the picture covers (all unless a cylinder's picture covers part of it)."""
    rows, n = t.shape
    tmax = o.max_thickness
    cols = slice(0, n) if cols is None else cols
    inside = (slice(0, rows), cols)
    if o.frame > 0:
        fr = int(math.ceil(o.frame / o.layer_height))
        t[:fr] = tmax
        t[-fr:] = tmax
        if o.shape != "cylinder":
            x = s if o.shape == "planar" else s * (o.diameter / 2)    # along the outer face, mm
            edge = (x <= o.frame + 1e-9) | (x >= pic_w - o.frame - 1e-9)
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
    elif o.shape == "arc":                             # along the mid-line's arc
        r_mid = o.diameter / 2 - o.max_thickness + t / 2
        steps = ((r_mid[:, 1:] + r_mid[:, :-1]) / 2) * np.diff(s)
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
