"""One job run beside the main work on a second core: `build`'s preview, and its stock
fallback and statistics.

The job runs in a child process forked from this one, so it sees all this process holds (the
kept scan, the map) without a copy, and sends back only its result, pickled. Two ways in:

    child = Forked.waiting(warm)      # forked now; warm() runs there at once (imports), and
    ...                               # the job comes later, pickled: child.give(fn, *args)
    child = Forked.running(fn)        # forked now and runs fn() there (a closure is fine)
    result = child.result()           # fn's value, or its exception raised here

A fork is safe only while this process runs one thread (a lock another thread holds would stay
locked in the child), so it is made only then, on Linux (macOS's system libraries are not
fork-safe), with two cores or more and without BULGEKIT_FORK=0. Otherwise, and when a child
ends without a result (killed), the job runs in this process when result() is called: the same
result, later. The child hears no Ctrl-C: this process's close() (in a finally) ends it, and
the kernel ends it when this process dies (even by SIGKILL); it shows no progress
(bulgekit.progress): its lines would cross this process's. A job writes only into parts of
outputs this process opened before the fork (bulgekit.outputs): ended half way, it leaves a
part this process removes.
"""
from __future__ import annotations

import gc
import os
import pickle
import signal
import sys
import threading
from typing import Any, Callable

_NO_JOB = object()
_SIGNALS = {signal.SIGINT, signal.SIGTERM}
_live: set[Forked] = set()             # children not yet reaped


def end_all() -> None:
    """Every child still running ended and reaped (bulgekit.outputs, before a failed run's
    parts are removed: none is written after)."""
    for child in list(_live):
        child.close()


def can_fork() -> bool:
    """Whether a job may run in a forked child here and now (see the module comment)."""
    return (sys.platform.startswith("linux") and os.environ.get("BULGEKIT_FORK", "1") != "0"
            and (os.cpu_count() or 1) >= 2 and threading.active_count() == 1)


class Forked:
    """One job in a forked child (or, where no fork is made, in this process at result())."""

    def __init__(self, fn: Callable[[], Any] | None, warm: Callable[[], None] | None = None):
        self._fn = fn                          # the job (None: given later, by give())
        self._given: Any = _NO_JOB             # (fn, args, kwargs) given to a waiting child
        self._pid = 0                          # the child's, until it is reaped
        self.forked = False                    # whether the job went to a child
        self._done = False
        self._value: Any = None
        self._error: BaseException | None = None
        self._to: int | None = None            # the pipe to a waiting child
        self._from = -1                        # the pipe from the child
        if not can_fork():
            return
        to_child = os.pipe() if fn is None else None
        from_child = os.pipe()
        for s in (sys.stdout, sys.stderr):     # (nothing buffered here is written twice)
            s.flush()
        parent = os.getpid()
        # no signal handled between the fork and the child's noting: one that unwinds this process
        # then finds it in _live (outputs ends every child before it removes their parts)
        signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
        try:
            pid = os.fork()
            if pid == 0:                       # the child: never returns
                self._serve(fn, warm, to_child, from_child, parent)
            self._pid = pid
            _live.add(self)
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)
        self.forked = True
        os.close(from_child[1])
        self._from = from_child[0]
        if to_child is not None:
            os.close(to_child[0])
            self._to = to_child[1]

    @classmethod
    def waiting(cls, warm: Callable[[], None] | None = None) -> Forked:
        """A child forked now that runs warm() and then waits for give()'s job."""
        return cls(None, warm)

    @classmethod
    def running(cls, fn: Callable[[], Any]) -> Forked:
        """A child forked now that runs fn() (the closure is the child's copy: not pickled)."""
        return cls(fn)

    def give(self, fn: Callable, *args, **kwargs) -> None:
        """The job of a waiting child: fn(*args, **kwargs), all picklable (fn at module level)."""
        if self._fn is not None or self._given is not _NO_JOB:
            raise RuntimeError("Forked.give: this child has its job already")
        self._given = (fn, args, kwargs)
        if self._to is None:
            return
        try:
            with os.fdopen(self._to, "wb") as f:
                pickle.dump(self._given, f, pickle.HIGHEST_PROTOCOL)
        except OSError:                        # the child is gone: result() runs the job here
            pass
        self._to = None

    def result(self) -> Any:
        """The job's value (its exception raised here). Waits for the child."""
        if not self._done:
            self._done = True
            got = self._collect() if self._pid else None
            if got is None:                    # no child, or it ended without a result
                try:
                    self._value = self._run_here()
                except BaseException as e:
                    self._error = e
            else:
                ok, v = got
                if ok:
                    self._value = v
                else:
                    self._error = v
        if self._error is not None:
            raise self._error
        return self._value

    def close(self) -> None:
        """End the child if it still runs (an error or Ctrl-C here) and wait for it."""
        if self._pid:
            try:
                os.kill(self._pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self._reap()

    def __enter__(self) -> Forked:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- inside -------------------------------------------------------------------------------

    def _run_here(self) -> Any:
        if self._fn is not None:
            return self._fn()
        if self._given is _NO_JOB:
            raise RuntimeError("Forked.result: no job was given")
        fn, args, kwargs = self._given
        return fn(*args, **kwargs)

    def _collect(self):
        """(True, value) or (False, exception) from the child; None if it sent nothing."""
        if self._to is not None:               # a waiting child never given a job
            os.close(self._to)
            self._to = None
        chunks = []
        fd, self._from = self._from, -1
        with os.fdopen(fd, "rb") as f:
            while True:
                b = f.read(1 << 20)
                if not b:
                    break
                chunks.append(b)
        self._reap()
        try:
            return pickle.loads(b"".join(chunks)) if chunks else None
        except Exception:                      # cut short (killed while writing)
            return None

    def _reap(self) -> None:
        if self._pid:
            try:
                os.waitpid(self._pid, 0)
            except ChildProcessError:
                pass
            self._pid = 0
            _live.discard(self)
            if self._to is not None:
                os.close(self._to)
                self._to = None
            if self._from >= 0:                # (closed without its result read)
                os.close(self._from)
                self._from = -1

    @staticmethod
    def _serve(fn, warm, to_child, from_child, parent) -> None:
        code = 0
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)   # Ctrl-C is the parent's to handle
            signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)   # (blocked across the fork)
            _live.clear()                      # (the parent's children)
            _end_with(parent)
            # no collector in a child: it runs one job and ends, and a collection would write to
            # every object the fork shares with the parent (copying their pages) and cost
            # importing matplotlib 0.02-0.04 s of CPU; what the job leaves in cycles ends with it
            gc.disable()
            # no progress lines from here: they would cross the parent's on its terminal
            from . import progress
            progress.disable()
            progress.listen(None)
            os.close(from_child[0])
            if to_child is not None:
                os.close(to_child[1])
            if warm is not None:
                try:
                    warm()
                except Exception:
                    pass                       # (the job says what is wrong, if anything)
            if fn is None:
                with os.fdopen(to_child[0], "rb") as f:
                    data = f.read()
                if not data:                   # no job given: nothing to send
                    os._exit(0)
                fn_, args, kwargs = pickle.loads(data)
                job = lambda: fn_(*args, **kwargs)  # noqa: E731
            else:
                job = fn
            try:
                out = (True, job())
            except Exception as e:
                out = (False, e)
            try:
                data = pickle.dumps(out, pickle.HIGHEST_PROTOCOL)
            except Exception:
                # an unpicklable value or exception: no result, the parent runs the job itself
                data = b""
            with os.fdopen(from_child[1], "wb") as f:
                f.write(data)
        except BaseException:
            code = 1
        finally:
            os._exit(code)


def _end_with(parent: int) -> None:
    """This (forked) process is killed when its parent dies: prctl(PR_SET_PDEATHSIG, SIGKILL)
    (Linux, where alone a child is forked); if the parent is gone already, it ends now."""
    import ctypes
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:
        os._exit(1)
