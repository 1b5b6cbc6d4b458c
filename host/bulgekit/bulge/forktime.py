"""Print time of an annotated file (`NAME.bulge.gcode`) as the bulgekit firmware runs it.

The estimator (gcode/estimate.py) knows G-code; the stops of an annotated file are not in its
moves but in the firmware: the map the M721 lines upload, the M720 settings and the M722 outer
wall markers. Here they are put back in, as the fork's core plans them (fallback.RefPlanner, its
mirror): each move the core splits becomes its pieces, the piece after a stop carries the extra
filament, and each stop is a dwell of P x w / 255 ms. The moves around a stop plan to rest, as
the fork's dwell block makes them (Planner::buffer_dwell clears the previous speed: the block
before decelerates to 0 and the one after starts from rest, docs/marlin-integration.md, "The
dwell block"); in the estimator that is a G4's planning, whose planner drain the dwell block has
none of, but whose junctions are the same. So the file is rewritten as the fallback's `--stop g4`
rewrite writes it (pieces, G4 P<ms>, extra E, G92 E), with the fork's M722 gating in place of
the slicer's comments, into a temporary file that the estimator reads at its own speed.

What the stepper then does at a stop, which a planner-level model leaves out, is added per stop
(FORK_START_S): the hold is counted from the last step before the point to the first step after
it, and that first step comes BK_DWELL_LEAD (0.5 ms) after the hold, where a start from rest on
stock Marlin takes its first step one interval at MINIMAL_STEP_RATE into the block (8.33 ms;
the estimator's trapezoids, like the stepper's ramp, count from the block's start). So the block
after a stop runs 1/MINIMAL_STEP_RATE earlier than the trapezoid the estimator plans, and a stop
adds max(P, lead) - 1/MINIMAL_STEP_RATE on top of the rest-to-rest junctions' time.
"""
from __future__ import annotations

import bisect
import os
import re
import tempfile
from dataclasses import dataclass, field, replace

import numpy as np

from . import mapformat
from .fallback import (MODE_OFF, STOP_G4, Action, RefPlanner, RewriteResult, Settings,
                       StockStops, _rewrite_records, rewrite)
from ..errors import BulgekitError
from ..gcode import check_file_ends, estimate as es, movescan, refuse_cut_off, split_code
from ..machine import PrinterModel

DWELL_LEAD_S = 0.0005          # BK_DWELL_LEAD: the first step after a hold (install-marlin.py)
POWER_ON = Settings(mode=MODE_OFF)   # M720's power-on state: the defaults, mode 0

# a line that starts with M720, M721 or M722 (an N word may lead), as the firmware reads them
_OURS = re.compile(rb"[ \t]*(?:[Nn]\d+[ \t]+)?[Mm]0*72([0-2])(?![0-9.])")


class ForkTimeError(BulgekitError):
    """An annotated file whose stops cannot be modelled (the message names file and line)."""


def is_annotated(path, head: int = 1 << 20) -> bool:
    """Whether the file uploads a map (an M721 line in its first MB, where the annotator and
    `mcodes` put the upload): only such files take the fork's path."""
    with open(path, "rb") as f:
        data = f.read(head)
    for i in _line_starts(data):
        mt = _OURS.match(data, i)
        if mt and mt.group(1) == b"1":
            return True
    return False


_M72 = re.compile(rb"72[0-2]")   # a literal's search (quicker than [Mm] or bytes.find); _OURS decides


def _line_starts(data, pattern=_M72) -> list[int]:
    """Starts of the lines where `pattern` stands."""
    out = []
    for mt in pattern.finditer(data):
        s = data.rfind(b"\n", 0, mt.start()) + 1
        if not out or out[-1] != s:
            out.append(s)
    return out


@dataclass
class Marks:
    """The bulgekit lines of a file: (line number, code) of each M720, M721, M722."""
    m720: list = field(default_factory=list)
    m721: list = field(default_factory=list)
    m722: list = field(default_factory=list)


def read_marks(data) -> Marks:
    """Every line of data (bytes) that starts with M720, M721 or M722, with its number."""
    out = Marks()
    lists = (out.m720, out.m721, out.m722)
    at, line = 0, 1
    for s in _line_starts(data):
        mt = _OURS.match(data, s)
        if not mt:
            continue
        line += data.count(b"\n", at, s)
        at = s
        end = data.find(b"\n", s)
        code = split_code(bytes(data[s:end if end >= 0 else len(data)]).decode("utf-8", "replace"))[0]
        lists[int(mt.group(1))].append((line, code))
    return out


def settings_timeline(m720, source: str) -> list[tuple[int, Settings]]:
    """(line, settings in force from it) from power-on through each M720 that sets something;
    an M720 the firmware refuses (a word out of range: all or nothing) changes nothing."""
    from ..gcode import GcodeError, parse_words
    out = [(0, POWER_ON)]
    for no, code in m720:
        try:
            w = parse_words(code.split(None, 1)[1] if " " in code.strip() else "", f"{source}:{no}")
        except GcodeError:
            continue
        if not w:
            continue                             # a report
        s = out[-1][1]
        if any(k in w and w[k] != int(w[k]) for k in "SP") or not w.keys() <= set("SPET"):
            continue                             # S and P are whole numbers; no other word
        try:
            new = Settings(mode=int(w.get("S", s.mode)), dwell_ms=int(w.get("P", s.dwell_ms)),
                           extra_e=w.get("E", s.extra_e), tolerance=w.get("T", s.tolerance))
        except ValueError:
            continue
        out.append((no, new))
    return out


class _GatedPlanner(RefPlanner):
    """RefPlanner with the fork's marker: a move is in the outer wall when the last M722 before
    its line said S1 (not where the slicer's comments say); and with the dwell and extra of the
    last M720 before its line (`bulgekit calibrate` changes the extra E between bands)."""

    def __init__(self, bmap, settings, lines: np.ndarray, states: np.ndarray, timeline=()):
        super().__init__(bmap, settings)
        self.m722_lines, self.m722_states = lines, states
        self.m720_lines = [n for n, _ in timeline]
        self.m720 = [st for _, st in timeline]

    def outer_at(self, line_no) -> np.ndarray:
        if not len(self.m722_lines):
            return np.zeros(np.shape(line_no), bool)
        k = np.searchsorted(self.m722_lines, line_no, side="left")
        return np.where(k > 0, self.m722_states[np.maximum(k - 1, 0)], False)

    def plan(self, m, outer=None):
        if m.arc:                   # the firmware never sees an arc's chords (RefPlanner.bypass)
            self.bypass(m)
            return [Action("line", m.x1, m.y1, m.z1, m.e)]
        if outer is None:
            outer = bool(self.outer_at(m.line_no))
        if self.m720_lines:
            k = bisect.bisect_right(self.m720_lines, m.line_no) - 1
            now = self.m720[k] if k >= 0 else POWER_ON
            if (now.dwell_ms, now.extra_e) != (self.s.dwell_ms, self.s.extra_e):
                self.s = replace(self.s, dwell_ms=now.dwell_ms, extra_e=now.extra_e)
        return super().plan(m, outer)


class _GatedChunks:
    """movescan chunks with each record's OUTER flag set from the M722 state at its line (what the
    Skipper and the compiled picker read)."""

    def __init__(self, chunks, planner: _GatedPlanner):
        self.c, self.p = chunks, planner
        self.roles = chunks.roles
        self.first_line = self.last_line = None

    @property
    def lines(self):
        return self.c.lines

    def __iter__(self):
        for a in self.c:
            if len(a):
                fl = a["flags"]
                want = np.where(self.p.outer_at(a["line_no"]), fl | movescan.OUTER,
                                fl & (0xFF ^ movescan.OUTER))
                if not np.array_equal(want, fl):      # (the annotator's markers: as the comments)
                    a = a.copy()
                    a["flags"] = want
                if self.first_line is None:
                    self.first_line = int(a["line_no"][0])
                self.last_line = int(a["line_no"][-1])
            yield a


@dataclass
class ForkEstimate:
    """The estimate of an annotated file: the estimator's Result with the fork's stops in it."""
    result: es.Result
    settings: Settings
    bmap: mapformat.BulgeMap | None
    stops: int = 0                 # dwells the core queues (points that share a stop: one)
    points: int = 0                # map points that fire
    dwell_s: float = 0.0           # their P x w / 255
    start_s: float = 0.0           # the stepper's earlier start after the stops (negative)
    extra_mm: float = 0.0          # extra filament laid after stops
    notes: list = field(default_factory=list)

    def summary(self) -> str:
        s = self.settings
        return (f"bulge stops as the bulgekit firmware plans them ({s.m720()}): {self.stops} stops "
                f"({self.points} points), dwell {self.dwell_s:.1f} s, extra filament "
                f"{self.extra_mm:.2f} mm")


def estimate_annotated(path, machine: es.Machine, model: PrinterModel, blocks: bool = False,
                       scanned: bool | None = None) -> ForkEstimate:
    """The print time of an annotated file as the bulgekit firmware runs it (see the module's
    doc). machine: the estimator's settings (es.Machine.from_model(model)); model: the printer,
    for its MINIMAL_STEP_RATE."""
    path = os.fspath(path)
    last = check_file_ends(path, path)          # the checks estimate_file makes, on the file given
    with open(path, "rb") as f:
        data = f.read()
    if last is not None:
        refuse_cut_off(last, data.count(b"\n") + 1, path)
    marks = read_marks(data)
    refused: list[str] = []                     # uploads the firmware refuses: the map stays
    bmap = mapformat.read_upload(marks.m721, path, refused)
    timeline = settings_timeline(marks.m720, path)
    m722 = [(n, _marker(c)) for n, c in marks.m722]
    m722 = [(n, on) for n, on in m722 if on is not None]
    lines = np.array([n for n, _ in m722], np.int64)
    states = np.array([on for _, on in m722], bool)
    feats = _features(data) if bmap is not None else None
    del data
    notes = [f"the firmware refuses {r}" for r in refused]
    # the settings in force at the first move that extrudes; none may change while moves follow
    first = _first_extrusion(path)
    k = bisect.bisect_right([n for n, _ in timeline], first if first is not None else 0) - 1
    settings = timeline[k][1]
    if bmap is None or settings.mode == MODE_OFF:
        notes.append("no map uploaded: the firmware stops nowhere" if bmap is None else
                     "M720 S0 (bulges off) at the first extrusion: the firmware stops nowhere")
        return ForkEstimate(es.estimate_file(path, machine, scanned=scanned, blocks=blocks), settings,
                            bmap, notes=notes)
    planner = _GatedPlanner(bmap, settings, lines, states, timeline)
    stops: list[tuple[int, int]] = []           # (line, ms) of each dwell the core queues

    last_move = [0]                             # the last move's line

    def on_move(m, acts):
        stops.extend((m.line_no, a.ms) for a in acts if a.kind == "dwell")
        last_move[0] = max(last_move[0], m.line_no)
    res = RewriteResult()
    cfg = StockStops(stop=STOP_G4, printer=model)
    with tempfile.TemporaryDirectory(prefix="bulgekit-forktime-") as tmp:
        out = os.path.join(tmp, os.path.basename(path))
        span = None
        done = False
        if (movescan.available() if scanned is None else scanned):
            def fast(chunks):
                nonlocal span
                g = _GatedChunks(chunks, planner)
                with open(out, "wb") as f, open(path, "rb") as src:
                    _rewrite_records(src, f, g, bmap, settings, path, res, cfg, None, planner, on_move)
                span = (g.first_line, g.last_line)
            try:
                movescan.run(path, fast, fast=True)
                done = True
            except movescan.Unsupported:
                planner = _GatedPlanner(bmap, settings, lines, states, timeline)
                stops.clear()
                res = RewriteResult()
        if done:
            try:
                r = es.estimate_file(out, machine, scanned=scanned, blocks=blocks)
            except es.EstimateError as e:      # (its lines numbered as the split file has them)
                raise es.EstimateError(str(e).replace(out, f"{path} (split as the firmware splits it)")) from None
        else:
            with open(path, encoding="utf-8", errors="replace") as f:
                r = es.estimate_lines(rewrite(f, bmap, settings, path, res, cfg, planner, on_move),
                                      machine, source=path, blocks=blocks)
            span = (first, last_move[0])
    _check_one_setting(timeline, span, first, path)
    # the stepper at each stop: the hold is at least the lead, and the block after it starts
    # 1 / MINIMAL_STEP_RATE sooner than its trapezoid (see the module's doc)
    sooner = 1 / model.min_step_rate if model.min_step_rate > 0 else 0.0
    start = hold = 0.0
    by = dict(r.by_feature)
    for line, ms in stops:
        h = max(ms / 1000, DWELL_LEAD_S) - ms / 1000
        start -= sooner
        hold += h
        f = feats(line)
        by[f] = by.get(f, 0.0) + h - sooner
    r = replace(r, total_s=r.total_s + start + hold, moves_s=r.moves_s + start,
                dwell_s=r.dwell_s + hold, by_feature=by)
    if res.unreached:
        notes.append(res.unreached.split("; ")[0] + " (they make no stop)")
    return ForkEstimate(r, settings, bmap, stops=len(stops), points=len(res.stops),
                        dwell_s=sum(ms for _, ms in stops) / 1000, start_s=start,
                        extra_mm=res.stats.extra_applied if res.stats else 0.0, notes=notes)


def _marker(code: str) -> bool | None:
    """M722 S1 (True) or S0 (False); None for what the firmware refuses, which leaves the marker
    as it was (no S0/S1, another letter)."""
    words = code.upper().split()
    if words and words[0][:1] == "N" and words[0][1:].isdigit():
        words = words[1:]
    if len(words) != 2 or words[1][:1] != "S":
        return None
    try:
        v = float(words[1][1:])
    except ValueError:
        return None
    return {1.0: True, 0.0: False}.get(v)


_TYPE = re.compile(rb";[ \t]*TYPE:([^\r\n;]*)")


def _features(data):
    """line -> the estimator's feature name (the last ;TYPE: comment before it, '' before any)."""
    at, line = 0, 1
    lines, names = [], []
    for mt in _TYPE.finditer(data):
        line += data.count(b"\n", at, mt.start())
        at = mt.start()
        lines.append(line)
        names.append(mt.group(1).decode("utf-8", "replace").strip())

    def feature(n: int) -> str:
        k = bisect.bisect_left(lines, n) - 1      # a comment on the stop's own line comes after it
        return names[k] if k >= 0 else ""
    return feature


def _first_extrusion(path) -> int | None:
    """The line of the file's first G0/G1 that extrudes in X/Y (machine.with_gcode's test)."""
    w = re.compile(r"([A-Za-z])\s*(-?\d+(?:\.\d*)?|-?\.\d+)")
    with open(path, encoding="utf-8", errors="replace") as f:
        for n, raw in enumerate(f, 1):
            code = split_code(raw)[0]
            if code[:1] in ("G", "g") and re.match(r"[Gg]0*[01]\b", code):
                words = dict((k.upper(), float(v)) for k, v in w.findall(code[2:]))
                if words.get("E", 0) > 0 and ("X" in words or "Y" in words):
                    return n
    return None


def _check_one_setting(timeline, span, first, source):
    """An M720 that changes the mode or the tolerance between the first extrusion and the last
    move: the stops after it are not modelled (refused rather than timed wrongly). A new dwell
    or extra is (the planner takes it at its line)."""
    if first is None or span is None:
        return
    last = span[1]
    k = bisect.bisect_right([n for n, _ in timeline], first) - 1
    for no, s in timeline[k + 1:]:
        if last is not None and no > last:
            break
        was = timeline[k][1]
        if (s.mode, s.tolerance) != (was.mode, was.tolerance):
            raise ForkTimeError(f"{source}:{no}: M720 changes the bulge mode or tolerance during the "
                                f"print ({was.m720()} -> {s.m720()}): the estimator models one per file")
