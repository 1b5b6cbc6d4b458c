"""The measurement tools of issue 25 (docs/verification/marlin-simulation.md, "Stops on stock
firmware"): trace_stops.py's per-stop figures for E-only stops, klipper_steps.py's
replay of Klipper's stepper commands, and stop_wall.py's stillness rule."""
import importlib.util
import re
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[3] / "tools"


def load(name):
    spec = importlib.util.spec_from_file_location(name, TOOLS / (name + ".py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


ts = load("trace_stops")
ks = load("klipper_steps")
sw = load("stop_wall")

MS = 16000  # cycles per ms at 16 MHz
ORIGIN = dict(X=0.0, Y=0.0, Z=0.0, E=0.0)


@pytest.fixture(autouse=True)
def e_steps_500():
    """--e-steps changes the module's table; every test starts from the RAMPS default."""
    ts.STEPS["E"] = 500.0
    yield
    ts.STEPS["E"] = 500.0


def write_trace(path, events):
    lines = []
    for cycle, pin in sorted(events):
        lines += ["%d %s 1" % (cycle, pin), "%d %s 0" % (cycle + 16, pin)]
    lines.sort(key=lambda l: int(l.split()[0]))
    path.write_text("0 F1 1\n0 A6 1\n" + "\n".join(lines) + "\n")
    return str(path)


def x_run(start, n, every):
    return [(start + k * every, "F0") for k in range(n)]


def test_per_stop_head_still_added_time_and_e_steps(tmp_path, capsys):
    """Reference: 40 X steps every 0.5 ms. Run: the same with a stop after the 20th
    X step in which E makes 6 steps (the file's E-only move) and the head stands
    100 ms; the stop adds 100 ms less the 0.5 ms X interval it replaces."""
    ref = write_trace(tmp_path / "ref.txt", x_run(1000, 40, MS // 2))
    last = 1000 + 19 * MS // 2
    resume = last + 100 * MS
    ev = x_run(1000, 20, MS // 2) + x_run(resume, 20, MS // 2)
    ev += [(last + 8 * MS + k * 16 * MS, "A4") for k in range(6)]
    run = write_trace(tmp_path / "run.txt", ev)
    gcode = tmp_path / "sent.g"
    # an unretract (after a retraction) is not a stop; the 6-step E-only move is
    gcode.write_text("M83\nG1 X0.125\nG1 E-0.5\nG1 E0.5\nG1 X0.25\nG1 E0.012\nG1 X0.5\n")
    assert ts.gcode_e_only_steps(str(gcode), ORIGIN) == [6]
    rc = ts.main(["stops", run, "--ref", ref, "--gcode", str(gcode), "--stop-ms", "100",
                  "--dwell-tol", "0.01", "-v"])
    out = capsys.readouterr().out
    row = re.search(r"^ 0\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+) \((\d+)\)", out, re.M)
    assert row, out
    head, still, added, e_in, e_file = row.groups()
    assert float(head) == pytest.approx(100.0)
    assert float(still) == pytest.approx(16.0)  # every axis: the E steps are 16 ms apart
    assert float(added) == pytest.approx(99.5)
    assert (int(e_in), int(e_file)) == (6, 6)
    assert "head still vs --stop-ms +- 0.01 ms: all within" in out
    # the E total (the 6 stop steps) and the final X are the G-code's: the run passes
    assert "E steps while the head stands = the file's E-only move: 1 of 1 stops" in out
    assert rc == 0


def test_stop_ms_outside_fails(tmp_path, capsys):
    ref = write_trace(tmp_path / "ref.txt", x_run(1000, 40, MS // 2))
    last = 1000 + 19 * MS // 2
    run = write_trace(tmp_path / "run.txt", x_run(1000, 20, MS // 2) + x_run(last + 117 * MS, 20, MS // 2))
    assert ts.main(["stops", run, "--ref", ref, "--stop-ms", "100", "--dwell-tol", "2"]) == 1
    assert "stops [0] outside" in capsys.readouterr().out


def test_e_steps_option_counts_marlin_rounding(tmp_path):
    """At 93 steps/mm, E0.0968 is 9.0024 steps: 9 from any whole-step start, and
    absolute E re-based by G92 rounds again."""
    g = tmp_path / "abs.g"
    g.write_text("M82\nG92 E0\nG1 X1 E0.3\nG1 E0.3968\nG1 X2 E0.5\nG92 E0.1\nG1 X3 E0.2\nG1 E0.2968\n")
    ts.main(["stops", str(write_trace(tmp_path / "t.txt", x_run(1000, 3, MS))), "--e-steps", "93"])
    assert ts.STEPS["E"] == 93
    # 0.3 mm = 27.9 -> 28 steps; 0.3968 mm = 36.9 -> 37: 9. After G92 E0.1 (9.3 -> 9),
    # 0.2 mm = 18.6 -> 19, 0.2968 = 27.6 -> 28: 9
    assert ts.gcode_e_only_steps(str(g), ORIGIN) == [9, 9]


def test_klipper_queue_step_replay(tmp_path):
    """queue_step: the first step `interval` after the previous one, then each
    interval grows by `add`; the direction pin changes before the next step."""
    dump = tmp_path / "out.dump"
    dump.write_text(
        "allocate_oids count=3\n"
        "config_stepper oid=2 step_pin=PF0 dir_pin=PF1 invert_step=0 step_pulse_ticks=32\n"
        "config_stepper oid=5 step_pin=PA4 dir_pin=PA6 invert_step=0 step_pulse_ticks=32\n"
        "finalize_config crc=1\n"
        "set_next_step_dir oid=2 dir=1\n"
        "queue_step oid=2 interval=1000 count=3 add=10\n"     # 1000, 2010, 3030
        "set_next_step_dir oid=5 dir=1\n"
        "queue_step oid=5 interval=500 count=1 add=0\n"       # E at 500, forward
        "set_next_step_dir oid=2 dir=0\n"
        "queue_step oid=2 interval=2000 count=2 add=-100\n"   # 5030, 6930
        "reset_step_clock oid=5 clock=100000\n"
        "queue_step oid=5 interval=40 count=1 add=0\n")       # 100040
    out = tmp_path / "tr.txt"
    assert ks.main([str(dump), "-o", str(out)]) == 0
    rises = [(int(c), p) for c, p, v in (l.split() for l in out.read_text().splitlines()) if v == "1"]
    assert [c for c, p in rises if p == "F0"] == [1000, 2010, 3030, 5030, 6930]
    assert [c for c, p in rises if p == "A4"] == [500, 100040]
    dirs = [(c, p, v) for c, p, v in (l.split() for l in out.read_text().splitlines()) if p == "F1"]
    assert dirs == [("1", "F1", "1"), ("3031", "F1", "0")]
    # trace_stops reads it: X went 3 forward and 2 back
    run = ts.Run(str(out), ORIGIN)
    assert run.count["X"] == 1 and run.count["E"] == 2


def test_klipper_replay_refuses_other_input(tmp_path):
    bad = tmp_path / "x.dump"
    bad.write_text("queue_step oid=2 interval=1 count=1 add=0\n")
    with pytest.raises(SystemExit, match="before its config_stepper"):
        ks.main([str(bad), "-o", str(tmp_path / "t.txt")])
    assert not (tmp_path / "t.txt").exists()


@pytest.mark.parametrize("n, rate, k, want_ms", [
    (9, 96, 80, 100.0),          # below 120 steps/s: 1/120 + 8/96 + 1/120
    (6, 60, 80, 100.0),
    (41, 447, 80, 1 / 447 * 41 * 1000 + 1000 / 120),   # v = 1.08 mm/s x 80 < 120
    (6, 360, 80, 6000 / 360 + 1000 / (360 / 93 * 80)),  # v x k = 310: the next move starts sooner
    (6, 360, 0, 6000 / 360 + 1000 / 120),               # issue 25's rule
])
def test_stillness_rule(n, rate, k, want_ms):
    assert sw.still_s(n, rate, 93.0 if rate != 447 else 415.0, k, 9.7) * 1000 == pytest.approx(want_ms)


def test_wall_files(tmp_path, capsys):
    """The three files differ only in the stops; the move form writes whole steps
    at the rate the rule gives (9 steps, 96 steps/s -> F61.61 for 100 ms at 93)."""
    assert sw.main([str(tmp_path), "--weights", "255,128", "--stop-e", "0.0968"]) == 0
    ref, g4, move = ((tmp_path / n).read_text().splitlines() for n in ("ref.g", "g4.g", "move.g"))
    assert [l for l in g4 if l not in ref] == ["G4 P100", "G4 P50"]
    stops = [l for l in move if l not in ref]
    assert stops[0] == "G1 E0.09677 F61.61"
    e, f = (float(v) for v in re.match(r"G1 E([\d.]+) F([\d.]+)", stops[1]).groups())
    assert round(e * 93, 3) == 9.0
    assert int(-(-f / 60 * 93 // 1)) == 203     # CEIL(F/60 x 93): the rate chosen for 50 ms
    assert sw.still_s(9, 203, 93.0, 80.0, 9.7) * 1000 == pytest.approx(50.0, abs=0.1)
    with pytest.raises(SystemExit, match="--weights"):
        sw.main([str(tmp_path), "--weights", "0,300"])
