#!/usr/bin/env python3
"""Check a simulated Marlin print from its step-pin trace (docs/verification/marlin-simulation.md).

    trace_stops.py cut GCODE --layers 2-4 --keep "External perimeter,Perimeter" -o OUT
        A short print from a sliced file: the chosen layers, only the chosen slicer
        features. Dropped lines leave the G-code's E frame intact: after each
        dropped run a "G92 E<value>" puts E where the dropped moves had left it,
        so no kept move extrudes the filament of a dropped one.

    trace_stops.py stops TRACE [--ref TRACE] [--map MAP.bkm] [--gcode SENT.gcode]
                        [--log UART.txt] [--dwell MS] [--extra MM] [--fallback]
        Step counts and stops of one run (bksim --trace with the RAMPS pins
        F0/F1 X, F6/F7 Y, L3/L1 Z, A4/A6 E0). A stop is a gap of at least --gap
        ms between two consecutive X/Y steps; its duration is that gap, i.e. the
        time the head stands at one step position. With --ref (the same G-code
        with the feature off) the stops of the reference are matched by position
        and the rest are the added stops; with --map each added stop is matched
        to its bulge point; with --gcode the E total and final position the
        G-code asks for are compared with the steps made and with M114 in --log.
        With --ref and -v, one line per added stop: how long the head (X, Y, Z)
        stands, how long every axis stands, the E steps made while the head
        stands against the steps of the file's extruder-only move there (stops
        written as `G1 E.. F..`, issue 25), and the time the stop added to the
        print (the run's delay behind the reference at the X/Y step halfway to
        the next stop, less the delay halfway from the previous one).
        --e-steps sets the E steps/mm of the firmware (default 500, RAMPS);
        --stop-ms gives each added stop's requested duration, in order.

Reads only bksim's trace format ('<cycle> <port><bit> <level>' per edge) and
G-code text; it builds nothing. Exit status 1 if a check fails.
"""

import argparse
import bisect
import math
import re
import sys

F_CPU = 16e6
STEPS = {"X": 80.0, "Y": 80.0, "Z": 400.0, "E": 500.0}      # RAMPS defaults
PINS = {"X": ("F0", "F1"), "Y": ("F6", "F7"), "Z": ("L3", "L1"), "E": ("A4", "A6")}
# Direction pin level for positive motion: Marlin writes INVERT_<A>_DIR for a
# negative move; the sim configuration has INVERT_Y_DIR true, the others false.
DIR_HIGH_POSITIVE = {"X": True, "Y": False, "Z": True, "E": True}
COREXY = False   # --corexy: the X/Y pins drive the A (x + y) and B (x - y) motors of a CoreXY


# ---- G-code ------------------------------------------------------------------------

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


def words(line):
    code = line.split(";", 1)[0]
    return {m.group(1).upper(): float(m.group(2)) for m in _WORD.finditer(code)}, code.strip()


def cut(args):
    lo, hi = (int(v) for v in args.layers.split("-"))
    keep = {k.strip() for k in args.keep.split(",") if k.strip()}
    out = ["; cut by tools/trace_stops.py from %s: layers %d-%d, features %s"
           % (args.gcode, lo, hi, ", ".join(sorted(keep))), "G21", "G90", "M82"]
    layer, feature, e, e_out = 0, None, 0.0, 0.0
    absolute_e = True
    out_absolute_e = True  # the E mode the output is in (its header says M82)
    dropped = False
    with open(args.gcode, encoding="utf-8", errors="replace") as f:
        for raw in f:
            line = raw.rstrip("\n")
            if line.startswith(";LAYER_CHANGE"):
                layer += 1
                feature = None
            elif line.startswith(";TYPE:"):
                feature = line[6:].strip()
            w, code = words(line)
            kept = lo <= layer <= hi and (feature is None or feature in keep) and not code.startswith(("M1", "G28", "M84"))
            if code.startswith("M82"):
                absolute_e = True
            elif code.startswith("M83"):
                absolute_e = False
            if kept:
                if not code.startswith(("M82", "M83")) and out_absolute_e != absolute_e:
                    # the source's M82/M83 was dropped with the lines before: say it here
                    out.append("M82 ; E mode of the source" if absolute_e else "M83 ; E mode of the source")
                out_absolute_e = absolute_e
                if dropped and absolute_e and abs(e - e_out) > 1e-9:
                    out.append("G92 E%.5f ; E where the dropped lines left it" % e)
                    e_out = e
                dropped = False
                out.append(line)
            elif code:
                dropped = True
            # E as the firmware would have it after this line
            if code.startswith(("G0", "G1")) and "E" in w and re.match(r"G0?[01]\b", code):
                e = w["E"] if absolute_e else e + w["E"]
                if kept:
                    e_out = e
            elif re.match(r"G92\b", code) and "E" in w:
                e = w["E"]
                if kept:
                    e_out = e
    with open(args.output, "w", encoding="utf-8") as f:
        f.write("\n".join(out) + "\n")
    print("%s: %d lines" % (args.output, len(out)))
    return 0


def _mapformat():
    """The host package's map module (bulgekit.bulge.mapformat), from this checkout."""
    import os
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "host"))
    from bulgekit.bulge import mapformat
    return mapformat


def gcode_e_only_steps(path, start):
    """E steps Marlin makes for each stop written as an extruder-only G0/G1, in
    order (positions held in steps rounded from mm, re-rounded at each G92 E).
    A stop is an E-only move forward; the first one after a retraction (an
    E-only move back) is the slicer's unretract, not a stop."""
    lround = _mapformat().round_half_away
    e, absolute_e, out = start["E"], True, []
    retracted = False
    at_step = lround(e * STEPS["E"])
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            w, code = words(line)
            g = re.match(r"([GM])0*(\d+)", code)
            if not g:
                continue
            c = g.group(1) + g.group(2)
            if c in ("G90", "M82"):
                absolute_e = True
            elif c in ("G91", "M83"):
                absolute_e = False
            elif c == "G92" and "E" in w:
                e = w["E"]
                at_step = lround(e * STEPS["E"])
            elif c in ("G0", "G1") and "E" in w:
                e = w["E"] if absolute_e else e + w["E"]
                target = lround(e * STEPS["E"])
                if not any(a in w for a in "XYZ"):
                    if target < at_step:
                        retracted = True
                    elif target > at_step:
                        if not retracted:
                            out.append(target - at_step)
                        retracted = False
                elif target > at_step:
                    retracted = False
                at_step = target
    return out


def gcode_end_state(path, start, segments=None, steps=None):
    """Final X Y Z E (host frame) and the filament the moves push (mm, net).
    If segments is a list, every extruding X/Y move is appended as (z, x0, y0, x1, y1).
    If steps is a list, the E steps Marlin makes for them are appended (one
    number): it holds E in steps rounded from the position in mm at each move,
    and G92 E sets that position again, so every G92 rounds once more."""
    pos = dict(start)
    absolute, absolute_e = True, True
    e_total = 0.0
    e_steps = 0
    lround = _mapformat().round_half_away  # Marlin's LROUND: half away from zero
    at_step = lround(pos["E"] * STEPS["E"])
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            w, code = words(line)
            if not code:
                continue
            g = re.match(r"([GM])0*(\d+)", code)
            if not g:
                continue
            c = g.group(1) + g.group(2)
            if c == "G90":
                absolute = absolute_e = True
            elif c == "G91":
                absolute = absolute_e = False
            elif c == "M82":
                absolute_e = True
            elif c == "M83":
                absolute_e = False
            elif c == "G92":
                for a in "XYZE":
                    if a in w:
                        pos[a] = w[a]
                if "E" in w:
                    at_step = lround(pos["E"] * STEPS["E"])
            elif c in ("G0", "G1"):
                x0, y0 = pos["X"], pos["Y"]
                for a in "XYZ":
                    if a in w:
                        pos[a] = w[a] if absolute else pos[a] + w[a]
                if "E" in w:
                    de = w["E"] - pos["E"] if absolute_e else w["E"]
                    if segments is not None and de > 0 and (x0, y0) != (pos["X"], pos["Y"]):
                        segments.append((pos["Z"], x0, y0, pos["X"], pos["Y"]))
                    e_total += de
                    pos["E"] += de
                    target = lround(pos["E"] * STEPS["E"])
                    e_steps += target - at_step
                    at_step = target
    if steps is not None:
        steps.append(e_steps)
    return pos, e_total


# ---- traces ------------------------------------------------------------------------

class Run:
    """Step events of one trace: times (cycles) and positions after each step."""

    def __init__(self, path, origin):
        pin_axis = {}
        for a, (step, direction) in PINS.items():
            pin_axis[step] = (a, "step")
            pin_axis[direction] = (a, "dir")
        level = {a: 0 for a in PINS}  # dir pins start low
        count = {a: 0 for a in PINS}
        self.xy = []           # (cycle, x count, y count) after each X or Y step
        self.e_steps = []      # (cycle, +1/-1)
        self.z = []
        self.last = 0
        self.first = None
        with open(path) as f:
            for line in f:
                parts = line.split()
                if len(parts) != 3 or parts[1] not in pin_axis:
                    continue
                cyc, (a, kind), v = int(parts[0]), pin_axis[parts[1]], parts[2] == "1"
                if kind == "dir":
                    level[a] = v
                    continue
                if not v:
                    continue
                d = 1 if level[a] == DIR_HIGH_POSITIVE[a] else -1
                if COREXY and a in "XY":
                    # an A or B step moves the head half a step along X and along Y:
                    # X and Y are counted in half steps (STEPS doubled), x = a + b, y = a - b
                    count["X"] += d
                    count["Y"] += d if a == "X" else -d
                else:
                    count[a] += d
                if self.first is None:
                    self.first = cyc
                self.last = cyc
                if a in "XY":
                    self.xy.append((cyc, count["X"], count["Y"]))
                elif a == "E":
                    self.e_steps.append((cyc, d))
                else:
                    self.z.append((cyc, count["Z"]))
        self.count = count
        self.origin = origin

    def mm(self, a, steps):
        return self.origin[a] + steps / STEPS[a]

    def head_still(self, c0, c1):
        """The longest time (cycles) in [c0, c1] with no X, Y or Z step."""
        if not hasattr(self, "_head"):
            self._head = sorted([c for c, _, _ in self.xy] + [c for c, _ in self.z])
        i, j = bisect.bisect_right(self._head, c0), bisect.bisect_left(self._head, c1)
        marks = [c0] + self._head[i:j] + [c1]
        return max(b - a for a, b in zip(marks, marks[1:]))

    def stops(self, gap_ms):
        """(start cycle, end cycle, x count, y count) of every X/Y gap >= gap_ms."""
        lim = gap_ms * 1e-3 * F_CPU
        out = []
        for (c0, x, y), (c1, _, _) in zip(self.xy, self.xy[1:]):
            if c1 - c0 >= lim:
                out.append((c0, c1, x, y))
        return out

    def stillness(self, c0, c1):
        """The longest time (cycles) in [c0, c1] with no step of any axis.

        A stop is the gap between two X/Y steps, but the other axes step near
        its ends: an E step can share the step event of the last X/Y step
        before it (a few µs later), and a piece whose leading axis is E steps
        E before its first X/Y step. The hold is the longest step-free stretch
        in between, not the time to the first step of any axis after c0."""
        if not hasattr(self, "_all"):  # every step of every axis, in time order
            self._all = sorted([c for c, _, _ in self.xy] + [c for c, _ in self.e_steps]
                               + [c for c, _ in self.z])
        i, j = bisect.bisect_right(self._all, c0), bisect.bisect_left(self._all, c1)
        marks = [c0] + self._all[i:j] + [c1]
        return max(b - a for a, b in zip(marks, marks[1:]))

    def z_at(self, cycle):
        """Z step count at this cycle (0 before the first Z step)."""
        if not hasattr(self, "_zc"):
            self._zc = [c for c, _ in self.z]
        i = bisect.bisect_right(self._zc, cycle)
        return self.z[i - 1][1] if i else 0

    def e_at(self, cycle):
        """Net E steps made up to and including this cycle."""
        import bisect
        if not hasattr(self, "_ec"):
            self._ec, self._ecum, n = [], [], 0
            for c, d in self.e_steps:
                n += d
                self._ec.append(c)
                self._ecum.append(n)
        i = bisect.bisect_right(self._ec, cycle)
        return self._ecum[i - 1] if i else 0


def per_stop(run, ref, added, args, origin):
    """One line per added stop; see the module doc. The k-th X/Y step is the
    same place on the path in both runs (same step counts)."""
    ms = lambda c: c / F_CPU * 1e3
    index = {c: i for i, (c, _, _) in enumerate(run.xy)}
    at = [index[c0] for c0, _, _, _ in added]
    # halfway (in X/Y steps) between consecutive stops, and the first and last steps
    marks = [0] + [(a + b) // 2 for a, b in zip(at, at[1:])] + [len(run.xy) - 1]
    lag = [(run.xy[i][0] - run.first) - (ref.xy[i][0] - ref.first) for i in marks]
    want_e = gcode_e_only_steps(args.gcode, origin) if args.gcode else []
    if want_e and len(want_e) != len(added):
        print("  (the file has %d extruder-only moves for %d added stops: not compared)"
              % (len(want_e), len(added)))
        want_e = []
    want_ms = [float(v) for v in args.stop_ms.split(",")] if args.stop_ms else []
    if args.verbose:
        print(" #   X/Y/Z still ms  all axes still ms  added ms  E steps (file)%s"
              % ("  requested ms" if len(want_ms) == len(added) else ""))
    heads, adds, e_bad = [], [], 0
    for k, (c0, c1, _, _) in enumerate(added):
        e_in = run.e_at(c1 - 1) - run.e_at(c0)
        heads.append(ms(run.head_still(c0, c1)))
        adds.append(ms(lag[k + 1] - lag[k]))
        line = "%2d  %14.3f  %17.3f  %8.2f  %7d" % (k, heads[-1], ms(run.stillness(c0, c1)), adds[-1], e_in)
        if want_e:
            e_bad += want_e[k] != e_in
            line += " (%d)%s" % (want_e[k], "" if want_e[k] == e_in else " MISMATCH")
        if len(want_ms) == len(added):
            line += "  %12g" % want_ms[k]
        if args.verbose:
            print(line)
    print("per stop: head (X/Y/Z) still min %.3f / mean %.3f / max %.3f ms; added min %.2f / mean %.2f "
          "/ max %.2f ms" % (min(heads), sum(heads) / len(heads), max(heads), min(adds),
                             sum(adds) / len(adds), max(adds)))
    if want_e:
        print("E steps while the head stands = the file's E-only move: %d of %d stops%s"
              % (len(added) - e_bad, len(added), "" if not e_bad else " MISMATCH"))
    return e_bad == 0


def read_map_points(path):
    """(z mm, x mm, y mm, weight) of every point of a .bkm file (host package)."""
    mapformat = _mapformat()
    with open(path, "rb") as f:
        m = mapformat.decode_map(f.read(), source=path)
    pts = []
    for layer in m.layers:
        for i, (x, y) in enumerate(m.points_mm(layer)):
            w = layer.weights[i] if layer.weights else 255
            pts.append((layer.z_cmm / 100.0, x, y, w))
    return pts


class Mesh:
    """A leveling mesh for runs with bed leveling on (MBL, bilinear ABL, UBL):
    a file of "x y z" lines (mm) on a rectangular grid, as probed or set with
    M421. The correction is bilinear inside the grid and the edge value
    outside it (keep the print inside the mesh); fade (M420 Z) scales it by
    1 - z/fade below the fade height and turns it off above."""

    def __init__(self, path, fade=0.0):
        rows = []
        with open(path, encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                line = line.split("#", 1)[0].strip()
                if not line:
                    continue
                try:
                    x, y, z = (float(v) for v in line.split())
                except ValueError:
                    raise SystemExit("%s:%d: expected 'x y z' in mm, got %r" % (path, n, line))
                rows.append((x, y, z))
        self.xs = sorted({r[0] for r in rows})
        self.ys = sorted({r[1] for r in rows})
        self.z = {(r[0], r[1]): r[2] for r in rows}
        if len(self.xs) < 2 or len(self.ys) < 2 or len(self.z) != len(self.xs) * len(self.ys) \
                or len(rows) != len(self.z):
            raise SystemExit("%s: not a full rectangular grid of at least 2 x 2 distinct points "
                             "(%d lines, %d x %d positions)" % (path, len(rows), len(self.xs), len(self.ys)))
        self.fade = fade

    @staticmethod
    def _cell(v, axis):
        v = min(max(v, axis[0]), axis[-1])
        i = max(0, min(len(axis) - 2, bisect.bisect_right(axis, v) - 1))
        return i, (v - axis[i]) / (axis[i + 1] - axis[i])

    def at(self, x, y):
        """Correction at (x, y) before fade, mm."""
        i, fx = self._cell(x, self.xs)
        j, fy = self._cell(y, self.ys)
        x0, x1, y0, y1 = self.xs[i], self.xs[i + 1], self.ys[j], self.ys[j + 1]
        lo = self.z[(x0, y0)] + (self.z[(x1, y0)] - self.z[(x0, y0)]) * fx
        hi = self.z[(x0, y1)] + (self.z[(x1, y1)] - self.z[(x0, y1)]) * fx
        return lo + (hi - lo) * fy

    def factor(self, z):
        return 1.0 if not self.fade else max(0.0, 1.0 - z / self.fade)

    def unlevel(self, x, y, z_phys):
        """The G-code z a physical (leveled) z at (x, y) came from."""
        m = self.at(x, y)
        if not self.fade:
            return z_phys - m
        z = (z_phys - m) / (1.0 - m / self.fade)
        return z if z < self.fade else z_phys

    def level(self, x, y, z):
        return z + self.at(x, y) * self.factor(z)


def expected_stop(segments, z, px, py, tol, min_piece):
    """Where the core's rule puts the stop for a point: on the first extruding
    move (in G-code order) that passes within tol, at the point's foot on it;
    a foot closer than min_piece to the move's start or end snaps there. A
    foot beyond the move's end is left to the next move when that one goes on
    from the end at the same z (it then takes the point at its foot, or at its
    start); otherwise the stop is at the end."""
    held = None  # the end a point beyond it would stop at
    for sz, x0, y0, x1, y1 in segments:
        if held is not None:
            if abs(sz - z) > 1e-3 or (x0, y0) != held:
                return held
        elif abs(sz - z) > 1e-3:
            continue
        dx, dy = x1 - x0, y1 - y0
        n = math.hypot(dx, dy)
        t = max(0.0, ((px - x0) * dx + (py - y0) * dy) / (n * n))
        tc = min(1.0, t)
        fx, fy = x0 + tc * dx, y0 + tc * dy
        if math.hypot(px - fx, py - fy) > tol:
            if held is not None:
                return held
            continue
        if t > 1.0:
            held = (x1, y1)
            continue
        if t * n < min_piece:
            return x0, y0
        if (1 - t) * n < min_piece:
            return x1, y1
        return fx, fy
    return held


def stops(args):
    origin = dict(zip("XYZE", (float(v) for v in args.origin.split(","))))
    run = Run(args.trace, origin)
    ok = True
    ms = lambda c: c / F_CPU * 1e3
    print("%s: steps X %d Y %d Z %d E %d, first..last step %.3f s"
          % (args.trace, run.count["X"], run.count["Y"], run.count["Z"], run.count["E"],
             ms(run.last - run.first) / 1e3))
    st = run.stops(args.gap)
    added = st
    if args.ref:
        ref = Run(args.ref, origin)
        rst = ref.stops(args.gap)
        refpos = {}
        for s in rst:
            refpos.setdefault((s[2], s[3]), []).append(s)
        added, matched = [], 0
        for s in st:
            lst = refpos.get((s[2], s[3]))
            if lst:
                lst.pop(0)
                matched += 1
                if not lst:
                    del refpos[(s[2], s[3])]
            else:
                added.append(s)
        missing = sum(len(v) for v in refpos.values())
        print("stops (gap >= %.1f ms): %d here, %d in the reference; %d at reference positions, "
              "%d added, %d reference stops missing"
              % (args.gap, len(st), len(rst), matched, len(added), missing))
        if missing:
            ok = False
        de = run.count["E"] - ref.count["E"]
        print("time first..last step: %.3f s here, %.3f s reference, %+.3f s"
              % (ms(run.last - run.first) / 1e3, ms(ref.last - ref.first) / 1e3,
                 ms((run.last - run.first) - (ref.last - ref.first)) / 1e3))
        if added:
            print("added time per added stop: %.2f ms"
                  % (ms((run.last - run.first) - (ref.last - ref.first)) / len(added)))
        print("E steps: %d here, %d reference, difference %d" % (run.count["E"], ref.count["E"], de))
        if args.extra is not None and not args.fallback:
            want = round(len(added) * args.extra * STEPS["E"])
            good = abs(de - want) <= 1
            ok &= good
            print("  expected %d stops x %.3f mm x %g steps/mm = %d: %s"
                  % (len(added), args.extra, STEPS["E"], want, "ok" if good else "MISMATCH"))
    if args.ref and added and len(run.xy) == len(ref.xy):
        # Extra E per stop: both runs make the same number of X/Y steps, so the
        # k-th X/Y step is the same place on the path. The E lead of this run
        # over the reference grows by the extra of each stop in the piece after it.
        index = {c: i for i, (c, _, _) in enumerate(run.xy)}
        lead = []
        for c0, _, _, _ in added:
            i = index[c0]
            lead.append(run.e_at(c0) - ref.e_at(ref.xy[i][0]))
        lead.append(run.count["E"] - ref.count["E"])
        per = [b - a for a, b in zip(lead, lead[1:])]
        print("extra E steps per stop (E lead over the reference from one stop to the next): "
              "min %d, max %d, mean %.2f; lead at the first stop %d" % (min(per), max(per), sum(per) / len(per), lead[0]))
        if args.verbose:
            print("  " + " ".join(str(v) for v in per))
    elif args.ref and added:
        print("X/Y step counts differ from the reference (%d vs %d): no per-stop E" % (len(run.xy), len(ref.xy)))
    if args.ref and added and len(run.xy) == len(ref.xy):
        ok &= per_stop(run, ref, added, args, origin)
    durs = [ms(c1 - c0) for c0, c1, _, _ in added]
    if durs:
        print("added stops: %d, duration min %.4f / mean %.4f / max %.4f ms"
              % (len(durs), min(durs), sum(durs) / len(durs), max(durs)))
        # The hold: every axis still (see Run.stillness; E steps next to the
        # X/Y gap's ends are not part of it).
        holds = [ms(run.stillness(c0, c1)) for c0, c1, _, _ in added]
        if holds:
            print("  hold (longest time with no step of any axis, E and Z included): "
                  "min %.4f / mean %.4f / max %.4f ms" % (min(holds), sum(holds) / len(holds), max(holds)))
        if args.stop_ms:
            want = [float(v) for v in args.stop_ms.split(",")]
            if len(want) != len(added):
                print("  --stop-ms lists %d stops, the run made %d added stops: MISMATCH"
                      % (len(want), len(added)))
                ok = False
            else:
                heads = [ms(run.head_still(c0, c1)) for c0, c1, _, _ in added]
                bad = [k for k, (h, w) in enumerate(zip(heads, want)) if abs(h - w) > args.dwell_tol]
                ok &= not bad
                print("  head still vs --stop-ms +- %.2f ms: %s"
                      % (args.dwell_tol, "all within" if not bad else "stops %s outside" % bad))
        if args.dwell is not None and not args.map:
            bad = [d for d in durs if abs(d - args.dwell) > args.dwell_tol]
            ok &= not bad
            print("  requested %d ms +- %.2f: %s" % (args.dwell, args.dwell_tol,
                                                    "all within" if not bad else "%d outside" % len(bad)))
    # Extra E per stop: E steps from the stop to the next stop or section end,
    # minus what the same stretch takes in the reference run.
    segments = []
    mesh = Mesh(args.mesh, args.fade) if args.mesh else None
    z_in_hold = 0
    if args.gcode:
        gcode_end_state(args.gcode, origin, segments)
    if args.map:
        pts = read_map_points(args.map)
        used = set()
        stop_weight = {}
        worst = worst_foot = 0.0
        print(" #   stop at X,Y (mm)      z     nearest point (mm)   dist mm  expected at (mm)    off mm  w   duration ms")
        for k, (c0, c1, x, y) in enumerate(added):
            sx, sy = run.mm("X", x), run.mm("Y", y)
            sz = run.mm("Z", run.z_at(c0))
            if mesh:
                # the map and the G-code are in unleveled z
                sz = mesh.unlevel(sx, sy, sz)
                if run.z_at(c1) != run.z_at(c0):
                    z_in_hold += 1
            best = None
            for j, (pz, px, py, w) in enumerate(pts):
                if abs(pz - sz) > 0.01 + 1e-6:
                    continue
                d = math.hypot(px - sx, py - sy)
                if best is None or d < best[0]:
                    best = (d, j)
            if best is None:
                print("%2d  %8.3f,%8.3f  %5.2f  no point on this layer" % (k, sx, sy, sz))
                ok = False
                continue
            d, j = best
            worst = max(worst, d)
            used.add(j)
            pz, px, py, w = pts[j]
            stop_weight[k] = w
            ft = expected_stop(segments, sz, px, py, args.tolerance, args.min_piece) if segments else None
            off = math.hypot(ft[0] - sx, ft[1] - sy) if ft else float("nan")
            if ft:
                worst_foot = max(worst_foot, off)
            if args.verbose:
                print("%2d  %8.3f,%8.3f  %5.2f  %8.3f,%8.3f  %6.3f  %8.3f,%8.3f  %6.3f  %3d  %9.4f"
                      % (k, sx, sy, sz, px, py, d, ft[0] if ft else 0, ft[1] if ft else 0, off, w, ms(c1 - c0)))
        print("map points %d, matched by a stop %d, largest stop-to-point distance %.3f mm"
              % (len(pts), len(used), worst))
        if mesh:
            print("stops with a Z step during the hold: %d" % z_in_hold)
            ok &= z_in_hold == 0
        ok &= len(used) == len(pts) == len(added) and worst <= args.tolerance
        if args.dwell is not None:
            # a point's dwell is P * w / 255, rounded, as the firmware computes it
            want = {k: (args.dwell * w + 127) // 255 for k, w in stop_weight.items()}
            bad = [k for k, w in want.items() if abs(ms(added[k][1] - added[k][0]) - w) > args.dwell_tol]
            ok &= not bad
            print("  requested %d ms x w/255 (%s ms) +- %.2f: %s"
                  % (args.dwell, ", ".join(str(v) for v in sorted(set(want.values()))), args.dwell_tol,
                     "all within" if not bad else "%d outside" % len(bad)))
        if segments:
            # The step grid allows half a step on each axis.
            lim = math.hypot(0.5 / STEPS["X"], 0.5 / STEPS["Y"]) + 1e-6
            print("largest distance from a stop to where the planner's rule puts it: %.4f mm "
                  "(half a step on X and Y: %.4f mm)" % (worst_foot, lim))
            ok &= worst_foot <= lim
    if args.gcode:
        counted = []
        end, e_total = gcode_end_state(args.gcode, origin, steps=counted)
        want_e = counted[0]  # as Marlin rounds: once per move, again at each G92 E
        print("G-code: net E %.5f mm = %d steps; final X%.3f Y%.3f Z%.3f E%.5f"
              % (e_total, want_e, end["X"], end["Y"], end["Z"], end["E"]))
        extra_steps = 0
        if args.extra is not None and not args.fallback:
            extra_steps = round(len(added) * args.extra * STEPS["E"])
        good = abs(run.count["E"] - (want_e + extra_steps)) <= 1
        ok &= good
        print("  E steps %d = G-code %d + %d stops x %g mm (%d): %s"
              % (run.count["E"], want_e, len(added), args.extra or 0, extra_steps, "ok" if good else "MISMATCH"))
        for a in "XYZ":
            got = run.mm(a, run.count[a])
            want = end[a]
            if a == "Z" and mesh:
                want = mesh.level(end["X"], end["Y"], end["Z"])  # the steppers stand at the leveled z
            if abs(got - want) > 0.5 / STEPS[a] + 1e-9:
                print("  final %s: steps give %.4f, expected %.4f: MISMATCH" % (a, got, want))
                ok = False
        if args.log:
            with open(args.log, encoding="utf-8", errors="replace") as f:
                reports = re.findall(r"X:(-?[\d.]+) Y:(-?[\d.]+) Z:(-?[\d.]+) E:(-?[\d.]+) Count", f.read())
            if not reports:
                print("  no M114 report in %s" % args.log)
                ok = False
            else:
                r = dict(zip("XYZE", (float(v) for v in reports[-1])))
                good = all(abs(r[a] - end[a]) <= 0.006 for a in "XYZE")
                ok &= good
                print("  last M114: X:%.2f Y:%.2f Z:%.2f E:%.2f vs G-code X%.2f Y%.2f Z%.2f E%.2f: %s"
                      % (r["X"], r["Y"], r["Z"], r["E"], end["X"], end["Y"], end["Z"], end["E"],
                         "ok" if good else "MISMATCH"))
    print("RESULT:", "ok" if ok else "FAILED")
    return 0 if ok else 1


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cut", help="short print from a sliced file")
    c.add_argument("gcode")
    c.add_argument("--layers", required=True, help="first-last layer, 1-based (;LAYER_CHANGE count)")
    c.add_argument("--keep", required=True, help="comma-separated ;TYPE: names to keep")
    c.add_argument("-o", "--output", required=True)
    s = sub.add_parser("stops", help="stops, E and final position of a trace")
    s.add_argument("trace")
    s.add_argument("--origin", default="0,0,0,0", help="X,Y,Z,E (mm) where the trace starts")
    s.add_argument("--gap", type=float, default=4.0, help="a stop is an X/Y gap of at least this, ms")
    s.add_argument("--ref", help="trace of the same G-code with the feature off")
    s.add_argument("--map", help="bulge map (.bkm) to match the added stops against")
    s.add_argument("--tolerance", type=float, default=0.25, help="largest stop-to-point distance, mm")
    s.add_argument("--min-piece", type=float, default=0.1, help="BK_MIN_PIECE_MM: feet closer to a move end snap to it")
    s.add_argument("--gcode", help="the G-code that was sent (for E and final position)")
    s.add_argument("--log", help="UART output with the final M114")
    s.add_argument("--dwell", type=int, help="requested dwell, ms")
    s.add_argument("--dwell-tol", type=float, default=1.0)
    s.add_argument("--stop-ms", help="each added stop's requested duration, ms, comma-separated "
                   "(checked against the time the head stands, +- --dwell-tol)")
    s.add_argument("--e-steps", type=float, help="the firmware's E steps/mm (default 500)")
    s.add_argument("--extra", type=float, help="extra filament per stop, mm")
    s.add_argument("--fallback", action="store_true", help="the G-code carries the extra E itself (G4 rewrite)")
    s.add_argument("--corexy", action="store_true", help="CoreXY: the X/Y pins step the A and B "
                   "motors (80 steps/mm each); positions and stops are read from them")
    s.add_argument("-v", "--verbose", action="store_true", help="one line per added stop")
    s.add_argument("--mesh", help="leveling mesh, 'x y z' lines (mm): stop layers and the final Z "
                   "are read with it, and no Z step may fall in a hold")
    s.add_argument("--fade", type=float, default=0.0, help="fade height of the mesh (M420 Z), mm; 0: none")
    args = ap.parse_args(argv)
    if getattr(args, "e_steps", None):
        STEPS["E"] = args.e_steps
    if getattr(args, "corexy", False):
        global COREXY
        COREXY = True
        STEPS["X"] = STEPS["Y"] = 2 * 80.0
    return cut(args) if args.cmd == "cut" else stops(args)


if __name__ == "__main__":
    sys.exit(main())
