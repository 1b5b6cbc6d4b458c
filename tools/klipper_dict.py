#!/usr/bin/env python3
"""An MCU data dictionary for Klipper's batch mode (docs/klipper.md), written from Klipper's
documented protocol, not from a firmware build.

    klipper_dict.py -o DICT.json [--clock 16000000] [--mcu atmega2560]

Klipper's host (klippy) normally learns the micro-controller's commands with `identify`: the MCU
sends a JSON data dictionary naming each command and response by its format string, the
enumerations (pin names) and the build's constants (docs/Protocol.md, "Data dictionary"). In
batch mode (`klippy.py printer.cfg -i in.gcode -o out.serial -d DICT`) no MCU answers, so the
dictionary is read from a file. This writes one for a RAMPS-like ATmega2560 board: the messages
klippy looks up for steppers, endstops (trsync), digital and software-PWM outputs and analog
inputs (docs/MCU_Commands.md), message tags 0 and 1 for identify as the protocol fixes them,
the pins PA0..PL7, and the constants klippy reads (CLOCK_FREQ, MCU, STATS_SUMSQ_BASE, ADC_MAX,
PWM_MAX, SERIAL_BAUD, RECEIVE_WINDOW). It is enough for printer.cfg files that use those
objects (stepper_x/y/z, extruder with a heater and a thermistor, force_move); a config that
needs another command fails at start with klippy's "Unknown command" naming it.
"""

import argparse
import json
import os
import sys

# Commands the host sends (tag order is free; 0 and 1 are identify's, fixed by the protocol).
COMMANDS = [
    "identify offset=%u count=%c",
    # basecmd: configuration, clock, shutdown (docs/MCU_Commands.md, "Startup Commands")
    "allocate_oids count=%c",
    "get_config",
    "finalize_config crc=%u",
    "get_clock",
    "get_uptime",
    "emergency_stop",
    "clear_shutdown",
    "reset",
    # steppers ("Stepper commands")
    "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u",
    "queue_step oid=%c interval=%u count=%hu add=%hi",
    "set_next_step_dir oid=%c dir=%c",
    "reset_step_clock oid=%c clock=%u",
    "stepper_get_position oid=%c",
    "stepper_stop_on_trigger oid=%c trsync_oid=%c",
    # endstops and trigger synchronisation ("Endstop commands")
    "config_endstop oid=%c pin=%c pull_up=%c",
    "endstop_home oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u"
    " pin_value=%c trsync_oid=%c trigger_reason=%c",
    "endstop_query_state oid=%c",
    "config_trsync oid=%c",
    "trsync_start oid=%c report_clock=%u report_ticks=%u expire_reason=%c",
    "trsync_set_timeout oid=%c clock=%u",
    "trsync_trigger oid=%c reason=%c",
    # GPIO outputs: digital and software PWM (heaters, fans)
    "config_digital_out oid=%c pin=%u value=%c default_value=%c max_duration=%u",
    "set_digital_out pin=%u value=%c",
    "update_digital_out oid=%c value=%c",
    "queue_digital_out oid=%c clock=%u on_ticks=%u",
    "set_digital_out_pwm_cycle oid=%c cycle_ticks=%u",
    # hardware PWM
    "config_pwm_out oid=%c pin=%u cycle_ticks=%u value=%hu default_value=%hu max_duration=%u",
    "queue_pwm_out oid=%c clock=%u value=%hu",
    "set_pwm_out pin=%u cycle_ticks=%u value=%hu",
    # analog inputs (thermistors)
    "config_analog_in oid=%c pin=%u",
    "query_analog_in oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u"
    " min_value=%hu max_value=%hu range_check_count=%c",
]

RESPONSES = [
    "identify_response offset=%u data=%.*s",
    "starting",
    "is_shutdown static_string_id=%hu",
    "shutdown clock=%u static_string_id=%hu",
    "config is_config=%c crc=%u is_shutdown=%c move_count=%hu",
    "clock clock=%u",
    "uptime high=%u clock=%u",
    "stats count=%u sum=%u sumsq=%u",
    "stepper_position oid=%c pos=%i",
    "endstop_state oid=%c homing=%c next_clock=%u pin_value=%c",
    "trsync_state oid=%c can_trigger=%c trigger_reason=%c clock=%u",
    "analog_in_state oid=%c next_clock=%u value=%hu",
]

# The ATmega2560's ports (there is no port I); a pin's number is port * 8 + bit, as Klipper's
# AVR code numbers them, given as ranges "PA0": [first number, count].
AVR_PORTS = "ABCDEFGHJKL"


def pins():
    return {"P%s0" % p: [(ord(p) - ord("A")) * 8, 8] for p in AVR_PORTS}


def dictionary(clock=16000000, mcu="atmega2560", version="bulgekit-batch"):
    tags, tag = {}, 2
    out = {"commands": {}, "responses": {}}
    for kind, formats in (("commands", COMMANDS), ("responses", RESPONSES)):
        for fmt in formats:
            if fmt.startswith("identify"):
                n = 1 if kind == "commands" else 0
            else:
                n, tag = tag, tag + 1
            if tag > 96:
                raise ValueError("more messages than one-byte tags")
            out[kind][fmt] = tags[fmt] = n
    out["output"] = {}
    out["enumerations"] = {"pin": pins(), "static_string_id": {"bulgekit batch mode": 0}}
    out["config"] = {"CLOCK_FREQ": clock, "MCU": mcu, "STATS_SUMSQ_BASE": 256, "ADC_MAX": 1023,
                     "PWM_MAX": 255, "SERIAL_BAUD": 250000, "RECEIVE_WINDOW": 192}
    out["version"] = version
    out["build_versions"] = "written by tools/klipper_dict.py"
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", required=True, help="JSON file to write")
    ap.add_argument("--clock", type=int, default=16000000, help="CLOCK_FREQ, Hz")
    ap.add_argument("--mcu", default="atmega2560", help="the MCU constant")
    args = ap.parse_args(argv)
    text = json.dumps(dictionary(args.clock, args.mcu), indent=1, sort_keys=True)
    tmp = args.output + ".part"
    with open(tmp, "w") as f:
        f.write(text + "\n")
    os.replace(tmp, args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
