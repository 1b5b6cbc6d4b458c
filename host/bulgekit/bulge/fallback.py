"""Stock-firmware rewrite (Takahashi & Miyashita, sec. 5.3) and the reference
planner the firmware path is checked against.

`RefPlanner` mirrors src/bulge_planner.cpp decision for decision, in float32
where the firmware computes in float, so that the same map, settings and
G-code give the same stops:
  * a move qualifies when it extrudes with XY motion, the mode allows it
    (marked mode: inside the outer wall; geometric: any) and a map layer lies
    within half a layer height of its end z;
  * every unfired point of that layer within the tolerance of the segment
    stops the head at its projection, in order along the move;
  * a point whose foot lies beyond the move's end is left to the next move:
    if that one continues the wall from the end, it stops the point at its
    foot there (within the tolerance) or at its start; any other motion from
    the end stops it at the end first; a move that starts elsewhere leaves
    it unfired;
  * a piece shorter than BK_MIN_PIECE_MM is not cut: the stop happens where
    the head already is (or at the move end);
  * the piece after a stop carries the extra filament; a stop at the last
    vertex hands it to the next move if that move qualifies, else it is lost.

`rewrite()` turns those actions back into plain G-code for stock firmware:
G1 pieces with E proportional to their length (eq. 1), a stop at each point
(an E-only move of whole steps timed to the dwell, StockStops; or G4 P<ms>,
the paper's), the extra E added to the next piece and a G92 E that puts the
host's E back (M82), or relative pieces (M83) which need no G92.
"""
from __future__ import annotations

import bisect
import math
import re
import struct
from dataclasses import dataclass, field
from typing import Iterable, Iterator

import numpy as np

from . import klipper_stop, mapformat
from ..gcode import movescan
from ..gcode import (MAX_ARC_SEGMENT_MM, _WORD, GcodeState, Line, Move, arc_geometry, command_of,
                     parse_lines, parse_words, split_code)
from ..errors import BulgekitError
from ..outputs import part as output_part
from .. import machine
from ..machine import PrinterModel
from . import stopmodel
from .stopmodel import Piece
from ..gcode import _M92_RX, _m92_e, _plain_lines, scan_m92


class UnreachedError(BulgekitError):
    """Map points that no move of the G-code reaches: the map was probably
    made for another file."""

f32 = np.float32

# Mirrors of config/bulgekit_config.h
DEFAULT_DWELL_MS = 100
DEFAULT_EXTRA_E_MM = 0.1
DEFAULT_TOLERANCE_MM = 0.25
MIN_PIECE_MM = 0.1
MAX_DWELL_MS = 2000
MAX_EXTRA_E_MM = 1.0
MAX_TOLERANCE_MM = 2.0

MODE_OFF, MODE_MARKED, MODE_GEOMETRIC = 0, 1, 2


@dataclass(frozen=True)
class Settings:
    """M720 settings."""
    mode: int = MODE_MARKED
    dwell_ms: int = DEFAULT_DWELL_MS
    extra_e: float = DEFAULT_EXTRA_E_MM
    tolerance: float = DEFAULT_TOLERANCE_MM

    def __post_init__(self):
        if self.mode not in (0, 1, 2):
            raise ValueError(f"mode {self.mode} must be 0, 1 or 2")
        if not 0 <= self.dwell_ms <= MAX_DWELL_MS or int(self.dwell_ms) != self.dwell_ms:
            raise ValueError(f"dwell {self.dwell_ms} ms outside 0..{MAX_DWELL_MS} (whole ms)")
        if not 0 <= self.extra_e <= MAX_EXTRA_E_MM:
            raise ValueError(f"extra E {self.extra_e} mm outside 0..{MAX_EXTRA_E_MM}")
        if not 0.01 <= self.tolerance <= MAX_TOLERANCE_MM:
            raise ValueError(f"tolerance {self.tolerance} mm outside 0.01..{MAX_TOLERANCE_MM}")

    def m720(self) -> str:
        return f"M720 S{self.mode} P{self.dwell_ms} E{self.extra_e:.3f} T{self.tolerance:.3f}"


@dataclass
class Action:
    kind: str           # "line" or "dwell"
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    e: float = 0.0      # filament of this piece, extra included
    ms: int = 0
    t: float = 1.0      # parameter along the host move (1 = its end)
    # for the stock writer (they change nothing the planner decides):
    extra: float = 0.0  # line: the extra filament in e; dwell: the extra owed after the stop
    dropped: float = 0.0  # line: extra owed before this move that it dropped


@dataclass
class StopRecord:
    """One stop as it happens: where, how long, which map point."""
    line_no: int
    x: float
    y: float
    z: float
    ms: int
    point: tuple[int, int]   # map point in quanta
    layer_z_cmm: int


@dataclass
class PlanStats:
    moves_split: int = 0
    points_fired: int = 0
    extra_applied: float = 0.0
    extra_dropped: float = 0.0
    layers_loaded: int = 0
    dwell_ms_total: int = 0


_F32, _U32 = struct.Struct("<f"), struct.Struct("<I")


def _bits(v) -> int:
    """v's IEEE bits as a float32 (rounded to nearest, as numpy rounds it)."""
    try:
        return _U32.unpack(_F32.pack(v))[0]
    except OverflowError:      # beyond float32's range: numpy's infinity
        return int(np.array(v, dtype=np.float32).view(np.uint32))


def _sorted_points(rec: mapformat.Layer) -> list[tuple[int, int, int]]:
    """A map layer's points (x, y, weight) in the order the planner looks at them: by x, then y
    (as BulgePlanner's layer window holds them)."""
    w = rec.weights or (255,) * len(rec.points)
    return sorted(((x, y, ww) for (x, y), ww in zip(rec.points, w)), key=lambda p: (p[0], p[1]))


class RefPlanner:
    """Python mirror of bk::BulgePlanner (no arena: the whole map is present)."""

    def __init__(self, bmap: mapformat.BulgeMap | None, settings: Settings):
        self.map = bmap
        self.s = settings
        self.q_um = bmap.quantum_um if bmap else 50
        self.lh = bmap.layer_height_cmm if bmap else 30
        self.q_mm = f32(self.q_um) * f32(0.001)
        self.tol2 = f32(settings.tolerance) * f32(settings.tolerance)
        self.layer = None          # (z_cmm, pts sorted [(x,y,w)], fired list)
        self.miss_z = None
        self.below = None          # z of the records next to the loaded layer
        self.above = None
        self.floor = None          # layers below it are released in the firmware
        self.carry = f32(0)
        self.stop_ms = 0           # dwell given at the current stop (merged points)
        self.stats = PlanStats()
        self.stops: list[StopRecord] = []
        self.top_z: float | None = None   # highest z of an extruding XY move
        self._zs = [l.z_cmm for l in bmap.layers] if bmap else []
        self._sorted = all(a <= b for a, b in zip(self._zs, self._zs[1:]))
        self.deferred: set[int] = set()   # points whose feet lay beyond the last move's end
        self.last_end = None       # float bits of that move's x1, y1

    def configure(self, settings: Settings) -> None:
        """New M720 settings between moves (BulgePlanner::apply): the layer, its marks, the
        owed extra and any deferred points stay."""
        self.s = settings
        self.tol2 = f32(settings.tolerance) * f32(settings.tolerance)

    def append_layers(self, layers) -> None:
        """Records an `M721 ... A1` append put after the map in force: a z that missed before is
        looked up again (the firmware forgets its miss when the map's last z changes)."""
        self.map.layers += list(layers)
        self._zs = [l.z_cmm for l in self.map.layers]
        self._sorted = all(a <= b for a, b in zip(self._zs, self._zs[1:]))
        self.miss_z = None
        if self.layer is not None:
            self.below, self.above = self._neighbors(self.layer[0])

    def passthrough(self, e: float, xy: bool, null: bool, outer: bool, z1: float) -> bool:
        """True when plan() would give the move back as it is: no point deferred, no extra owed,
        and not a move the mode splits (an extruding X/Y move in mode 2, or in mode 1 inside the
        outer wall). Its bookkeeping is done here. For a caller that moves line by line
        (Klipper's module) and need not build a Move for most lines."""
        if self.deferred or self.carry != 0:
            return False
        if e > 0 and xy:
            if self.map is not None and (self.s.mode == MODE_GEOMETRIC
                                         or (self.s.mode == MODE_MARKED and outer)):
                return False
            if self.top_z is None or z1 > self.top_z:
                self.top_z = z1
        if not null:
            self.stop_ms = 0
        return True

    # -- layer window (MapStore::find_layer + BulgePlanner::window)
    def _find(self, zc: int):
        best = None
        best_d = 0
        # layers are in ascending z (else every one is looked at): the released ones, below the
        # floor, are skipped by bisection rather than one by one (a file calls this per layer)
        lo = bisect.bisect_left(self._zs, self.floor) if self._sorted and self.floor is not None else 0
        for i in range(lo, len(self._zs)):
            z = self._zs[i]
            if self.floor is not None and z < self.floor:
                continue  # released
            d = z - zc
            if d > 0 and 2 * d > self.lh:
                break
            d = abs(d)
            if 2 * d <= self.lh and (best is None or d < best_d):
                best, best_d = i, d
        return best

    def _neighbors(self, z: int):
        if self._sorted:
            zs = self._zs
            i = bisect.bisect_left(zs, z)
            lo = 0 if self.floor is None else bisect.bisect_left(zs, self.floor)
            j = max(bisect.bisect_right(zs, z), lo)
            return (zs[i - 1] if i > lo else None), (zs[j] if j < len(zs) else None)
        live = [v for v in self._zs if self.floor is None or v >= self.floor]
        below = max((v for v in live if v < z), default=None)
        above = min((v for v in live if v > z), default=None)
        return below, above

    def _keeps(self, zc: int) -> bool:
        """The loaded layer is the one for zc (no search needed)."""
        if self.layer is not None:
            d = zc - self.layer[0]
            if d == 0:
                return True
            if d > 0 and 2 * d <= self.lh and (self.above is None or d <= self.above - zc):
                return True
            if d < 0 and -2 * d <= self.lh and (self.below is None or -d < zc - self.below):
                return True
        return False

    @staticmethod
    def _cmm(z) -> int:
        v = float(f32(z) * f32(100.0))
        return int(v + 0.5) if v >= 0 else -int(0.5 - v)

    def _window(self, zc: int) -> bool:
        if self._keeps(zc):
            return True
        if self.map is None or not self.map.layers:
            return False
        if self.miss_z is not None and zc == self.miss_z:
            return False
        i = self._find(zc)
        if i is None:
            self.miss_z = zc
            return False
        self.miss_z = None
        rec = self.map.layers[i]
        old = self.layer
        pts = _sorted_points(rec)
        self.below, self.above = self._neighbors(rec.z_cmm)
        if old is not None and old[0] == rec.z_cmm:
            self.layer = (rec.z_cmm, pts, old[2])  # the same layer again keeps its marks
            return True
        self.layer = (rec.z_cmm, pts, [False] * len(pts))
        self.stats.layers_loaded += 1
        if old is None or rec.z_cmm > old[0]:
            self.floor = rec.z_cmm
        return True

    def _eligible(self, m: Move, outer: bool) -> bool:
        if self.s.mode == MODE_OFF or (self.s.mode == MODE_MARKED and not outer):
            return False
        if not (f32(m.e) > 0 and (f32(m.x0) != f32(m.x1) or f32(m.y0) != f32(m.y1))):
            return False
        return self._window(self._cmm(m.z1)) and len(self.layer[1]) > 0

    def _foot(self, i: int, x0, y0, fdx, fdy, len2):
        """Point i against the segment from (x0, y0) along (fdx, fdy), in
        float32 as BulgePlanner::exact: (t of its foot, raised to 0 but not
        capped at 1; whether it lies within the tolerance of the segment)."""
        px, py, _ = self.layer[1][i]
        ux = f32(px) * self.q_mm - x0
        uy = f32(py) * self.q_mm - y0
        t = max((ux * fdx + uy * fdy) / len2, f32(0))
        tc = min(t, f32(1))
        ex, ey = ux - tc * fdx, uy - tc * fdy
        return t, ex * ex + ey * ey <= self.tol2

    def plan(self, m: Move, outer: bool | None = None) -> list[Action]:
        """Actions for one G0/G1 move (or one arc chord)."""
        if outer is None:
            outer = m.outer
        if m.e > 0 and (m.x0 != m.x1 or m.y0 != m.y1) and (self.top_z is None or m.z1 > self.top_z):
            self.top_z = m.z1
        null = m.x0 == m.x1 and m.y0 == m.y1 and m.z0 == m.z1 and m.e == 0
        actions: list[Action] = []
        if self.deferred and not null:
            self._flush(m, outer, actions)
        if not self._eligible(m, outer):
            # as the firmware: a move that moves nothing keeps the owed extra
            dropped = 0.0
            if not null:
                self.stop_ms = 0
                if self.carry != 0:
                    dropped = float(self.carry)
                    self.stats.extra_dropped += dropped
                    self.carry = f32(0)
            return actions + [Action("line", m.x1, m.y1, m.z1, m.e, dropped=dropped)]
        self.last_end = (_bits(m.x1), _bits(m.y1))
        x0, y0, z0 = f32(m.x0), f32(m.y0), f32(m.z0)
        x1, y1, z1 = f32(m.x1), f32(m.y1), f32(m.z1)
        fdx, fdy = x1 - x0, y1 - y0
        len2 = fdx * fdx + fdy * fdy
        pending = self.carry
        self.carry = f32(0)
        zc, pts, fired = self.layer
        # all hits, nearest to the start first (ties: the sorted point order)
        margin = self.s.tolerance + 3 * self.q_um / 1000
        bx0, bx1 = min(m.x0, m.x1) - margin, max(m.x0, m.x1) + margin
        by0, by1 = min(m.y0, m.y1) - margin, max(m.y0, m.y1) + margin
        hits = []
        for i, (px, py, w) in enumerate(pts):
            if fired[i]:
                continue
            xm, ym = px * self.q_um / 1000, py * self.q_um / 1000
            if xm < bx0 or xm > bx1 or ym < by0 or ym > by1:
                continue
            t, near = self._foot(i, x0, y0, fdx, fdy, len2)
            if not near:
                continue
            if t > 1:
                self.deferred.add(i)  # its foot is beyond the end: the next move decides
                continue
            hits.append((t, i))
        if hits:
            self.stats.moves_split += 1
        elif pending == 0:
            # nothing to cut or to add: the move as it is (what line_to(1, 0) makes of it)
            self.stop_ms = 0
            return actions + [Action("line", m.x1, m.y1, m.z1, m.e * (1.0 - 0.0) + 0.0, t=1.0)]
        ln = np.sqrt(len2, dtype=np.float32)
        t_done = f32(0)

        def line_to(t, t_prev):
            nonlocal pending
            # filament in double (the firmware's float differs by ~1e-7 relative);
            # an unsplit move keeps the host's exact number
            piece_e = m.e * (float(t) - float(t_prev))
            if t >= 1:
                a = Action("line", m.x1, m.y1, m.z1, 0.0, t=1.0)
            else:
                ax = x0 + t * (x1 - x0)
                ay = y0 + t * (y1 - y0)
                az = m.z1 if z0 == z1 else float(z0 + t * (z1 - z0))
                a = Action("line", float(ax), float(ay), az, 0.0, t=float(t))
            a.e = piece_e + float(pending)
            a.extra = float(pending)
            self.stats.extra_applied += float(pending)
            pending = f32(0)
            self.stop_ms = 0
            actions.append(a)

        # points that share a stop (no line between them) make one dwell, as
        # the firmware's action lists do: a list only ends before a cut
        hits.sort(key=lambda h: h[0])
        for t, i in hits:
            if (t - t_done) * ln < f32(MIN_PIECE_MM):
                pass  # stop where the head already is
            else:
                if (f32(1) - t) * ln < f32(MIN_PIECE_MM):
                    t = f32(1)
                line_to(t, t_done)
                t_done = t
            pending = self._stop(m, i, actions, pending)
        if t_done < 1:
            line_to(f32(1), t_done)
        else:
            self.carry = self.carry + pending
        return actions

    def _stop(self, m: Move, i: int, actions: list[Action], pending):
        """Point i of the layer stops where the head is now (BulgePlanner::stop);
        returns the extra owed after it."""
        zc, pts, fired = self.layer
        fired[i] = True
        self.stats.points_fired += 1
        px, py, w = pts[i]
        ms = (self.s.dwell_ms * w + 127) // 255
        # one stop (merged points) never exceeds the per-point limits
        ms = min(ms, MAX_DWELL_MS - self.stop_ms)
        self.stop_ms += ms
        if actions and actions[-1].kind == "dwell":
            actions[-1].ms += ms
        else:
            actions.append(Action("dwell", ms=ms))
        self.stats.dwell_ms_total += ms
        # where the head stops: the end of the last line, or the move start
        lx = next((a for a in reversed(actions) if a.kind == "line"), None)
        sx, sy, sz = (lx.x, lx.y, lx.z) if lx else (m.x0, m.y0, m.z0)
        self.stops.append(StopRecord(m.line_no, sx, sy, sz, ms, (px, py), zc))
        extra = f32(self.s.extra_e)
        room = f32(MAX_EXTRA_E_MM) - pending
        if extra > room:
            extra = room if room > 0 else f32(0)
            self.stats.extra_dropped += float(f32(self.s.extra_e) - extra)
        actions[-1].extra = float(pending + extra)
        return pending + extra

    def _flush(self, m: Move, outer: bool, actions: list[Action]) -> None:
        """Points the last move deferred (BulgePlanner::flush): a move that
        continues the wall from its end takes those within the tolerance; the
        others stop at that end now; a move that starts elsewhere (the head
        was moved meanwhile) leaves them unfired."""
        deferred, self.deferred = sorted(self.deferred), set()
        lx, ly = self.last_end
        at_b = _bits(m.x0) == lx and _bits(m.y0) == ly
        on = (at_b and self._keeps(self._cmm(m.z1)) and self.s.mode != MODE_OFF
              and (self.s.mode != MODE_MARKED or outer) and f32(m.e) > 0
              and (_bits(m.x0) != _bits(m.x1) or _bits(m.y0) != _bits(m.y1)))
        if not at_b:
            return
        x0, y0 = f32(m.x0), f32(m.y0)
        fdx, fdy = f32(m.x1) - x0, f32(m.y1) - y0
        len2 = fdx * fdx + fdy * fdy
        for i in deferred:
            if on and len2 != 0 and self._foot(i, x0, y0, fdx, fdy, len2)[1]:
                continue  # this move's own matching takes it
            self.carry = self._stop(m, i, actions, self.carry)


class Skipper:
    """Which moves of a file can change what a RefPlanner does, so that only those go through
    its Python code (a 100 MB file has three million moves; a map's points lie on a few
    thousand). A move is planned when
      - it is a candidate (eligible but for the layer window: mode, outer wall, extruding in
        float32) whose z (0.01 mm, float32) differs from the last candidate's and has a map layer
        within half a layer height: only then can the window load or switch a layer (the same z
        gives the same window, see _window; a z with no layer near only misses, which changes
        nothing but the cache miss_z, and that only saves a search that would miss as well);
      - it is a candidate whose box, widened by plan()'s own margin, holds a point of a map layer
        within half a layer height of its z: only such moves stop or defer points;
      - it is the first move after one of those that moves anything (null moves change nothing):
        it flushes deferred points and takes or drops the extra filament still owed.
    A skipped candidate would only lay its filament unchanged; a skipped other move would only
    keep the state clean, which the moves planned before it already left so. top_z is set from
    every extruding move. host/tests/gcode/test_movescan.py checks stops, extras and drops against
    planning every move.

    With arcs_bypass, arc chords are as the firmware sees them in a file that has them: not at
    all (Marlin cuts arcs into segments past its planner hook, so nothing on an arc is split and
    the core's state is untouched): select() leaves them out. (The annotated file writes the arcs
    that would change anything as chords, fallback.ArcLines.)"""

    def __init__(self, planner: RefPlanner, arcs_bypass: bool = False):
        self.p = planner
        self.arcs_bypass = arcs_bypass
        s = planner.s
        bm = planner.map
        self.lh = planner.lh
        self.margin = s.tolerance + 3 * planner.q_um / 1000 + 1e-6
        pz, px, py = [], [], []
        if bm is not None:
            q = planner.q_um / 1000
            for l in bm.layers:
                for x, y in l.points:
                    pz.append(l.z_cmm)
                    px.append(x * q)
                    py.append(y * q)
        order = np.lexsort((np.array(px), np.array(pz))) if pz else np.empty(0, np.int64)
        # every layer's z, points or none: the window can load any of them (_find)
        self.lz = np.sort(np.array(planner._zs, dtype=np.int64))
        self.pz = np.array(pz, dtype=np.int64)[order]
        self.px = np.array(px, dtype=np.float64)[order]
        self.py = np.array(py, dtype=np.float64)[order]
        self.last_zc = None        # the last candidate's z
        self.owed = False          # a planned move still needs the next moving one planned
        self.top_z = None
        self.own_top = True        # top_z from the chunks' records (lean chunks: their tops)

    def classes_of(self, a: np.ndarray) -> np.ndarray:
        """The chunk's class bits (movescan.classes, kept as self.classes), its highest extruding
        z taken into top_z."""
        c, top, top_line = movescan.classes(a)      # (one pass over the records)
        self.classes = c
        if self.arcs_bypass:
            top = top_line                          # (arc chords: not the planner's)
        if top is not None and self.own_top:
            self.top_z = top if self.top_z is None else max(self.top_z, top)
        return c

    def select(self, a: np.ndarray, followers: bool = True) -> np.ndarray:
        """Indices into the RECORD array a (one chunk, in file order) to plan. followers=False:
        without the first moving move after each (plan_records' lazy run picks those itself
        from self.moving, the chunk's moving moves, when the planner's state asks for one)."""
        c = self.classes_of(a)
        seen = (c & movescan.ARC) == 0 if self.arcs_bypass else np.ones(len(a), bool)  # the planner's
        null = (c & movescan.NULL) != 0
        mode = self.p.s.mode
        ci = np.empty(0, np.intp)
        if mode != MODE_OFF and len(self.pz):
            # candidates: extruding in XY in float32, in the outer wall in marked mode
            want = movescan.EXTRUDES_F32 | (movescan.OUTER if mode == MODE_MARKED else 0)
            ci = np.flatnonzero(((c & want) == want) & seen)
        pick = np.zeros(len(a), bool)
        if len(ci):
            zc = movescan.z_cmm(a["z1"][ci])
            prev = np.concatenate([[self.last_zc if self.last_zc is not None else zc[0] + 1], zc[:-1]])
            # a new z with no map layer within half a layer height cannot load or switch the
            # window (_find finds nothing, whatever the floor): planned, it would only miss
            change = np.flatnonzero(zc != prev)
            lo = np.searchsorted(self.lz, zc[change] - self.lh / 2, side="left")
            hi = np.searchsorted(self.lz, zc[change] + self.lh / 2, side="right")
            pick[ci[change[hi > lo]]] = True
            self.last_zc = int(zc[-1])
            pick[ci[self._near(a, ci, zc)]] = True
        # the first moving move after each picked one (and after the last chunk's)
        moving = np.flatnonzero(~null & seen)
        if not followers:
            self.moving = moving
            return np.flatnonzero(pick)
        if self.owed and len(moving):
            pick[moving[0]] = True
        picked = np.flatnonzero(pick)              # all of them move (candidates, moving[0])
        if len(picked):
            k = np.searchsorted(moving, picked, side="right")
            pick[moving[k[k < len(moving)]]] = True
            self.owed = bool((k >= len(moving)).any())
        return np.flatnonzero(pick)

    def _near(self, a: np.ndarray, ci: np.ndarray, zc: np.ndarray) -> np.ndarray:
        """Candidates (rows ci of the RECORD array a, z in 0.01 mm) whose widened box holds a map
        point of a layer within half a layer height of their z."""
        half = self.lh / 2
        lo = np.searchsorted(self.pz, zc - half, side="left")
        hi = np.searchsorted(self.pz, zc + half, side="right")
        out = np.zeros(len(ci), bool)
        span = hi - lo
        has = np.flatnonzero(span > 0)
        if not len(has):
            return out
        c = a[ci[has]]                           # only the candidates with a layer near
        m = self.margin
        bx0 = np.minimum(c["x0"], c["x1"]) - m
        bx1 = np.maximum(c["x0"], c["x1"]) + m
        by0 = np.minimum(c["y0"], c["y1"]) - m
        by1 = np.maximum(c["y0"], c["y1"]) + m
        # candidate x point pairs, a few million at a time
        csum = np.cumsum(span[has])
        start = 0
        while start < len(has):
            stop = int(np.searchsorted(csum, (csum[start - 1] if start else 0) + 4_000_000, side="right"))
            stop = max(stop, start + 1)
            n = span[has[start:stop]]
            rep = np.repeat(np.arange(start, stop), n)          # positions in has (rows of c)
            off = np.arange(len(rep)) - np.repeat(np.cumsum(n) - n, n)
            j = lo[has[rep]] + off
            px, py = self.px[j], self.py[j]
            ok = (px >= bx0[rep]) & (px <= bx1[rep]) & (py >= by0[rep]) & (py <= by1[rep])
            out[has[np.unique(rep[ok])]] = True
            start = stop
        return out


def record_move(r, index: int, roles) -> Move:
    """One movescan RECORD row as a gcode.Move."""
    role, fl = int(r["role"]), int(r["flags"])
    return Move(index, int(r["line_no"]), float(r["x0"]), float(r["y0"]), float(r["z0"]),
                float(r["x1"]), float(r["y1"]), float(r["z1"]), float(r["e"]), float(r["e_start"]),
                float(r["f"]), bool(fl & movescan.OUTER), roles[role] if 0 <= role < len(roles) else None,
                bool(fl & movescan.ARC))


def record_moves(a, rows, done: int, roles) -> list[Move]:
    """record_move of the RECORD array a's rows (moves before a: done), converted together."""
    out = []
    for i, (x0, y0, z0, x1, y1, z1, e, e0, f, _, line, role, fl, _) in zip(rows.tolist(), a[rows].tolist()):
        out.append(Move(done + i, line, x0, y0, z0, x1, y1, z1, e, e0, f, bool(fl & movescan.OUTER),
                        roles[role] if 0 <= role < len(roles) else None, bool(fl & movescan.ARC)))
    return out


def _clean(planner: RefPlanner) -> bool:
    """Nothing owed to the next move: no deferred point, no extra filament, no stop in progress.
    A move planned then that is not itself picked by the Skipper (not near a point, no new
    window) changes nothing of the planner's state, its stops or its statistics."""
    return not planner.deferred and planner.carry == 0 and planner.stop_ms == 0


class ArcLines:
    """Which G2/G3 lines of a file the outputs write as G1 chords: an on_move hook of a planner run
    that plans every arc's chords (Marlin's own segments, gcode.arc_segments) like G0/G1 moves.
    The bulgekit firmware splits only G0/G1 moves (Marlin cuts an arc into segments past its
    planner hook), so an arc that the run changes must reach it as its chords: one on which a
    point stops, that takes or drops extra filament, or that a point's deferral or a stop in
    progress crosses (the planner is not clean, _clean, before or after one of its chords). Then
    the firmware's stops on the written file are this run's, point for point (every other arc
    left the planner as it found it, as the firmware's bypass of it does). Arcs the run leaves
    alone stay arcs. A move the Skipper does not plan changes nothing and finds the planner
    clean, so the planned ones tell it all.

    `lines`: those arcs' line numbers. As an on_chunk hook too (collect, with plan_records'
    on_chunk), `found` gets each one's chord records (RECORD rows), in file order."""

    def __init__(self, planner: RefPlanner):
        self.planner = planner
        self.lines: set[int] = set()
        self.found: list[np.ndarray] = []
        self._dirty = False               # the planner was not clean after the last planned move
        self._new: list[int] = []         # lines found since the last collect

    def __call__(self, m: Move, actions: list[Action]) -> None:
        dirty = not _clean(self.planner)
        if m.arc and (self._dirty or dirty or not _unchanged(m, actions)) and m.line_no not in self.lines:
            self.lines.add(m.line_no)
            self._new.append(m.line_no)
        self._dirty = dirty

    def collect(self, a: np.ndarray, done: int = 0, planned=None) -> None:
        """on_chunk: the chord records of the lines found in the chunk a (a line's are all in
        one chunk, movescan.Chunks)."""
        if not self._new:
            return
        rows = a[np.isin(a["line_no"], self._new) & ((a["flags"] & movescan.ARC) != 0)]
        starts, _ = movescan.runs(rows["line_no"])
        self.found += np.split(rows, starts[1:])
        self._new = []


def _hooks(*hooks):
    """One on_move hook that calls each of hooks (None: left out) in turn."""
    hooks = [h for h in hooks if h is not None]
    if len(hooks) == 1:
        return hooks[0]

    def each(m, actions):
        for h in hooks:
            h(m, actions)
    return each


def _plan_lazily(planner: RefPlanner, sk: Skipper, a, rows, done: int, roles) -> None:
    """Plan the picked rows of chunk a, and the first moving move after one only when the
    planner's state is not clean after it (Skipper picks every such move; most leave nothing
    owed). sk.owed carries a move owed into the next chunk."""
    moving = sk.moving
    todo = rows.tolist()
    picked = dict(zip(todo, record_moves(a, rows, done, roles)))       # (converted together)
    k, last, follow = 0, -1, sk.owed
    while True:
        if follow:
            j = int(np.searchsorted(moving, last, side="right"))
            if j == len(moving):
                break                              # owed to the next chunk's first moving move
            r = int(moving[j])
            if k < len(todo) and todo[k] == r:
                k += 1
        elif k < len(todo):
            r = todo[k]
            k += 1
        else:
            break
        m = picked.get(r)
        planner.plan(m if m is not None else record_moves(a, np.array([r]), done, roles)[0])
        last = r
        follow = not _clean(planner)
    sk.owed = follow


REACH_VERSION = 1      # the compiled reach planner's VERSION this code calls (_reach.c's module init)
_reach_c = False       # the compiled reach planner once looked for: the module, or None


def _compiled_reach():
    """The compiled reach planner (bulge/_reach.c), or None: not built, or built from an older
    _reach.c (gcode.compiled_helper); the Python planner then does the work, to the same stops."""
    global _reach_c
    if _reach_c is False:
        from ..gcode import compiled_helper
        _reach_c = compiled_helper("_reach", REACH_VERSION, "reach check (_reach)",
                                   "the check runs slower", package=__package__)
    return _reach_c


def _native(planner: RefPlanner, sk: "Skipper", fresh: bool = True):
    """A compiled twin of a planner and its Skipper (_reach.new), or None: not built, no map, or
    layers not in strictly ascending z (its window's search assumes them so; RefPlanner searches
    others one by one). fresh: the twin plans (a lazy run), so the planner must not have planned
    yet; else it only picks the moves (Skipper.select, _reach.pick)."""
    c = _compiled_reach()
    bm = planner.map
    zs = planner._zs
    if c is None or bm is None or any(a >= b for a, b in zip(zs, zs[1:])):
        return None
    if fresh and (planner.layer is not None or planner.stops or planner.deferred):
        return None
    px, py, pw, off = [], [], [], [0]
    for rec in bm.layers:            # each layer's points in the planner's order
        for x, y, ww in _sorted_points(rec):
            px.append(x)
            py.append(y)
            pw.append(ww)
        off.append(len(px))
    f = movescan.RECORD.fields
    offsets = tuple(f[k][1] for k in ("x0", "y0", "z0", "x1", "y1", "z1", "e", "line_no", "flags"))
    i8 = np.int64
    s = planner.s
    return c.new(np.array(zs, i8), np.array(off, i8), np.array(px, i8), np.array(py, i8), np.array(pw, i8),
                 planner.q_um, planner.lh, s.mode, s.dwell_ms, s.extra_e, s.tolerance, offsets,
                 movescan.RECORD.itemsize, sk.lz, sk.pz, sk.px, sk.py, sk.margin, sk.arcs_bypass)


def _adopt(planner: RefPlanner, native) -> None:
    """The compiled run's stops, statistics, top_z and owed extra into the planner. Its layer
    window stays behind: a planner run so is read, not planned further."""
    stops, stats, top, carry, stop_ms = _compiled_reach().result(native)
    planner.stops = [StopRecord(line, x, y, z, ms, (px, py), zc) for line, x, y, z, ms, px, py, zc in stops]
    planner.stats = PlanStats(*stats)
    planner.top_z = top
    planner.carry = f32(carry)
    planner.stop_ms = stop_ms


def plan_records(planner: RefPlanner, chunks, on_move=None, arcs_bypass: bool = False,
                 on_chunk=None, lazy: bool = False) -> None:
    """Run a file's moves (movescan chunks) through the planner, skipping the moves that cannot
    change what it does (Skipper). on_move(move, actions) is called for every planned move as it
    is planned; on_chunk(chunk, moves before it, {row: (move, actions)}) after each chunk.
    arcs_bypass: arc chords are not planned, as the firmware sees them (Skipper). lazy (no on_move,
    no on_chunk: only the planner's stops and statistics count): the move after a picked
    one is planned only when something is owed to it (_plan_lazily), the same stops; by the
    compiled planner (_reach.c) when it is built and the planner is fresh (_native). Otherwise
    the moves are picked in C when it is built (_reach.pick) and planned here."""
    if lazy and (on_move is not None or on_chunk is not None):
        raise ValueError("plan_records: lazy planning hands no moves to on_move or on_chunk")
    sk = Skipper(planner, arcs_bypass)
    lean = getattr(chunks, "tops", None) is not None
    # lean chunks with every arc chord (a kept Scan's, run(..., lean=2)): what any run in marked
    # mode plans (every candidate is an outer-wall move, every follower of one is kept)
    all_arcs = getattr(chunks, "all_arcs", True)
    if lean and not (planner.s.mode == MODE_MARKED and (all_arcs or (lazy and arcs_bypass))):
        raise ValueError("plan_records: lean chunks hold what a lazy run in marked mode with "
                         "arcs bypassed plans, no more")
    sk.own_top = not lean or all_arcs         # (every extruding arc chord, for a top with arcs)
    native = _native(planner, sk, fresh=lazy)
    done = 0
    for a in chunks:
        planned = {}
        if lazy and native is not None:    # select(followers=False) and _plan_lazily, in C
            sk.owed = _reach_c.run(native, np.ascontiguousarray(a), sk.classes_of(a), sk.owed)
            rows = np.empty(0, np.intp)
        elif lazy:
            _plan_lazily(planner, sk, a, sk.select(a, followers=False), done, chunks.roles)
            rows = np.empty(0, np.intp)
        elif native is not None:           # select(a), in C
            got, sk.owed = _reach_c.pick(native, np.ascontiguousarray(a), sk.classes_of(a), sk.owed)
            rows = np.frombuffer(got, np.int64)
        else:
            rows = sk.select(a)
        for i, m in zip(rows.tolist(), record_moves(a, rows, done, chunks.roles)):
            acts = planner.plan(m)
            planned[i] = (m, acts)
            if on_move is not None:
                on_move(m, acts)
        if on_chunk is not None:
            on_chunk(a, done, planned)
        done += len(a)
    if lazy and native is not None:
        _adopt(planner, native)
    if lean:                                   # every part's top, as select() takes a chunk's
        for top in chunks.tops:
            if top is not None:
                sk.top_z = top if sk.top_z is None else max(sk.top_z, top)
    if sk.top_z is not None and (planner.top_z is None or sk.top_z > planner.top_z):
        planner.top_z = sk.top_z


def unreached(planner: RefPlanner) -> list[tuple[int, int, int]]:
    """Map points (layer z in 0.01 mm, x, y in quanta) the planner never stopped at."""
    if planner.map is None:
        return []
    fired: dict[int, set] = {}
    for s in planner.stops:
        fired.setdefault(s.layer_z_cmm, set()).add(s.point)
    return [(l.z_cmm, x, y) for l in planner.map.layers for (x, y) in l.points
            if (x, y) not in fired.get(l.z_cmm, ())]


def unreached_message(planner: RefPlanner, source: str) -> str | None:
    """What is wrong when map points are never reached, or None."""
    if planner.map is not None and not planner.map.layers:
        return (f"{source}: the map has no points (a header only): nothing would bulge. "
                "Use --allow-unreached to write the file anyway.")
    miss = unreached(planner)
    if not miss:
        return None
    bm = planner.map
    per_layer: dict[int, int] = {}
    for z, _, _ in miss:
        per_layer[z] = per_layer.get(z, 0) + 1
    whole = [z for l in bm.layers for z in [l.z_cmm] if per_layer.get(z) == len(l.points)]
    part = [(z, n) for z, n in per_layer.items() if z not in whole]

    def zl(zs):
        zs = sorted(zs)
        return ", ".join(f"{z / 100:.2f}" for z in zs[:6]) + (" ..." if len(zs) > 6 else "")
    where = "outer-wall" if planner.s.mode == MODE_MARKED else "extruding"
    out = [f"{source}: {len(miss)} of {bm.point_count} map points are not within "
           f"{planner.s.tolerance:.2f} mm of any {where} move"]
    if whole:
        out.append(f"{len(whole)} layer(s) get no stop at all (z {zl(whole)} mm)")
        top = planner.top_z
        above = [z for z in whole if top is None or 2 * (z - round(top * 100)) > bm.layer_height_cmm]
        if above:
            out.append(f"{len(above)} of them above the print's last extrusion at z {top:.2f} mm"
                       if top is not None else "the G-code has no extruding X/Y move")
    if part:
        out.append(f"{sum(n for _, n in part)} point(s) missed on {len(part)} other layer(s) "
                   f"(z {zl(z for z, _ in part)} mm)")
    return ("; ".join(out) + ". Is the map made for this G-code (same slice, same "
            "--geometric/tolerance)? Use --allow-unreached to write the file anyway.")


# --- stops for stock firmware -------------------------------------------------------------
# A stop is written as an extruder-only move (--stop move, the default) or as G4 P<ms>
# (--stop g4, the paper's rewrite). Marlin's G4 drains the planner queue before it dwells
# (planner.synchronize()); a G1 of E alone is queued like any move, and the head stands still
# while the extruder makes its steps. Measured in simulated stock Marlin 2.1.2.7 (issue 25,
# docs/verification/marlin-simulation.md): with n whole E steps at r steps/s the head stands still for
#     1/max(r, 120) + (n - 1)/r + 1/max(120, v k) s
# where r is the block's nominal rate, ceil(n x feed / length) in whole steps/s, and 120 steps/s
# Marlin's MINIMAL_STEP_RATE. The E move's first step comes 1/r after the last X/Y step (never
# later than 1/120 s); the next X/Y move enters at v = min(r / E steps/mm, v_jd) (junction
# deviation takes the E-only move as a 90 degree corner) and makes its first step 1/(v k) after
# the last E step, k being its leading axis's steps per mm of path. Below v k = 120 this is
# 1/120 + (n - 1)/r + 1/120 (issue 25's rule); short, fast stops end sooner than that rule says.
# Every number of it is the printer model's (issue 36, bulge/stopmodel.py): the floor
# (min_step_rate), the E speed up to which the E move enters at its own speed (junction deviation
# at M204 R, or the E/X jerks), v (junction deviation at the next move's own acceleration, with
# LIN_ADVANCE's cut; classic jerk: the next move's jerk-limited safe speed, 10 mm/s along X at
# Marlin's jerks, whatever the E rate), the steps per mm and the segment minimum. The few names
# below that stand for printer numbers are the default model's; the rule reads the printer's.
# Firmwares other than Marlin 2.x (prusa, reprap, klipper) keep the Marlin defaults' rule.
STOP_MOVE, STOP_G4 = "move", "g4"
DEFAULT_E_STEPS = machine.DEFAULT.e_steps   # the default printer model's E steps/mm
MIN_STEPS_PER_SEGMENT = machine.DEFAULT.min_segment_steps   # Marlin drops a move with fewer steps
                               # on every axis (the default model's; the rule reads the printer's)
SLOWEST_STEP_RATE = 32         # steps/s: AVR stepper timer's longest interval (F_CPU / 500000)
XY_STEPS = machine.DEFAULT.steps_per_mm.x   # steps/mm of X: the default model's, where no printer
                               # says (still_s's k)
NEAREST_MS = 1.0               # a stop further than this from its dwell is counted as "nearest"
MIN_AUTORETRACT = 0.1          # mm: with FWRETRACT autoretract on (M209 S1) Marlin turns a move of
                               # E alone this long or longer into a firmware retract/recover
G4_OVER_S = 0.017              # G4 P100 held the head 116.4-117.4 ms (issue 25): a move that would
                               # miss its dwell by more than this is written as G4 instead


@dataclass(frozen=True)
class StockStops:
    """How a stock file writes its stops, for which printer. e_steps: the printer's E steps/mm
    until the file's own M92 E changes it (the printer runs the file's M92, so that wins from its
    line on); None: the printer model's. stop_e_steps: E steps laid during each stop (None: the
    fewest that make a move, 6, or more when a long dwell needs them to keep the rate above
    SLOWEST_STEP_RATE); they are taken from the stop's extra filament, the rest of which goes on
    the next piece as before. printer: the model whose planner runs the file (bulgekit.machine)."""
    stop: str = STOP_MOVE
    e_steps: float | None = None
    stop_e_steps: int | None = None
    printer: PrinterModel = machine.DEFAULT

    def __post_init__(self):
        if self.e_steps is None:
            object.__setattr__(self, "e_steps", self.printer.e_steps)
        if self.stop not in (STOP_MOVE, STOP_G4):
            raise ValueError(f"stop {self.stop!r} must be {STOP_MOVE!r} or {STOP_G4!r}")
        if not (math.isfinite(self.e_steps) and 1 <= self.e_steps <= 10000):
            raise ValueError(f"E steps {self.e_steps} outside 1..10000 steps/mm")
        if self.stop_e_steps is not None and not MIN_STEPS_PER_SEGMENT <= self.stop_e_steps <= 10000:
            raise ValueError(f"stop E steps {self.stop_e_steps} outside {MIN_STEPS_PER_SEGMENT}..10000")

    @property
    def klipper(self) -> bool:
        """Stops as E-only moves planned the way Klipper plans them (klipper_stop)."""
        return (self.stop == STOP_MOVE and self.printer is not None
                and getattr(self.printer, "firmware", None) == "klipper")


def rule_model(pm: PrinterModel | None) -> PrinterModel:
    """The model whose planner the stop rule follows: the printer's own for Marlin 2.x, Marlin's
    defaults for the other firmwares (their planners are not modelled here)."""
    if pm is None or pm.firmware != "marlin":
        return machine.DEFAULT
    return pm


def _floor(pm: PrinterModel):
    f = pm.min_step_rate
    return int(f) if f == int(f) and f > 0 else (f if f > 0 else 1)


def still_s(n: int, rate: int, spm: float | None = None, k: float = XY_STEPS,
            printer: PrinterModel | None = None, nxt: Piece | None = None) -> float:
    """Seconds the head stands still for an E-only move of n steps at `rate` steps/s (the rule
    above) at `spm` E steps/mm, the next move's leading axis making k steps per mm of its path,
    on `printer` (None: Marlin's defaults); nxt: that move (direction, E per mm, feed), which the
    classic-jerk and LIN_ADVANCE junctions need. Without spm: issue 25's rule (the next move
    starts at the 120 steps/s floor)."""
    pm = rule_model(printer)
    # the E block's steps as Marlin's AVR timer makes them (stopmodel.avr_interval_s): its
    # first at max(rate, floor), the others at the rate; 1/rate is exact only at the table's
    # points, and at 38-39 steps/s the table's 16-bit product wraps (a 200 ms stop of 8 steps
    # at 38 steps/s held the head 231 ms)
    first = stopmodel.avr_interval_s(max(rate, _floor(pm)))
    return first + (n - 1) * stopmodel.avr_interval_s(rate) + next_start_s(rate, spm, k, pm, nxt, n)


def next_start_s(rate: int, spm: float | None = None, k: float = XY_STEPS,
                 printer: PrinterModel | None = None, nxt: Piece | None = None, n: int = 0) -> float:
    """The last term of still_s: from the stop's last E step to the next move's first step."""
    pm = rule_model(printer)
    v = stopmodel.next_entry(pm, rate, spm, nxt, n) if spm else 0.0
    return 1 / max(_floor(pm), v * k)


@dataclass
class StopMove:
    """One stop as written: `g4` (a G4 P ms), or an E-only move of n steps at `rate` steps/s."""
    ms: int
    kind: str
    n: int = 0
    rate: int = 0
    still: float = 0.0         # s the head stands still (G4: the dwell itself)
    start: float = 0.0         # of that, s until the next move's first step (next_start_s)
    nearest: bool = False      # the dwell could not be made exactly (counted in the stats)
    why: str = ""              # a move stop written as G4: "extra" (under 6 steps), "long"
    klipper: klipper_stop.KlipperStop | None = None   # Klipper's form: E (mm) and speed
    ramp: float = 0.0          # s the moves around it add by braking and starting (stopmodel.ramp_s)
    v_exit: float = 0.0        # mm/s the move before brakes to (the E move's entry; G4: 0)
    v_entry: float = 0.0       # mm/s the move after starts at (next_entry; G4: 0)
    here: Piece | None = None  # the move it stops on (for stopmodel.chain_ramps)
    after: Piece | None = None  # the piece the head goes on with

    def feed(self, spm: float) -> float:
        """mm/min whose block rate, ceil(n x feed / length), is `rate`: the middle of the feeds
        that give it, so float rounding in the firmware cannot change it."""
        return (self.rate - 0.5) * 60 / spm


def _min_steps_for(d: float, pm: PrinterModel = machine.DEFAULT) -> int:
    """The fewest steps whose rate stays at or above SLOWEST_STEP_RATE for a stillness of d s."""
    need = 1 + SLOWEST_STEP_RATE * (d - 2 / _floor(pm))
    return max(_min_segment(pm), math.ceil(need - 1e-9))


def _min_segment(pm: PrinterModel) -> int:
    return pm.min_segment_steps if pm.min_segment_steps > 0 else 1


def plan_stop(ms: int, spm: float, owed_mm: float, steps: int | None = None,
              k: float = XY_STEPS, printer: PrinterModel | None = None,
              nxt: Piece | None = None, here: Piece | None = None) -> StopMove:
    """The E-only move for a stop of `ms`: n whole steps (`steps`, or the fewest that make it),
    at most the whole steps of the extra owed at the stop, and the rate whose stillness is
    nearest the dwell (k: the next move's leading-axis steps per mm of path, see still_s). Falls back to G4 when the owed extra is under MIN_STEPS_PER_SEGMENT steps
    (a shorter E-only move is dropped by Marlin: the stop would be lost). printer: the model
    (None: Marlin's defaults); nxt / here: the moves after and before the stop, for the
    junctions and for the stop-and-start time (`ramp`, with `here`)."""
    pm = rule_model(printer)
    d = ms / 1000
    if ms == 0:
        return StopMove(0, "none")            # a weight-0 point: nothing to hold
    want = steps if steps is not None else _min_steps_for(d, pm)
    avail = math.floor(owed_mm * spm + 1e-6)
    if avail < _min_segment(pm):
        return _g4(ms, "extra", pm, here, nxt)
    best = None
    # whole rates make the stillness come in quanta ((n - 1)/r^2 per step/s, large at low
    # rates): unless the steps were given, a step or a few more are added when the fewest
    # miss the dwell by more than NEAREST_MS
    last = want if steps is not None else min(avail, 2 * want + 8)
    for n in range(min(want, avail), max(min(want, avail), last) + 1):
        cand = _rate_for(n, d, spm, k, pm, nxt)
        if best is None or abs(cand.still - d) < abs(best.still - d) - 1e-9:
            best = cand
        if abs(best.still - d) * 1000 <= NEAREST_MS:
            break
    best.ms = ms
    if abs(best.still - d) > G4_OVER_S and best.still < d:
        # too little extra for the slowest rate: G4 holds nearer the dwell, despite its drain
        return _g4(ms, "long", pm, here, nxt)
    best.nearest = abs(best.still - d) * 1000 > NEAREST_MS
    if here is not None:
        best.here, best.after = here, nxt
        best.v_exit = stopmodel.e_entry(pm, best.rate, spm, here)
        best.v_entry = stopmodel.next_entry(pm, best.rate, spm, nxt, best.n)
        best.ramp = stopmodel.ramp_s(pm, here, best.v_exit, best.v_entry)
    return best


def _g4(ms: int, why: str, pm: PrinterModel, here: Piece | None,
        after: Piece | None = None) -> StopMove:
    """A stop written as G4: the head brakes to rest and starts from rest (and the planner
    drains and refills, which is not counted in `ramp`)."""
    ramp = stopmodel.ramp_s(pm, here, 0.0, 0.0) if here is not None else 0.0
    return StopMove(ms, STOP_G4, still=ms / 1000, why=why, ramp=ramp, here=here, after=after)


def _rate_for(n: int, d: float, spm: float, k: float = XY_STEPS,
              printer: PrinterModel | None = None, nxt: Piece | None = None) -> StopMove:
    """n steps at the whole rate whose stillness is nearest d s: a first guess from issue 25's
    rule, then the whole rates around it by the full rule (stillness falls as the rate rises)."""
    pm = rule_model(printer)
    floor = _floor(pm)
    # above the E entry limit (junction deviation at M204 R; classic jerk: the E/X jerks) the E
    # move would have to accelerate from the junction: the rule holds below it
    r_max = max(int(min(pm.max_feedrate.e, stopmodel.e_entry_limit(pm)) * spm), floor)
    if d >= (n + 1) / floor:
        r = (n - 1) / (d - 2 / floor)
    elif d > 1 / floor:
        r = n / (d - 1 / floor)
    else:
        r = float(r_max)
    clamp = lambda q: min(max(q, SLOWEST_STEP_RATE), r_max)
    still = lambda q: still_s(n, q, spm, k, pm, nxt)
    lo, hi = clamp(math.floor(r)), clamp(math.ceil(r))
    # the full rule's stillness is at most the first guess's: slow down until it is not short
    while lo > SLOWEST_STEP_RATE and still(lo) < d:
        hi, lo = lo, clamp(max(SLOWEST_STEP_RATE, lo - max(1, lo // 16)))
    while hi - lo > 1:                                   # bisect the whole rates between
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if still(mid) >= d else (lo, mid)
    cands = [lo, hi]
    if lo <= 40:
        # under 40 steps/s the AVR timer is not monotonic (38 and 39 steps/s wrap: avr_ticks), so
        # the bisection may stop beside the nearest: try every rate there
        cands += [q for q in range(SLOWEST_STEP_RATE, 41) if q <= r_max]
    rate = min(cands, key=lambda q: abs(still(q) - d))
    return StopMove(0, STOP_MOVE, n, rate, still(rate), start=next_start_s(rate, spm, k, pm, nxt, n))


def _lround(v) -> int:
    """C's lroundf: halves away from zero."""
    v = float(v)
    return int(math.floor(v + 0.5)) if v >= 0 else -int(math.floor(-v + 0.5))


def _digits(value: float, ok) -> str:
    """value with 6 or more decimals, as few as make ok(written value) true."""
    for nd in range(6, 12):
        txt = f"{value:.{nd}f}"
        if ok(float(txt)):
            break
    return txt.rstrip("0").rstrip(".") if "." in txt else txt


def stop_e_lines(e_pos: float, n: int, spm: float, abs_e: bool) -> tuple[list[str], str, float]:
    """(lines before the stop, its E word, the filament it lays in host terms) for an E-only move
    of exactly n steps from host E e_pos. Marlin plans a move to lround(E x steps/mm) steps, in
    float. The target is put in the middle of a step, lround(e_pos x spm) + n, a whole number,
    so that neither float32 nor the fraction carried from before changes the count:
      - absolute E (M82): Marlin's position is the last E the file wrote, known here exactly:
        the move goes to the target;
      - relative E (M83): Marlin adds each E to its position in float32, which drifts from the
        host's sum (0.1 mm over 1,400 mm of a file without G92 E0: ten steps at 93 steps/mm),
        so the position is first set to the whole step nearest the host's (G92 E), and the move
        is n steps from there.
    The filament laid is target/spm - e_pos either way (the next piece lays the rest of the
    extra, so the total is the host's); as many digits as the exact count needs."""
    f = np.float32
    spm32 = f(spm)
    start = _lround(f(e_pos) * spm32)
    target = start + n
    if abs_e:
        e = _digits(target / spm, lambda v: _lround(f(v) * spm32) == target)
        return [], f"E{e}", float(e) - e_pos
    base = _digits(start / spm, lambda v: _lround(f(v) * spm32) == start)
    step = _digits(n / spm, lambda v: _lround(f(f(float(base)) + f(v)) * spm32) == target)
    return [f"G92 E{base}"], f"E{step}", float(base) + float(step) - e_pos


class StopWriter:
    """Writes the stops of one stock file (used by rewrite() and the byte path alike) and counts
    what it wrote. E laid during a stop is taken from the extra filament of the next piece
    (`debt`); if that piece never comes (the extra is dropped at a wall's end), it stays laid."""

    def __init__(self, stops: StockStops, m92: list[tuple[int, float]] | None = None):
        self.cfg = stops
        self.m92 = list(m92 or [])             # (line number, E steps/mm) of the file's M92 E
        self.debt = 0.0
        self.moves = 0                         # stops written as E-only moves
        self.g4 = 0                            # stops written as G4 (--stop g4, or too little extra)
        self.g4_why: dict[str, int] = {}       # --stop move, written as G4: why (StopMove.why)
        self.nearest = 0                       # stops whose stillness is off their dwell (> 1 ms)
        self.still_s = 0.0                     # stillness of the E-only stops, s
        self.run_s = 0.0                       # their time as blocks: the stillness but the
                                               # next move's start (gcode/estimate.py's model)
        self.g4_s = 0.0                        # dwell of the G4 stops, s
        self.stop_e_mm = 0.0                   # E laid during stops
        self.unpaid_e_mm = 0.0                 # of that, not taken from a following piece
        self.autoretract = 0                   # stops of MIN_AUTORETRACT or more (see there)
        self.pm = rule_model(stops.printer)    # the planner the stops are timed for
        self.ramp_s = 0.0                      # braking into and starting from the stops, s, by
                                               # the model's stepper arithmetic (stopmodel.ramp_s)
        self.written: list[StopMove] = []      # every stop counted, in the file's order
        self.arcs = ArcCount()                 # G2/G3 written as G1 chords (ArcLines)
        # Klipper's form (stops.klipper): its numbers, the toolhead's accel as the file sets it,
        # the last X/Y move (end x, y and unit direction) and E moved past the cross-section limit
        self.kp = klipper_stop.KlipperParams.from_model(stops.printer) if stops.klipper else None
        self.accel = self.kp.accel if self.kp else None
        self.prev = None
        self.spill_e_mm = 0.0                  # E moved on to a later piece (cross-section limit)
        self.capped_e_mm = 0.0                 # of that, E no later piece of its wall could take
        self.spill = 0.0                       # E owed to the next extruding piece
        self.guessed = 0                       # Klipper stops with a neighbour's direction unknown

    _ACCEL_RX = re.compile(r"^\s*(?:M204\b(?P<m>[^;]*)|SET_VELOCITY_LIMIT\b(?P<s>[^;]*))", re.I)

    def note_accel(self, raw: str) -> None:
        """Klipper's M204 (S, else the smaller of P and T: toolhead.py cmd_M204) and
        SET_VELOCITY_LIMIT ACCEL= set the toolhead's max_accel, which the stop's head terms use
        (max_extrude_only_accel stays what the config made it)."""
        mt = self._ACCEL_RX.match(raw)
        if not mt or self.kp is None:
            return
        if mt.group("m") is not None:
            w = {k.upper(): float(v) for k, v in
                 re.findall(r"([SPTspt])\s*([-+]?(?:\d+\.?\d*|\.\d+))", mt.group("m"))}
            acc = w.get("S")
            if acc is None and "P" in w and "T" in w:
                acc = min(w["P"], w["T"])
        else:
            v = re.search(r"\bACCEL\s*=\s*([-+]?(?:\d+\.?\d*|\.\d+))", mt.group("s"), re.I)
            acc = float(v.group(1)) if v else None
        if acc is not None and acc > 0:
            self.accel = acc

    def lose_spill(self) -> None:
        self.capped_e_mm += self.spill
        self.spill = 0.0

    def note_move(self, m: Move) -> None:
        """The last move with X/Y motion (the one a stop at its end decelerates on)."""
        dx, dy = m.x1 - m.x0, m.y1 - m.y0
        ln = math.hypot(dx, dy)
        if ln > 1e-9:
            self.prev = (m.x1, m.y1, dx / ln, dy / ln)
        elif m.z1 != m.z0:
            self.prev = None

    def edge_in(self, at, u) -> float:
        """tail_s of a stop at `at` reached along u (None: not known, the mean)."""
        if u is None:
            self.guessed += 1
            return klipper_stop.mean_edge_s(self.kp, self.accel)
        return klipper_stop.tail_s(self.kp, at[0], at[1], u[0], u[1], self.accel)

    def edge_out(self, at, u) -> float:
        if u is None:
            self.guessed += 1
            return klipper_stop.mean_edge_s(self.kp, self.accel)
        return klipper_stop.lead_s(self.kp, at[0], at[1], u[0], u[1], self.accel)

    def plan_klipper(self, a: Action, tail: float, lead: float, later: bool = False) -> StopMove:
        """Klipper's form of the stop (klipper_stop.plan): the extra owed here, less what
        stops before it laid already, in one E-only move timed so that the head stands the
        dwell; G4 when nothing is owed. later: the lead is known only later (the E is chosen
        for the longest lead)."""
        ks = klipper_stop.plan(self.kp, a.ms, a.extra - self.debt, tail, lead, self.accel,
                               klipper_stop.max_edge_s(self.kp, self.accel) if later else None)
        if ks is None:
            return StopMove(a.ms, STOP_G4, still=a.ms / 1000, why="extra")
        still = ks.still
        return StopMove(a.ms, STOP_MOVE, still=still, start=lead, klipper=ks,
                        nearest=abs(still - a.ms / 1000) * 1000 > NEAREST_MS)

    def spm_at(self, line_no: int) -> float:
        k = bisect.bisect_left(self.m92, (line_no,))
        return self.m92[k - 1][1] if k else self.cfg.e_steps

    def note_m92(self, line_no: int, raw: str) -> None:
        """rewrite()'s stream: an M92 line (the byte path scans the file for them first)."""
        mt = _M92_RX.match(raw.encode("utf-8", "replace"))
        v = _m92_e(mt.group(1)) if mt else None
        if v is not None:
            self.m92.append((line_no, v))

    def plan(self, a: Action, line_no: int, k: float = XY_STEPS, nxt: Piece | None = None,
             here: Piece | None = None) -> StopMove:
        """k: leading-axis steps per mm of the move the head goes on with (see still_s); nxt,
        here: the moves after and before the stop (plan_stop)."""
        if self.cfg.stop == STOP_G4:
            return _g4(a.ms, "", self.pm, here, nxt)
        # the extra owed here, less what stops before it (not yet paid) laid already
        return plan_stop(a.ms, self.spm_at(line_no), a.extra - self.debt, self.cfg.stop_e_steps, k,
                         self.pm, nxt, here)

    def count(self, stop: StopMove, laid: float = 0.0) -> None:
        self.ramp_s += stop.ramp
        self.written.append(stop)
        if stop.kind == STOP_G4:
            self.g4 += 1
            self.g4_s += stop.still
            if stop.why:
                self.g4_why[stop.why] = self.g4_why.get(stop.why, 0) + 1
            return
        self.moves += 1
        self.still_s += stop.still
        self.run_s += stop.still - stop.start
        self.nearest += stop.nearest
        self.stop_e_mm += laid
        self.debt += laid
        self.autoretract += laid >= MIN_AUTORETRACT - 1e-9 and self.kp is None

    def drop(self) -> None:
        """The planner dropped the extra owed: E a stop laid stays laid."""
        self.unpaid_e_mm += self.debt
        self.debt = 0.0

    def pay(self, a: Action) -> float:
        """Filament to take off a line piece for E laid during the stops before it: the piece
        that carries their extra (a stop's E may pass its whole steps of extra by the half step
        it was aimed to the middle of: that comes off the piece's own filament)."""
        if self.debt == 0 or a.extra <= 0:
            return 0.0
        take = min(self.debt, a.e)
        self.unpaid_e_mm += self.debt - take
        self.debt = 0.0
        return take

    def summary(self) -> str:
        if self.cfg.stop == STOP_G4:
            return f"stops as G4 P<ms>: {self.g4} ({self.g4_s:.1f} s dwell)"
        out = (f"stops as E-only moves{' (Klipper)' if self.kp else ''}: {self.moves} "
               f"({self.still_s:.1f} s head still, {self.stop_e_mm:.3f} mm E in them)")
        if self.kp is not None and self.spill_e_mm > 1e-9:
            out += (f"; {self.spill_e_mm:.3f} mm extra moved on to later pieces (Klipper's "
                    f"max_extrude_cross_section)")
            if self.capped_e_mm > 1e-9:
                out += f", {self.capped_e_mm:.3f} mm of it left out"
        if self.g4_why.get("extra"):
            out += f"; {self.g4_why['extra']} as G4 (extra under {_min_segment(self.pm)} E steps)"
        if self.g4_why.get("long"):
            out += (f"; {self.g4_why['long']} as G4 (dwell too long for the extra's steps at "
                    f"{SLOWEST_STEP_RATE} steps/s)")
        if self.nearest:
            out += f"; {self.nearest} not exactly as asked (nearest made)"
        if self.unpaid_e_mm > 1e-9:
            out += f"; {self.unpaid_e_mm:.3f} mm stop E beyond the extra (dropped at walls' ends)"
        if self.autoretract:
            out += (f"; {self.autoretract} lay {MIN_AUTORETRACT} mm or more: with FWRETRACT "
                    "autoretract on (M209 S1) Marlin would make them recover moves")
        return out


def _fmt(v: float, nd: int = 5) -> str:
    s = f"{v:.{nd}f}".rstrip("0").rstrip(".")
    if s in ("-0", ""):
        s = "0"
    return s


@dataclass
class RewriteResult:
    lines_in: int = 0
    moves_split: int = 0
    stops: list = field(default_factory=list)
    stats: PlanStats | None = None
    unreached: str | None = None     # message when map points get no stop
    stock: StopWriter | None = None  # how the stops were written, and their counts
    planner: RefPlanner | None = None  # the planner after its run over the file


def rewrite(lines: Iterable[str], bmap: mapformat.BulgeMap, settings: Settings,
            source: str = "<gcode>", result: RewriteResult | None = None,
            stops: StockStops = StockStops(), planner: RefPlanner | None = None,
            on_move=None) -> Iterator[str]:
    """Yield the stock-firmware G-code (lines end with '\\n'). planner: a new one to run (else
    one is made); on_move(move, actions) is called for every move as it is planned."""
    planner = planner if planner is not None else RefPlanner(bmap, settings)
    arcs = ArcLines(planner)
    st = GcodeState()
    res = result if result is not None else RewriteResult()
    sw = res.stock = StopWriter(stops)
    yield _header(bmap, settings, stops)
    if sw.kp is not None:
        yield from _rewrite_klipper(lines, source, st, planner, res, sw, on_move, arcs)
    else:
        for ln, raw, per_move in _planned(lines, source, st, planner, res, arcs, on_move):
            if per_move is None:
                if ln.cmd == "M92":
                    sw.note_m92(ln.line_no, ln.raw)
                yield raw
                continue
            unchanged = all(_unchanged(m, a) for m, a in per_move)
            if unchanged and ln.line_no not in arcs.lines:
                if any(a.dropped for _, acts in per_move for a in acts):
                    sw.drop()
                yield raw
                continue
            res.moves_split += not unchanged
            yield from _emit(ln, per_move, st, sw)
        if sw.arcs.arcs:
            yield f"; bulgekit fallback: {sw.arcs.text()}\n"
    res.stops = planner.stops
    res.stats = planner.stats
    res.planner = planner
    res.unreached = unreached_message(planner, source)


def _planned(lines, source, st, planner, res, arcs: "ArcLines", on_move):
    """rewrite()'s lines as both its loops take them: (line, its text with a line end, its
    [(move, actions)], None for a line without moves), each move planned and handed to the arcs'
    hook and to on_move as it is planned."""
    for ln in parse_lines(lines, source, st):
        res.lines_in += 1
        raw = ln.raw if ln.raw.endswith("\n") else ln.raw.rstrip("\r") + "\n"
        if not ln.moves:
            yield ln, raw, None
            continue
        per_move = [(m, planner.plan(m)) for m in ln.moves]
        for m, acts in per_move:
            arcs(m, acts)
            if on_move is not None:
                on_move(m, acts)
        yield ln, raw, per_move


def _rewrite_klipper(lines, source, st, planner, res, sw: StopWriter, on_move,
                     arcs: "ArcLines") -> Iterator[str]:
    """rewrite()'s loop for Klipper's form: the same lines, and (a) the toolhead's accel as the
    file's M204 / SET_VELOCITY_LIMIT set it, (b) the last X/Y move seen (a stop at the next
    move's start decelerated on it), (c) a stop at the end of a line held until the next move
    with motion shows where the head goes on (_KlipperPending)."""
    pend, held = None, []
    for ln, raw, per_move in _planned(lines, source, st, planner, res, arcs, on_move):
        if per_move is None:
            sw.note_accel(ln.raw)
            outs = [raw]
        else:
            if pend is not None:
                kin = next((m for m in ln.moves if (m.x0, m.y0, m.z0) != (m.x1, m.y1, m.z1)), None)
                for m in ln.moves[:ln.moves.index(kin) if kin is not None else len(ln.moves)]:
                    pend.note_e_only(m)
                if kin is not None:
                    at = pend.at
                    same = abs(kin.x0 - at[0]) < 1e-6 and abs(kin.y0 - at[1]) < 1e-6
                    held[0] = pend.resolve(_unit_xy(kin) if same else None)
                    yield from held
                    pend, held = None, []
            unchanged = all(_unchanged(m, a) for m, a in per_move) and ln.line_no not in arcs.lines
            if unchanged and sw.spill > 0:     # extra owed past the cross-section limit
                if any(m.e > 0 and (m.x0, m.y0) != (m.x1, m.y1) for m in ln.moves):
                    unchanged = False          # this line's extruding move takes it (_emit)
                elif any((m.x0, m.y0) != (m.x1, m.y1) for m in ln.moves):
                    sw.lose_spill()            # a travel first: the wall ended
            if unchanged:
                if any(a.dropped for _, acts in per_move for a in acts):
                    sw.drop()
                for m, _ in per_move:
                    sw.note_move(m)
                outs = [raw]
            else:
                res.moves_split += not all(_unchanged(m, a) for m, a in per_move)
                outs = list(_emit(ln, per_move, st, sw))
        for o in outs:
            if isinstance(o, _KlipperPending):
                if pend is not None:           # (a line ends with one stop at most)
                    held[0] = pend.resolve(None)
                    yield from held
                    held = []
                pend = o
                held.append(o)
            elif pend is not None:
                held.append(o)
            else:
                yield o
    if pend is not None:
        held[0] = pend.resolve(None)
        yield from held
    sw.lose_spill()
    if sw.arcs.arcs:
        yield f"; bulgekit fallback: {sw.arcs.text()}\n"


def _unchanged(m: Move, actions: list[Action]) -> bool:
    """The planner left the move as it was: one line to its end with its own filament."""
    return (len(actions) == 1 and actions[0].kind == "line" and actions[0].t == 1.0
            and abs(actions[0].e - m.e) < 1e-12)


def _lead_steps(m: Move, at: tuple, nxt: Action | None, spm: float, stop_n: int,
                pm: PrinterModel = machine.DEFAULT) -> float:
    """Steps per mm of path of the leading axis of the piece the head goes on with (still_s's k):
    X/Y at XY_STEPS, or E where that piece carries the rest of the extra in more steps than X/Y
    make (at 415 E steps/mm, 37-49 steps over 0.1-0.6 mm: Marlin then starts it at its entry
    speed times E's steps per mm, and the head moves on sooner; stock-verify, issue 25). Without
    a piece after the stop on this move (a stop at its end), the move's own direction, X/Y only.
    `at`: where the head stands (x, y). X and Y steps/mm: the printer model's."""
    sx, sy = pm.steps_per_mm.x, pm.steps_per_mm.y
    if nxt is not None and nxt.kind == "line":
        dx, dy = nxt.x - at[0], nxt.y - at[1]
        length = math.hypot(dx, dy)
        if length > 1e-9:
            e_steps = max(0.0, nxt.e * spm - stop_n)     # the stop's steps come out of its extra
            return max(_xy_steps(sx, sy, abs(dx), abs(dy)), e_steps) / length
    dx, dy = abs(m.x1 - m.x0), abs(m.y1 - m.y0)
    length = math.hypot(dx, dy)
    return _xy_steps(sx, sy, dx, dy) / length if length > 1e-9 else sx


def _xy_steps(sx: float, sy: float, dx: float, dy: float) -> float:
    """The leading X/Y axis's steps over (dx, dy) (>= 0)."""
    return sx * max(dx, dy) if sx == sy else max(sx * dx, sy * dy)


def _pieces(m: Move, at: tuple, nxt: Action | None, spm: float, stop_n: int, k: float,
            pm: PrinterModel, owed: float = 0.0) -> tuple[Piece, Piece]:
    """(the move the head stops on, the piece it goes on with) as stopmodel sees them: unit
    direction, filament per mm of path (the piece after: less the stop's own steps), feed mm/s,
    k (the piece after: `k` as _lead_steps gave it), length. A stop at the move's end: the next
    line carries the rest of the extra (`owed`), taken as a piece like this move."""
    f = m.f / 60.0
    here = stopmodel.piece_of(pm, m)
    length = math.hypot(m.x1 - m.x0, m.y1 - m.y0)
    rest = max(0.0, owed - stop_n / spm)
    after = Piece(here.ux, here.uy, here.e_per_mm + (rest / length if length > 1e-9 else 0.0), f, k,
                  length)
    if nxt is not None and nxt.kind == "line":
        ndx, ndy = nxt.x - at[0], nxt.y - at[1]
        nlen = math.hypot(ndx, ndy)
        if nlen > 1e-9:
            e = max(0.0, nxt.e - stop_n / spm)
            after = Piece(abs(ndx) / nlen, abs(ndy) / nlen, e / nlen, f, k, nlen)
    return here, after


def _unit_xy(m: Move) -> tuple[float, float] | None:
    dx, dy = m.x1 - m.x0, m.y1 - m.y0
    ln = math.hypot(dx, dy)
    return (dx / ln, dy / ln) if ln > 1e-9 else None


class _KlipperPending:
    """A Klipper stop at the end of a line: its E is fixed, its speed waits for the direction
    of the next move (the lead term, klipper_stop.lead_s). rewrite() holds the output after it
    until that move's line comes (resolve), or the file ends (resolve(None): the mean)."""

    def __init__(self, sw: StopWriter, stop: StopMove, at, before: list[str], word: str):
        self.sw, self.stop, self.at, self.before, self.word = sw, stop, at, before, word
        self.between = 0.0         # s of E-only moves the file makes before the next X/Y move

    def note_e_only(self, m: Move) -> None:
        """An E-only move (a retract, an unretract) after the stop: the head stands during it."""
        if m.e and m.f > 0:
            self.between += klipper_stop.e_move_s(self.sw.kp, abs(m.e), m.f / 60, self.sw.accel)

    def resolve(self, u) -> str:
        sw, stop = self.sw, self.stop
        lead = sw.edge_out(self.at, u)
        ks = klipper_stop.retime(sw.kp, stop.klipper, lead, sw.accel, self.between)
        sw.still_s += ks.still - stop.still
        sw.run_s += (ks.still - lead) - (stop.still - stop.start)
        near = abs(ks.still - stop.ms / 1000) * 1000 > NEAREST_MS
        sw.nearest += near - stop.nearest
        stop.klipper, stop.still, stop.start, stop.nearest = ks, ks.still, lead, near
        return "".join(b + "\n" for b in self.before) + f"G1 {self.word} F{ks.speed * 60:.3f}\n"


def _klipper_e(e_pos: float, d: float, abs_e: bool) -> tuple[str, float]:
    """(E word, filament laid) of a Klipper stop laying d mm from host E e_pos: Klipper keeps E
    in double, so no step rounding to aim at (stop_e_lines' care is Marlin's)."""
    if abs_e:
        txt = _fmt(e_pos + d)
        return f"E{txt}", float(txt) - e_pos
    txt = _fmt(d)
    return f"E{txt}", float(txt)


def _emit(ln: Line, per_move, st: GcodeState, sw: StopWriter) -> Iterator[str]:
    """G-code for one source line whose moves were split or got extra E, or a G2/G3 written as its
    chords (ArcLines): a G1 for each chord, or for each piece of a chord split at a stop. A
    chord's end is written with at least as many decimals as the arc's own word, so the last one
    ends on the arc's X, Y, Z and (M82) E as written; relative pieces (G91, M83) are each the
    rounded running total less what was written before, so they add up to the arc's words
    exactly (_Running). The arc's E goes in equal parts to its chords (Marlin's are of equal
    length: equal angles, equal Z steps), as the parser reads it. With a
    Klipper stop at the end of the line it also yields a _KlipperPending (rewrite() resolves it)."""
    w = ln.words or {}
    comment = ""
    i = ln.raw.find(";")
    if i >= 0:
        comment = ln.raw[i:].rstrip("\r\n")
    abs_xyz, abs_e = st.abs_xyz, st.abs_e
    first = True
    # host positions before the line: the first move's start
    m0 = per_move[0][0]
    cx, cy, cz = m0.x0, m0.y0, m0.z0
    e_host = m0.e_start            # host E at the start of the current move
    e_out = m0.e_start             # E as written (absolute mode)
    added = 0.0
    feed = None                    # a stop move changed the feed: the feed to give back
    nd, run = _DIGITS, None        # decimals of a whole move's end; an arc's running totals
    if m0.arc:
        nd = {k: max(5, v) for k, v in _word_decimals(ln.raw).items()}
        run = {k: _Running(v) for k, v in nd.items()}
        sw.arcs.add(len(per_move), _arc_deviation(ln, per_move))
    wx, wy = cx, cy                # Klipper: the position as written (a stop's place on the step grid)
    for m, acts in per_move:
        e_host = m.e_start
        acc = 0.0                  # filament written for this move so far
        for i, a in enumerate(acts):
            if a.dropped:
                sw.drop()
            if a.kind == "dwell" and sw.kp is not None:
                if a.ms == 0:
                    continue               # a weight-0 point: nothing to hold
                nxt = acts[i + 1] if i + 1 < len(acts) else None
                prev = acts[i - 1] if i and acts[i - 1].kind == "line" else None
                at = (wx, wy)          # as written: the stop's offset from a half step decides
                u_m = _unit_xy(m)
                if prev is not None:
                    u_in = u_m
                else:                  # the stop is at this move's start: the move before's end
                    p = sw.prev
                    u_in = p[2:] if p and abs(p[0] - at[0]) < 1e-6 and abs(p[1] - at[1]) < 1e-6 else None
                tail = sw.edge_in(at, u_in)
                later = nxt is None or nxt.kind != "line"
                if later:              # the next move is another line's: the mean until known
                    lead = klipper_stop.mean_edge_s(sw.kp, sw.accel)
                else:
                    lead = sw.edge_out(at, u_m)
                stop = sw.plan_klipper(a, tail, lead, later)
                if stop.kind == STOP_G4:
                    sw.count(stop)
                    yield f"G4 P{a.ms}\n"
                    continue
                word, laid = _klipper_e(e_host + acc + added, stop.klipper.e_mm, abs_e)
                sw.count(stop, laid)
                acc += laid
                feed = m.f
                if later:
                    yield _KlipperPending(sw, stop, at, [], word)
                else:
                    yield f"G1 {word} F{stop.klipper.speed * 60:.3f}\n"
                continue
            if a.kind == "dwell":
                spm = sw.spm_at(ln.line_no)
                nxt = acts[i + 1] if i + 1 < len(acts) else None
                prev = acts[i - 1] if i and acts[i - 1].kind == "line" else None
                at = (prev.x, prev.y) if prev else (m.x0, m.y0)    # a dwell carries no position
                guess = sw.cfg.stop_e_steps or _min_segment(sw.pm)
                k = _lead_steps(m, at, nxt, spm, guess, sw.pm)
                laid = 0 if sw.cfg.stop == STOP_G4 else guess      # (G4 lays none of the extra)
                stop = sw.plan(a, ln.line_no, k, *_pieces(m, at, nxt, spm, laid, k, sw.pm, a.extra)[::-1])
                if stop.kind == STOP_MOVE and stop.n != guess:   # k with the steps it lays
                    k = _lead_steps(m, at, nxt, spm, stop.n, sw.pm)
                    stop = sw.plan(a, ln.line_no, k, *_pieces(m, at, nxt, spm, stop.n, k, sw.pm, a.extra)[::-1])
                if stop.kind == "none":
                    continue
                if stop.kind == STOP_G4:
                    sw.count(stop)
                    yield f"G4 P{a.ms}\n"
                    continue
                before, word, laid = stop_e_lines(e_host + acc + added, stop.n, spm, abs_e)
                sw.count(stop, laid)
                acc += laid
                feed = m.f
                for b in before:
                    yield b + "\n"
                yield f"G1 {word} F{stop.feed(spm):.3f}\n"
                continue
            parts = ["G1"]
            if a.t >= 1.0:
                tx, ty, tz = m.x1, m.y1, m.z1
            else:
                tx, ty, tz = a.x, a.y, a.z
            if abs_xyz:
                if tx != cx or "X" in w or a.t < 1.0:
                    parts.append(f"X{_fmt(tx, 4 if a.t < 1 else nd['X'])}")
                    wx = float(parts[-1][1:])
                if ty != cy or "Y" in w or a.t < 1.0:
                    parts.append(f"Y{_fmt(ty, 4 if a.t < 1 else nd['Y'])}")
                    wy = float(parts[-1][1:])
                if tz != cz or (first and "Z" in w):
                    parts.append(f"Z{_fmt(tz, 4 if a.t < 1 else nd['Z'])}")
            else:
                for k, t, c in (("X", tx, cx), ("Y", ty, cy), ("Z", tz, cz)):
                    if t != c:
                        parts.append(f"{k}{_fmt(t - c, 4) if run is None else run[k].step(t - c)}")
                        if k == "X":
                            wx += float(parts[-1][1:])
                        elif k == "Y":
                            wy += float(parts[-1][1:])
            piece_e = a.e - sw.pay(a)     # E a stop laid comes off the extra this piece carries
            if sw.kp is not None and (a.extra > 0 or sw.spill > 0):
                # Klipper refuses a move over max_extrude_cross_section (extruder.py check_move):
                # extra above the limit goes on to the next extruding pieces (StopWriter.spill)
                if a.e > 0 and (tx, ty) != (cx, cy):
                    carried, sw.spill = sw.spill, 0.0
                    piece_e += carried
                    lim = sw.kp.piece_e_limit(math.dist((cx, cy, cz), (tx, ty, tz))) * 0.999
                    own = max(a.e - a.extra, 0.0)
                    if piece_e > max(lim, own):
                        sw.spill = piece_e - max(lim, own)
                        piece_e -= sw.spill
                        sw.spill_e_mm += max(0.0, sw.spill - carried)
                elif (tx, ty) != (cx, cy):
                    sw.lose_spill()            # a travel: the wall ended (as the planner's extra)
            acc += piece_e
            if abs_e:
                e_out = e_host + acc + added
                parts.append(f"E{_fmt(e_out, nd['E'])}")
            else:
                parts.append(f"E{_fmt(piece_e) if run is None else run['E'].step(piece_e)}")
            if first and "F" in w:
                parts.append(f"F{_fmt(w['F'], 3)}")
            elif feed is not None:
                parts.append(f"F{_fmt(m.f, 3)}")
            feed = None
            first = False
            cx, cy, cz = tx, ty, tz
            yield " ".join(parts) + "\n"
        extra_here = acc - m.e
        added += extra_here
        if sw.kp is not None:
            sw.note_move(m)
    if feed is not None:
        yield f"G1 F{_fmt(per_move[-1][0].f, 3)}\n"   # the stop's feed must not carry on
    if abs_e and abs(added) > 1e-9:
        # put the host's E back where the original line left it
        yield f"G92 E{_fmt(per_move[-1][0].e_start + per_move[-1][0].e, nd['E'])}\n"
    if comment:
        yield comment + "\n"


_DIGITS = dict.fromkeys("XYZE", 5)     # decimals of a move's end as _emit writes it


def _word_decimals(raw: str) -> dict[str, int]:
    """Decimals of the X, Y, Z and E words of a line as written (0 for a word it has not)."""
    code, _ = split_code(raw)
    out = dict.fromkeys("XYZE", 0)
    for letter, val in _WORD.findall(code.upper()):
        if letter in out:
            out[letter] = len(val.partition(".")[2])
    return out


class _Running:
    """Relative pieces of a total, written with nd decimals so that they add up to the rounded
    total exactly: each is the running total rounded, less what was written before."""

    def __init__(self, nd: int):
        self.nd, self.scale = nd, 10 ** nd
        self.total, self.wrote = 0.0, 0

    def step(self, piece: float) -> str:
        self.total += piece
        units = round(self.total * self.scale)
        d, self.wrote = units - self.wrote, units
        q, r = divmod(abs(d), self.scale)
        frac = f"{r:0{self.nd}d}".rstrip("0")
        return ("-" if d < 0 else "") + str(q) + (f".{frac}" if frac else "")


def _arc_deviation(ln: Line, per_move) -> float:
    """The farthest (mm) an arc's chords lie from it: r (1 - cos(sweep / 2n)) for its n chords."""
    m0, m1 = per_move[0][0], per_move[-1][0]
    _, _, r, _, sweep, _ = arc_geometry(m0.x0, m0.y0, m1.x1, m1.y1, ln.words or {},
                                        ln.cmd == "G2", f"line {ln.line_no}")
    return r * (1 - math.cos(abs(sweep) / (2 * len(per_move))))


@dataclass
class ArcCount:
    """G2/G3 lines an output writes as G1 chords (ArcLines): how many, their chords, and the
    farthest a chord lies from its arc, mm."""
    arcs: int = 0
    chords: int = 0
    deviation: float = 0.0

    def add(self, chords: int, deviation: float) -> None:
        self.arcs += 1
        self.chords += chords
        self.deviation = max(self.deviation, deviation)

    def text(self) -> str:
        return (f"{self.arcs} G2/G3 arc{'s' if self.arcs != 1 else ''} through map points written "
                f"as {self.chords} G1 chords, Marlin's own segments (at most "
                f"{_fmt(MAX_ARC_SEGMENT_MM, 2)} mm; within {self.deviation:.4f} mm of the arc)")


def rewrite_line(text: str, line_no: int, per_move, abs_xyz: bool, abs_e: bool, sw: StopWriter,
                 source: str) -> str:
    """_emit for a line given as its text (ending in its line end) and the moves (with their
    actions) that records gave: the stock file's byte path, and annotate's arcs (arc_text)."""
    code, _ = split_code(text)
    head = code.split(None, 1)
    words = parse_words(head[1] if len(head) > 1 else "", f"{source}:{line_no}")
    st = GcodeState()
    st.abs_xyz, st.abs_e = abs_xyz, abs_e
    return "".join(_emit(Line(line_no, text, command_of(head[0]), words, [], None), per_move, st, sw))


def arc_text(text: str, rows: np.ndarray, sw: StopWriter, source: str) -> str:
    """An arc's line (text) as its chords (its RECORD rows, ArcLines.found), for the annotated
    file: what the stock file writes for it where no point stops on it."""
    fl = int(rows[0]["flags"])
    per_move = [(m, [Action("line", m.x1, m.y1, m.z1, m.e)])
                for m in record_moves(rows, np.arange(len(rows)), 0, ())]
    return rewrite_line(text, int(rows[0]["line_no"]), per_move, bool(fl & movescan.ABS_XYZ),
                        bool(fl & movescan.ABS_E), sw, source)


def _header(bmap: mapformat.BulgeMap, settings: Settings, stops: StockStops) -> str:
    how = ""
    if stops.klipper:
        how = ", stops as E-only moves planned as Klipper plans them"
    elif stops.stop == STOP_MOVE:
        how = (f", stops as E-only moves at {_fmt(stops.e_steps, 3)} E steps/mm"
               " (or as M92 E in the file sets)"
               + (f", {stops.stop_e_steps} E steps each" if stops.stop_e_steps else ""))
    return (f"; bulgekit fallback: {len(bmap.layers)} layers, {bmap.point_count} points, "
            f"dwell {settings.dwell_ms} ms, extra E {settings.extra_e:.3f} mm, "
            f"tolerance {settings.tolerance:.3f} mm, mode {settings.mode}{how}\n"
            f"{PRINTER_HEADER}{stops.printer.describe()}\n")


PRINTER_HEADER = "; bulgekit printer: "   # the header's second line: the model the file is for


_COPY_BYTES = 1 << 20


def _copy(src, out, n: int | None) -> bytes:
    """n bytes (None: the rest) of src to out, a megabyte at a time: the stretches between two
    changed lines may be most of the file, and memory stays bounded. The last byte copied."""
    last = b""
    while n is None or n > 0:
        b = src.read(_COPY_BYTES if n is None else min(n, _COPY_BYTES))
        if not b:
            break
        out.write(b)
        last = b[-1:]
        if n is not None:
            n -= len(b)
    return last


def _rewrite_records(src, out, chunks, bmap: mapformat.BulgeMap, settings: Settings,
                     source: str, res: RewriteResult, stops: StockStops = StockStops(),
                     m92: list | None = None, planner: RefPlanner | None = None,
                     on_move=None) -> None:
    """rewrite() on the compiled scanner's chunks: the same output, but lines that stay as they
    are copied as bytes and only the moves that can change planned (Skipper; on_move sees
    those). Needs a file whose lines end in \n or \r\n and that is valid UTF-8 (rewrite_file
    checks)."""
    planner = planner if planner is not None else RefPlanner(bmap, settings)
    arcs = ArcLines(planner)
    sw = res.stock = StopWriter(stops, m92)
    out.write(_header(bmap, settings, stops).encode())
    pos = 0                                   # bytes of src copied so far

    def emit_changed(a, done, planned):
        nonlocal pos
        lines = np.ascontiguousarray(a["line_no"])      # in file order: a line's moves by bisection
        seen = set()
        for i, (m, acts) in sorted(planned.items()):     # in file order, as rewrite() goes
            ln_no = int(lines[i])
            if ln_no in seen:
                continue
            if _unchanged(m, acts) and ln_no not in arcs.lines:
                if acts[0].dropped:
                    sw.drop()
                continue
            seen.add(ln_no)
            idx = np.arange(*np.searchsorted(lines, [ln_no, ln_no + 1]))   # the line's moves (an arc's chords)
            r0 = a[idx[0]]
            start = int(r0["offset"])
            _copy(src, out, start - pos)
            raw = src.readline()                  # the line, through its \n
            pos = start + len(raw)
            per_move = []
            for i in idx:
                m = record_move(a[i], done + int(i), chunks.roles)
                per_move.append(planned.get(int(i)) or (m, [Action("line", m.x1, m.y1, m.z1, m.e)]))
            res.moves_split += not all(_unchanged(m, acts) for m, acts in per_move)
            fl = int(r0["flags"])
            out.write(rewrite_line(raw.decode("utf-8"), ln_no, per_move, bool(fl & movescan.ABS_XYZ),
                                   bool(fl & movescan.ABS_E), sw, source).encode())
    plan_records(planner, chunks, _hooks(arcs, on_move), on_chunk=emit_changed)
    last = _copy(src, out, None)
    if last and last != b"\n":
        out.write(b"\n")                         # as rewrite(): every line ends in a line end
    if sw.arcs.arcs:
        out.write(f"; bulgekit fallback: {sw.arcs.text()}\n".encode())
    res.lines_in = chunks.lines
    res.stops = planner.stops
    res.stats = planner.stats
    res.planner = planner
    res.unreached = unreached_message(planner, source)


def rewrite_file(src, dst, bmap: mapformat.BulgeMap, settings: Settings,
                 allow_unreached: bool = False, stops: StockStops = StockStops(),
                 on_plan=None) -> RewriteResult:
    """Rewrite src into dst.  Map points no move reaches are an error (the
    map is likely for another file) unless allow_unreached; then the message
    is in result.unreached.  dst is only written when the rewrite succeeds.
    on_plan(planner) is called with each planner made to run over the file (a second one when
    the compiled scanner leaves the file to the text path) and returns an on_move hook (see
    rewrite()), or None: build's statistics count on the rewrite's run (result.planner)."""
    from ..gcode import check_not_processed, open_checked
    res = RewriteResult()
    byte_path = movescan.available() and not stops.klipper    # Klipper's form: the text path

    def plain(data, source):                  # run with open_checked's checks, on the bytes
        nonlocal byte_path
        byte_path = byte_path and _plain_lines(data)
    kept = movescan.kept(src)                 # build's one scan: checked, and its lines known
    if kept is not None:
        byte_path = byte_path and kept.plain_lines
        lines = kept.text_lines()
    else:
        _, lines = open_checked(src, checks=(check_not_processed, plain))     # streamed, not held

    def new_planner():
        p = RefPlanner(bmap, settings)
        return p, (on_plan(p) if on_plan is not None else None)
    with output_part(dst) as tmp:
        done = False
        if byte_path:
            def fast(chunks):
                r = RewriteResult()
                with open(tmp, "wb") as f, open(src, "rb") as g:
                    m92 = None if stops.stop != STOP_MOVE else kept.m92 if kept else scan_m92(src)
                    _rewrite_records(g, f, chunks, bmap, settings, str(src), r, stops, m92,
                                     *new_planner())
                return r
            try:
                res = movescan.run(src, fast, fast=True)
                done = True
            except movescan.Unsupported:
                pass                          # a line the compiled scanner leaves to gcode/__init__.py
        if not done:
            with open(tmp, "w", encoding="utf-8", newline="") as f:
                buf = []
                for out in rewrite(lines, bmap, settings, str(src), res, stops, *new_planner()):
                    buf.append(out)
                    if len(buf) >= 4096:
                        f.write("".join(buf))
                        buf.clear()
                f.write("".join(buf))
        if res.unreached and not allow_unreached:
            raise UnreachedError(res.unreached)
    return res
