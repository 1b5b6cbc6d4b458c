"""Serial sender against a fake Marlin on the other end of a pseudo-terminal.

The fake printer checks line numbers and checksums like Marlin, damages
chosen incoming lines (as line noise would) so that it asks for resends,
answers long commands with busy: keep-alives, and records what it executed,
so the tests can demand that every line ran exactly once and in order.
"""
import os
import random
import select
import threading
import time
import tty

import pytest

from bulgekit.printer.sender import (
    InputError, Line, PrinterError, SendError, SendTimeout, Sender, checksum, clean_line, frame,
    prepare, read_gcode, send_lines,
)


class FakeMarlin(threading.Thread):
    def __init__(self, fd, *, corrupt=(), corrupt_rate=0.0, seed=1, busy_cmds=("G28", "G4"), busy_count=3,
                 busy_delay=0.05, refuse=None, fatal=None, silent_after=None, banner=True, last_n=0,
                 reboot_on=None, ask_old=None, arena=2048, replies=None):
        super().__init__(daemon=True)
        self.fd = fd
        self.corrupt = set(corrupt)          # indexes of received lines (0-based) to damage
        self.rng = random.Random(seed)
        self.corrupt_rate = corrupt_rate
        self.busy_cmds = busy_cmds
        self.busy_count = busy_count
        self.busy_delay = busy_delay
        self.refuse = refuse or {}           # command → error text
        self.fatal = fatal                   # command that halts the printer
        self.silent_after = silent_after     # stop answering after this many executed commands
        self.banner = banner
        self.last_n = last_n
        self.reboot_on = reboot_on
        self.ask_old = ask_old               # command after which it claims an older line was lost
        self.arena = arena                   # what M721's status line reports (None: stock firmware)
        self.replies = replies or {}         # command -> lines it prints before its ok (M115, M503)
        self.executed = []
        self.received = 0
        self.damaged = 0
        self.resends_asked = 0
        self.busy_sent = 0
        self.raw_lines = []
        self.stop = threading.Event()

    def say(self, text):
        os.write(self.fd, (text + "\n").encode())

    def run(self):
        if self.banner:
            # Like a board reset by the port opening: the banner comes a
            # moment later (pyserial drops input that arrived before open).
            time.sleep(0.3)
            self.say("start")
            self.say("echo:Marlin bulgekit-fake")
            self.say("echo: Free Memory: 4000")
        buf = b""
        while not self.stop.is_set():
            r, _, _ = select.select([self.fd], [], [], 0.05)
            if not r:
                continue
            try:
                chunk = os.read(self.fd, 1024)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                self.handle(raw.decode("ascii", "replace").strip())

    def resend(self, why):
        self.say(f"Error:{why}, Last Line: {self.last_n}")
        self.say(f"Resend: {self.last_n + 1}")
        self.say("ok")
        self.resends_asked += 1

    def handle(self, line):
        if not line:
            return
        idx = self.received
        self.received += 1
        if idx in self.corrupt or (self.corrupt_rate and self.rng.random() < self.corrupt_rate):
            # flip one bit of a character before the '*' (line noise)
            k = self.rng.randrange(0, line.index("*") if "*" in line else len(line))
            line = line[:k] + chr(ord(line[k]) ^ 0x04) + line[k + 1:]
            self.damaged += 1
        self.raw_lines.append(line)
        if self.silent_after is not None and len(self.executed) >= self.silent_after:
            return
        cmd = line
        if line.startswith("N"):
            if "*" not in line:
                self.resend("No Checksum with line number")
                return
            body, cs = line.rsplit("*", 1)
            if not cs.isdigit() or checksum(body) != int(cs):
                self.resend("checksum mismatch")
                return
            num, cmd = body[1:].split(" ", 1)
            n = int(num)
            is_m110 = cmd.startswith("M110")
            if n != self.last_n + 1 and not is_m110:
                self.resend("Line Number is not Last Line Number+1")
                return
            if is_m110:
                arg = [w for w in cmd.split()[1:] if w.startswith("N")]
                self.last_n = int(arg[0][1:]) if arg else n
            else:
                self.last_n = n
        self.execute(cmd)

    def execute(self, cmd):
        if cmd.startswith("M110"):
            self.say("ok")
            return
        self.executed.append(cmd)
        if self.reboot_on and cmd == self.reboot_on:
            self.say("start")
            return
        if self.fatal and cmd == self.fatal:
            self.say("Error:Printer halted. kill() called!")
            return
        if self.ask_old and cmd == self.ask_old:
            # claims the line before this one never arrived
            self.last_n -= 2
            self.executed.pop()
            self.executed.pop()
            self.say(f"Resend: {self.last_n + 1}")
            self.say("ok")
            self.ask_old = None
            return
        if cmd.split()[0] in self.busy_cmds:
            for _ in range(self.busy_count):
                time.sleep(self.busy_delay)
                self.say("echo:busy: processing")
                self.busy_sent += 1
        if cmd in self.refuse:
            self.say("Error:" + self.refuse[cmd])
        if cmd.startswith("M105"):
            self.say("ok T:210.0 /210.0 B:60.0 /60.0")
            return
        for reply in self.replies.get(cmd.strip(), ()):
            self.say(reply)
        if cmd.startswith("M720") and cmd.strip() == "M720":
            self.say("echo:  M720 S1 P100 E0.100 T0.250")
        if cmd.strip() == "M721":
            if self.arena is None:
                self.say('echo:Unknown command: "M721"')
            else:
                self.say(f"echo:BulgeMap layers:0 bytes:0/{self.arena} points:0 z:-")
        self.say("ok")


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(slave)  # before the printer talks, so nothing is echoed back
    name = os.ttyname(slave)
    printers = []

    def start(**kw):
        p = FakeMarlin(master, **kw)
        printers.append(p)
        p.start()
        return p

    yield name, start
    for p in printers:
        p.stop.set()
        p.join(2)
    os.close(slave)
    os.close(master)


def program(n=60):
    lines = ["G28 ; home", "G90", "M82"]
    for i in range(n):
        lines.append(f"G1 X{i % 50}.5 Y{(i * 7) % 50}.25 E{i * 0.1:.3f} F1800")
        if i % 17 == 0:
            lines.append("G4 P10")
    return lines


def test_frame_and_checksum_match_marlin():
    # Known value: the XOR of "N1 G28" is computed by hand here
    x = 0
    for ch in "N1 G28":
        x ^= ord(ch)
    assert frame(1, "G28") == f"N1 G28*{x}"
    assert checksum("N0 M110 N0") == 125  # the number hosts commonly send for M110 N0


def test_clean_and_prepare():
    assert clean_line("  G1 X1 ; move") == "G1 X1"
    assert clean_line("N12 G1 X1*55") == "G1 X1"
    assert clean_line("; only comment") == ""
    ls = prepare(["G28", "", "; c", "M105"], "job")
    assert ls == [Line("G28", "job:1"), Line("M105", "job:4")]
    with pytest.raises(InputError, match="job:2: character 'é'"):
        prepare(["G28", "M117 café"], "job")
    with pytest.raises(InputError, match=r"job:1: '\*' cannot be sent"):
        prepare(["M117 5*3=15"], "job")
    assert clean_line("N7 M117 hi *99") == "M117 hi"


def test_clean_stream_all_lines_once_in_order(pty_pair):
    name, start = pty_pair
    printer = start()
    lines = program()
    with Sender(name, boot_wait=1.0, timeout=5) as s:
        assert s.boot_messages[0] == "start"
        stats = s.send(lines, progress=False)
    expected = prepare(lines)
    assert printer.executed == [l.cmd for l in expected]
    assert stats.lines == len(expected) and stats.resends == 0
    assert stats.busy == printer.busy_sent > 0
    # every line went out numbered 1.. with a valid checksum
    numbered = [l for l in printer.raw_lines if not l.startswith("N0 ")]
    assert [int(l[1:].split(" ")[0]) for l in numbered] == list(range(1, len(expected) + 1))


def test_resends_recover_every_damaged_line(pty_pair):
    name, start = pty_pair
    # damage the M110 itself, a line early on, and two lines in a row
    printer = start(corrupt=(0, 3, 10, 11), last_n=417)
    lines = program(40)
    with Sender(name, boot_wait=1.0, timeout=5) as s:
        stats = s.send(lines, progress=False)
    assert printer.executed == [l.cmd for l in prepare(lines)]
    assert printer.damaged == 4 and printer.resends_asked == 4
    assert stats.resends == 3  # the M110 repeat is not part of the stream's stats


def test_random_noise_stress(pty_pair):
    name, start = pty_pair
    printer = start(corrupt_rate=0.15, seed=7, busy_count=2, busy_delay=0.01)
    lines = program(300)
    with Sender(name, boot_wait=0.5, timeout=5, max_resends=20) as s:
        stats = s.send(lines, progress=False)
    assert printer.executed == [l.cmd for l in prepare(lines)]
    assert printer.damaged > 20
    assert stats.resends == printer.resends_asked - (1 if printer.raw_lines[0] != "N0 M110 N0*125" else 0)
    assert stats.busy == printer.busy_sent


def test_printer_asking_for_older_line(pty_pair):
    name, start = pty_pair
    lines = ["G90", "G1 X1", "G1 X2", "G1 X3", "G1 X4"]
    printer = start(ask_old="G1 X3")
    with Sender(name, boot_wait=0.5, timeout=5) as s:
        stats = s.send(lines, progress=False)
    assert printer.executed == lines
    assert stats.resends == 1


def test_timeout_names_line_and_port(pty_pair):
    name, start = pty_pair
    start(silent_after=2)
    with Sender(name, boot_wait=0.3, timeout=0.6) as s:
        t0 = time.monotonic()
        with pytest.raises(SendTimeout) as e:
            s.send([Line("G90", "job.gcode:1"), Line("G91", "job.gcode:2"), Line("G1 X5", "job.gcode:3")],
                   progress=False)
        assert time.monotonic() - t0 < 3
    msg = str(e.value)
    assert "job.gcode:3" in msg and "N3 'G1 X5'" in msg and name in msg and "0.6 s" in msg


def test_busy_keeps_a_long_command_alive(pty_pair):
    name, start = pty_pair
    # 6 × 0.2 s of busy is 1.2 s in all, longer than the 0.5 s timeout
    printer = start(busy_count=6, busy_delay=0.2)
    with Sender(name, boot_wait=0.3, timeout=0.5) as s:
        stats = s.send(["G28", "G1 X1"], progress=False)
    assert printer.executed == ["G28", "G1 X1"] and stats.busy == 6


def test_refused_command_stops_after_it_unless_asked(pty_pair):
    name, start = pty_pair
    printer = start(refuse={"M720 P2500": "M720 P2500.000 not in [0.000..2000.000]"})
    with Sender(name, boot_wait=0.3, timeout=5) as s:
        with pytest.raises(PrinterError, match=r"cmds:2: printer refused 'M720 P2500': M720 P2500.000 not in"):
            s.send([Line("M720 S1", "cmds:1"), Line("M720 P2500", "cmds:2"), Line("M720 P50", "cmds:3")],
                   progress=False)
        assert printer.executed == ["M720 S1", "M720 P2500"]
        # the connection is still in step: the next send continues the numbering
        stats = s.send(["M720 P50"], progress=False)
        assert stats.lines == 1 and printer.executed[-1] == "M720 P50"
        stats = s.send(["M720 P2500", "G90"], progress=False, continue_on_error=True)
        assert stats.lines == 2 and len(stats.errors) == 1 and stats.errors[0][1] == "M720 P2500"
    assert printer.executed[-2:] == ["M720 P2500", "G90"]


def test_fatal_error_stops_at_once(pty_pair):
    name, start = pty_pair
    printer = start(fatal="M104 S999")
    with Sender(name, boot_wait=0.3, timeout=5) as s:
        with pytest.raises(PrinterError, match="halted.*kill"):
            s.send(["G90", "M104 S999", "G1 X1"], progress=False)
    assert printer.executed == ["G90", "M104 S999"]


def test_reboot_mid_stream_is_reported(pty_pair):
    name, start = pty_pair
    start(reboot_on="G1 X2")
    with Sender(name, boot_wait=0.3, timeout=5) as s:
        with pytest.raises(SendError, match="restarted"):
            s.send(["G1 X1", "G1 X2", "G1 X3"], progress=False)


def test_command_returns_report(pty_pair):
    name, start = pty_pair
    start()
    with Sender(name, boot_wait=0.3, timeout=5) as s:
        assert s.command("M720") == ["echo:  M720 S1 P100 E0.100 T0.250"]
        assert s.command("M105") == []  # its report rides on the ok line


def test_too_long_line_rejected_before_anything_is_sent(pty_pair):
    name, start = pty_pair
    printer = start()
    long_cmd = "M721 O0 D" + "A" * 90
    with Sender(name, boot_wait=0.3, timeout=5) as s:
        with pytest.raises(InputError, match=r"map:2: line is \d+ characters"):
            s.send([Line("G90", "map:1"), Line(long_cmd, "map:2")], progress=False)
    assert printer.executed == []


def test_read_gcode_and_send_lines_with_progress(pty_pair, tmp_path, capsys):
    name, start = pty_pair
    printer = start(corrupt=(2,))
    f = tmp_path / "job.gcode"
    f.write_text("; header\nG28\n\nG1 X1 ; go\nM105\n")
    lines = read_gcode(f)
    assert [l.source for l in lines] == [f"{f}:2", f"{f}:4", f"{f}:5"]
    stats = send_lines(name, lines, boot_wait=0.3, timeout=5, progress=True, desc="job")
    assert printer.executed == ["G28", "G1 X1", "M105"]
    assert stats.resends == 1 and "3 lines" in stats.summary()
    err = capsys.readouterr().err
    assert "job" in err and "3/3" in err


def test_unknown_command_from_stock_firmware(pty_pair):
    name, start = pty_pair
    printer = start()

    # Stock Marlin answers our M-codes with an echo and then ok.
    orig = printer.execute

    def stock(cmd):
        if cmd.startswith("M72"):
            printer.executed.append(cmd)
            printer.say(f'echo:Unknown command: "{cmd}"')
            printer.say("ok")
        else:
            orig(cmd)

    printer.execute = stock
    with Sender(name, boot_wait=0.3, timeout=5) as s:
        with pytest.raises(PrinterError, match="Unknown command"):
            s.send(["G90", "M721 X"], progress=False)


def test_open_errors(tmp_path):
    with pytest.raises(SendError, match="cannot open"):
        Sender(str(tmp_path / "ttyNOPE"), boot_wait=0).open()
    with pytest.raises(InputError, match="cannot read"):
        read_gcode(tmp_path / "none.gcode")


def test_banner_after_handshake_started(pty_pair):
    # The board boots only after our M110 went out (boot_wait too short):
    # the sender lets the banner pass and sends M110 again.
    name, start = pty_pair
    printer = start()
    with Sender(name, boot_wait=0, timeout=5) as s:
        stats = s.send(["G90", "G1 X1"], progress=False)
        assert "start" in s.boot_messages
    assert printer.executed == ["G90", "G1 X1"] and stats.resends == 0


def test_send_cli_commands_map_and_file(pty_pair, tmp_path):
    from click.testing import CliRunner

    from bulgekit.bulge import mapformat
    from bulgekit.cli import main

    name, start = pty_pair
    printer = start(corrupt=(4,))
    # a map large enough for two M721 chunk lines
    data = mapformat.encode_map([(0.3 * k, [(10.0 + i, 2.0 * i) for i in range(8)]) for k in range(1, 6)],
                                quantum_um=50, layer_height_mm=0.3)
    bkm = tmp_path / "m.bkm"
    bkm.write_bytes(data)
    g = tmp_path / "job.gcode"
    g.write_text("G28\nG1 X1 ; move\n")
    r = CliRunner().invoke(main, ["send", "-p", name, "--boot-wait", "0.5", "--timeout", "5", "--no-progress",
                                  "-c", "M720", "--map", str(bkm), str(g)])
    assert r.exit_code == 0, r.output
    upload = mapformat.upload_lines(data)
    assert printer.executed == ["M720"] + upload + ["G28", "G1 X1"]
    assert "echo:  M720 S1 P100 E0.100 T0.250" in r.output
    assert "m.bkm: " in r.output and "1 resent" in r.output and "job.gcode: 2 lines" in r.output


def test_send_cli_refusal_and_timeout_messages(pty_pair, tmp_path):
    from click.testing import CliRunner

    from bulgekit.cli import main

    name, start = pty_pair
    start(refuse={"M720 P5000": "M720 P5000.000 not in [0.000..2000.000]"})
    g = tmp_path / "bad.gcode"
    g.write_text("G90\nM720 P5000\nG1 X1\n")
    r = CliRunner().invoke(main, ["send", "-p", name, "--boot-wait", "0.5", "--timeout", "5", "--no-progress", str(g)])
    assert r.exit_code == 1
    assert f"{g}:2: printer refused 'M720 P5000': M720 P5000.000 not in [0.000..2000.000]" in r.output
    r = CliRunner().invoke(main, ["send", "-p", str(tmp_path / "nope"), "--boot-wait", "0", "-c", "M105"])
    assert r.exit_code == 1 and "cannot open" in r.output


def _annotated(tmp_path, arena):
    from bulgekit.bulge import mapformat
    from bulgekit.bulge.annotate import annotate_bytes
    from bulgekit.bulge.fallback import Settings
    g = "G90\nM83\nG1 Z0.3\n;TYPE:External perimeter\nG1 X10 Y0 E1\n"
    out = annotate_bytes(g.encode(), mapformat.encode_map([(0.3, [(5.0, 0.0)])]), Settings(), arena=arena)
    f = tmp_path / f"a{arena}.gcode"
    f.write_bytes(out)
    return f


@pytest.mark.parametrize("printer_arena, file_arena, ok", [(1024, 2048, False), (2048, 1024, True),
                                                           (None, 2048, False)])
def test_send_checks_the_printer_arena_before_an_annotated_file(pty_pair, tmp_path, printer_arena,
                                                                file_arena, ok):
    from click.testing import CliRunner

    from bulgekit.cli import main

    name, start = pty_pair
    printer = start(arena=printer_arena)
    f = _annotated(tmp_path, file_arena)
    assert f"arena {file_arena}" in f.read_text().splitlines()[0]
    r = CliRunner().invoke(main, ["send", "-p", name, "--boot-wait", "0.5", "--timeout", "5",
                                  "--no-progress", str(f)])
    assert printer.executed[0] == "M721"  # the status query comes first
    if ok:
        assert r.exit_code == 0, r.output
        assert printer.executed[-1] == "M721 X" and len(printer.executed) > 5
    else:
        assert r.exit_code == 1 and printer.executed == ["M721"]  # nothing of the file was sent
        if printer_arena is None:
            assert "is it running bulgekit firmware" in r.output and "bulgekit fallback" in r.output
        else:
            assert (f"annotated for a 2048-byte map arena, but the printer's is 1024" in r.output
                    and "--arena 1024" in r.output)


ENDER3_REPLIES = {
    "M115": ["FIRMWARE_NAME:Marlin 2.1.2.7 (Dec  1 2026 10:00:00) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
             "PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ender-3 EXTRUDER_COUNT:1", "Cap:EEPROM:1"],
    "M503": ["echo:; Steps per unit:", "echo:  M92 X80.00 Y80.00 Z400.00 E93.00",
             "echo:  M203 X500.00 Y500.00 Z5.00 E25.00", "echo:  M201 X500.00 Y500.00 Z100.00 E5000.00",
             "echo:  M204 P500.00 R500.00 T500.00", "echo:  M205 B20000.00 S0.00 T0.00 J0.08"],
}


def test_printer_read_saves_the_profile(pty_pair, tmp_path):
    """`bulgekit printer read` asks M115 and M503 and writes a profile that --printer takes."""
    from click.testing import CliRunner

    from bulgekit import machine
    from bulgekit.cli import main
    name, start = pty_pair
    p = start(replies=ENDER3_REPLIES)
    out = tmp_path / "ender.toml"
    r = CliRunner().invoke(main, ["printer", "read", "-p", name, "-o", str(out), "--boot-wait", "1"])
    assert r.exit_code == 0, r.output
    assert "M115" in p.executed and "M503" in p.executed
    m = machine.load(str(out))
    assert (m.firmware, m.accel, m.junction_deviation, m.max_accel.e) == ("marlin", 500, 0.08, 5000)
    assert m.steps_per_mm == machine.Axes(80, 80, 400, 93)
    r = CliRunner().invoke(main, ["printer", "show", str(out)])
    assert r.exit_code == 0 and "accel 500" in r.output, r.output


def test_printer_read_refuses_a_reply_without_settings(pty_pair, tmp_path):
    from click.testing import CliRunner

    from bulgekit.cli import main
    name, start = pty_pair
    start(replies={"M115": ENDER3_REPLIES["M115"]})
    out = tmp_path / "x.toml"
    r = CliRunner().invoke(main, ["printer", "read", "-p", name, "-o", str(out), "--boot-wait", "1"])
    assert r.exit_code == 1 and "M503 printed no settings" in r.output, r.output
    assert not out.exists()
