#!/usr/bin/env python3
"""Fit G2/G3 arcs to runs of G1 moves of a sliced file, as ArcWelder or a slicer's arc fitting
does, to make arc-fitted test input from a real slice (Debian's PrusaSlicer 2.5 has no arc
fitting; docs/host.md, "Arcs").

    arc_fit.py IN.gcode OUT.gcode [--tolerance 0.025] [--min-moves 3] [--max-radius 500]

A run of consecutive extruding moves "G1 X.. Y.. E.." (an F word allowed on the first only, a
comment after the words ignored; any other line ends a run) whose start and ends lie within
--tolerance mm of one circle, and so do the middles of its moves, turning one way and less than
a whole turn, becomes one G2 (clockwise) or G3 with the run's last X and Y as written, I and J to
the circle's centre (3 decimals), and its E: the last move's E word with M82, the run's E words
added up exactly (as decimals) with M83; the first move's F goes on the arc. Every other line is
copied as it is. G91 (relative X/Y) files are refused. The summary on stderr says how many moves
became how many arcs and how far the arcs lie from the moves they replace.

Used by host/tests/bulge/test_arcs.py on host/tests/data/prusa_cyl.gcode and prusa_cyl_m83.gcode.
"""
from __future__ import annotations

import argparse
import math
import re
import sys
from decimal import Decimal

_MOVE = re.compile(r"^G1 X(-?[0-9.]+) Y(-?[0-9.]+) E(-?[0-9.]+)(?: F([0-9.]+))?[ \t]*(;.*)?$")
_E_WORD = re.compile(r"\bE(-?[0-9.]+)")
_XY_WORD = re.compile(r"\b([XY])(-?[0-9.]+)")


def _circle(a, b, c):
    """Centre and radius of the circle through three points (None: on a line)."""
    (ax, ay), (bx, by), (cx, cy) = a, b, c
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-12:
        return None
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return (ux, uy), math.hypot(ax - ux, ay - uy)


def fit(pts, tol: float, max_radius: float):
    """The arc through the points pts (the run's start, then each move's end): (centre, radius,
    sweep in radians, counter-clockwise positive), or None when they do not lie on one within tol
    (the ends and each move's middle), turning one way, less than a whole turn."""
    got = _circle(pts[0], pts[len(pts) // 2], pts[-1])
    if got is None:
        return None
    (cx, cy), r = got
    if r > max_radius:
        return None
    sweep, sign = 0.0, 0
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        for x, y in ((x1, y1), ((x0 + x1) / 2, (y0 + y1) / 2)):
            if abs(math.hypot(x - cx, y - cy) - r) > tol:
                return None
        d = math.atan2((x0 - cx) * (y1 - cy) - (y0 - cy) * (x1 - cx),
                       (x0 - cx) * (x1 - cx) + (y0 - cy) * (y1 - cy))
        s = 1 if d > 0 else -1 if d < 0 else 0
        if s == 0 or (sign and s != sign):
            return None
        sign = s
        sweep += d
    if abs(sweep) >= 2 * math.pi - 1e-3:
        return None
    return (cx, cy), r, sweep


class Fitter:
    def __init__(self, tol: float, min_moves: int, max_radius: float):
        self.tol, self.min_moves, self.max_radius = tol, min_moves, max_radius
        self.x = self.y = self.e = 0.0
        self.abs_e = True
        self.run: list = []            # (x, y, E text, F text, line) of the moves of the run
        self.start = (0.0, 0.0)
        self.moves_in = self.arcs = self.moves_fitted = 0
        self.deviation = 0.0           # the farthest a replaced move's end or middle lies from its arc

    def line(self, raw: str, out: list) -> None:
        text = raw.rstrip("\r\n")
        mt = _MOVE.match(text)
        e = float(mt.group(3)) if mt else 0.0
        if mt and (not self.run or mt.group(4) is None) and (e > self.e if self.abs_e else e > 0):
            if not self.run:
                self.start = (self.x, self.y)
            self.run.append((float(mt.group(1)), float(mt.group(2)), mt.group(3), mt.group(4), raw))
            self.x, self.y = self.run[-1][0], self.run[-1][1]
            self.e = e if self.abs_e else self.e
            return
        self.flush(out)
        if mt and mt.group(4) is not None and (e > self.e if self.abs_e else e > 0):
            self.line(raw, out)        # a move with an F word starts a run
            return
        self.state(text)
        out.append(raw)

    def state(self, text: str) -> None:
        code = text.split(";", 1)[0].strip().upper()
        head = code.split(None, 1)[0] if code else ""
        if head in ("M82", "G90"):
            self.abs_e = True
        elif head == "M83":
            self.abs_e = False
        elif head == "G91":
            raise SystemExit("arc_fit: relative X/Y (G91) is not supported")
        if head in ("G0", "G1", "G2", "G3", "G92"):
            for k, v in _XY_WORD.findall(code):
                if k == "X":
                    self.x = float(v)
                else:
                    self.y = float(v)
            e = _E_WORD.search(code)
            if e and self.abs_e:
                self.e = float(e.group(1))

    def flush(self, out: list) -> None:
        run, i = self.run, 0
        self.run = []
        self.moves_in += len(run)
        pts = [self.start] + [(m[0], m[1]) for m in run]
        while i < len(run):
            j = i + self.min_moves
            best = None
            while j <= len(run):
                got = fit(pts[i:j + 1], self.tol, self.max_radius)
                if got is None:
                    break
                best = (j, got)
                j += 1
            if best is None:
                out.append(run[i][4])
                i += 1
                continue
            j, ((cx, cy), r, sweep) = best
            out.append(self.arc(run[i:j], pts[i], cx, cy, sweep) + "\n")
            self.deviation = max(self.deviation, _deviation(pts[i:j + 1], pts[i], cx, cy))
            self.arcs += 1
            self.moves_fitted += j - i
            i = j

    def arc(self, moves, start, cx, cy, sweep) -> str:
        last = moves[-1]
        e = last[2] if self.abs_e else _plain(sum(Decimal(m[2]) for m in moves))
        x, y = _XY_WORD.findall(_MOVE.match(last[4].rstrip("\r\n")).group(0))[:2]
        i, j = _round3(cx - start[0]), _round3(cy - start[1])
        f = f" F{moves[0][3]}" if moves[0][3] is not None else ""
        return f"{'G3' if sweep > 0 else 'G2'} X{x[1]} Y{y[1]} I{i} J{j} E{e}{f}"


def _round3(v: float) -> str:
    s = f"{v:.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _plain(d: Decimal) -> str:
    s = format(d, "f")
    return s.rstrip("0").rstrip(".") if "." in s else s


def _deviation(pts, start, cx, cy) -> float:
    """How far the moves' ends and middles lie from the arc as written: the centre rounded to
    3 decimals from the start, radius from the start (as a G-code reader takes it)."""
    ccx = start[0] + float(_round3(cx - start[0]))
    ccy = start[1] + float(_round3(cy - start[1]))
    r = math.hypot(start[0] - ccx, start[1] - ccy)
    worst = 0.0
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        for x, y in ((x1, y1), ((x0 + x1) / 2, (y0 + y1) / 2)):
            worst = max(worst, abs(math.hypot(x - ccx, y - ccy) - r))
    return worst


def fit_text(lines, tol: float = 0.025, min_moves: int = 3, max_radius: float = 500.0):
    """(the arc-fitted lines, the Fitter with its counts) of a file's lines."""
    f = Fitter(tol, min_moves, max_radius)
    out: list[str] = []
    for raw in lines:
        f.line(raw, out)
    f.flush(out)
    return out, f


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--tolerance", type=float, default=0.025,
                    help="mm: how far a move's end or middle may lie from the arc")
    ap.add_argument("--min-moves", type=int, default=3, help="the fewest moves an arc replaces")
    ap.add_argument("--max-radius", type=float, default=500.0, help="mm: no flatter arcs")
    a = ap.parse_args(argv)
    with open(a.src, encoding="utf-8", newline="") as fh:
        out, f = fit_text(fh, a.tolerance, a.min_moves, a.max_radius)
    with open(a.dst, "w", encoding="utf-8", newline="") as fh:
        fh.writelines(out)
    print(f"arc_fit: {f.moves_fitted} of {f.moves_in} extruding moves became {f.arcs} arcs "
          f"(within {f.deviation:.4f} mm of the moves they replace)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
