"""Strokes -> bulge points on the outer-wall toolpath -> compact map.

Sampling: a stroke crossing layers gives one point per layer it crosses; a
stroke running along a layer gives points every `spacing` mm (default twice
the line width, the smallest gap at which two bulges stay apart).  Every
point is snapped onto that layer's outer-wall toolpath, points of different
strokes closer than half the spacing are merged, and each layer's points are
sorted in the order the nozzle passes them.

Limits are checked, never applied silently: more than 64 points in a layer
is an error naming the layer; a map larger than the firmware arena is
reported with the layers that do not fit, and `annotate` can stream it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from . import faces, mapformat
from ..errors import BulgekitError
from .strokes import Picture, Stroke
from .wall import WallModel

ARENA_BYTES = mapformat.ARENA_BYTES   # BK_MAP_ARENA_BYTES
LAYER_POINTS_MAX = mapformat.LAYER_POINTS_MAX
DEFAULT_LINE_WIDTH = 0.45


class BuildError(BulgekitError):
    """Strokes that cannot become a map (message names the stroke or layer)."""


@dataclass
class BulgePoint:
    layer: int          # index into the wall model
    z: float            # layer z, mm
    u: float            # mm along the wall from the reference (0..L)
    s: float            # mm along the toolpath in print order
    x: float
    y: float
    weight: int
    sources: tuple[str, ...]


@dataclass
class BuildResult:
    model: WallModel
    points: list[BulgePoint]
    layers: list[tuple[float, list[tuple[float, float]]]]   # (z, [(x, y)]) wall order
    weights: list[list[int]] | None
    map_bytes: bytes
    quantum_um: int
    spacing: float
    record_sizes: list[int] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    # build(strict=False) only: the layers over the per-layer limit, (z, points), left out of
    # the map, and their points
    too_many: list[tuple[float, int]] = field(default_factory=list)
    over_points: list[BulgePoint] = field(default_factory=list)
    # the strokes as placed (a drawing asked for on a face moved there: faces.place), and the
    # warnings about them (crossing a corner, on the first layer: faces.warnings)
    strokes: list[Stroke] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def bulge_map(self) -> mapformat.BulgeMap:
        return mapformat.decode_map(self.map_bytes)

    @property
    def records_bytes(self) -> int:
        return len(self.map_bytes) - mapformat.HEADER_BYTES

    def overflow(self, arena: int = ARENA_BYTES) -> list[tuple[float, int]]:
        """Layers (z, record bytes) beyond the arena when sent all at once
        (the firmware keeps the 8-byte header beside the arena)."""
        used = 0
        out = []
        for (z, _), size in zip(self.layers, self.record_sizes):
            used += size
            if used > arena:
                out.append((z, size))
        return out


def _stroke_samples(st: Stroke, step: float) -> np.ndarray:
    pts = np.asarray(st.points, dtype=float).reshape(-1, 2)
    if len(pts) == 1:
        return pts
    seg = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] == 0:
        return pts[:1]
    n = max(2, int(math.ceil(s[-1] / step)) + 1)
    ss = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(ss, s, pts[:, 0]), np.interp(ss, s, pts[:, 1])], axis=1)


def sample_strokes(strokes: Sequence[Stroke], model: WallModel, spacing: float
                   ) -> dict[int, list[tuple[float, int, str]]]:
    """Per layer index: (u, weight, source) before merging."""
    if not (math.isfinite(spacing) and spacing > 0):
        raise BuildError(f"point spacing {spacing} mm must be a positive number")
    out: dict[int, list[tuple[float, int, str]]] = {}
    min_h = min(w.height for w in model.walls) or model.layer_height
    step = max(min(spacing, min_h) / 4, 0.005)
    lo, hi = model.v_range
    runs: dict[int, list[tuple[float, float, str]]] = {}   # per layer: (umin, umax, stroke)
    for k, st in enumerate(strokes):
        name = st.source or f"stroke {k + 1}"
        if not st.points:
            raise BuildError(f"{name}: empty stroke (no points)")
        arr = np.asarray(st.points, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 2 or not np.isfinite(arr).all():
            raise BuildError(f"{name}: points must be finite (u, v) pairs")
        if not 0 <= st.weight <= 255:
            raise BuildError(f"{name}: weight {st.weight} outside 0..255")
        vmin, vmax = float(arr[:, 1].min()) - st.dome, float(arr[:, 1].max()) + st.dome
        if vmin < lo - 1e-9 or vmax > hi + 1e-9:
            # said of the text, drawing or picture as asked for (a picture's dot: if not turned
            # since, its grid's place is the picture's)
            d = st.drawing
            if d is not None and (not isinstance(d, Picture) or d.holds(*st.points[0])):
                raise BuildError(d.off_the_wall(strokes, lo, hi))
            raise BuildError(
                f"{name}: stroke spans v {vmin:.2f}..{vmax:.2f} mm, outside the outer wall's "
                f"height {lo:.2f}..{hi:.2f} mm")
        if st.dome:
            _dome_samples(st, name, model, out, runs)
            continue
        smp = _stroke_samples(st, step)
        layer = model.layer_of_v(smp[:, 1])
        if (layer < 0).any():
            bad = float(smp[np.argmax(layer < 0), 1])
            raise BuildError(f"{name}: v {bad:.2f} mm falls in a layer without outer wall")
        # runs of consecutive samples in one layer
        cuts = np.nonzero(np.diff(layer))[0] + 1
        for run_idx in np.split(np.arange(len(smp)), cuts):
            li = int(layer[run_idx[0]])
            us = smp[run_idx, 0]
            umin, umax = float(us.min()), float(us.max())
            wall = model.walls[li]
            shift = wall.place_run(umin, umax)
            if shift is None:
                a, b = wall.u_covered()
                raise BuildError(
                    f"{name}: u {umin:.2f}..{umax:.2f} mm on layer z {wall.z:.2f} mm, where the "
                    f"outer wall is an open chain ({wall.length:.1f} mm, e.g. the last turn of a "
                    f"spiral) covering only u {a:.2f}..{b:.2f} mm"
                    + (f" (+/- {wall.turn:.1f} mm turns)" if wall.turn else "")
                    + "; nothing is printed there to bulge. Keep the strokes on it or below it.")
            us = us - shift
            umin, umax = umin - shift, umax - shift
            runs.setdefault(li, []).append((umin, umax, name))
            span = umax - umin
            if span < spacing:
                us_out = [(umin + umax) / 2]
            else:
                n = 1 + int(math.floor(span / spacing + 1e-9))
                us_out = list(np.linspace(umin, umax, n))
            for u in us_out:
                out.setdefault(li, []).append((float(u), st.weight, name))
    _check_extent(runs, model)
    return out


DOME_MIN_WEIGHT = 26     # a dome's layer lighter than this (under a tenth of the dwell) gets no point


def _dome_samples(st: Stroke, name: str, model: WallModel, out: dict, runs: dict) -> None:
    """A dot with height: one point at its u on every layer whose bead's middle lies within
    st.dome of its v, weighted by the dome's height there (the dwell grows toward the middle)."""
    (u, v), = st.points
    for li, wall in enumerate(model.walls):
        dv = (wall.z - wall.height / 2) - v
        if abs(dv) >= st.dome:
            continue
        w = int(round(st.weight * math.sqrt(1 - (dv / st.dome) ** 2)))
        if w < DOME_MIN_WEIGHT:
            continue
        shift = wall.place_run(u, u)
        if shift is None:
            a, b = wall.u_covered()
            raise BuildError(f"{name}: u {u:.2f} mm on layer z {wall.z:.2f} mm, where the outer wall "
                             f"covers only u {a:.2f}..{b:.2f} mm; nothing is printed there to bulge.")
        runs.setdefault(li, []).append((u - shift, u - shift, name))
        out.setdefault(li, []).append((float(u - shift), w, name))


def _check_extent(runs: dict[int, list[tuple[float, float, str]]], model: WallModel) -> None:
    """u is taken around the wall, so strokes longer than the wall would wrap
    and land on their own start; refuse instead of merging them silently."""
    bad = []
    for li in sorted(runs):
        w = model.walls[li]
        if not w.closed:
            continue  # checked in sample_strokes
        L = w.length
        lo = min(r[0] for r in runs[li])
        hi = max(r[1] for r in runs[li])
        if hi - lo > L + 1e-6:
            bad.append((li, lo, hi, L))
    if not bad:
        return
    li, lo, hi, L = max(bad, key=lambda b: b[2] - b[1] - b[3])
    start = min(runs[li], key=lambda r: r[0])[2]
    # the first stroke (along u) that runs past one full turn
    past = min((r for r in runs[li] if r[1] > lo + L + 1e-6), key=lambda r: r[0])
    zs = ", ".join(f"{model.walls[b[0]].z:.2f}" for b in bad[:6]) + (" ..." if len(bad) > 6 else "")
    raise BuildError(
        f"{past[2]}: runs to u {past[1]:.2f} mm, past the end of the outer wall: on layer "
        f"z {model.walls[li].z:.2f} mm the strokes span {hi - lo:.1f} mm (u {lo:.2f}..{hi:.2f}, "
        f"from {start}) but the wall is only {L:.1f} mm around, so the end would be written "
        f"over the start. {len(bad)} layer(s) too long (z {zs} mm); make the text/strokes "
        "smaller or shorter.")


def _merge(samples: list[tuple[float, int, str]], length: float, min_gap: float,
           closed: bool = True):
    """Merge points closer than min_gap along a wall of this length (around
    the loop when closed; an open chain's u is already checked to lie on it)."""
    pts = sorted(((u % length if closed else u, w, {src}) for u, w, src in samples),
                 key=lambda p: p[0])
    merged: list[list] = []
    for u, w, src in pts:
        if merged and u - merged[-1][0] < min_gap:
            merged[-1][1] = max(merged[-1][1], w)
            merged[-1][2] |= src
        else:
            merged.append([u, w, src])
    if closed and len(merged) > 1 and merged[0][0] + length - merged[-1][0] < min_gap:
        last = merged.pop()
        merged[0][1] = max(merged[0][1], last[1])
        merged[0][2] |= last[2]
    return merged


# Maps the toolkit writes quantise XY to 0.1 mm: a quarter of a 0.4 mm nozzle,
# under half the 0.25 mm match tolerance and far below a bump's ~1 mm, and it
# keeps text maps under 3 bytes/point (docs/reference/map-format.md: 2.79 vs 3.23 at 50 um).
MAP_QUANTUM_UM = 100


def build(strokes: Sequence[Stroke], model: WallModel, spacing: float | None = None,
          line_width: float = DEFAULT_LINE_WIDTH, quantum_um: int = MAP_QUANTUM_UM,
          max_points: int = LAYER_POINTS_MAX, strict: bool = True) -> BuildResult:
    """Place strokes on the walls and encode the map. A layer over max_points is an error;
    with strict=False (the studio's preview, which shows the rest) it is left out of the map
    and listed in the result's too_many, its points in over_points."""
    if not strokes:
        raise BuildError("no strokes to place")
    if spacing is None:
        if not (math.isfinite(line_width) and line_width > 0):
            raise BuildError(f"line width {line_width} mm must be a positive number "
                             "(the point spacing defaults to twice it)")
        spacing = 2 * line_width
    strokes = faces.place(strokes, model)
    per_layer = sample_strokes(strokes, model, spacing)
    notes = list(model.notes) + _wrap_note(per_layer, model)
    points: list[BulgePoint] = []
    layers = []
    weights = []
    too_many = []
    over_points: list[BulgePoint] = []
    for li in sorted(per_layer):
        wall = model.walls[li]
        merged = _merge(per_layer[li], wall.length, spacing / 2, wall.closed)
        over = len(merged) > max_points
        if over:
            too_many.append((wall.z, len(merged)))
            if strict:
                continue
        us = np.array([m[0] for m in merged])
        ss = wall.s_of_u(us)
        xy = wall.xy_of_s(ss)
        order = np.argsort(ss, kind="stable")
        lbp = [BulgePoint(li, wall.z, float(us[j]), float(ss[j]), float(xy[j, 0]), float(xy[j, 1]),
                          int(merged[j][1]), tuple(sorted(merged[j][2]))) for j in order]
        if over:
            over_points += lbp
            continue
        points += lbp
        layers.append((wall.z, [(bp.x, bp.y) for bp in lbp]))
        weights.append([bp.weight for bp in lbp])
    if too_many and strict:
        raise BuildError(too_many_message(too_many, max_points, spacing))
    if not layers and not too_many:
        raise BuildError("the strokes produced no points")
    use_w = any(w != 255 for lw in weights for w in lw)
    wts = weights if use_w else None
    try:
        data = mapformat.encode_map(layers, quantum_um=quantum_um,
                                    layer_height_mm=model.layer_height, weights=wts)
    except mapformat.MapFormatError as e:
        raise BuildError(f"map encoding failed: {e}") from None
    bm = mapformat.decode_map(data)
    sizes = [len(mapformat.encode_record(l, bm.has_weights)) for l in bm.layers]
    res = BuildResult(model, points, layers, wts, data, quantum_um, spacing, sizes, notes,
                      too_many, over_points, list(strokes), faces.warnings(strokes, model))
    return res


def too_many_message(too_many: list[tuple[float, int]], max_points: int, spacing: float) -> str:
    detail = ", ".join(f"z {z:.2f} mm: {n}" for z, n in too_many)
    return (f"too many points in {len(too_many)} layer(s) (at most {max_points} per layer): "
            f"{detail}. Increase --spacing (now {spacing:.2f} mm) or simplify the strokes.")


def _wrap_note(per_layer, model: WallModel) -> list[str]:
    """u runs round a closed wall: strokes placed past its length (e.g. --at beyond it) land
    from its start again. Allowed (a loop has no end), but said once, not silently."""
    for li in sorted(per_layer):
        w = model.walls[li]
        top = max(u for u, _, _ in per_layer[li])
        if w.closed and top >= w.length + 1e-6:
            return [f"strokes reach u {top:.1f} mm, past the outer wall's {w.length:.1f} mm "
                    f"(first at z {w.z:.2f} mm): the wall is a loop, so they go on from its "
                    f"start (u {top % w.length:.1f} mm)"]
    return []
