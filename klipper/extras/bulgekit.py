# bulgekit for Klipper: bulge maps (M720, M721, M722) and width mode (M723)
#
# Copyright (C) 2026  the bulgekit authors
#
# This file may be distributed under the terms of the GNU GPLv3 license.
#
# The same M-codes as bulgekit's Marlin fork (docs/reference/mcodes.md), done in klippy:
#  * M721 uploads a bulge map; the outer wall's extruding moves (between M722 S1 and
#    M722 S0, or every extruding move in M720 S2) are split at the map's points by the
#    host package's reference planner (bulgekit.bulge.fallback.RefPlanner, the Python mirror
#    of the firmware core's rule, docs/planner.md), and the head stops at each point for
#    the dwell while an extruder-only move lays the extra filament (timed as
#    bulgekit.bulge.klipper_stop plans Klipper's moves: no look-ahead flush);
#  * M723 keeps the extruder at one rate and sets each line's width by the head speed.
# The module sits in gcode_move's chain of move transforms (as bed_mesh does) and hides
# the extra filament from the G-code position (as exclude_object hides its offsets).
# Docs: docs/klipper.md in the bulgekit repository.
import logging, math, os, re, sys

HOST_DIRS = ("bulgekit_host",)   # beside this file: install-klipper.py's link or copy


def _import_host():
    """The host package's shared modules: the map codec, the reference planner and the
    Klipper stop model (one implementation, shared with the `bulgekit` command). The copy
    install-klipper.py placed beside this file comes first (it matches this module), then
    the checkout this file links to, then a `bulgekit` installed in Klipper's Python."""
    here = os.path.dirname(os.path.abspath(__file__))
    tries = [os.path.join(here, d) for d in HOST_DIRS]
    tries.append(os.path.join(os.path.dirname(os.path.realpath(__file__)),
                              os.pardir, os.pardir, "host"))
    for d in tries:
        if os.path.isdir(os.path.join(d, "bulgekit")):
            d = os.path.normpath(d)
            if d not in sys.path:
                sys.path.insert(0, d)
            break
    from bulgekit.bulge import fallback, klipper_stop, mapformat
    return fallback, klipper_stop, mapformat


# Limits of the firmware core (config/bulgekit_config.h)
MAX_FLOW = 100.0         # BK_WIDTH_MAX_FLOW_MM3S
MAX_E_RATE = 50.0        # BK_WIDTH_MAX_E_RATE
MIN_DIA, MAX_DIA = 1.0, 3.5
MAX_LAYER = 2.0
MIN_SPEED, MAX_SPEED = 0.1, 1000.0
MAX_LINE = 5.0
M721_CHUNK_CHARS_MAX = 64

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)$")
_WHOLE = re.compile(r"\+?\d+$")


class Words:
    """A command's words as the fork's GcodeArgs reads them, from the raw line (Klipper's
    parser splits a base32 word such as DABC3 into D, A, B and C3)."""

    def __init__(self, commandline):
        code = commandline.split(";", 1)[0]
        code = code.split("*", 1)[0].strip()
        toks = code.split()
        if toks and toks[0][:1].upper() == "N" and toks[0][1:].isdigit():
            toks = toks[1:]
        self.code = toks[0].upper() if toks else ""
        self.words = {}
        self.odd = self.dup = None
        for t in toks[1:]:
            letter = t[0].upper()
            if not ("A" <= letter <= "Z"):
                self.odd = "?"
                continue
            if letter in self.words and self.dup is None:
                self.dup = letter
            self.words.setdefault(letter, t[1:])

    def none(self):
        return not self.words and self.odd is None

    def has(self, letter):
        return letter in self.words

    def check(self, allowed, code):
        bad = self.odd or next((c for c in sorted(self.words) if c not in allowed), None)
        if bad:
            return "%s unknown parameter %s" % (code, bad)
        if self.dup:
            return "%s duplicate parameter %s" % (code, self.dup)
        return None

    def whole(self, letter):
        """(status, value): 'absent', 'empty', 'bad' or 'ok' (a whole number <= 2^32 - 1)."""
        if letter not in self.words:
            return "absent", None
        t = self.words[letter]
        if t == "":
            return "empty", None
        if not _WHOLE.match(t) or int(t) > 0xFFFFFFFF:
            return "bad", None
        return "ok", int(t)

    def number(self, letter, f32):
        """(status, float32 value) as the fork's strict decimal reader: the mantissa divided
        once by a power of ten, in float32."""
        if letter not in self.words:
            return "absent", None
        t = self.words[letter]
        if t == "":
            return "empty", None
        if not _NUMBER.match(t):
            return "bad", None
        neg = t.startswith("-")
        whole, _, frac = t.lstrip("+-").partition(".")
        mant = nfrac = 0
        for i, ch in enumerate(whole + frac):
            if mant < 100000000:
                mant = mant * 10 + int(ch)
                nfrac += i >= len(whole)
            elif i < len(whole):
                return "bad", None      # an integer part too large to be a setting
        v = f32(mant) / f32(10.0 ** nfrac)
        return "ok", -v if neg else v


def _fixed(v):
    return "%.3f" % float(v)


class WidthMode:
    """M723: the extruder at one rate r, each extruding move's head speed v = L r / dE
    (src/width_mode.cpp)."""

    def __init__(self, f32, dia=1.75, low=5.0, high=150.0):
        self.f32 = f32
        self.on = False
        self.kind = None            # "Q" or "R"
        self.target = f32(0)
        self.dia, self.height = f32(dia), f32(0)
        self.low, self.high = f32(low), f32(high)
        self.percent = 100
        self.clear_stats()
        self.recompute()

    def clear_stats(self):
        self.moves = self.clamped_low = self.clamped_high = 0
        self.max_dev = self.sum_dev = self.f32(0)

    def base_rate(self, kind=None, target=None, dia=None):
        f32 = self.f32
        kind = self.kind if kind is None else kind
        target = self.target if target is None else target
        dia = self.dia if dia is None else dia
        inv_area = (f32(4.0) / f32(3.14159265)) / (dia * dia)
        return target * inv_area if kind == "Q" else (target if kind == "R" else f32(0))

    def recompute(self):
        f32 = self.f32
        self.inv_area = (f32(4.0) / f32(3.14159265)) / (self.dia * self.dia)
        self.rate = self.base_rate() * f32(self.percent) * f32(0.01)

    LIMITS = (("Q", True, 0.0, MAX_FLOW), ("R", True, 0.0, MAX_E_RATE),
              ("D", False, MIN_DIA, MAX_DIA), ("H", False, 0.0, MAX_LAYER),
              ("L", False, MIN_SPEED, MAX_SPEED), ("U", False, MIN_SPEED, MAX_SPEED))

    def command(self, w):
        """None, or the error text (without Klipper's '!!')."""
        f32 = self.f32
        err = w.check("SQRDHLU", "M723")
        if err:
            return err
        s_st, s = w.whole("S")
        if s_st != "absent" and (s_st != "ok" or s > 1):
            return "M723 S must be 0 or 1"
        new = dict(kind=self.kind, target=self.target, D=self.dia, H=self.height,
                   L=self.low, U=self.high)
        for letter, lo_open, lo, hi in self.LIMITS:
            st, v = w.number(letter, f32)
            if st == "absent":
                continue
            if st != "ok":
                return "M723 %s bad number" % letter
            if not ((v > f32(lo)) if lo_open else (v >= f32(lo))) or not v <= f32(hi):
                return "M723 %s%s not in %s%s..%s]" % (letter, _fixed(v), "(" if lo_open else "[",
                                                       _fixed(lo), _fixed(hi))
            if letter == "R" and w.has("Q"):
                return "M723 Q or R, not both"
            if letter in "QR":
                new["kind"], new["target"] = letter, v
            else:
                new[letter] = v
        if new["L"] > new["U"]:
            return "M723 L%s > U%s" % (_fixed(new["L"]), _fixed(new["U"]))
        r = self.base_rate(new["kind"], new["target"], new["D"])
        if r > f32(MAX_E_RATE):
            return "M723 extruder rate %s > %s (Q, D)" % (_fixed(r), _fixed(MAX_E_RATE))
        on = None if s_st == "absent" else s
        if on == 1 and new["kind"] is None:
            return "M723 S1 needs Q or R"
        if on == 1 and not self.on:
            self.clear_stats()
        self.kind, self.target = new["kind"], new["target"]
        self.dia, self.height, self.low, self.high = new["D"], new["H"], new["L"], new["U"]
        if on is not None:
            self.on = bool(on)
        self.recompute()
        return None

    def report(self):
        words = ["M723 S%d" % self.on]
        if self.kind:
            words.append("%s%s" % (self.kind, _fixed(self.target)))
        words += ["D" + _fixed(self.dia), "H" + _fixed(self.height), "L" + _fixed(self.low),
                  "U" + _fixed(self.high)]
        clamped = self.clamped_low + self.clamped_high
        mean = self.sum_dev / self.f32(clamped or 1)
        return "%s\nwidth rate:%s feed%%:%d moves:%d low:%d high:%d maxdev:%s meandev:%s" % (
            " ".join(words), _fixed(self.rate), self.percent, self.moves, self.clamped_low,
            self.clamped_high, _pct(self.max_dev), _pct(mean))

    def set_percent(self, percent):
        if percent > 0 and percent != self.percent:
            self.percent = percent
            self.recompute()

    def retime(self, xy_len, de):
        """The head speed (mm/s) of an extruding move of xy_len mm feeding de mm."""
        f32 = self.f32
        self.moves += 1
        v = f32(xy_len) * self.rate / f32(de)
        if v < self.low:
            c = self.low
            self.clamped_low += 1
        elif v > self.high:
            c = self.high
            self.clamped_high += 1
        else:
            return float(v)
        dev = abs(c / v - f32(1.0))
        self.max_dev = max(self.max_dev, dev)
        self.sum_dev += dev
        return float(c)

    def width_e(self, width, has_e, xy_len):
        """(dE, None) for a W word, or (None, error text)."""
        f32 = self.f32
        if not self.on or not self.height > 0:
            return None, "W needs M723 S1 and H"
        if has_e:
            return None, "W and E in one move"
        if not (width > 0) or width > f32(MAX_LINE):
            return None, "W%s not in (0.000..%s]" % (_fixed(width), _fixed(MAX_LINE))
        if not xy_len > 0:
            return None, "W without XY travel"
        return float(width * self.height * f32(xy_len) * self.inv_area), None


class _Line:
    """The fields of a move RefPlanner.plan reads (as bulgekit.gcode.Move has them)."""
    __slots__ = ("index", "line_no", "x0", "y0", "z0", "x1", "y1", "z1", "e", "outer")


def _unit(d):
    n = math.hypot(d[0], d[1])
    return d[0] / n, d[1] / n


def _pct(ratio):
    v = float(ratio) * 100.0
    return ">=1000000%" if v >= 1000000 else "%.2f%%" % v


class MapUpload:
    """M721: the map in force and an open upload (src/map_upload.cpp), with the map codec of
    the host package (bulgekit.bulge.mapformat)."""

    def __init__(self, mapformat, arena):
        self.mf = mapformat
        self.arena = arena
        self.map = None             # a BulgeMap, or None
        self.record_bytes = 0
        self.size = self.received = 0
        self.crc = 0
        self.append = False
        self.data = None
        self.appended = []          # the layers the last append committed

    def is_open(self):
        return self.size > 0

    def free(self):
        return self.arena - self.record_bytes

    def _in(self, w, letter, lo, hi):
        st, v = w.whole(letter)
        if st != "ok":
            return None, "M721 %s missing or bad" % letter
        if not lo <= v <= hi:
            return None, "M721 %s%s not in %d..%d" % (letter, w.words[letter], lo, hi)
        return v, None

    def handle(self, w):
        """(kind, text): kind 'ok', 'committed', 'cleared' or 'error'; text the reply lines."""
        err = w.check("SCAODEX", "M721")
        if err:
            return "error", err
        act = 0
        for g, letters in enumerate(("SCA", "OD", "E", "X"), 1):
            if any(w.has(c) for c in letters):
                if act and act != g:
                    return "error", "M721 mixed actions"
                act = g
        if act in (2, 3) and not self.is_open():
            return "error", "M721 no upload open"
        if act == 1:
            return self.begin(w)
        if act == 2:
            return self.chunk(w)
        if act == 3:
            return self.commit()
        if act == 4:
            self.size = self.received = 0
            self.map, self.record_bytes = None, 0
            return "cleared", "BulgeMap cleared"
        return "ok", self.status()

    def begin(self, w):
        st, a = w.whole("A")
        if st == "empty":
            a = 1
        elif st == "absent":
            a = 0
        else:
            a, err = self._in(w, "A", 0, 1)
            if err:
                return "error", err
        if a and self.map is None:
            return "error", "M721 A1 needs a map"
        head = 0 if a else self.mf.HEADER_BYTES
        size, err = self._in(w, "S", head or 1, self.free() + head)
        if err:
            return "error", err
        st, crc = w.whole("C")
        if st != "ok":
            return "error", "M721 C missing or bad"
        lines = []
        if self.is_open():
            lines.append("M721 upload %d/%d dropped" % (self.received, self.size))
        self.size, self.crc, self.received, self.append = size, crc, 0, bool(a)
        self.data = bytearray(size)
        lines.append("M721 receiving %d bytes%s" % (size, " (append)" if a else ""))
        return "ok", "\n".join(lines)

    def chunk(self, w):
        off, err = self._in(w, "O", 0, self.received)
        if err:
            return "error", err
        text = w.words.get("D", "")
        if not text:
            return "error", "M721 D missing or bad"
        data, pos = _base32(text)
        if data is None:
            return "error", "M721 D bad base32 at char %d" % pos
        if off + len(data) > self.size:
            return "error", "M721 O%d+%d > S%d" % (off, len(data), self.size)
        self.data[off:off + len(data)] = data
        self.received = max(self.received, off + len(data))
        return "ok", ""

    def commit(self):
        if self.received != self.size:
            return "error", "M721 received %d/%d" % (self.received, self.size)
        data, size = bytes(self.data), self.size
        self.size = self.received = 0          # closed either way
        crc = self.mf.crc32(data)
        if crc != self.crc:
            return "error", "M721 CRC %d != C%d" % (crc, self.crc)
        try:
            if self.append:
                after = self.map.layers[-1].z_cmm if self.map.layers else -1
                layers = self.mf.decode_records(data, self.map.has_weights, after)
            else:
                new = self.mf.decode_map(data)
        except self.mf.MapFormatError as e:
            return "error", "M721 %s at byte %d" % (e.code, e.offset or 0)
        if self.append:
            self.record_bytes += size
            self.appended = layers
            return "appended", None
        self.map, self.record_bytes = new, size - self.mf.HEADER_BYTES
        return "committed", self.status()

    def status(self):
        m = self.map
        layers = len(m.layers) if m else 0
        points = m.point_count if m else 0
        z = "-" if not layers else "%.2f..%.2f" % (m.layers[0].z_cmm / 100.0,
                                                  m.layers[-1].z_cmm / 100.0)
        text = "BulgeMap layers:%d bytes:%d/%d points:%d z:%s" % (
            layers, self.record_bytes, self.arena, points, z)
        if self.is_open():
            text += " upload:%d/%d%s" % (self.received, self.size, " append" if self.append else "")
        return text


def _base32(text):
    """(bytes, None) or (None, the position of the first bad character), as the fork's
    base32_decode: A-Z and 2-7 in either case, no padding, canonical (unused bits zero)."""
    if len(text) > M721_CHUNK_CHARS_MAX:
        return None, M721_CHUNK_CHARS_MAX
    acc = bits = 0
    out = bytearray()
    for i, ch in enumerate(text):
        lo = ch.lower()
        if "a" <= lo <= "z":
            v = ord(lo) - ord("a")
        elif "2" <= ch <= "7":
            v = ord(ch) - ord("2") + 26
        else:
            return None, i
        acc = ((acc << 5) | v) & 0xFFFF
        bits += 5
        if bits >= 8:
            bits -= 8
            out.append((acc >> bits) & 0xFF)
    if bits > 4:
        return None, len(text)
    if acc & ((1 << bits) - 1):
        return None, len(text) - 1
    return bytes(out), None


class BulgeKit:
    def __init__(self, config):
        self.printer = config.get_printer()
        self.fallback, self.kstop, self.mapformat = _import_host()
        import numpy
        self.f32 = numpy.float32
        fb = self.fallback
        self.settings = fb.Settings(
            mode=config.getint("mode", 0, minval=0, maxval=2),
            dwell_ms=config.getint("dwell", fb.DEFAULT_DWELL_MS, minval=0,
                                   maxval=fb.MAX_DWELL_MS),
            extra_e=config.getfloat("extra", fb.DEFAULT_EXTRA_E_MM, minval=0.,
                                    maxval=fb.MAX_EXTRA_E_MM),
            tolerance=config.getfloat("tolerance", fb.DEFAULT_TOLERANCE_MM, minval=0.01,
                                      maxval=fb.MAX_TOLERANCE_MM))
        self.width = WidthMode(
            self.f32,
            dia=config.getfloat("filament_diameter", 1.75, minval=MIN_DIA, maxval=MAX_DIA),
            low=config.getfloat("width_min_speed", 5., minval=MIN_SPEED, maxval=MAX_SPEED),
            high=config.getfloat("width_max_speed", 150., minval=MIN_SPEED, maxval=MAX_SPEED))
        # the map's room: all that one M721 can carry (S is 16 bits), as Klipper's host has the
        # memory; nothing is released while printing, so no smaller arena is offered
        self.upload = MapUpload(self.mapformat, 65535 - self.mapformat.HEADER_BYTES)
        self.planner = fb.RefPlanner(None, self.settings)
        self.marker = False
        self.next_transform = None
        self.last_in = None         # the last position handed down, as gcode_move sees it
        self.e_off = 0.             # extra filament laid so far (hidden from gcode_move)
        self.ahead = 0.             # extra laid by stop moves, not yet taken off a piece
        self.last_d = None          # X/Y of the last move with X/Y motion
        self.held = None            # a stop waiting for the direction that leaves it
        self.held_moves = []        # E-only moves after it (a retract), held with it
        self.stops = 0
        self.stop_ms_total = 0
        self.extra_laid = 0.
        self.line_no = 0
        self.log_stops = config.getboolean("log_stops", False)
        self.line = _Line()
        self.gcode = self.printer.lookup_object("gcode")
        self.gcode_move = self.printer.load_object(config, "gcode_move")
        for cmd in ("M720", "M721", "M722", "M723", "BULGEKIT_STATUS"):
            self.gcode.register_command(cmd, getattr(self, "cmd_" + cmd),
                                        desc=getattr(self, "cmd_%s_help" % cmd, None))
        self.printer.register_event_handler("klippy:connect", self._handle_connect)
        self.printer.register_event_handler("klippy:ready", self._handle_ready)

    # -- set-up
    def _handle_connect(self):
        self.toolhead = self.printer.lookup_object("toolhead")
        # G0/G1 with a W word (M723): wrapped, the rest goes to gcode_move's handler
        self.prev_g1 = {}
        for cmd in ("G1", "G0"):
            self.prev_g1[cmd] = self.gcode.register_command(cmd, None)
            self.gcode.register_command(cmd, self._g1_handler(self.prev_g1[cmd]))
        # a stop held for the next move's direction is made before the head waits
        for cmd in ("G4", "M400"):
            prev = self.gcode.register_command(cmd, None)
            if prev is not None:
                self.gcode.register_command(cmd, self._wait_handler(prev))
        kin = self.toolhead.get_kinematics()
        steppers = {s.get_name(): s for s in kin.get_steppers()}
        name = type(kin).__name__.lower()
        kind = "corexy" if "corexy" in name else "cartesian"
        sx, sy = steppers.get("stepper_x"), steppers.get("stepper_y")
        if kind == "corexy" or sx is None:
            sx, sy = steppers.get("stepper_a", sx), steppers.get("stepper_b", sy)
        self.steps_xy = (1. / sx.get_step_dist() if sx else 80.,
                         1. / sy.get_step_dist() if sy else 80.)
        self.kinematics = kind

    def _handle_ready(self):
        # on top of the chain, after the transforms others put in at connect (skew_correction,
        # z_thermal_adjust) or at start (bed_mesh): the planner sees the file's coordinates
        self.next_transform = self.gcode_move.set_move_transform(self, force=True)
        self.last_in = None

    def _params(self):
        th = self.toolhead
        ex = th.get_extruder()
        accel = th.max_accel
        mcr = getattr(th, "min_cruise_ratio", None)
        if mcr is None:
            mcr = 1. - th.max_accel_to_decel / accel
        kw = dict(accel=accel, min_cruise_ratio=mcr, kinematics=self.kinematics,
                  x_steps=self.steps_xy[0], y_steps=self.steps_xy[1])
        if hasattr(ex, "max_e_velocity"):
            kw.update(e_velocity=ex.max_e_velocity, e_accel=ex.max_e_accel,
                      cross_section=ex.max_extrude_ratio * ex.filament_area,
                      filament_area=ex.filament_area, nozzle=ex.nozzle_diameter)
        return self.kstop.KlipperParams(**kw)

    # -- the move transform
    def get_position(self):
        self._release_held(None)
        pos = list(self.next_transform.get_position())
        pos[3] -= self.e_off
        self.last_in = list(pos)
        return pos

    def move(self, newpos, speed):
        if self.last_in is None:
            self.get_position()
        start = self.last_in
        self.last_in = newpos[:]
        base = self.gcode_move.base_position
        de = newpos[3] - start[3]
        dx, dy = newpos[0] - start[0], newpos[1] - start[1]
        moves_xy = dx != 0. or dy != 0.
        if self.width.on and de > 0. and moves_xy:
            self.width.set_percent(int(round(self.gcode_move.speed_factor * 6000.)))
            speed = self.width.retime(math.hypot(dx, dy), de / self.gcode_move.extrude_factor)
        if self.held is None and self.planner.passthrough(
                de, moves_xy, not moves_xy and de == 0. and newpos[2] == start[2],
                self.marker, newpos[2] - base[2]):
            # the common case: a line the planner gives back as it is
            self.next_transform.move([newpos[0], newpos[1], newpos[2], newpos[3] + self.e_off],
                                     speed)
            if moves_xy:
                self.last_d = (dx, dy)
            return
        if self.held is not None and moves_xy:
            self._release_held((dx, dy))     # this move leaves the held stop
        self.line_no += 1
        m = self.line        # what plan() reads of a bulgekit.gcode.Move, reused
        m.index = m.line_no = self.line_no
        m.x0, m.y0, m.z0 = start[0] - base[0], start[1] - base[1], start[2] - base[2]
        m.x1, m.y1, m.z1 = newpos[0] - base[0], newpos[1] - base[1], newpos[2] - base[2]
        m.e, m.outer = de, self.marker
        actions = self.planner.plan(m, self.marker)
        if len(actions) == 1 and not actions[0].extra and not actions[0].dropped:
            self._down([newpos[0], newpos[1], newpos[2], newpos[3] + self.e_off], speed, dx, dy)
            return
        here = start[:3] + [start[3] + self.e_off]     # as handed down: the extra included
        for i, a in enumerate(actions):
            if a.kind == "dwell":
                self.stops += 1
                self.stop_ms_total += a.ms
                self._stop(here, a.ms, a.extra, actions[i + 1:])
                continue
            take = min(self.ahead, a.extra)
            self.ahead -= take
            if a.dropped and self.ahead:
                self.ahead = 0.         # laid at the stop already: kept, not dropped
            self.e_off += a.extra - take
            self.extra_laid += a.extra - take
            if a.t >= 1.:
                tgt = [newpos[0], newpos[1], newpos[2], newpos[3] + self.e_off]
            else:
                tgt = [a.x + base[0], a.y + base[1], a.z + base[2],
                       start[3] + de * a.t + self.e_off]
            self._down(tgt, speed, tgt[0] - here[0], tgt[1] - here[1])
            here = tgt

    def _down(self, pos, speed, dx, dy):
        """One move to the next transform; a held stop goes first once its lead is known."""
        moves_xy = dx != 0. or dy != 0.
        if self.held is not None:
            if not moves_xy and pos[2] == self.held[0][2]:
                self.held_moves.append((list(pos), speed))   # E-only: the head stands
                return
            self._release_held((dx, dy) if moves_xy else None)
        self.next_transform.move(pos, speed)
        if moves_xy:
            self.last_d = (dx, dy)

    def _stop(self, here, ms, owed, rest):
        """A stop of ms at `here` (as handed down), laying the extra owed after it: held until
        the direction leaving it is known (the next piece of this move, or the next move)."""
        if self.log_stops:
            base = self.gcode_move.base_position
            logging.info("bulgekit: stop X%.4f Y%.4f Z%.4f P%d", here[0] - base[0],
                         here[1] - base[1], here[2] - base[2], ms)
        self._release_held(None)
        self.held = (list(here), ms, owed, self.last_d)
        for a in rest:
            if a.kind == "line":
                base = self.gcode_move.base_position
                dx, dy = a.x + base[0] - here[0], a.y + base[1] - here[1]
                if dx != 0. or dy != 0.:
                    self._release_held((dx, dy), mid_move=True)
                break

    def _release_held(self, lead_dir, mid_move=False):
        """Queues the held stop: an E-only move laying the extra owed (as much as its time
        allows), timed so that the head stands for the dwell. The E it lays comes off the
        pieces that carry that extra: of this move (mid_move) or the planner's carry to the
        next move; a carry the planner has dropped meanwhile (a retract came first) is laid
        here all the same and comes off nothing."""
        if self.held is None:
            return
        (pos, ms, owed, arrive), held_moves = self.held, self.held_moves
        self.held, self.held_moves = None, []
        p = self._params()
        ks = self.kstop
        tail = ks.tail_s(p, pos[0], pos[1], *_unit(arrive)) if arrive else ks.mean_edge_s(p)
        lead = ks.lead_s(p, pos[0], pos[1], *_unit(lead_dir)) if lead_dir else ks.mean_edge_s(p)
        between = 0.
        prev_e = pos[3]
        for hp, hs in held_moves:
            between += ks.e_move_s(p, abs(hp[3] - prev_e), hs)
            prev_e = hp[3]
        stop = ks.plan(p, ms, owed, tail, lead) if owed > 0. else None
        if stop is not None and between:
            stop = ks.retime(p, stop, lead, between=between)
        cur = list(self.next_transform.get_position())
        if stop is None:
            # nothing to lay: a dwell (it flushes the look-ahead)
            self.toolhead.dwell(max(0., ms / 1000. - tail - lead - between))
        else:
            cur[3] += stop.e_mm
            self.e_off += stop.e_mm
            self.ahead += stop.e_mm if mid_move else min(stop.e_mm, float(self.planner.carry))
            self.extra_laid += stop.e_mm
            self.next_transform.move(cur, stop.speed)
        for hp, hs in held_moves:
            hp = list(hp)
            hp[3] += stop.e_mm if stop is not None else 0.
            self.next_transform.move(hp, hs)

    # -- G-code
    def _words(self, gcmd):
        return Words(gcmd.get_commandline())

    cmd_M720_help = "bulgekit: bulge settings (S mode, P dwell ms, E extra mm, T tolerance mm)"
    def cmd_M720(self, gcmd):
        w = self._words(gcmd)
        s = self.settings
        if w.none():
            gcmd.respond_info("M720 S%d P%d E%.3f T%.3f" % (s.mode, s.dwell_ms, s.extra_e,
                                                           s.tolerance))
            return
        err = w.check("SPET", "M720")
        if err:
            raise gcmd.error(err)
        f32 = self.f32
        fb = self.fallback
        v = {"S": f32(s.mode), "P": f32(s.dwell_ms), "E": f32(s.extra_e), "T": f32(s.tolerance)}
        limits = (("S", 0., 2.), ("P", 0., float(fb.MAX_DWELL_MS)), ("E", 0., fb.MAX_EXTRA_E_MM),
                  ("T", f32(0.01) - f32(1e-6), fb.MAX_TOLERANCE_MM))
        for letter, lo, hi in limits:
            st, x = w.number(letter, f32)
            if st == "absent":
                continue
            if st != "ok":
                raise gcmd.error("M720 %s bad number" % letter)
            if not (x >= f32(lo) and x <= f32(hi)):
                raise gcmd.error("M720 %s%s not in [%s..%s]" % (letter, _fixed(x), _fixed(lo),
                                                              _fixed(hi)))
            if letter in "SP" and x != int(x):
                raise gcmd.error("M720 %s%s not a whole number" % (letter, _fixed(x)))
            v[letter] = x
        self.settings = fb.Settings(mode=int(v["S"]), dwell_ms=int(v["P"]),
                                    extra_e=float(v["E"]), tolerance=float(v["T"]))
        self.planner.configure(self.settings)

    cmd_M721_help = "bulgekit: bulge map upload (S C [A1] begin, O D chunk, E commit, X clear)"
    def cmd_M721(self, gcmd):
        kind, text = self.upload.handle(self._words(gcmd))
        if kind == "error":
            raise gcmd.error(text)
        if kind == "committed":
            self.planner = self.fallback.RefPlanner(self.upload.map, self.settings)
        elif kind == "cleared":
            self.planner = self.fallback.RefPlanner(None, self.settings)
        elif kind == "appended":
            self.planner.append_layers(self.upload.appended)     # the map in force grows
            text = self.upload.status()
        if text:
            gcmd.respond_info(text)

    cmd_M722_help = "bulgekit: outer-wall marker (S1 start, S0 end)"
    def cmd_M722(self, gcmd):
        w = self._words(gcmd)
        err = w.check("S", "M722")
        if err:
            raise gcmd.error(err)
        st, s = w.whole("S")
        if st != "ok" or s > 1:
            raise gcmd.error("M722 needs S0 or S1")
        self.marker = s == 1

    cmd_M723_help = "bulgekit: width mode (S0/S1, Q or R, D, H, L, U)"
    def cmd_M723(self, gcmd):
        w = self._words(gcmd)
        if w.none():
            self.width.set_percent(int(round(self.gcode_move.speed_factor * 6000.)))
            gcmd.respond_info(self.width.report())
            return
        err = self.width.command(w)
        if err:
            raise gcmd.error(err)

    def _g1_handler(self, prev):
        def g1(gcmd):
            if "W" in gcmd.get_command_parameters():
                self.width_move(gcmd, prev)
            else:
                prev(gcmd)
        return g1

    def _wait_handler(self, prev):
        def wait(gcmd):
            self._release_held(None)
            prev(gcmd)
        return wait

    def width_move(self, gcmd, prev):
        """G0/G1 with a W word: its E from the width (M723), or an error and no move."""
        params = gcmd.get_command_parameters()
        w = self._words(gcmd)
        st, width = w.number("W", self.f32)
        if st != "ok":
            raise gcmd.error("W bad number")
        gm = self.gcode_move
        pos = gm.get_status()["gcode_position"]
        tgt = [pos[0], pos[1]]
        for i, axis in enumerate("XY"):
            if axis in params:
                v = float(params[axis])
                tgt[i] = v if gm.absolute_coord else tgt[i] + v
        de, err = self.width.width_e(width, "E" in params, math.hypot(tgt[0] - pos[0],
                                                                      tgt[1] - pos[1]))
        if err:
            raise gcmd.error(err)
        new = {k: v for k, v in params.items() if k != "W"}
        new["E"] = repr(pos[3] + de if gm.absolute_coord and gm.absolute_extrude else de)
        prev(self.gcode.create_gcode_command(gcmd.get_command(), gcmd.get_commandline(), new))

    cmd_BULGEKIT_STATUS_help = "bulgekit: map, stops and width mode"
    def cmd_BULGEKIT_STATUS(self, gcmd):
        st = self.get_status(None)
        m, wd = st["map"], st["width"]
        gcmd.respond_info(
            "bulgekit: map loaded:%s layers:%d points:%d | M720 S%d P%d E%.3f T%.3f marker:%d |"
            " stops:%d stop_ms:%d extra_laid:%.4f | width on:%d rate:%.3f moves:%d low:%d"
            " high:%d" % (int(m["loaded"]), m["layers"], m["points"], st["mode"], st["dwell_ms"],
                          st["extra"], st["tolerance"], int(st["outer_wall"]), st["stops"],
                          st["stop_ms_total"], st["extra_laid"], int(wd["enabled"]), wd["rate"],
                          wd["moves"], wd["clamped_low"], wd["clamped_high"]))

    def get_status(self, eventtime):
        m = self.upload.map
        s, wd = self.settings, self.width
        return {
            "map": {"loaded": m is not None,
                    "layers": len(m.layers) if m else 0,
                    "points": m.point_count if m else 0,
                    "bytes": self.upload.record_bytes},
            "mode": s.mode, "dwell_ms": s.dwell_ms, "extra": s.extra_e,
            "tolerance": s.tolerance, "outer_wall": self.marker,
            "stops": self.stops, "stop_ms_total": self.stop_ms_total,
            "extra_laid": self.extra_laid,
            "width": {"enabled": wd.on, "rate": float(wd.rate), "moves": wd.moves,
                      "clamped_low": wd.clamped_low, "clamped_high": wd.clamped_high,
                      "height": float(wd.height)},
        }


def load_config(config):
    return BulgeKit(config)
