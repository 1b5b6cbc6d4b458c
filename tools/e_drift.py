#!/usr/bin/env python3
"""How far Marlin's E position drifts from the file's own in a G-code file.

    python3 tools/e_drift.py GCODE [STEPS_PER_MM ...]

Marlin adds each relative E (M83) to its position in float32 (G0_G1: destination = current
+ E) and plans to lround(position x steps/mm); absolute E (M82) is taken as written. This adds
the file's E the same way and prints the largest difference from the exact sum, in mm and in
steps: why the stock fallback sets E with G92 before each stop in M83 files (docs/host.md,
"Stops on stock firmware").
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "host"))

from bulgekit.gcode import GcodeState, parse_lines  # noqa: E402


def main(argv):
    if not argv:
        sys.exit(__doc__.strip().splitlines()[2].strip())
    path, spms = argv[0], [float(v) for v in argv[1:]] or [93.0, 415.0]
    f = np.float32
    st = GcodeState()
    marlin, worst, moves = f(0), 0.0, 0
    with open(path, encoding="utf-8", errors="replace") as src:
        for ln in parse_lines(src, path, st):
            if ln.cmd == "G92" and ln.words and "E" in ln.words:
                marlin = f(ln.words["E"])
            for m in ln.moves:
                if m.e == 0:
                    continue
                moves += 1
                marlin = f(marlin + f(m.e)) if not st.abs_e else f(m.e_start + m.e)
                worst = max(worst, abs(float(marlin) - (m.e_start + m.e)))
    print(f"{path}: {moves} moves with E, final E {st.e:.3f} mm, largest drift {worst:.4f} mm = "
          + ", ".join(f"{worst * s:.2f} steps at {s:g}/mm" for s in spms))


if __name__ == "__main__":
    main(sys.argv[1:])
