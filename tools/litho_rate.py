#!/usr/bin/env python3
"""Extruder rate on a lithophane's mid-line, through the firmware core and the estimator.

    python3 tools/litho_rate.py OUT/NAME.litho.gcode [OUT/NAME.stock.gcode] [--accel 1000 3000]

For the width-mode file the firmware core (bkcore, tools/bkcore) runs the file as the Marlin
adapter would: M723 retimes every extruding move. Its output (one line per move: X Y Z, the
move's filament and the speed the core chose) is turned back into G-code, each move tagged with
the ;TYPE: of the G1 it came from, and timed by the Marlin-style estimator (bulgekit.gcode.estimate)
with acceleration and junction deviation. A stock file is timed as it is (eq. 2: its F already
holds the speed). Printed per file, over the mid-line after the first layer:

  cruise   share of extruding time within +-5 % of the set rate, counting each move at its own
           speed (no ramps): what the core or eq. 2 asked for; only pieces capped at the head's
           maximum speed can fall outside
  planned  the same share with the estimator's trapezoids: time spent accelerating between pieces
           of different width runs the extruder below (or above) the set rate
and the time lost to ramps, i.e. planned time minus cruise time on the mid-line.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))

from bulgekit.gcode import estimate  # noqa: E402

_LINE = re.compile(r"^line X(\S+) Y(\S+) Z(\S+) E(\S+) F(\S+)$")


def tagged_core_gcode(path: Path, bkcore: str) -> tuple[str, float]:
    """bkcore's moves as G-code (M83, explicit F), with the source file's ;TYPE: and ;LAYER:
    comments put back before the move they preceded. Returns (gcode, set mid-line rate mm/s)."""
    src = path.read_text()
    r = subprocess.run([bkcore], input=src, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        sys.exit(f"{path}: bkcore failed: {r.stdout[-500:]}{r.stderr[-500:]}")
    lines = [m for m in map(_LINE.match, r.stdout.splitlines()) if m]
    notes, out = [], ["G90", "M83"]
    it = iter(lines)
    for raw in src.splitlines():
        if raw.startswith((";TYPE:", ";LAYER:")):
            notes.append(raw)
        elif raw.startswith("G1 "):
            m = next(it)
            out.extend(notes)
            notes = []
            x, y, z, e, f = (float(v) for v in m.groups())
            out.append(f"G1 X{x:.3f} Y{y:.3f} Z{z:.3f} E{e:.5f} F{f:.2f}")
    if next(it, None) is not None:
        sys.exit(f"{path}: bkcore printed more moves than the file has G1 lines")
    return "\n".join(out) + "\n", mid_rate(src)


def mid_rate(src: str) -> float:
    """The mid-line's extruder rate (mm/s of filament) from the file's options block."""
    opts = dict(re.findall(r"^; (\w+) = (.+)$", src, re.M))
    q = float(opts["wall_speed"]) * float(opts["line_width"]) * float(opts["layer_height"]) \
        if opts.get("paper_rate") == "true" else float(opts["infill_flow"])
    return q / (math.pi * float(opts["filament"]) ** 2 / 4)


def report(name: str, gcode_text: str, rate: float, accel: float) -> dict:
    m = estimate.Machine(accel=accel, travel_accel=accel, retract_accel=accel, junction_deviation=0.013,
                         max_feedrate=dict(X=300, Y=300, Z=5, E=25), lookahead=None)
    res = estimate.estimate_lines(gcode_text.splitlines(), m)
    mid = mid_line_mask(res)
    cruise = estimate.e_rate_share(res, mask=mid, ref=rate, tol=0.05, cruise_only=True)
    planned = estimate.e_rate_share(res, mask=mid, ref=rate, tol=0.05)
    b = res.blocks
    t_plan = float(estimate.block_times(res)[mid].sum())
    t_cruise = float((b["length"] / b["nominal_speed"])[mid].sum())
    out = dict(file=name, accel=accel, total_s=res.total_s, mid_line_s=t_plan, cruise=cruise,
               planned=planned, ramp_loss_s=t_plan - t_cruise)
    print(f"{name} @ {accel:g} mm/s^2: total {res.total_s / 60:.1f} min; mid-line {t_plan:.0f} s, "
          f"{100 * cruise:.1f} % of its extruding time within 5 % of {rate:.4f} mm/s at cruise, "
          f"{100 * planned:.1f} % with ramps; ramps cost {t_plan - t_cruise:.0f} s")
    return out


def mid_line_mask(res):
    """Extruding mid-line blocks after the first layer."""
    b = res.blocks
    if "mid-line" not in res.features:
        sys.exit("no ;TYPE:mid-line in the file: not a bulgekit lithophane")
    return estimate.extruding(res) & (b["layer"] >= 1) & (b["feature"] == res.features.index("mid-line"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", type=Path, help="NAME.litho.gcode and/or NAME.stock.gcode")
    ap.add_argument("--accel", type=float, nargs="+", default=[1000.0, 3000.0])
    ap.add_argument("--bkcore", default=os.environ.get("BULGEKIT_BKCORE", str(ROOT / ".build/bin/bkcore")))
    a = ap.parse_args(argv)
    for f in a.files:
        text = f.read_text()
        if "M723 S1" in text:
            g, rate = tagged_core_gcode(f, a.bkcore)
        else:
            g, rate = text, mid_rate(text)
        for acc in a.accel:
            report(f.name, g, rate, acc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
