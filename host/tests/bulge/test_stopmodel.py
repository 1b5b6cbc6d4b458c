"""The stock stop's rule from the printer model (issue 36): still_s / plan_stop and the
stop-and-start time (stopmodel) against figures measured in simulated stock Marlin 2.1.2.7 with
Marlin's defaults, an Ender-3's settings, classic jerk and LIN_ADVANCE (data/stops_sim.json:
read from step traces, not from this code)."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from click.testing import CliRunner

from bulgekit import machine
from bulgekit.bulge import api, stats, stopmodel
from bulgekit.bulge.fallback import Settings, StockStops, plan_stop, still_s
from bulgekit.bulge.stopmodel import Piece

SIM = json.loads((Path(__file__).resolve().parents[1] / "data" / "stops_sim.json").read_text())
EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
ENDER3 = machine.PRESETS["ender3"]
JERK = machine.PRESETS["marlin-classic-jerk"]


def model(run) -> machine.PrinterModel:
    pm = machine.PRESETS[run["printer"]]
    if run.get("linear_advance_k"):
        pm = replace(pm, linear_advance_k=run["linear_advance_k"])
    return pm


def wall_piece() -> Piece:
    w = SIM["wall"]
    return Piece(1.0, 0.0, w["e_per_mm"], w["feed_mm_s"], w["k"])


def test_two_printers_give_different_stops():
    p = wall_piece()
    # Marlin's defaults: the next move enters at the E speed, first step after 1/120 s
    marlin = plan_stop(100, 93, 0.1, k=80, printer=machine.MARLIN, nxt=p, here=p)
    # classic jerk: it enters at the X jerk, 10 mm/s, 1.25 ms after the last E step: a slower rate
    jerk = plan_stop(100, 93, 0.1, k=80, printer=JERK, nxt=p, here=p)
    assert (marlin.n, marlin.rate) == (6, 60) and marlin.start == pytest.approx(1 / 120)
    assert (jerk.n, jerk.rate) == (6, 55) and jerk.start == pytest.approx(1 / 800)
    assert marlin.feed(93) != jerk.feed(93)
    # an Ender-3 holds the same (its E speed is under both corner speeds) but brakes and
    # starts at 500 mm/s^2: some 58 ms more per stop on the wall
    ender = plan_stop(100, 93, 0.1, k=80, printer=ENDER3, nxt=p, here=p)
    assert (ender.n, ender.rate) == (6, 60)
    assert ender.ramp > 10 * marlin.ramp > 0


def test_marlin_preset_is_todays_rule():
    """Marlin's defaults give the numbers the rule gave before it read a printer model."""
    v_jd = (3000 * 0.013 / (2 ** 0.5 - 1)) ** 0.5
    for rate in (60, 143, 287, 478, 900):
        v = min(rate / 93, v_jd)
        iv = stopmodel.avr_interval_s     # the E steps as the AVR timer makes them
        old = iv(max(rate, 120)) + 5 * iv(rate) + 1 / max(120, v * 80)
        assert still_s(6, rate, 93, 80, machine.MARLIN) == old
        assert still_s(6, rate, 93, 80) == old
    assert stopmodel.e_entry_limit(machine.MARLIN) == v_jd


@pytest.mark.parametrize("run", SIM["wall"]["runs"], ids=lambda r: f"{r['printer']}{'-la' if r.get('linear_advance_k') else ''}-{r['rate']}")
def test_wall_stillness_and_stop_and_start_as_simulated(run):
    w, p, pm = SIM["wall"], wall_piece(), model(run)
    rule = still_s(w["n"], run["rate"], w["e_steps"], w["k"], pm, p) * 1000
    # the AVR timer's table (60 steps/s: intervals 0.07 ms long each, +0.37 ms) is in the rule
    assert rule == pytest.approx(run["still_ms"], abs=0.1)
    ramp = stopmodel.ramp_s(pm, p, stopmodel.e_entry(pm, run["rate"], w["e_steps"], p),
                            stopmodel.next_entry(pm, run["rate"], w["e_steps"], p, w["n"])) * 1000
    sim = run["added_ms"] - run["still_ms"]
    assert ramp == pytest.approx(sim, rel=0.10)


def test_classic_jerk_next_move_starts_at_its_jerk():
    p = wall_piece()
    # along X the X jerk; along a diagonal each axis may jump 10 mm/s: 14.1 mm/s on the path
    assert stopmodel.next_entry(JERK, 60, 93, p, 6) == pytest.approx(10.0)
    diag = Piece(2 ** -0.5, 2 ** -0.5, 0.0374, 40.0, 80 * 2 ** -0.5)
    assert stopmodel.next_entry(JERK, 60, 93, diag, 6) == pytest.approx(10 * 2 ** 0.5)
    # capped by what the E move lets the next one reach at M204 R over its 6 steps
    slow = replace(JERK, retract_accel=100.0)
    assert stopmodel.next_entry(slow, 60, 93, p, 6) == pytest.approx(((60 / 93) ** 2 + 2 * 100 * 6 / 93) ** 0.5)


def test_lin_advance_cuts_the_next_moves_acceleration():
    la = replace(machine.MARLIN, linear_advance_k=0.22)
    p = wall_piece()
    e_jerk = (0.013 * 0.5 ** 0.5 / (1 - 0.5 ** 0.5) * 10000) ** 0.5
    assert stopmodel.piece_accel(la, p) == pytest.approx(e_jerk / (0.22 * 0.0374))
    assert stopmodel.piece_accel(machine.MARLIN, p) == 3000.0
    # the stillness is the same (an E-only move has no advance), the ramps longer
    assert still_s(6, 60, 93, 80, la, p) == still_s(6, 60, 93, 80, machine.MARLIN, p)


def test_stats_time_every_marlin_model_by_its_stepper():
    """The default model too (its statistics' hashes were made again for it); another firmware
    is timed as v/a at its model's acceleration."""
    assert stats.timed_model(machine.MARLIN) is machine.MARLIN and stats.timed_model(None) is machine.MARLIN
    assert stats.timed_model(ENDER3) is ENDER3
    prusa = replace(machine.MARLIN, firmware="prusa", accel=1250.0)
    assert stats.timed_model(prusa) is None and stats.accel_of(prusa) == 1250.0


@pytest.fixture(scope="module")
def cylinder_maps(tmp_path_factory):
    """The example cylinder's maps for the dwells in the data (the map is the printer's own
    business only through the dwell)."""
    out = {}
    for d in sorted({r["dwell"] for r in SIM["cylinder"]["runs"]}):
        o = tmp_path_factory.mktemp(f"cyl{d}")
        from bulgekit.cli import main
        r = CliRunner().invoke(main, ["build", str(EXAMPLES / "cylinder40x20.gcode"),
                                      "--placement", str(EXAMPLES / "placement.toml"),
                                      "--no-preview", "-q", "--dwell", str(d), "-o", str(o)])
        assert r.exit_code == 0, r.output
        out[d] = (o / "cylinder40x20.bkm").read_bytes()
    return out


@pytest.mark.parametrize("run", SIM["cylinder"]["runs"],
                         ids=lambda r: f"{r['printer']}{'-la' if r.get('linear_advance_k') else ''}-{r['dwell']}-{r['first']}")
def test_sliced_cylinder_as_simulated(run, cylinder_maps, tmp_path):
    """The host's stock file for the printer: its stops' stillness as the rule puts it, and the
    statistics' stop-and-start time per stop (gaps between stops from the planner's run) within
    10 % of the simulated mean."""
    pm = model(run)
    timers = []

    def on_plan(p):
        timers.append(stats.StopTimer(p, printer=pm))
        return timers[-1]
    s = Settings(dwell_ms=run["dwell"])
    res = api.fallback_gcode(EXAMPLES / "cylinder40x20.gcode", cylinder_maps[run["dwell"]],
                             tmp_path / "stock.gcode", s, allow_unreached=True,
                             stops=StockStops("move", None, None, pm), _on_plan=on_plan)
    st = stats.Stats([], 0, 0, 0, 0, 0, s, printer=pm, stock=res.stock, gaps=timers[-1].gaps)
    lo, hi = run["first"], run["first"] + run["count"]
    ramps = st.stock_ramps()[lo:hi]
    stills = [w.still for w in res.stock.written[lo:hi]]
    assert len(ramps) == run["count"]
    assert 1000 * sum(stills) / len(stills) == pytest.approx(run["still_ms_mean"], abs=0.45)
    assert 1000 * sum(ramps) / len(ramps) == pytest.approx(run["ramp_ms_mean"], rel=0.10)


def test_avr_timer_table_and_its_16_bit_wrap():
    """Marlin's AVR calc_timer_interval: exact at the table's points, interpolated between, and
    at 38-39 steps/s the slow table's product wraps at 16 bits. Simulated on stock Marlin 2.1.2.7
    (Marlin's defaults, E 93; the calibration piece's dwell column, docs/verification/
    marlin-simulation.md): 8 steps at 38 steps/s held the head 231.28 ms (1/r says 200.9),
    7 steps at 45 steps/s 151.04 ms, 6 at 60 steps/s 100.37 ms."""
    t = stopmodel.avr_ticks
    assert [t(r) for r in (32, 40, 48, 120, 2080)] == [62500, 50000, 41666, 16666, 961]
    assert (t(37), t(38), t(39), t(40)) == (54688, 61317, 59755, 50000)
    assert t(20) == 62500                        # the slowest the timer makes
    assert still_s(8, 38, 93) * 1000 == pytest.approx(231.28, abs=0.05)
    assert still_s(7, 45, 93) * 1000 == pytest.approx(151.04, abs=0.05)
    assert still_s(6, 60, 93) * 1000 == pytest.approx(100.37, abs=0.05)
    # the writer keeps off the wrap: 200 and 150 ms stops of the calibration piece's column
    for ms in (150, 200):
        s = plan_stop(ms, 93.0, 0.1)
        assert s.kind == "move" and s.rate not in (38, 39) and abs(s.still * 1000 - ms) < 1


# LIN_ADVANCE K 0.22, 63 ms stops (layers 7-14): time each stop added beyond its stillness, ms, read
# from the step trace (docs/verification/marlin-simulation.md, "Calibration piece and band totals";
# run tr-la-move-7-14), for runs of stops 0.97 mm apart on the round wall: there the piece after
# one stop, which carries its extra, runs to the next stop and brakes into it at its own, cut
# acceleration (the model took the slicer line's, and was short by 3.5-6.3 ms at such stops)
LA_RUNS = {30: 10.41, 31: 15.45, 32: 16.14, 33: 14.70, 34: 15.94, 113: 10.96, 114: 16.87,
           117: 11.15, 118: 16.42, 119: 11.04, 120: 15.17}


def test_lin_advance_stops_in_a_row_brake_in_the_piece_that_carries_the_extra(cylinder_maps, tmp_path):
    pm = replace(machine.PRESETS["marlin"], linear_advance_k=0.22)
    timers = []

    def on_plan(p):
        timers.append(stats.StopTimer(p, printer=pm))
        return timers[-1]
    s = Settings(dwell_ms=100)
    res = api.fallback_gcode(EXAMPLES / "cylinder40x20.gcode", cylinder_maps[100],
                             tmp_path / "stock.gcode", s, allow_unreached=True,
                             stops=StockStops("move", None, None, pm), _on_plan=on_plan)
    st = stats.Stats([], 0, 0, 0, 0, 0, s, printer=pm, stock=res.stock, gaps=timers[-1].gaps)
    ramps = st.stock_ramps()
    for i, sim in LA_RUNS.items():
        assert 1000 * ramps[i] == pytest.approx(sim, abs=2.5), i
