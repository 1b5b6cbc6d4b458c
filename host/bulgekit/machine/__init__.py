"""The printer model: what every writer and the estimator know of the printer a file is for.

A stop on stock firmware is timed by the printer's own planner, so its shape depends on the
printer's numbers: steps/mm (a stop is whole E steps), accelerations and feed-rate limits (how
long the head takes to stop and start again), the corner rule (junction deviation or classic
jerk: how fast the next move may start), Marlin's step-rate floor and segment minimum, and for
Klipper the extrude-only limits and square corner velocity. One frozen `PrinterModel` holds
them; nothing else in the package keeps a copy of a printer constant.

Where a model comes from (`resolve`):
  * a preset by name (`PRESETS`: each cites the file its numbers are read from);
  * a file (`load`): a saved M503 reply (M92 M201 M203 M204 M205 M900, as Marlin and Prusa's
    firmware print them), a Klipper printer.cfg (its [include]s and SAVE_CONFIG block
    followed), or a profile TOML that `to_toml` writes;
  * then the G-code's own settings (`with_gcode`): the printer runs the file's M92, M201,
    M203, M204, M205 and M900, so they win from their line on.

The firmware kind (`firmware`) chooses the stop form: marlin (Marlin 2.x, the bulgekit fork's
base), klipper, prusa (Prusa's firmwares: MK3S's and Buddy's) or reprap (RepRapFirmware).
"""
from __future__ import annotations

import dataclasses
import glob
import math
import os
import re
import tomllib
from dataclasses import dataclass, replace

from ..errors import BulgekitError, MissingInputError

FIRMWARES = ("marlin", "klipper", "prusa", "reprap")
KINEMATICS = ("cartesian", "corexy")   # (a Klipper stop's head terms: which motors step, when)
AXES = "XYZE"


class ProfileError(BulgekitError):
    """A printer profile that cannot be used: names the file, line and setting."""


class ProfileMissing(ProfileError, MissingInputError):
    """--printer names neither a preset nor a file: a usage error (exit status 2)."""


@dataclass(frozen=True)
class Axes:
    """One number per axis (X, Y, Z, E); `axes["X"]` reads one."""
    x: float
    y: float
    z: float
    e: float

    def __getitem__(self, axis: str) -> float:
        return getattr(self, axis.lower())

    def with_(self, **kw) -> "Axes":
        return replace(self, **{k.lower(): float(v) for k, v in kw.items()})

    def as_dict(self) -> dict:
        return {a: self[a] for a in AXES}


@dataclass(frozen=True)
class PrinterModel:
    """A printer's motion settings. Marlin names in brackets."""
    name: str = "marlin"
    firmware: str = "marlin"
    source: str = ""                              # where the numbers come from
    steps_per_mm: Axes = Axes(80, 80, 400, 93)    # M92
    max_feedrate: Axes = Axes(300, 300, 5, 25)    # M203, mm/s
    max_accel: Axes = Axes(3000, 3000, 100, 10000)  # M201, mm/s^2
    accel: float = 3000.0                         # M204 P: printing moves
    travel_accel: float = 3000.0                  # M204 T
    retract_accel: float = 3000.0                 # M204 R: moves of E alone
    junction_deviation: float | None = 0.013      # M205 J, mm (None: classic jerk)
    jerk: Axes | None = None                      # M205 X Y Z E, mm/s (CLASSIC_JERK)
    min_segment_steps: int = 6                    # MIN_STEPS_PER_SEGMENT: a shorter move is dropped
    lookahead: int = 16                           # BLOCK_BUFFER_SIZE
    min_step_rate: float = 120.0                  # MINIMAL_STEP_RATE, steps/s: a block's floor
    linear_advance_k: float = 0.0                 # M900 K (0: LIN_ADVANCE off or unused)
    # Klipper ([printer] and [extruder]); None: Klipper's own default, derived (see klipper_*)
    square_corner_velocity: float = 5.0
    minimum_cruise_ratio: float = 0.5
    max_extrude_only_velocity: float | None = None
    max_extrude_only_accel: float | None = None
    max_extrude_cross_section: float | None = None
    nozzle_diameter: float = 0.4
    filament_diameter: float = 1.75
    kinematics: str = "cartesian"                 # [printer] kinematics: which motors X/Y step

    def __post_init__(self):
        if self.firmware not in FIRMWARES:
            raise ValueError(f"firmware {self.firmware!r} must be one of {', '.join(FIRMWARES)}")
        if self.kinematics not in KINEMATICS:
            raise ValueError(f"kinematics {self.kinematics!r} must be one of {', '.join(KINEMATICS)}")
        if (self.junction_deviation is None) == (self.jerk is None):
            raise ValueError("give either a junction deviation or classic jerk, not both")
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            vals = v.as_dict().items() if isinstance(v, Axes) else [(f.name, v)]
            for k, x in vals:
                if isinstance(x, (int, float)) and not isinstance(x, bool):
                    if not math.isfinite(x) or x < 0:
                        raise ValueError(f"{f.name} {k}: {x} must be a finite number >= 0")
        for a in AXES:
            if self.steps_per_mm[a] <= 0 or self.max_feedrate[a] <= 0 or self.max_accel[a] <= 0:
                raise ValueError(f"{a}: steps/mm, maximum feed rate and acceleration must be > 0")

    # --- derived numbers -----------------------------------------------------------------
    @property
    def e_steps(self) -> float:
        return self.steps_per_mm.e

    @property
    def xy_steps(self) -> float:
        """Steps per mm of X (the leading axis of a move along X)."""
        return self.steps_per_mm.x

    def corner_speed(self, accel: float | None = None) -> float:
        """mm/s the next X/Y move may enter at after a move of E alone: a 90 degree corner.
        Junction deviation: sqrt(a JD sin(th/2) / (1 - sin(th/2))) at th = 90 degrees, so
        sqrt(a JD / (sqrt 2 - 1)); classic jerk: the X jerk (the speed the axis may jump to)."""
        if self.jerk is not None:
            return self.jerk.x
        a = self.accel if accel is None else accel
        return math.sqrt(a * self.junction_deviation / (math.sqrt(2) - 1))

    @property
    def filament_area(self) -> float:
        return math.pi * (self.filament_diameter / 2) ** 2

    @property
    def klipper_cross_section(self) -> float:
        """[extruder] max_extrude_cross_section, mm^2: Klipper's default is 4 nozzle^2."""
        if self.max_extrude_cross_section is not None:
            return self.max_extrude_cross_section
        return 4.0 * self.nozzle_diameter ** 2

    @property
    def klipper_extrude_only(self) -> tuple[float, float]:
        """(velocity mm/s, accel mm/s^2) of a move of E alone in Klipper: max_extrude_only_*,
        whose defaults are [printer]'s max_velocity and max_accel times cross-section/filament
        area (klippy/kinematics/extruder.py), fixed when Klipper reads its config: a file's M204 or
        SET_VELOCITY_LIMIT (`accel` after with_gcode) changes the toolhead's max_accel, not these."""
        ratio = self.klipper_cross_section / self.filament_area
        v = self.max_extrude_only_velocity
        a = self.max_extrude_only_accel
        return (self.max_feedrate.x * ratio if v is None else v,
                self.max_accel.x * ratio if a is None else a)

    @property
    def rate_accel(self) -> float:
        """The acceleration a run of short moves at changing speeds gets: the print acceleration;
        on Klipper the accel-to-decel limit, max_accel x (1 - minimum_cruise_ratio), by which its
        look-ahead plans a move that speeds up and slows down again (a lithophane's mid-line)."""
        if self.firmware == "klipper" and 0 < self.minimum_cruise_ratio < 1:
            return self.accel * (1 - self.minimum_cruise_ratio)
        return self.accel

    def describe(self) -> str:
        """One line: what a file's header and the statistics name."""
        corner = (f"jerk {_n(self.jerk.x)}/{_n(self.jerk.y)}/{_n(self.jerk.z)}/{_n(self.jerk.e)} mm/s"
                  if self.jerk is not None else f"JD {_n(self.junction_deviation)} mm")
        s = self.steps_per_mm
        out = (f"{self.name} ({self.firmware}): steps/mm {_n(s.x)}/{_n(s.y)}/{_n(s.z)}/{_n(s.e)}, "
               f"accel {_n(self.accel)} (travel {_n(self.travel_accel)}, retract "
               f"{_n(self.retract_accel)}) mm/s^2, {corner}")
        if self.linear_advance_k:
            out += f", K {_n(self.linear_advance_k)}"
        if self.firmware == "klipper":
            v, a = self.klipper_extrude_only
            out += f", square corner {_n(self.square_corner_velocity)} mm/s, extrude-only {_n(v)} mm/s {_n(a)} mm/s^2"
        return out


def _n(v: float) -> str:
    s = f"{v:.4f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


# --- presets ---------------------------------------------------------------------------------
MARLIN = PrinterModel(
    name="marlin", firmware="marlin",
    source="Marlin 2.1.2.x Configuration.h/Configuration_adv.h defaults (RAMPS example), "
           "E steps 93 (a stock Ender-3 extruder; the example's 500 is for its geared one)")

PRESETS: dict[str, PrinterModel] = {
    "marlin": MARLIN,
    "ender3": PrinterModel(
        name="ender3", firmware="marlin",
        source="Marlin's example configuration config/examples/Creality/Ender-3/CrealityV1 "
               "(Configurations, release-2.1.2.4): DEFAULT_AXIS_STEPS_PER_UNIT, "
               "DEFAULT_MAX_FEEDRATE, DEFAULT_MAX_ACCELERATION, DEFAULT_*ACCELERATION, "
               "JUNCTION_DEVIATION_MM",
        steps_per_mm=Axes(80, 80, 400, 93), max_feedrate=Axes(500, 500, 5, 25),
        max_accel=Axes(500, 500, 100, 5000), accel=500, travel_accel=500, retract_accel=500,
        junction_deviation=0.08),
    "marlin-classic-jerk": PrinterModel(
        name="marlin-classic-jerk", firmware="marlin",
        source="Marlin 2.1.2.x defaults with CLASSIC_JERK: DEFAULT_XJERK/YJERK 10, ZJERK 0.3, "
               "DEFAULT_EJERK 5",
        junction_deviation=None, jerk=Axes(10, 10, 0.3, 5)),
    "prusa-mk3s": PrinterModel(
        name="prusa-mk3s", firmware="prusa",
        source="PrusaSlicer's PrusaResearch.ini, [printer:Original Prusa i3 MK3] "
               "machine_max_* (normal mode); steps/mm of Prusa-Firmware's MK3S "
               "Configuration_prusa.h (100, 100, 400, 280)",
        steps_per_mm=Axes(100, 100, 400, 280), max_feedrate=Axes(200, 200, 12, 120),
        max_accel=Axes(1000, 1000, 200, 5000), accel=1250, travel_accel=1250, retract_accel=1250,
        junction_deviation=None, jerk=Axes(8, 8, 0.4, 4.5)),
    "klipper-corexy": PrinterModel(
        name="klipper-corexy", firmware="klipper",
        source="Klipper's config/example-corexy.cfg: max_velocity 300, max_accel 3000, "
               "rotation_distance 40 at 16 microsteps (80 steps/mm); extruder rotation_distance "
               "33.5 (95.5 steps/mm), nozzle 0.4, filament 1.75; square_corner_velocity and the "
               "extrude-only limits at Klipper's defaults",
        steps_per_mm=Axes(80, 80, 400, 3200 / 33.5), max_feedrate=Axes(300, 300, 25, 300),
        max_accel=Axes(3000, 3000, 30, 3000), accel=3000, travel_accel=3000, retract_accel=3000,
        junction_deviation=5.0 ** 2 * (math.sqrt(2) - 1) / 3000, lookahead=0, min_step_rate=0.0,
        min_segment_steps=0, kinematics="corexy"),
}
DEFAULT = MARLIN


def preset(name: str) -> PrinterModel:
    try:
        return PRESETS[name]
    except KeyError:
        raise ProfileError(f"no printer preset {name!r} (presets: {', '.join(PRESETS)}; "
                           "or give a file: an M503 reply, a Klipper printer.cfg or a profile TOML)") from None


def resolve(spec: str | None, firmware: str | None = None) -> PrinterModel:
    """A preset's name or a file's path (None: DEFAULT); firmware, when given, overrides the
    model's kind (the stop form)."""
    if spec is None:
        m = DEFAULT
    elif spec in PRESETS:
        m = PRESETS[spec]
    elif os.path.exists(spec):
        m = load(spec)
    else:
        raise ProfileMissing(f"--printer {spec}: neither a file nor a preset (presets: {', '.join(PRESETS)})")
    if firmware is not None and firmware != m.firmware:
        m = _klipper_shape(replace(m, firmware=firmware)) if firmware == "klipper" else replace(m, firmware=firmware)
    return m


def klipper_jd(square_corner_velocity: float, accel: float) -> float:
    """The junction deviation Klipper derives from square_corner_velocity (klippy/toolhead.py):
    scv^2 (sqrt 2 - 1) / max_accel, so that a 90 degree corner is taken at scv."""
    return square_corner_velocity ** 2 * (math.sqrt(2) - 1) / accel


def _klipper_shape(m: PrinterModel) -> PrinterModel:
    """A Marlin-read model run by Klipper: no step-rate floor or segment minimum, corners by
    square corner velocity."""
    return replace(m, min_step_rate=0.0, min_segment_steps=0, lookahead=0, jerk=None,
                   junction_deviation=klipper_jd(m.square_corner_velocity, m.accel))


# --- files -----------------------------------------------------------------------------------
def load(path: str) -> PrinterModel:
    """A profile file of any of the three kinds, told by its content."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise ProfileError(f"{path}: cannot read printer profile: {e.strerror}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ProfileError(f"{path}: not a text file (an M503 reply, a printer.cfg or a profile TOML)") from None
    name = os.path.splitext(os.path.basename(path))[0]
    if path.endswith(".toml") or re.search(r"^\s*\[printer_model\]", text, re.M):
        return from_toml(text, path)
    if re.search(r"^\s*\[(printer|extruder|stepper_x)\]", text, re.M):
        return from_klipper_cfg(path)
    if _M_LINE.search(text):
        return from_m503(text, source=path, name=name)
    raise ProfileError(f"{path}: not a printer profile: no M92/M201/M203/M204/M205 line, no Klipper "
                       "[printer] section, no [printer_model] table")


# an M503 line: "echo:  M203 X500.00 Y500.00 Z5.00 E25.00", a G-code line, or "M205 ..." from a log
_M_LINE = re.compile(r"^(?:echo:)?\s*(?:N\d+\s+)?(M92|M201|M203|M204|M205|M900|M115)\b(.*)$", re.M | re.I)
_WORD = re.compile(r"([A-Za-z])\s*(-?\d+(?:\.\d*)?|-?\.\d+)")


def _words(rest: str) -> dict[str, float]:
    rest = rest.split(";", 1)[0]
    return {k.upper(): float(v) for k, v in _WORD.findall(rest)}


def apply_mcode(m: PrinterModel, cmd: str, words: dict[str, float], where: str) -> PrinterModel:
    """The model after one of M92 M201 M203 M204 M205 M900, as Marlin applies it (M204 S: both
    print and travel, Marlin 1.x and Prusa's spelling; M205 J switches to junction deviation, X/Y
    to classic jerk only where the model has classic jerk, as a firmware built without it ignores
    them)."""
    cmd = cmd.upper()
    try:
        if cmd in ("M92", "M201", "M203"):
            attr = {"M92": "steps_per_mm", "M201": "max_accel", "M203": "max_feedrate"}[cmd]
            axes = {a: v for a, v in words.items() if a in AXES}
            if axes:
                m = replace(m, **{attr: getattr(m, attr).with_(**axes)})
        elif cmd == "M204":
            kw = {}
            if "S" in words:
                kw.update(accel=words["S"], travel_accel=words["S"])
            if "P" in words:
                kw["accel"] = words["P"]
            if "T" in words:
                kw["travel_accel"] = words["T"]
            if "R" in words:
                kw["retract_accel"] = words["R"]
            m = replace(m, **kw)
        elif cmd == "M205":
            if "J" in words and words["J"] > 0:
                m = replace(m, junction_deviation=words["J"], jerk=None)
            jerk = {a: v for a, v in words.items() if a in AXES}
            if jerk and m.jerk is not None:
                m = replace(m, jerk=m.jerk.with_(**jerk))
        elif cmd == "M900" and "K" in words:
            m = replace(m, linear_advance_k=words["K"])
    except ValueError as e:
        raise ProfileError(f"{where}: {cmd}: {e}") from None
    return m


def _classic_jerk_reply(text: str) -> bool:
    """An M503 reply from a firmware with classic jerk: its M205 has X/Y and no J."""
    for mt in _M_LINE.finditer(text):
        if mt.group(1).upper() == "M205":
            w = _words(mt.group(2))
            if "J" not in w and ("X" in w or "Y" in w):
                return True
    return False


def has_settings(text: str) -> bool:
    """Whether the text holds an M92, M201, M203, M204, M205 or M900 line (an M503 reply's)."""
    return any(mt.group(1).upper() != "M115" for mt in _M_LINE.finditer(text))


def firmware_of_m115(reply: str) -> str | None:
    """The firmware kind in an M115 reply's FIRMWARE_NAME, or None."""
    mt = re.search(r"FIRMWARE_NAME:\s*([^\n]*)", reply, re.I)
    if not mt:
        return None
    fw = mt.group(1).lower()
    if "klipper" in fw:
        return "klipper"
    if "prusa" in fw:
        return "prusa"
    if "reprap" in fw or "duet" in fw:
        return "reprap"
    if "marlin" in fw:
        return "marlin"
    return None


def from_m503(text: str, base: PrinterModel = DEFAULT, source: str = "<M503>",
              name: str = "m503") -> PrinterModel:
    """A model from a saved M503 reply (and, if present, M115's): settings it does not print
    keep base's. A reply with classic jerk (M205 X Y, no J) gives classic jerk."""
    fw = firmware_of_m115(text) or base.firmware
    m = replace(base, name=name, firmware=fw, source=f"M503 reply {source}")
    if _classic_jerk_reply(text) and m.jerk is None:
        m = replace(m, junction_deviation=None, jerk=Axes(10, 10, 0.3, 5))
    if not has_settings(text):
        raise ProfileError(f"{source}: no M92/M201/M203/M204/M205/M900 line in the M503 reply")
    for mt in _M_LINE.finditer(text):
        cmd = mt.group(1).upper()
        if cmd != "M115":
            line = text.count("\n", 0, mt.start()) + 1
            m = apply_mcode(m, cmd, _words(mt.group(2)), f"{source}:{line}")
    return m


def with_gcode(m: PrinterModel, lines, source: str = "<gcode>") -> PrinterModel:
    """The model after the G-code's own M92/M201/M203/M204/M205/M900 before its first move
    that extrudes (the start G-code and the slicer's machine limits). Later ones change
    settings mid-print; the estimator follows those (honour_file_limits)."""
    for n, raw in enumerate(lines, 1):
        if isinstance(raw, bytes):
            raw = raw.decode("utf-8", "replace")
        s = raw.lstrip()
        if s[:1] in ("G", "g") and _WORD.search(s) and re.match(r"[Gg]0*[0-3]\b", s):
            w = _words(s[s.index(" "):] if " " in s else "")
            if w.get("E", 0) > 0 and ("X" in w or "Y" in w):
                break
            continue
        mt = _M_LINE.match(s)
        if mt and mt.group(1).upper() != "M115":
            m = apply_mcode(m, mt.group(1), _words(mt.group(2)), f"{source}:{n}")
    return m


# --- Klipper's printer.cfg -------------------------------------------------------------------
def _read_cfg(path: str, sections: dict, seen: set, depth: int = 0) -> None:
    """Klipper's config syntax into sections[name] = {key: (value, 'file:line')}; [include
    GLOB] read where it stands (relative to the including file), later values win, as
    configfile.py does. The SAVE_CONFIG block (#*# lines) is read after the file."""
    real = os.path.realpath(path)
    if real in seen or depth > 20:
        raise ProfileError(f"{path}: [include] loop")
    seen = seen | {real}
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise ProfileError(f"{path}: cannot read: {e.strerror}") from None
    body, saved = [], []
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith("#*#"):
            saved.append((n, line[3:].lstrip(" ")))
        else:
            body.append((n, line))
    for part in (body, saved):
        section, key = None, None
        for n, line in part:
            where = f"{path}:{n}"
            stripped = re.split(r"\s[#;]|^[#;]", line, maxsplit=1)[0].rstrip()
            if not stripped.strip():
                continue
            if line[:1] in (" ", "\t") and key is not None:     # continuation of a value
                v, w = sections[section][key]
                sections[section][key] = (v + "\n" + stripped.strip(), w)
                continue
            mt = re.match(r"\s*\[([^\]]+)\]\s*$", stripped)
            if mt:
                name = mt.group(1).strip()
                if name.startswith("include "):
                    pat = os.path.join(os.path.dirname(path), name[8:].strip())
                    files = sorted(glob.glob(pat, recursive=True))
                    if not files and not glob.has_magic(pat):
                        raise ProfileError(f"{where}: [include] {name[8:].strip()}: no such file")
                    for inc in files:
                        _read_cfg(inc, sections, seen, depth + 1)
                    section, key = None, None
                else:
                    section, key = name, None
                    sections.setdefault(section, {})
                continue
            if section is None and part is saved:
                continue                      # the block's banner and its "do not edit" lines
            mt = re.match(r"\s*([^:=\s]+)\s*[:=]\s*(.*)$", stripped)
            if not mt or section is None:
                raise ProfileError(f"{where}: not a Klipper config line: {line.strip()!r}")
            key = mt.group(1).lower()
            sections[section][key] = (mt.group(2).strip(), where)


def from_klipper_cfg(path: str) -> PrinterModel:
    """A model from a Klipper printer.cfg: [printer] max_velocity, max_accel,
    square_corner_velocity, minimum_cruise_ratio; steps/mm from each stepper's
    rotation_distance, microsteps, full_steps_per_rotation and gear_ratio; [extruder]'s too,
    with nozzle and filament diameters, max_extrude_only_*, max_extrude_cross_section and
    pressure_advance (kept as the K of the model)."""
    sections: dict = {}
    _read_cfg(path, sections, set())

    def get(sec, key, default=None, conv=float):
        v = sections.get(sec, {}).get(key)
        if v is None:
            if default is None:
                raise ProfileError(f"{path}: [{sec}] has no {key}")
            return default
        try:
            return conv(v[0])
        except ValueError:
            raise ProfileError(f"{v[1]}: [{sec}] {key}: {v[0]!r} is not a number") from None

    if "printer" not in sections:
        raise ProfileError(f"{path}: no [printer] section (nor in its includes)")

    def steps(sec) -> float:
        if sec not in sections:
            raise ProfileError(f"{path}: no [{sec}] section (nor in its includes)")
        rd = get(sec, "rotation_distance")
        micro = get(sec, "microsteps")
        full = get(sec, "full_steps_per_rotation", 200.0)
        ratio = 1.0
        gr = sections[sec].get("gear_ratio")
        if gr:
            for pair in gr[0].split(","):
                try:
                    a, b = (float(x) for x in pair.split(":"))
                except ValueError:
                    raise ProfileError(f"{gr[1]}: [{sec}] gear_ratio: {gr[0]!r} is not a:b[, c:d]") from None
                ratio *= a / b
        if rd <= 0:
            raise ProfileError(f"{path}: [{sec}] rotation_distance must be > 0")
        return full * micro * ratio / rd

    v = get("printer", "max_velocity")
    a = get("printer", "max_accel")
    zv = get("printer", "max_z_velocity", v)
    za = get("printer", "max_z_accel", a)
    opt = lambda sec, key: get(sec, key, -1.0) if key in sections.get(sec, {}) else None
    spm = Axes(steps("stepper_x"), steps("stepper_y"), steps("stepper_z"), steps("extruder"))
    nozzle = get("extruder", "nozzle_diameter")
    fil = get("extruder", "filament_diameter")
    kin = sections["printer"].get("kinematics", ("cartesian", ""))[0].strip().lower()
    kin = kin if kin in KINEMATICS else "cartesian"     # others: the stop's head terms as cartesian
    mcr = opt("printer", "minimum_cruise_ratio")
    if mcr is None and "max_accel_to_decel" in sections["printer"]:
        mcr = max(0.0, 1.0 - get("printer", "max_accel_to_decel") / a)
    try:
        return PrinterModel(
            name=os.path.splitext(os.path.basename(path))[0], firmware="klipper",
            source=f"Klipper config {path}", steps_per_mm=spm,
            max_feedrate=Axes(v, v, zv, v), max_accel=Axes(a, a, za, a),
            accel=a, travel_accel=a, retract_accel=a,
            junction_deviation=klipper_jd(get("printer", "square_corner_velocity", 5.0), a),
            jerk=None, lookahead=0, min_step_rate=0.0, min_segment_steps=0,
            linear_advance_k=opt("extruder", "pressure_advance") or 0.0,
            square_corner_velocity=get("printer", "square_corner_velocity", 5.0),
            minimum_cruise_ratio=0.5 if mcr is None else mcr,
            max_extrude_only_velocity=opt("extruder", "max_extrude_only_velocity"),
            max_extrude_only_accel=opt("extruder", "max_extrude_only_accel"),
            max_extrude_cross_section=opt("extruder", "max_extrude_cross_section"),
            nozzle_diameter=nozzle, filament_diameter=fil, kinematics=kin)
    except ValueError as e:
        raise ProfileError(f"{path}: {e}") from None


# --- the profile TOML ------------------------------------------------------------------------
def to_toml(m: PrinterModel) -> str:
    """The profile as TOML, every field written (from_toml reads it back to an equal model)."""
    out = ["# bulgekit printer profile (bulgekit printer read / --printer FILE)", "[printer_model]"]
    for f in dataclasses.fields(m):
        v = getattr(m, f.name)
        if v is None:
            continue
        if isinstance(v, Axes):
            v = "{ " + ", ".join(f"{a} = {_toml_num(v[a])}" for a in AXES) + " }"
        elif isinstance(v, str):
            v = '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        else:
            v = _toml_num(v)
        out.append(f"{f.name} = {v}")
    return "\n".join(out) + "\n"


def _toml_num(v) -> str:
    return str(v) if isinstance(v, int) and not isinstance(v, bool) else repr(float(v))


def from_toml(text: str, source: str = "<toml>") -> PrinterModel:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{source}: {e}") from None
    t = doc.get("printer_model")
    if not isinstance(t, dict):
        raise ProfileError(f"{source}: no [printer_model] table")
    names = {f.name: f for f in dataclasses.fields(PrinterModel)}
    kw = {}
    for k, v in t.items():
        if k not in names:
            raise ProfileError(f"{source}: [printer_model] {k}: unknown setting "
                               f"(known: {', '.join(names)})")
        if isinstance(v, dict):
            missing = [a for a in AXES if a not in v]
            if missing or len(v) != 4:
                raise ProfileError(f"{source}: [printer_model] {k}: give X, Y, Z and E")
            try:
                v = Axes(*(float(v[a]) for a in AXES))
            except (TypeError, ValueError):
                raise ProfileError(f"{source}: [printer_model] {k}: numbers wanted") from None
        kw[k] = v
    if "jerk" in kw and "junction_deviation" not in kw:
        kw["junction_deviation"] = None
    try:
        return PrinterModel(**kw)
    except (TypeError, ValueError) as e:
        raise ProfileError(f"{source}: [printer_model]: {e}") from None
