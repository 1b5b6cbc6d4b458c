"""How Marlin 2.1.2.x's planner and AVR stepper time a stop, from a printer model's numbers.

The stock stop (fallback.py, "stops for stock firmware") is an E-only move of n steps at r
steps/s between two X/Y moves A (before) and B (after). Read from Marlin 2.1.2.7's planner.cpp
and stepper.cpp and checked in simulated stock Marlin 2.1.2.7 with four settings (issue 36,
docs/verification/marlin-simulation.md "Stops exact on Marlin with other settings"):

  head still = 1/max(r, floor) + (n - 1)/r + 1/max(floor, v k)

floor being MINIMAL_STEP_RATE (120 steps/s). A new block's first step comes one interval of its
initial rate after the last step of the block before (stepper.cpp loads the block and sets
`interval` from `initial_rate`), and the initial rate is its entry speed times its leading
axis's steps per mm of path (k), never under the floor. So:

  * the E block enters at its own speed vE = r / E steps/mm while the junction A -> E allows it
    (`e_entry_limit`): junction deviation's 90 degree corner speed sqrt(a JD / (sqrt 2 - 1)) with
    a the E block's acceleration, M204 R (limited by the axes' M201 along the junction); with
    classic jerk the X and E jerks (the E block enters at vE up to them). Above it the E block
    would start slower and accelerate: the writer keeps r under it;
  * B enters at v (`next_entry`):
      - junction deviation: min(vE, sqrt(a_B JD / (sqrt 2 - 1))), a_B being B's own
        acceleration (M204 P, limited by M201 along B and by LIN_ADVANCE, below), and not over
        B's feed rate;
      - classic jerk: Marlin's jerk junction (planner.cpp, "Classic Jerk Limiting"): after an
        E-only block whose safe speed passes 99 % of the jerk-limited junction speed, B enters
        at its own safe speed, its feed rate times min over its axes of jerk / that axis's
        speed: the X jerk (10 mm/s) for a move along X, whatever vE. So the head starts 1/(v k)
        = 1.25 ms after the last E step at 80 steps/mm, not 1/120 s. Capped by what the E
        block lets B reach (sqrt(vE^2 + 2 a_R n/spm), the planner's forward pass);
      - LIN_ADVANCE: an E-only move takes the retract branch (no advance); B, a printing move,
        has its acceleration cut to E's jerk / (K x its E per mm of path) (with junction
        deviation E's jerk is sqrt(JD sqrt(1/2)/(1 - sqrt(1/2)) M201 E)): that changes a_B above
        and the ramps below, not the stillness at Marlin's defaults.

The stop-and-start time (`ramp_s`): what A's braking into the stop and B's start add over
cruising, beyond the stillness. Marlin's AVR stepper ramps in discrete steps (each interval's
rate from the time since the ramp began, the first interval of a block included), so braking
ends well above the floor and a start from the floor is at speed after one interval: at
3000 mm/s^2 a stop from 40 mm/s costs 3.6 ms, not v/a = 13 ms. `ramp_s` runs that arithmetic
(trapezoid of planner.cpp calculate_trapezoid_for_block, stepper.cpp's phases) for A as one
block braking from its feed to the E block's entry and B as one block starting at v.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from ..gcode import estimate as es
from ..machine import PrinterModel

TIMER_RATE = 2_000_000          # AVR STEPPER_TIMER_RATE: F_CPU / 8
SQRT_HALF = math.sqrt(0.5)


def _avr_table(step: int) -> tuple[list[int], list[int]]:
    """Marlin's AVR speed_lookuptable.h (F_CPU 16 MHz) by the formula it was made with: entry i
    holds the ticks of 32 + step x i steps/s and the difference to entry i + 1 (the slow table's
    last difference is 3 in Marlin's)."""
    t = [int(TIMER_RATE / (32 + step * i)) for i in range(257)]
    g = [t[i] - t[i + 1] for i in range(256)]
    if step == 8:
        g[255] = 3
    return t[:256], g


_SLOW = _avr_table(8)
_FAST = _avr_table(256)


def avr_ticks(rate: float) -> int:
    """Timer ticks (2 MHz) between steps at `rate` whole steps/s, as Marlin's AVR
    calc_timer_interval makes them: a table lookup with linear interpolation, exact only at its
    points (32 + 8k steps/s below 2,080), and under 40 steps/s the slow table's product of the
    difference and the rate's low 3 bits is an AVR int, 16 bits, so it wraps: 38 and 39 steps/s
    give 61,317 and 59,755 ticks (30.7 and 29.9 ms, not 26.3 and 25.6)."""
    r = int(rate)
    if r <= 32:
        return _SLOW[0][0]
    r -= 32
    if r >= 0x800:
        i = min(r >> 8, 255)
        return _FAST[0][i] - (((r & 0xFF) * _FAST[1][i] + 128) >> 8)
    i = r >> 3
    return _SLOW[0][i] - (((_SLOW[1][i] * (r & 7)) & 0xFFFF) >> 3)


def avr_interval_s(rate: float) -> float:
    """Seconds between steps at `rate` whole steps/s on Marlin's AVR stepper (avr_ticks)."""
    return avr_ticks(rate) / TIMER_RATE


@dataclass(frozen=True)
class Piece:
    """The X/Y move on one side of a stop, as the planner sees it: unit direction (ux, uy) in
    X/Y, filament per mm of path, feed rate mm/s (as written: the printer's limits are applied
    here), and k, its leading axis's steps per mm of path (E's included)."""
    ux: float
    uy: float
    e_per_mm: float
    feed: float
    k: float
    length: float = 0.0     # mm (0: not known)


def piece_of(pm: PrinterModel, m) -> Piece:
    """A move (x0, y0, x1, y1, e, f: gcode.Move) as a Piece: its X/Y direction, filament per mm,
    feed, and its leading X/Y axis's steps per mm of path (a move without X/Y motion: along X)."""
    dx, dy = abs(m.x1 - m.x0), abs(m.y1 - m.y0)
    length = math.hypot(dx, dy)
    if length <= 1e-9:
        return Piece(1.0, 0.0, 0.0, m.f / 60.0, pm.steps_per_mm.x)
    ux, uy = dx / length, dy / length
    return Piece(ux, uy, max(m.e, 0.0) / length, m.f / 60.0,
                 max(pm.steps_per_mm.x * ux, pm.steps_per_mm.y * uy))


def floor_rate(pm: PrinterModel) -> float:
    return pm.min_step_rate if pm.min_step_rate > 0 else 1.0


def corner_speed(a: float, jd: float) -> float:
    """Junction deviation's speed at a 90 degree corner (E-only move against an X/Y move)."""
    return math.sqrt(a * jd / (math.sqrt(2) - 1))


def junction_speed(a: float, jd: float, e_per_mm: float = 0.0) -> float:
    """Junction deviation's speed from an E-only move into a printing move laying e_per_mm of
    filament per mm of path: Marlin normalises both blocks' unit vectors with their E (planner.cpp,
    `esteps > 0`), so the angle is over 90 degrees by the E component: cos = -e/sqrt(1 + e^2),
    sqrt(a JD sin(th/2) / (1 - sin(th/2))). (This counts where LIN_ADVANCE has cut a, on a piece
    that carries a stop's extra: e 0.1-0.4 mm/mm, 10-60 % faster than at 90 degrees.)"""
    if e_per_mm <= 0:
        return corner_speed(a, jd)
    sh = math.sqrt(0.5 * (1 + e_per_mm / math.sqrt(1 + e_per_mm ** 2)))
    return math.sqrt(a * jd * sh / (1 - sh))


def e_jerk(pm: PrinterModel) -> float:
    """E's jerk as LIN_ADVANCE uses it (planner.h recalculate_max_e_jerk with junction
    deviation; the M205 E jerk with classic jerk)."""
    if pm.jerk is not None:
        return pm.jerk.e
    return math.sqrt(pm.junction_deviation * SQRT_HALF / (1 - SQRT_HALF) * pm.max_accel.e)


def piece_accel(pm: PrinterModel, p: Piece | None) -> float:
    """A printing move's acceleration, mm/s^2 of path: M204 P, limited by each axis's M201 along
    it (LIMIT_ACCEL) and by LIN_ADVANCE (E's jerk / (K x E per mm), planner.cpp). Without a
    piece: M204 P."""
    a = pm.accel
    if p is None:
        return a
    if pm.linear_advance_k > 0 and 0 < p.e_per_mm <= 3.0:
        a = min(a, e_jerk(pm) / (pm.linear_advance_k * p.e_per_mm))
    for lim, u in ((pm.max_accel.x, p.ux), (pm.max_accel.y, p.uy), (pm.max_accel.e, p.e_per_mm)):
        if u > 1e-12 and lim / u < a:
            a = lim / u
    return a


def e_move_accel(pm: PrinterModel) -> float:
    """The acceleration of a move of E alone, mm/s^2 of E: M204 R (Marlin applies no M201
    limit to it)."""
    return pm.retract_accel


def e_entry_limit(pm: PrinterModel) -> float:
    """mm/s of E: the fastest E-only move that still enters at its own speed after an X/Y move
    (so its first step comes 1/r after the last X/Y step). Junction deviation: the 90 degree
    corner speed at the junction's acceleration (M204 R, limited by M201 X and E along the
    junction's half-way vector, 1/sqrt 2 on each); classic jerk: the E and X/Y jerks."""
    if pm.jerk is not None:
        return min(pm.jerk.e, pm.jerk.x, pm.jerk.y)
    a = min(e_move_accel(pm), pm.max_accel.x / SQRT_HALF, pm.max_accel.e / SQRT_HALF)
    return corner_speed(a, pm.junction_deviation)


def _jerk_junction(pm: PrinterModel, fa: float, prev, fb: float, cur) -> float:
    """Classic jerk: the junction speed planner.cpp gives a block of feed fb and axis speeds cur
    (X, Y, Z, E) after one of feed fa and axis speeds prev (the estimator's jerk_junction)."""
    j = pm.jerk
    jerks = (j.x, j.y, j.z, j.e)
    return es.jerk_junction(fa, prev, es.jerk_safe_speed(fa, prev, jerks), fb, cur,
                            es.jerk_safe_speed(fb, cur, jerks), jerks)


def _speeds(p: Piece, f: float):
    return (f * p.ux, f * p.uy, 0.0, f * p.e_per_mm)


def e_entry(pm: PrinterModel, rate: float, spm: float, p: Piece | None = None) -> float:
    """mm/s of E at which an E-only move at `rate` steps/s enters after the X/Y move p (its
    braking ends there): junction deviation min(vE, e_entry_limit); classic jerk planner.cpp's
    jerk junction."""
    ve = rate / spm
    if pm.jerk is None or p is None:
        return min(ve, e_entry_limit(pm))
    fa = feed_for(pm, p)
    return min(ve, _jerk_junction(pm, fa, _speeds(p, fa), ve, (0.0, 0.0, 0.0, ve)))


def next_entry(pm: PrinterModel, rate: float, spm: float, p: Piece | None = None, n: int = 0) -> float:
    """mm/s (of B's path) at which B, the move after an E-only stop of n steps at `rate` steps/s
    (E steps/mm spm), enters: see the module doc."""
    ve = rate / spm
    if pm.jerk is None:
        v = min(ve, junction_speed(piece_accel(pm, p), pm.junction_deviation,
                                   p.e_per_mm if p is not None else 0.0))
        return min(v, p.feed) if p is not None and p.feed > 0 else v
    q = p if p is not None else Piece(1.0, 0.0, 0.0, pm.max_feedrate.x, pm.steps_per_mm.x)
    fb = feed_for(pm, q)
    v = _jerk_junction(pm, ve, (0.0, 0.0, 0.0, ve), fb, _speeds(q, fb))
    ve_in = min(ve, e_entry_limit(pm))
    return min(v, math.sqrt(ve_in ** 2 + 2 * e_move_accel(pm) * n / spm))


def feed_for(pm: PrinterModel, p: Piece) -> float:
    """The piece's feed rate as Marlin runs it: the M203 limits of each axis."""
    f = p.feed
    for lim, u in ((pm.max_feedrate.x, p.ux), (pm.max_feedrate.y, p.uy),
                   (pm.max_feedrate.e, p.e_per_mm)):
        if u > 1e-12 and f * u > lim:
            f = lim / u
    return f


def _interval(rate: float) -> float:
    return TIMER_RATE / max(rate, 32.0)


def _block_span(count: int, nominal: int, initial: int, final: int, accel: int) -> float:
    """Seconds from a block's first step to its last, as Marlin's AVR stepper makes them
    (trapezoid of calculate_trapezoid_for_block, then stepper.cpp's acceleration, cruise and
    deceleration phases, no S-curve)."""
    return _block_times(count, nominal, initial, final, accel, -1)[0]


@functools.lru_cache(maxsize=4096)
def _block_times(count: int, nominal: int, initial: int, final: int, accel: int,
                 mark: int) -> tuple[float, float]:
    """(_block_span, seconds from the first step to step `mark`, 0-based; -1: none)."""
    ha = 0.5 / accel
    af = ha * (nominal ** 2 - initial ** 2)
    df = ha * (nominal ** 2 - final ** 2)
    a_st, d_st = math.ceil(af), math.floor(df)
    if count - a_st - d_st < 0:
        a_st = min(max(math.ceil((count + af - df) * 0.5), 0), count)
        d_st = count - a_st
    dec_after = count - d_st
    arate = accel * (1 << 24) / TIMER_RATE
    acc_rate = initial
    iv = _interval(initial)
    at, dt, t, t0, tm = iv, 0.0, 0.0, None, 0.0
    for done in range(1, count + 1):
        t += iv
        if t0 is None:
            t0 = t
        if done - 1 == mark:
            tm = t - t0
        if done >= count:
            break
        if done <= a_st:
            acc_rate = min(int(at * arate / (1 << 24)) + initial, nominal)
            iv = _interval(acc_rate)
            at += iv
        elif done > dec_after:
            s = int(dt * arate / (1 << 24))
            iv = _interval(max(acc_rate - s, final) if s < acc_rate else final)
            dt += iv
        else:
            iv = _interval(nominal)
    return (t - t0) / TIMER_RATE, tm / TIMER_RATE


def ramp_s(pm: PrinterModel, p: Piece, v_exit: float, v_entry: float) -> float:
    """Seconds a stop adds beyond its stillness: the move before braking from its feed to
    v_exit (the E block's entry, or 0 for a stop from rest) and the move after starting at
    v_entry, against cruising, by Marlin's AVR stepper arithmetic (module doc). Both sides are
    taken as long straight moves of the piece's direction, feed and k."""
    v = feed_for(pm, p)
    if v <= 0 or p.k <= 0:
        return 0.0
    fl = floor_rate(pm)
    nom = max(math.ceil(v * p.k), 1)
    acc = max(math.ceil(piece_accel(pm, p) * p.k), 1)
    fa = int(max(fl, math.ceil(nom * min(v_exit, v) / v)))
    ib = int(max(fl, math.ceil(nom * min(v_entry, v) / v)))
    if fa >= nom and ib >= nom:
        return 0.0
    need_a = max(0, math.floor((nom ** 2 - fa ** 2) / (2 * acc))) + 3
    need_b = max(0, math.ceil((nom ** 2 - ib ** 2) / (2 * acc))) + 3
    cost_a = _block_span(need_a, nom, nom, fa, acc) - (need_a - 1) / nom
    cost_b = _block_span(need_b, nom, ib, nom, acc) - (need_b - 1) / nom
    return max(0.0, cost_a + cost_b - 1 / nom)


def _rates(pm: PrinterModel, p: Piece, v_exit: float, v_entry: float):
    """(nominal, braking's final rate, start's initial rate, accel) in steps of p's leading axis."""
    v = feed_for(pm, p)
    fl = floor_rate(pm)
    nom = max(math.ceil(v * p.k), 1)
    acc = max(math.ceil(piece_accel(pm, p) * p.k), 1)
    fa = int(min(nom, max(fl, math.ceil(nom * min(v_exit, v) / v))))
    ib = int(min(nom, max(fl, math.ceil(nom * min(v_entry, v) / v))))
    return nom, fa, ib, acc


def _brake_s(nom: int, fa: int, acc: int) -> float:
    need = max(0, math.floor((nom ** 2 - fa ** 2) / (2 * acc))) + 3
    return _block_span(need, nom, nom, fa, acc) - (need - 1) / nom


def _chain_span(segs: list[tuple[int, int]], nom: int, initial: int, final: int,
                mark: int = -1) -> float | tuple[float, float]:
    """Seconds from the first step to the last of blocks run one after another (segs: (steps,
    accel steps/s^2) each, all at nominal rate nom), entering the first at `initial` and leaving
    the last at `final` steps/s: junction rates by the planner's passes (v^2 = v0^2 + 2 a d),
    each block by _block_span, and between two blocks one interval of the next one's initial
    rate. With mark (a step's index from the first, 0-based): (that, seconds to step mark)."""
    segs = [(c, a) for c, a in segs if c > 0]
    n = len(segs)
    fwd = [float(initial)] + [0.0] * n
    for j, (c, a) in enumerate(segs):
        fwd[j + 1] = min(float(nom), math.sqrt(fwd[j] ** 2 + 2 * a * c))
    bwd = [0.0] * n + [float(final)]
    for j in range(n - 1, -1, -1):
        c, a = segs[j]
        bwd[j] = min(float(nom), math.sqrt(bwd[j + 1] ** 2 + 2 * a * c))
    r = [max(1, math.ceil(min(f, b))) for f, b in zip(fwd, bwd)]
    r[0], r[-1] = initial, final
    t, tm, before = 0.0, 0.0, 0
    for j, (c, a) in enumerate(segs):
        if j:
            t += _interval(r[j]) / TIMER_RATE
        span, at = _block_times(c, nom, max(r[j], 1), max(r[j + 1], 1), a,
                                mark - before if 0 <= mark - before < c else -1)
        if 0 <= mark - before < c:
            tm = t + at
        t += span
        before += c
    return t if mark < 0 else (t, tm)


def _start_s(nom: int, ib: int, acc: int, first: tuple[int, int] | None = None) -> float:
    """A start from `ib` to the feed, beyond cruising; first: (steps, accel) of the piece right
    after the stop when its acceleration is its own (LIN_ADVANCE: the extra it carries)."""
    need = max(0, math.ceil((nom ** 2 - ib ** 2) / (2 * min(acc, first[1] if first else acc)))) + 3
    if first is None or first[0] >= need:
        a = first[1] if first is not None else acc
        need = max(0, math.ceil((nom ** 2 - ib ** 2) / (2 * a))) + 3
        return _block_span(need, nom, ib, nom, a) - (need - 1) / nom
    rest = need - first[0] + 3
    return _chain_span([first, (rest, acc)], nom, ib, nom) - (first[0] + rest - 1) / nom


@dataclass(frozen=True)
class RampStop:
    """One stop for chain_ramps: the move it is on (p: its braking), the piece the head goes on
    with (after, its length: its own acceleration for a start, None: p's), the speed the move
    before brakes to (v_exit: the E block's entry, 0 for a stop from rest) and the one after
    starts at (v_entry), and the path (mm) from the stop before it with nothing else stopping the
    head between (None: far, or not known: each side ramps in full)."""
    p: Piece
    v_exit: float
    v_entry: float
    gap: float | None = None
    after: Piece | None = None


def _first(pm: PrinterModel, s: RampStop, k: float):
    if s.after is None or s.after.length <= 0:
        return None
    return (max(1, round(s.after.length * k)), max(math.ceil(piece_accel(pm, s.after) * k), 1))


def _reaches(prev: RampStop, gap: float | None) -> bool:
    """The piece the head goes on with after `prev` runs to the next stop, `gap` mm on (within
    0.02 mm): then it is also the block that brakes into that stop."""
    return (gap is not None and prev.after is not None and prev.after.length > 0
            and prev.after.length >= gap - 0.02)


def chain_ramps(pm: PrinterModel, stops: list[RampStop]) -> list[float]:
    """Seconds each stop adds beyond its stillness, stops one after another along the path:
    between two stops closer than a full start and a full braking the head does not reach its
    feed, and the two share the gap's cost (the gap run as the piece after the first stop, at
    its own acceleration, then one block to the second stop, by _chain_span): the first stop
    takes the delay at the gap's halfway step, the second the rest (as a trace measures it)."""
    out = [0.0] * len(stops)
    rates = [_rates(pm, s.p, s.v_exit, s.v_entry) if feed_for(pm, s.p) > 0 and s.p.k > 0 else None
             for s in stops]
    firsts = [_first(pm, s, s.p.k) for s in stops]
    for i, r in enumerate(rates):
        if r is None:
            continue
        nom, fa, ib, acc = r
        out[i] -= 1 / nom
        prev = rates[i - 1] if i else None
        gap = stops[i].gap
        count = round(gap * stops[i].p.k) if gap is not None else None
        if prev is not None and count is not None and count >= 2:
            pnom, pfa, pib, pacc = prev
            f = firsts[i - 1]
            a0 = min(acc, f[1]) if f else acc
            # the piece after the stop before reaches this one (the gap is that one block): it
            # brakes into this stop at its own acceleration too (LIN_ADVANCE: cut for the extra
            # it carries; this stop's move, p, is the slicer's line without that extra)
            reach = _reaches(stops[i - 1], gap)
            bacc = a0 if f and reach else acc
            full = (max(0, math.ceil((nom ** 2 - pib ** 2) / (2 * a0)))
                    + max(0, math.floor((nom ** 2 - fa ** 2) / (2 * bacc))) + 6)
            if count < full:                     # the head does not reach its feed between
                segs = [f, (count - f[0], acc)] if f and not reach and f[0] < count else [(count, a0)]
                mid = count // 2
                span, t_mid = _chain_span(segs, nom, min(pib, nom), fa, mid)
                cost = span - (count - 1) / nom
                first = t_mid - mid / nom           # the delay halfway: the first stop's share
                out[i - 1] += first
                out[i] += cost - first
                continue
        if prev is not None:
            pnom, pfa, pib, pacc = prev
            out[i - 1] += _start_s(pnom, pib, pacc, firsts[i - 1]) if pib < pnom else 0.0
            f = firsts[i - 1]
            if f and _reaches(stops[i - 1], gap):
                acc = min(acc, f[1])             # braking in the piece after the stop before
        out[i] += _brake_s(nom, fa, acc) if fa < nom else 0.0
    if rates and rates[-1] is not None:
        nom, fa, ib, acc = rates[-1]
        out[-1] += _start_s(nom, ib, acc, firsts[-1]) if ib < nom else 0.0
    return [max(0.0, x) for x in out]
