#!/usr/bin/env python3
"""Where a word put on a face of a sliced part stops the head (docs/host.md, "Faces and corners").

    python3 tools/face_check.py GCODE [--text BOX] [--size 5] [--face 2] [--align center] [--at 0,5]

Builds the word with --face/--align as `bulgekit build` does, runs the stock rewrite (and with it
the reference planner, fallback.RefPlanner) over the file, and takes every stop the planner makes:
its u on the wall of its layer, and the face that holds it. Prints the stops on the face and off
it, the stops' u extent and its middle, and how far its aligned end (or middle) lies from the
face's start, middle or end plus U.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "host"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("gcode")
    ap.add_argument("--text", default="BOX")
    ap.add_argument("--size", type=float, default=5.0)
    ap.add_argument("--face", type=int, default=2)
    ap.add_argument("--align", default="center")
    ap.add_argument("--at", default="0,5")
    a = ap.parse_args(argv)
    from bulgekit.bulge import api
    from bulgekit.bulge.strokes import on_face, text_strokes
    u, v = (float(x) for x in a.at.split(","))
    strokes = on_face(text_strokes(a.text, a.size, u0=u, v0=v), a.face, a.align, u)
    planners = []
    with tempfile.TemporaryDirectory() as d:
        out = api.build(a.gcode, strokes, d)
        # the stock rewrite's planner run, again, to keep its stops
        api.fallback_gcode(a.gcode, out.result.map_bytes, Path(d) / "again.gcode",
                           _on_plan=lambda p: planners.append(p))
    model = out.result.model
    by_z = {round(w.z * 100): w for w in model.walls}
    stops = planners[-1].stops
    on, off, per_layer = 0, 0, {}
    for st in stops:
        w = by_z[st.layer_z_cmm]
        s, _ = w.project(st.x, st.y)
        uu = float(w.u_of_s(s))
        f = w.faces[a.face - 1]
        uu = (uu - f.u0) % w.length + f.u0            # in the face's own turn of u
        if f.u0 <= uu <= f.u1:
            on += 1
        else:
            off += 1
        per_layer.setdefault(st.layer_z_cmm, []).append((uu, f))
    lo = min(x for p in per_layer.values() for x, _ in p)
    hi = max(x for p in per_layer.values() for x, _ in p)
    f0 = next(iter(per_layer.values()))[0][1]
    want = {"left": f0.u0, "center": f0.middle, "right": f0.u1}[a.align] + u
    got = {"left": lo, "center": (lo + hi) / 2, "right": hi}[a.align]
    print(f"{a.gcode}: '{a.text}' on face {a.face} ({a.align}, U {u:g}), {len(stops)} stops on "
          f"{len(per_layer)} layers: {on} on the face, {off} off it")
    print(f"face {a.face}: u {f0.u0:.2f}..{f0.u1:.2f} mm, middle {f0.middle:.2f}; the stops: u "
          f"{lo:.2f}..{hi:.2f}, middle {(lo + hi) / 2:.2f}; their {a.align} {got:.2f}, "
          f"{abs(got - want):.2f} mm from where it was asked for ({want:.2f})")
    for w in out.result.warnings:
        print(f"warning: {w}")
    return 0 if off == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
