#!/usr/bin/env python3
"""Time the compiled G-code scanner's feed() alone, in each of its modes, on one file.

    python3 tools/bench_scan.py FILE [--reps 5] [--so PATH] [--modes full,lean1,lean2,events]

FILE: e.g. the bench file, DIR/big.gcode after `python3 tools/bench_host.py --mb 100 --keep DIR`.

The file's bytes are read into memory first, then fed to a fresh Scanner in 2 MB parts as
movescan feeds them (a part's unused tail goes to the next one), on this thread only; the time is
the minimum over --reps runs, printed with MB/s, and the same for the thread's CPU time (which
other work on a shared machine disturbs less). Also printed per mode: a SHA-256 of everything
the scanner gives (records, move numbers, tops, lines, flagged lines, line ends, role names), so
that two builds can be checked for identical results: --so loads the module from another built
file (e.g. a copy of an older _scan*.so) instead of this checkout's.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.machinery
import importlib.util
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "host"))

from bulgekit import gcode  # noqa: E402
from bulgekit.gcode import movescan  # noqa: E402

PART = 2 << 20
MODES = {"full": {}, "lean1": {"lean": 1}, "lean2": {"lean": 2}, "events": {"events": True}}


def load(so: str | None):
    if so is None:
        if movescan._scan is None:
            sys.exit("bench_scan: bulgekit.gcode._scan is not built (cd host && python3 setup.py "
                     "build_ext --inplace)")
        return movescan._scan
    loader = importlib.machinery.ExtensionFileLoader("_scan", so)
    spec = importlib.util.spec_from_file_location("_scan", so, loader=loader)
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


def scanner(mod, mode: str):
    if mode == "events":                      # as gcode/estimate.py makes it
        return mod.Scanner((), (), movescan._classify, events=True)
    return mod.Scanner(sorted(gcode.OUTER_ROLES), sorted(gcode._S3D_ROLES), movescan._classify,
                       **MODES[mode])


def scan(mod, mode: str, data: bytes, digest=None, clock=time.perf_counter) -> float:
    """Seconds feed() took over data (by clock); digest (a hash) gets everything the scanner
    gave."""
    sc = scanner(mod, mode)
    view = memoryview(data)
    base, size, took = 0, PART, 0.0
    while True:
        stop = min(base + size, len(view))
        final = stop == len(view)
        t = clock()
        recs, used = sc.feed(view[base:stop], final, base)
        took += clock() - t
        if digest is not None:
            digest.update(recs)
            digest.update(repr((used, sc.lines, sc.flagged, sc.line_ends, sc.top, sc.e)).encode())
            if mode == "lean2":
                digest.update(sc.numbers)
        base += used
        if final:
            break
        size = PART if used else 2 * size
    if digest is not None:
        digest.update(repr(list(sc.roles)).encode())
    return took


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("file")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--so", help="a built _scan module file to time instead of this checkout's")
    ap.add_argument("--modes", default=",".join(MODES))
    a = ap.parse_args()
    try:
        data = Path(a.file).read_bytes()
    except OSError as e:
        sys.exit(f"bench_scan: {a.file}: {e.strerror}")
    modes = a.modes.split(",")
    bad = [m for m in modes if m not in MODES]
    if bad:
        sys.exit(f"bench_scan: --modes: unknown {', '.join(bad)} (of {', '.join(MODES)})")
    mod = load(a.so)
    mb = len(data) / 1e6
    print(f"{mb:.1f} MB, VERSION {getattr(mod, 'VERSION', '?')}, min of {a.reps} runs")
    for mode in modes:
        h = hashlib.sha256()
        scan(mod, mode, data, h)
        best = min(scan(mod, mode, data) for _ in range(a.reps))
        cpu = min(scan(mod, mode, data, clock=time.thread_time) for _ in range(a.reps))
        print(f"{mode:7s} {best:6.3f} s {mb / best:5.0f} MB/s, CPU {cpu:6.3f} s {mb / cpu:5.0f} MB/s"
              f"  sha256 {h.hexdigest()[:16]}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
