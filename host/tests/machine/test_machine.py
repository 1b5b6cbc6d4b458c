"""The printer model (bulgekit.machine): presets, the three profile readers, the G-code's own
settings, and the numbers derived from them."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from bulgekit import machine as M

ENDER3_M503 = """\
Send: M503
Recv: echo:; Steps per unit:
Recv: echo:  M92 X80.00 Y80.00 Z400.00 E93.00
Recv: echo:; Maximum feedrates (units/s):
echo:  M203 X500.00 Y500.00 Z5.00 E25.00
echo:; Maximum Acceleration (units/s2):
echo:  M201 X500.00 Y500.00 Z100.00 E5000.00
echo:; Acceleration (units/s2): P<print_accel> R<retract_accel> T<travel_accel>
echo:  M204 P500.00 R500.00 T500.00
echo:; Advanced: B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> J<junc_dev>
echo:  M205 B20000.00 S0.00 T0.00 J0.08
echo:  M900 K0.22
ok
"""


def test_m503_reply_gives_its_numbers():
    m = M.from_m503(ENDER3_M503, source="ender.txt", name="ender")
    assert m.steps_per_mm == M.Axes(80, 80, 400, 93)
    assert m.max_feedrate == M.Axes(500, 500, 5, 25)
    assert m.max_accel == M.Axes(500, 500, 100, 5000)
    assert (m.accel, m.retract_accel, m.travel_accel) == (500, 500, 500)
    assert m.junction_deviation == 0.08 and m.jerk is None
    assert m.linear_advance_k == 0.22
    # the same settings as the preset that cites Marlin's Ender-3 example configuration
    e3 = M.PRESETS["ender3"]
    for f in ("steps_per_mm", "max_feedrate", "max_accel", "accel", "junction_deviation"):
        assert getattr(m, f) == getattr(e3, f), f


def test_m503_with_classic_jerk_and_old_m204():
    text = ("echo:  M92 X100.00 Y100.00 Z400.00 E280.00\n"
            "echo:  M204 S1250.00 T1250.00\n"
            "echo:  M205 S0.00 T0.00 B20000 X8.00 Y8.00 Z0.40 E4.50\n"
            "FIRMWARE_NAME:Prusa-Firmware 3.13.2 based on Marlin\n")
    m = M.from_m503(text)
    assert m.junction_deviation is None and m.jerk == M.Axes(8, 8, 0.4, 4.5)
    assert m.accel == m.travel_accel == 1250
    assert m.firmware == "prusa"
    assert m.corner_speed() == 8


def test_m503_without_settings_is_refused():
    with pytest.raises(M.ProfileError, match="no M92"):
        M.from_m503("ok\nok\n", source="empty.txt")


def test_bad_value_names_file_and_line(tmp_path):
    p = tmp_path / "bad.txt"
    p.write_text("echo:  M92 X80 Y80 Z400 E93\necho:  M201 X0 Y500\n")
    with pytest.raises(M.ProfileError, match=r"bad.txt:2: M201"):
        M.load(str(p))


def test_toml_round_trip_every_preset(tmp_path):
    for name, m in M.PRESETS.items():
        p = tmp_path / f"{name}.toml"
        p.write_text(M.to_toml(m))
        assert M.load(str(p)) == m, name
        assert M.resolve(str(p)) == m


def test_toml_errors_name_the_setting(tmp_path):
    p = tmp_path / "x.toml"
    p.write_text("[printer_model]\naccel = 500.0\nacel = 3\n")
    with pytest.raises(M.ProfileError, match="acel: unknown setting"):
        M.load(str(p))
    p.write_text("[printer_model]\nsteps_per_mm = { X = 80, Y = 80 }\n")
    with pytest.raises(M.ProfileError, match="steps_per_mm: give X, Y, Z and E"):
        M.load(str(p))
    p.write_text("[printer_model]\nfirmware = \"smoothie\"\n")
    with pytest.raises(M.ProfileError, match="firmware 'smoothie'"):
        M.load(str(p))


def test_klipper_cfg_follows_includes_and_save_config(tmp_path):
    (tmp_path / "hw").mkdir()
    (tmp_path / "printer.cfg").write_text("""\
[include hw/*.cfg]
[printer]
kinematics: corexy
max_velocity: 300
max_accel: 5000   ; comment
square_corner_velocity: 8.0
max_z_velocity: 15
max_z_accel: 350

#*# <---------------------- SAVE_CONFIG ---------------------->
#*# [extruder]
#*# pressure_advance = 0.045
""")
    (tmp_path / "hw" / "steppers.cfg").write_text("""\
[stepper_x]
rotation_distance: 40
microsteps: 32
[stepper_y]
rotation_distance: 40
microsteps: 32
full_steps_per_rotation: 200
[stepper_z]
rotation_distance: 8
microsteps: 16
""")
    (tmp_path / "hw" / "extruder.cfg").write_text("""\
[extruder]
rotation_distance: 22.6789511
gear_ratio: 50:17
microsteps: 16
nozzle_diameter: 0.400
filament_diameter: 1.75
max_extrude_only_velocity: 120
""")
    m = M.load(str(tmp_path / "printer.cfg"))
    assert m.firmware == "klipper"
    assert m.steps_per_mm.x == pytest.approx(160) and m.steps_per_mm.z == pytest.approx(400)
    assert m.steps_per_mm.e == pytest.approx(200 * 16 * 50 / 17 / 22.6789511)
    assert m.accel == 5000 and m.max_feedrate.z == 15 and m.max_accel.z == 350
    assert m.square_corner_velocity == 8
    assert m.linear_advance_k == 0.045              # from the SAVE_CONFIG block
    v, a = m.klipper_extrude_only
    assert v == 120                                 # given
    ratio = 4 * 0.4 ** 2 / (math.pi * 0.875 ** 2)   # Klipper's default max_extrude_cross_section
    assert a == pytest.approx(5000 * ratio)
    assert m.corner_speed() == pytest.approx(8)     # a 90 degree corner at scv


def test_klipper_missing_include_and_section(tmp_path):
    p = tmp_path / "printer.cfg"
    p.write_text("[include missing.cfg]\n[printer]\nmax_velocity: 300\nmax_accel: 3000\n")
    with pytest.raises(M.ProfileError, match=r"printer.cfg:1: \[include\] missing.cfg"):
        M.load(str(p))
    p.write_text("[printer]\nmax_velocity: 300\nmax_accel: 3000\n[extruder]\nnozzle_diameter: 0.4\n")
    with pytest.raises(M.ProfileError, match=r"no \[stepper_x\]"):
        M.load(str(p))


def test_gcode_settings_win_before_the_first_extrusion():
    lines = ["M201 X1000 Y1000 Z200 E5000 ; sets maximum accelerations\n",
             "M204 P1250 R1250 T1250\n", "M205 J0.02\n", "M92 E415\n",
             "G1 X10 Y10 F3000\n", "G1 X20 Y10 E1.0\n", "M204 P100\n"]
    m = M.with_gcode(M.DEFAULT, lines)
    assert m.max_accel.x == 1000 and m.accel == 1250 and m.junction_deviation == 0.02
    assert m.e_steps == 415
    assert m.accel != 100          # after the first extruding move: the estimator's to follow


def test_presets_differ_where_they_should():
    d, e3, cj = M.PRESETS["marlin"], M.PRESETS["ender3"], M.PRESETS["marlin-classic-jerk"]
    assert d.corner_speed() == pytest.approx(9.7033, abs=1e-4)    # sqrt(3000 * 0.013 / 0.4142)
    assert e3.corner_speed() == pytest.approx(math.sqrt(500 * 0.08 / (math.sqrt(2) - 1)))
    assert cj.corner_speed() == 10
    assert M.resolve(None) is M.DEFAULT
    assert M.resolve("ender3", firmware="klipper").firmware == "klipper"
    with pytest.raises(M.ProfileError, match="neither a file nor a preset"):
        M.resolve("/no/such/file.cfg")


def test_model_refuses_nonsense():
    with pytest.raises(ValueError, match="either a junction deviation or classic jerk"):
        M.PrinterModel(jerk=M.Axes(10, 10, 0.3, 5))
    with pytest.raises(ValueError, match="finite"):
        M.PrinterModel(accel=float("nan"))
    with pytest.raises(ValueError, match="> 0"):
        M.PrinterModel(steps_per_mm=M.Axes(80, 80, 400, 0))


def test_klipper_plans_speed_changes_at_its_accel_to_decel(tmp_path):
    """A lithophane's mid-line speeds up and slows down within short moves: Klipper's look-ahead
    plans that at max_accel x (1 - minimum_cruise_ratio) (its max_accel_to_decel), Marlin at its
    print acceleration; `litho`'s --accel default is that."""
    from click.testing import CliRunner
    from bulgekit.cli import main
    k = M.PRESETS["klipper-corexy"]
    assert k.rate_accel == 1500 and M.PRESETS["marlin"].rate_accel == 3000
    assert replace(k, minimum_cruise_ratio=0.0).rate_accel == 3000
    import json
    r = CliRunner().invoke(main, ["litho", "--calibration", "--printer", "klipper-corexy", "-o", str(tmp_path), "-q"])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "calibration.litho.json").read_text())["options"]["accel"] == 1500
