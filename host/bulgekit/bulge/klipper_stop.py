"""Stops for Klipper (issue 36): an extruder-only move planned as Klipper plans it.

Klipper (klippy/toolhead.py, kinematics/extruder.py at 84104bbb) plans a G1 of E alone as a
move of its own:
  * `Move.__init__`: its length is |E| (move_d), its speed the G1's F / 60, not capped by
    max_velocity; `ExtruderStepper.check_move` limits it to max_extrude_only_velocity and
    max_extrude_only_accel (`Move.limit_speed`, axis ratio 1);
  * `Move.calc_junction` returns at once when either move is not kinematic: the junctions on
    both sides of it keep max_start_v2 = 0, so the head comes to a standstill at the end of
    the X/Y move before it and starts again from rest after it;
  * `LookAheadQueue.flush` gives such a move, from rest to rest, cruise_v2 = min(v^2,
    d * a_e, d * min(a_e, mcr)) with mcr = max_accel * (1 - minimum_cruise_ratio) (the
    minimum-cruise-ratio pseudo acceleration) and `Move.set_junction` the trapezoid
    accel_t = decel_t = cv / a_e, cruise_t = (d - cv^2 / a_e) / cv: its time is
    T = d / cv + cv / a_e;
  * steps (klippy/chelper/itersolve.c) fall where a motor's position crosses the middle
    between two step positions.

The head therefore stands from the last X/Y step of the decelerating piece to the first step of
the next one: tail + T + lead, where tail and lead are the times a motor takes, decelerating or
accelerating at the toolhead's max_accel, over the distance between the stop point and the
nearest half-step crossing (at most one step: sqrt(2 / (a k)), 2.9 ms at 3000 mm/s^2 and 80
steps/mm). Both are computed from the stop's position on the motors' step grid, which is assumed
to lie on whole multiples of the step distance (a homed axis whose position_endstop is a
multiple of it, or SET_KINEMATIC_POSITION at such a point). G4 instead flushes the look-ahead and
adds its time after the standstill: tail + P + lead.

Nothing here imports Klipper: the numbers are the printer model's (bulgekit.machine).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

MIN_STOP_E_MM = 0.0001        # the least E a stop move lays (E is written with 5 decimals)
E_MARGIN = 0.95               # a stop lays at most this share of what its time could take


@dataclass(frozen=True)
class KlipperParams:
    """What a Klipper stop depends on (from a PrinterModel: `from_model`)."""
    accel: float = 3000.0               # [printer] max_accel (M204 S / SET_VELOCITY_LIMIT change it)
    min_cruise_ratio: float = 0.5       # [printer] minimum_cruise_ratio
    e_velocity: float = 79.8            # [extruder] max_extrude_only_velocity, mm/s
    e_accel: float = 798.0              # [extruder] max_extrude_only_accel, mm/s^2 (fixed at start)
    kinematics: str = "cartesian"       # cartesian or corexy: which motors X/Y moves step
    x_steps: float = 80.0               # steps/mm of the X (corexy: A) motor
    y_steps: float = 80.0               # steps/mm of the Y (corexy: B) motor
    cross_section: float = 0.64         # [extruder] max_extrude_cross_section, mm^2
    filament_area: float = math.pi * 0.875 ** 2
    nozzle: float = 0.4

    @classmethod
    def from_model(cls, m) -> "KlipperParams":
        v, a = m.klipper_extrude_only
        return cls(accel=m.accel, min_cruise_ratio=m.minimum_cruise_ratio, e_velocity=v,
                   e_accel=a, kinematics=getattr(m, "kinematics", "cartesian"),
                   x_steps=m.steps_per_mm.x, y_steps=m.steps_per_mm.y,
                   cross_section=m.klipper_cross_section, filament_area=m.filament_area,
                   nozzle=m.nozzle_diameter)

    @property
    def mcr_accel(self) -> float:
        return self.accel * (1.0 - self.min_cruise_ratio)

    @property
    def max_ratio(self) -> float:
        """E per mm of path Klipper allows (extruder.py's max_extrude_ratio)."""
        return self.cross_section / self.filament_area

    def piece_e_limit(self, length: float) -> float:
        """The most E a move of `length` mm (X/Y/Z) may lay without `Move exceeds maximum
        extrusion` (check_move: allowed when E/length <= the ratio, or E <= nozzle x ratio)."""
        return self.max_ratio * max(length, self.nozzle)

    def motors(self, x: float, y: float, ux: float, uy: float):
        """(position in steps, steps per mm of path) of each X/Y motor at (x, y) moving along
        the unit vector (ux, uy)."""
        if self.kinematics == "corexy":      # klippy/kinematics/corexy.py: a = x + y, b = x - y
            return [((x + y) * self.x_steps, (ux + uy) * self.x_steps),
                    ((x - y) * self.y_steps, (ux - uy) * self.y_steps)]
        return [(x * self.x_steps, ux * self.x_steps), (y * self.y_steps, uy * self.y_steps)]


def _frac(v: float) -> float:
    return v - math.floor(v)


def tail_s(p: KlipperParams, x: float, y: float, ux: float, uy: float,
           accel: float | None = None) -> float:
    """Seconds from the last motor step of a move along (ux, uy) that stops at (x, y) to the
    standstill: the motor whose last half-step crossing lies nearest the stop point (in time)."""
    a = p.accel if accel is None else accel
    best = None
    for q, c in p.motors(x, y, ux, uy):
        if abs(c) < 1e-9:
            continue
        d = _frac(q - 0.5) if c > 0 else _frac(0.5 - q)       # steps back to the last crossing
        t = math.sqrt(2 * (d / abs(c)) / a)
        best = t if best is None else min(best, t)
    return 0.0 if best is None else best


def lead_s(p: KlipperParams, x: float, y: float, ux: float, uy: float,
           accel: float | None = None) -> float:
    """Seconds from the start of a move along (ux, uy) from rest at (x, y) to its first motor
    step (the nearest half-step crossing ahead, reached accelerating at `accel`)."""
    a = p.accel if accel is None else accel
    best = None
    for q, c in p.motors(x, y, ux, uy):
        if abs(c) < 1e-9:
            continue
        d = 1.0 - (_frac(q - 0.5) if c > 0 else _frac(0.5 - q))   # steps ahead to the next one
        t = math.sqrt(2 * (d / abs(c)) / a)
        best = t if best is None else min(best, t)
    return 0.0 if best is None else best


def mean_edge_s(p: KlipperParams, accel: float | None = None) -> float:
    """tail_s or lead_s of a move along X at an unknown grid phase: the mean of sqrt(2 d/(a k))
    over d uniform in one step, 2/3 sqrt(2 / (a k)) (corexy: both motors step at k along X)."""
    a = p.accel if accel is None else accel
    return 2.0 / 3.0 * math.sqrt(2.0 / (a * p.x_steps))


def max_edge_s(p: KlipperParams, accel: float | None = None) -> float:
    """The longest tail_s or lead_s of an X/Y move: a whole step of a motor making k / sqrt 2
    steps per mm of path (a 45 degree move on a cartesian; corexy's motors make at least k)."""
    a = p.accel if accel is None else accel
    return math.sqrt(2.0 * math.sqrt(2.0) / (a * min(p.x_steps, p.y_steps)))


def cruise_v(p: KlipperParams, d: float, v: float, accel: float | None = None) -> float:
    """The cruise speed Klipper gives an E-only move of d mm at v mm/s (see the module doc)."""
    mcr = (p.accel if accel is None else accel) * (1.0 - p.min_cruise_ratio)
    cv2 = min(v * v, p.e_velocity ** 2, d * p.e_accel, d * min(p.e_accel, mcr))
    return math.sqrt(cv2)


def e_move_s(p: KlipperParams, d: float, v: float, accel: float | None = None) -> float:
    """Seconds Klipper plans for an E-only move of d mm at v mm/s, from rest to rest."""
    if d <= 0:
        return 0.0
    cv = cruise_v(p, d, v, accel)
    return d / cv + cv / p.e_accel


def _fastest(p: KlipperParams, d: float, accel: float | None) -> float:
    mcr = (p.accel if accel is None else accel) * (1.0 - p.min_cruise_ratio)
    return math.sqrt(min(p.e_velocity ** 2, d * min(p.e_accel, mcr)))


def max_e_for(p: KlipperParams, t: float, accel: float | None = None) -> float:
    """The most E (mm) an E-only move can lay in t seconds (at its fastest, see e_move_s)."""
    if t <= 0:
        return 0.0
    mcr = (p.accel if accel is None else accel) * (1.0 - p.min_cruise_ratio)
    am = min(p.e_accel, mcr)
    d = (t / (1.0 / math.sqrt(am) + math.sqrt(am) / p.e_accel)) ** 2
    if math.sqrt(d * am) > p.e_velocity:     # the velocity cap binds: cruise at e_velocity
        v = p.e_velocity
        d = max(0.0, (t - v / p.e_accel) * v)
    return d


def speed_for(p: KlipperParams, d: float, t: float, accel: float | None = None) -> float:
    """mm/s whose E-only move of d mm lasts t s (the slow root of d / v + v / a_e = t); the
    fastest the limits allow when t is shorter than that."""
    a_e = p.e_accel
    disc = t * t - 4 * d / a_e
    top = _fastest(p, d, accel)
    if disc < 0:
        return top
    v = a_e / 2 * (t - math.sqrt(disc))
    return min(v, top)


@dataclass
class KlipperStop:
    """One stop as Klipper plans it: tail + E move + lead = the dwell (or the nearest)."""
    ms: int
    e_mm: float                 # E the move lays (as written)
    speed: float                # mm/s (F / 60)
    move_s: float               # the move's planned time (e_move_s)
    tail: float
    lead: float
    between: float = 0.0        # E-only moves after it, before the next X/Y move (a retract)

    @property
    def still(self) -> float:
        return self.tail + self.move_s + self.between + self.lead


def plan(p: KlipperParams, ms: int, owed_mm: float, tail: float, lead: float,
         accel: float | None = None, lead_max: float | None = None) -> KlipperStop | None:
    """The E-only move for a stop of `ms` whose head stands tail + move + lead: it lays the extra
    owed there (or the most its time allows, E_MARGIN of it), at the speed that makes its time
    the dwell less tail and lead. lead_max: the lead is not known yet (retime sets it later):
    the E is chosen for the shortest time it may leave. None: no E owed to lay (write G4)."""
    t = ms / 1000.0 - tail - lead
    t_e = t if lead_max is None else ms / 1000.0 - tail - max(lead, lead_max)
    d = min(owed_mm, E_MARGIN * max_e_for(p, max(t_e, 0.0), accel))
    d = math.floor(d * 1e5) / 1e5                 # as written: 5 decimals, never above the owed
    if d < MIN_STOP_E_MM:
        d = MIN_STOP_E_MM
        if owed_mm < d:
            return None
    v = speed_for(p, d, max(t, 0.0), accel)
    v = math.ceil(v * 60 * 1000) / 1000 / 60     # F as written (3 decimals), rounded up
    return KlipperStop(ms, d, v, e_move_s(p, d, v, accel), tail, lead)


def retime(p: KlipperParams, ks: KlipperStop, lead: float, accel: float | None = None,
           between: float = 0.0) -> KlipperStop:
    """The same stop's E with its lead known, and the time of E-only moves (a retract) the file
    makes between it and the next X/Y move, during which the head stands too: the speed for the
    time left (the fastest the limits allow when none is left)."""
    t = ks.ms / 1000.0 - ks.tail - lead - between
    v = speed_for(p, ks.e_mm, max(t, 0.0), accel)
    v = math.ceil(v * 60 * 1000) / 1000 / 60
    return KlipperStop(ks.ms, ks.e_mm, v, e_move_s(p, ks.e_mm, v, accel), ks.tail, lead, between)
