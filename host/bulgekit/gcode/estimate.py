"""Print time of any G-code, planned the way Marlin 2.1 plans it.

    from bulgekit.gcode.estimate import Machine, estimate_file
    r = estimate_file("part.gcode", Machine(accel=1000, travel_accel=1000))
    r.total_s, r.by_feature, r.blocks          # blocks: one row per planner block (numpy)
    estimate_file("part.gcode", blocks=False)  # the totals only (blocks None), in less memory

Every G0/G1 becomes a block as in Marlin's Planner::_buffer_steps (module/planner.cpp):

  length      XYZ distance; |dE| for a move of E alone. Moves under MIN_STEPS_PER_SEGMENT (6)
              steps on every axis are dropped and their distance goes to the next move.
  speed       F (mm/min) x M220 %, lowered until no axis exceeds its M203 maximum. In width mode
              (M723 on, our firmware) an extruding XY move gets v = L * r / dE instead (r: the
              extruder rate, docs/width-mode.md), clamped to [L, U].
  accel       M204 P for moves that extrude, T for travel, R for E alone; a move with X/Y/Z is
              lowered until no axis exceeds its M201 maximum: a <= amax_i * length / |d_i|.
  junction    junction deviation (M205 J): with u, u' the unit vectors of two moves (XYZE,
              normalised, for moves that extrude; XYZ / length for travel) and
              cos(theta) = -u'.u, sin(theta/2) = sqrt((1 - cos) / 2),
                  v_j^2 = a_j * JD * sin(theta/2) / (1 - sin(theta/2))
              where a_j is the accel lowered by the axis limits along (u - u')/|u - u'|; for
              moves under 1 mm turning by more than 45 degrees (JD_HANDLE_SMALL_SEGMENTS)
              v_j^2 <= length * a_j / theta (the speed on an arc through the corner; theta
              from Marlin's acos lookup table, as the firmware computes it). Then
              v_j <= both moves' speeds. Classic jerk (Machine.jerk, M205 X Y Z E) follows
              Marlin's HAS_CLASSIC_JERK branch instead.

The entry speeds then follow the planner's passes: backwards, a block may enter no faster than
it can brake to the next block's entry (v^2 <= v_next^2 + 2 a L); forwards, no faster than the
previous block could accelerate to. Marlin plans only what its block buffer holds: when a block
starts to run, the blocks behind it (up to BLOCK_BUFFER_SIZE - 2 of them, the buffer keeps one
slot free and the running block is locked) are all it knows, and the last of them must be able
to stop. `Machine.lookahead` is that buffer size (16, Marlin's default); None plans with the
whole file, as slicers' estimators do. Both passes are solved in closed form with prefix sums:
    backward: v_i^2 = min_k (m_k + S_k) - S_i     (k from i over the window; S: sum of 2 a L)
    forward:  v_i^2 = S_i + min_{k <= i} (b_k - S_k)
Each block is then a trapezoid (accelerate, cruise, brake).

A program that writes G-code can hand its moves over as numbers (MoveBlock items among the
lines: `bulgekit litho` does), so they are not parsed again; the blocks are the same. The blocks
are planned as the file is read (_Planner): each run of blocks between two stops once its end is
known, a long one a chunk of blocks at a time, each chunk with the braking distance of its fastest
block on both sides (what decides a block's speeds lies within it): the same speeds in a fraction
of the memory. blocks=False (what `bulgekit estimate` uses) keeps no row per block, only the
totals. The per-block passes (tiny moves, limits, junctions, the planner's passes) run in C when
_plan.c is built (host/setup.py), with the same numbers as the numpy code here
(host/tests/gcode/test_plan_c.py). `Machine(min_segment_steps=0)` plans every move, as Klipper and
RepRapFirmware do.

A file (estimate_file) is read by the compiled scanner when it is built (movescan, its events
mode): the plain moves come as move records and are taken as arrays, operation for operation as
the text parser below takes them, and every other line goes to the text parser in order; the
blocks are the same to the bit (host/tests/gcode/test_estimate_scan.py).

A move of E alone (a retraction, or a stop in a stock file, see bulge/fallback.py) runs n whole steps
(n = lround(|dE| x M92 E)) at the block's rate r = ceil(n x speed / |dE|) steps/s. Below Marlin's
MINIMAL_STEP_RATE (120 steps/s) the stepper starts and ends the block at 120 steps/s: it takes
1/120 + (n - 1)/r s (measured in simulated stock Marlin 2.1.2.7, issue 25: the head stands still
1/120 + (n - 1)/r + 1/120 s, the last 1/120 being the following block's first step, which its
trapezoid holds). It is queued like any move: the planner does not empty, and the moves on either
side slow to its speed (a junction with a move of E alone is limited by both moves' speeds).

The planner empties (the machine stops) at G4, G28, M400 and the heating waits M109/M190: the
moves before brake to a stop and the ones after start from rest (the drain's cost), the dwell
itself is added; the time the host takes to fill the queue again is not modelled. Not
modelled either: Marlin's slow-down when the buffer runs low (a host that keeps it full: SD
card, or a fast enough serial line), LIN_ADVANCE, S-curve acceleration. G2/G3 are cut into Marlin
2.1's own segments (gcode.arc_segments: at most 1 mm, at least 72 to a turn).
"""
from __future__ import annotations

import bisect
import contextlib
import functools
import math
import operator
import os
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import BulgekitError
from ..machine import DEFAULT as _PM, PrinterModel
from . import (GcodeError, arc_geometry, arc_point, check_file_ends, command_of, parse_words,
               refuse_cut_off, split_code)

PLAN_VERSION = 1       # the compiled planner's VERSION this code calls (_plan.c's module init)


def _compiled_planner():
    """The compiled planner passes (_plan.c), or None: not built, or built from an older _plan.c
    (gcode.compiled_helper); numpy then does the work, to the same bits."""
    from . import compiled_helper
    return compiled_helper("_plan", PLAN_VERSION, "planner (_plan)", "estimates run slower")


_plan = _compiled_planner()

AXES = "XYZE"


class EstimateError(BulgekitError):
    """A G-code line the estimator cannot plan (the message names file and line)."""


def _axes(x, y, z, e):
    return {"X": float(x), "Y": float(y), "Z": float(z), "E": float(e)}


@dataclass
class Machine:
    """Planner settings, as the estimator plans with them: a printer model's (from_model); the
    defaults are the default model's (machine.DEFAULT: Marlin 2.1.2.x's Configuration.h, E 93)."""
    accel: float = _PM.accel                  # M204 P, printing moves, mm/s^2
    travel_accel: float = _PM.travel_accel    # M204 T
    retract_accel: float = _PM.retract_accel  # M204 R, moves of E alone
    max_accel: dict = field(default_factory=_PM.max_accel.as_dict)        # M201
    max_feedrate: dict = field(default_factory=_PM.max_feedrate.as_dict)  # M203, mm/s
    steps_per_mm: dict = field(default_factory=_PM.steps_per_mm.as_dict)  # M92
    junction_deviation: float = _PM.junction_deviation  # M205 J, mm
    jerk: dict | None = None          # classic jerk (M205 X Y Z E, mm/s) instead of JD
    jd_small_segments: bool = True    # JD_HANDLE_SMALL_SEGMENTS
    min_planner_speed: float = 0.05   # MINIMUM_PLANNER_SPEED, mm/s
    min_segment_steps: int = _PM.min_segment_steps  # MIN_STEPS_PER_SEGMENT
    lookahead: int | None = _PM.lookahead  # BLOCK_BUFFER_SIZE; None: the whole file
    min_step_rate: float = _PM.min_step_rate  # MINIMAL_STEP_RATE, steps/s (0: none, Klipper)
    honour_file_limits: bool = False  # apply the file's M201/M203/M204/M205

    @classmethod
    def from_model(cls, pm: PrinterModel, **kw) -> "Machine":
        """The estimator's settings for a printer model (kw: any field changed). A Klipper model
        plans with its whole look-ahead, no step-rate floor and no segment minimum, and its
        corners at the junction deviation its square corner velocity stands for."""
        m = cls(accel=pm.accel, travel_accel=pm.travel_accel, retract_accel=pm.retract_accel,
                max_accel=pm.max_accel.as_dict(), max_feedrate=pm.max_feedrate.as_dict(),
                steps_per_mm=pm.steps_per_mm.as_dict(),
                junction_deviation=pm.junction_deviation if pm.jerk is None else _PM.junction_deviation,
                jerk=None if pm.jerk is None else pm.jerk.as_dict(),
                min_segment_steps=pm.min_segment_steps, lookahead=pm.lookahead or None,
                min_step_rate=pm.min_step_rate)
        return replace(m, **kw) if kw else m


@dataclass
class Result:
    total_s: float
    moves_s: float
    dwell_s: float
    by_feature: dict
    features: list
    blocks: np.ndarray | None     # structured: see BLOCK_DTYPE (None: not asked for, blocks=False)
    lines: int
    n_blocks: int = 0             # planner blocks (moves not dropped)
    filament: float = 0.0         # deposited_filament(): filament laid by extruding blocks, mm

    def summary(self) -> str:
        h, rem = divmod(self.total_s, 3600)
        return f"{int(h)}h {int(rem // 60):02d}m {rem % 60:04.1f}s"


@dataclass
class MoveBlock:
    """Moves a program already holds as numbers, given to estimate_lines in place of their text
    (which it then need not parse): G1 to absolute X, Y (mm) with relative E (mm) or W words,
    F (mm/min) per move, all as the text has them (rounded alike). Needs G90 and M83 in force."""
    x: np.ndarray
    y: np.ndarray
    e: np.ndarray
    f: np.ndarray
    w: np.ndarray | None = None

    def __len__(self):
        return len(self.x)


BLOCK_DTYPE = [("line", "i8"), ("feature", "i4"), ("layer", "i4"), ("dx", "f8"), ("dy", "f8"), ("dz", "f8"),
               ("de", "f8"), ("length", "f8"), ("nominal_speed", "f8"), ("accel", "f8"),
               ("entry_speed", "f8"), ("exit_speed", "f8"), ("cruise_speed", "f8"),
               ("t_accel", "f8"), ("t_cruise", "f8"), ("t_decel", "f8")]


class _Parser:
    """G-code to raw moves (deltas, feed, accel class), in Marlin's modal state."""

    def __init__(self, m: Machine, source: str):
        self.m, self.src = m, source
        self.pos = [0.0, 0.0, 0.0, 0.0]
        self.rel = [False, False, False, False]
        self.f = 1500.0 / 60                    # Marlin's power-on feedrate, mm/s
        self.F = 1500.0                         # the same as written (mm/min): the scanner's
        self.pct = 100.0
        self.feature, self.features, self.fidx = "", [""], {"": 0}
        self.layer = -1
        # planner settings that the file may change (copies)
        self.accel, self.travel_accel, self.retract_accel = m.accel, m.travel_accel, m.retract_accel
        self.max_accel = dict(m.max_accel)
        self.max_fr = dict(m.max_feedrate)
        self.jd = m.junction_deviation
        self.jerk = dict(m.jerk) if m.jerk is not None else None
        self.width = None                       # width mode: dict(r=, D=, H=, L=, U=) when on
        self.w_state = dict(q=None, r=None, D=1.75, H=0.0, L=5.0, U=150.0)
        self.rows = []                          # (line, feat, layer, dx, dy, dz, de, v, accel, brk, jd, jerk)
        self.parts = []                         # rows turned into column arrays, and MoveBlocks' columns
        self.brk = True                         # the next block starts from rest
        self.pending = [0.0, 0.0, 0.0, 0.0]     # distance of dropped tiny moves
        self.dwell = 0.0
        self.dwell_by_feature: dict[str, float] = {}
        self.spm = dict(m.steps_per_mm)         # M92 in the file changes it
        self.e_at = 0                           # the planner's E position, whole steps
        self.g92_at = None                      # _take: e_at as a G92 between two ranges set it
        self.g92_lines = []                     # _take: G92s after the last range gathered

    def err(self, n, msg):
        raise EstimateError(f"{self.src}:{n}: {msg}")

    def words(self, n, rest, bare=False):
        """The words after a command, read as every reader of the package reads them
        (gcode.parse_words, which refuses a letter without a value in a move or a G92, as
        gcode.parse_lines does; bare: it is None, as in G28 X)."""
        try:
            return parse_words(rest, f"{self.src}:{n}", bare)
        except GcodeError as e:
            raise EstimateError(str(e)) from None

    def line(self, n: int, raw: str):
        if ";" in raw:
            comment = raw.partition(";")[2]
            c = comment.strip()
            if c.startswith("TYPE:"):
                name = c[5:].strip()
                if name not in self.fidx:
                    self.fidx[name] = len(self.features)
                    self.features.append(name)
                self.feature = name
            elif c.startswith("LAYER:"):
                try:
                    self.layer = int(c[6:])
                except ValueError:
                    pass
            elif c == "LAYER_CHANGE":
                self.layer += 1
        # the command and its words as gcode.parse_lines reads them: no comment, checksum or
        # line number; G01 is G1
        code, _ = split_code(raw)
        if not code:
            return
        head = code.split(None, 1)
        cmd = command_of(head[0])
        rest = head[1] if len(head) > 1 else ""
        if cmd in ("G0", "G1"):
            self.move(n, self.words(n, rest))
        elif cmd in ("G2", "G3"):
            self.arc(n, cmd == "G2", self.words(n, rest))
        elif cmd == "G92":
            w = self.words(n, rest)
            if not any(a in w for a in AXES):
                w = {a: 0.0 for a in AXES}
            for i, a in enumerate(AXES):
                if a in w:
                    self.pos[i] = w[a] or 0.0
            self.e_at = _lround(self.pos[3] * self.spm["E"])
        elif cmd == "G90":
            self.rel = [False] * 4
        elif cmd == "G91":
            self.rel = [True] * 4
        elif cmd == "M82":
            self.rel[3] = False
        elif cmd == "M83":
            self.rel[3] = True
        elif cmd == "G4":
            w = self.words(n, rest, bare=True)
            t = (w.get("P") or 0.0) / 1000 + (w.get("S") or 0.0)
            self.dwell += t
            self.dwell_by_feature[self.feature] = self.dwell_by_feature.get(self.feature, 0.0) + t
            self.brk = True
        elif cmd == "G28":
            w = self.words(n, rest, bare=True)
            for i, a in enumerate("XYZ"):
                if not any(k in w for k in "XYZ") or a in w:
                    self.pos[i] = 0.0
            self.brk = True
        elif cmd == "M92":
            # steps/mm: the E-only rule and the tiny-move rule count whole steps
            w = self.words(n, rest, bare=True)
            for a in AXES:
                if w.get(a) and w[a] > 0:
                    self.spm[a] = w[a]
            self.e_at = _lround(self.pos[3] * self.spm["E"])   # Marlin re-sets its position
        elif cmd in ("M400", "M109", "M190", "M116", "M0", "M1"):
            self.brk = True
        elif cmd == "M220":
            w = self.words(n, rest, bare=True)
            if w.get("S") is not None:
                if w["S"] <= 0:
                    self.err(n, f"M220 S{w['S']:g}: feed rate percentage must be > 0")
                self.pct = w["S"]
        elif cmd == "M723":
            self.m723(n, self.words(n, rest, bare=True))
        elif cmd in ("M201", "M203", "M204", "M205") and self.m.honour_file_limits:
            self.limits(cmd, self.words(n, rest, bare=True))

    def limits(self, cmd, w):
        if cmd == "M201":
            for a in AXES:
                if w.get(a):
                    self.max_accel[a] = w[a]
        elif cmd == "M203":
            for a in AXES:
                if w.get(a):
                    self.max_fr[a] = w[a]
        elif cmd == "M204":
            if w.get("S"):
                self.accel = self.travel_accel = w["S"]
            if w.get("P"):
                self.accel = w["P"]
            if w.get("T"):
                self.travel_accel = w["T"]
            if w.get("R"):
                self.retract_accel = w["R"]
        elif cmd == "M205":
            if w.get("J"):
                self.jd = w["J"]
            if self.jerk is not None:
                for a in AXES:
                    if w.get(a) is not None:
                        self.jerk[a] = w[a]

    def m723(self, n, w):
        s = self.w_state
        for k in ("D", "H", "L", "U"):
            if w.get(k) is not None:
                s[k] = w[k]
        if w.get("Q") is not None:
            s["q"], s["r"] = w["Q"], None
        if w.get("R") is not None:
            s["r"], s["q"] = w["R"], None
        if w.get("S") is not None:
            self.width = bool(w["S"])
        if self.width and s["q"] is None and s["r"] is None:
            self.err(n, "M723 S1 without a rate (Q or R)")

    def _rate(self):
        s = self.w_state
        r = s["r"] if s["r"] is not None else s["q"] / (math.pi * s["D"] ** 2 / 4)
        return r * self.pct / 100

    def move(self, n, w, f_override=None):
        if w.get("F"):
            self.f = w["F"] / 60
            self.F = w["F"]
        target = list(self.pos)
        for i, a in enumerate(AXES):
            v = w.get(a)
            if v is not None:
                target[i] = self.pos[i] + v if self.rel[i] else v
        d = [target[i] - self.pos[i] for i in range(4)]
        self.pos = target
        if "W" in w and w["W"] is not None:                # width mode: filament from the width
            s = self.w_state
            L = math.hypot(d[0], d[1])
            d[3] = w["W"] * s["H"] * L / (math.pi * s["D"] ** 2 / 4)
        self.emit(n, d, f_override)

    def emit(self, n, d, f_override=None):
        m = self.m
        d = [d[i] + self.pending[i] for i in range(4)]
        steps = [abs(d[i]) * self.spm[a] for i, a in enumerate(AXES)]
        xyz = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        e_to = _lround(self.pos[3] * self.spm["E"])
        if xyz == 0:
            # E alone: whole steps from the planner's position (the fraction carried matters)
            steps[3] = abs(e_to - self.e_at)
        if max(steps) < m.min_segment_steps or max(steps) == 0:   # Marlin drops it; the distance carries on
            self.pending = d
            return
        self.pending = [0.0, 0.0, 0.0, 0.0]
        n_e = steps[3] if xyz == 0 else 0
        self.e_at = e_to
        v = f_override if f_override is not None else self.f * self.pct / 100
        if self.width and d[3] > 0 and (d[0] or d[1]):
            s = self.w_state
            # v = L * r / dE, r scaled by M220; the limits apply to the scaled speed
            v = min(max(math.hypot(d[0], d[1]) * self._rate() / d[3], s["L"]), s["U"])
        if xyz > 0:
            accel = self.accel if d[3] != 0 else self.travel_accel
        else:
            accel = self.retract_accel
        self.rows.append((n, self.fidx[self.feature], self.layer, d[0], d[1], d[2], d[3], v, accel,
                          self.brk, self.jd, tuple(self.jerk[a] for a in AXES) if self.jerk else None,
                          tuple(self.max_accel[a] for a in AXES), tuple(self.max_fr[a] for a in AXES),
                          n_e, self.spm["E"]))
        self.brk = False
        if len(self.rows) >= CHUNK:            # planned part by part (_Planner)
            self.flush()

    def flush(self):
        if self.rows:
            self.parts.append(_columns(self.rows))
            self.rows = []

    def block(self, n, mb: MoveBlock):
        """A MoveBlock: the same blocks as its lines would give, computed on whole arrays."""
        k = len(mb)
        if k == 0:
            return
        m, s = self.m, self.w_state
        x = np.concatenate([[self.pos[0]], mb.x])
        y = np.concatenate([[self.pos[1]], mb.y])
        dx, dy = np.diff(x), np.diff(y)
        L = np.hypot(dx, dy)
        de = np.asarray(mb.e, float)
        if mb.w is not None:
            de = np.where(mb.w > 0, mb.w * s["H"] * L / (math.pi * s["D"] ** 2 / 4), de)
        spm = self.spm
        steps = np.maximum(np.maximum(np.abs(dx) * spm["X"], np.abs(dy) * spm["Y"]), np.abs(de) * spm["E"])
        if (self.rel[0] or self.rel[1] or not self.rel[3] or any(self.pending)
                or np.any(steps < max(m.min_segment_steps, 1e-12)) or np.any(L == 0)):
            for i in range(k):                          # as the text: move by move
                w = {"X": float(mb.x[i]), "Y": float(mb.y[i]), "F": float(mb.f[i])}
                if mb.w is not None and mb.w[i] > 0:
                    w["W"] = float(mb.w[i])
                elif mb.e[i] != 0:
                    w["E"] = float(mb.e[i])
                self.move(n + i, w)
            return
        self.flush()
        v = np.asarray(mb.f, float) / 60 * self.pct / 100
        if self.width:
            ext = de > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                vw = np.clip(L * self._rate() / de, s["L"], s["U"])
            v = np.where(ext, vw, v)
        brk = np.zeros(k, bool)
        brk[0] = self.brk
        # what is the same for every move is held once (_plan_parts broadcasts it), not per move:
        # a large file's parts are all held until planned
        rows = lambda vals: np.array(vals, float)
        self.parts.append({
            "line": n + np.arange(k), "feature": self.fidx[self.feature], "layer": self.layer,
            "dx": dx, "dy": dy, "dz": 0.0, "de": de, "v": v,
            "accel": np.where(de != 0, self.accel, self.travel_accel), "brk": brk, "jd": self.jd,
            "jerk": None if self.jerk is None else rows([self.jerk[a] for a in AXES]),
            "amax": rows([self.max_accel[a] for a in AXES]),
            "vmax": rows([self.max_fr[a] for a in AXES]),
            "n_e": 0.0, "spm_e": spm["E"]})
        self.brk = False
        self.f = float(mb.f[-1]) / 60
        self.F = float(mb.f[-1])
        e_end = float(np.cumsum(np.concatenate([[self.pos[3]], de]))[-1])     # summed as the text's moves
        self.pos = [float(mb.x[-1]), float(mb.y[-1]), self.pos[2], e_end]
        self.e_at = _lround(self.pos[3] * spm["E"])

    def arc(self, n, cw, w):
        x0, y0 = self.pos[0], self.pos[1]
        if w.get("F"):
            self.f = w["F"] / 60
            self.F = w["F"]
        x1 = (x0 + w["X"] if self.rel[0] else w["X"]) if w.get("X") is not None else x0
        y1 = (y0 + w["Y"] if self.rel[1] else w["Y"]) if w.get("Y") is not None else y0
        z1 = (self.pos[2] + w["Z"] if self.rel[2] else w["Z"]) if w.get("Z") is not None else self.pos[2]
        e1 = (self.pos[3] + w["E"] if self.rel[3] else w["E"]) if w.get("E") is not None else self.pos[3]
        try:                                    # Marlin's segments, as every reader cuts them
            cx, cy, r, a0, sweep, segs = arc_geometry(x0, y0, x1, y1, w, cw, f"{self.src}:{n}")
        except GcodeError as e:
            raise EstimateError(str(e)) from None
        z0, e0 = self.pos[2], self.pos[3]
        px, py = x0, y0
        for k in range(1, segs + 1):
            if k == segs:
                nx, ny = x1, y1
            else:
                nx, ny = arc_point(cx, cy, r, a0, sweep, k / segs)
            self.emit(n, [nx - px, ny - py, (z1 - z0) / segs, (e1 - e0) / segs])
            px, py = nx, ny
        self.pos = [x1, y1, z1, e1]
        self.e_at = _lround(e1 * self.spm["E"])


def _norm(*c):
    """Each row's Euclidean norm, the columns summed in order (what np.linalg.norm(axis=1) does,
    to the bit, without its slow reduction along short rows)."""
    s = c[0] * c[0]
    for x in c[1:]:
        s = s + x * x
    return np.sqrt(s)


def _row_min(*c):
    """Each row's smallest value (the columns' minimum)."""
    out = c[0]
    for x in c[1:]:
        out = np.minimum(out, x)
    return out


def _junctions(d, L, v, accel, jd, jerk, amax, m: Machine):
    """Max entry speed squared of every block from its junction with the one before (d: the
    blocks' dx, dy, dz, de as rows; L, v, accel: length, nominal speed, acceleration; amax: M201
    per axis, rows). Column by column: each operation is the one a row of numbers gets."""
    n = len(v)
    out = np.zeros(n)
    if n < 2:
        return out
    if jerk is not None:
        out[1:] = _classic_jerk(d, L, v, jerk)
        return out
    col = [d[:, i] for i in range(4)]
    extr = col[3] != 0
    nd = _norm(*col)
    unit = [np.where(extr, c / nd, c / L) for c in col]
    u, p = [c[1:] for c in unit], [c[:-1] for c in unit]
    cos = -(u[0] * p[0] + u[1] * p[1] + u[2] * p[2] + u[3] * p[3])
    j = [a - b for a, b in zip(u, p)]
    jn = _norm(*j)
    nz = jn > 0
    j = [np.divide(c, jn, out=np.zeros_like(c), where=nz) for c in j]
    aj = accel[1:]
    with np.errstate(divide="ignore"):
        lim = _row_min(*(np.where(np.abs(c) > 0, amax[1:, i] / np.abs(c), np.inf) for i, c in enumerate(j)))
    aj = np.minimum(aj, lim)
    c = np.maximum(cos, -0.999999)
    with np.errstate(invalid="ignore"):                   # cos a hair over 1: replaced below
        s2 = np.sqrt(0.5 * (1 - c))
    vj2 = aj * jd[1:] * s2 / (1 - s2)
    if m.jd_small_segments:
        small = (L[1:] < 1) & (c < -0.7071067812)
        if small.any():
            k = np.flatnonzero(small)
            vj2[k] = np.minimum(vj2[k], L[1:][k] * aj[k] / _jd_lut_acos_neg(c[k]))
    vj2 = np.where(cos > 0.999999, m.min_planner_speed ** 2, vj2)
    out[1:] = np.minimum(vj2, np.minimum(v[1:], v[:-1]) ** 2)
    return out


# Marlin's JD_USE_LOOKUP_TABLE (default with JD_HANDLE_SMALL_SEGMENTS): acos by 16 lines
_JD_K = np.array([-1.03145837, -1.30760646, -1.75205851, -2.41705704, -3.37769222, -4.74888992,
                  -6.69649887, -9.45661736, -13.3640480, -18.8928222, -26.7136841, -37.7754593,
                  -53.4201813, -75.5458374, -106.836761, -218.532821])
_JD_B = np.array([1.57079637, 1.70887053, 2.04220939, 2.62408352, 3.52467871, 4.85302639,
                  6.77020454, 9.50875854, 13.4009285, 18.9188995, 26.7321243, 37.7885055,
                  53.4293975, 75.5523529, 106.841369, 218.534011])


def _jd_lut_acos_neg(cos):
    """acos(-cos) as Marlin's table gives it: t = |cos| picks a line by the leading zeros of
    (1 - t) * 2^15 (16-bit), theta = k t + b, mirrored for cos > 0."""
    neg = np.where(cos < 0, -1.0, 1.0)
    t = neg * cos
    x = np.clip(np.floor((1.0 - t) * 32768.0), 0, 65535).astype(np.int64)
    bits = np.zeros_like(x)
    nz = x > 0
    bits[nz] = np.floor(np.log2(x[nz])).astype(np.int64) + 1
    idx = np.where(t < 3e-8, 0, np.clip(16 - bits - 1, 0, 15))
    theta = t * _JD_K[idx] + _JD_B[idx]
    return np.where(neg > 0, math.pi - theta, theta)


def _classic_jerk(d, L, v, jerk):
    """Marlin's HAS_CLASSIC_JERK junction (from Prusa's MK firmware), block by block."""
    speed = d * (v / L)[:, None]                             # per-axis speed at cruise
    n = len(v)
    out = np.zeros(n - 1)
    safe_prev = None
    for i in range(n):
        jk = jerk[i]
        safe = jerk_safe_speed(v[i], speed[i], jk)
        if i > 0:
            vj = jerk_junction(v[i - 1], speed[i - 1], safe_prev, v[i], speed[i], safe, jk)
            out[i - 1] = vj * vj
        safe_prev = safe
    return out


def jerk_safe_speed(nominal: float, speeds, jerks) -> float:
    """Classic jerk (planner.cpp's safe_speed): the speed from which a block of this nominal
    speed and these per-axis speeds (X, Y, Z, E) may start or stop at once."""
    safe, limited = nominal, False
    for cs, mj in zip(speeds, jerks):
        cs = abs(cs)
        if cs > mj:
            if limited:
                if cs * safe > nominal * mj:
                    safe = nominal * mj / cs
            else:
                safe *= mj / cs
                limited = True
    return safe


def jerk_junction(v_prev: float, prev, safe_prev: float, v_cur: float, cur, safe_cur: float,
                  jerks) -> float:
    """Classic jerk ("Classic Jerk Limiting" in planner.cpp): the speed at the junction from a
    block of nominal speed v_prev and per-axis speeds prev to one of v_cur and cur, each axis's
    change of speed within its jerk; the blocks' safe speeds (jerk_safe_speed) where both allow
    more."""
    vf, lim = 1.0, False
    if v_cur < v_prev:
        vj, ssf = v_cur, v_cur / v_prev
    else:
        vj, ssf = v_prev, 1.0
    for a in range(4):
        vx, ve = prev[a] * ssf, cur[a]
        if lim:
            vx *= vf
            ve *= vf
        if vx > ve:
            j = (vx - ve) if (ve > 0 or vx < 0) else max(vx, -ve)
        else:
            j = (ve - vx) if (ve < 0 or vx > 0) else max(-vx, ve)
        if j > jerks[a]:
            vf *= jerks[a] / j
            lim = True
    if lim:
        vj *= vf
    if safe_prev > vj * 0.99 and safe_cur > vj * 0.99:
        vj = safe_cur
    return vj


def _plan_segment_np(a, L, vn, maxentry2, m: Machine):
    """Entry, exit and cruise speeds and the trapezoid's times (accelerate, cruise, brake) of
    blocks that run without a stop in between: a, L, vn: their acceleration, length and nominal
    speed; maxentry2: the square of the speed each may enter at (its junction)."""
    n = len(a)
    vmin2 = m.min_planner_speed ** 2
    M = np.append(np.minimum(maxentry2, vn ** 2), vmin2)
    M[0] = vmin2                                            # starts from rest (a stop: MINIMUM_PLANNER_SPEED)
    S = np.concatenate([[0.0], np.cumsum(2 * a * L)])       # S[k] = sum_{m<k} 2 a_m L_m
    arr = M + S
    if m.lookahead is None or m.lookahead - 2 >= n:
        back = np.minimum.accumulate(arr[::-1])[::-1][:-1]
    else:
        W = max(1, m.lookahead - 2)
        from numpy.lib.stride_tricks import sliding_window_view
        pad = np.concatenate([arr, np.full(W - 1, np.inf)])
        back = sliding_window_view(pad, W).min(axis=1)[:n]
        end = np.minimum(np.arange(n) + W, n)
        back = np.minimum(back, vmin2 + S[end])
    back = back - S[:-1]
    fwd = S[:-1] + np.minimum.accumulate(back - S[:-1])
    entry2 = np.maximum(np.minimum(back, fwd), 0.0)
    exit2 = np.append(entry2[1:], vmin2)
    v0, v1 = np.sqrt(entry2), np.sqrt(exit2)
    # peak speed of a triangle: accelerate from v0, brake to v1 within L
    vpeak = np.sqrt(np.maximum((2 * a * L + entry2 + exit2) / 2, 0.0))
    vc = np.minimum(vn, vpeak)
    vc = np.maximum(vc, np.maximum(v0, v1))
    ta = (vc - v0) / a
    td = (vc - v1) / a
    d_c = np.maximum(L - (vc ** 2 - entry2) / (2 * a) - (vc ** 2 - exit2) / (2 * a), 0.0)
    tc = d_c / vc
    return v0, v1, vc, ta, tc, td


def _plan_window(a, L, vn, me2, m: Machine, lo, hi, k0, k1, t, sp) -> None:
    """_plan_segment_np on blocks lo..hi-1 of a run (a, L, vn, me2: its columns), the results of
    blocks k0..k1-1 written there in t (time) and sp (_SPEEDS' arrays, or Nones): by the compiled
    planner (_plan.c) when it is built, which gives the same numbers (host/tests/gcode/test_plan_c.py)."""
    n = hi - lo
    W = -1 if m.lookahead is None or m.lookahead - 2 >= n else max(1, m.lookahead - 2)
    if _plan is not None and W <= 64:       # a longer window: numpy's sliding minimum is quicker
        _plan.segment(a, L, vn, me2, m.min_planner_speed ** 2, W, lo, hi, k0, k1, t, *sp)
        return
    res = _plan_segment_np(a[lo:hi], L[lo:hi], vn[lo:hi], me2[lo:hi], m)
    w = slice(k0 - lo, k1 - lo)
    t[k0:k1] = (res[3] + res[4] + res[5])[w]
    for o, r in zip(sp, res):
        if o is not None:
            o[k0:k1] = r[w]


def _columns(rows) -> dict:
    """The parser's rows (tuples) as column arrays."""
    cols = list(zip(*rows))
    out = {name: np.array(cols[k]) for k, name in enumerate(("line", "feature", "layer", "dx", "dy", "dz", "de"))}
    out.update(v=np.array(cols[7], float), accel=np.array(cols[8], float), brk=np.array(cols[9], bool),
               jd=np.array(cols[10], float), amax=np.array(cols[12], float), vmax=np.array(cols[13], float),
               jerk=None if cols[11][0] is None else np.array(cols[11], float),
               n_e=np.array(cols[14], float), spm_e=np.array(cols[15], float))
    return out


def _full(q: dict, k: int) -> dict:
    """A part whose constants are held once (a MoveBlock's: a number, or one row of axis
    limits) with them repeated for each of its k moves, as the planner's passes take them."""
    out = dict(q)
    for name in ("dz", "jd", "n_e", "spm_e", "accel", "v", "feature", "layer"):
        if np.ndim(q[name]) == 0:
            out[name] = np.full(k, q[name])
    for name in ("amax", "vmax", "jerk"):
        if q[name] is not None and np.ndim(q[name]) == 1:
            out[name] = np.ascontiguousarray(np.broadcast_to(np.asarray(q[name], float), (k, len(q[name]))))
    return out


CHUNK = 1 << 16          # blocks computed at once (a large file's temporaries stay small)
_SPEEDS = ("entry_speed", "exit_speed", "cruise_speed", "t_accel", "t_cruise", "t_decel")


class _Planner:
    """The parser's parts (column arrays) -> planned blocks, part by part as the file is read.
    Per part: each block's length, speed and acceleration under the axis limits and its junction
    with the block before; the blocks are gathered into runs (no stop in between), and each run is
    planned (_plan_run) once its end is known. What is kept: each block's time, feature and (of
    extruding ones) filament, for the totals; with blocks=True also every block's row
    (BLOCK_DTYPE), for callers that ask for them."""

    def __init__(self, m: Machine, source: str, blocks: bool = True):
        self.m, self.source, self.keep = m, source, blocks
        self.prev = None                 # the last block so far: its junction with the next one
        self.prev_c = None               # the same for _plan.blocks: its unit vector, speed, 1
        self.run = _Run()
        self.e_only = []                 # the run's moves of E alone: (index in the run, n_e, spm_e, vn)
        self.t, self.de = [], []
        self.feature = []                # the run's blocks' features
        self.by_feature = {}             # time per feature index, summed block by block in order
        self.parts, self.speeds = [], []      # blocks=True: BLOCK_DTYPE rows; planned speeds per run
        self.n = 0
        self.bad = None                  # the line of the first move with feed rate 0

    def feed(self, p: "_Parser") -> None:
        """Takes the parser's parts so far."""
        parts, p.parts = p.parts, []
        for q in parts:
            self.add(q)

    def add(self, q: dict) -> None:
        k = len(q["v"])
        if not k:
            return
        q = _full(q, k)
        self.n += k
        if self.bad is not None:                # nothing more is planned; the parse goes on
            return
        f8 = np.float64
        if _plan is not None and q["jerk"] is None and self.prev is None:
            self._add_c(q, k)
            return
        d = np.column_stack([np.asarray(q[c], f8) for c in ("dx", "dy", "dz", "de")])
        v, accel = np.asarray(q["v"], f8), np.asarray(q["accel"], f8)
        xyz = _norm(d[:, 0], d[:, 1], d[:, 2])
        L = np.where(xyz > 0, xyz, np.abs(d[:, 3]))
        # per-axis limits: speed so no axis exceeds its M203, accel so none exceeds its M201
        vmax, amax = q["vmax"], q["amax"]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = [np.abs(d[:, i]) / L for i in range(4)]
            vlim = _row_min(*(np.where(r > 0, vmax[:, i] / r, np.inf) for i, r in enumerate(ratio)))
            alim = _row_min(*(np.where(r > 0, amax[:, i] / r, np.inf) for i, r in enumerate(ratio)))
        vn = np.minimum(v, vlim)
        acc = np.where(xyz > 0, np.minimum(accel, alim), accel)
        del ratio, vlim, alim
        if np.any(vn <= 0):
            self.bad = int(np.asarray(q["line"])[int(np.argmax(vn <= 0))])
            return
        # junctions: each block's with the one before (the previous part's last block first)
        jd, amax = np.asarray(q["jd"], f8), np.asarray(q["amax"], f8)
        jerk = None if q["jerk"] is None else np.asarray(q["jerk"], f8)
        cols = (d, L, vn, acc, jd, jerk, amax)
        last = tuple(None if c is None else c[-1:].copy() for c in cols)
        if self.prev is not None:
            cols = tuple(None if c is None else np.concatenate([pc, c]) for pc, c in zip(self.prev, cols))
        me2 = _junctions(*cols, self.m)
        if self.prev is not None:
            me2 = me2[1:]
        self.prev = last
        del cols, jd, amax, jerk
        self._keep(q, k, d[:, 0], d[:, 1], d[:, 2], d[:, 3], L, vn, acc, me2)

    def _add_c(self, q: dict, k: int) -> None:
        """add's numbers by the compiled planner (_plan.blocks: the same, operation for operation)."""
        f8 = np.float64
        dx, dy, dz, de = (np.asarray(q[c], f8) for c in ("dx", "dy", "dz", "de"))
        L, vn, acc, me2 = np.empty(k), np.empty(k), np.empty(k), np.empty(k)
        if self.prev_c is None:
            self.prev_c = np.zeros(6)
        _plan.blocks(dx, dy, dz, de, np.asarray(q["v"], f8), np.asarray(q["accel"], f8),
                     np.asarray(q["jd"], f8), np.asarray(q["amax"], f8), np.asarray(q["vmax"], f8),
                     self.prev_c, bool(self.m.jd_small_segments), self.m.min_planner_speed ** 2,
                     L, vn, acc, me2)
        if np.any(vn <= 0):
            self.bad = int(np.asarray(q["line"])[int(np.argmax(vn <= 0))])
            return
        self._keep(q, k, dx, dy, dz, de, L, vn, acc, me2)

    def _keep(self, q, k, dx, dy, dz, de, L, vn, acc, me2) -> None:
        """A part's planned numbers: into the run, and what the totals (and blocks) need."""
        f8 = np.float64
        e_only = np.flatnonzero((dx == 0) & (dy == 0) & (dz == 0) & (de != 0))
        n_e, spm_e, vn_e = np.asarray(q["n_e"], f8)[e_only], np.asarray(q["spm_e"], f8)[e_only], vn[e_only]
        feature = np.asarray(q["feature"])
        self.de.append(de[(de > 0) & ((dx != 0) | (dy != 0) | (dz != 0))])
        if self.keep:
            b = np.zeros(k, dtype=BLOCK_DTYPE)
            for name in ("line", "feature", "layer"):
                b[name] = q[name]
            b["dx"], b["dy"], b["dz"], b["de"] = dx, dy, dz, de
            b["length"], b["nominal_speed"], b["accel"] = L, vn, acc
            self.parts.append(b)
        # runs: a block after a stop starts one
        lo = 0
        for hi in np.flatnonzero(q["brk"]).tolist() + [k]:
            if hi > lo:
                w = (e_only >= lo) & (e_only < hi)
                if w.any():
                    self.e_only.append((e_only[w] - lo + self.run.n, n_e[w], spm_e[w], vn_e[w]))
                self.run.add(acc[lo:hi], L[lo:hi], vn[lo:hi], me2[lo:hi])
                self.feature.append(feature[lo:hi].astype(np.int32))
            if hi < k:
                self.close()
            lo = hi

    def close(self) -> None:
        """Plans the run gathered so far."""
        if not self.run.n:
            return
        run, self.run = self.run, _Run()
        t, sp = _plan_run(run, self.m, self.keep)
        if self.e_only:
            sel, n_e, spm_e, vn = (np.concatenate(c) for c in zip(*self.e_only))
            k, tc = _slow_e_only(vn, sel, n_e, spm_e, self.m.min_step_rate)
            if sp[3] is not None:
                sp[3][k], sp[4][k], sp[5][k] = 0.0, tc, 0.0
            t[k] = (0.0 + tc) + 0.0                      # t_accel + t_cruise + t_decel
        self.t.append(t)
        # the time per feature as np.bincount(feature, weights=t) adds it up over the whole file:
        # block by block in order (cumsum continues each feature's sum exactly so)
        feature = np.concatenate(self.feature)
        self.feature = []
        for c0 in range(0, len(t), CHUNK):
            f, tt = feature[c0:c0 + CHUNK], t[c0:c0 + CHUNK]
            for i in np.flatnonzero(np.bincount(f)).tolist():
                self.by_feature[i] = np.cumsum(np.concatenate([[self.by_feature.get(i, 0.0)], tt[f == i]]))[-1]
        if self.keep:
            self.speeds.append(sp)
        self.e_only = []

    def finish(self):
        """(each block's time, the time per feature index, the filament of extruding blocks,
        the blocks or None, the number of blocks)."""
        self.close()
        if self.bad is not None:
            raise EstimateError(f"{self.source}:{self.bad}: move with feed rate 0")
        t = self.t[0] if len(self.t) == 1 else np.concatenate(self.t) if self.t else np.zeros(0)
        self.t = []
        de, self.de = self.de, []
        filament = float(np.concatenate(de).sum()) if de else 0.0
        del de
        b = None
        if self.keep:
            b = np.concatenate(self.parts) if self.parts else np.zeros(0, dtype=BLOCK_DTYPE)
            self.parts = []
            for i, name in enumerate(_SPEEDS):
                if len(b):
                    b[name] = np.concatenate([s[i] for s in self.speeds])
        return t, self.by_feature, filament, b, self.n


class _Run:
    """A run of blocks (no stop between them) as its columns came, piece by piece: acceleration,
    length, nominal speed, junction speed squared; and cum, the prefix sums of the lengths
    (np.cumsum over the whole run, to the bit: each piece's sums continue from the last one's
    total), made piece by piece when needed. Windows are copied out as they are planned
    (window()), and pieces behind them are let go (drop()), so that planning needs no second copy
    of the run."""

    def __init__(self):
        self.pieces = []                 # (a, L, vn, me2) or None once dropped
        self.cums = {}                   # piece -> its cum values, made when a search needs them
        self.starts = []                 # each piece's first block
        self.lasts = []                  # each piece's last cum
        self.n = 0
        self.vn_max = self.a_min = None

    def _sums(self, j: int) -> np.ndarray:
        total = self.lasts[j - 1] if j else 0.0
        return np.cumsum(np.concatenate([[total], self.pieces[j][1]]))[1:]

    def add(self, a, L, vn, me2) -> None:
        self.pieces.append((a, L, vn, me2))
        self.starts.append(self.n)
        self.lasts.append(float(self._sums(len(self.pieces) - 1)[-1]))     # kept: one number
        self.n += len(a)
        vm, am = vn.max(), a.min()
        self.vn_max = vm if self.vn_max is None else np.maximum(self.vn_max, vm)
        self.a_min = am if self.a_min is None else np.minimum(self.a_min, am)

    def cum(self, i: int) -> float:
        """The run's cum[i] (cum[0] = 0: before the first block)."""
        if i == 0:
            return 0.0
        j = bisect.bisect_right(self.starts, i - 1) - 1
        return self._cum(j)[i - 1 - self.starts[j]]

    def _cum(self, j: int) -> np.ndarray:
        if j not in self.cums:
            self.cums[j] = self._sums(j)
        return self.cums[j]

    def searchsorted(self, x: float, side: str) -> int:
        """np.searchsorted(cum, x, side) on the run's n + 1 cum values."""
        if x < 0 or (side == "left" and x <= 0):       # cum[0] = 0, and every cum >= 0
            return 0
        j = (bisect.bisect_right if side == "right" else bisect.bisect_left)(self.lasts, x)
        if j == len(self.pieces):
            return self.n + 1
        return 1 + self.starts[j] + int(np.searchsorted(self._cum(j), x, side=side))

    def window(self, lo: int, hi: int):
        """(a, L, vn, me2) of blocks lo..hi-1, contiguous."""
        j = bisect.bisect_right(self.starts, lo) - 1
        parts = []
        while j < len(self.pieces) and self.starts[j] < hi:
            s0 = self.starts[j]
            parts.append(tuple(c[max(lo - s0, 0):hi - s0] for c in self.pieces[j]))
            j += 1
        if len(parts) == 1:
            return parts[0]
        return tuple(np.concatenate(c) for c in zip(*parts))

    def drop(self, lo: int) -> None:
        """Lets go of the pieces that end before block lo."""
        for j in range(len(self.pieces) - 1):
            if self.starts[j + 1] > lo:
                break
            self.pieces[j] = None
            self.cums.pop(j, None)


def _plan_run(run: _Run, m: Machine, speeds: bool):
    """Plans a run of blocks (no stop between them), a chunk at a time when it is long: (each
    block's time, _SPEEDS' arrays or Nones). A block's speeds depend only on blocks within the
    distance the head needs to reach or lose its highest speed (v^2 / 2a), so each chunk is
    planned with that much on both sides and only its own blocks are kept: the same result as
    planning the whole run at once."""
    n = run.n
    t = np.empty(n)
    sp = [np.empty(n) if speeds else None for _ in _SPEEDS]
    if n <= 2 * CHUNK:
        _plan_window(*run.window(0, n), m, 0, n, 0, n, t, sp)
        return t, sp
    reach = float(run.vn_max * run.vn_max / (2 * run.a_min)) * 1.5 + 1.0
    for c0 in range(0, n, CHUNK):
        c1 = min(n, c0 + CHUNK)
        lo = run.searchsorted(run.cum(c0) - reach, "right") - 1
        hi = run.searchsorted(run.cum(c1) + reach, "left") + 1
        lo, hi = max(0, lo - m.lookahead if m.lookahead else lo), min(n, hi + (m.lookahead or 0))
        # the window's edges are planned wrongly: not kept
        _plan_window(*run.window(lo, hi), m, 0, hi - lo, c0 - lo, c1 - lo, t[lo:],
                     [None if o is None else o[lo:] for o in sp])
        run.drop(lo)
    return t, sp


def estimate_lines(lines, machine: Machine | None = None, source: str = "<gcode>",
                   blocks: bool = True) -> Result:
    """Items of `lines`: G-code lines, or MoveBlocks standing for the lines of their moves.
    blocks=False: Result.blocks is None (the totals only, in less memory)."""
    m = machine or Machine()
    p = _Parser(m, source)
    plan = _Planner(m, source, blocks)
    count = 0
    for raw in lines:
        if isinstance(raw, MoveBlock):
            p.block(count + 1, raw)
            count += len(raw)
        else:
            count += 1
            p.line(count, raw)
        if p.parts:
            plan.feed(p)
    p.flush()
    plan.feed(p)
    return _result(p, plan, count)


def _result(p: _Parser, plan: _Planner, count: int) -> Result:
    t, sums, filament, b, n = plan.finish()
    feats = p.features
    by = {}
    if n:
        by = {feats[i]: float(sums.get(i, 0.0)) for i in range(len(feats)) if sums.get(i, 0.0) > 0}
    for f, dt in p.dwell_by_feature.items():
        by[f] = by.get(f, 0.0) + dt
    moves = float(t.sum())
    return Result(total_s=moves + p.dwell, moves_s=moves, dwell_s=p.dwell, by_feature=by,
                  features=feats, blocks=b, lines=count, n_blocks=n, filament=filament)


def _lround(v: float) -> int:
    return int(math.floor(v + 0.5)) if v >= 0 else -int(math.floor(-v + 0.5))


def _slow_e_only(vn, sel, steps_e, spm_e, floor):
    """Moves of E alone (indices sel, their nominal speed, whole steps and steps/mm) whose step rate is under
    the step-rate floor (Marlin's MINIMAL_STEP_RATE, 120): 1/120 + (n - 1)/r s, all at their
    speed (see the module's doc); faster
    ones keep their trapezoid, which is n/r plus the ramp. -> (those moves, their cruise time)."""
    n = steps_e
    if floor <= 0:                              # no step-rate floor (Klipper): none is slow
        return sel[:0], np.zeros(0)
    # Marlin's length of the block is its whole steps in mm: the rate is speed x steps/mm
    rate = np.ceil(vn * spm_e - 1e-9)
    slow = (rate < floor) & (n >= 1)
    return sel[slow], 1 / floor + (n[slow] - 1) / rate[slow]


def estimate_file(path, machine: Machine | None = None, scanned: bool | None = None,
                  blocks: bool = True) -> Result:
    """The file's estimate: from the compiled scanner's move records (movescan, events mode)
    when it is built, else (or scanned=False) from its lines; both give the same blocks
    (host/tests/gcode/test_estimate_scan.py). blocks=False: Result.blocks is None (the totals
    only, in less memory: what `bulgekit estimate` prints). The file is checked as every
    command checks G-code (gcode.check_complete: empty, binary, cut off: the same messages) on
    the way, not in a pass of its own; one with no move or dwell to time (an SVG, say) is
    refused too."""
    from . import movescan
    path = os.fspath(path)
    try:
        last = check_file_ends(path, path)
        r = None
        if scanned is None:
            scanned = movescan.available()
        if scanned:
            try:
                r = _estimate_scanned(path, machine or Machine(), path, blocks)
            except movescan.Unsupported:
                pass                                   # a line only the text parser takes
        if r is None:
            with open(path, encoding="utf-8", errors="replace") as f:
                r = estimate_lines(f, machine, source=path, blocks=blocks)
    except OSError as e:
        raise EstimateError(f"{path}: {e.strerror or e}") from None
    if last is not None:
        refuse_cut_off(last, r.lines, path)
    if r.n_blocks == 0 and r.dwell_s == 0:
        raise EstimateError(f"{path}: no move or dwell to time (G0-G3, G4); is it a G-code file?")
    return r


# Lines the estimator reads itself (the scanner's events) that move the head or set its position
# as the scanner may not (G28, a bare G92, arcs ...): the moves gathered before them are taken
# first. Every other event (comments, feed and acceleration settings, dwells, G90/M83 ...)
# leaves the position alone, and the moves on either side of it are taken together, each with
# the state it set; so does a G92 of numbers, which the scanner sets alike.
_HARD = frozenset(("G0", "G1", "G2", "G3", "G92", "G28", "M92", "M723"))


@functools.lru_cache(maxsize=4096)                     # slicers repeat the same few event lines
def _command(raw: str) -> str | None:
    """The command of a line as _Parser.line reads it (None: a comment or blank)."""
    code, _ = split_code(raw)
    return command_of(code.split(None, 1)[0]) if code else None


def _estimate_scanned(path: str, m: Machine, source: str, blocks: bool = True) -> Result:
    """estimate_lines on the file, its plain moves taken from the scanner's records as arrays
    (what _Parser.move and emit would compute, operation for operation) and every other line
    (the scanner's events: comments with TYPE:/LAYER, other commands, odd moves) given to
    _Parser.line in order. A move whose start is not where the parser stands (after a G28, a bare
    G92 ...: the scanner does not follow those) is read from its text too. Each chunk's blocks are
    planned as it is read (_Planner)."""
    from . import movescan
    p = _Parser(m, source)
    plan = _Planner(m, source, blocks)
    if movescan._scan is None:
        raise movescan.Unsupported("bulgekit.gcode._scan is not built")
    sc = movescan._scan.Scanner((), (), movescan._classify, events=True)
    base, buf = 0, b""

    def text_at(off: int) -> str:
        i = off - base
        j = buf.find(b"\n", i)
        j = len(buf) if j < 0 else j
        r = buf.find(b"\r", i, j)
        return buf[i:j if r < 0 else r].decode("utf-8", "replace")

    def feed(data, part, final, at):
        """One feed (movescan._file_parts): the part fed (with its file offset), its records,
        and the scanner's E and lines after it (read and scanned ahead on a thread:
        movescan._ahead); and the bytes used."""
        recs, used = sc.feed(part, final, at)
        return (part, at, np.frombuffer(recs, dtype=movescan.RECORD), sc.e, sc.lines), used

    lines = 0
    try:
        with open(path, "rb") as f, contextlib.ExitStack() as stack:
            fed = movescan._file_parts(f, feed)
            if movescan._use_ahead(os.fstat(f.fileno()).st_size):
                fed = movescan._ahead(fed)
                stack.callback(fed.close)     # (the worker stopped before the file is closed)
            for buf, base, a, e, lines in fed:
                # the E the chunk ends at: the next record's start (every line that sets E, an
                # event or a move, has a record, so none comes between)
                _take(p, a, text_at, e)
                plan.feed(p)
                _progress_tick(lines)
    except movescan._scan.ScanUnsupported:
        raise movescan.Unsupported("the scanner refused a line") from None
    p.flush()
    plan.feed(p)
    return _result(p, plan, lines)


_EVENT = 16                                             # the scanner's flag for an event record
_ABS_XYZ, _ABS_E = 4, 8                                 # movescan.ABS_XYZ, ABS_E


def _progress_tick(n: int) -> None:
    from .. import progress
    progress.tick(n)


def _take(p: _Parser, a: np.ndarray, text, e_last: float) -> None:
    """One chunk of records (see _estimate_scanned). Moves are gathered in ranges while only
    lines that leave the position alone come between them (_SOFT, comments), each range with the
    parser's state at its start, and taken as arrays when another line comes (or the chunk ends).
    text(byte offset): a record's line."""
    n = len(a)
    if not n:
        return
    ev = np.flatnonzero(a["flags"] & _EVENT)
    ev_line = a["line_no"][ev].tolist()
    ev_off = a["offset"][ev].tolist()
    # a move's end E is the next record's start E (an event's record holds the state before it)
    e_next = np.append(a["e_start"][1:], e_last)
    ranges = []                                         # (start, end, state, E steps at its start)
    i = 0
    for q, j in enumerate(ev.tolist() + [n]):
        while j > i:                                    # moves i .. j-1
            if not ranges and not _in_step(p, a[i]):
                r = a[i]
                p.line(int(r["line_no"]), text(int(r["offset"])))    # from its text until in step again
                i += 1
                continue
            # the E steps a range starts from: the first one's are the parser's now (a G92
            # gathered later sets p.e_at), a later one's are its last block's unless a G92 set them
            at = p.e_at if not ranges and p.g92_at is None else p.g92_at
            ranges.append((i, j, _state(p), at))
            p.g92_at = None
            if p.g92_lines:
                p.g92_lines = []
            p.brk = False                               # taken by the range's first block (or carried)
            i = j
        if j == n:
            break
        ln = ev_line[q]
        raw = text(ev_off[q])
        cmd = _command(raw)
        if ranges and cmd in _HARD:
            if cmd == "G92" and _plain_g92(raw):
                p.line(ln, raw)
                p.g92_at = p.e_at                       # the E steps the next range starts from
                p.g92_lines.append((ln, raw))           # again once the moves are taken
                i = j + 1
                continue
            _vector_moves(p, a, e_next, ranges)
            ranges = []
        p.line(ln, raw)
        i = j + 1
    if ranges:
        _vector_moves(p, a, e_next, ranges)


@functools.lru_cache(maxsize=4096)
def _plain_g92(raw: str) -> bool:
    """A G92 that sets E, and only axes given as numbers (as the scanner sets them)."""
    if "*" in raw or "(" in raw:
        return False
    head = split_code(raw)[0].split(None, 1)
    try:
        w = parse_words(head[1] if len(head) > 1 else "", "", bare=True)
    except GcodeError:
        return False
    return "E" in w and w.keys() <= {"X", "Y", "Z", "E"} and None not in w.values()


def _in_step(p: _Parser, r) -> bool:
    """Whether the parser stands where the record starts, in its modes, at its feed rate."""
    fl = int(r["flags"])
    return (not p.width and p.pos[0] == r["x0"] and p.pos[1] == r["y0"] and p.pos[2] == r["z0"]
            and p.pos[3] == r["e_start"] and p.F == r["f"] and p.rel[0] == (not fl & _ABS_XYZ)
            and p.rel[1] == p.rel[2] == p.rel[0] and p.rel[3] == (not fl & _ABS_E))


def _lround_array(v: np.ndarray) -> np.ndarray:
    return np.where(v >= 0, np.floor(v + 0.5), -np.floor(-v + 0.5)).astype(np.int64)


def _vector_moves(p: _Parser, a: np.ndarray, e_next: np.ndarray, ranges) -> None:
    """_Parser.move + emit for the moves of `ranges`, as arrays (see _take)."""
    m = p.m
    R = len(ranges)
    rs = np.array([s for s, _, _, _ in ranges], np.int64)
    counts = np.array([e for _, e, _, _ in ranges], np.int64) - rs
    starts = np.cumsum(counts) - counts                 # each range's first move among the k taken
    k = int(counts.sum())
    rid = np.repeat(np.arange(R), counts)               # each move's range
    idx = np.arange(k) + (rs - starts)[rid]
    # the records as rows of 8-byte words (movescan.RECORD; np.take of plain rows is quick)
    w = a.dtype.itemsize // 8
    g = np.take(a.view(np.float64).reshape(len(a), w), idx, axis=0)
    x0, y0, z0, x1, y1, z1, de, f = (g[:, a.dtype.fields[c][1] // 8]
                                     for c in ("x0", "y0", "z0", "x1", "y1", "z1", "e", "f"))
    off = a.dtype.fields["line_no"][1]
    line_no = g.view(np.int32).reshape(k, 2 * w)[:, off // 4] if off % 4 == 0 else a["line_no"][idx]
    # the states as one matrix, a row per range: feature, layer, M220, accel x3, jd, jerk x4,
    # M201 x4, M203 x4, brk (_state)
    S = np.array([st for _, _, st, _ in ranges], float)
    brk_in = np.zeros(k, bool)
    brk_in[starts] = S[:, 19] != 0
    sx, sy, sz, se = (p.spm[ax] for ax in AXES)
    ea = e_next[idx]
    e_to = _lround_array(ea * se)
    e_prev = np.concatenate([[p.e_at], e_to[:-1]])
    reset = np.zeros(k, bool)                      # a G92 before it set the E steps
    g92 = [(q, r[3]) for q, r in enumerate(ranges) if r[3] is not None]
    if g92:
        q, at = zip(*g92)
        e_prev[starts[list(q)]] = at
        reset[starts[list(q)]] = True
    if _plan is not None:                          # the same, move by move in C
        D, ne, emitted = np.empty((k, 4)), np.empty(k), np.empty(k, bool)
        pend = np.array(p.pending, float)
        _plan.moves(x0, y0, z0, x1, y1, z1, de, e_to, e_prev, reset, np.array([sx, sy, sz, se], float),
                    float(m.min_segment_steps), pend, D, ne, emitted)
        p.pending = pend.tolist()
    else:
        D, ne, emitted = _drop_tiny(p, k, x0, y0, z0, x1, y1, z1, de, e_to, e_prev, reset)
    E = np.flatnonzero(emitted)
    cs = np.cumsum(brk_in)
    if len(E):
        before = np.concatenate([[0], cs[E[:-1]]])
        brk = (cs[E] - before) > 0
        p.brk = p.brk or bool(cs[-1] - cs[E[-1]] > 0)
        p.e_at = int(e_to[E[-1]])
        DE = D[E] if len(E) < k else D
        xyzE = np.sqrt(DE[:, 0] * DE[:, 0] + DE[:, 1] * DE[:, 1] + DE[:, 2] * DE[:, 2])
        rE = rid[E]                                     # each emitted block's range
        nE = len(E)

        def state(c0, c1=None):
            """State columns c0 (..c1) per emitted block; a column the same in every range is
            given as a broadcast view, not copied."""
            cols = S[:, c0:c1 or c0 + 1]
            if (cols == cols[0]).all():
                out = np.broadcast_to(cols[0], (nE, cols.shape[1]))
            else:
                out = cols[rE]
            return out if c1 else out[:, 0]

        acc = np.where(xyzE > 0, np.where(DE[:, 3] != 0, state(3), state(4)), state(5))
        p.flush()
        p.parts.append({
            "line": line_no[E].astype(np.int64), "feature": state(0).astype(np.int64),
            "layer": state(1).astype(np.int64), "dx": DE[:, 0], "dy": DE[:, 1], "dz": DE[:, 2],
            "de": DE[:, 3], "v": f[E] / 60 * state(2) / 100, "accel": acc, "brk": brk,
            "jd": state(6), "jerk": None if p.jerk is None else state(7, 11),
            "amax": state(11, 15), "vmax": state(15, 19),
            "n_e": ne[E], "spm_e": np.broadcast_to(float(se), (nE,))})
    else:
        p.brk = p.brk or bool(cs[-1] > 0)
    p.pos = [float(x1[-1]), float(y1[-1]), float(z1[-1]), float(ea[-1])]
    p.F = float(f[-1])
    p.f = p.F / 60
    for n, raw in p.g92_lines:                    # G92s after the last range: on the position now
        p.line(n, raw)
    p.g92_lines, p.g92_at = [], None


def _drop_tiny(p: _Parser, k, x0, y0, z0, x1, y1, z1, de, e_to, e_prev, reset):
    """_vector_moves' Marlin rule for tiny moves, on arrays (_plan.moves does it in C):
    -> (D: dx dy dz de as planned, ne: E-alone whole steps, emitted); sets p.pending."""
    m = p.m
    sx, sy, sz, se = (p.spm[ax] for ax in AXES)
    D = np.empty((k, 4))
    np.subtract(x1, x0, out=D[:, 0])
    np.subtract(y1, y0, out=D[:, 1])
    np.subtract(z1, z0, out=D[:, 2])
    D[:, 3] = de
    xyz = np.sqrt(D[:, 0] * D[:, 0] + D[:, 1] * D[:, 1] + D[:, 2] * D[:, 2])
    st_e = np.where(xyz == 0, np.abs(e_to - e_prev), np.abs(D[:, 3]) * se)
    mx = np.maximum(np.maximum(np.abs(D[:, 0]) * sx, np.abs(D[:, 1]) * sy), np.maximum(np.abs(D[:, 2]) * sz, st_e))
    ne = np.where(xyz == 0, st_e, 0.0)
    emitted = np.ones(k, bool)
    # Dropped moves (too few steps, Marlin's rule): their distance goes to the next move. A move
    # the arrays above drop does drop when the move before it was planned (its E steps and
    # distance are then the ones used above); the usual case, one dropped move (a lone F word)
    # whose next move is planned, is computed on arrays ("single"), chains of them one at a time.
    drop = (mx < m.min_segment_steps) | (mx == 0)
    todo = np.flatnonzero(drop)
    pending = any(p.pending)
    nxt_ok = np.zeros(len(todo), bool)
    if len(todo):
        s1 = todo + 1
        nxt_ok = s1 < k
        nxt_ok[nxt_ok] = ~drop[s1[nxt_ok]]
        if pending and todo[0] == 0:
            nxt_ok[0] = False
    single = todo[nxt_ok]
    if len(single):
        # as the loop below computes it: the dropped move's distance (plus nothing pending)
        # added to the next move's, whose E steps count from the dropped one's start
        s1 = single + 1
        d1 = D[s1] + (D[single] + 0.0)
        xs1 = np.sqrt(d1[:, 0] * d1[:, 0] + d1[:, 1] * d1[:, 1] + d1[:, 2] * d1[:, 2])
        e_at1 = np.where(reset[s1], e_prev[s1], e_prev[single])
        st1 = np.where(xs1 == 0, np.abs(e_to[s1] - e_at1), np.abs(d1[:, 3]) * se)
        mx1 = np.maximum(np.maximum(np.abs(d1[:, 0]) * sx, np.abs(d1[:, 1]) * sy),
                         np.maximum(np.abs(d1[:, 2]) * sz, st1))
        ok = ~((mx1 < m.min_segment_steps) | (mx1 == 0))
        nxt_ok[np.flatnonzero(nxt_ok)[~ok]] = False
        single, s1, d1, xs1, st1 = single[ok], s1[ok], d1[ok], xs1[ok], st1[ok]
    chains = list(todo[~nxt_ok])
    if pending and (not chains or chains[0] != 0):
        chains.insert(0, 0)
    covered = []                                   # (first, end) of each chain taken one by one
    nxt, last_pend = 0, [0.0, 0.0, 0.0, 0.0]
    for j in chains:
        if j < nxt:
            continue
        j0 = j
        pend, e_at = (list(p.pending) if j == 0 else [0.0, 0.0, 0.0, 0.0]), int(e_prev[j])
        while j < k:
            if reset[j]:
                e_at = int(e_prev[j])
            d = [float(D[j, c]) + pend[c] for c in range(4)]
            steps = [abs(d[0]) * sx, abs(d[1]) * sy, abs(d[2]) * sz, abs(d[3]) * se]
            xj = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            et = int(e_to[j])
            if xj == 0:
                steps[3] = abs(et - e_at)
            j += 1
            if max(steps) < m.min_segment_steps or max(steps) == 0:
                emitted[j - 1] = False
                pend = d
                continue
            D[j - 1] = d
            ne[j - 1] = steps[3] if xj == 0 else 0
            e_at, pend = et, [0.0, 0.0, 0.0, 0.0]
            break
        nxt = j
        covered.append((j0, j))
        last_pend = pend if j == k else [0.0, 0.0, 0.0, 0.0]
    if len(single):
        if covered:                                # a single one inside a chain is the chain's
            c0, c1 = np.array(covered).T
            w = np.searchsorted(c0, single, side="right") - 1
            free = (w < 0) | (single >= c1[np.maximum(w, 0)])
            single, s1, d1, xs1, st1 = single[free], s1[free], d1[free], xs1[free], st1[free]
        emitted[single] = False
        D[s1] = d1
        ne[s1] = np.where(xs1 == 0, st1, 0.0)
    p.pending = last_pend if nxt == k else [0.0, 0.0, 0.0, 0.0]
    return D, ne, emitted


_XYZE = operator.itemgetter(*AXES)


def _state(p: _Parser) -> tuple:
    """The parser's state a range of moves starts with, as one row of numbers (see _vector_moves)."""
    return ((p.fidx[p.feature], p.layer, p.pct, p.accel, p.travel_accel, p.retract_accel, p.jd)
            + (_NO_JERK if p.jerk is None else _XYZE(p.jerk)) + _XYZE(p.max_accel) + _XYZE(p.max_fr)
            + (p.brk,))


_NO_JERK = (0.0, 0.0, 0.0, 0.0)


def block_times(res: Result) -> np.ndarray:
    b = res.blocks
    return b["t_accel"] + b["t_cruise"] + b["t_decel"]


def extruding(res: Result) -> np.ndarray:
    """Blocks that lay filament: X/Y/Z motion with dE > 0."""
    b = res.blocks
    return (b["de"] > 0) & ((b["dx"] != 0) | (b["dy"] != 0) | (b["dz"] != 0))


def deposited_filament(res: Result, mask=None) -> float:
    """Filament (mm) laid by extruding moves (retractions and their primes are not counted)."""
    if res.blocks is None:                                 # blocks=False: the sum kept
        if mask is not None:
            raise ValueError("deposited_filament with a mask needs the blocks (blocks=True)")
        return res.filament
    sel = extruding(res) if mask is None else (extruding(res) & mask)
    return float(res.blocks["de"][sel].sum())


def e_rate_share(res: Result, mask=None, ref: float | None = None, tol: float = 0.05,
                 cruise_only: bool = False) -> float:
    """Share of extruding time with the extruder rate (dE/L x head speed) within +-tol of `ref`
    (mm/s of filament; None: the time-weighted median rate at cruise of the selected blocks).
    Exact over the trapezoids: the speed is linear in time while accelerating or braking, so the
    time spent in a speed band is that band's overlap with the ramp divided by the acceleration.
    cruise_only: each block counted at its nominal speed for length / nominal speed seconds."""
    b = res.blocks
    sel = extruding(res) if mask is None else (extruding(res) & np.asarray(mask, bool))
    if not sel.any():
        return float("nan")
    b = b[sel]
    k = b["de"] / b["length"]                              # filament per mm of motion
    if ref is None:
        rate = k * b["nominal_speed"]
        w = b["length"] / b["nominal_speed"]
        o = np.argsort(rate)
        cw = np.cumsum(w[o])
        ref = float(rate[o][np.searchsorted(cw, cw[-1] / 2)])
    lo, hi = ref * (1 - tol) / k, ref * (1 + tol) / k      # speed band per block
    if cruise_only:
        t = b["length"] / b["nominal_speed"]
        inside = (b["nominal_speed"] >= lo) & (b["nominal_speed"] <= hi)
        return float(t[inside].sum() / t.sum())

    def ramp(va, vb, a):
        top, bot = np.maximum(va, vb), np.minimum(va, vb)
        return np.maximum(np.minimum(top, hi) - np.maximum(bot, lo), 0.0) / a

    a = b["accel"]
    t_in = ramp(b["entry_speed"], b["cruise_speed"], a) + ramp(b["cruise_speed"], b["exit_speed"], a)
    vc = b["cruise_speed"]
    t_in = t_in + np.where((vc >= lo) & (vc <= hi), b["t_cruise"], 0.0)
    total = (b["t_accel"] + b["t_cruise"] + b["t_decel"]).sum()
    return float(t_in.sum() / total)
