"""Stream G-code / M-codes to a Marlin printer over a serial line.

Protocol (Marlin's): every line goes out as "N<n> <cmd>*<xor>", with <xor>
the XOR of all bytes before '*'.  "N0 M110 N0" resets the numbering at
connect.  One line is in flight at a time (send, wait for "ok"), which
Marlin's 4-slot command queue keeps busy enough and which makes the reply
to each command unambiguous:

  ok ...           the line was taken; go on.
  Resend: <n>      the line arrived damaged or out of order.  Marlin follows
                   it with an "ok" that acknowledges nothing; after that ok
                   the stream restarts at line n.
  busy: ...        (usually "echo:busy: processing") a long command such as
                   G28 or M109 is still running; restarts the reply timeout.
  Error:...        checksum / line-number errors come with a Resend and are
                   handled by it; "Printer halted", "kill() called" and the
                   thermal errors stop the stream at once; any other error is
                   the printer refusing the command in flight, which stops
                   the stream after its ok (unless continue_on_error).
  start            the firmware rebooted mid-stream: stop, nothing is known
                   about what ran.

No line is ever skipped: a line leaves the queue only on its own "ok".
"""
from __future__ import annotations

import os
import re
import sys
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

from ..errors import BulgekitError, InputError

MAX_LINE = 95  # Marlin's MAX_CMD_SIZE is 96 bytes including the terminator

_FATAL = re.compile(r"printer halted|kill\(\) called|thermal runaway|maxtemp|mintemp|heating failed|"
                    r"printer stopped|emergency stop", re.I)
_TRANSPORT = re.compile(r"checksum|line number|no line number|format error", re.I)
_RESEND = re.compile(r"^(?:resend|rs)\s*:?\s*N?\s*(\d+)", re.I)
_EXISTING_N = re.compile(r"^\s*N\d+\s+")
_FRAMED_TAIL = re.compile(r"\s*\*\d+\s*$")


class SendError(BulgekitError):
    """Streaming stopped; the message says at which line and why."""


class SendTimeout(SendError):
    """The printer did not answer in time."""


class PrinterError(SendError):
    """The printer reported an error for a command, or halted."""


@dataclass(frozen=True)
class Line:
    cmd: str
    source: str = ""


@dataclass
class SendStats:
    lines: int = 0          # lines acknowledged
    bytes: int = 0          # bytes written, resends included
    resends: int = 0        # lines sent again on request
    busy: int = 0           # busy: keep-alives seen
    errors: list = field(default_factory=list)    # (source, cmd, printer message) of refused commands
    messages: list = field(default_factory=list)  # other printer output (echo:, reports), in order
    elapsed: float = 0.0

    def summary(self) -> str:
        rate = self.lines / self.elapsed if self.elapsed > 0 else 0.0
        s = (f"{self.lines} lines, {self.bytes} bytes in {self.elapsed:.1f} s ({rate:.1f} lines/s), "
             f"{self.resends} resent, {self.busy} busy")
        if self.errors:
            s += f", {len(self.errors)} refused"
        return s


def checksum(text: str) -> int:
    c = 0
    for b in text.encode("ascii"):
        c ^= b
    return c


def frame(n: int, cmd: str) -> str:
    body = f"N{n} {cmd}"
    return f"{body}*{checksum(body)}"


def clean_line(raw: str) -> str:
    """A G-code line without comment, surrounding blanks, line number or
    checksum ('' if nothing is left)."""
    s = raw.split(";", 1)[0].strip()
    if _EXISTING_N.match(s):
        # An already framed line: drop its number and checksum.
        s = _FRAMED_TAIL.sub("", _EXISTING_N.sub("", s, count=1))
    return s.strip()


def prepare(lines: Iterable, name: str = "input") -> list[Line]:
    """Lines to send, from strings (source: "<name>:<index>") or Line objects.

    Comments and blank lines are dropped (Marlin ignores them anyway); a
    character Marlin cannot take is an InputError naming the line.
    """
    out = []
    for i, item in enumerate(lines, 1):
        if isinstance(item, Line):
            raw, src = item.cmd, item.source or f"{name}:{i}"
        else:
            raw, src = str(item), f"{name}:{i}"
        cmd = clean_line(raw)
        if not cmd:
            continue
        bad = [c for c in cmd if not (32 <= ord(c) < 127)]
        if bad:
            raise InputError(f"{src}: character {bad[0]!r} cannot be sent to the printer (ASCII only)")
        if "*" in cmd:
            raise InputError(f"{src}: '*' cannot be sent inside a command (it starts the checksum)")
        out.append(Line(cmd, src))
    return out


def read_gcode(path) -> list[Line]:
    """Lines of a G-code file, each tagged file:line for messages."""
    path = os.fspath(path)
    try:
        with open(path, "r", encoding="utf-8", errors="strict") as f:
            text = f.read()
    except OSError as e:
        raise InputError(f"{path}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        line = text_line_of_byte(path, e.start)
        raise InputError(f"{path}:{line}: not UTF-8/ASCII text") from None
    from ..gcode import check_complete
    check_complete(text, path)
    return prepare((Line(t, f"{path}:{i}") for i, t in enumerate(text.splitlines(), 1)), path)


def text_line_of_byte(path, offset):
    with open(path, "rb") as f:
        return f.read(offset).count(b"\n") + 1


class _SerialLink:
    """Line reader over a pyserial port with our own buffer, because
    pyserial's readline() returns half lines when its timeout strikes."""

    def __init__(self, ser):
        self.ser = ser
        self.buf = bytearray()

    def write(self, data: bytes):
        self.ser.write(data)
        self.ser.flush()

    def readline(self, deadline: float) -> str | None:
        while True:
            nl = self.buf.find(b"\n")
            if nl >= 0:
                raw = bytes(self.buf[:nl])
                del self.buf[:nl + 1]
                return raw.decode("ascii", errors="replace").strip("\r\x00 ")
            if time.monotonic() >= deadline:
                return None
            chunk = self.ser.read(max(1, self.ser.in_waiting))
            if chunk:
                self.buf.extend(chunk)

    def close(self):
        self.ser.close()


class Sender:
    """A connection to a printer.  Use as a context manager:

        with Sender("/dev/ttyUSB0", 115200) as s:
            stats = s.send(read_gcode("part.gcode"))

    port is a device path or a pyserial URL (socket://host:port, rfc2217://,
    loop://), or an already open pyserial-like object.  boot_wait: seconds
    to listen after opening for the firmware's "start" (opening a USB port
    usually resets the board); 0 to skip.
    """

    def __init__(self, port, baud: int = 115200, *, timeout: float = 30.0, boot_wait: float = 2.0,
                 max_line: int = MAX_LINE, max_resends: int = 10,
                 on_message: Callable[[str], None] | None = None):
        self.port = port
        self.port_name = port if isinstance(port, str) else getattr(port, "port", None) or repr(port)
        self.baud = baud
        self.timeout = timeout
        self.boot_wait = boot_wait
        self.max_line = max_line
        self.max_resends = max_resends
        self.on_message = on_message
        self.link: _SerialLink | None = None
        self.next_n = 1
        self.boot_messages: list[str] = []
        self._last_heard = ""

    # -- connection

    def open(self):
        if isinstance(self.port, str):
            import serial
            try:
                ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0.05, write_timeout=self.timeout)
            except (serial.SerialException, ValueError, OSError) as e:
                raise SendError(f"cannot open {self.port}: {e}") from None
        else:
            ser = self.port
        self.link = _SerialLink(ser)
        self._wait_boot()
        self.reset_line_numbers()
        return self

    def close(self):
        if self.link is not None:
            try:
                self.link.close()
            finally:
                self.link = None

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def _wait_boot(self):
        if self.boot_wait <= 0:
            return
        deadline = time.monotonic() + self.boot_wait
        started = False
        while True:
            line = self.link.readline(deadline)
            if line is None:
                return
            if line:
                self.boot_messages.append(line)
                self._message(line)
            if line.startswith("start"):
                started = True
            if started:
                # The banner follows "start"; wait for it to go quiet.
                deadline = time.monotonic() + 0.5

    def reset_line_numbers(self):
        """Send "N0 M110 N0" so the next line is N1.  Also the way back to a
        known state after a SendError."""
        self.next_n = 0
        # Until M110 is through, the printer counts from whatever the last
        # session left, so any Resend number just means "send M110 again".
        self._stream([Line("M110 N0", "line-number reset")], None, False, SendStats(), resend_any=True)
        self.next_n = 1

    # -- streaming

    def send(self, lines: Sequence, *, progress: bool = True, continue_on_error: bool = False,
             desc: str | None = None) -> SendStats:
        """Send lines (Line objects or strings) and return statistics. progress: True for a
        bar on stderr, or a function called with the number of lines taken so far.

        Raises SendTimeout, PrinterError or SendError with the line's source
        when the stream cannot go on; lines before it were all acknowledged.
        """
        if self.link is None:
            raise SendError("sender is not open")
        lines = prepare(lines)
        self._check_lengths(lines)
        stats = SendStats()
        bar = None
        if callable(progress):
            bar = _Counter(progress)
        elif progress:
            from tqdm import tqdm
            bar = tqdm(total=len(lines), unit="line", desc=desc or "send", file=sys.stderr,
                       dynamic_ncols=True, mininterval=0.2)
        t0 = time.monotonic()
        try:
            self._stream(lines, bar, continue_on_error, stats)
        finally:
            stats.elapsed = time.monotonic() - t0
            if bar is not None:
                bar.set_postfix(resent=stats.resends, busy=stats.busy, refresh=False)
                bar.close()
        return stats

    def command(self, cmd: str, source: str = "command") -> list[str]:
        """Send one command and return the printer's other output lines that
        arrived before its ok (e.g. the report of "M720")."""
        stats = SendStats()
        lines = prepare([Line(cmd, source)])
        if not lines:
            raise InputError(f"{source}: empty command")
        self._check_lengths(lines)
        self._stream(lines, None, False, stats)
        return stats.messages

    def _check_lengths(self, lines: list[Line]):
        # Checked before anything goes out, so a file is not half printed.
        for i, ln in enumerate(lines):
            f = frame(self.next_n + i, ln.cmd)
            if len(f) > self.max_line:
                raise InputError(f"{ln.source}: line is {len(f)} characters with number and checksum "
                                 f"({f[:40]}...); the printer takes at most {self.max_line}")

    def _message(self, text: str):
        if self.on_message is not None:
            self.on_message(text)

    def _stream(self, lines: list[Line], bar, continue_on_error: bool, stats: SendStats,
                resend_any: bool = False):
        base = self.next_n  # lines[i] is N(base + i)
        i = 0
        resend_count: dict[int, int] = {}
        while i < len(lines):
            n = base + i
            ln = lines[i]
            data = (frame(n, ln.cmd) + "\n").encode("ascii")
            try:
                self.link.write(data)
            except Exception as e:  # pyserial raises SerialException / SerialTimeoutException / OSError
                raise SendError(f"{ln.source}: writing to {self.port_name} failed: {e}") from None
            stats.bytes += len(data)
            nxt, refused = self._await_ok(n, ln, stats, handshake=resend_any)
            if nxt is None:
                # Taken (even if refused: the printer counted the line number).
                i += 1
                stats.lines += 1
                self.next_n = base + i
                if bar is not None:
                    bar.update(1)
                    if stats.resends or stats.busy:
                        bar.set_postfix(resent=stats.resends, busy=stats.busy, refresh=False)
                if refused is not None:
                    stats.errors.append((ln.source, ln.cmd, refused))
                    if not continue_on_error:
                        raise PrinterError(f"{ln.source}: printer refused {ln.cmd!r}: {refused}")
                    if bar is not None:
                        bar.write(f"{ln.source}: printer refused {ln.cmd!r}: {refused}")
                continue
            if resend_any:
                nxt = n
            # Resend from line nxt
            if not base <= nxt <= n:
                raise SendError(f"{ln.source}: printer asked to resend N{nxt}, which was "
                                f"{'never sent' if nxt > n else 'acknowledged before this stream'} "
                                f"(stream is N{base}..N{base + len(lines) - 1}); stopping")
            resend_count[nxt] = resend_count.get(nxt, 0) + 1
            if resend_count[nxt] > self.max_resends:
                raise SendError(f"{lines[nxt - base].source}: printer asked for N{nxt} "
                                f"{resend_count[nxt]} times; check the cable and the baud rate ({self.baud})")
            stats.resends += 1
            if bar is not None and nxt - base < i:
                # Acknowledged lines are never taken back; only log it.
                bar.write(f"printer asked to go back to N{nxt}")
            i = nxt - base
            self.next_n = base + i

    def _await_ok(self, n: int, ln: Line, stats: SendStats,
                  handshake: bool = False) -> tuple[int | None, str | None]:
        """Wait for the reply to line n.  Returns (None, refusal or None)
        when the line was taken, or (line number to resend from, None)."""
        deadline = time.monotonic() + self.timeout
        resend_to = None
        refused = None
        while True:
            reply = self.link.readline(deadline)
            if reply is None:
                heard = f"; last heard: {self._last_heard!r}" if self._last_heard else "; nothing heard yet"
                raise SendTimeout(f"{ln.source}: no reply from the printer on {self.port_name} within "
                                  f"{self.timeout:g} s after N{n} {ln.cmd!r}{heard}. "
                                  f"Is the firmware running and the baud rate ({self.baud}) right?")
            if not reply:
                continue
            self._last_heard = reply
            low = reply.lower()
            if low.startswith("ok"):
                if resend_to is not None:
                    return resend_to, None
                return None, refused
            m = _RESEND.match(reply)
            if m:
                resend_to = int(m.group(1))
                continue
            if "busy:" in low:
                stats.busy += 1
                deadline = time.monotonic() + self.timeout
                continue
            if low.startswith("error"):
                text = reply.split(":", 1)[1].strip() if ":" in reply else reply
                if _FATAL.search(text):
                    raise PrinterError(f"{ln.source}: printer halted after N{n} {ln.cmd!r}: {text}")
                if _TRANSPORT.search(text):
                    continue  # its Resend: follows
                refused = text if refused is None else f"{refused}; {text}"
                self._message(reply)
                continue
            if "unknown command" in low:
                # Stock firmware without bulgekit says this to M720..M723.
                refused = reply if refused is None else f"{refused}; {reply}"
                self._message(reply)
                continue
            if reply.startswith("start"):
                if handshake:
                    # The board came up only now (it resets when the port
                    # opens): the M110 went to the bootloader.  Let the
                    # banner pass, then send it again.
                    self.boot_messages.append(reply)
                    self._message(reply)
                    quiet = time.monotonic() + 0.5
                    while (extra := self.link.readline(quiet)) is not None:
                        if extra and not extra.lower().startswith("ok"):
                            self.boot_messages.append(extra)
                            self._message(extra)
                        quiet = time.monotonic() + 0.5
                    return n, None
                raise SendError(f"{ln.source}: the printer restarted (said 'start') while N{n} {ln.cmd!r} "
                                f"was in flight; stopping — check power and the USB reset")
            stats.messages.append(reply)
            self._message(reply)


class _Counter:
    """Stands in for the progress bar when a program shows progress its own way."""

    def __init__(self, fn):
        self.fn, self.n = fn, 0

    def update(self, k: int = 1):
        self.n += k
        self.fn(self.n)

    def set_postfix(self, **kw):
        pass

    def write(self, text: str):
        pass

    def close(self):
        pass


def send_lines(port, lines: Sequence, baud: int = 115200, **kw) -> SendStats:
    """Open, send, close.  kw: progress, continue_on_error, desc go to
    send(); the rest to Sender()."""
    send_kw = {k: kw.pop(k) for k in ("progress", "continue_on_error", "desc") if k in kw}
    with Sender(port, baud, **kw) as s:
        return s.send(lines, **send_kw)
