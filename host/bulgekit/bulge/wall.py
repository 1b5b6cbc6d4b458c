"""Outer-wall toolpaths per layer, parameterised by arc length.

A stroke is drawn on the unrolled outer wall: u (mm along the wall) and v
(mm above the bed).  For each layer the wall is the outer-wall toolpath as
the slicer printed it.  u = 0 is where a ray from the layer's centroid in
a fixed reference direction (default: towards the front, -Y) meets the wall
(the outermost crossing), and u grows counter-clockwise seen from above,
i.e. left to right for someone looking at the wall from outside.  Using a
fixed direction instead of the slicer's seam keeps u = 0 at the same place
on every layer, so a stroke lands where it was drawn whatever the seam or
print direction of each layer.

Corners and faces: a corner is where the wall turns by CORNER_TURN_DEG or more within
CORNER_SPAN_MM of its length, between straight runs (turning less than STRAIGHT_TURN_DEG over
STRAIGHT_MM) on both sides; a face is the stretch between two corners. A round wall has none,
and is one face. Faces are numbered in the direction of u from face 1, the one holding u = 0
(or starting there). See Wall.corners and Wall.faces.

Spiral (vase) walls are cut into layer windows of one layer height around
the grid of layer heights, the same windows the firmware matches moves in.
"""
from __future__ import annotations

import functools
import hashlib
import math
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..gcode import movescan
from ..gcode import Move, header_layer_height, open_checked
from ..errors import BulgekitError

# one chunk of walls_from_records' pass in C (None without the compiled scanner: numpy's steps)
_wall_rows = getattr(movescan._scan, "wall_rows", None)


class WallError(BulgekitError):
    """The G-code has no usable outer wall."""


CORNER_TURN_DEG = 30.0     # a corner turns the wall this much or more ...
CORNER_SPAN_MM = 2.0       # ... within this length of it,
STRAIGHT_MM = 2.0          # with a straight run this long on each side:
STRAIGHT_TURN_DEG = 10.0   # turning less than this over it (a round wall has no corners)
CORNER_STEP_MM = 0.1       # where corners are looked for: every this much along the wall


@dataclass(frozen=True)
class Face:
    """A stretch of a wall between two corners: u0..u1 (mm, u0 < u1; face 1 may start below 0,
    as it holds u = 0)."""
    number: int
    u0: float
    u1: float

    @property
    def middle(self) -> float:
        return (self.u0 + self.u1) / 2

    @property
    def length(self) -> float:
        return self.u1 - self.u0


def corner_positions(xy: np.ndarray, s: np.ndarray, closed: bool = True) -> np.ndarray:
    """Arc lengths (print order, ascending) of the corners of the polyline xy whose vertices lie
    at arc lengths s. A corner: the direction of the straight run of STRAIGHT_MM before a stretch
    of CORNER_SPAN_MM and that of the run after it differ by CORNER_TURN_DEG or more, and each run
    is straight: its halves differ by less than STRAIGHT_TURN_DEG and less than an eighth of that
    turn (a round wall turns evenly, a quarter as much over a half-run as across the stretch:
    never a corner, whatever its radius). Directions are those of chords between points of the
    wall, not of its segments, so a sliced polygon of many tiny segments, arcs cut into chords or
    a corner rounded to 1 mm or less read as the wall they make. The corner is the middle of the
    positions (every CORNER_STEP_MM) that see it so; a closed wall is a loop of length s[-1]."""
    xy = np.ascontiguousarray(xy, dtype=float)
    s = np.ascontiguousarray(s, dtype=float)
    # (many layers are the same polygon: a prism's, a stacked file's; looked up by their bytes)
    key = (hashlib.blake2b(xy.tobytes() + s.tobytes(), digest_size=16).digest(), closed)
    got = _corner_memo.get(key)
    if got is None:
        got = _corner_positions(xy, s, closed)
        if len(_corner_memo) >= 256:
            _corner_memo.clear()
        _corner_memo[key] = got
    return got.copy()


_corner_memo: dict = {}


def _corner_positions(xy: np.ndarray, s: np.ndarray, closed: bool) -> np.ndarray:
    w, run = CORNER_SPAN_MM / 2, STRAIGHT_MM
    L = float(s[-1]) if len(s) else 0.0
    if len(xy) < 3 or not L > (2 * (w + run) if closed else 0.0):
        return np.zeros(0)
    # the chords' directions differ by no more than the wall turns at its vertices between them,
    # which lie within w + run of the position: a wall that turns less than CORNER_TURN_DEG over
    # any such stretch has no corner (a round wall's vertices: no chords needed)
    d = np.diff(xy, axis=0)
    seg = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) > 1e-9)      # segments with a direction
    if len(seg) > 1:
        h = np.arctan2(d[seg, 1], d[seg, 0])
        # the turn into each segment, at its start (a loop: the first one's from the last)
        turns = np.abs(np.angle(np.exp(1j * np.diff(np.concatenate([h[-1:], h]) if closed else h))))
        at = s[seg] if closed else s[seg[1:]]
        at3 = np.concatenate([at - L, at, at + L]) if closed else at
        cum = np.concatenate([[0.0], np.cumsum(np.tile(turns, 3) if closed else turns)])
        lo = np.searchsorted(at3, at3 - 2 * (w + run), "left")
        if float((cum[1:] - cum[lo]).max()) < math.radians(CORNER_TURN_DEG):
            return np.zeros(0)
    n = max(1, math.ceil(L / CORNER_STEP_MM))
    q = np.arange(n + (0 if closed else 1)) * (L / n)

    def at(d):
        p = q + d
        p = np.mod(p, L) if closed else np.clip(p, 0.0, L)
        return np.interp(p, s, xy[:, 0]) + 1j * np.interp(p, s, xy[:, 1])

    a, m1, b = at(-w - run), at(-w - run / 2), at(-w)
    c, m2, e = at(w), at(w + run / 2), at(w + run)
    turn = np.abs(np.angle((e - c) * np.conj(b - a)))
    bend = np.maximum(np.abs(np.angle((b - m1) * np.conj(m1 - a))),
                      np.abs(np.angle((e - m2) * np.conj(m2 - c))))
    ok = ((turn >= math.radians(CORNER_TURN_DEG)) & (bend < math.radians(STRAIGHT_TURN_DEG))
          & (bend < turn / 8) & (np.abs(b - a) > run / 2) & (np.abs(e - c) > run / 2))
    if not closed:                      # runs that leave an open chain are no runs
        ok &= (q - w - run >= 0) & (q + w + run <= L)
    idx = np.flatnonzero(ok)
    if not len(idx):
        return np.zeros(0)
    # positions that see one corner lie together (a few steps of flicker allowed): its middle
    groups = np.split(idx, np.flatnonzero(np.diff(idx) > 3) + 1)
    if closed and len(groups) > 1 and groups[0][0] + n - groups[-1][-1] <= 3:
        groups[0] = np.concatenate([groups.pop() - n, groups[0]])   # one round the start
    mids = [(g[0] + g[-1]) / 2 * (L / n) for g in groups]
    return np.sort(np.mod(mids, L) if closed else np.array(mids))


@dataclass
class Wall:
    """The outer wall of one layer: a polyline in print order."""
    z: float                 # layer z, mm (0.01 mm grid)
    xy: np.ndarray           # (N+1, 2) vertices in print order
    s: np.ndarray            # (N+1,) arc length at the vertices
    move_index: np.ndarray   # (N,) running move number of each segment
    height: float = 0.0      # bead height (z - previous layer z)
    ccw: bool = True         # printed counter-clockwise seen from above
    s_ref: float = 0.0       # arc length (print order) where u == 0
    centroid: tuple[float, float] = (0.0, 0.0)
    closed: bool = True      # a loop; an open chain (top of a vase) has ends
    turn: float = 0.0        # open chain: length of the nearest loop (u's period), 0 if none

    @property
    def length(self) -> float:
        return float(self.s[-1])

    # u <-> s: u runs counter-clockwise from the reference, s in print order
    def s_of_u(self, u):
        L = self.length
        u = np.asarray(u, dtype=float)
        s = self.s_ref + u if self.ccw else self.s_ref - u
        # an open chain does not go round: u beyond its ends has no place
        # (check with u_covered() first)
        return np.mod(s, L) if self.closed else s

    def u_covered(self) -> tuple[float, float]:
        """u range the wall covers: one turn for a loop, the chain's ends else."""
        if self.closed:
            return (-math.inf, math.inf)
        a, b = -self.s_ref, self.length - self.s_ref
        return (a, b) if self.ccw else (-b, -a)

    def place_run(self, umin: float, umax: float) -> float | None:
        """Shift (a whole number of turns) that puts u umin..umax on the wall,
        or None when the run leaves an open chain."""
        if self.closed:
            return 0.0
        a, b = self.u_covered()
        shifts = [0.0]
        if self.turn > 0:
            k = math.floor((umin - a) / self.turn)
            shifts += [k * self.turn, (k + 1) * self.turn]
        for d in shifts:
            if umin - d >= a - 1e-6 and umax - d <= b + 1e-6:
                return d
        return None

    @functools.cached_property
    def corners(self) -> np.ndarray:
        """u of the wall's corners (corner_positions), ascending: in 0..length on a loop."""
        return np.sort(np.asarray(self.u_of_s(corner_positions(self.xy, self.s, self.closed))
                                  if self.closed else self._chain_u(corner_positions(
                                      self.xy, self.s, False)), dtype=float))

    def _chain_u(self, s):
        s = np.asarray(s, dtype=float)
        return s - self.s_ref if self.ccw else self.s_ref - s

    @functools.cached_property
    def faces(self) -> tuple[Face, ...]:
        """The stretches between corners, numbered along u from face 1, which holds u = 0 (or
        starts there). A loop without corners is one face, u -L/2..L/2 (its middle at u = 0);
        an open chain's ends end its first and last faces."""
        c = [float(x) for x in self.corners]
        if not self.closed:
            a, b = self.u_covered()
            bounds = [a] + [x for x in c if a + 1e-6 < x < b - 1e-6] + [b]
            spans = list(zip(bounds, bounds[1:]))
            first = next((i for i, (x, y) in enumerate(spans) if x <= 0 < y), 0)
            spans = spans[first:] + spans[:first]
            return tuple(Face(i + 1, x, y) for i, (x, y) in enumerate(spans))
        L = self.length
        if not c:
            return (Face(1, -L / 2, L / 2),)
        if c[0] <= 1e-6 or c[0] >= L - 1e-6:                     # a corner at u = 0
            c = sorted(x % L if x < L - 1e-6 else 0.0 for x in c)
            ends = c + [c[0] + L]
        else:
            ends = [c[-1] - L] + c
        return tuple(Face(i + 1, x, y) for i, (x, y) in enumerate(zip(ends, ends[1:])))

    def face_of_u(self, u: float) -> Face:
        """The face that holds u (taken round the loop)."""
        fs = self.faces
        if self.closed:
            L = self.length
            u = (u - fs[0].u0) % L + fs[0].u0
        return next((f for f in fs if f.u0 <= u < f.u1), fs[-1])

    def u_of_s(self, s):
        L = self.length
        s = np.asarray(s, dtype=float)
        u = s - self.s_ref if self.ccw else self.s_ref - s
        return np.mod(u, L)

    def xy_of_s(self, s) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        return np.stack([x, y], axis=1)

    def xy_of_u(self, u) -> np.ndarray:
        return self.xy_of_s(self.s_of_u(u))

    def project(self, x: float, y: float) -> tuple[float, float]:
        """(s, distance) of the wall point nearest (x, y)."""
        a = self.xy[:-1]
        d = self.xy[1:] - a
        l2 = np.einsum("ij,ij->i", d, d)
        l2[l2 == 0] = 1e-18
        t = np.clip(((x - a[:, 0]) * d[:, 0] + (y - a[:, 1]) * d[:, 1]) / l2, 0, 1)
        px = a[:, 0] + t * d[:, 0]
        py = a[:, 1] + t * d[:, 1]
        dist = np.hypot(px - x, py - y)
        i = int(np.argmin(dist))
        return float(self.s[i] + t[i] * (self.s[i + 1] - self.s[i])), float(dist[i])


@dataclass
class WallModel:
    walls: list[Wall]
    layer_height: float
    geometric: bool = False          # found without feature comments
    source: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def zs(self) -> np.ndarray:
        return np.array([w.z for w in self.walls])

    @property
    def v_range(self) -> tuple[float, float]:
        w0 = self.walls[0]
        return (w0.z - w0.height, self.walls[-1].z)

    def layer_of_v(self, v) -> np.ndarray:
        """Index of the layer whose bead holds height v (-1 outside the wall)."""
        v = np.atleast_1d(np.asarray(v, dtype=float))
        zs = self.zs
        bottoms = zs - np.array([w.height for w in self.walls])
        i = np.searchsorted(zs, v - 1e-9, side="left")
        out = np.full(v.shape, -1, dtype=int)
        ok = i < len(zs)
        ii = np.where(ok, i, 0)
        inside = ok & (v >= bottoms[ii] - 1e-9)
        out[inside] = ii[inside]
        return out


def _z_cmm(z: float) -> int:
    v = float(np.float32(z) * np.float32(100.0))
    return int(v + 0.5) if v >= 0 else -int(0.5 - v)


def _next(a: np.ndarray) -> np.ndarray:
    """np.roll(a, -1) for 1-D a, without np.roll's overhead (called for every loop of a file)."""
    return np.concatenate((a[1:], a[:1]))


def _signed_area(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, _next(y)) - np.dot(y, _next(x)))


def _area_centroid(xy: np.ndarray) -> tuple[float, tuple[float, float]]:
    """_signed_area and the centroid of one polygon, the same operations on the same arrays, the
    rolled columns made once."""
    x, y = xy[:, 0], xy[:, 1]
    xn, yn = _next(x), _next(y)
    area = 0.5 * float(np.dot(x, yn) - np.dot(y, xn))
    cr = x * yn - xn * y
    a = cr.sum() / 2
    if abs(a) < 1e-12:
        return area, (float(x.mean()), float(y.mean()))
    return area, (float(((x + xn) * cr).sum() / (6 * a)), float(((y + yn) * cr).sum() / (6 * a)))


def _crossings(a, b, cx, cy, dx, dy):
    """Where the ray (cx, cy) + t (dx, dy) crosses the segments a -> b: (t along the ray, w along
    each segment, whether it does with t > 0)."""
    ex = b[:, 0] - a[:, 0]
    ey = b[:, 1] - a[:, 1]
    den = dx * ey - dy * ex
    wx = a[:, 0] - cx
    wy = a[:, 1] - cy
    ok = np.abs(den) > 1e-12
    t = np.divide(wx * ey - wy * ex, den, out=np.zeros_like(den), where=ok)   # along the ray
    w = np.divide(wx * dy - wy * dx, den, out=np.zeros_like(den), where=ok)   # along the segment
    ok &= (t > 0) & (w >= 0) & (w <= 1)
    return t, w, ok


def _walls_geometry(first: np.ndarray, ends: np.ndarray, index: np.ndarray, r0: np.ndarray,
                    r1: np.ndarray, direction) -> tuple[list, list, list, list, list, list]:
    """Walls whose vertices are first[i] (x, y) and the move ends (x1, y1) at the rows
    r0[i]..r1[i]-1 of ends (index: the moves' numbers): per wall its vertices, arc lengths, move
    numbers, whether it runs counter-clockwise, its centroid and the arc length where the
    reference ray crosses it. Every number is, to the bit, what the wall's own arrays give
    (_area_centroid, np.cumsum of np.hypot, _ray_hit): computed for many walls at once (a file
    has thousands of layers), element by element the same operations, and
    - each wall's sums as np.add.reduceat over its values behind a 0.0: reduceat copies a
      segment's first element and adds the pairwise sum of the rest, which is then 0.0 + the
      pairwise sum of the wall's values, what .sum() gives (its identity 0.0 plus that sum);
    - arc lengths as np.cumsum along the rows of a padded 2-D array (each one add after another,
      as a wall's own np.cumsum);
    - the orientation from the sum of the cross products when it lies beyond the rounding error
      of any order of summation, else from np.dot as _signed_area (BLAS may sum in another order:
      only a wall of near zero area can tell)."""
    m = len(r0)
    n = r1 - r0 + 1                                   # vertices (3 or more)
    xys, ss, mis = [None] * m, [None] * m, [None] * m
    ccw = np.ones(m, bool)
    cx_all, cy_all, s_ref = np.empty(m), np.empty(m), np.empty(m)
    hit = np.zeros(m, bool)                           # s_ref from a crossing
    pairs = np.ascontiguousarray(ends, dtype=np.float64).view(np.complex128).ravel()   # (x1 y1)
    by_len = np.argsort(n, kind="stable")
    n_sorted = n[by_len]
    dx, dy = direction
    eps = np.finfo(float).eps
    k = 0
    while k < m:
        # a block: walls of about one length (padding them to the longest wastes <= 1/4), about
        # 2**16 vertices (memory)
        n0 = int(n_sorted[k])
        j = min(int(np.searchsorted(n_sorted, n0 + n0 // 4, side="right")),
                k + max(1, (1 << 16) // n0))
        ids = by_len[k:j]
        k = j
        nb = n[ids]
        P = int(nb.max())
        W = len(ids)
        rows = np.arange(W)
        # column 0: a 0.0 ahead of each wall (the reduceat above); columns 1..n its vertices; the
        # rest repeats its last vertex, and one column more keeps every segment's end inside
        # (np.take of 16-byte items is some 8 times faster than indexing rows of 2 floats, and
        # writes into XY: gathered for every column, the first and the padding set after)
        R = np.minimum(r0[ids, None] + np.arange(-2, P), r1[ids, None] - 1)
        XY = np.empty((W, P + 2, 2))
        np.take(pairs, R, out=XY.view(np.complex128)[:, :, 0], mode="clip")
        XY[:, 0] = XY[:, P + 1] = 0.0
        XY[:, 1] = first[ids]
        R = R[:, 2:P + 1]
        X, Y = XY[:, :, 0], XY[:, :, 1]
        XN = np.empty((W, P + 2))
        YN = np.empty((W, P + 2))
        XN[:, :-1], YN[:, :-1] = X[:, 1:], Y[:, 1:]
        XN[rows, nb], YN[rows, nb] = X[:, 1], Y[:, 1]       # a wall's last vertex -> its first
        XN[:, -1] = YN[:, -1] = 0.0
        CR = X * YN - XN * Y
        AX = (X + XN) * CR
        AY = (Y + YN) * CR
        for a in (CR, AX, AY):
            a[:, 0] = 0.0
        seg = np.empty(2 * W, np.int64)                   # [0.0 + wall i) and the rest, per row
        seg[0::2] = rows * (P + 2)
        seg[1::2] = seg[0::2] + nb + 1
        cr, ax, ay = (np.add.reduceat(a.ravel(), seg)[0::2] for a in (CR, AX, AY))
        ar = cr / 2
        S = np.empty((W, P))
        S[:, 0] = 0.0
        S[:, 1:] = np.hypot(X[:, 2:P + 1] - X[:, 1:P], Y[:, 2:P + 1] - Y[:, 1:P])
        S = np.cumsum(S, axis=1)
        MI = index[R]
        # the orientation: sure when the sum of the cross products is beyond the rounding error
        # of any order of summation, here and in BLAS (some n eps times the sum of the products'
        # magnitudes: 8 (n + 4) eps times their bound 2 n M^2, M the block's largest coordinate);
        # NaN and inf go to np.dot
        M = max(float(XY.max()), -float(XY.min()))
        sure = np.abs(cr) > 16 * (nb + 4) * eps * nb * M * M
        ccw[ids] = cr >= 0
        with np.errstate(divide="ignore", invalid="ignore"):   # (tiny areas: the means below)
            cx, cy = ax / (6 * ar), ay / (6 * ar)
        if (nb == P).all() and (np.diff(ids) == 1).all():
            # one length, walls in order (a file of one shape): the row views in one go
            w0 = int(ids[0])
            xys[w0:w0 + W] = list(XY[:, 1:P + 1])
            ss[w0:w0 + W] = list(S)
            mis[w0:w0 + W] = list(MI)
        else:
            for i, (w, ni) in enumerate(zip(ids.tolist(), nb.tolist())):
                xys[w] = XY[i, 1:ni + 1]
                ss[w] = S[i, :ni]
                mis[w] = MI[i, :ni - 1]
        for i in np.flatnonzero(~sure).tolist():
            ni, xy = int(nb[i]), xys[ids[i]]
            area = 0.5 * float(np.dot(xy[:, 0], YN[i, 1:ni + 1])
                               - np.dot(xy[:, 1], XN[i, 1:ni + 1]))
            ccw[ids[i]] = area >= 0
        for i in np.flatnonzero(np.abs(ar) < 1e-12).tolist():
            xy = xys[ids[i]]
            cx[i], cy[i] = float(xy[:, 0].mean()), float(xy[:, 1].mean())
        cx_all[ids], cy_all[ids] = cx, cy
        # the reference ray's crossings, as _ray_hit: per wall the one of greatest t (the first of
        # equal ones, as argmax), or _ray_hit's fallback when there is none. _crossings only on the
        # segments whose ends do not both lie well on one side of the ray's line: it finds the
        # others not crossing it either (w outside 0..1), as lim lies far above the rounding
        # errors of its arithmetic and of side's (some 50 eps times the largest coordinate)
        V = XY[:, 1:P + 1]
        side = V[:, :, 0] * dy - V[:, :, 1] * dx                  # - (cx dy - cy dx)
        c_side = cx * dy - cy * dx
        cand = np.arange(P - 1) < (nb - 1)[:, None]
        lim = 1e-12 * (1.0 + max(M, float(np.abs(cx).max()), float(np.abs(cy).max())))
        if math.isfinite(lim):
            above = side > (c_side + lim)[:, None]
            below = side < (c_side - lim)[:, None]
            cand &= ~((above[:, :-1] & above[:, 1:]) | (below[:, :-1] & below[:, 1:]))
        wi, ki = np.nonzero(cand)
        t, wt, ok = _crossings(V[wi, ki], V[wi, ki + 1], cx[wi], cy[wi], dx, dy)
        wi, ki, t, wt = wi[ok], ki[ok], t[ok], wt[ok]
        o = np.lexsort((ki, -t, wi))                       # per wall: greatest t, first segment
        o = o[np.unique(wi[o], return_index=True)[1]]
        hw, hk = wi[o], ki[o]
        s0, s1 = S[hw, hk], S[hw, hk + 1]
        s_ref[ids[hw]] = s0 + wt[o] * (s1 - s0)
        hit[ids[hw]] = True
    cens = list(zip(cx_all.tolist(), cy_all.tolist()))
    srefs = s_ref.tolist()
    for w in np.flatnonzero(~hit).tolist():
        srefs[w] = _ray_hit(xys[w], ss[w], cens[w], direction)
    return xys, ss, mis, ccw.tolist(), cens, srefs


def _ray_hit(xy: np.ndarray, s: np.ndarray, c, direction) -> float:
    """Arc length of the outermost crossing of the ray c + t*direction."""
    cx, cy = c
    dx, dy = direction
    t, w, ok = _crossings(xy[:-1], xy[1:], cx, cy, dx, dy)
    if ok.any():
        idx = np.nonzero(ok)[0]
        k = idx[np.argmax(t[idx])]
        return float(s[k] + w[k] * (s[k + 1] - s[k]))
    # open gap or odd shape: the vertex best aligned with the direction
    proj = (xy[:, 0] - cx) * dx + (xy[:, 1] - cy) * dy
    return float(s[int(np.argmax(proj))])


@functools.lru_cache(maxsize=1024)
def _spread(n: int) -> np.ndarray:
    """Which 64 of n points _median_distance takes (spread evenly: many layers' loops have the
    same number of points)."""
    i = np.linspace(0, n - 1, 64).astype(int)
    i.flags.writeable = False
    return i


def _median_distance(pts: np.ndarray, poly: np.ndarray) -> float:
    """Median distance from (up to 64 of) pts to the polyline poly."""
    if len(pts) > 64:
        pts = pts[_spread(len(pts))]
    # A point is no farther from the polyline than from its nearest vertex (ub), and a segment
    # ab can be nearer only if |pa| + |pb| - |ab| <= 2 ub (for q on ab, |pq| >= (|pa| + |pb| -
    # |ab|) / 2). Only those segments are projected on, with the arithmetic once used on all
    # of them: the same minimum (geometric mode asks this of every layer's loops: a 100 MB
    # file spent some 14 s here).
    dx = pts[:, 0:1] - poly[None, :, 0]
    dy = pts[:, 1:2] - poly[None, :, 1]
    dv = np.sqrt(dx * dx + dy * dy)                      # (points, vertices)
    seg = poly[1:] - poly[:-1]
    ln = np.sqrt((seg * seg).sum(-1))
    ub = dv.min(axis=1) * (1 + 1e-9) + 1e-9             # (room for rounding: more kept, not less)
    ii, jj = np.nonzero((dv[:, :-1] + dv[:, 1:] - ln) * 0.5 <= ub[:, None])
    a, d, p = poly[:-1][jj], seg[jj], pts[ii]
    l2 = np.maximum((d * d).sum(-1), 1e-18)
    t = np.clip(((p - a) * d).sum(-1) / l2, 0, 1)
    q = a + t[..., None] * d
    near = np.full(len(pts), np.inf)
    np.minimum.at(near, ii, np.sqrt(((q - p) ** 2).sum(-1)))
    near.sort()                                          # the median as np.median takes it
    k = len(near) // 2
    return float(near[k]) if len(near) % 2 else (float(near[k - 1]) + float(near[k])) / 2


class _Chain:
    """A run of eligible moves that join end to start at one layer bucket: its points are the
    first move's start and every move's end (rows r0..r1-1 of the collected moves' ends)."""
    __slots__ = ("bucket", "r0", "r1", "first", "_ends")

    def __init__(self, bucket, r0, r1, first, ends):
        self.bucket, self.r0, self.r1 = bucket, r0, r1
        self.first = first                     # (x0, y0) of its first move
        self._ends = ends

    @property
    def pts(self) -> np.ndarray:
        return np.concatenate([np.array([self.first]), self._ends[self.r0:self.r1]])


def extract_walls(moves: Iterable[Move], layer_height: float | None = None,
                  geometric: bool = False, ref_angle_deg: float = -90.0,
                  source: str = "<gcode>", header_height: float | None = None
                  ) -> WallModel:
    """Outer walls per layer from parsed moves.

    geometric=False uses the moves the slicer tagged as outer wall;
    geometric=True uses every extruding move and keeps, per layer, the closed
    loop of largest area (the outermost one).
    """
    return walls_from_records(movescan.from_moves(moves), layer_height, geometric,
                              ref_angle_deg, source, header_height)


def _rows_np(a: np.ndarray, c: np.ndarray, num: np.ndarray | None, row: int, inside: int,
             breaks: int, last: tuple[float, float] | None, after: int, done: int,
             rows_done: int):
    """One chunk of walls_from_records' pass (a: RECORD array, c: its movescan.classes, num: its
    move numbers in a lean scan, else None), from the state the chunk before left: the breaks
    since the last row, that row's end (x1, y1) and the last record's number. -> (breaks, after,
    whether a move is on the outer wall, parts): parts None when no move is a row, else per row
    its end (x1 + i y1), number and whether it joins the row before; the rows that may begin a
    chain and their starts (x0, y0); where each run of one z begins, its z (0.01 mm) and how many
    of its rows are flat. (_scan.wall_rows does the same steps in one pass over the records.)"""
    outer = bool((c & movescan.OUTER).any())
    ok = (c & row) == row
    brk = ~ok & ((c & (movescan.MOVED | inside)) != inside)
    if num is not None:
        # a break also for the moves left out before a record
        brk |= np.diff(num, prepend=after) > 1
        after = int(num[-1])
    rec = np.flatnonzero(ok)
    # breaks up to each record (with those of earlier chunks since the last row); a row has
    # one behind it when the count grew since the row before (a break record is no row, a
    # gap counts before the record it precedes)
    nb = np.cumsum(brk)
    if not len(rec):
        return breaks + (int(nb[-1]) if len(nb) else 0), after, outer, None
    at = nb[rec]
    broken = np.diff(at, prepend=-breaks) > 0
    breaks = int(nb[-1] - at[-1])
    rows = _coords(a, rec)                  # x0 y0 z0 x1 y1 z1
    # the rows come in runs of one z (layers): z in 0.01 mm once per run, and how many of
    # each run's rows are flat (planar)
    z1 = rows[:, 5]
    st, zs = movescan.runs(z1)
    zrun = movescan.z_cmm(zs)
    flat = np.abs(z1 - rows[:, 2]) < 1e-6
    pz = np.add.reduceat(flat, st, dtype=np.int64)
    # its start at the end of the row before (columns one by one: numpy is slow on rows of 2)
    link = np.empty(len(rows), bool)
    link[1:] = np.maximum(np.abs(rows[1:, 0] - rows[:-1, 3]),
                          np.abs(rows[1:, 1] - rows[:-1, 4])) <= 1e-4   # (NaN: no)
    link[0] = (last is not None and abs(last[0] - rows[0, 0]) <= 1e-4
               and abs(last[1] - rows[0, 1]) <= 1e-4)
    link &= ~broken
    # (a chain begins where a row does not join the one before, or lies in another bucket:
    # at another z)
    may_begin = ~link
    may_begin[st] = True
    fr = np.flatnonzero(may_begin)
    # (x1 y1 as one complex: concatenated some 3 times faster than rows of 2 floats)
    e1 = np.ndarray((len(rows),), np.complex128, rows, 24, (48,))
    return breaks, after, outer, (e1, rec + done if num is None else num[rec], link,
                                  fr + rows_done, rows[fr, 0:2], st + rows_done, zrun, pz)


def _rows_c(a, c, num, row, inside, breaks, last, after, done, rows_done):
    """_rows_np by the compiled scanner's wall_rows (the same parts, to the bit); None for a
    chunk it leaves to numpy (a row's z not finite)."""
    got = _wall_rows(np.ascontiguousarray(a), c, num, row, inside, breaks, last, after, done,
                     rows_done)
    if got is None or got[3] is None:
        return got
    breaks, after, outer, (e1, nm, link, fr, fxy, st, zr, pz) = got
    i8 = np.int64
    return breaks, after, outer, (
        np.frombuffer(e1, np.complex128), np.frombuffer(nm, i8), np.frombuffer(link, bool),
        np.frombuffer(fr, i8), np.frombuffer(fxy, np.float64).reshape(-1, 2),
        np.frombuffer(st, i8), np.frombuffer(zr, i8), np.frombuffer(pz, i8))


def _coords(a: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """x0 y0 z0 x1 y1 z1 of the records rec of the RECORD array a, as an (n, 6) float64 array
    (gathered as one 48-byte item a record: twice as fast as rows of 6 floats)."""
    a = np.ascontiguousarray(a)
    items = np.ndarray((len(a),), np.dtype("V48"), a, 0, (a.itemsize,))
    return items[rec].view("<f8").reshape(-1, 6)


def walls_from_records(chunks: Iterable[np.ndarray], layer_height: float | None = None,
                       geometric: bool = False, ref_angle_deg: float = -90.0,
                       source: str = "<gcode>", header_height: float | None = None
                       ) -> WallModel:
    """extract_walls on the moves as movescan.RECORD arrays, chunk by chunk, without a Python
    step per move: a 100 MB file has some three million. chunks may be a kept lean Scan's
    (movescan.Chunks.numbers) in marked mode: it holds every outer-wall move, and a move left
    out between two records is outside the wall, a break."""
    # Per chunk, of the eligible moves (the rows): their ends (x1 y1), move numbers, z (0.01 mm)
    # and whether each joins the row before (its start at that one's end, no break between: a
    # move that travels or leaves the outer wall breaks a chain); the start (x0 y0) only of rows
    # that may begin a chain (not joined, or another z); the z of the planar ones in runs.
    e1s: list[np.ndarray] = []
    nums: list[np.ndarray] = []
    zst_parts: list[np.ndarray] = []           # rows where a run of one z begins
    zr_parts: list[np.ndarray] = []            # and its z (0.01 mm)
    links: list[np.ndarray] = []
    firsts: list[np.ndarray] = []
    first_rows: list[np.ndarray] = []
    pz_lens: list[np.ndarray] = []             # and how many of its rows are flat
    any_outer = False
    done = 0                                   # moves before this chunk
    rows_done = 0                              # rows before this chunk
    breaks = 0                                 # breaks since the last row
    last = None                                # the last row's x1, y1
    numbers = getattr(chunks, "numbers", None)
    if numbers is not None and geometric:
        raise ValueError("walls_from_records: lean chunks hold the outer-wall moves only")
    after = -1                                 # lean: the number of the last record's move
    # from a move's class bits (movescan.classes): a row extrudes moving in XY, on the outer wall
    # unless geometric; a move that is no row breaks a chain when it moves in XY or (marked
    # mode) lies outside the outer wall: not (still and inside)
    row = movescan.EXTRUDES | (0 if geometric else movescan.OUTER)
    inside = 0 if geometric else movescan.OUTER
    rows_of = _rows_c if _wall_rows is not None else _rows_np
    for a in chunks:
        c, _, _ = movescan.classes(a)          # (one pass over the records)
        num = numbers[-1] if numbers is not None else None
        got = rows_of(a, c, num, row, inside, breaks, last, after, done, rows_done)
        if got is None:                        # (a z the compiled pass leaves to numpy)
            got = _rows_np(a, c, num, row, inside, breaks, last, after, done, rows_done)
        breaks, after, outer, parts = got
        any_outer = any_outer or outer
        done += len(a)
        if parts is None:
            continue
        e1, num_rows, link, fr, fxy, st, zrun, pz = parts
        e1s.append(e1)
        nums.append(num_rows)
        links.append(link)
        first_rows.append(fr)
        firsts.append(fxy)
        zst_parts.append(st)
        zr_parts.append(zrun)
        pz_lens.append(pz)
        last = (float(e1[-1].real), float(e1[-1].imag))
        rows_done += len(e1)
    if not geometric and not any_outer:
        raise WallError(
            f"{source}: no outer-wall feature comments found (;TYPE:External perimeter, "
            ";TYPE:Outer wall, ;TYPE:WALL-OUTER, ; outer perimeter). Slice with feature "
            "comments enabled, or use geometric mode (M720 S2): pass --geometric to take "
            "the outermost closed loop of each layer as the wall.")
    ends = np.concatenate(e1s) if e1s else np.empty(0, np.complex128)
    ends = ends.view(np.float64).reshape(-1, 2)                # x1 y1 of every row
    index = np.concatenate(nums) if nums else np.empty(0, np.int64)
    link = np.concatenate(links) if links else np.empty(0, bool)
    first_row = np.concatenate(first_rows) if first_rows else np.empty(0, np.int64)
    first_xy = np.concatenate(firsts) if firsts else np.empty((0, 2))
    del e1s, nums, links, first_rows, firsts
    # A layer has many moves at its z; a spiral wall only now and then two
    # consecutive moves at the same rounded z. (np.unique over the runs of one z, weighed)
    zp, inv = np.unique(np.concatenate(zr_parts) if zr_parts else np.empty(0, np.int64),
                        return_inverse=True)
    counts = np.bincount(inv.ravel(), np.concatenate(pz_lens) if pz_lens else None, len(zp))
    zs_planar = [int(z) for z in zp[counts >= 4]]
    if layer_height is not None and not (math.isfinite(layer_height) and 0 < layer_height <= 2.0):
        raise WallError(f"{source}: layer height {layer_height} mm must be > 0 and <= 2 mm")
    notes: list[str] = []
    if header_height and layer_height is not None and abs(header_height - layer_height) > 1e-6:
        notes.append(f"layer height {layer_height:g} mm given, but the G-code says "
                     f"{header_height:g} mm: using the G-code's")
    h = header_height or layer_height
    if not h:
        diffs = np.diff(np.array(zs_planar)) if len(zs_planar) > 1 else np.array([])
        diffs = diffs[diffs >= 5]
        h = float(np.bincount(diffs).argmax()) / 100 if len(diffs) else 0.2
    h_cmm = max(1, round(h * 100))

    # The bucket of each move: the firmware's reading of its z, its end z in 0.01 mm rounded in
    # float32 (bulge_planner.cpp eligible()); a move off the planar layers (a spiral) snaps to
    # the layer grid above the highest planar layer below, nearest grid z, the lower one on a
    # tie (as MapStore::find_layer). A planar move's z is a planar layer's, which that snapping
    # leaves as it is: the bucket is a function of the z, computed once per run of one z.
    zst = np.concatenate(zst_parts) if zst_parts else np.empty(0, np.int64)
    zr = np.concatenate(zr_parts) if zr_parts else np.empty(0, np.int64)
    zsp = np.array(zs_planar, dtype=np.int64)
    i = np.searchsorted(zsp, zr, side="right") - 1
    base = np.where(i >= 0, zsp[np.maximum(i, 0)] if len(zsp) else 0, 0)
    d = zr - base
    bucket_run = base - ((h_cmm - 2 * d) // (2 * h_cmm)) * h_cmm
    # A chain starts where a row does not join the one before or lies in another bucket.
    start = ~link
    start[zst[1:][bucket_run[1:] != bucket_run[:-1]]] = True
    starts = np.flatnonzero(start)
    stops = np.append(starts[1:], len(link))
    buckets = bucket_run[np.searchsorted(zst, starts, side="right") - 1]
    long = stops - starts >= 2                  # three points or more
    starts, stops, buckets = starts[long], stops[long], buckets[long]
    fxy = first_xy[np.searchsorted(first_row, starts)]
    gap = max(2.0, 3 * h)
    # whether each chain is closed (its end within gap of its start), with math.hypot on Python
    # floats as ever (np.hypot may round otherwise)
    dx_end = (ends[stops - 1, 0] - fxy[:, 0]).tolist() if len(starts) else []
    dy_end = (ends[stops - 1, 1] - fxy[:, 1]).tolist() if len(starts) else []
    hyp = math.hypot
    shut = np.array([hyp(a, b) <= gap for a, b in zip(dx_end, dy_end)], bool)
    if not math.isfinite(ref_angle_deg):
        raise WallError(f"{source}: reference angle {ref_angle_deg} is not a finite number")
    direction = (math.cos(math.radians(ref_angle_deg)), math.sin(math.radians(ref_angle_deg)))
    # The chains of each bucket (in file order), buckets ascending; most buckets have one chain,
    # which is their wall: _Chain objects only for the others, and all of geometric mode's.
    by = np.argsort(buckets, kind="stable")
    bst, bvals = movescan.runs(buckets[by])
    bcount = np.diff(np.append(bst, len(by)))
    pick = np.where(bcount == 1, by[bst] if len(by) else 0, -1)   # per bucket: the chain chosen
    unclosed = (bcount == 1) & ~shut[pick] if len(by) else np.zeros(0, bool)
    upper: np.ndarray | None = None
    # Geometric mode goes top-down: the wall of a layer must lie near the wall
    # of the layer above, which rejects a skirt (it stands off the part) even
    # though it is the largest loop of the first layer.
    general = range(len(bvals) - 1, -1, -1) if geometric else np.flatnonzero(bcount != 1).tolist()
    for k in general:
        b = int(bvals[k])
        js = by[bst[k]:bst[k] + bcount[k]].tolist()
        cands = [_Chain(b, int(starts[j]), int(stops[j]), (float(fxy[j, 0]), float(fxy[j, 1])), ends)
                 for j in js]
        closed = [c for c, j in zip(cands, js) if shut[j]]
        pool = closed or cands
        # (most layers have one wall: no areas to compare)
        if len(pool) == 1:
            best = pool[0]
        else:
            area = [abs(_signed_area(np.array(c.pts))) for c in pool]
            # the largest (the first of equals); in geometric mode below the top, the largest of
            # those near the wall above, if any is: looked for from the largest down
            big = sorted(range(len(pool)), key=lambda i: -area[i])
            best = pool[big[0]]
            if geometric and upper is not None:
                best = next((pool[i] for i in big if _median_distance(np.array(pool[i].pts), upper)
                             <= max(1.0, 3 * h)), best)
        unclosed[k] = not closed
        pick[k] = by[bst[k] + cands.index(best)]
        if geometric:
            upper = np.array(best.pts, dtype=float)
    for k in (range(len(bvals) - 1, -1, -1) if geometric else range(len(bvals))):
        if unclosed[k]:
            notes.append(f"layer z {int(bvals[k]) / 100:.2f}: no closed outer loop, "
                         "using the largest open one")
    walls: list[Wall] = []
    prev_z = None
    geom = (_walls_geometry(fxy[pick], ends, index, starts[pick], stops[pick], direction)
            if len(pick) else ([],) * 6)
    for b, xy, s, mi, ccw, cen, s_ref, closed in zip(bvals.tolist(), *geom, shut[pick].tolist()):
        z = b / 100
        height = (z - prev_z) if prev_z is not None else min(z, h)
        if prev_z is not None and height > 1.5 * h:
            height = h  # a layer without wall in between
        prev_z = z
        walls.append(Wall(z, xy, s, mi, height, ccw, s_ref, cen, closed))
    loops = [w for w in walls if w.closed]
    for w in walls:
        if not w.closed and loops:
            w.turn = min(loops, key=lambda c: abs(c.z - w.z)).length
    if not walls:
        what = "extruding closed loops" if geometric else "outer-wall extrusions"
        raise WallError(f"{source}: no {what} found")
    return WallModel(walls, h_cmm / 100, geometric, source, notes)


def walls_from_gcode(path, layer_height: float | None = None, geometric: bool = False,
                     ref_angle_deg: float = -90.0) -> WallModel:
    ends, _ = open_checked(path)                    # checked; its moves are scanned in chunks
    return movescan.run(path, lambda chunks: walls_from_records(
        chunks, layer_height, geometric, ref_angle_deg, str(path), header_layer_height(ends)))
