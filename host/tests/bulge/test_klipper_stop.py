"""Klipper-shaped stops (issue 36): the stock writer's E-only moves for a Klipper printer.

Each stop's planned stillness is checked here independently of klipper_stop's closed forms:
the E-only move's time from Klipper's trapezoid as its documentation states it (docs/Kinematics.md:
constant acceleration to a cruise speed and back, from rest to rest, since Klipper's junction
with a move of E alone is zero; the extrude-only limits default to max_velocity and max_accel
times 4 nozzle^2 / filament area, docs/Config_Reference.md [extruder]); the head's last step
before the stop and first step after it by stepping the motors through the deceleration and
the acceleration in 1 us steps (a step where a motor's position crosses the middle between two
step positions, klippy/chelper/itersolve.c). Measured in Klipper's batch mode in
docs/verification/marlin-simulation.md, "Stops exact on Klipper".
"""
import math
import re

import pytest

from bulgekit import machine
from bulgekit.bulge import klipper_stop, mapformat
from bulgekit.bulge.fallback import Settings, StockStops, rewrite

CFG = """[printer]
kinematics: {kin}
max_velocity: {v}
max_accel: {a}
square_corner_velocity: 5
[stepper_x]
rotation_distance: 40
microsteps: 16
[stepper_y]
rotation_distance: 40
microsteps: 16
[stepper_z]
rotation_distance: 8
microsteps: 16
[extruder]
rotation_distance: {rd}
microsteps: 16
nozzle_diameter: 0.400
filament_diameter: 1.750
"""
# generic RAMPS cartesian (E 93) and a Voron-like CoreXY (E 415), default cross-section
CONFIGS = {"ramps": dict(kin="cartesian", v=300, a=3000, rd=34.408602),
           "corexy": dict(kin="corexy", v=350, a=4000, rd=7.710843)}


@pytest.fixture(params=sorted(CONFIGS))
def model(request, tmp_path):
    p = tmp_path / "printer.cfg"
    p.write_text(CFG.format(**CONFIGS[request.param]))
    m = machine.load(str(p))
    assert m.firmware == "klipper" and m.kinematics == CONFIGS[request.param]["kin"]
    return m


def bmap(points, lh=0.3):
    return mapformat.decode_map(mapformat.encode_map([(0.3, points)], layer_height_mm=lh))


# a wall from X100 Y100: along +X, then a diagonal, then along +Y; points on pieces, one at a
# move's end (its next move is the next line: the lead is known there only) and one at a start
WALL = ("G90\nM83\nG1 X100 Y100 Z0.3 F1200\n{pre};TYPE:External perimeter\nG1 F1800\n"
        "G1 X110 Y100 E0.45\nG1 X117 Y104.3 E0.37\nG1 X117 Y112 E0.36\nG1 X117 Y120 E0.36\n")
POINTS = [(102.3, 100.0), (106.71, 100.0), (110.0, 100.0), (113.2, 101.97), (117.0, 108.4),
          (117.0, 112.0), (117.0, 116.05)]


def written(model, dwell=100, extra=0.1, pre="", points=POINTS):
    text = WALL.format(pre=pre)
    out = "".join(rewrite(text.splitlines(keepends=True), bmap(points),
                          Settings(dwell_ms=dwell, extra_e=extra), stops=StockStops(printer=model)))
    return text, [l for l in out.splitlines() if l and not l.startswith("; bulgekit")]


def _words(line):
    return {k: float(v) for k, v in re.findall(r"([XYZEF])([-+]?\d*\.?\d+)", line.split(";")[0])}


STOP_RX = re.compile(r"^G1 E[\d.]+ F\d+\.\d{3}$")      # the writer's stop move


def moves(lines):
    """(kind, start, end, e, f) of each G1: 'xy', 'e' (E alone) or 'stop' (the writer's E-only
    stop move), positions absolute."""
    x = y = z = 0.0
    f = None
    out = []
    for ln in lines:
        if not ln.startswith("G1"):
            continue
        w = _words(ln)
        f = w.get("F", f)
        nx, ny, nz = w.get("X", x), w.get("Y", y), w.get("Z", z)
        if (nx, ny, nz) != (x, y, z):
            out.append(("xy", (x, y, z), (nx, ny, nz), w.get("E", 0.0), f))
        elif "E" in w:
            out.append(("stop" if STOP_RX.match(ln) else "e", (x, y, z), (x, y, z), w["E"], f))
        x, y, z = nx, ny, nz
    return out


def e_only_s(model, d, f):
    """Klipper's trapezoid for d mm of E alone at F f, rest to rest, from the documented limits."""
    area = math.pi * (model.filament_diameter / 2) ** 2
    ratio = 4 * model.nozzle_diameter ** 2 / area
    v_max, a = model.max_feedrate.x * ratio, model.max_accel.x * ratio   # [printer], not M204
    assert model.accel * (1 - model.minimum_cruise_ratio) >= a     # the cruise ratio binds not
    v = min(f / 60, v_max, math.sqrt(a * d))         # the peak a triangle of d would reach
    t_acc = v / a
    cruise = d - v * t_acc                          # accel and decel each take v^2 / 2a
    return 2 * t_acc + cruise / v


def motors(model, x, y):
    """Steps (float) of the X/Y motors at (x, y)."""
    k = model.steps_per_mm.x
    if model.kinematics == "corexy":
        return ((x + y) * k, (x - y) * k)
    return (x * k, y * k)


def edge_s(model, at, unit, accel, sign):
    """Seconds from standstill at `at` back to the last motor step of the move arriving along
    unit (sign -1), or on to the first step leaving along it (sign +1): stepped in 1 us."""
    q0 = [math.floor(q - 0.5) for q in motors(model, at[0], at[1])]
    t = 0.0
    while t < 0.02:
        t += 1e-6
        s = sign * accel * t * t / 2
        q = motors(model, at[0] + unit[0] * s, at[1] + unit[1] * s)
        if [math.floor(v - 0.5) for v in q] != q0:
            return t
    raise AssertionError("no step within 20 ms")


def unit(p0, p1):
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    n = math.hypot(dx, dy)
    return dx / n, dy / n


def stops_of(model, lines, accel=None):
    """(E, F, head-still seconds) of every stop move, from the G-code alone."""
    accel = model.accel if accel is None else accel
    mv = moves(lines)
    out = []
    for i, (kind, p0, p1, e, f) in enumerate(mv):
        if kind != "stop":
            continue
        before = next(m for m in reversed(mv[:i]) if m[0] == "xy")
        j, after = next((j, m) for j, m in enumerate(mv) if j > i and m[0] == "xy")
        assert before[2] == p0 == after[1]
        tail = edge_s(model, p0, unit(before[1], before[2]), accel, -1)
        lead = edge_s(model, p0, unit(after[1], after[2]), accel, +1)
        # E-only moves between (a retract): the head stands during them too
        between = sum(e_only_s(model, abs(m[3]), m[4]) for m in mv[i + 1:j])
        out.append((e, f, tail + e_only_s(model, e, f) + between + lead))
    return out


@pytest.mark.parametrize("dwell", [100, 63, 25])
def test_each_stop_holds_the_head_for_the_dwell(model, dwell):
    _, lines = written(model, dwell)
    got = stops_of(model, lines)
    assert len(got) == len(POINTS)
    for e, f, still in got:
        assert still == pytest.approx(dwell / 1000, abs=2e-5)      # 0.02 ms
        assert f < 60 * model.klipper_extrude_only[0]


def test_long_stops_lay_the_whole_extra_and_the_pieces_none(model):
    text, lines = written(model, 100)
    assert [e for e, _, _ in stops_of(model, lines)] == [0.1] * len(POINTS)
    src_e = sum(m[3] for m in moves(text.splitlines()))
    assert sum(m[3] for m in moves(lines)) == pytest.approx(src_e + 0.1 * len(POINTS), abs=1e-4)
    # the pieces lay their own filament: E per mm as in the source
    for kind, p0, p1, e, _ in moves(lines):
        if kind == "xy" and e > 0 and p0[:2] != (100, 100):
            assert e / math.dist(p0, p1) == pytest.approx(0.045, abs=0.0025)


def test_short_stops_lay_what_their_time_allows(model):
    # 15 ms: tail and lead take up to ~6 ms, the E move ~9-13 ms; a_e (T/2)^2 at most
    _, lines = written(model, 15)
    v, a_e = model.klipper_extrude_only
    for e, f, still in stops_of(model, lines):
        t_e = e_only_s(model, e, f)
        assert 0 < e <= a_e * (t_e / 2) ** 2 + 1e-9
        assert still == pytest.approx(0.015, abs=2e-5)


def test_no_piece_exceeds_the_cross_section_limit_and_e_is_kept(model):
    # extra 0.5 mm at 15 ms: the stop lays ~0.02 mm, the rest would be 0.48 mm on a 0.3 mm piece
    # (1.6 mm^2 against the default 0.64): it is spread over the pieces after
    pts = [(109.7, 100.0), (113.2, 101.97)]
    text, lines = written(model, 15, extra=0.5, points=pts)
    area = math.pi * (model.filament_diameter / 2) ** 2
    ratio = 4 * model.nozzle_diameter ** 2 / area
    for kind, p0, p1, e, _ in moves(lines):
        if kind == "xy" and e > 0:
            # extruder.py check_move: allowed if E/length <= ratio or E <= nozzle x ratio
            assert e / math.dist(p0, p1) <= ratio or e <= model.nozzle_diameter * ratio
    src_e = sum(m[3] for m in moves(text.splitlines()))
    assert sum(m[3] for m in moves(lines)) == pytest.approx(src_e + 0.5 * len(pts), abs=1e-4)


def test_the_files_accel_sets_the_head_terms(model):
    # Klipper's M204 S (and SET_VELOCITY_LIMIT ACCEL) set max_accel; M204 P alone is refused
    for pre, acc in (("M204 S1500\n", 1500), ("SET_VELOCITY_LIMIT ACCEL=2000\n", 2000),
                     ("M204 P1200 T2500\n", 1200), ("M204 P1200\n", None)):
        _, lines = written(model, 100, pre=pre)
        for _, _, still in stops_of(model, lines, acc):
            assert still == pytest.approx(0.1, abs=2e-5), pre


def test_a_retract_after_a_stop_counts_in_its_time(model):
    # a point at the wall's end; the slicer retracts, travels and unretracts: Klipper plans the
    # retract as another move of E alone, during which the head still stands
    text = WALL.format(pre="") + "G1 E-0.8 F2100\nG1 X130 Y130 F7800\nG1 E0.8 F2100\nG1 X140 Y130 E0.45 F1800\n"
    out = "".join(rewrite(text.splitlines(keepends=True), bmap([(117.0, 120.0)]),
                          Settings(dwell_ms=100), stops=StockStops(printer=model)))
    lines = [l for l in out.splitlines() if l and not l.startswith("; bulgekit")]
    (got,) = stops_of(model, lines)
    assert got[2] == pytest.approx(0.1, abs=2e-5)


def test_klipper_trapezoid_matches_the_module(model):
    p = klipper_stop.KlipperParams.from_model(model)
    for d, f in ((0.1, 60.0), (0.1, 300.0), (0.02, 200.0), (0.05, 6000.0)):
        assert klipper_stop.e_move_s(p, d, f / 60) == pytest.approx(e_only_s(model, d, f), rel=1e-12)


def test_marlin_model_keeps_marlins_form():
    # any other firmware: the Marlin form (whole E steps at the rate rule), as without a model
    text = WALL.format(pre="")
    a = "".join(rewrite(text.splitlines(keepends=True), bmap(POINTS), Settings(), stops=StockStops()))
    b = "".join(rewrite(text.splitlines(keepends=True), bmap(POINTS), Settings(),
                        stops=StockStops(printer=machine.preset("marlin"))))
    assert a == b
