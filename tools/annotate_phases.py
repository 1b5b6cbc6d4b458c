#!/usr/bin/env python3
"""Where `bulgekit annotate`'s time goes on one file, phase by phase, in one process each run.

    python3 tools/bench_host.py --mb 100 --keep DIR        # makes DIR/big.gcode and DIR/big.bkm
    python3 tools/annotate_phases.py DIR [--runs 5] [--against OTHER_CHECKOUT] [--command]

Each run is a fresh Python process that does what annotate_file does, one phase after the other:
import (the modules the command loads), read (the map read and decoded, the G-code read and checked
complete), reach (the reach check), markers (bulge/annotate.py's _annotated: the lines added and
the pieces of output) and write (the pieces to a file in DIR, removed after). Printed: each
phase's median seconds over the runs. With --against the other checkout's host package is timed
too, its runs alternating with this one's (the machine's speed drifts). With --command each run
also times the whole `bulgekit annotate` command (a fresh process) and a plain Python line read of
the file just before it (tools/bench_host.py's): the median of their ratios.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PHASES = ["import", "read", "reach", "markers", "write"]
sys.path.insert(0, str(ROOT / "tools"))


def one_run(d: Path) -> dict[str, float]:
    t = [time.perf_counter()]
    import bulgekit.cli  # noqa: F401  (what `bulgekit annotate` loads)
    from bulgekit.bulge import annotate as an, mapformat
    from bulgekit.bulge.fallback import Settings
    from bulgekit.gcode import check_complete, check_not_processed
    t.append(time.perf_counter())
    src, settings = str(d / "big.gcode"), Settings()
    map_bytes = (d / "big.bkm").read_bytes()
    bm = mapformat.decode_map(map_bytes, source="map")
    with open(src, "rb") as f:
        data = f.read()
    check_complete(data, src)
    t.append(time.perf_counter())
    msg, flagged = an._reach(data, map_bytes, settings, src, bm)
    if flagged != 0:
        check_not_processed(data, src)
    t.append(time.perf_counter())
    out = an._annotated(data, map_bytes, settings, an.ARENA_BYTES, True, src, an.AnnotateResult(), bm)
    t.append(time.perf_counter())
    dst = d / "phases.out.gcode"
    with open(dst, "wb") as f:
        write = getattr(an, "_write_pieces", None)    # (older checkouts: writelines)
        write(f, out) if write else f.writelines(out)
    t.append(time.perf_counter())
    dst.unlink()
    return {p: b - a for p, a, b in zip(PHASES, t, t[1:])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dir", type=Path, help="holds big.gcode and big.bkm (bench_host.py --keep)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--against", type=Path, help="another checkout, timed alternately")
    ap.add_argument("--command", action="store_true", help="also the whole command against a read")
    ap.add_argument("--once", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.once:
        print(json.dumps(one_run(a.dir)))
        return
    for name in ("big.gcode", "big.bkm"):
        if not (a.dir / name).is_file():
            sys.exit(f"annotate_phases: {a.dir / name} not found (make it with "
                     "tools/bench_host.py --keep DIR)")
    checkouts = {"this": ROOT} | ({"against": a.against.resolve()} if a.against else {})
    runs: dict[str, list[dict[str, float]]] = {k: [] for k in checkouts}
    for i in range(a.runs):
        for k, root in checkouts.items():
            env = dict(os.environ, PYTHONPATH=str(root / "host"))
            r = subprocess.run([sys.executable, __file__, str(a.dir), "--once"], env=env,
                               capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"annotate_phases: the run in {root} failed:\n{r.stderr}")
            runs[k].append(json.loads(r.stdout))
            if a.command:
                from bench_host import plain_read
                read = plain_read(a.dir / "big.gcode")[0]
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "bulgekit", "annotate", str(a.dir / "big.gcode"),
                                str(a.dir / "big.bkm"), "-o", str(a.dir / "phases.out.gcode"),
                                "--quiet"], env=env, check=True, capture_output=True)
                runs[k][-1]["x read"] = (time.perf_counter() - t) / read
                (a.dir / "phases.out.gcode").unlink()
            print(f"run {i + 1}/{a.runs} ({k})", file=sys.stderr)
    for k, root in checkouts.items():
        med = {p: statistics.median(r[p] for r in runs[k]) for p in PHASES}
        whole = (f"; the command {statistics.median(r['x read'] for r in runs[k]):.2f}x a read"
                 if a.command else "")
        print(f"{root}: " + ", ".join(f"{p} {med[p]:.3f}" for p in PHASES)
              + f", all {sum(med.values()):.3f} s{whole} (medians of {a.runs})")


if __name__ == "__main__":
    main()
