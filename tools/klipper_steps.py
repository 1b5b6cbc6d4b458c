#!/usr/bin/env python3
"""Step times of a Klipper batch run, as a bksim trace (docs/verification/marlin-simulation.md,
"Stops on stock firmware").

    klipper_steps.py DUMP.txt -o TRACE.txt

DUMP.txt is what Klipper's `klippy/parsedump.py DICT OUT.serial` prints for a batch run
(`klippy.py printer.cfg -i FILE.gcode -o OUT.serial -d DICT`): the commands the host would
send to the MCU. This replays the stepper commands the way Klipper's MCU code does
(src/stepper.c): `queue_step oid interval count add` makes `count` steps, the first
`interval` clock ticks after the stepper's previous step and each further one
`interval + k * add` after the one before; `set_next_step_dir` sets the direction pin for the
steps that follow; `reset_step_clock` sets the time the next interval counts from. Each
step and direction change is written as a rising edge in bksim's trace format,
`<clock> <port><pin> <level>`, with the pin names of `config_stepper` (PF0 -> F0), so
tools/trace_stops.py reads a Klipper run like a simulated Marlin one. The MCU clock of
an ATmega2560 build is 16 MHz, the same as trace_stops.py's.

Reads text only; it runs nothing of Klipper's.
"""

import argparse
import os
import re
import sys

_ARGS = re.compile(r"(\w+)=(\S+)")


def pin_name(pin):
    """Klipper's AVR pin name (PF0) as bksim's (F0)."""
    m = re.fullmatch(r"P([A-L])([0-7])", pin)
    if not m:
        raise ValueError("pin %r is not an AVR port pin like PF0" % pin)
    return m.group(1) + m.group(2)


def replay(lines):
    """[(clock, pin, level)] of every step (level 1, the pulse's rising edge) and
    direction change, in time order, and the number of steps per step pin."""
    steppers = {}   # oid -> dict(step=pin, dir=pin, clock=last step time, dir_level=...)
    events, counts = [], {}
    for n, line in enumerate(lines, 1):
        parts = line.split(None, 1)
        if not parts:
            continue
        cmd, args = parts[0], dict(_ARGS.findall(parts[1] if len(parts) > 1 else ""))
        if cmd == "config_stepper":
            steppers[int(args["oid"])] = {"step": pin_name(args["step_pin"]),
                                          "dir": pin_name(args["dir_pin"]),
                                          "clock": 0, "dir_level": 0, "next_dir": 0}
            counts[pin_name(args["step_pin"])] = 0
            continue
        if cmd not in ("queue_step", "set_next_step_dir", "reset_step_clock"):
            continue
        s = steppers.get(int(args["oid"]))
        if s is None:
            raise ValueError("line %d: %s for oid %s before its config_stepper" % (n, cmd, args["oid"]))
        if cmd == "set_next_step_dir":
            s["next_dir"] = int(args["dir"])
        elif cmd == "reset_step_clock":
            s["clock"] = int(args["clock"])
        else:
            interval, count, add = int(args["interval"]), int(args["count"]), int(args["add"])
            if s["next_dir"] != s["dir_level"]:
                # the MCU sets the pin when it loads the move, before its first step
                s["dir_level"] = s["next_dir"]
                events.append((s["clock"] + 1, s["dir"], s["dir_level"]))
            for _ in range(count):
                s["clock"] += interval
                events.append((s["clock"], s["step"], 1))
                events.append((s["clock"] + 1, s["step"], 0))
                interval += add
            counts[s["step"]] += count
    events.sort()
    return events, counts


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dump", help="parsedump.py output")
    ap.add_argument("-o", "--output", required=True, help="trace file to write")
    args = ap.parse_args(argv)
    try:
        with open(args.dump, encoding="utf-8", errors="replace") as f:
            events, counts = replay(f)
    except (OSError, ValueError, KeyError) as e:
        raise SystemExit("klipper_steps.py: %s: %s" % (args.dump, e))
    if not counts:
        raise SystemExit("klipper_steps.py: %s: no config_stepper line (not a parsedump.py output?)"
                         % args.dump)
    tmp = args.output + ".part"
    with open(tmp, "w") as out:
        for clock, pin, level in events:
            out.write("%d %s %d\n" % (clock, pin, level))
    os.replace(tmp, args.output)  # written whole or not at all
    print("%s: %s" % (args.output, ", ".join("%s %d steps" % kv for kv in sorted(counts.items()))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
