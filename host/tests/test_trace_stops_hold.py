"""tools/trace_stops.py's hold: the time every axis stands still at a stop,
read from a step-pin trace where E steps sit next to the ends of the X/Y gap."""
import importlib.util
import re
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[2] / "tools" / "trace_stops.py"
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
