"""tools/trace_width.py on synthetic step traces: motion time, and the mid-line's E rate in
windows against the rate the file sets (M723 Q over the filament area)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
import trace_width  # noqa: E402

F = 16e6
RATE = 8 / (math.pi * 1.75 ** 2 / 4)           # M723 Q8, 1.75 mm filament: mm/s of filament

GCODE = """M83
;LAYER:0
;TYPE:wall
G1 X10 E1 F600
;LAYER:1
M723 S1 Q8 D1.75 H0.2
;TYPE:mid-line
G1 X20 E1
G1 X30 E1
"""


def e_steps(t0, n, rate):
    """n E steps (500 per mm) from t0 s at `rate` mm/s: trace lines, and the time after them."""
    dt = 1 / (rate * 500)
    lines = []
    for i in range(1, n + 1):
        c = int(round((t0 + i * dt) * F))
        lines += [f"{c} A4 1", f"{c + 20} A4 0"]
    return lines, t0 + n * dt


def write(tmp_path, rates):
    lines = ["0 A6 1"]                          # E direction: forward
    first, t = e_steps(0.0, 500, 1.0)           # layer 0 wall: 1 mm of filament in 1 s
    lines += first
    for r in rates:                             # the two mid-line moves, 500 steps each
        more, t = e_steps(t, 500, r)
        lines += more
    (tmp_path / "tr.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "a.gcode").write_text(GCODE)
    return str(tmp_path / "tr.txt"), str(tmp_path / "a.gcode"), t


def test_rate_at_the_set_rate(tmp_path):
    tr, g, t_end = write(tmp_path, [RATE, RATE])
    r = trace_width.analyse(tr, g, window_ms=40)
    assert r["set_rate_mm_s"] == pytest.approx(RATE)
    assert r["mean_rate_mm_s"] == pytest.approx(RATE, rel=2e-3)
    assert r["share_within_5pct"] == pytest.approx(1.0)
    assert r["time_s"] == pytest.approx(t_end - 1 / 500, abs=1e-3)   # first step to last step (ms)
    assert r["mid_line_time_s"] == pytest.approx(2 / RATE, rel=2e-3)


def test_a_slow_move_falls_outside(tmp_path):
    tr, g, _ = write(tmp_path, [RATE, RATE / 2])
    r = trace_width.analyse(tr, g, window_ms=40)
    t_fast, t_slow = 1 / RATE, 2 / RATE
    # windows close at move ends; each move is one window here (300+ ms each)
    assert r["share_within_5pct"] == pytest.approx(t_fast / (t_fast + t_slow), rel=5e-3)
    assert r["mean_rate_mm_s"] == pytest.approx(2 / (t_fast + t_slow), rel=5e-3)


def test_a_ramp_inside_one_long_move_is_off_rate_only_where_it_is(tmp_path):
    """One mid-line move whose first part runs at half the rate (the head ramping up inside a
    long merged piece): as one window its mean rate is off and all of it counts as off; cut
    into 40 ms slices only the slow part does. The other move is at the rate throughout."""
    lines = ["0 A6 1"]
    first, t = e_steps(0.0, 500, 1.0)
    lines += first
    more, t = e_steps(t, 500, RATE)
    lines += more
    slow, t = e_steps(t, 100, RATE / 2)         # 0.2 mm of filament slow, then 0.8 mm at the rate
    fast, t = e_steps(t, 400, RATE)
    lines += slow + fast
    (tmp_path / "tr.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "a.gcode").write_text(GCODE)
    r = trace_width.analyse(str(tmp_path / "tr.txt"), str(tmp_path / "a.gcode"), window_ms=40)
    t1, t_slow, t_fast = 1 / RATE, 0.2 * 2 / RATE, 0.8 / RATE
    total = t1 + t_slow + t_fast
    assert r["share_within_5pct"] == pytest.approx(t1 / total, rel=5e-3)
    # the slices that straddle the change from slow to fast are off too: at most one 40 ms slice
    assert (t1 + t_fast - 0.04) / total <= r["share_within_5pct_sliced"] <= (t1 + t_fast) / total + 1e-3


def test_a_move_without_e_inside_the_mid_line_is_not_extruder_time(tmp_path):
    """Where the walls take a narrow gap the mid-line crosses it without E: the head's time there
    is neither in the mid-line's time nor in its rate."""
    lines = ["0 A6 1"]
    first, t = e_steps(0.0, 500, 1.0)
    lines += first
    more, t = e_steps(t, 500, RATE)
    lines += more
    more, t = e_steps(t + 0.25, 500, RATE)      # a 0.25 s dry move, then the next piece
    lines += more
    (tmp_path / "tr.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "a.gcode").write_text(GCODE.replace("G1 X20 E1\n", "G1 X20 E1\nG1 X25 F9000\n"))
    r = trace_width.analyse(str(tmp_path / "tr.txt"), str(tmp_path / "a.gcode"), window_ms=40)
    assert r["mid_line_time_s"] == pytest.approx(2 / RATE, rel=3e-3)
    assert r["share_within_5pct"] == pytest.approx(1.0)
    assert r["mean_rate_mm_s"] == pytest.approx(RATE, rel=3e-3)


def test_a_stock_file_without_m723_takes_the_rate_of_eq_2(tmp_path, capsys):
    """A stock-firmware file has no M723: the set rate is E x F / length of its mid-line moves."""
    tr, _, _ = write(tmp_path, [RATE, RATE / 2])
    f = RATE * 60 * 10 / 1                       # 10 mm pieces laying 1 mm of filament each
    stock = GCODE.replace("M723 S1 Q8 D1.75 H0.2\n", "").replace("G1 X20 E1\n", f"G1 X20 E1 F{f:.1f}\n")
    (tmp_path / "s.gcode").write_text(stock)
    r = trace_width.analyse(tr, str(tmp_path / "s.gcode"), window_ms=40)
    assert r["set_rate_mm_s"] == pytest.approx(RATE, rel=1e-4)
    assert r["set_rate_from"] == "E x F / length (no M723)"
    t_fast, t_slow = 1 / RATE, 2 / RATE
    assert r["share_within_5pct"] == pytest.approx(t_fast / (t_fast + t_slow), rel=5e-3)
    assert trace_width.main([tr, str(tmp_path / "s.gcode")]) == 0
    assert "against 3.3260 (E x F / length (no M723))" in capsys.readouterr().out


def test_no_rate_to_be_had_is_a_message_not_a_traceback(tmp_path, capsys):
    tr, _, _ = write(tmp_path, [RATE, RATE])
    # no M723, and mid-line moves of E alone: nothing to take a rate from
    (tmp_path / "n.gcode").write_text(GCODE.replace("M723 S1 Q8 D1.75 H0.2\n", "")
                                      .replace("G1 X20 E1\nG1 X30 E1\n", "G1 E1\nG1 E1\n"))
    assert trace_width.main([tr, str(tmp_path / "n.gcode")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'n.gcode'}: no M723 Q" in err and "give --rate MM_S" in err
    assert trace_width.main([tr, str(tmp_path / "n.gcode"), "--rate", str(RATE)]) == 0
    assert "100.0 % of the time within 5 %" in capsys.readouterr().out
