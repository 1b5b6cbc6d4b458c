#!/usr/bin/env python3
"""Ctrl-C at random moments of `bulgekit build --fallback` on a large file (issue 37).

    python3 tools/interrupt_soak.py [--mb 100] [--runs 20] [--seed N] [--keep DIR] [--sigterm]

The input is made as tools/bench_host.py makes it (bench_annotate.make_gcode: a real
PrusaSlicer file's middle layers repeated up to --mb). One whole run writes the outputs; then
each of --runs runs is sent SIGINT (--sigterm: SIGTERM) to its process group, as a terminal's
Ctrl-C is, at a random moment between its start (once its handlers are in place: Python's own
start-up comes before) and the whole run's time. Each run must end with exit status 130 (143)
and one line on stderr, and leave the output folder as it was (the same files, none replaced,
no part), with no process of it left; or, stopped once its outputs went in place, end as usual
(exit status 0, every output new). Prints one line per run and the counts; exit status 1 if
any run broke the rule. Linux (reads /proc).
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))


def start(args, cwd) -> subprocess.Popen:
    """`python -m bulgekit ARGS` (this checkout's package) in its own session and process group."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "host"))
    return subprocess.Popen([sys.executable, "-m", "bulgekit", *map(str, args)], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)


def ready(proc) -> float:
    """Waits until the command's own SIGTERM handler is in place (bulgekit.outputs.ending; Python
    alone catches SIGINT only); returns when (time.monotonic)."""
    t0 = time.monotonic()
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"the command ended before it started: {proc.communicate()}")
        try:
            status = Path(f"/proc/{proc.pid}/status").read_text()
        except FileNotFoundError:
            status = ""
        caught = next((int(ln.split()[1], 16) for ln in status.splitlines() if ln.startswith("SigCgt:")), 0)
        if caught >> (signal.SIGTERM - 1) & 1:
            return time.monotonic()
        if time.monotonic() - t0 > 30:
            raise RuntimeError("the command did not start within 30 s")
        time.sleep(0.002)


def alive(group: int) -> bool:
    """Whether a process of the group still runs (given a moment to be reaped)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.0:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return False
        time.sleep(0.01)
    return True


def whole_run(args, cwd) -> float:
    """One run to its end: its seconds from when its handlers were in place."""
    proc = start(args, cwd)
    t = ready(proc)
    _, err = proc.communicate(timeout=600)
    if proc.returncode != 0:
        raise RuntimeError(f"the whole run failed: {err.decode()}")
    return time.monotonic() - t


def stop_at(args, cwd, delay: float, sig=signal.SIGINT, group: bool = True):
    """The command stopped `delay` s after its handlers are in place: (exit status, stderr's
    lines, whether a process of it was left). group: the signal to its process group, as a
    terminal's Ctrl-C (its forked children hear it too); else to it alone, as `kill PID`."""
    proc = start(args, cwd)
    time.sleep(max(0.0, ready(proc) + delay - time.monotonic()))
    if proc.poll() is None:
        (os.killpg if group else os.kill)(proc.pid, sig)
    _, err = proc.communicate(timeout=600)
    return proc.returncode, err.decode().splitlines(), alive(proc.pid)


def files(d: Path) -> dict:
    """Every file in d (and below): its inode, size and time (a replaced file has a new inode)."""
    return {str(p.relative_to(d)): (st.st_ino, st.st_size, st.st_mtime_ns)
            for p in sorted(d.rglob("*")) if p.is_file() for st in [p.stat()]}


def main() -> int:
    from bench_annotate import bench_setup, make_gcode

    def more(ap):
        ap.add_argument("--runs", type=int, default=20, help="runs stopped (default 20)")
        ap.add_argument("--seed", type=int, default=None, help="random seed (default: new)")
        ap.add_argument("--sigterm", action="store_true", help="send SIGTERM instead of SIGINT")
    a, folder = bench_setup(__doc__, more)
    sig = signal.SIGTERM if a.sigterm else signal.SIGINT
    word = "terminated" if a.sigterm else "interrupted"
    seed = a.seed if a.seed is not None else random.randrange(1 << 30)
    rng = random.Random(seed)
    with folder as d:
        src, out = d / "big.gcode", d / "out"
        size, _ = make_gcode(src, a.mb)
        args = ["build", src, "--text", "HELLO", "--at", "5,3", "--fallback", "-o", out, "-q"]
        seconds = whole_run(args, d)
        before = files(out)
        print(f"input {size / 1e6:.1f} MB; a whole build --fallback: {seconds:.1f} s, "
              f"{len(before)} files; {a.runs} runs, {sig.name} at random moments (seed {seed})")
        codes: dict[int, int] = {}
        broken = 0
        for k in range(a.runs):
            delay = rng.uniform(0.0, seconds)
            code, err, left = stop_at(args, d, delay, sig)
            now = files(out)
            codes[code] = codes.get(code, 0) + 1
            renewed = now.keys() == before.keys() and all(now[n][0] != before[n][0] for n in now)
            if code == 0:                      # stopped once its outputs were in place
                ok = err == [] and renewed and not left
                said = "outputs all new" if renewed else "OUTPUTS NOT ALL NEW"
            else:
                ok = code == 128 + sig and err == [f"bulgekit: {word}"] and now == before and not left
                added = sorted(set(now) - set(before))
                said = ("outputs unchanged" if now == before else
                        "OUTPUTS CHANGED" + (f", new files {added}" if added else ""))
            broken += not ok
            print(f"run {k + 1:2d}: {sig.name} at {delay:5.2f} s: exit {code}, stderr {err!r}, {said}"
                  f"{', A PROCESS LEFT' if left else ''}{'' if ok else '  <-- BROKEN'}")
            before = now
        print(f"exit statuses: {dict(sorted(codes.items()))}; runs that broke the rule: {broken}")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
