#!/usr/bin/env python3
"""Benchmark the host commands on one large G-code (issue 12's goals, default 100 MB).

    python3 tools/bench_host.py [--mb 100] [--keep DIR]

The input and its map are made as in tools/bench_annotate.py (a real PrusaSlicer file's middle
layers repeated upward; one bulge point per layer). Each command runs in a fresh Python process
(this checkout's package) so that its time and peak memory (ru_maxrss) are its own. Printed per
command: seconds, MB/s, the ratio to a plain Python line read of the same file, peak MB, and the
goal where the issue sets one (build <= 15 s and annotate <= 8 s per 100 MB, peak <= 500 MB).
"""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT / "host"))

from bench_annotate import bench_setup, make_gcode, make_map  # noqa: E402

# run one CLI command in this process and report its peak memory (kB on Linux) on the last line
_RUNNER = ("import resource, runpy, sys\n"
           "sys.argv = ['bulgekit'] + sys.argv[1:]\n"
           "try:\n    runpy.run_module('bulgekit.cli', run_name='__main__')\n"
           "except SystemExit as e:\n    code = e.code\nelse:\n    code = 0\n"
           "print('maxrss', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
           "sys.exit(code)\n")


def plain_read(path: Path) -> float:
    t = time.perf_counter()
    with open(path, encoding="utf-8", errors="replace") as f:
        for _ in f:
            pass
    return time.perf_counter() - t


def run(args: list[str]) -> tuple[float, float]:
    env = {"PYTHONPATH": str(ROOT / "host"), "PATH": "/usr/bin:/bin"}
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _RUNNER, *args], capture_output=True, text=True,
                       env=env)
    dt = time.perf_counter() - t
    if r.returncode not in (0, 1):               # stats exits 1 on warnings; anything else fails
        sys.exit(f"bench_host: {' '.join(args[:2])} failed: {r.stderr[-500:]}")
    kb = int(r.stderr.strip().splitlines()[-1].split()[1])
    return dt, kb / 1024


def main() -> int:
    a, folder = bench_setup(__doc__)
    with folder as d:
        src, bkm = d / "big.gcode", d / "big.bkm"
        size, z_top = make_gcode(src, a.mb)
        bkm.write_bytes(make_map(z_top))
        mb = size / 1e6
        base = min(plain_read(src) for _ in range(2))
        print(f"input: {mb:.1f} MB; a plain Python line read takes {base:.2f} s ({mb / base:.0f} MB/s)")
        scale = 100.0 / mb                       # goals are per 100 MB
        cases = [
            # issue 12's build: map, annotated, stock fallback, stats and previews
            ("build", ["build", str(src), "--text", "HELLO", "--at", "5,3", "-o", str(d / "build"),
                       "--fallback", "--quiet"], 15.0),
            ("build -P", ["build", str(src), "--text", "HELLO", "--at", "5,3", "-o", str(d / "b2"),
                          "--no-preview", "--quiet"], None),
            ("annotate", ["annotate", str(src), str(bkm), "-o", str(d / "a.gcode"), "--quiet"], 8.0),
            ("fallback", ["fallback", str(src), str(bkm), "-o", str(d / "f.gcode"), "--quiet",
                          "--allow-unreached"], None),
            ("stats", ["stats", str(bkm), "--gcode", str(src), "--quiet"], None),
        ]
        print(f"{'command':<10}{'s':>8}{'MB/s':>8}{'x read':>8}{'peak MB':>9}  goal per 100 MB")
        for name, args, goal in cases:
            dt, peak = run(args)
            per100 = dt * scale
            # goals are checked on the full 100 MB: a small file's run is mostly start-up
            g = "" if goal is None or mb < 99 else f"<= {goal:g} s: {'met' if per100 <= goal else 'NOT met'}"
            # memory is checked on the full 100 MB only: it does not scale with size alone
            m = f"; peak <= 500 MB: {'met' if peak <= 500 else 'NOT met'}" if mb >= 99 else ""
            print(f"{name:<10}{dt:8.2f}{mb / dt:8.1f}{dt / base:8.1f}{peak:9.0f}  {g}{m}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
