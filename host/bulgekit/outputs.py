"""Outputs written all or nothing, and how a command ends on SIGINT or SIGTERM (issue 37).

Every file bulgekit writes for its user is written under a part name beside it
(NAME.EXT.<pid>-<n>.part) and renamed over its target once everything the run makes is whole:

    with outputs.Outputs() as out:        # one run's outputs (the CLI opens one per command)
        out.folder(outdir)                # made now; taken back, if this made it, with the rest
        outputs.write(outdir / "a.txt", text)
        with outputs.part(outdir / "b.gcode") as p:
            ...                           # write p
    # here every output is in place (renamed together, SIGINT and SIGTERM held back meanwhile),
    # or, after an error or a signal, none: the parts are removed, and earlier files of the same
    # names are as they were

An Outputs (or write, part) opened while another is open in this thread joins it: its files go
in place when the outermost one ends, so a command's files go together (cli/_util.friendly opens
one per command). apart(): inside it, what is written goes in place on its own (files a command
reads back: post-process's build in a scratch() folder, the studio's export folder).

A job in a forked child (bulgekit.parallel) writes only into parts its parent opened before the
fork (Outputs.part(dst) in the parent): the parent ends the child if it still runs, then removes
them with the rest.

ending(): a command's SIGINT and SIGTERM raise Stopped, which unwinds it (each finally runs:
parts removed, children ended) and ends it with one line on stderr and exit status 130 or 143.
"""
from __future__ import annotations

import contextlib
import contextvars
import errno
import itertools
import os
import shutil
import signal
import sys
import tempfile
import threading
from pathlib import Path

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_current: contextvars.ContextVar[Outputs | None] = contextvars.ContextVar("bulgekit_outputs",
                                                                          default=None)
_numbers = itertools.count(1)
_ending = 0             # ending()s open in this process (the CLI's): a final commit drops signals


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class Outputs:
    """The files of one run, all or none (see the module comment). final: the run's last step
    (the CLI's command): a signal during or after the renaming is dropped, the command only
    reports from there on, so exit status 130/143 always means no new file."""

    def __init__(self, *, final: bool = False):
        self.final = final
        self._parts: dict[str, tuple[str, bool]] = {}   # target -> (its part, a folder?)
        self._made: list[Path] = []                     # folders this run made, outermost first
        self._root: Outputs = self                      # the one that renames (self or the outer)
        self._outer: Outputs | None = None
        self._mine: list[str] = []                      # joined: targets added while it was open
        self._token = None

    def __enter__(self) -> Outputs:
        self._outer = _current.get()
        if self._outer is not None:
            self._root = self._outer._root
        self._token = _current.set(self)
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        _current.reset(self._token)
        root = self._root
        if exc is None:
            if root is self:
                try:
                    self._commit()
                except BaseException:              # (also a signal as the renaming began)
                    self._discard(list(self._parts))
                    raise
            return False
        named = {part: dst for dst, (part, _) in root._parts.items()}
        if root is self:
            self._discard(list(self._parts))
        else:
            self._discard(self._mine)
        if isinstance(exc, OSError) and exc.filename in named:    # said of the file asked for
            raise type(exc)(exc.errno, exc.strerror, named[exc.filename]) from None
        return False

    def part(self, dst, *, folder: bool = False) -> Path:
        """The part dst is written to (the same one each time dst is asked for). A folder's part
        is made here, empty; a file's is made by the writer."""
        dst = os.path.abspath(os.fspath(dst))
        root = self._root
        got = root._parts.get(dst)
        if got is None:
            head, name = os.path.split(dst)
            part = os.path.join(head, f"{name}.{os.getpid()}-{next(_numbers)}.part")
            with held():                      # noted before it exists: taken back if cut short
                root._parts[dst] = got = (part, folder)
                o = self
                while o is not root:                  # (each joined one takes back its own)
                    o._mine.append(dst)
                    o = o._outer
                if folder:
                    try:
                        os.mkdir(part)
                    except OSError as e:
                        raise type(e)(e.errno, e.strerror, dst) from None
        return Path(got[0])

    def folder(self, path) -> Path:
        """path made (with its parents) if missing; those this run made go if it fails."""
        path = Path(path)
        missing = []
        p = path.absolute()
        while not p.exists() and p != p.parent:
            missing.append(p)
            p = p.parent
        with held():
            path.mkdir(parents=True, exist_ok=True)
            self._root._made.extend(reversed(missing))
        return path

    def _commit(self) -> None:
        for dst, (part, is_folder) in self._parts.items():
            # what a rename would refuse, before any is made (a file over a folder)
            if os.path.isdir(dst) and not is_folder:
                raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), dst)
        with held(drop=self.final and _ending > 0):
            for dst, (part, _) in list(self._parts.items()):
                try:
                    os.replace(part, dst)
                except OSError as e:
                    raise type(e)(e.errno, e.strerror, dst) from None
                del self._parts[dst]
            self._made.clear()

    def _discard(self, targets) -> None:
        """The parts of targets removed (and the folders this run made, when empty), each even
        when a signal comes meanwhile; that signal's exception is raised at the end."""
        root = self._root
        steps = [(dst, *root._parts[dst]) for dst in targets if dst in root._parts]
        if root is self:
            # a child forked to write a part is ended first (its parent's finally does so too,
            # but a signal may come before the parent holds it)
            steps = [(None, None, None)] + steps + [(None, d, None) for d in reversed(self._made)]
        came = None
        for dst, path, is_folder in steps:
            while True:
                try:
                    if path is None:
                        from . import parallel
                        parallel.end_all()
                    elif dst is None:
                        path.rmdir()              # (only when empty: a file from before stays)
                    elif is_folder:
                        shutil.rmtree(path)
                    else:
                        os.unlink(path)
                except OSError:
                    pass
                except BaseException as e:        # (a second Ctrl-C, outside the CLI): go on
                    came = came or e
                    continue
                break
            if dst is not None:
                root._parts.pop(dst, None)
        if root is self:
            self._made.clear()
        if came is not None:
            raise came


def current() -> Outputs | None:
    """The Outputs open in this thread, if any."""
    return _current.get()


@contextlib.contextmanager
def part(dst):
    """dst's part, to write (an Outputs of its own, or the one open); an OSError about the part,
    or one naming no file (a write's), is said of dst, the file the user named."""
    with Outputs() as out:
        p = out.part(dst)
        try:
            yield p
        except OSError as e:
            if e.filename not in (os.fspath(p), None):
                raise
            raise type(e)(e.errno, e.strerror, os.fspath(dst)) from None


def write(dst, data) -> Path:
    """dst written all or nothing: data is str or bytes, or an iterable of them (written piece by
    piece; text or binary by the first)."""
    pieces = [data] if isinstance(data, (str, bytes, bytearray, memoryview)) else data
    with part(dst) as p:
        with open(p, "wb") as f:
            for piece in pieces:
                f.write(piece.encode("utf-8") if isinstance(piece, str) else piece)
    return Path(dst)


@contextlib.contextmanager
def apart():
    """Inside, writing does not join the Outputs open: each write goes in place when it ends."""
    token = _current.set(None)
    try:
        yield
    finally:
        _current.reset(token)


@contextlib.contextmanager
def scratch(beside):
    """A temporary folder in `beside` (the same file system: its files can be renamed into
    place), removed at the end however the run ends (write into it apart())."""
    d = None
    try:
        with held():
            d = Path(tempfile.mkdtemp(prefix=".bulgekit-", dir=beside))
        yield d
    finally:
        if d is not None:
            shutil.rmtree(d, ignore_errors=True)


@contextlib.contextmanager
def held(drop: bool = False):
    """SIGINT and SIGTERM held back until the end, then handled as they would have been (drop:
    not at all; later ones neither, until ending() puts its handlers back). Python runs signal
    handlers in the main thread whichever thread the signal reached, so a signal mask does not
    hold them: the handlers are swapped for one that notes the signal. Elsewhere than in the
    main thread no handler runs: nothing to hold."""
    if not _main_thread():
        yield
        return
    got = []
    old = {n: signal.signal(n, lambda signum, frame: got.append((signum, frame))) for n in _SIGNALS}
    try:
        yield
    finally:
        if not drop:
            for n, h in old.items():
                signal.signal(n, h)
            if got:
                signum, frame = got[0]
                h = old[signum]
                if callable(h):
                    h(signum, frame)          # KeyboardInterrupt, or ending()'s Stopped
                elif h == signal.SIG_DFL:
                    os.kill(os.getpid(), signum)


class Stopped(BaseException):
    """SIGINT or SIGTERM during ending(): unwinds the command (not an Exception, so nothing
    takes it for an error and goes on)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _stop(signum, frame):
    for n in _SIGNALS:                        # once: a second Ctrl-C does not cut the unwinding short
        signal.signal(n, signal.SIG_IGN)
    raise Stopped(signum)


@contextlib.contextmanager
def ending(prog: str = "bulgekit", exiting: bool = False):
    """A command's SIGINT and SIGTERM: each unwinds it (Stopped) and ends it with one line on
    stderr, `PROG: interrupted` or `PROG: terminated`, and exit status 128 + the signal's
    number (130, 143). The handlers before are put back at the end, or with exiting (the
    process ends with the command) both signals are ignored from then on: a command that
    finished is not cut short in its exit. One inside another does nothing."""
    global _ending
    if not _main_thread() or _ending:
        yield
        return
    old = {}
    _ending += 1
    try:
        for n in _SIGNALS:
            old[n] = signal.signal(n, _stop)
        yield
    except Stopped as e:
        word = "interrupted" if e.signum == signal.SIGINT else "terminated"
        err = sys.stderr
        with contextlib.suppress(Exception):
            err.write(("\r\x1b[K" if err.isatty() else "") + f"{prog}: {word}\n")   # (past a progress line)
            err.flush()
        raise SystemExit(128 + e.signum) from None
    finally:
        _ending -= 1
        for n, h in old.items():
            signal.signal(n, signal.SIG_IGN if exiting else h)
