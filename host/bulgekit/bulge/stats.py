"""Stops, per-layer counts and the time bulges add to a print.

Two levels: `map_stats` reads only the map (what was asked for);
`print_stats` also runs the G-code through the reference planner
(fallback.RefPlanner), so it counts the stops that will really happen and
names the points no outer-wall move passes within the tolerance.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from . import mapformat
from . import stopmodel
from .. import machine
from ..gcode import movescan
from .fallback import ArcCount, ArcLines, RefPlanner, Settings, plan_records
from ..gcode import ARC_CHORD_DEVIATION_MM, open_checked

ARENA_BYTES = mapformat.ARENA_BYTES


@dataclass
class LayerCount:
    z: float
    points: int
    stops: int | None = None


@dataclass
class Stats:
    layers: list[LayerCount]
    points: int
    map_bytes: int
    arena: int
    dwell_s: float                 # total dwell, weights applied
    extra_e_mm: float              # total extra filament
    settings: Settings
    stops: int | None = None       # from the G-code run
    missed: list[tuple[float, float, float]] = field(default_factory=list)  # (z, x, y)
    extra_dropped_mm: float = 0.0
    decel_s: float | None = None   # stop/start cost at the moves' feedrates
    slicer_time_s: float | None = None
    stock: object | None = None    # fallback.StopWriter of the stock file, when one was written
    arcs: ArcCount | None = None   # G2/G3 through points, written as G1 chords (from the G-code run)
    printer: object | None = None  # the printer model decel_s was timed for (None: v/a, below)
    gaps: list = field(default_factory=list)  # with printer: each stop's (ms, path mm from the
                                              # stop before, or None), from StopTimer

    def stock_ramps(self) -> list[float] | None:
        """With a printer model and a stock file: the seconds each stop of the stock file adds
        beyond its stillness (stopmodel.chain_ramps: its own speeds into and out of each stop,
        the gaps between stops from the planner's run), in the file's order; None when the
        stops written and the planner's do not pair up."""
        if self.printer is None or self.stock is None:
            return None
        written = [w for w in self.stock.written if w.here is not None]
        gaps = [g for ms, g in self.gaps if ms > 0 or self.stock.cfg.stop == "g4"]
        if len(written) != len(self.stock.written) or len(written) != len(gaps):
            return [w.ramp for w in self.stock.written]
        return stopmodel.chain_ramps(self.printer, [stopmodel.RampStop(w.here, w.v_exit, w.v_entry, g, w.after)
                                                    for w, g in zip(written, gaps)])

    @property
    def added_s(self) -> float:
        return self.dwell_s + (self.decel_s or 0.0)

    @property
    def fits_arena(self) -> bool:
        return self.map_bytes - mapformat.HEADER_BYTES <= self.arena

    def text(self, per_layer: bool = True) -> str:
        s = self.settings
        out = [f"bulge map: {len(self.layers)} layers, {self.points} points, {self.map_bytes} bytes "
               f"(printer arena {self.arena} bytes: "
               + ("fits)" if self.fits_arena else "streamed as appends while printing)"),
               f"settings: {s.m720()}"]
        if self.stops is not None:
            out.append(f"stops when printed: {self.stops} of {self.points} points")
            if self.missed:
                show = ", ".join(f"z {z:.2f} ({x:.2f}, {y:.2f})" for z, x, y in self.missed[:8])
                more = f" and {len(self.missed) - 8} more" if len(self.missed) > 8 else ""
                out.append(f"WARNING: {len(self.missed)} points are not within {s.tolerance:.2f} mm "
                           f"of any {'outer-wall' if s.mode == 1 else 'extruding'} move: {show}{more}")
            if self.extra_dropped_mm > 1e-9:
                out.append(f"extra filament lost to stops at a wall's end: {self.extra_dropped_mm:.3f} mm")
            if self.arcs is not None and self.arcs.arcs:
                out.append(f"arcs: {self.arcs_text()}")
        out.append(f"extra filament: {self.extra_e_mm:.2f} mm")
        t = f"added time: {_hms(self.dwell_s)} dwell"
        if self.decel_s is not None:
            t += f" + {_hms(self.decel_s)} stopping/starting = {_hms(self.added_s)}"
        if self.slicer_time_s:
            t += f" ({100 * self.added_s / self.slicer_time_s:.1f}% of the slicer's {_hms(self.slicer_time_s)})"
        out.append(t)
        if self.stock is not None:
            # the stock file's stops as the printer runs them: an E-only stop is a block of
            # its stillness less the braking's last step (counted in stopping/starting below),
            # as bulgekit estimate times it; a G4 its dwell and the planner's drain
            out.append(f"stock file: {self.stock.summary()}")
            held = self.stock.run_s + self.stock.g4_s
            ramps = self.decel_s
            if self.printer is not None:
                # timed by the printer's own stepper: the stillness as the head stands, the
                # braking and starting around each stop as the stock file's stops make them
                held = self.stock.still_s + self.stock.g4_s
                ramps = sum(self.stock_ramps())
            t = f"stock file's added time: {_hms(held)} in the stops"
            if ramps is not None:
                t += f" + {_hms(ramps)} stopping/starting = {_hms(held + ramps)}"
            if self.stock.g4:
                t += f" (and the planner's drain and refill at each of its {self.stock.g4} G4)"
            out.append(t)
        if per_layer:
            out.append("per layer (z mm: points" + (" / stops" if self.stops is not None else "") + "):")
            row = []
            for lc in self.layers:
                row.append(f"{lc.z:.2f}:{lc.points}" + (f"/{lc.stops}" if lc.stops is not None else ""))
            for i in range(0, len(row), 8):
                out.append("  " + "  ".join(row[i:i + 8]))
        return "\n".join(out)


    def arcs_text(self) -> str:
        """The arcs written as chords: as counted where they were written (ArcCount.text), or
        their number and the farthest Marlin's segments can lie from an arc."""
        if self.arcs.chords:
            return self.arcs.text()
        n = self.arcs.arcs
        return (f"{n} G2/G3 arc{'s' if n != 1 else ''} through map points written as G1 chords, "
                f"Marlin's own segments (at most 1 mm; within {ARC_CHORD_DEVIATION_MM:.3f} mm "
                "of the arc)")


def _hms(sec: float) -> str:
    sec = float(sec)
    if sec < 60:
        return f"{sec:.1f} s"
    m, s = divmod(round(sec), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s"


def map_stats(map_bytes: bytes, settings: Settings, arena: int = ARENA_BYTES) -> Stats:
    bm = mapformat.decode_map(map_bytes, source="map")
    layers = []
    dwell_ms = 0
    for l in bm.layers:
        layers.append(LayerCount(l.z_cmm / 100, len(l.points)))
        ws = l.weights or (255,) * len(l.points)
        dwell_ms += sum((settings.dwell_ms * w + 127) // 255 for w in ws)
    n = bm.point_count
    return Stats(layers, n, len(map_bytes), arena, dwell_ms / 1000, n * settings.extra_e, settings)


# (with a word each match holds, found first: a match begins at the line of the last ";" up to
# that word, and the regex is tried from there on; anchored at every line of the file's 4 MB of
# ends, it takes some 30 ms)
_TIME_RX = (
    (re.compile(r"^; estimated printing time \(normal mode\) = (.+)$", re.M), "dhms",
     "; estimated printing time"),                                                     # Prusa, Orca
    (re.compile(r"^;TIME:(\d+)", re.M), "s", ";TIME:"),                                 # Cura
    (re.compile(r"^;\s*Build time: (\d+) hours? (\d+) minutes?", re.M), "hm", "Build time: "),  # S3D
)


def slicer_time(text: str) -> float | None:
    """The slicer's own print time estimate, seconds, if it wrote one."""
    for rx, kind, word in _TIME_RX:
        at = text.find(word)
        if at < 0:
            continue
        semi = text.rfind(";", 0, at + 1)
        m = rx.search(text, text.rfind("\n", 0, semi) + 1 if semi > 0 else 0)
        if not m:
            continue
        if kind == "s":
            return float(m.group(1))
        if kind == "hm":
            return int(m.group(1)) * 3600 + int(m.group(2)) * 60
        total = 0.0
        for num, unit in re.findall(r"(\d+)([dhms])", m.group(1)):
            total += int(num) * {"d": 86400, "h": 3600, "m": 60, "s": 1}[unit]
        return total or None
    return None


def timed_model(pm) -> object | None:
    """The printer model the stop-and-start time is timed with: a Marlin model's own stepper
    (stopmodel.ramp_s; None: machine.DEFAULT's). Another firmware's (None returned) is timed as
    v/a at its model's acceleration (accel_of): its planner is not modelled step by step."""
    pm = machine.DEFAULT if pm is None else pm
    return pm if pm.firmware == "marlin" else None


def accel_of(pm) -> float:
    """The acceleration a stop's braking and starting is timed at where timed_model gives None."""
    return (machine.DEFAULT if pm is None else pm).accel


class StopTimer:
    """An on_move hook of a planner's run (plan_records, fallback.rewrite): the time the stops
    cost over cruising, decelerating to each and back: v/a at its move's feed rate, or with a
    printer model (timed_model) Marlin's stepper braking to rest and starting from rest at the
    model's acceleration for that move (stopmodel.ramp_s)."""

    def __init__(self, planner: RefPlanner, accel_mm_s2: float = 1000.0, printer=None):
        self.planner, self.accel = planner, accel_mm_s2
        self.printer = printer
        self.seen = 0
        self._decel_s = 0.0
        self.arcs = ArcLines(planner)          # the arcs the outputs write as chords
        self.ramp_stops: list = []     # with a printer: (ms, stopmodel.RampStop) per stop
        self._last = None              # (move index, path mm since the chain began, mm at its last stop)

    @property
    def decel_s(self) -> float:
        if self.printer is None:
            return self._decel_s
        return sum(stopmodel.chain_ramps(self.printer, [r for _, r in self.ramp_stops]))

    @property
    def gaps(self) -> list:
        return [(ms, r.gap) for ms, r in self.ramp_stops]

    def __call__(self, m, actions) -> None:
        self.arcs(m, actions)
        k = len(self.planner.stops) - self.seen      # stops this move made
        self.seen = len(self.planner.stops)
        if self.printer is None:
            if k:
                self._decel_s += k * (m.f / 60.0) / self.accel
            return
        # the path since the last stop, while moves follow one another extruding
        chain = self._last is not None and m.index == self._last[0] + 1 and m.extruding
        s, last_stop = (self._last[1], self._last[2]) if chain else (0.0, None)
        if not m.extruding:
            self._last = None
            return
        piece = stopmodel.piece_of(self.printer, m)
        cx, cy = m.x0, m.y0
        for a in actions:
            if a.kind == "line":
                s += math.hypot(a.x - cx, a.y - cy)
                cx, cy = a.x, a.y
            elif a.kind == "dwell":
                gap = s - last_stop if last_stop is not None else None
                self.ramp_stops.append((a.ms, stopmodel.RampStop(piece, 0.0, 0.0, gap)))
                last_stop = s
        self._last = (m.index, s, last_stop)


def print_stats(gcode_path, map_bytes: bytes, settings: Settings, arena: int = ARENA_BYTES,
                accel_mm_s2: float | None = None, planned: StopTimer | None = None,
                printer=None) -> Stats:
    """map_stats plus a run of the G-code through the reference planner. planned: the hook of
    a run of a planner with this map and these settings over this file that has already
    happened (build: the stock fallback's), which is then not run again. printer: the model
    the stopping and starting is timed for (None: machine.DEFAULT); accel_mm_s2, when given,
    times it as v/a at that acceleration instead."""
    if accel_mm_s2 is None:
        accel_mm_s2, printer = accel_of(printer), timed_model(printer)
    else:
        printer = None
    st = map_stats(map_bytes, settings, arena)
    bm = mapformat.decode_map(map_bytes)
    ends, _ = open_checked(gcode_path)             # checked; its moves are scanned in chunks

    def run(chunks):
        timer = StopTimer(RefPlanner(bm, settings), accel_mm_s2, printer)
        plan_records(timer.planner, chunks, timer)
        return timer
    if planned is None:
        planned = movescan.run(gcode_path, run)
    planner, decel = planned.planner, planned.decel_s
    fired: dict[int, set] = {}
    per_z: dict[int, int] = {}
    dwell_ms = 0
    for s in planner.stops:
        fired.setdefault(s.layer_z_cmm, set()).add(s.point)
        per_z[s.layer_z_cmm] = per_z.get(s.layer_z_cmm, 0) + 1
    dwell_ms = planner.stats.dwell_ms_total
    q = bm.quantum_um / 1000
    missed = []
    for l, lc in zip(bm.layers, st.layers):
        lc.stops = per_z.get(l.z_cmm, 0)
        done = fired.get(l.z_cmm, set())
        for p in l.points:
            if p not in done:
                missed.append((l.z_cmm / 100, p[0] * q, p[1] * q))
    st.stops = len(planner.stops)
    st.missed = missed
    st.extra_dropped_mm = planner.stats.extra_dropped
    st.dwell_s = dwell_ms / 1000
    st.extra_e_mm = planner.stats.extra_applied
    st.decel_s = decel
    st.printer = planned.printer
    st.gaps = planned.gaps if planned.printer is not None else []
    st.arcs = ArcCount(len(planned.arcs.lines))
    st.slicer_time_s = slicer_time(ends)
    return st
