#!/usr/bin/env python3
"""Figures of `bulgekit litho`'s paths on one picture (docs/verification/lithophane.md, "Clean paths"):
extruding moves (and where the plan's pieces lie: front wall, back wall, mid-line), the shortest
extruding move, the estimate with Marlin's 6-step rule and with every move planned (as Klipper
does), the volume laid per sample interval against the body's, and a linear grey ramp's printed
thickness.

    python3 tools/litho_paths_check.py PICTURE [--shape cylinder] [--block-rate N] [--out DIR]
    python3 tools/litho_paths_check.py PICTURE --gcode OLD.litho.gcode   # time an existing file only
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))

from bulgekit.gcode import estimate as es  # noqa: E402
from bulgekit import litho as lt  # noqa: E402


def timed(path, block_rate: float = 120.0) -> str:
    r6 = es.estimate_file(path, es.Machine())
    r0 = es.estimate_file(path, es.Machine(min_segment_steps=0))
    ext = es.extruding(r0)
    L = r0.blocks["length"][ext]
    out = (f"{path}: {int(ext.sum())} extruding moves, shortest {L.min():.4f} mm, "
           f"{int((L < 0.075).sum())} under 0.075 mm; estimate (3000 mm/s^2, JD 0.013, 16 blocks) "
           f"{r6.total_s:.1f} s with Marlin's 6-step rule, {r0.total_s:.1f} s with every move planned "
           f"({100 * (r0.total_s / r6.total_s - 1):+.2f} %)")
    if block_rate:
        # moves in XY the board would plan faster than block_rate a second (speed / length)
        b = r0.blocks
        xy = (b["dx"] != 0) | (b["dy"] != 0)
        rate = np.where(xy, b["nominal_speed"] / np.maximum(b["length"], 1e-12), 0.0)
        over = rate > block_rate * 1.001
        for name, sel in (("laid", ext), ("passing", xy & ~ext)):
            k = over & sel
            out += (f"; {name} moves over {block_rate:g} blocks/s: {int(k.sum())}"
                    + (f" (up to {rate[k].max():.0f})" if k.any() else ""))
    return out


def where(plan) -> str:
    """Laid pieces per layer of the picture (the foot left out) by where they lie: the front wall
    (the relief's side; a cylinder's outer wall), the back wall (inner), a planar plate's two
    ends, the mid-line(s). Joins written as connectors are not pieces of the plan."""
    o, fld = plan.options, plan.field
    n = {"front wall": 0, "back wall": 0, "ends": 0, "mid-line": 0}
    r_in = o.diameter / 2 - o.max_thickness
    for L in plan.layers[fld.n_foot:]:
        for s in L.sections:
            on = s.e > 0
            if s.kind != "wall":
                n["mid-line"] += int(on.sum())
                continue
            mid = (s.pts[:-1] + s.pts[1:]) / 2
            if o.shape == "planar":
                end = np.abs(np.diff(s.u)) < 1e-9     # across the layer, at one sample
                off = mid[:, 1]                       # from the back face
            else:
                end = np.zeros(len(on), bool)
                off = np.linalg.norm(mid, axis=1) - r_in
            front = off > o.min_thickness / 2
            n["ends"] += int((on & end).sum())
            n["front wall"] += int((on & ~end & front).sum())
            n["back wall"] += int((on & ~end & ~front).sum())
    k = len(plan.layers) - fld.n_foot
    return ("laid pieces per picture layer: "
            + ", ".join(f"{key} {v / k:.1f}" for key, v in n.items() if v or key != "ends")
            + f" ({k} layers, {len(fld.s)} samples each)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("picture")
    ap.add_argument("--shape", default="planar", choices=lt.SHAPES)
    ap.add_argument("--block-rate", type=float, default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--gcode", nargs="+", default=None, help="only time these files")
    a = ap.parse_args(argv)
    if a.gcode:
        for g in a.gcode:
            print(timed(g))
        return 0
    kw = {} if a.block_rate is None else {"block_rate": a.block_rate}
    out = a.out or Path(tempfile.mkdtemp(prefix="litho_paths_"))
    res = lt.make(a.picture, out, options=lt.LithoOptions(shape=a.shape, **kw))
    for key in ("gcode", "stock"):
        print(timed(res.paths[key], res.plan.options.block_rate))
    plan = res.plan
    print(where(plan))
    tot, dev = lt.laid_deviations(plan, plan.field.n_foot + 1)      # the first layer runs slower only
    d = np.concatenate(dev)
    inner = np.concatenate([x[1:-1] for x in dev]) if a.shape == "planar" else d
    print(f"volume laid per sample interval vs the body: median {100 * np.median(d):.3f} %, "
          f"99th percentile {100 * np.percentile(d, 99):.2f} %, largest {100 * d.max():.2f} % "
          f"({100 * inner.max():.2f} % without a plate's end intervals); per layer "
          f"{100 * min(tot):+.3f} .. {100 * max(tot):+.3f} %")
    s = res.stats
    print(f"gaps shared by the walls: {100 * s['gaps']['shared_share']:.2f} % of samples; fill ratio "
          f"{s['fill_ratio']}; JSON estimate {s['estimate']}")
    # a linear grey ramp, white to black, at the same options
    ramp = out / "ramp.png"
    from PIL import Image
    Image.fromarray(np.tile(np.linspace(255, 0, 256).round().astype(np.uint8), (24, 1))).save(ramp)
    rp = lt.plan_lithophane(ramp, lt.LithoOptions(shape=a.shape, height=4.0, stretch=True, **kw))
    t = lt.printed_thickness(rp)
    jumps = np.diff(t, axis=1)
    if a.shape == "cylinder":
        jumps = jumps[:, :-1]                                # the seam joins black to white
    print(f"grey ramp: printed thickness {t.min():.3f}..{t.max():.3f} mm, steps between neighbouring "
          f"samples {jumps.min():+.4f}..{jumps.max():+.4f} mm, |printed - planned| max "
          f"{np.abs(t - rp.field.t[rp.field.n_foot:]).max():.4f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
