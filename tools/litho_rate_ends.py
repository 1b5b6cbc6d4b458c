#!/usr/bin/env python3
"""Where a lithophane band's mid-line leaves the set extruder rate: near its stretches' ends (the
head starting and stopping) or inside them (the picture's steps). Estimator figures, exact over
the trapezoids (docs/verification/lithophane.md, "Extruder rate on the mid-line, verified").

    python3 tools/litho_rate_ends.py out/band.litho.gcode [--end-mm 3] [--rate 3.326]

The machine is the file's own (M204 etc., `--honour-file-limits`), 16-block look-ahead; the set
rate defaults to the file's own mid-line rate (its options block, as tools/litho_rate.py reads it:
8 mm^3/s at the defaults, less with --accel below 3000).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "host"))

from bulgekit.gcode import estimate as es  # noqa: E402
from litho_rate import mid_rate  # noqa: E402


def split(path: str, end_mm: float, rate: float) -> tuple[list, int]:
    """([(part, seconds, share of the mid-line's time, share of that part within +-5 % of rate)],
    the number of stretches)."""
    r = es.estimate_file(path, es.Machine(honour_file_limits=True, lookahead=16))
    b = r.blocks
    if "mid-line" not in r.features:
        raise SystemExit(f"{path}: no mid-line after the first layer")
    mid = es.extruding(r) & (b["layer"] >= 1) & (b["feature"] == r.features.index("mid-line"))
    idx = np.flatnonzero(mid)
    if not len(idx):
        raise SystemExit(f"{path}: no mid-line after the first layer")
    cut = np.flatnonzero(np.diff(idx) > 1)
    starts, ends = np.append(idx[0], idx[cut + 1]), np.append(idx[cut], idx[-1])
    near = np.zeros(len(b), bool)
    for s, e in zip(starts, ends):               # a stretch: mid-line blocks one after another
        run = np.cumsum(b["length"][s:e + 1])
        near[s:e + 1] = (run - b["length"][s:e + 1] < end_mm) | (run[-1] - run + b["length"][s:e + 1] <= end_mm)
    t = es.block_times(r)
    total = t[mid].sum()
    out = []
    for part, m in (("all", mid), (f"within {end_mm:g} mm of a stretch's end", mid & near),
                    ("inside the stretches", mid & ~near)):
        out.append((part, float(t[m].sum()), float(t[m].sum() / total),
                    es.e_rate_share(r, mask=m, ref=rate) if m.any() else float("nan")))
    return out, len(starts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("gcode", nargs="+")
    ap.add_argument("--end-mm", type=float, default=3.0, help="how far from a stretch's end counts as its end")
    ap.add_argument("--rate", type=float, default=None,
                    help="set rate, mm/s of filament (default: the file's own mid-line rate)")
    a = ap.parse_args(argv)
    for path in a.gcode:
        rate = a.rate if a.rate is not None else mid_rate(Path(path).read_text(errors="replace"))
        parts, n = split(path, a.end_mm, rate)
        print(f"{path}: {n} mid-line stretches after the first layer")
        for part, sec, share, inside in parts:
            print(f"  {part}: {sec:.2f} s ({100 * share:.1f} % of the mid-line), {100 * inside:.1f} % within +-5 %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
