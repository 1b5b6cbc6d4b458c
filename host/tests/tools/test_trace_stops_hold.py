"""tools/trace_stops.py's hold: the time every axis stands still at a stop,
read from a step-pin trace where E steps sit next to the ends of the X/Y gap."""
import importlib.util
import re
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[3] / "tools" / "trace_stops.py"
spec = importlib.util.spec_from_file_location("trace_stops", TOOL)
ts = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ts)

MS = 16000  # cycles per ms at 16 MHz


def step(lines, cycle, pin):
    lines += ["%d %s 1" % (cycle, pin), "%d %s 0" % (cycle + 16, pin)]


def trace(tmp_path, e_after_last_xy, e_before_first_xy):
    """X steps every 0.5 ms, a 100 ms X/Y gap, X steps again. An E step 2 µs
    after the last X step before the gap (the same step event) and/or one
    1 ms before the first X step after it (a piece led by E)."""
    lines = ["0 F1 1", "0 A6 1"]  # X and E move forward
    c = 1000
    for _ in range(10):
        step(lines, c, "F0")
        c += MS // 2
    last = c - MS // 2
    if e_after_last_xy:
        step(lines, last + 32, "A4")
    resume = last + 100 * MS
    if e_before_first_xy:
        step(lines, resume - MS, "A4")
    for k in range(10):
        step(lines, resume + k * MS // 2, "F0")
    lines.sort(key=lambda l: int(l.split()[0]))
    f = tmp_path / "trace.txt"
    f.write_text("\n".join(lines) + "\n")
    return str(f), last, resume


def hold_line(capsys, path):
    assert ts.main(["stops", path, "--gap", "4", "--dwell", "100"]) == 0
    out = capsys.readouterr().out
    m = re.search(r"hold \(longest time with no step of any axis.*\): min ([\d.]+) / mean ([\d.]+) / max ([\d.]+) ms", out)
    assert m, out
    return [float(v) for v in m.groups()]


@pytest.mark.parametrize("after, before, expect", [
    (False, False, 100.0),
    (True, False, 100.0 - 32 / MS),          # the E step shares the last X/Y step's event
    (False, True, 99.0),                      # E leads the next piece by 1 ms
    (True, True, 99.0 - 32 / MS),
])
def test_hold_is_the_longest_still_stretch(tmp_path, capsys, after, before, expect):
    path, last, resume = trace(tmp_path, after, before)
    run = ts.Run(path, dict(X=0, Y=0, Z=0, E=0))
    (c0, c1, _, _), = run.stops(4.0)
    assert (c0, c1) == (last, resume)
    assert run.stillness(c0, c1) / MS == pytest.approx(expect)
    lo, mean, hi = hold_line(capsys, path)
    assert lo == pytest.approx(expect, abs=1e-4) and hi == pytest.approx(expect, abs=1e-4)
    # the old reading, the first step of any axis after the last X/Y step,
    # gave 0.002 ms when an E step shared that step event
    assert lo > 90


def test_cut_keeps_the_source_e_mode(tmp_path):
    """A relative-E file (M83 before the first layer) cut to later layers stays
    relative: the cut's header says M82, so the dropped M83 is said again."""
    src = tmp_path / "rel.gcode"
    src.write_text("M83\nG1 Z0.2\n;LAYER_CHANGE\n;TYPE:External perimeter\nG1 X1 E0.5\n"
                   ";LAYER_CHANGE\n;TYPE:External perimeter\nG1 X2 E0.5\nG1 X3 E0.25\n")
    out = tmp_path / "cut.gcode"
    assert ts.main(["cut", str(src), "--layers", "2-2", "--keep", "External perimeter", "-o", str(out)]) == 0
    lines = [l.split(";")[0].strip() for l in out.read_text().splitlines()]
    lines = [l for l in lines if l]
    assert lines[:3] == ["G21", "G90", "M82"]
    assert lines[3:] == ["M83", "G1 X2 E0.5", "G1 X3 E0.25"]
    # the E the cut asks for, read as the firmware would: 0.75 mm, not 0.25 - 0.5
    pos, e_total = ts.gcode_end_state(str(out), dict(X=0, Y=0, Z=0, E=0))
    assert e_total == pytest.approx(0.75)


def test_e_steps_round_at_each_g92_as_marlin_does(tmp_path):
    """199 G92 resets in a real file made the E check one rounding short; here a
    0.0013 mm move (0.65 steps) rounds to 1 step every time, 3 times over."""
    g = tmp_path / "g92.gcode"
    g.write_text("M82\n" + "G1 X1 E0.0013\nG92 E0\n" * 3)
    steps = []
    pos, e_total = ts.gcode_end_state(str(g), dict(X=0, Y=0, Z=0, E=0), steps=steps)
    assert e_total == pytest.approx(0.0039)
    assert round(e_total * ts.STEPS["E"]) == 2   # the old reading
    assert steps == [3]                          # what the steppers do
