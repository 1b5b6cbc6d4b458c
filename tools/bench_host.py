#!/usr/bin/env python3
"""Benchmark the host commands on one large G-code (issue 12's goals, default 100 MB).

    python3 tools/bench_host.py [--mb 100] [--keep DIR] [--repeat N]
    python3 tools/bench_host.py --gcode PART.gcode       # a sliced file of your own, as it is

The input and its map are made as in tools/bench_annotate.py (a real PrusaSlicer file's middle
layers repeated upward: 14,579 short layers in 100 MB; one bulge point per layer). With --gcode
the file is used as given and annotate, fallback and stats use the map build made on it (HELLO
at 5,3 mm); the ratios are to a read of that file. The goals are judged on the made input. Each command runs in a fresh Python process
(this checkout's package) so that its time and peak memory (ru_maxrss) are its own. Printed per
command: seconds, MB/s, the ratio to a plain Python line read of the same file made just before each
run (wall time, and user CPU time, which a machine loaded by other work disturbs less), peak MB, and
the goals (issue 26: build <= 5x a plain read, annotate <= 2.5x, peak <= 500 MB; `bulgekit
estimate` >= 1 M lines/s). With --repeat N each command runs N times, one after the other: the
median time and CPU, the median of each run's ratio to a plain read made just before it (the
goals are judged on it), the fastest and slowest run, the largest peak. Each timed run writes
new files on a quiet disk (_quiet_disk); the peak also counts one more run of each command,
sampled for its children's memory and not timed (see run()).
"""
from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT / "host"))

from bench_annotate import bench_setup, make_gcode, make_map  # noqa: E402

# run one CLI command in this process and report its peak memory and its children's (kB on
# Linux: a child forked to work beside it, bulgekit.parallel) on the last line
_RUNNER = ("import resource, runpy, sys\n"
           "sys.argv = ['bulgekit'] + sys.argv[1:]\n"
           "try:\n    runpy.run_module('bulgekit.cli', run_name='__main__')\n"
           "except SystemExit as e:\n    code = e.code\nelse:\n    code = 0\n"
           "ru = resource.getrusage(resource.RUSAGE_SELF)\n"
           "rc = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
           "print('maxrss', ru.ru_maxrss, rc.ru_maxrss, ru.ru_utime + rc.ru_utime, file=sys.stderr)\n"
           "sys.exit(code)\n")


def _quiet_disk(outputs: tuple[Path, ...] = ()) -> None:
    """Before a timed run: take away what the command's last run wrote (outputs: files or
    folders), so that each run writes new files as a first build does (a file replaced on ext4
    costs the replacing run the old file's freeing, and writeback of the new one), and write out
    what is left in the page cache (the made input, other commands' outputs): the kernel writes
    dirty pages back some 30 s after they were written, and on a small machine that work lands
    in whichever run is timed then."""
    for p in outputs:
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
    if hasattr(os, "sync"):
        os.sync()


def plain_read(path: Path) -> tuple[float, float, int]:
    """Seconds, user CPU seconds and lines of a plain Python line read."""
    _quiet_disk()
    t, u = time.perf_counter(), time.process_time()
    n = 0
    with open(path, encoding="utf-8", errors="replace") as f:
        for _ in f:
            n += 1
    return time.perf_counter() - t, time.process_time() - u, n


def _tree_pss_kb(pid: int) -> int:
    """Proportional set size (kB) of the process pid and its children, now: memory they share
    (a fork's pages) counted once. 0 if it is gone."""
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/smaps_rollup") as f:
                for line in f:
                    if line.startswith("Pss:"):
                        total += int(line.split()[1])
                        break
            with open(f"/proc/{p}/task/{p}/children") as f:
                todo += [int(c) for c in f.read().split()]
        except (OSError, ValueError):
            pass
    return total


def run(args: list[str], outputs: tuple[Path, ...] = (), sample: bool = False
        ) -> tuple[float, float, float]:
    """Seconds, peak MB and user CPU seconds (its children's too) of one command in a fresh
    process. The peak is the larger of the process's own and its children's (ru_maxrss) and,
    with sample, the most the process and the children it forks to work beside it
    (bulgekit.parallel) held together, sampled every 20 ms as their proportional set sizes (pages
    they share counted once). Sampling costs the run CPU (reading smaps_rollup walks the
    processes' page tables: build's median 1.05 s unsampled, 1.15 s sampled, 12 runs each on two
    cores), so main() samples a run of its own, untimed."""
    env = {"PYTHONPATH": str(ROOT / "host"), "PATH": "/usr/bin:/bin"}
    _quiet_disk(outputs)
    t = time.perf_counter()
    pr = subprocess.Popen([sys.executable, "-c", _RUNNER, *args], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, env=env)
    tree = 0
    sampling = sample and os.path.exists(f"/proc/{pr.pid}/smaps_rollup")
    while sampling and pr.poll() is None:
        tree = max(tree, _tree_pss_kb(pr.pid))
        time.sleep(0.02)
    out, err = pr.communicate()
    dt = time.perf_counter() - t
    if pr.returncode not in (0, 1):              # stats exits 1 on warnings; anything else fails
        sys.exit(f"bench_host: {' '.join(args[:2])} failed: {err[-500:]}")
    _, kb, _, user = err.strip().splitlines()[-1].split()
    return dt, max(int(kb), tree) / 1024, float(user)


def main() -> int:
    def more(ap):
        ap.add_argument("--gcode", type=Path,
                        help="time the commands on this sliced file instead (--mb ignored)")
        ap.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="run each command N times: median, fastest and slowest (default 1)")
    a, folder = bench_setup(__doc__, more)
    if a.repeat < 1:
        sys.exit(f"bench_host: --repeat {a.repeat}: give 1 or more")
    with folder as d:
        if a.gcode is None:
            src, bkm = d / "big.gcode", d / "big.bkm"
            size, z_top = make_gcode(src, a.mb)
            bkm.write_bytes(make_map(z_top))
        else:
            src, bkm = a.gcode, d / "build" / f"{a.gcode.stem}.bkm"     # (made by the build case)
            if not src.is_file():
                sys.exit(f"bench_host: --gcode {src}: no such file")
            size = src.stat().st_size
        mb = size / 1e6
        judged = a.gcode is None and mb >= 99        # the goals are for the made 100 MB input
        base, base_user, lines = min(plain_read(src) for _ in range(2))
        print(f"input: {mb:.1f} MB, {lines} lines; a plain Python line read takes {base:.2f} s "
              f"({mb / base:.0f} MB/s), {base_user:.2f} s user CPU")
        cases = [
            # issue 12's build: map, annotated, stock fallback, stats and previews
            ("build", ["build", str(src), "--text", "HELLO", "--at", "5,3", "-o", str(d / "build"),
                       "--fallback", "--quiet"], 5.0),
            # the same build without its preview (what drawing it costs)
            ("build -P", ["build", str(src), "--text", "HELLO", "--at", "5,3", "-o", str(d / "b2"),
                          "--fallback", "--no-preview", "--quiet"], None),
            ("annotate", ["annotate", str(src), str(bkm), "-o", str(d / "a.gcode"), "--quiet"], 2.5),
            ("fallback", ["fallback", str(src), str(bkm), "-o", str(d / "f.gcode"), "--quiet",
                          "--allow-unreached"], None),
            ("stats", ["stats", str(bkm), "--gcode", str(src), "--quiet"], None),
            ("estimate", ["estimate", str(src)], None),
        ]
        spread = a.repeat > 1
        print(f"{'command':<10}{'s':>8}{'MB/s':>8}{'x read':>8}{'user s':>8}{'x read':>8}{'peak MB':>9}"
              + (f"{'runs: s min-max':>18}" if spread else "") + "  goals")
        for name, args, goal in cases:
            # (what follows -o: the output the run before left, taken away before each run)
            outs = (Path(args[args.index("-o") + 1]),) if "-o" in args else ()
            # each run right after a plain read of its own: the ratios are of two things timed
            # at the same moment (a virtual machine's speed drifts by tens of percent in minutes)
            runs, reads = [], []
            for _ in range(a.repeat):
                reads.append(plain_read(src))
                runs.append(run(args, outs))
            dt = statistics.median(r[0] for r in runs)
            user = statistics.median(r[2] for r in runs)
            x_read = statistics.median(r[0] / b[0] for r, b in zip(runs, reads))
            x_user = statistics.median(r[2] / b[1] for r, b in zip(runs, reads))
            # the peak: the timed runs' and one more run's, sampled (and not timed)
            peak = max([r[1] for r in runs] + [run(args, outs, sample=True)[1]])
            rng = (f"{a.repeat:>6}: {min(r[0] for r in runs):.2f}-{max(r[0] for r in runs):.2f}"
                   if spread else "")
            # goals are checked on the full 100 MB: a small file's run is mostly start-up
            g = "" if goal is None or not judged else f"<= {goal:g}x read: {'met' if x_read <= goal else 'NOT met'}"
            # memory is checked on the full 100 MB only: it does not scale with size alone
            m = f"; peak <= 500 MB: {'met' if peak <= 500 else 'NOT met'}" if judged and name != "estimate" else ""
            if name == "estimate":
                g = (f"{lines / dt / 1e6:.2f} M lines/s ({lines / user / 1e6:.2f} M per user CPU s)"
                     + ("" if not judged else f": >= 1 M lines/s {'met' if lines / dt >= 1e6 else 'NOT met'}"))
            print(f"{name:<10}{dt:8.2f}{mb / dt:8.1f}{x_read:8.1f}{user:8.2f}{x_user:8.1f}"
                  f"{peak:9.0f}{rng:>18}  {g}{m}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
