"""The small public API: strokes + sliced G-code -> map, annotated G-code,
stock-firmware fallback and statistics.

    import bulgekit as bk
    strokes = bk.text_strokes("HELLO", size_mm=6, u0=-15, v0=3)
    out = bk.build("cyl.gcode", strokes, "out/")
    print(out.stats.text())

Every user-facing failure raises a BulgekitError subclass whose message
names the file and line, stroke or layer at fault.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from . import annotate as _annotate
from . import fallback as _fallback
from . import mapbuild, mapformat, stats as _stats, wall
from .. import outputs, parallel, progress
from .fallback import MODE_GEOMETRIC, MODE_MARKED, Settings
from ..errors import BulgekitError, InputError
from .strokes import Stroke

_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".gif", ".tif", ".tiff", ".webp"}


def load_strokes(path, *, image_width_mm: float | None = None, offset=(0.0, 0.0),
                 scale: float = 1.0, pitch_mm: float = 1.5,
                 curve_tolerance_mm: float = 0.05, skip_unsupported: bool = False) -> list[Stroke]:
    """Strokes from a .json stroke list, an .svg drawing or a grayscale image
    (dots; needs image_width_mm). skip_unsupported: an SVG's <text>/<image> is warned about
    and skipped instead of refused."""
    from . import strokes as st
    p = os.fspath(path)
    ext = Path(p).suffix.lower()
    if ext == ".json":
        return st.load_json(p, offset=offset, scale=scale)
    if ext == ".svg":
        return st.load_svg(p, offset=offset, scale=scale, tolerance_mm=curve_tolerance_mm,
                           skip_unsupported=skip_unsupported)
    if ext in _IMAGE_EXT:
        if not image_width_mm:
            raise InputError(f"{p}: an image needs a width on the wall (--image-width MM)")
        return st.image_dots(p, image_width_mm, u0=offset[0], v0=offset[1], pitch_mm=pitch_mm)
    raise InputError(f"{p}: unknown stroke file type {ext!r} (use .json, .svg or an image)")


def walls(gcode, *, geometric: bool = False, layer_height: float | None = None,
          ref_angle_deg: float = -90.0) -> wall.WallModel:
    """Outer walls per layer of a sliced file (see bulge/wall.py for u and v)."""
    with progress.phase("reading the walls", path=gcode):
        return wall.walls_from_gcode(gcode, layer_height, geometric, ref_angle_deg)


def build_map(model: wall.WallModel, strokes: Sequence[Stroke], *, spacing: float | None = None,
              line_width: float = mapbuild.DEFAULT_LINE_WIDTH, quantum_um: int = mapbuild.MAP_QUANTUM_UM,
              strict: bool = True) -> mapbuild.BuildResult:
    return mapbuild.build(strokes, model, spacing=spacing, line_width=line_width,
                          quantum_um=quantum_um, strict=strict)


annotate_gcode = _annotate.annotate_gcode    # (defined beside annotate_file: the CLI's
                                             # annotate calls it without importing build's modules)


def fallback_gcode(gcode, map_bytes: bytes, out, settings: Settings = Settings(), *,
                   allow_unreached: bool = False,
                   stops: _fallback.StockStops = _fallback.StockStops(),
                   _on_plan=None) -> _fallback.RewriteResult:
    """Map points no move reaches are an error unless allow_unreached. stops: how the stops
    are written (E-only moves by default, or G4)."""
    with progress.phase("stock fallback", path=gcode):
        return _fallback.rewrite_file(gcode, out, mapformat.decode_map(map_bytes, source="map"),
                                      settings, allow_unreached, stops, _on_plan)


def bulge_stats(map_bytes: bytes, settings: Settings = Settings(), gcode=None,
          arena: int = _stats.ARENA_BYTES, _planned: _stats.StopTimer | None = None,
          printer=None) -> _stats.Stats:
    """printer: the model whose planner times the stops' braking and starting (None: the
    default model's)."""
    if gcode is None:
        return _stats.map_stats(map_bytes, settings, arena)
    with progress.phase("statistics", path=gcode):
        return _stats.print_stats(gcode, map_bytes, settings, arena, planned=_planned, printer=printer)


@dataclass
class BuildOutput:
    map_path: Path
    gcode_path: Path
    fallback_path: Path | None
    stats_path: Path
    result: mapbuild.BuildResult
    annotate: _annotate.AnnotateResult
    stats: _stats.Stats


def build(gcode, strokes: Sequence[Stroke], outdir, *, name: str | None = None,
          geometric: bool = False, spacing: float | None = None,
          line_width: float = mapbuild.DEFAULT_LINE_WIDTH, layer_height: float | None = None,
          ref_angle_deg: float = -90.0, settings: Settings | None = None,
          stream: bool = True, arena: int = _annotate.ARENA_BYTES,
          write_fallback: bool = False, quantum_um: int = mapbuild.MAP_QUANTUM_UM,
          stops: _fallback.StockStops = _fallback.StockStops(), _on_map=None,
          _check_walls=None) -> BuildOutput:
    """Strokes + sliced G-code -> <name>.bkm, <name>.bulge.gcode, <name>.stats.txt
    (and <name>.stock.gcode with write_fallback) in outdir. _on_map(result): called with the
    map as soon as it is placed (the CLI starts the preview's drawing there). _check_walls(model):
    called with the walls before anything is placed or written (it raises to refuse them)."""
    gcode = Path(gcode)
    from ..gcode import movescan
    # checked once and scanned once: every pass below works from this scan's move records, in
    # marked mode the lean ones (walls, the planner runs and the stock fallback need no more)
    marked = (settings.mode if settings is not None else
              MODE_GEOMETRIC if geometric else MODE_MARKED) == MODE_MARKED
    with movescan.Scan(gcode, str(gcode), lean=marked).kept():
        return _build(gcode, strokes, outdir, name, geometric, spacing, line_width, layer_height,
                      ref_angle_deg, settings, stream, arena, write_fallback, quantum_um, stops,
                      _on_map, _check_walls)


def _build(gcode: Path, strokes, outdir, name, geometric, spacing, line_width, layer_height,
           ref_angle_deg, settings, stream, arena, write_fallback, quantum_um, stops,
           on_map, check_walls=None) -> BuildOutput:
    outdir = Path(outdir)
    name = name or gcode.stem
    if settings is None:
        settings = Settings(mode=MODE_GEOMETRIC if geometric else MODE_MARKED)
    elif geometric and settings.mode != MODE_GEOMETRIC:
        raise BulgekitError("geometric=True needs settings with mode 2 (M720 S2)")
    model = walls(gcode, geometric=settings.mode == MODE_GEOMETRIC, layer_height=layer_height,
                  ref_angle_deg=ref_angle_deg)
    if check_walls is not None:
        check_walls(model)
    res = build_map(model, strokes, spacing=spacing, line_width=line_width,
                    quantum_um=quantum_um)
    if not stream and res.overflow(arena):
        over = ", ".join(f"z {z:.2f}" for z, _ in res.overflow(arena))
        raise mapbuild.BuildError(
            f"the map ({len(res.map_bytes)} bytes) exceeds the printer's {arena}-byte arena; "
            f"layers {over} mm do not fit. Allow streaming (drop --no-stream) or use fewer points.")
    if on_map is not None:
        on_map(res)
    map_path = outdir / f"{name}.bkm"
    gpath = outdir / f"{name}.bulge.gcode"
    fpath = outdir / f"{name}.stock.gcode" if write_fallback else None
    spath = outdir / f"{name}.stats.txt"
    # The folder is made only now that the inputs are checked; the files go in place together
    # when all are whole (in the CLI, with the command's other files), or none does and the
    # folder goes too if this made it (bulgekit.outputs)
    with outputs.Outputs() as staged:
        staged.folder(outdir)
        if fpath is not None:
            staged.part(fpath)     # before the fork: the child writes it, this process removes it
        outputs.write(map_path, res.map_bytes)
        # the map was placed on this file's walls; points it still misses are
        # listed by the stats below (one planner run instead of three)
        def stock_and_stats():
            stock = None
            timers: list[_stats.StopTimer] = []
            if fpath is not None:
                # the statistics count on the stock file's planner run: the planner runs once
                def on_plan(planner):
                    timers.append(_stats.StopTimer(planner, _stats.accel_of(stops.printer),
                                                   _stats.timed_model(stops.printer)))
                    return timers[-1]
                stock = fallback_gcode(gcode, res.map_bytes, fpath, settings, allow_unreached=True,
                                       stops=stops, _on_plan=on_plan).stock
            return stock, bulge_stats(res.map_bytes, settings, gcode, arena,
                                      timers[-1] if timers else None, stops.printer)
        # the stock file and the statistics are made on a second core while the map is annotated
        # into the G-code: a child forked from this process and its scan (bulgekit.parallel;
        # where none can be forked, after the annotating, as before). The same files; of two
        # errors, annotate's is said, as before.
        beside = parallel.Forked.running(stock_and_stats) if fpath is not None else None
        try:
            ann = annotate_gcode(gcode, res.map_bytes, gpath, settings, stream=stream, arena=arena,
                                 check=False)
            if beside is None:
                stock, st = stock_and_stats()
            elif beside.forked:                # (a child shows no progress: one line for both)
                with progress.phase("stock fallback and statistics"):
                    stock, st = beside.result()
            else:                              # (made here now, with their own lines)
                stock, st = beside.result()
        finally:
            if beside is not None:
                beside.close()                 # (ended before its part is removed)
        st.stock = stock
        st.arcs = ann.arcs                     # (as written: their chords and how near the arcs)
        outputs.write(spath, st.text() + "\n")
    return BuildOutput(map_path, gpath, fpath, spath, res, ann, st)
