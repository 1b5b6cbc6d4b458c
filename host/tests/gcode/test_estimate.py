"""The print-time estimator on cases computed by hand from the planner's formulas."""
from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from bulgekit.gcode import estimate as es
from bulgekit.cli import main

VMIN = 0.05                 # MINIMUM_PLANNER_SPEED: where every stop starts and ends


def machine(**kw):
    base = dict(accel=1000.0, travel_accel=1000.0, retract_accel=1000.0, lookahead=None)
    base.update(kw)
    return es.Machine(**base)


def run(text, **kw):
    return es.estimate_lines(text.strip().splitlines(), machine(**kw))


def trapezoid(L, v, a, v0=VMIN, v1=VMIN):
    """Time of one block: accelerate from v0, cruise at v (or less), brake to v1."""
    vc = min(v, math.sqrt((2 * a * L + v0 ** 2 + v1 ** 2) / 2))
    d = L - (vc ** 2 - v0 ** 2) / (2 * a) - (vc ** 2 - v1 ** 2) / (2 * a)
    return (vc - v0) / a + d / vc + (vc - v1) / a


def test_one_move_trapezoid():
    r = run("G1 X100 F6000")                 # 100 mm at 100 mm/s, 5 mm to reach it at 1000 mm/s^2
    assert r.total_s == pytest.approx(trapezoid(100, 100, 1000), rel=1e-9)
    assert r.total_s == pytest.approx(1.1, abs=1e-3)


def test_one_move_triangle():
    r = run("G1 X4 F6000")                   # too short to reach 100 mm/s
    vp = math.sqrt((2 * 1000 * 4 + 2 * VMIN ** 2) / 2)
    assert r.blocks["cruise_speed"][0] == pytest.approx(vp)
    assert r.total_s == pytest.approx(2 * (vp - VMIN) / 1000, rel=1e-9)


def test_collinear_junction_is_the_slower_speed():
    r = run("G1 X50 F6000\nG1 X100 F3000")
    b = r.blocks
    assert b["exit_speed"][0] == pytest.approx(50.0) and b["entry_speed"][1] == pytest.approx(50.0)
    expect = trapezoid(50, 100, 1000, VMIN, 50) + trapezoid(50, 50, 1000, 50, VMIN)
    assert r.total_s == pytest.approx(expect, rel=1e-9)


def test_right_angle_junction_deviation():
    r = run("G1 X50 F6000\nG1 Y50")
    # cos(theta) = 0, sin(theta/2) = sqrt(1/2): v^2 = a * JD * s / (1 - s)
    s = math.sqrt(0.5)
    vj = math.sqrt(1000 * 0.013 * s / (1 - s))
    assert r.blocks["entry_speed"][1] == pytest.approx(vj, rel=1e-9)
    assert vj == pytest.approx(5.60, abs=0.01)


def test_junction_acceleration_limited_by_axis():
    # X max accel 200: along the junction vector (-1, 1)/sqrt2 the limit is 200 * sqrt2
    m_acc = es._axes(200, 3000, 100, 10000)
    r = run("G1 X50 F6000\nG1 Y50", max_accel=m_acc)
    s = math.sqrt(0.5)
    aj = min(1000, 200 * math.sqrt(2))
    assert r.blocks["entry_speed"][1] == pytest.approx(math.sqrt(aj * 0.013 * s / (1 - s)), rel=1e-9)
    # and the X move itself accelerates at 200
    assert r.blocks["accel"][0] == pytest.approx(200)


def test_small_segment_arc_limit():
    # 0.1 mm moves turning by 30 degrees (JD_HANDLE_SMALL_SEGMENTS: under 1 mm, more than 135
    # degrees between -u_prev and u): the arc limit v^2 = L a / theta is below the JD value
    turn = math.radians(30)
    text = f"G1 X0.1 F6000\nG1 X{0.1 + 0.1 * math.cos(turn):.9f} Y{0.1 * math.sin(turn):.9f}"
    r = run(text)
    cos = -math.cos(turn)                    # between -u_prev and u
    s = math.sqrt(0.5 * (1 - cos))
    theta = math.acos(-cos)                  # the firmware's table is within 0.01 rad of it
    assert 0.1 * 1000 / theta < 1000 * 0.013 * s / (1 - s)          # the arc limit is the one that acts
    assert r.blocks["entry_speed"][1] == pytest.approx(math.sqrt(0.1 * 1000 / theta), rel=0.01)
    assert es._jd_lut_acos_neg(np.array([cos]))[0] == pytest.approx(theta, abs=0.01)
    assert es._jd_lut_acos_neg(np.array([-0.999999]))[0] < 0.002    # straight on: no limit


def test_reversal_stops():
    r = run("G1 X10 F6000\nG1 X0")
    assert r.blocks["entry_speed"][1] == pytest.approx(VMIN)


def test_retraction_uses_retract_accel_and_e_limit():
    r = run("M83\nG1 E-1 F2100", retract_accel=500.0)
    b = r.blocks
    assert b["length"][0] == pytest.approx(1.0)
    assert b["nominal_speed"][0] == pytest.approx(25.0)          # M203 E 25 caps F2100 (35 mm/s)
    assert b["accel"][0] == pytest.approx(500.0)
    assert r.total_s == pytest.approx(trapezoid(1.0, 25.0, 500.0), rel=1e-9)


def test_z_move_limited_by_axis_accel_and_feedrate():
    r = run("G1 Z1 F600")                    # 10 mm/s asked, Z max 5 mm/s, Z max accel 100
    b = r.blocks
    assert b["nominal_speed"][0] == pytest.approx(5.0) and b["accel"][0] == pytest.approx(100.0)
    assert r.total_s == pytest.approx(trapezoid(1.0, 5.0, 100.0), rel=1e-9)


def test_dwell_adds_time_and_stops_the_planner():
    r = run("G1 X50 F6000\nG4 P500\nG1 X100")
    assert r.dwell_s == pytest.approx(0.5)
    assert r.blocks["exit_speed"][0] == pytest.approx(VMIN) and r.blocks["entry_speed"][1] == pytest.approx(VMIN)
    assert r.total_s == pytest.approx(0.5 + 2 * trapezoid(50, 100, 1000), rel=1e-9)


def test_relative_and_absolute_agree():
    a = run("G90\nM82\nG1 X10 Y5 E1 F3000\nG1 X20 Y5 E2")
    b = run("G91\nM83\nG1 X10 Y5 E1 F3000\nG1 X10 Y0 E1")
    assert a.total_s == pytest.approx(b.total_s, rel=1e-12)
    assert es.deposited_filament(a) == pytest.approx(2.0)


def test_g90_makes_e_absolute_again():
    # Marlin's G90 clears every relative flag, E's too
    r = run("M83\nG90\nG1 X10 E1 F3000\nG1 X20 E1")
    assert r.blocks["de"].tolist() == [1.0, 0.0]     # E1 again: no filament on the second move


def test_tiny_moves_carry_their_distance():
    # 0.05 mm at 80 steps/mm = 4 steps < 6: dropped, its distance goes to the next move
    r = run("G1 X0.05 F3000\nG1 X10.05")
    assert len(r.blocks) == 1 and r.blocks["length"][0] == pytest.approx(10.05)


def test_width_mode_speed_from_the_rate():
    area = math.pi * 1.75 ** 2 / 4
    e08 = 0.8 * 0.2 * 10 / area                       # 10 mm of a 0.8 mm line at 0.2 mm layers
    e01 = 0.1 * 0.2 * 10 / area
    r = run(f"M83\nM723 S1 Q8 D1.75 H0.2 L5 U150\nG1 X10 E{e08:.6f} F600\nG1 X20 E{e01:.6f}\n"
            f"G1 X30 W0.8\nG1 X40 F3000\nM723 S0\nG1 X50 E{e08:.6f} F600")
    v = r.blocks["nominal_speed"]
    assert v[0] == pytest.approx(8 / (0.8 * 0.2), rel=1e-5)      # v = q / (W H) = 50 mm/s
    assert v[1] == pytest.approx(150.0)                           # 400 mm/s capped at U
    assert v[2] == pytest.approx(50.0, rel=1e-9)                  # a W word: the same width
    assert r.blocks["de"][2] == pytest.approx(e08, rel=1e-9)
    assert v[3] == pytest.approx(50.0)                            # travel keeps its F
    assert v[4] == pytest.approx(10.0)                            # mode off: F600 again


def test_width_mode_scales_with_m220():
    area = math.pi * 1.75 ** 2 / 4
    e = 0.8 * 0.2 * 10 / area
    r = run(f"M83\nM220 S50\nM723 S1 Q8 D1.75\nG1 X10 E{e:.6f} F600")
    assert r.blocks["nominal_speed"][0] == pytest.approx(25.0, rel=1e-5)


def test_lookahead_window_limits_speed_on_short_segments():
    text = "G1 X0 F6000\n" + "\n".join(f"G1 X{0.2 * i:.1f}" for i in range(1, 201))
    full = run(text, lookahead=None)
    buf = run(text, lookahead=16)
    assert full.blocks["cruise_speed"].max() == pytest.approx(100.0)
    # a block may enter no faster than the 14 blocks it sees can brake: v^2 = vmin^2 + 2 a (14 x 0.2)
    v = math.sqrt(VMIN ** 2 + 2 * 1000 * 14 * 0.2)
    assert buf.blocks["entry_speed"][100] == pytest.approx(v, rel=1e-9)
    assert buf.total_s > full.total_s * 1.2


def test_classic_jerk_junction():
    r = run("G1 X50 F6000\nG1 Y50", jerk=es._axes(10, 10, 0.4, 5))
    assert r.blocks["entry_speed"][1] == pytest.approx(10.0, rel=1e-9)


def test_e_rate_share_by_hand():
    # one extruding move at 50 mm/s from rest: the rate is within 5 % while v is in [47.5, 52.5]
    r = run("M83\nG1 X100 E5 F3000")
    k = 5 / 100
    t_ramp_in = 2 * (50 - 47.5) / 1000
    b = r.blocks
    t_total = b["t_accel"][0] + b["t_cruise"][0] + b["t_decel"][0]
    share = es.e_rate_share(r, ref=k * 50)
    assert share == pytest.approx((b["t_cruise"][0] + t_ramp_in) / t_total, rel=1e-9)
    assert es.e_rate_share(r, ref=k * 50, cruise_only=True) == 1.0
    assert es.e_rate_share(r) == pytest.approx(share)            # median rate = the cruise rate


def test_features_and_layers():
    r = run(";LAYER:0\n;TYPE:wall\nG1 X10 E1 F600\n;TYPE:mid-line\nG1 X20 E1\n;LAYER:1\nG1 X30 E1")
    names = [r.features[i] for i in r.blocks["feature"]]
    assert names == ["wall", "mid-line", "mid-line"] and r.blocks["layer"].tolist() == [0, 0, 1]
    assert sum(r.by_feature.values()) == pytest.approx(r.total_s)


def test_file_limits_only_when_asked():
    text = "M204 P500 T500\nG1 X100 F6000"
    assert run(text).total_s == pytest.approx(trapezoid(100, 100, 1000), rel=1e-9)
    assert run(text, honour_file_limits=True).total_s == pytest.approx(trapezoid(100, 100, 500), rel=1e-9)


def test_bad_line_names_file_and_line(tmp_path):
    p = tmp_path / "bad.gcode"
    p.write_text("G1 X10 F600\nG1 Xabc\n")
    # (the words read as every command reads them: gcode.parse_words's message)
    with pytest.raises(es.EstimateError, match=r"bad\.gcode:2: unparsable value 'Xabc' in 'Xabc'"):
        es.estimate_file(p)
    r = CliRunner().invoke(main, ["estimate", str(p)])
    assert r.exit_code != 0 and "bad.gcode:2" in r.output


def test_cli(tmp_path):
    p = tmp_path / "a.gcode"
    p.write_text(";TYPE:wall\nG1 X100 F6000\n")
    r = CliRunner().invoke(main, ["estimate", str(p), "--accel", "1000", "--travel-accel", "1000",
                                  "--lookahead", "0"])
    assert r.exit_code == 0, r.output
    assert "0h 00m 01.1s" in r.output and "wall" in r.output


@pytest.mark.parametrize("name, prusa_s", [("prusa_cyl.gcode", 15 * 60 + 8), ("prusa_cyl_m83.gcode", 15 * 60 + 21)])
def test_agrees_with_prusaslicer_in_classic_jerk(data_dir, name, prusa_s):
    """PrusaSlicer 2.5 estimates in classic-jerk mode with the limits in its config block
    (machine_limits_usage = time_estimate_only; normal mode = the first values): its
    '; estimated printing time (normal mode)' line is prusa_s. Ours with the same limits."""
    text = (data_dir / name).read_text()
    assert f"estimated printing time (normal mode) = {prusa_s // 60}m {prusa_s % 60}s" in text
    assert "; machine_max_jerk_x = 10,10" in text and "; machine_max_acceleration_extruding = 1500," in text
    m = es.Machine(accel=1500, travel_accel=1500, retract_accel=1500, max_accel=es._axes(9000, 9000, 500, 10000),
                   max_feedrate=es._axes(500, 500, 12, 120), jerk=es._axes(10, 10, 0.2, 2.5), lookahead=None)
    r = es.estimate_file(data_dir / name, m)
    assert r.total_s == pytest.approx(prusa_s, rel=0.01)


# -- moves of E alone (issue 25: stops in stock files) -------------------------------------

def test_slow_e_only_move_follows_the_minimum_rate_rule():
    # 9 steps at 93 steps/mm, F61.5: ceil(61.5 / 60 x 93) = 96 steps/s, under Marlin's 120:
    # 1/120 + 8/96 s (the head stands still 1/120 s longer: the next block's first step)
    r = es.estimate_lines(["M83", "M92 E93", "G1 E0.0968 F61.5"], machine())
    assert r.total_s == pytest.approx(1 / 120 + 8 / 96, rel=1e-12)
    # at 500 steps/mm the same move is 48 steps at 513 steps/s: a trapezoid
    r = es.estimate_lines(["M83", "M92 E500", "G1 E0.0968 F61.5"], machine())
    assert r.total_s == pytest.approx(trapezoid(0.0968, 61.5 / 60, 1000.0), rel=1e-9)


def test_e_only_steps_count_from_the_planners_position():
    # E0.07 at 93 steps/mm is 6.51 steps: 6 or 7 whole steps by the fraction carried from before
    def stop_time(e0):
        r = es.estimate_lines(["M83", "M92 E93", f"G92 E{e0}", "G1 E0.07 F42"], machine())
        return r.total_s
    assert stop_time(0.0) == pytest.approx(1 / 120 + 6 / 66)           # 0 -> 6.51: 7 steps
    assert stop_time(0.5797) == pytest.approx(1 / 120 + 5 / 66)        # 53.91 -> 60.42: 6 steps
    # under six steps Marlin drops it, and the distance goes to the next move
    r = es.estimate_lines(["M83", "M92 E93", "G1 E0.03 F18", "G1 X10 E0.5 F1200"], machine())
    assert len(r.blocks) == 1 and r.blocks["de"][0] == pytest.approx(0.53)


def test_stop_as_e_only_move_on_the_issues_wall():
    """The issue's wall: 40 mm/s in 0.5 mm pieces, three stops, RAMPS defaults (3000 mm/s^2,
    JD 0.013, 16 blocks), measured in simulated stock Marlin 2.1.2.7: 103.6 ms added per stop for
    G1 E0.0968 F61.5 (93 steps/mm) and 103.7 for G1 E0.0988 F64.6 (415). G4 P100 empties the
    planner: it costs more (155.1 ms measured; the host's refill of the queue is not modelled)."""
    def added(stop, spm):
        def wall(with_stop):
            out = ["G90", "M83", f"M92 E{spm}", "G1 X0 Y0 F2400"]
            for i in range(120):
                out.append(f"G1 X{0.5 * (i + 1):.3f} E0.0187 F2400")     # F back after a stop
                if with_stop and i in (30, 60, 90):
                    out.append(stop)
            return out
        m = es.Machine()
        return (es.estimate_lines(wall(True), m).total_s - es.estimate_lines(wall(False), m).total_s) / 3
    move93 = added("G1 E0.0968 F61.5", 93)
    move415 = added("G1 E0.0988 F64.6", 415)
    g4 = added("G4 P100", 93)
    assert move93 * 1000 == pytest.approx(103.6, abs=1.5)
    assert move415 * 1000 == pytest.approx(103.7, abs=1.5)
    assert g4 > move93 + 0.005


def test_cli_e_steps(tmp_path):
    # 9 steps at 93 steps/mm, 96 steps/s: 1/120 + 8/96 = 0.0917 s each; at 500 steps/mm 48 steps
    # at 513 steps/s: trapezoids through collinear junctions, 0.0968 mm at 1.025 mm/s = 0.0944 s
    p = tmp_path / "a.gcode"
    p.write_text("M83\n" + "G1 E0.0968 F61.5\n" * 100)
    r = CliRunner().invoke(main, ["estimate", str(p), "--e-steps", "500"])
    assert r.exit_code == 0 and "(9.4 s; 100 moves" in r.output, r.output
    # the default is the printer model's (Marlin's defaults with E 93), as build's
    r = CliRunner().invoke(main, ["estimate", str(p)])
    assert r.exit_code == 0 and "(9.2 s; 100 moves" in r.output, r.output
    assert "steps/mm 80/80/400/93" in r.output
    r = CliRunner().invoke(main, ["estimate", str(p), "--printer", "prusa-mk3s"])
    assert r.exit_code == 0 and "steps/mm 100/100/400/280" in r.output, r.output
    r = CliRunner().invoke(main, ["estimate", str(p), "--e-steps", "0"])
    assert r.exit_code == 2 and "--e-steps" in r.output


def test_a_klipper_model_has_no_step_rate_floor():
    """Klipper steps an E-only move at its own speed from the first step: no 1/120 s floor (and
    no division by the floor of 0 it has)."""
    from bulgekit import machine
    m = es.Machine.from_model(machine.PRESETS["klipper-corexy"])
    assert m.min_step_rate == 0 and m.min_segment_steps == 0 and m.lookahead is None
    r = es.estimate_lines(["M83", "G1 E0.0968 F61.5"], m)
    # a trapezoid at the extruder's own limits, not 1/120 + (n - 1)/r
    assert r.total_s == pytest.approx(trapezoid(0.0968, 61.5 / 60, m.retract_accel), rel=1e-6)
