"""Outputs written all or nothing: one file (_write_atomic), or all of make's files together
(_Staged), with SIGINT and SIGTERM held back while names change."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


@contextlib.contextmanager
def _held():
    """SIGINT and SIGTERM held back until the end, then handled as they would have been. Python
    runs signal handlers in the main thread whichever thread the signal reached (numpy's worker
    threads do not block it), so a signal mask does not hold them: the handlers are swapped for
    one that notes the signal. Elsewhere than the main thread no handler runs: nothing to hold."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    old = {n: signal.signal(n, lambda signum, frame: got.append((signum, frame)))
           for n in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for n, h in old.items():
            signal.signal(n, h)
        if got:
            signum, frame = got[0]
            h = old[signum]
            if callable(h):
                h(signum, frame)                      # e.g. KeyboardInterrupt, the CLI's SystemExit
            elif h == signal.SIG_DFL:
                os.kill(os.getpid(), signum)


def _write_atomic(path, data, binary=False):
    """Write all of it or nothing: a temporary file in the same folder, renamed over the target.
    `data`: str or bytes, or an iterable of them (written piece by piece)."""
    path = Path(path)
    tmp = None
    try:
        with _held():                                 # the file is made and its name kept
            fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".part", dir=path.parent)
        with os.fdopen(fd, "wb" if binary else "w") as f:
            if isinstance(data, (str, bytes)):
                f.write(data)
            else:
                f.writelines(data)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        try:
            if tmp is not None:
                os.unlink(tmp)
        except OSError:
            pass
        raise


def _shown(path) -> str:
    """A file's name as the user will see it: without _Staged's temporary suffix."""
    name = Path(path).name
    return name.rsplit(".", 2)[0] if name.endswith(".part") else name


class _Staged:
    """Outputs written under temporary names beside their targets (NAME.EXT.xxxx.part) and
    renamed over them together at the end, with SIGINT and SIGTERM held back while renaming: a
    run that fails or is interrupted leaves no new file and the earlier ones intact."""

    def __init__(self, final: dict):
        self.final, self.tmp = final, {}

    def __enter__(self) -> dict:
        try:
            with _held():                             # no file made and not yet recorded
                for k, p in self.final.items():
                    fd, t = tempfile.mkstemp(prefix=p.name + ".", suffix=".part", dir=p.parent)
                    os.close(fd)
                    self.tmp[k] = Path(t)
        except BaseException:
            self._discard()
            raise
        return dict(self.tmp)

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            self._discard()
            return False
        try:
            with _held():
                for k in list(self.tmp):
                    os.replace(self.tmp[k], self.final[k])
                    del self.tmp[k]
        except BaseException:
            self._discard()
            raise
        return False

    def _discard(self) -> None:
        for t in self.tmp.values():
            try:
                os.unlink(t)
            except OSError:
                pass
        self.tmp.clear()
