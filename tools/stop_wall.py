#!/usr/bin/env python3
"""A straight wall with stops, written three ways, for timing stops on stock firmware
(docs/verification/marlin-simulation.md, "Stops on stock firmware").

    stop_wall.py OUTDIR [--e-steps 93] [--weights 255,255,255,128,64,38] [--dwell 100]
                 [--feed 2400] [--printer PRESET|FILE]

writes OUTDIR/ref.g (no stops), OUTDIR/g4.g (each stop a `G4 P<ms>`) and OUTDIR/move.g
(each stop an extruder-only move), ready for `bksim --ok-pace --input`: no comments, no
blank lines (Marlin answers no "ok" to those), a `G4 P1200` first so the boot is over.

The wall: from X100 Y100, z 0.2, 0.5 mm pieces along +X at 40 mm/s (F2400), relative
E (M83), 0.0187 mm of filament per piece (0.45 x 0.2 mm bead, 1.75 mm filament).
After every 20 pieces (10 mm) comes one stop, weight w of 255 from --weights, so its
dwell is P x w / 255 ms, rounded as the firmware rounds it; then 20 more pieces.

The move form (issue 25): n whole E steps at the firmware's E steps/mm, at a rate r
(steps/s) that makes Marlin 2.1.2.x hold the head for the dwell. As read from the
step traces of this wall and Marlin's planner:
  head still = 1/max(r, 120) + (n - 1)/r + 1/max(120, v x k)
- the first E step comes one interval after the last X/Y step: the E move enters at
  its own speed (the junction allows it), at least Marlin's 120 steps/s minimum;
- the next X/Y move enters at the junction speed v = min(r / E steps/mm, v_jd), with
  v_jd the junction-deviation limit for a 90 degree corner between an E-only and an
  X/Y move (sqrt(a x JD x 2.414), 9.7 mm/s at 3000 mm/s^2 and JD 0.013), so its
  first step comes after 1/(v x k), k = its leading axis's steps per mm of path
  (80 along X here), and again not later than 1/120 s.
With v x k below 120 this is the issue's rule (1/120 + (n-1)/r + 1/120 below
120 steps/s, n/r + 1/120 above). Marlin plans an extruder-only move at
r = CEIL(F/60 x steps/mm) (its length is taken from the steps), so F is written
for r - 0.5. n is --stop-e in whole steps, at least the fewest steps Marlin queues
as a move (MIN_STEPS_PER_SEGMENT, 6).
"""

import argparse
import math
import os
import sys

MIN_STEP_RATE = 120.0      # Marlin's MINIMAL_STEP_RATE, steps/s
MIN_STEPS = 6              # MIN_STEPS_PER_SEGMENT in Marlin's default configuration
PIECE_MM, PIECES_PER_GAP, FEED = 0.5, 20, 2400
E_PER_PIECE = 0.45 * 0.2 * PIECE_MM / (math.pi * 1.75 ** 2 / 4)


def dwell_ms(p, w):
    """P x w / 255, rounded to the nearest ms (as the fork's M720 and the host do)."""
    return (p * w + 127) // 255


def still_s(n, r, e_steps, k, v_jd):
    """How long Marlin 2.1.2.x holds the head for n E steps at r steps/s (module doc)."""
    v = min(r / e_steps, v_jd)
    return 1 / max(r, MIN_STEP_RATE) + (n - 1) / r + 1 / max(MIN_STEP_RATE, v * k)


def stop_move(ms, n, e_steps, k, v_jd, max_rate):
    """The whole rate (steps/s) whose hold for n steps is nearest ms; the hold
    falls as the rate rises, so bisect, then take the better neighbour."""
    d = ms / 1000.0
    lo, hi = 1.0, max_rate
    for _ in range(100):
        mid = (lo + hi) / 2
        if still_s(n, mid, e_steps, k, v_jd) > d:
            lo = mid
        else:
            hi = mid
    cands = [r for r in (math.floor(lo), math.ceil(lo)) if 1 <= r <= max_rate] or [int(max_rate)]
    return min(cands, key=lambda r: abs(still_s(n, r, e_steps, k, v_jd) - d))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("outdir")
    ap.add_argument("--e-steps", type=float, default=93.0, help="the firmware's E steps/mm")
    ap.add_argument("--dwell", type=int, default=100, help="P of a full-weight stop, ms")
    ap.add_argument("--weights", default="255,255,255,128,64,38",
                    help="one weight (1..255) per stop, comma-separated")
    ap.add_argument("--max-e-rate", type=float, default=25.0,
                    help="the firmware's E max feedrate (M203 E), mm/s")
    ap.add_argument("--stop-e", type=float, default=0.0,
                    help="filament laid during a stop, mm (whole steps, at least 6; default 6 steps)")
    ap.add_argument("--xy-steps", type=float, default=80.0, help="X steps/mm (the wall runs along X)")
    ap.add_argument("--accel", type=float, default=3000.0, help="printing acceleration, mm/s^2")
    ap.add_argument("--jd", type=float, default=0.013, help="junction deviation, mm")
    ap.add_argument("--rule", choices=("junction", "issue"), default="junction",
                    help="junction: the rule above; issue: issue 25's rule (the next move's first "
                    "step always 1/120 s after the last E step), for comparison")
    ap.add_argument("--feed", type=float, default=FEED, help="the wall's feed rate, mm/min")
    ap.add_argument("--printer", help="a printer model (bulgekit's presets or a profile file): "
                    "the rates then come from the host's own rule for it (bulgekit.bulge.fallback), "
                    "--e-steps, --accel, --jd and --max-e-rate being the model's unless given")
    args = ap.parse_args(argv)
    try:
        weights = [int(w) for w in args.weights.split(",")]
    except ValueError:
        raise SystemExit("stop_wall.py: --weights wants whole numbers, got %r" % args.weights)
    if not weights or any(not 1 <= w <= 255 for w in weights):
        raise SystemExit("stop_wall.py: --weights must be 1..255, got %r" % args.weights)
    if args.e_steps <= 0:
        raise SystemExit("stop_wall.py: --e-steps must be > 0")
    host_rule = None
    if args.printer:
        host_rule = _host_rule(args, argv or sys.argv[1:])
    n = max(MIN_STEPS, round(args.stop_e * args.e_steps))
    k = args.xy_steps if args.rule == "junction" else 0.0  # v x 0 < 120: always 1/120
    v_jd = math.sqrt(args.accel * args.jd * (1 / (math.sqrt(2) - 1)))  # 90 degrees: sin/(1-sin) = 2.414
    os.makedirs(args.outdir, exist_ok=True)
    head = ["G4 P1200", "G92 X100 Y100 Z0 E0", "G1 Z0.2 F600", "M83"]
    tail = ["M400", "M114"]
    bodies = {"ref": [], "g4": [], "move": []}
    x = 100.0
    plan = []
    for i in range(len(weights) + 1):
        for _ in range(PIECES_PER_GAP):
            x += PIECE_MM
            piece = "G1 X%.3f E%.5f F%s" % (x, E_PER_PIECE, "%g" % args.feed)
            for b in bodies.values():
                b.append(piece)
        if i == len(weights):
            break
        ms = dwell_ms(args.dwell, weights[i])
        if host_rule is not None:
            r, st = host_rule(ms, n)
        else:
            r = stop_move(ms, n, args.e_steps, k, v_jd, args.max_e_rate * args.e_steps)
        # F for r - 0.5 steps/s, so that CEIL() lands on r; E to 5 decimals
        # is within 0.001 steps of n at up to 100 steps/mm (more digits above).
        digits = max(5, int(math.ceil(math.log10(args.e_steps * 100))))
        e = n / args.e_steps
        f = (r - 0.5) * 60.0 / args.e_steps
        bodies["g4"].append("G4 P%d" % ms)
        bodies["move"].append("G1 E%.*f F%.2f" % (digits, e, f))
        plan.append((weights[i], ms, n, r, (st if host_rule is not None
                                            else still_s(n, r, args.e_steps, k, v_jd)) * 1000))
    for name, body in bodies.items():
        with open(os.path.join(args.outdir, name + ".g"), "w") as fh:
            fh.write("\n".join(head + body + tail) + "\n")
    print("%s: ref.g, g4.g, move.g; E %g steps/mm, %d stops" % (args.outdir, args.e_steps, len(plan)))
    print(" w   dwell ms  E steps  rate steps/s  head still (rule) ms")
    for w, ms, n, r, st in plan:
        print("%3d  %8d  %7d  %12d  %8.3f" % (w, ms, n, r, st))
    return 0


def _host_rule(args, argv):
    """(ms, n) -> (rate, stillness s) by the host's rule for the printer model (issue 36): the
    wall's pieces (along +X, E_PER_PIECE per PIECE_MM, at --feed) are the moves around each stop."""
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "host")
    sys.path.insert(0, here)
    from bulgekit.bulge import fallback, stopmodel
    from dataclasses import replace
    from bulgekit.machine import resolve
    pm = resolve(args.printer)
    if any(a.startswith("--e-steps") for a in argv):
        pm = replace(pm, steps_per_mm=pm.steps_per_mm.with_(E=args.e_steps))
    args.e_steps = pm.e_steps
    piece = stopmodel.Piece(1.0, 0.0, E_PER_PIECE / PIECE_MM, args.feed / 60.0, pm.steps_per_mm.x)

    def rule(ms, n):
        m = fallback._rate_for(n, ms / 1000.0, pm.e_steps, piece.k, pm, piece)
        return m.rate, m.still
    return rule


if __name__ == "__main__":
    sys.exit(main())
