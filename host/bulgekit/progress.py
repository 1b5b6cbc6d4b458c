"""Progress of long work on stderr: `phase` names a pass over a G-code file, the parser ticks.

The library only declares its passes (`with progress.phase("walls", total_lines):`) and the
G-code parser calls `tick(lines_done)` now and then; nothing is shown unless a command has
switched the display on (`enable()`: the CLI does when stderr is a terminal and --quiet is not
given). One line per pass, redrawn at most 5 times a second:

    walls: 45 % (680,000 of 1,512,000 lines), 210,000 lines/s, 4 s left

A program with its own display (the studio) calls `listen(fn)` instead: fn(label, done, total)
is called at the same moments, and once with done == total when a pass ends. A listener hears
only the passes of the thread that set it (the studio's worker, not its sending thread).
"""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

_stream = None          # where to draw, when enabled
_state = None           # the current pass: [label, total, start time, last draw time]
_local = threading.local()   # .listener: fn(label, done, total) of this thread, or None
RATE_AFTER_S = 1.0      # a pass's rate and time left are shown once it has run this long


def listen(fn) -> None:
    """Report this thread's passes to fn(label, lines_done, lines_total) (None: stop)."""
    _local.listener = fn


def _listener():
    return getattr(_local, "listener", None)


def enable(stream=None) -> None:
    global _stream
    _stream = stream or sys.stderr


def enabled() -> bool:
    return _stream is not None


def disable() -> None:
    global _stream
    _stream = None


def count_lines(path) -> int:
    """Lines of a file, for a pass's total (a byte count of newlines: fast)."""
    n = 0
    with open(path, "rb") as f:
        while chunk := f.read(1 << 22):
            n += chunk.count(b"\n")
    return n


@contextmanager
def phase(label: str, total_lines: int | None = None, path=None, unit: str = "lines"):
    """A pass over a file (or over other units of work): shown while it runs, then closed with
    its time."""
    global _state
    heard = _listener()
    if _stream is None and heard is None:
        yield
        return
    total = total_lines if total_lines is not None else (count_lines(path) if path else 0)
    _state = [label, max(total, 1), time.perf_counter(), 0.0, unit]
    if heard is not None:
        heard(label, 0, _state[1])
    try:
        yield
        dt = time.perf_counter() - _state[2]
        if heard is not None:
            heard(label, _state[1], _state[1])
        if _stream is not None:
            _stream.write(f"\r{label}: done in {dt:.1f} s{' ' * 40}\n")
            _stream.flush()
    finally:
        _state = None


def tick(done: int) -> None:
    """Called by the parser every few thousand lines."""
    if _state is None:
        return
    now = time.perf_counter()
    if now - _state[3] < 0.2:
        return
    _state[3] = now
    label, total, t0, _, unit = _state
    heard = _listener()
    if heard is not None:
        heard(label, min(done, total), total)
    if _stream is None:
        return
    pct = f"\r{label}: {min(100, 100 * done // total):3d} % ({done:,} of {total:,} {unit})"
    if now - t0 < RATE_AFTER_S:
        # a pass that jumps through records it already holds says nothing of the rate to come
        _stream.write(pct + " " * 30)
    else:
        rate = done / (now - t0)
        left = max(total - done, 0) / rate if rate > 0 else 0.0
        _stream.write(f"{pct}, {rate:,.0f} {unit}/s, {left:.0f} s left ")
    _stream.flush()
