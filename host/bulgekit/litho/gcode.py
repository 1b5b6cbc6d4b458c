"""The G-code writer: the plan as the width-mode file (M723) and as the stock-firmware file
(eq. 2: F per piece), each with its estimated time; what the estimate assumes."""
from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import outputs
from ..gcode import startend
from .options import LithoError, LithoOptions, options_dict
from .paths import Plan, Section


# --- G-code --------------------------------------------------------------------------------

DEFAULT_START = ("; default start (replace with --start-gcode FILE, where the words temp and bed_temp "
                 "in braces\n; are filled in)\n" + startend.HEAT_AND_HOME)
DEFAULT_END = "; default end (replace with --end-gcode FILE)\n" + startend.END


def _fmt(v: float, nd: int) -> str:
    s = f"{v:.{nd}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _word_chars(letter: str, a: np.ndarray, nd: int, on=None) -> tuple[np.ndarray, np.ndarray]:
    """The words `letter` + each value to nd decimals (Python's shortest repr of the rounded
    value: no trailing zeros but a whole number's ".0"; zero as "0"), as a character matrix and
    which of its characters are written, computed on the whole array at once. Each word starts
    with a space; `on`: which rows have the word at all."""
    k = np.rint(np.asarray(a, float) * 10 ** nd).astype(np.int64)
    neg, m = k < 0, np.abs(k)
    ip, fp = np.divmod(m, 10 ** nd)
    D = max(1, len(str(int(ip.max())))) if len(m) else 1
    n = len(k)
    digits = lambda v, count: (v[:, None] // 10 ** np.arange(count - 1, -1, -1)) % 10 + ord("0")
    # trailing zeros of the fraction: written up to its last non-zero digit, at least one
    tz = np.zeros(n, int)
    rest = fp.copy()
    for _ in range(nd):
        z = (rest % 10 == 0) & (rest > 0)
        tz += z
        rest = np.where(z, rest // 10, rest)
    shown_f = np.where(fp > 0, nd - tz, 1)
    chars = np.empty((n, 4 + D + nd), np.uint8)
    chars[:, 0], chars[:, 1], chars[:, 2] = ord(" "), ord(letter), ord("-")
    chars[:, 3:3 + D] = digits(ip, D)
    chars[:, 3 + D] = ord(".")
    chars[:, 4 + D:] = digits(fp, nd)
    mask = np.zeros((n, 4 + D + nd), bool)
    mask[:, :2] = True
    mask[:, 2] = neg
    mask[:, 3:3 + D] = ip[:, None] >= 10 ** np.arange(D - 1, -1, -1)
    mask[:, 2 + D] = True                               # the units digit
    mask[:, 3 + D:] = (m[:, None] > 0) & (np.arange(nd + 1) <= shown_f[:, None])
    if on is not None:
        mask &= np.asarray(on, bool)[:, None]
    return chars, mask


def _move_texts(x, y, amount, f, laid, newf, sizes) -> list:
    """Lines "G1 X Y [E|W] [F]" for rounded columns (X, Y to 3 decimals, E 5 or W 4, F 1), where
    `amount` is (letter, values, decimals), one text per group of `sizes` lines (without its
    last newline). Built as one character matrix: the writer's hot loop (a cylinder has half a
    million moves per file)."""
    n = len(x)
    parts = [(np.frombuffer(b"G1", np.uint8)[None, :].repeat(n, 0), None),
             _word_chars("X", x, 3), _word_chars("Y", y, 3),
             _word_chars(amount[0], amount[1], amount[2], on=laid), _word_chars("F", f, 1, on=newf),
             (np.full((n, 1), ord("\n"), np.uint8), None)]
    chars = np.hstack([c for c, _ in parts])
    mask = np.hstack([np.ones_like(c, bool) if m is None else m for c, m in parts])
    text = chars[mask].tobytes().decode("ascii")
    ends = np.cumsum(mask.sum(axis=1))[np.cumsum(sizes) - 1].tolist()
    return [text[a:b - 1] for a, b in zip([0] + ends[:-1], ends)]


class _Writer:
    """Writes one of the two G-code files. `mode`: "litho" (width mode: M723 sets the extruder
    rate, the firmware picks each piece's speed) or "stock" (eq. 2: explicit F per piece so that
    E * F / L is the same rate, for stock firmware). `items` holds the file as lines, and each
    section's moves as (text, estimate.MoveBlock), so the estimate need not parse them again."""

    def __init__(self, plan: Plan, mode: str):
        self.p, self.o, self.mode = plan, plan.options, mode
        self.items: list = []
        self.x = self.y = None
        self.f = None
        self.retracted = False
        self.flow = None
        self.pending: list = []       # sections whose text is still to be made

    def flush(self):
        """Make the text of the sections written since the last flush."""
        if not self.pending:
            return
        idx, *cols = zip(*self.pending)
        X, Y, A, F, laid, newf = (np.concatenate(c) for c in cols)
        amount = ("W", A, 4) if self.mode == "litho" and self.o.words == "w" else ("E", A, 5)
        for i, text in zip(idx, _move_texts(X, Y, amount, F, laid, newf, [len(c) for c in cols[0]])):
            self.items[i][0] = text
        self.pending = []

    def out(self, s):
        self.items.append(s)

    def text(self):
        """The file's text in pieces (one per line or section)."""
        for it in self.items:
            yield (it if isinstance(it, str) else it[0]) + "\n"

    def lines(self):
        """The file for the estimator: lines, and MoveBlocks for the sections' moves."""
        for it in self.items:
            if isinstance(it, str):
                yield from it.split("\n")
            else:
                yield it[1]

    def move(self, x, y, e=None, f=None, w=None):
        ox, oy = self.p.origin
        words = [f"G1 X{_fmt(x + ox, 3)} Y{_fmt(y + oy, 3)}"]
        if w is not None:
            words.append(f"W{_fmt(w, 4)}")
        elif e is not None and e != 0:
            words.append(f"E{_fmt(e, 5)}")
        if f is not None:
            fm = f * 60
            if self.f is None or abs(fm - self.f) > 1e-6:
                words.append(f"F{_fmt(fm, 1)}")
                self.f = float(_fmt(fm, 1))
        self.out(" ".join(words))
        self.x, self.y = x, y

    def travel(self, x, y):
        o = self.o
        if self.x is not None and math.hypot(x - self.x, y - self.y) < 1e-6:
            return
        far = self.x is None or math.hypot(x - self.x, y - self.y) >= o.retract_min
        if far and o.retract > 0 and not self.retracted:
            self.out(f"G1 E-{_fmt(o.retract, 4)} F{_fmt(o.retract_speed * 60, 1)}")
            self.f = o.retract_speed * 60
            self.retracted = True
        self.move(x, y, f=o.travel_speed)

    def prime(self):
        if self.retracted:
            self.out(f"G1 E{_fmt(self.o.retract, 4)} F{_fmt(self.o.retract_speed * 60, 1)}")
            self.f = self.o.retract_speed * 60
            self.retracted = False

    def set_flow(self, q):
        if self.mode == "litho" and (self.flow is None or abs(q - self.flow) > 1e-9):
            self.out(f"M723 Q{_fmt(q, 4)}")
            self.flow = q

    def section(self, s: Section, wall_flow, mid_flow):
        from ..gcode.estimate import MoveBlock

        o = self.o
        start = s.pts[0]
        if self.x is None or math.hypot(start[0] - self.x, start[1] - self.y) > 1e-6:
            d = math.inf if self.x is None else math.hypot(start[0] - self.x, start[1] - self.y)
            if d < o.retract_min and not self.retracted:
                # a short join inside the part: laid at this section's width, so no travel
                self.out(";TYPE:connector")
                self.set_flow(wall_flow if s.kind == "wall" else mid_flow)
                e = d * s.width[0] * o.layer_height / o.filament_area if s.width[0] > 0 else 0.0
                self._piece(start[0], start[1], e, s.v[0], s.width[0] if e > 0 else None)
            else:
                self.out(";TYPE:travel")
                self.travel(start[0], start[1])
        self.prime()
        self.out(f";TYPE:{s.kind}")
        self.set_flow(wall_flow if s.kind == "wall" else mid_flow)
        # every piece at once: X Y, E (or W) where laid, F where it changes
        ox, oy = self.p.origin
        X, Y = np.round(s.pts[1:, 0] + ox, 3), np.round(s.pts[1:, 1] + oy, 3)
        laid = s.e > 0
        F = np.round(s.v * 60, 1)
        use_w = self.mode == "litho" and o.words == "w"
        E = np.where(laid, np.round(s.e, 5), 0.0)
        Wd = np.where(laid, np.round(s.width, 4), 0.0) if use_w else None
        prev = np.concatenate([[self.f if self.f is not None else -1.0], F[:-1]])
        newf = np.abs(F - prev) > 1e-6
        # the text is made with the next sections' (flush): fewer, larger array steps
        self.pending.append((len(self.items), X, Y, Wd if use_w else E, F, laid, newf))
        self.items.append([None, MoveBlock(X, Y, E, F, Wd)])
        self.f = float(F[-1])
        self.x, self.y = s.pts[-1]

    def _piece(self, x, y, e, v, width):
        if self.mode == "stock":
            self.move(x, y, e=e, f=v)
        elif self.o.words == "w" and width is not None:
            self.move(x, y, w=width)
        else:
            # E per width; F is the same speed the firmware will choose, so the file also
            # prints right on firmware without width mode (the firmware ignores F here)
            self.move(x, y, e=e, f=v)


def write_gcode(plan: Plan, path, mode: str, name: str = "lithophane", estimate_with=()) -> list:
    """Write one G-code file, and return its estimated print time (s, from the moves as
    written) for every estimate.Machine in `estimate_with`."""
    from .. import progress as pg

    o = plan.options
    w = _Writer(plan, mode)
    fill = lambda text: text.replace("{temp}", str(o.temp)).replace("{bed_temp}", str(o.bed_temp))
    start = DEFAULT_START if o.start_gcode is None else _read_text(o.start_gcode, "start-gcode")
    end = DEFAULT_END if o.end_gcode is None else _read_text(o.end_gcode, "end-gcode")
    w.out(f"; bulgekit litho: {name}, {o.shape}, {len(plan.layers)} layers, "
          f"{'width mode (M723)' if mode == 'litho' else 'stock firmware (eq. 2: F per piece)'}")
    for k, v in sorted(options_dict(o).items()):          # one short line each (firmware line limits)
        w.out(f"; {k} = {json.dumps(v)}")
    w.out(fill(start).rstrip("\n"))
    w.out("G90 ; absolute positions")
    w.out("M83 ; relative E")
    if o.start_gcode is None and o.purge:
        w.out(";TYPE:purge")
        y = 5.0 - plan.origin[1]
        x0, x1 = 10.0 - plan.origin[0], o.bed[0] - 10.0 - plan.origin[0]
        w.out(f"G1 Z{_fmt(o.layer_height, 3)} F{_fmt(o.z_speed * 60, 1)}")
        w.move(x0, y, f=o.travel_speed)
        purge_e = (x1 - x0) * o.line_width * 1.5 * o.layer_height / o.filament_area
        w.move(x1, y, e=purge_e, f=o.first_layer_speed)
    if mode == "litho":
        w.out(f"M723 S1 Q{_fmt(o.wall_flow, 4)} D{_fmt(o.filament, 4)} H{_fmt(o.layer_height, 4)} "
              f"L{_fmt(o.min_speed, 3)} U{_fmt(o.max_speed, 3)} ; width mode: extruder at one rate")
        w.flow = o.wall_flow
    ratio = o.first_layer_speed / o.wall_speed
    n = len(plan.layers)
    with pg.phase(f"writing {Path(path).name}", n, unit="layers"):
        for k, L in enumerate(plan.layers):
            w.out(f";LAYER:{k}")
            w.out(f"G1 Z{_fmt(L.z, 3)} F{_fmt(o.z_speed * 60, 1)}")
            w.f = o.z_speed * 60
            wall_q = o.wall_flow * (ratio if k == 0 else 1.0)
            mid_q = o.mid_flow * (ratio if k == 0 else 1.0)
            for s in L.sections:
                w.section(s, wall_q, mid_q)
            if sum(len(q[1]) for q in w.pending) > 16384:
                w.flush()
            if k % 16 == 0:
                pg.tick(k)
        if mode == "litho":
            w.out("M723 S0 ; width mode off")
        if o.retract > 0:
            w.out(f"G1 E-{_fmt(o.retract, 4)} F{_fmt(o.retract_speed * 60, 1)}")
        w.out(fill(end).rstrip("\n"))
        w.flush()
        outputs.write(path, w.text())
    for it in w.items:                              # the estimate needs the moves' numbers only
        if not isinstance(it, str):
            it[0] = None
    from ..gcode import estimate

    out = []
    for m in estimate_with:
        every = "" if m.min_segment_steps else ", every move planned"
        with pg.phase(f"estimating {Path(path).name}{every}", 1, unit="estimates"):
            out.append(estimate.estimate_lines(w.lines(), m, source=os.fspath(path), blocks=False).total_s)
    return out


def _read_text(path, opt):
    try:
        return Path(path).read_text()
    except OSError as e:
        raise LithoError(f"--{opt} {path}: {e.strerror or e}") from None


def machine_for(o: LithoOptions):
    """The estimate's machine: the printer model's (o.printer; by default Marlin's defaults) at
    the acceleration `accel` for printing, travel and retraction (its axes' M201 limits raised
    to it where it is higher, so that what the user states is what is timed)."""
    from ..gcode import estimate
    m = estimate.Machine.from_model(o.printer)
    top = {k: max(v, o.accel) if k in ("X", "Y") else v for k, v in m.max_accel.items()}
    return replace(m, accel=o.accel, travel_accel=o.accel, retract_accel=o.accel, max_accel=top)


def machine_words(m) -> dict:
    """What an estimate assumes, as the JSON and the CLI name it."""
    jerk = None if m.jerk is None else [m.jerk[a] for a in "XYZE"]      # mm/s, X Y Z E
    return {"accel_mm_s2": m.accel, "travel_accel_mm_s2": m.travel_accel,
            "junction_deviation_mm": m.junction_deviation, "classic_jerk": jerk,
            "lookahead_blocks": m.lookahead, "min_segment_steps": m.min_segment_steps}
