"""Lithophanes printed with one variable-width mid-line per layer (Jang & Hong 2017, Algorithm 1).

The part stands on the bed and every layer is one row of the picture. Per layer there is the back
face (a straight line for `planar`, a circle for `cylinder`), the front face carrying the relief
(thickness from the picture: dark = thick), one wall line inside each face, and between the walls a
single mid-line whose width is the gap at every point. That width is set by head speed at one
extruder rate (firmware width mode, M723: v = q / (W * H)), so the gap fills in one pass.

    plan = litho.plan_lithophane("cat.png", LithoOptions(shape="cylinder"))
    out = litho.make("cat.png", "out/")      # .litho.gcode .stock.gcode .stl .transmission.png .json

Geometry per layer, on the sample grid (no polygon offsets): every sample has a probe across
the layer (vertical for planar, radial for cylinder) from the back face to the relief at
thickness t. Along it lie three bands: the back wall [0, wb], the mid-line [wb, t - wf] and the
front wall [t - wf, t], wb = wf = one line width unless said below. The bands between two
samples are trapezoids (in polar form for the cylinder), so together they are exactly the body
the STL holds, and each piece lays its band's area (width = area / length: the filament is the
body's volume). Only the split between the lines changes below, never the thickness.

  - A gap t - 2 w narrower than a printable mid-line (`min_line`, by default the narrowest line
    the mid-line's rate lays at `max_speed`, q / (U * H), but at least half a line) is not
    snapped. light_gaps "mid-line" (default): the walls narrow (to wall_min at least) so that a
    mid-line of min_line x (1 + MID_MARGIN) runs on unbroken. light_gaps "walls": the two walls
    widen by half of it each (ww = w + gap / 2) and lay it at their own rate (width by feedrate:
    v = q_wall / (W * H)). Mid-line pieces narrower than min_line give their area to the walls.
  - With `rate_accel` (light_gaps "mid-line") the mid-line's width, so its speed, is planned
    along the layer as a planner plans speeds (_steady_walls): small steps from sample to sample,
    a centre line that turns little; the walls (wall_min .. wall_max, back and front apart) take
    what the picture changes faster than that, so the extruder runs at its set rate through
    the planner's ramps.
  - A wall along a slope is longer than its band is wide; it keeps its width (so its speed) and
    takes what it lays beyond its band from the mid-line beside it.
  - Wider than `max_line`: the layer gets n = ceil(gap / max_line) mid-lines of gap / n each.
  - Pieces merge where they run on straight (a line within CHORD_TOL of every point they
    replace, its ends free) at one width (the merged width and area per sample within WIDTH_TOL
    of every piece's), none is shorter than MIN_MOVE (6 steps), and with `block_rate` none is
    shorter than its speed / block_rate: short pieces merge with their neighbours (area summed:
    the volume is kept).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .options import LithoError, LithoOptions
from .thickness import Field, thickness_field


# --- per-layer paths -----------------------------------------------------------------------

CHORD_TOL = 0.01       # mm: how far a merged piece may stray from the points it replaces
WIDTH_TOL = 0.005      # pieces merge only where their widths agree within this share
MIN_MOVE = 0.075       # mm: 6 steps at 80 steps/mm, the shortest move Marlin executes
ROUNDING = 0.0015      # mm: a move written to 0.001 mm in X and Y is up to this much shorter


@dataclass
class Section:
    """One continuous extrusion path: points (k, 2) in part coordinates (mm), filament per piece
    (k - 1,) in mm, head speed per piece (mm/s), and the kind: wall, mid-line, connector.
    `u` is each point's place along the layer in samples (for volume checks)."""
    kind: str
    pts: np.ndarray
    e: np.ndarray
    v: np.ndarray
    width: np.ndarray          # line width per piece (mm): deposited area / length
    u: np.ndarray | None = None


@dataclass
class Layer:
    z: float
    sections: list
    gap: np.ndarray            # the mid-line band's extent across the layer per sample (mm)
    wall: np.ndarray           # each wall's band across the layer per sample (mm): line width + share


@dataclass
class Plan:
    options: LithoOptions
    field: Field
    layers: list = field(default_factory=list)
    origin: tuple = (0.0, 0.0)     # bed position of the part's (0, 0)
    counts: dict = field(default_factory=dict)


def _layer_polygon(o: LithoOptions, fld: Field, k: int):
    """The layer's cross-section (shapely), as the STL has it."""
    from shapely.geometry import Polygon

    t = fld.t[k]
    if o.shape == "arc":
        r_in, a = o.diameter / 2 - o.max_thickness, arc_start(fld) + fld.s
        outer = np.column_stack([(r_in + t) * np.cos(a), (r_in + t) * np.sin(a)])
        inner = np.column_stack([r_in * np.cos(a), r_in * np.sin(a)])[::-1]
        return Polygon(np.vstack([outer, inner]))
    if o.shape == "planar":
        if k < fld.n_foot:                                  # the foot block, centred on the plate
            y0 = (o.max_thickness - o.foot) / 2
            return Polygon([(0, y0), (fld.s[-1], y0), (fld.s[-1], y0 + o.foot), (0, y0 + o.foot)])
        front = np.column_stack([fld.s, t])[::-1]
        return Polygon(np.vstack([[(0.0, 0.0), (fld.s[-1], 0.0)], front]))
    r_in = o.diameter / 2 - o.max_thickness
    c, sn = np.cos(fld.s), np.sin(fld.s)
    outer = np.column_stack([(r_in + t) * c, (r_in + t) * sn])
    inner = np.column_stack([r_in * c, r_in * sn])[::-1]
    return Polygon(outer, [inner])


def _speeds(width, o: LithoOptions, flow):
    """Head speed for a line of width W at volumetric rate q: v = q / (W * H) (eq. 1), capped."""
    with np.errstate(divide="ignore"):
        v = flow / np.maximum(width * o.layer_height, 1e-12)
    return np.clip(v, o.min_speed, o.max_speed)


def _capped(s: Section, o: LithoOptions, flow) -> np.ndarray:
    """Laid pieces whose speed was capped: their volumetric rate W * H * v is below the flow."""
    return (s.e > 0) & (s.width * o.layer_height * s.v < flow * (1 - 1e-6))


def arc_start(fld: Field) -> float:
    """The angle (rad) where an arc's samples start: the arc is centred on the front (-Y), its
    convex face towards the front, the picture left to right seen from there."""
    return -math.pi / 2 - float(fld.s[-1]) / 2


def end_unit(o: LithoOptions) -> float:
    """Along an open layer, the samples' unit per mm: 1 on a plate (x mm); on an arc (angle) 1 /
    the radius of a thin plate's middle, where its end walls are measured."""
    return 1.0 if o.shape == "planar" else 1.0 / (o.diameter / 2 - o.max_thickness + o.min_thickness / 2)


class _Band:
    """Points across the layer on each sample's probe (planar: vertical lines at x; cylinder and
    arc: radial lines at angle s), and the area of a band between two probes. Everything in a layer
    is a band between two offsets from the back face, so the bands add up to the body exactly
    (the STL is linear between samples too)."""

    def __init__(self, o: LithoOptions, fld: Field, k: int, x=None):
        self.o, self.closed, self.arc = o, o.shape == "cylinder", o.shape == "arc"
        if self.closed:
            self.r_in = o.diameter / 2 - o.max_thickness
            self.c, self.sn = np.cos(fld.s), np.sin(fld.s)
            self.dth = 2 * math.pi / len(fld.s)
        elif self.arc:
            self.r_in = o.diameter / 2 - o.max_thickness
            self.x = fld.s if x is None else x
            a = arc_start(fld) + self.x
            self.c, self.sn = np.cos(a), np.sin(a)
        else:
            self.x = fld.s if x is None else x
            self.y0 = (o.max_thickness - o.foot) / 2 if k < fld.n_foot else 0.0

    def points(self, off):
        """Points at `off` mm from the back face (per sample); a closed band repeats its first."""
        if self.closed:
            r = self.r_in + off
            p = np.column_stack([r * self.c, r * self.sn])
            return np.vstack([p, p[:1]])
        if self.arc:
            r = self.r_in + off
            return np.column_stack([r * self.c, r * self.sn])
        return np.column_stack([self.x, self.y0 + off])

    def area(self, lo, hi):
        """Area (mm^2) of the band between offsets lo and hi, per piece between samples."""
        h = hi - lo
        if self.closed:
            hr = h * (self.r_in + (lo + hi) / 2)             # exact for an annulus sector
            hr = np.append(hr, hr[:1])
            return (hr[:-1] + hr[1:]) / 2 * self.dth
        if self.arc:
            hr = h * (self.r_in + (lo + hi) / 2)
            return (hr[:-1] + hr[1:]) / 2 * np.abs(np.diff(self.x))
        return (h[:-1] + h[1:]) / 2 * np.abs(np.diff(self.x))


def _width_runs(seg, area, laid, du) -> np.ndarray:
    """Where runs of pieces that may merge start (and the end): a run is all laid or all not, and
    in a laid run the merged piece's width (area / length) and its area per sample interval
    (area / du, what each sample it spans gets) stay within WIDTH_TOL of every member's,
    greedily as long as they can. Neighbours that differ a little merge wherever they lie, not
    only inside a fixed bin. A piece across the layer (du = 0: a planar plate's end) stands
    alone."""
    n = len(seg)
    with np.errstate(divide="ignore", invalid="ignore"):
        wd = np.where(seg > 1e-12, area / seg, 0.0)
        pu = np.where(du > 1e-9, area / du, -1.0)
    # runs of one width and one area per sample (the plain wall, flat areas) are taken as one
    # item: the loop below sees only where they change
    step = np.flatnonzero((laid[1:] != laid[:-1]) | (np.abs(wd[1:] - wd[:-1]) > 1e-9 * wd[1:])
                          | (np.abs(pu[1:] - pu[:-1]) > 1e-9 * np.abs(pu[1:])) | (pu[1:] < 0))
    first = np.concatenate([[0], step + 1])
    A, L, U = (np.add.reduceat(x, first).tolist() for x in (area, seg, du))
    W, P, on = wd[first].tolist(), pu[first].tolist(), laid[first].tolist()
    lo_tol, hi_tol = 1 - WIDTH_TOL, 1 + WIDTH_TOL
    starts = [0]
    a = l_ = u_ = wlo = whi = plo = phi = 0.0
    state = None
    for i, (ai, li, ui, wi, pi, oi) in enumerate(zip(A, L, U, W, P, on)):
        if oi != state or pi < 0 or plo < 0:
            starts.append(i)
            state, a, l_, u_, wlo, whi, plo, phi = oi, ai, li, ui, wi, wi, pi, pi
            continue
        if not oi:
            continue
        a2, l2, u2 = a + ai, l_ + li, u_ + ui
        wlo2 = wi if wi < wlo else wlo
        whi2 = wi if wi > whi else whi
        plo2 = pi if pi < plo else plo
        phi2 = pi if pi > phi else phi
        w, pm = a2 / (l2 if l2 > 1e-12 else 1e-12), a2 / u2
        if w > wlo2 * hi_tol or w < whi2 * lo_tol or pm > plo2 * hi_tol or pm < phi2 * lo_tol:
            starts.append(i)
            a, l_, u_, wlo, whi, plo, phi = ai, li, ui, wi, wi, pi, pi
        else:
            a, l_, u_, wlo, whi, plo, phi = a2, l2, u2, wlo2, whi2, plo2, phi2
    b = first[np.unique(starts)]
    return np.append(b, n)


def _line_end(px, py, sx, sy, th, j, last):
    """Where a merged piece from (sx, sy) at angle th ends beside point j: on its line within
    CHORD_TOL of the point, and there as far from point j + 1 as point j is (the next piece keeps
    its length, so its width, if it stays alone), else as near that as the tolerance allows."""
    c, sn = math.cos(th), math.sin(th)
    ox, oy = px[j] - sx, py[j] - sy
    d = ox * c + oy * sn                            # point j's foot on the line
    h2 = (ox * sn - oy * c) ** 2
    if j == last or h2 >= CHORD_TOL ** 2:
        return sx + d * c, sy + d * sn
    room = math.sqrt(CHORD_TOL ** 2 - h2)          # the line's stretch within the tolerance
    qx, qy = sx - px[j + 1], sy - py[j + 1]
    L2 = (px[j + 1] - px[j]) ** 2 + (py[j + 1] - py[j]) ** 2
    b = qx * c + qy * sn                            # |E - point j + 1|^2 = (t + b)^2 + const
    disc = b * b - (qx * qx + qy * qy) + L2
    if disc >= 0:                                   # the root nearer point j's foot
        r = math.sqrt(disc)
        t = -b - r if abs(-b - r - d) < abs(-b + r - d) else -b + r
    else:                                           # no such place: the nearest approach
        t = -b
    if t < d - room:
        t = d - room
    elif t > d + room:
        t = d + room
    return sx + t * c, sy + t * sn


def _sleeve(px, py, runs, last, keep, ox, oy):
    """Merged pieces over each run (i0, i1) of points (lists px, py), each within CHORD_TOL of
    every point it replaces: from its start, the longest run of points that one line can pass
    within the tolerance of (the directions each point allows, intersected), ending on that line
    beside its last point (so not always on a point: _line_end). Ends are written to ox, oy
    (the points' places, given as px, py) and marked in `keep`; the path's last point (`last`)
    stays where it is. A run starts from ox[i0], oy[i0] (where the run before it ended)."""
    tol, inf, pi, two_pi = CHORD_TOL, math.inf, math.pi, 2 * math.pi
    hypot, atan2, asin = math.hypot, math.atan2, math.asin
    for i0, i1 in runs:
        sx, sy = ox[i0], oy[i0]
        lo, hi = -inf, inf
        ref = None
        j = i0 + 1
        while j <= i1:
            qx, qy = px[j] - sx, py[j] - sy
            r = hypot(qx, qy)
            if r > tol:
                phi = atan2(qy, qx)
                if ref is not None:                 # the same turn as the cone
                    if phi - ref > pi:
                        phi -= two_pi
                    elif ref - phi > pi:
                        phi += two_pi
                da = 0.0 if j == last else asin(tol / r)
                nlo, nhi = phi - da, phi + da
                if nlo < lo:
                    nlo = lo
                if nhi > hi:
                    nhi = hi
                if nlo > nhi:
                    # (a fresh cone takes any point: here at least one lies between start and j)
                    # the line ends beside point j - 1; the next one starts there
                    e = _line_end(px, py, sx, sy, (lo + hi) / 2, j - 1, last)
                    sx, sy = ox[j - 1], oy[j - 1] = e
                    keep[j - 1] = True
                    lo, hi, ref = -inf, inf, None
                    continue
                lo, hi = nlo, nhi
                if ref is None:
                    ref = phi
            j += 1
        # the run's end: on the line beside point i1 (the path's last point: on it)
        if i1 != last and ref is not None:
            ox[i1], oy[i1] = _line_end(px, py, sx, sy, (lo + hi) / 2, i1, last)
        keep[i1] = True


def _keep_straight(pts, area, laid, u):
    """Points to keep when neighbouring pieces merge, and where they are: pieces run on as one
    where they are laid at one width (the merged width within WIDTH_TOL of every piece's,
    _width_runs) or not laid, and the path strays no more than CHORD_TOL from the points it
    drops (_sleeve). Returns (keep, points)."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    bounds = _width_runs(seg, area, laid, np.abs(np.diff(u)))
    keep = np.zeros(len(pts), bool)
    keep[bounds] = True
    multi = np.flatnonzero(np.diff(bounds) > 1)
    if not len(multi):
        return keep, pts
    px, py = pts[:, 0].tolist(), pts[:, 1].tolist()
    ox, oy = px[:], py[:]                           # where the points are after the merge
    last = len(pts) - 1
    _sleeve(px, py, zip(bounds[multi].tolist(), bounds[multi + 1].tolist()), last, keep, ox, oy)
    orig, pts = pts, np.column_stack([ox, oy])
    k = np.flatnonzero(keep)
    # A merged piece's width is its area over its chord, a little shorter than the path, and a
    # run the chord split has widths of its own: where a merged piece is off a member by more
    # than the tolerance, it keeps all its points.
    chord = np.linalg.norm(pts[k[1:]] - pts[k[:-1]], axis=1)
    on = laid[k[:-1]] & (np.diff(k) > 1)
    if on.any():
        du = np.abs(np.diff(u))
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.add.reduceat(area, k[:-1])
            bad = np.zeros(len(a), bool)
            # the width on the chord, and the area per sample interval, against every member's
            for per, merged in ((seg, chord), (du, np.add.reduceat(du, k[:-1]))):
                each = np.where(laid, area / np.maximum(per, 1e-12), 0.0)
                m = a / np.maximum(merged, 1e-12)
                lo, hi = np.minimum.reduceat(each, k[:-1]), np.maximum.reduceat(each, k[:-1])
                bad |= (m > lo * (1 + WIDTH_TOL)) | (m < hi * (1 - WIDTH_TOL))
        bad = np.flatnonzero(on & bad)
        for j in bad.tolist():
            keep[k[j]:k[j + 1]] = True
    # A piece left on its own beside a moved end is longer or shorter by the move: where that
    # puts its width off by more than the tolerance, the end goes back to its point, and the
    # merged pieces that end also ends keep all their points (so they stay on the tolerance).
    with np.errstate(divide="ignore", invalid="ignore"):
        wd = area / np.maximum(seg, 1e-12)
    moved = np.any(pts != orig, axis=1)
    while moved.any():
        k = np.flatnonzero(keep)
        i = k[:-1][(np.diff(k) == 1) & laid[k[:-1]]]
        w = area[i] / np.maximum(np.linalg.norm(pts[i + 1] - pts[i], axis=1), 1e-12)
        bad = i[np.abs(w - wd[i]) > WIDTH_TOL * wd[i]]
        ends = np.union1d(bad, bad + 1)
        ends = ends[moved[ends]]
        if not len(ends):
            break
        for e in ends.tolist():
            pts[e], moved[e] = orig[e], False
            pos = int(np.searchsorted(k, e))
            if pos > 0:
                keep[k[pos - 1]:e] = True
            if pos < len(k) - 1:
                keep[e:k[pos + 1]] = True
    return keep, pts


def _long_enough(pts, area, laid, o: LithoOptions, flow, rate):
    """Points to keep so that every laid piece is at least MIN_MOVE long as written (ROUNDING)
    and, with a block-rate budget, no shorter than its speed / rate: short pieces merge with
    their laid neighbours (the areas add up, width = area / length, so the volume is kept). Also
    the pieces of laid runs that cannot be made long enough at all (too short in total)."""
    n = len(area)
    keep = np.ones(n + 1, bool)
    lonely = np.zeros(n, bool)
    L = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    H = o.layer_height
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.clip(flow * L / np.maximum(area * H, 1e-12), o.min_speed, o.max_speed)
    need = np.maximum(MIN_MOVE + ROUNDING, v / rate) if rate else np.full(n, MIN_MOVE + ROUNDING)
    short = laid & (L < need - 1e-9)
    if not short.any():
        return keep, lonely
    # runs of laid pieces that hold a short one
    edge = np.diff(np.concatenate([[0], laid.astype(np.int8), [0]]))
    r0, r1 = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
    has = np.add.reduceat(short.astype(int), r0) > 0 if len(r0) else []
    px, py, al = pts[:, 0].tolist(), pts[:, 1].tolist(), area.tolist()
    lo, hi, inv_rate = o.min_speed, o.max_speed, (1.0 / rate if rate else 0.0)
    for i, j in zip(r0[has], r1[has]):
        groups, s, acc = [], i, 0.0
        for q in range(i, j):
            acc += al[q]
            ln = math.hypot(px[q + 1] - px[s], py[q + 1] - py[s])
            sp = min(max(flow * ln / max(acc * H, 1e-12), lo), hi)
            if ln >= max(MIN_MOVE + ROUNDING, sp * inv_rate) - 1e-9:
                groups.append((s, q + 1))
                s, acc = q + 1, 0.0
        if s < j:                                   # a short tail joins the group before it
            if not groups:
                lonely[i:j] = True
                continue
            groups[-1] = (groups[-1][0], j)
        for g0, g1 in groups:
            keep[g0 + 1:g1] = False
    return keep, lonely


def _pieces(kind, pts, area, laid, u, o: LithoOptions, flow, merge=True) -> tuple:
    """A section from points and the area each piece lays: straight runs merged, short pieces
    merged (block-rate budget). Returns (section or None if nothing is laid, lonely) where
    lonely marks laid pieces that could not be made long enough (the caller gives them away)."""
    if merge:
        keep, pts = _keep_straight(pts, area, laid, u)
        k1 = np.flatnonzero(keep)
        pts, area, laid, u = pts[k1], np.add.reduceat(area, k1[:-1]), laid[k1[:-1]], u[k1]
        back = k1
    else:
        back = np.arange(len(pts))
    keep, lonely = _long_enough(pts, area, laid, o, flow, o.block_rate)
    if lonely.any():                                # in the caller's piece numbering
        out = np.zeros(int(back[-1]), bool)
        for i in np.flatnonzero(lonely):
            out[back[i]:back[i + 1]] = True
        return None, out
    k2 = np.flatnonzero(keep)
    pts, area, laid, u = pts[k2], np.add.reduceat(area, k2[:-1]), laid[k2[:-1]], u[k2]
    if not laid.any():
        return None, None
    L = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    width = np.where(laid, area / np.maximum(L, 1e-12), 0.0)
    v = np.where(laid, _speeds(width, o, flow), o.travel_speed)
    if o.block_rate:                                # a head only passing through: slower, not cut up
        v = np.where(laid, v, np.minimum(v, np.maximum(L * o.block_rate, o.min_speed)))
    e = np.where(laid, area * o.layer_height / o.filament_area, 0.0)
    return Section(kind, pts, e, v, width, u), None


def _trim(s: Section) -> Section:
    """An open path without its unlaid ends."""
    on = np.flatnonzero(s.e > 0)
    a, b = on[0], on[-1] + 1
    return Section(s.kind, s.pts[a:b + 1], s.e[a:b], s.v[a:b], s.width[a:b], s.u[a:b + 1])


def _layer_paths(o: LithoOptions, fld: Field, k: int, wall_q, mid_q, counts: dict):
    """Walls and mid-line(s) of layer k, each a band between offsets from the back face on every
    sample's probe: back wall [0, wb], mid-line [wb, t - wf], front wall [t - wf, t], with the
    walls' widths from the field (wall_widths: a line width, narrowed for a thin mid-line or
    widened to share a light gap, and planned for a steady mid-line). A mid-line piece narrower
    than min_line gives its area to the two walls, half each, and the head moves on along the
    middle there. Returns (walls, mids, gm, mean wall width)."""
    t = fld.t[k].astype(float)
    n = len(t)
    w, nl = o.line_width, int(fld.lines[k])
    lmin = o.line_min()
    planar = o.shape != "cylinder"                  # open: a plate or an arc, with two ends
    unit = end_unit(o)
    wb, wf = fld.ww[k], fld.wf[k]                  # back and front wall widths
    ww = (wb + wf) / 2
    gm = t - wb - wf
    if planar:
        # the mid-line runs between the end walls (x = w .. X - w), the walls' centre lines from
        # x = w / 2 to X - w / 2: the samples inside, and the ends
        X = fld.s[-1]
        ends = lambda a: np.concatenate([[a * unit], fld.s[(fld.s > a * unit + 1e-9) & (fld.s < X - a * unit - 1e-9)],
                                         [X - a * unit]])
        xm = ends(w)
        um = xm / (X / (n - 1))
        wwm = np.interp(xm, fld.s, wb)
        gmm = np.interp(xm, fld.s, t) - wwm - np.interp(xm, fld.s, wf)
        band = _Band(o, fld, k, xm)
    else:
        wwm, gmm, band = wb, gm, _Band(o, fld, k)
        um = np.arange(n + 1, dtype=float)
    # the walls: centre lines half their band in from each face
    if planar:
        xw = ends(w / 2)
        uw = xw / (X / (n - 1))
        tw, wbv, wfv = np.interp(xw, fld.s, t), np.interp(xw, fld.s, wb), np.interp(xw, fld.s, wf)
        bw = _Band(o, fld, k, xw)
        move_w = lambda a: np.diff(np.interp(xw, xm, np.concatenate([[0.0], np.cumsum(a)])))
        move_m = lambda a: np.diff(np.interp(xm, xw, np.concatenate([[0.0], np.cumsum(a)])))
    else:
        uw, tw, wbv, wfv, bw = um, t, wb, wf, band
        move_w = move_m = lambda a: a
    back_p, front_p = bw.points(wbv / 2), bw.points(tw - wfv / 2)
    back_a, front_a = bw.area(np.zeros(len(wbv)), wbv), bw.area(tw - wfv, tw)
    # A wall along a slope is longer than its band is wide: at its own width it lays a little
    # more than the band, taken from the mid-line beside it, so that the walls keep one speed.
    bar = lambda a: (a + np.roll(a, -1))[: len(back_a)] / 2
    want = [np.maximum(bar(w_) * np.linalg.norm(np.diff(p_, axis=0), axis=1) - a_, 0.0)
            for p_, a_, w_ in ((back_p, back_a, wbv), (front_p, front_a, wfv))]
    mid_w = move_w(band.area(wwm, wwm + gmm))
    take = want[0] + want[1]
    scale = np.where(take > mid_w, mid_w / np.maximum(take, 1e-12), 1.0)
    back_a, front_a = back_a + want[0] * scale, front_a + want[1] * scale
    taken = move_m(take * scale)
    given = np.zeros(len(um) - 1)                   # mid-line area per piece given to the walls
    mids = []
    for i in range(nl):
        lo, hi = wwm + gmm * i / nl, wwm + gmm * (i + 1) / nl
        pts = band.points((lo + hi) / 2)
        area = np.maximum(band.area(lo, hi) - taken / nl, 0.0)
        L = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        laid = area >= lmin * L * (1 - 1e-6)
        while True:
            sec, lonely = _pieces("mid-line", pts, area, laid, um, o, mid_q)
            if lonely is None:
                break
            laid = laid & ~lonely                   # runs too short for the block rate: to the walls
        given += np.where(laid, 0.0, area)
        if sec is None:                             # the walls merge all along
            continue
        if not band.closed:
            sec = _trim(sec)
            if i % 2:                               # serpentine: odd lines run back
                sec = _reverse(sec)
        mids.append(sec)
    counts["shared_mm3"] += float(given.sum() * o.layer_height)
    g_w = move_w(given)
    back_a, front_a = back_a + g_w / 2, front_a + g_w / 2
    if planar:
        # one loop, counter-clockwise: back left to right, up the right end, front right to
        # left, down the left end; the ends are plain lines of one line width
        nw = len(xw)
        pts = np.vstack([back_p, front_p[::-1], back_p[:1]])
        end_a = np.linalg.norm(pts[[nw, 2 * nw]] - pts[[nw - 1, 2 * nw - 1]], axis=1) * w
        area = np.concatenate([back_a, [end_a[0]], front_a[::-1], [end_a[1]]])
        uu = np.concatenate([uw, uw[::-1], uw[:1]])
        walls, _ = _pieces("wall", pts, area, np.ones(len(area), bool), uu, o, wall_q)
        walls = [walls]
    else:
        lay = np.ones(n, bool)
        outer, _ = _pieces("wall", front_p, front_a, lay, uw, o, wall_q)
        if np.all(wb == w) and np.all(g_w == 0):
            # a plain circle: chords of as many samples as the chord tolerance allows
            r, step = band.r_in + w / 2, 1
            # a chord over k samples strays from the points it drops by r (cos(a) - cos(k dth / 2)),
            # a the angle of the point nearest its middle
            while step < n // 3 and r * (math.cos(((step + 1) % 2) * band.dth / 2)
                                         - math.cos((step + 1) * band.dth / 2)) <= CHORD_TOL:
                step += 1
            keep = np.unique(np.append(np.arange(0, n + 1, step), n))
            inner, _ = _pieces("wall", back_p[keep][::-1], np.add.reduceat(back_a, keep[:-1])[::-1],
                               np.ones(len(keep) - 1, bool), uw[keep][::-1], o, wall_q, merge=False)
        else:
            inner, _ = _pieces("wall", back_p[::-1], back_a[::-1], lay, uw[::-1], o, wall_q)
        walls = [outer, inner]                      # outer counter-clockwise, inner clockwise
    return walls, mids, gm, ww


def _reverse(s: Section) -> Section:
    u = None if s.u is None else s.u[::-1].copy()
    return Section(s.kind, s.pts[::-1].copy(), s.e[::-1].copy(), s.v[::-1].copy(), s.width[::-1].copy(), u)


def _rotate_loop(s: Section, near, o: LithoOptions | None = None) -> Section:
    """A closed loop started at its point nearest `near`: a vertex, or a new one on a long piece
    (split in two, each part laying its share), so that the way there is short."""
    a, b = s.pts[:-1], s.pts[1:]
    d = b - a
    L2 = np.maximum((d * d).sum(axis=1), 1e-24)
    f = np.clip(((near - a) * d).sum(axis=1) / L2, 0.0, 1.0)
    q = a + d * f[:, None]
    j = int(np.argmin(np.linalg.norm(q - near, axis=1)))
    Lj = math.sqrt(L2[j])
    need = MIN_MOVE + ROUNDING
    if o is not None and o.block_rate:
        need = max(need, s.v[j] / o.block_rate)
    if f[j] * Lj >= need and (1 - f[j]) * Lj >= need:         # split piece j at q
        fj = f[j]
        pts = np.vstack([s.pts[:j + 1], q[j:j + 1], s.pts[j + 1:]])
        ins = lambda x, y0, y1: np.concatenate([x[:j], [y0, y1], x[j + 1:]])
        e = ins(s.e, s.e[j] * fj, s.e[j] * (1 - fj))
        s = Section(s.kind, pts, e, ins(s.v, s.v[j], s.v[j]), ins(s.width, s.width[j], s.width[j]),
                    None if s.u is None else np.concatenate([s.u[:j + 1], [s.u[j] + (s.u[j + 1] - s.u[j]) * fj],
                                                              s.u[j + 1:]]))
        i = j + 1
    else:
        i = j if f[j] < 0.5 else j + 1
    pts = s.pts[:-1]
    i %= len(pts)
    if i == 0:
        return s
    pts = np.vstack([pts[i:], pts[:i], pts[i:i + 1]])
    roll = lambda x: np.concatenate([x[i:], x[:i]])
    u = None if s.u is None else np.concatenate([s.u[i:-1], s.u[:i], s.u[i:i + 1]])
    return Section(s.kind, pts, roll(s.e), roll(s.v), roll(s.width), u)


def _orient(s: Section, near) -> Section:
    """An open path started at the end nearer `near`."""
    if np.linalg.norm(s.pts[-1] - near) < np.linalg.norm(s.pts[0] - near):
        return _reverse(s)
    return s


def _join(s: Section, at, o: LithoOptions, flow) -> Section:
    """A section started from `at` when the way there is too short for a move of its own (under
    MIN_MOVE, or under its speed / block rate): its first piece begins at `at` and lays the same
    volume over the longer way (no extra filament at the join)."""
    d = float(np.linalg.norm(s.pts[0] - at))
    if d <= 1e-6 or d >= o.retract_min:
        return s
    need = max(MIN_MOVE + ROUNDING, s.v[0] / o.block_rate if o.block_rate else 0.0)
    if d >= need:
        return s                                    # a connector of its own (_Writer)
    pts = s.pts.copy()
    pts[0] = at
    e, v, width = s.e.copy(), s.v.copy(), s.width.copy()
    L = float(np.linalg.norm(pts[1] - pts[0]))
    if e[0] > 0:
        width[0] = width[0] * np.linalg.norm(s.pts[1] - s.pts[0]) / max(L, 1e-12)
        v[0] = float(_speeds(np.array([width[0]]), o, flow)[0])
    return Section(s.kind, pts, e, v, width, s.u)


def plan_lithophane(image, o: LithoOptions | None = None, progress=None) -> Plan:
    """Paths for every layer. `progress(done, total)` is called now and then."""
    o = o or LithoOptions()
    fld = image if isinstance(image, Field) else thickness_field(image, o)   # a Field: calibration_field
    o = replace(o, foot=fld.foot)          # the plan and its files carry the depth in use
    if o.width is None:                    # ... and the width (a plate's; 100 as before elsewhere)
        o = replace(o, width=float(fld.picture_mm[0]) if o.shape == "planar" and fld.layout else 100.0)
    _check_fits(o, fld)
    plan = Plan(o, fld)
    plan.counts.update(shared_mm3=0.0)
    H = o.layer_height
    pos = None
    capped = 0
    for k in range(fld.layers):
        ratio = o.first_layer_speed / o.wall_speed if k == 0 else 1.0
        wall_q, mid_q = o.wall_flow * ratio, o.mid_flow * ratio
        walls, mids, gm, ww = _layer_paths(o, fld, k, wall_q, mid_q, plan.counts)
        if pos is None:
            pos = walls[0].pts[0]
        secs = []
        flows = []
        if o.shape != "cylinder":
            # one loop round the plate (or arc), then the mid-line(s) from the end nearer the loop's start
            secs.append(_rotate_loop(walls[0], pos, o))
            flows.append(wall_q)
            for m in mids:
                secs.append(_orient(m, secs[-1].pts[-1]))
                flows.append(mid_q)
        else:
            # inner wall, mid-line loop(s), outer wall (odd layers outside in): each loop starts at
            # the seam, next to where the last one ended, so a layer needs no travel
            order = [(walls[1], wall_q)] + [(m, mid_q) for m in mids] + [(walls[0], wall_q)]
            if k % 2:
                order = order[::-1]
            for s, q in order:
                secs.append(_rotate_loop(s, pos if not secs else secs[-1].pts[-1], o))
                flows.append(q)
        # the first part joins where the layer below ended, the others the part before them
        ends = [pos] + [p.pts[-1] for p in secs[:-1]]
        secs = [_join(s, at, o, q) for s, at, q in zip(secs, ends, flows)]
        plan.layers.append(Layer(z=(k + 1) * H, sections=secs, gap=gm, wall=ww))
        pos = secs[-1].pts[-1]
        capped += sum(int(np.sum(_capped(s, o, mid_q))) for s in secs if s.kind == "mid-line")
        if progress and (k % 25 == 0 or k == fld.layers - 1):
            progress(k + 1, fld.layers)
    plan.counts["capped_pieces"] = capped
    _place(plan)
    return plan


def _check_fits(o: LithoOptions, fld: Field) -> None:
    """Refuse a part larger than the bed (with the purge line at the front), before any planning."""
    if o.shape == "planar":
        size = (fld.s[-1], max(o.max_thickness, o.foot))
    elif o.shape == "arc":
        P = np.vstack([_layer_polygon(o, fld, k).exterior.coords for k in (0, fld.layers - 1)])
        size = tuple(P.max(axis=0) - P.min(axis=0))
    else:
        size = (o.diameter, o.diameter)
    bx, by = o.bed[0], o.bed[1]
    margin = 2.0
    if size[0] + 2 * margin > bx or size[1] + 2 * margin + (12 if o.purge else 0) > by:
        raise LithoError(f"--bed: the part is {size[0]:.1f} x {size[1]:.1f} mm and does not fit a "
                         f"{bx:g} x {by:g} mm bed (with {margin:g} mm margins"
                         f"{' and the purge line' if o.purge else ''})")
    height = fld.layers * o.layer_height
    if len(o.bed) == 3 and height > o.bed[2]:
        raise LithoError(f"--bed: the part is {height:.1f} mm tall, more than the printer's "
                         f"{o.bed[2]:g} mm")


def _place(plan: Plan) -> None:
    """Centre the part on the bed."""
    o = plan.options
    pts = np.vstack([s.pts for L in plan.layers for s in L.sections])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    plan.origin = (o.bed[0] / 2 - (lo[0] + hi[0]) / 2, o.bed[1] / 2 - (lo[1] + hi[1]) / 2)
