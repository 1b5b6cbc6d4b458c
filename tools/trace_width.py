#!/usr/bin/env python3
"""Print time and the mid-line's extruder rate of a simulated Marlin print, from its step trace.

    trace_width.py TRACE GCODE [--rate MM_S] [--window MS] [--json]

TRACE is bksim's pin trace of a run with the RAMPS pins (see trace_stops.py: F0/F1 X, F6/F7 Y,
L3/L1 Z, A4/A6 E0); GCODE is the file that was sent. Reported:

  time      first to last step of any axis (the print's motion time as the firmware ran it)
  mid-line  for every ;TYPE:mid-line move after the first layer, the time at which the E step
            count reached the move's end: consecutive mid-line moves are gathered into windows
            of at least --window ms (a 0.4 mm piece carries only 5-20 E steps, too few to time
            one by one) and each window's E rate (steps / 500 per mm / time) is compared with
            the set rate (--rate, default: the file's own M723 Q / filament area; in a file
            without M723, a stock-firmware file, the median E x F / length of its mid-line
            moves after the first layer, the rate eq. 2 sets). The share of mid-line time in
            windows within +-5 % is printed, and the mean rate over all; and the share when
            each window is cut into slices of about --window ms (a long piece's own speed
            ramps then count as off-rate only where they are, as the estimator counts them).

Reads only bksim's trace format and G-code text; it builds nothing.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from trace_stops import F_CPU, STEPS, Run, words  # noqa: E402


def mid_line_moves(path):
    """("move", layer, kind, E, M723 rate in force, E x F / length) per move that changes E, in
    file order (the last is None for a move without X/Y motion), ("dry", layer, kind) per G0/G1
    without E, and ("g92", ...) where G92 sets E.
    E is followed as Marlin does (M82/M83, G90 resets E to absolute, G92 E); X/Y and F as well
    (G90/G91), for the eq. 2 rate of a file without M723."""
    out, kind, layer = [], None, -1
    e_rel, e, rate = False, 0.0, None
    xy_rel, x, y, f = False, 0.0, 0.0, None
    area = math.pi * 1.75 ** 2 / 4
    for raw in open(path, encoding="utf-8", errors="replace"):
        if raw.startswith(";TYPE:"):
            kind = raw[6:].strip()
            continue
        if raw.startswith(";LAYER:"):
            layer = int(raw[7:])
            continue
        w, code = words(raw)
        head = code.split()[0].upper() if code else ""
        if head == "M83":
            e_rel = True
        elif head in ("M82", "G90"):
            e_rel = False
            if head == "G90":
                xy_rel = False
        elif head == "G91":
            xy_rel = e_rel = True
        elif head == "G92" and "E" in w:
            e_base = w["E"]
            out.append(("g92", e, e_base))             # the count goes on; only the frame moves
            e = e_base
        elif head == "M723":
            if "D" in w:
                area = math.pi * w["D"] ** 2 / 4
            if "Q" in w:
                rate = w["Q"] / area                   # the rate in force for what follows
        elif head in ("G0", "G1"):
            f = w.get("F", f)
            nx = x + w.get("X", 0.0) if xy_rel else w.get("X", x)
            ny = y + w.get("Y", 0.0) if xy_rel else w.get("Y", y)
            length = math.hypot(nx - x, ny - y)
            x, y = nx, ny
            if "E" in w:
                new = e + w["E"] if e_rel else w["E"]
                eq2 = (new - e) * f / 60 / length if f and length > 1e-9 else None
                out.append(("move", layer, kind, new - e, rate, eq2))
                e = new
            elif length > 1e-9 or "Z" in w:
                out.append(("dry", layer, kind))       # no E steps mark its end: see analyse
    return out


def analyse(trace: str, gcode: str, rate: float | None = None, window_ms: float = 40.0) -> dict:
    run = Run(trace, {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0})
    total = (run.last - run.first) / F_CPU if run.first is not None else 0.0
    # net E steps after each E step, and their cycles
    cyc, cum, n = [], [], 0
    for c, d in run.e_steps:
        n += d
        cyc.append(c)
        cum.append(n)
    # walk the moves: the commanded E (in steps) after each, and when the trace got there
    target = 0.0
    i = 0
    windows, cur = [], None
    mid_rate = None
    eq2_rates = []
    prev_t, prev_n = run.first, 0
    dry = False
    for item in mid_line_moves(gcode):
        if item[0] == "g92":
            continue
        if item[0] == "dry":
            # a move without E (a travel, or a gap the walls fill inside a mid-line): its time
            # is no extruder time. It ends a window, and the next move's time starts at its first
            # E step, not at the last step before the dry move.
            if cur is not None and (cur[1] - cur[0]) / F_CPU * 1e3 >= window_ms / 2:
                windows.append(cur)
            cur = None
            dry = True
            continue
        _, layer, kind, de, r, eq2 = item
        if kind == "mid-line" and layer >= 1 and de > 0 and eq2 is not None:
            eq2_rates.append(eq2)
        target += de
        want = round(target * STEPS["E"])
        # the first step at which the count equals the target, searching forward
        while i < len(cum) and cum[i] != want:
            i += 1
        if i >= len(cum):
            break
        t_end = cyc[i]
        if dry and de > 0:
            # the move's first E step (prev_n + 1), found between the previous target and this one
            j = i
            while j > 0 and cum[j - 1] > prev_n:
                j -= 1
            if cum[j] == prev_n + 1:
                prev_t, prev_n = cyc[j], prev_n + 1
        dry = False
        if kind == "mid-line" and layer >= 1 and de > 0:
            if r is not None:
                mid_rate = r
            if cur is None:
                cur = [prev_t, t_end, prev_n, want]
            else:
                cur[1], cur[3] = t_end, want
            if (cur[1] - cur[0]) / F_CPU * 1e3 >= window_ms:
                windows.append(cur)
                cur = None
        elif cur is not None:                           # the stretch ended: keep what it has
            if (cur[1] - cur[0]) / F_CPU * 1e3 >= window_ms / 2:
                windows.append(cur)
            cur = None
        prev_t, prev_n = t_end, want
    ref = rate if rate is not None else mid_rate
    source = "--rate" if rate is not None else "M723 Q" if mid_rate is not None else None
    if ref is None and eq2_rates:
        ref, source = float(np.median(eq2_rates)), "E x F / length (no M723)"
    t_in = t_all = steps_all = t_in_sliced = 0.0
    cyc_a, cum_a = np.asarray(cyc, dtype=np.int64), np.asarray(cum, dtype=np.int64)
    for t0, t1, n0, n1 in windows:
        dt = (t1 - t0) / F_CPU
        if dt <= 0:
            continue
        r = (n1 - n0) / STEPS["E"] / dt
        t_all += dt
        steps_all += n1 - n0
        if ref and abs(r / ref - 1) <= 0.05:
            t_in += dt
        if ref:
            t_in_sliced += _sliced_in(cyc_a, cum_a, t0, t1, n0, n1, window_ms, ref)
    return {"time_s": round(total, 3), "mid_line_windows": len(windows),
            "mid_line_time_s": round(t_all, 3),
            "set_rate_mm_s": ref, "set_rate_from": source,
            "mean_rate_mm_s": (steps_all / STEPS["E"] / t_all) if t_all else None,
            "share_within_5pct": (t_in / t_all) if t_all else None,
            "share_within_5pct_sliced": (t_in_sliced / t_all) if t_all else None}


def _sliced_in(cyc, cum, t0, t1, n0, n1, window_ms, ref) -> float:
    """Seconds of the window [t0, t1] (cycles; n0, n1 the E step counts there) within +-5 % of
    ref when it is cut into slices of about window_ms: a window of whole moves may run for many
    times window_ms (a long merged piece, its own speed ramp inside it), and its mean rate
    then stands for the whole of it. The count at a slice's edge is the trace's net E count at
    the last step before it."""
    dt = (t1 - t0) / F_CPU
    k = max(1, int(dt * 1e3 // window_ms))
    edges = t0 + (t1 - t0) * np.arange(k + 1) / k
    at = np.searchsorted(cyc, edges[1:-1], side="right") - 1
    counts = np.concatenate([[n0], np.where(at >= 0, cum[np.maximum(at, 0)], n0), [n1]])
    rates = np.diff(counts) / STEPS["E"] / (dt / k)
    return float((np.abs(rates / ref - 1) <= 0.05).sum() * dt / k)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trace")
    ap.add_argument("gcode")
    ap.add_argument("--rate", type=float, help="set extruder rate, mm/s of filament")
    ap.add_argument("--window", type=float, default=40.0, help="ms per rate window (default 40)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if a.rate is not None and not (math.isfinite(a.rate) and a.rate > 0):
        ap.error(f"--rate: must be a number > 0, got {a.rate}")
    r = analyse(a.trace, a.gcode, a.rate, a.window)
    if r["mid_line_time_s"] and r["set_rate_mm_s"] is None:
        print(f"trace_width.py: {a.gcode}: no M723 Q and no mid-line move with E, F and a length to "
              "take the set rate from; give --rate MM_S", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(r, indent=1))
    else:
        print(f"motion time {r['time_s']:.2f} s")
        if r["mid_line_time_s"]:
            print(f"mid-line after layer 1: {r['mid_line_time_s']:.2f} s in {r['mid_line_windows']} windows; "
                  f"mean E rate {r['mean_rate_mm_s']:.4f} mm/s against {r['set_rate_mm_s']:.4f} "
                  f"({r['set_rate_from']}); "
                  f"{100 * r['share_within_5pct']:.1f} % of the time within 5 % "
                  f"({100 * r['share_within_5pct_sliced']:.1f} % with long windows cut into {a.window:g} ms slices)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
