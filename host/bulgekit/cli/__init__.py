"""bulgekit command line."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import click

from ._util import (AT_HELP, FINITE, POSITIVE, Num, at_for, face_options, friendly, outdir_option, pair,
                    printer_model, printer_options, progress_option, warning_lines)
from .. import __version__
from ..bulge import mapformat
from ..bulge.fallback import (DEFAULT_DWELL_MS, DEFAULT_E_STEPS, DEFAULT_EXTRA_E_MM, DEFAULT_TOLERANCE_MM,
                       MIN_STEPS_PER_SEGMENT, MODE_GEOMETRIC, MODE_MARKED, Settings, StockStops)
from ..errors import BulgekitError


def _read_map(path) -> bytes:
    """A map file's bytes, checked here so that a corrupt file is named in the message."""
    return _read_decoded_map(path)[0]


def _read_decoded_map(path) -> tuple[bytes, mapformat.BulgeMap]:
    """_read_map's bytes, and the map they hold (not decoded again by the command)."""
    data = Path(path).read_bytes()
    return data, mapformat.decode_map(data, source=str(path))


def _settings_options(fn):
    fn = click.option("--geometric", is_flag=True,
                      help="Geometric mode (M720 S2): no outer-wall markers; every extruding move "
                           "near a point bulges. For G-code without feature comments.")(fn)
    fn = click.option("--tolerance", type=FINITE, default=DEFAULT_TOLERANCE_MM, show_default=True,
                      help="M720 T: how far (mm) a point may be from a move to stop it.")(fn)
    fn = click.option("--extra", type=FINITE, default=DEFAULT_EXTRA_E_MM, show_default=True,
                      help="M720 E: extra filament (mm) after each stop.")(fn)
    fn = click.option("--dwell", type=int, default=DEFAULT_DWELL_MS, show_default=True,
                      help="M720 P: dwell (ms) at each point, scaled by its weight/255.")(fn)
    return fn


def _stock_options(fn):
    """How a stock file writes its stops (docs/host.md, "Stops on stock firmware")."""
    fn = click.option("--stop-e-steps", type=click.IntRange(MIN_STEPS_PER_SEGMENT, 10000),
                      help="Stock file: E steps laid during each stop, taken from its extra filament "
                           "(the rest goes on the next piece) [the fewest that make a move: "
                           f"{MIN_STEPS_PER_SEGMENT}, more for long dwells].")(fn)
    fn = click.option("--e-steps", type=Num(1.0, 10000.0),
                      help="Stock file: the printer's E steps/mm (M92 E), until an M92 E in the "
                           "G-code changes it [the printer model's; Marlin's defaults: "
                           f"{_fmt_num(DEFAULT_E_STEPS)}].")(fn)
    fn = click.option("--stop", "stop_kind", type=click.Choice(["move", "g4"]), default="move",
                      show_default=True,
                      help="Stock file: each stop as an extruder-only move (queued, no planner "
                           "drain, exact to the millisecond) or as G4 P<ms> (the paper's rewrite).")(fn)
    return printer_options(fn)


def _fmt_num(v: float) -> str:
    return f"{v:g}"


def _stops(stop_kind, e_steps, stop_e_steps, printer=None, firmware=None, gcode=None) -> StockStops:
    """How the stock file writes its stops, for the printer model (--printer, --firmware, then
    the G-code's own settings before its first extrusion)."""
    pm = printer_model(printer, firmware, gcode)
    try:
        return StockStops(stop_kind, e_steps, stop_e_steps, pm)
    except ValueError as e:        # values from a placement file's [bulges]
        raise click.BadParameter(str(e), param_hint="'--stop', '--e-steps' or '--stop-e-steps'") from None


def _braille_check(strokes, settings: Settings, spacing, line_width):
    """The check that a print can make readable braille dots, when there is braille to place."""
    from ..bulge.braille import wall_check
    return wall_check(strokes, settings.dwell_ms, spacing, line_width)


def _arena_option(fn):
    return click.option("--arena", type=click.IntRange(min=1), default=mapformat.ARENA_BYTES,
                        show_default=True,
                        help="Printer's map arena (BK_MAP_ARENA_BYTES), bytes.")(fn)


def _allow_unreached_option(fn):
    return click.option("--allow-unreached", is_flag=True,
                        help="Write the file even if map points are not reached by any move "
                             "(they will not bulge); default: error.")(fn)


# Settings' messages start with the field's name; the option that sets it is named in the error.
_SETTING_OPTION = {"dwell": "--dwell", "extra E": "--extra", "tolerance": "--tolerance"}


def _settings(dwell, extra, tolerance, geometric) -> Settings:
    try:
        return Settings(MODE_GEOMETRIC if geometric else MODE_MARKED, dwell, extra, tolerance)
    except ValueError as e:
        opt = next((o for k, o in _SETTING_OPTION.items() if str(e).startswith(k)), None)
        raise click.BadParameter(str(e), param_hint=f"'{opt}'" if opt else None) from None


def _scanner_words() -> str:
    from .. import gcode
    return {"compiled": "compiled",
            "stale": f"Python only, the compiled one is out of date: {gcode.SCAN_REBUILD}",
            "missing": "Python only, bulgekit.gcode._scan not built: slower on large files"}[gcode.scanner_state()]


class _Main(click.Group):
    """The command group: Ctrl-C (SIGINT) and SIGTERM end any command with one line on stderr
    and exit status 130 or 143, its outputs and its children taken back (bulgekit.outputs);
    bulgekit's warnings are one line each on stderr (warning_lines)."""

    def main(self, *args, **kwargs):
        from .. import outputs
        with outputs.ending(), warning_lines():
            return super().main(*args, **kwargs)


@click.group(cls=_Main, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="bulgekit",
                      message="%(prog)s %(version)s (G-code scanner: " + _scanner_words() + ")")
def main():
    """Bulges on the outer wall of FDM prints (over-extrusion by dwell + extra filament).

    \b
    Typical use:
      bulgekit build part.gcode --text "HELLO" --at 5,3 -o out/
      -> out/part.bkm (bulge map), out/part.bulge.gcode (print this on bulgekit
         firmware), out/part.stats.txt; --fallback adds out/part.stock.gcode for
         stock firmware (each stop an extruder-only move plus the extra E;
         --stop g4 for the paper's G4 dwells).

    Strokes are drawn on the unrolled outer wall: u = mm along the wall,
    counter-clockwise (left to right seen from outside) from the front (-Y) of
    each layer; v = mm above the bed. --face N puts a drawing on face N of the
    wall (its stretches between corners, 1 holding u = 0; the preview numbers
    them). Run `bulgekit demo` for a worked example.
    """


@main.command(short_help="Strokes + sliced G-code -> map, annotated G-code, stats, preview.")
@click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
@click.option("-s", "--strokes", "stroke_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Stroke file: .json stroke list, .svg drawing or an image (dots). Repeatable.")
@click.option("--placement", type=click.Path(exists=True, dir_okay=False),
              help="TOML placement file (text, strokes, [bulges] settings; see examples/placement.toml), "
                   "as `post-process` reads it; options given here win over its [bulges].")
@click.option("--text", help="Write this text on the wall (single-stroke font).")
@click.option("--braille", help="Write this text in braille at --at (liblouis; the standard's "
                                "spacing: dots 2.5 mm, cells 6 mm, lines 10 mm; \\n between lines).")
@click.option("--braille-grade", type=click.IntRange(1, 2), default=1, show_default=True,
              help="Braille grade of Unified English Braille (2: contracted).")
@click.option("--braille-table", metavar="TABLE",
              help="A liblouis table instead of --braille-grade (e.g. de-g2.ctb, fr-bfu-g2.ctb).")
@click.option("--text-size", "--size", "text_size", type=POSITIVE, default=6.0, show_default=True,
              help="Capital height of --text, mm.")
@click.option("--at", callback=pair, metavar="U,V",
              help="U,V mm: where input goes (--text baseline start; stroke files shifted by it, "
                   "an SVG page's / image's lower-left corner), as in `strokes` and `preview`; "
                   "with --face, U is an offset from the aligned place. " + AT_HELP)
@face_options
@click.option("--font", default="futural", show_default=True, help="Hershey font of --text (as in `strokes`).")
@click.option("--letter-spacing", type=FINITE, default=0.0, show_default=True,
              help="Extra mm between letters of --text.")
@click.option("--scale", type=POSITIVE, default=1.0, show_default=True, help="Scale SVG/JSON stroke files.")
@click.option("--image-width", type=POSITIVE, help="Width (mm) on the wall of an image stroke file.")
@click.option("--curve-tolerance", type=POSITIVE, default=0.05, show_default=True,
              help="SVG curve flattening tolerance, mm (--tolerance is M720 T).")
@click.option("--mirror", is_flag=True, help="Mirror --text (paint rollers).")
@click.option("--skip-unsupported", is_flag=True, help="Warn about and skip SVG <text>/<image>.")
@outdir_option()
@click.option("--name", help="Output base name (default: the G-code's name).")
@click.option("--spacing", type=POSITIVE, help="Distance (mm) between points along a layer [2 x line width].")
@click.option("--line-width", type=POSITIVE, default=0.45, show_default=True, help="Outer-wall line width, mm.")
@click.option("--layer-height", type=Num(0.0, 2.0, lo_open=True),
              help="Layer height (mm) if the G-code does not say (its ;layer_height wins).")
@click.option("--ref-angle", type=FINITE, default=-90.0, show_default=True,
              help="Direction (deg, from +X) from the layer centre where u = 0.")
@click.option("--no-stream", is_flag=True, help="Fail instead of streaming a map larger than the printer's arena.")
@click.option("--fallback", "write_fallback", is_flag=True, help="Also write <name>.stock.gcode for stock firmware.")
@click.option("--preview/--no-preview", default=True, show_default=True, help="Write <name>.preview.png.")
@click.option("--preview-3d", is_flag=True, help="Also write <name>.preview3d.png (the walls in 3D).")
@_settings_options
@_stock_options
@progress_option
@friendly
@click.pass_context
def build(ctx, gcode, placement, stroke_files, text, braille, braille_grade, braille_table, text_size, at, face,
          align, font, letter_spacing, scale, image_width, curve_tolerance, mirror, skip_unsupported, outdir,
          name, spacing, line_width, layer_height, ref_angle, no_stream,
          write_fallback, preview, preview_3d, dwell, extra, tolerance, geometric, stop_kind, e_steps,
          stop_e_steps, printer, firmware):
    """Place strokes on GCODE's outer wall: map + annotated G-code + stats."""
    from .. import parallel
    from ..bulge import preview as pv
    # the preview is drawn on a second core while the build works: a child forked first thing
    # (before any thread) imports matplotlib while this process reads the strokes and the file,
    # and draws once the map is placed; it is ended however the command ends
    drawn = parallel.Forked.waiting(pv.warm) if preview else None
    if drawn is not None:
        ctx.call_on_close(drawn.close)
    from ..bulge import api
    from ..bulge.strokes import on_face, text_strokes
    strokes = []
    if placement:
        from ..bulge.placement import load_placement
        pl = load_placement(placement)
        strokes += pl.strokes
        given = lambda p: ctx.get_parameter_source(p) == click.core.ParameterSource.COMMANDLINE
        b = pl.bulges
        dwell = dwell if given("dwell") else b.get("dwell", dwell)
        extra = extra if given("extra") else b.get("extra", extra)
        tolerance = tolerance if given("tolerance") else b.get("tolerance", tolerance)
        geometric = geometric if given("geometric") else b.get("geometric", geometric)
        spacing = spacing if given("spacing") else b.get("spacing", spacing)
        line_width = line_width if given("line_width") else b.get("line_width", line_width)
        write_fallback = write_fallback or b.get("fallback", False)
        stop_kind = stop_kind if given("stop_kind") else b.get("stop", stop_kind)
        e_steps = e_steps if given("e_steps") else b.get("e_steps", e_steps)
        stop_e_steps = stop_e_steps if given("stop_e_steps") else b.get("stop_e_steps", stop_e_steps)
        printer = printer if given("printer") else pl.printer
        firmware = firmware if given("firmware") else b.get("firmware", firmware)
    for f in stroke_files:
        a = at_for(at, f)
        strokes += on_face(api.load_strokes(f, image_width_mm=image_width, offset=a, scale=scale,
                                            curve_tolerance_mm=curve_tolerance,
                                            skip_unsupported=skip_unsupported), face, align, a[0])
    if text:
        a = at_for(at)
        strokes += on_face(text_strokes(text, text_size, spacing=letter_spacing, u0=a[0], v0=a[1],
                                        mirror=mirror, font=font), face, align, a[0])
    if braille:
        from ..bulge.braille import DOT_BASE, braille_strokes
        a = at_for(at)
        if at is None:                      # the dots' domes clear of the first layers too
            a = (a[0], a[1] + DOT_BASE / 2)
        strokes += on_face(braille_strokes(braille.replace("\\n", "\n"), a[0], a[1], braille_grade,
                                           braille_table), face, align, a[0])
    if not strokes:
        raise click.UsageError("nothing to draw: give --strokes FILE, --text TEXT, --braille TEXT "
                               "or --placement FILE")
    settings = _settings(dwell, extra, tolerance, geometric)
    stops = _stops(stop_kind, e_steps, stop_e_steps, printer, firmware, gcode)
    t0 = time.perf_counter()
    stem = name or Path(gcode).stem
    on_map = None
    if drawn is not None:
        def on_map(res):
            args, kw = pv.unrolled_job(res, f"{stem}.bulge.gcode")
            drawn.give(pv.unrolled_png, *args, **kw)
    out = api.build(gcode, strokes, outdir, name=name, spacing=spacing, line_width=line_width,
                    layer_height=layer_height, ref_angle_deg=ref_angle, settings=settings,
                    stream=not no_stream, write_fallback=write_fallback, stops=stops,
                    _on_map=on_map, _check_walls=_braille_check(strokes, settings, spacing, line_width))
    click.echo(out.stats.text(per_layer=False))
    for note in out.result.notes:
        click.echo(f"note: {note}")
    for w in out.result.warnings:
        click.echo(f"warning: {w}", err=True)
    if out.annotate.appends:
        click.echo(f"streaming: {out.annotate.initial_records} layers at the start, "
                   f"{len(out.annotate.appends)} appends while printing")
    click.echo(f"wrote {out.map_path}, {out.gcode_path}, {out.stats_path}"
               + (f", {out.fallback_path}" if out.fallback_path else ""))
    if preview:
        click.echo(f"wrote {pv.build_unrolled(out, Path(outdir) / f'{stem}.preview.png', drawn)}")
    if preview_3d:
        click.echo(f"wrote {pv.build_3d(out, Path(outdir) / f'{stem}.preview3d.png')}")
    click.echo(f"done in {time.perf_counter() - t0:.1f} s")


@main.command("post-process", short_help="For a slicer's post-processing step: annotate a G-code file in place.")
@click.option("--placement", required=True, type=click.Path(exists=True, dir_okay=False),
              help="TOML placement file: what to draw and the bulge settings (examples/placement.toml).")
@_arena_option
@click.option("--keep", type=click.Path(file_okay=False),
              help="Also keep the map and the stats in this folder.")
@click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
@friendly
def post_process(placement, arena, keep, gcode):
    """Annotate GCODE in place with the drawing a placement file describes, for bulgekit
    firmware (M720-M722), or rewrite it for stock firmware when the placement says
    `fallback = true`. Slicers pass the G-code path last:

    \b
      PrusaSlicer / OrcaSlicer / Bambu Studio, Print settings > Output options >
      Post-processing scripts:   /path/to/bulgekit post-process --placement /path/to/placement.toml
      Cura: Extensions > Post Processing > Add a script > bulgekit (integrations/cura/)

    The file is replaced only when everything succeeded; on any error it is left as the slicer
    wrote it, the message goes to stderr and the exit status is 1 (2 for a missing input file,
    named here or in the placement file, as for a bad option: slicers take any other than 0 as
    a failure)."""
    import shutil

    from .. import outputs
    from ..bulge import api
    from ..bulge.mapbuild import DEFAULT_LINE_WIDTH
    from ..bulge.placement import PlacementError, load_placement

    pl = load_placement(placement)
    b = pl.bulges
    try:
        settings = Settings(MODE_GEOMETRIC if b.get("geometric") else MODE_MARKED,
                            b.get("dwell", DEFAULT_DWELL_MS), b.get("extra", DEFAULT_EXTRA_E_MM),
                            b.get("tolerance", DEFAULT_TOLERANCE_MM))
        stops = StockStops(b.get("stop", "move"), b.get("e_steps"), b.get("stop_e_steps"),
                           printer_model(pl.printer, b.get("firmware"), gcode))
    except ValueError as e:
        raise PlacementError(f"{placement}: bulges: {e}") from None
    src = Path(gcode)
    # built in a scratch folder beside the file, then the result takes the file's place with
    # --keep's files when the command ends: all or nothing (bulgekit.outputs)
    with outputs.scratch(src.parent) as tmp, outputs.Outputs() as staged:
        with outputs.apart():
            lw = b.get("line_width", DEFAULT_LINE_WIDTH)
            out = api.build(src, pl.strokes, tmp, name="pp", spacing=b.get("spacing"),
                            line_width=lw, settings=settings, arena=arena,
                            write_fallback=bool(b.get("fallback")), stops=stops,
                            _check_walls=_braille_check(pl.strokes, settings, b.get("spacing"), lw))
        result = out.fallback_path if b.get("fallback") else out.gcode_path
        if keep:
            staged.folder(keep)
            for p in (out.map_path, out.stats_path):
                outputs.write(Path(keep) / f"{src.stem}{p.suffix}", p.read_bytes())
        shutil.copymode(src, result)
        os.replace(result, staged.part(src))        # (one file system: renamed, not copied)
    for w in out.result.warnings:
        click.echo(f"bulgekit: warning: {w}", err=True)
    s = out.stats
    click.echo(f"bulgekit: {s.points} points on {len(s.layers)} layers "
               f"{'rewritten for stock firmware' if b.get('fallback') else 'annotated'} into {src}"
               + (f" ({s.arcs.arcs} G2/G3 arcs through them as G1 chords)" if s.arcs and s.arcs.arcs else ""))


@main.command(short_help="Add M720/M721/M722 for bulgekit firmware (moves untouched).")
@click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
@click.argument("map_file", metavar="MAP", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Annotated G-code to write.")
@click.option("--no-stream", is_flag=True, help="Fail if the map is larger than the printer's arena.")
@_arena_option
@_allow_unreached_option
@_settings_options
@progress_option
@friendly
def annotate(gcode, map_file, output, no_stream, arena, allow_unreached, dwell, extra, tolerance,
             geometric):
    """Add M720/M721/M722 for the bulgekit firmware to GCODE (moves untouched).

    GCODE is also run through the reference planner: map points that no move
    reaches (a map made for another file) are an error unless --allow-unreached."""
    from ..bulge import annotate as an        # (not the api: none of build's modules, 0.025 s)
    settings = _settings(dwell, extra, tolerance, geometric)
    t0 = time.perf_counter()
    map_bytes, bm = _read_decoded_map(map_file)
    res = an.annotate_gcode(gcode, map_bytes, output, settings, stream=not no_stream, arena=arena,
                            allow_unreached=allow_unreached, _decoded=bm)
    for note in res.notes:
        click.echo(f"WARNING: {note}", err=True)
    dt = time.perf_counter() - t0
    click.echo(f"wrote {output}: {res.lines_added} lines added, {res.markers} markers, "
               f"{res.initial_records} layers uploaded at the start"
               + (f", {len(res.appends)} appends while printing" if res.appends else "")
               + f" ({dt:.2f} s)")
    if res.arcs.arcs:
        click.echo(res.arcs.text())


@main.command(short_help="Rewrite for stock firmware: stops as E-only moves (or G4) + extra E.")
@click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
@click.argument("map_file", metavar="MAP", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="G-code to write.")
@_allow_unreached_option
@_settings_options
@_stock_options
@progress_option
@friendly
def fallback(gcode, map_file, output, allow_unreached, dwell, extra, tolerance, geometric, stop_kind,
             e_steps, stop_e_steps, printer, firmware):
    """Rewrite GCODE for stock firmware: split at each point, stop there (an extruder-only
    move of whole E steps timed to the dwell, or G4 P<ms> with --stop g4), extra E on the
    next piece, G92 E.

    Map points that no move reaches (a map made for another file) are an
    error unless --allow-unreached."""
    from ..bulge import api
    settings = _settings(dwell, extra, tolerance, geometric)
    res = api.fallback_gcode(gcode, _read_map(map_file), output, settings, allow_unreached=allow_unreached,
                             stops=_stops(stop_kind, e_steps, stop_e_steps, printer, firmware, gcode))
    if res.unreached:
        click.echo(f"WARNING: {res.unreached}", err=True)
    st = res.stats
    click.echo(f"wrote {output}: {st.points_fired} stops on {res.moves_split} lines, "
               f"{st.dwell_ms_total / 1000:.1f} s dwell, {st.extra_applied:.2f} mm extra filament")
    click.echo(res.stock.summary())
    if res.stock.arcs.arcs:
        click.echo(res.stock.arcs.text())


@main.command(short_help="M720 settings + M721 upload of a map, for any host.")
@click.argument("map_file", metavar="MAP", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False),
              help="File to write (default: standard output).")
@click.option("--numbered", is_flag=True,
              help="Add N<n> line numbers and *checksums (for terminals that do not).")
@_arena_option
@_settings_options
@friendly
def mcodes(map_file, output, numbered, arena, dwell, extra, tolerance, geometric):
    """The M-code stream that configures the printer and uploads MAP: M720 settings,
    M721 begin/chunks/commit. Send it from Pronterface, OctoPrint or `bulgekit send`
    before printing G-code that carries M722 markers (or none, with --geometric)."""
    from .. import outputs
    settings = _settings(dwell, extra, tolerance, geometric)
    data = _read_map(map_file)
    mapformat.check_upload_fits(data, arena, map_file)
    if numbered:
        # M110 N0 resets the printer's line counter; numbered lines follow from N1
        body = f"N1 {settings.m720()}"
        cs = 0
        for ch in body.encode():
            cs ^= ch
        text = ["M110 N0", f"{body}*{cs}"] + mapformat.upload_lines(data, start_line=2)
    else:
        text = [settings.m720()] + mapformat.upload_lines(data)
    out = "\n".join(text) + "\n"
    if output:
        outputs.write(output, out)
        click.echo(f"wrote {output}: {len(text)} lines ({len(data)} map bytes)")
    else:
        click.echo(out, nl=False)


@main.command(short_help="Points, stops per layer and added print time.")
@click.argument("map_file", metavar="MAP", type=click.Path(exists=True, dir_okay=False))
@click.option("-g", "--gcode", type=click.Path(exists=True, dir_okay=False),
              help="Also run this (unannotated) G-code to count the stops that really happen.")
@_arena_option
@click.option("--accel", type=POSITIVE,
              help="Time the stops' braking and starting as v/a at this acceleration (mm/s^2) "
                   "[the printer model's planner, step by step on Marlin].")
@_settings_options
@printer_options
@progress_option
@friendly
def stats(map_file, gcode, arena, accel, dwell, extra, tolerance, geometric, printer, firmware):
    """Per-layer points, stops and the time bulges add. Warnings (points the G-code's moves do
    not reach) go to stderr, and then the exit status is 1."""
    from ..bulge import stats as st
    settings = _settings(dwell, extra, tolerance, geometric)
    data = _read_map(map_file)
    if gcode:
        from .. import progress
        with progress.phase("statistics", path=gcode):
            s = st.print_stats(gcode, data, settings, arena, accel,
                               printer=printer_model(printer, firmware, gcode))
    else:
        s = st.map_stats(data, settings, arena)
    warned = False
    for line in s.text().splitlines():
        warned |= line.startswith("WARNING:")
        click.echo(line, err=line.startswith("WARNING:"))
    if warned:
        sys.exit(1)


class _UnlistedArgument(click.Argument):
    """An argument kept for old command lines, left out of the usage line."""

    def get_usage_pieces(self, ctx):
        return []


@main.command(short_help="Worked example: text on a sliced cylinder.")
@outdir_option()
@click.argument("old_outdir", cls=_UnlistedArgument, required=False, type=click.Path(file_okay=False))
@click.option("--text", default="BULGE", show_default=True)
@click.pass_context
@friendly
def demo(ctx, outdir, old_outdir, text):
    """Worked example: text on a sliced 40 mm cylinder -> OUTDIR."""
    if old_outdir is not None:  # `bulgekit demo DIR`, the spelling before -o/--outdir
        if ctx.get_parameter_source("outdir") is click.core.ParameterSource.COMMANDLINE:
            raise click.UsageError("give the output folder once, with -o/--outdir")
        outdir = old_outdir
    from ..bulge import api
    from ..bulge.strokes import load_json, text_strokes
    ex = _examples_dir()
    gcode = ex / "cylinder40x20.gcode"
    strokes = text_strokes(text, 6.0, u0=4.0, v0=7.0)
    extra = ex / "wave.json"
    if extra.exists():
        strokes += load_json(str(extra))
    out = api.build(gcode, strokes, outdir, name="demo", write_fallback=True)
    click.echo(out.stats.text(per_layer=False))
    from ..bulge.preview import build_3d, build_unrolled
    png = build_unrolled(out, Path(outdir) / "demo.preview.png")
    png3 = build_3d(out, Path(outdir) / "demo.preview3d.png")
    for p in (out.map_path, out.gcode_path, out.fallback_path, out.stats_path, png, png3):
        if p:
            click.echo(f"wrote {p}")


def _examples_dir() -> Path:
    here = Path(__file__).resolve()
    for up in here.parents:
        cand = up / "examples"
        if (cand / "cylinder40x20.gcode").exists():
            return cand
    raise BulgekitError("demo data not found: run from a bulgekit checkout (examples/cylinder40x20.gcode)")


# preview, send and strokes live in io.py; litho, estimate and studio in their own modules.
from . import estimate, io, litho, printer, studio  # noqa: E402  (needs `main` defined above)

io.register(main)
litho.register(main)
estimate.register(main)
printer.register(main)
studio.register(main)


@main.command(short_help="The paper's calibration prints as one part: dwell series and extra-E stripes.")
@outdir_option()
@click.option("--name", default="calibrate", show_default=True, help="Base name of the outputs.")
@click.option("--stop", "stop_kind", type=click.Choice(["move", "g4"]), default="move", show_default=True,
              help="Stock file: each stop as an extruder-only move or as G4 P<ms>.")
@click.option("--layer-height", type=Num(0.05, 0.6), default=0.2, show_default=True, help="mm.")
@click.option("--line-width", type=Num(0.2, 1.2), default=0.45, show_default=True, help="Wall line width, mm.")
@click.option("--temp", type=click.IntRange(150, 320), default=210, show_default=True, help="Nozzle, °C.")
@click.option("--bed-temp", type=click.IntRange(0, 130), default=60, show_default=True, help="Bed, °C.")
@click.option("--bed", callback=pair, default="180,180", show_default=True, metavar="X,Y",
              help="Bed size, mm: the piece goes in its middle.")
@printer_options
@friendly
def calibrate(outdir, name, stop_kind, layer_height, line_width, temp, bed_temp, bed, printer, firmware):
    """Print this to choose the dwell and the extra filament for your printer and filament: one
    box, 140 x 20 x 41 mm, whose front face carries the over-extrusion paper's two tests, each
    value written under it in raised digits.

    \b
      A (bottom): single bumps at dwells of 0, 10, 20, 50, 100, 150, 200, 300 and 500 ms
      B (top):    bands at extra filament 0, 0.05, 0.1, 0.2 and 0.5 mm: 3 lines along the
                  layers and 10 across them, at 100 ms stops

    \b
    Writes to OUTDIR/:
      NAME.bulge.gcode   for bulgekit firmware (M720 P510: each dwell a map weight; M720 E per band)
      NAME.stock.gcode   for stock firmware, the stops written in for the printer model (--printer)
      NAME.bkm           the map
      NAME.png           the front face: what to look for

    Then: bulgekit firmware `M720 P<dwell> E<extra>` and `M500`; stock firmware: --dwell and
    --extra of build (or dwell and extra in a placement's [bulges])."""
    from ..bulge import calibrate as cal
    pm = printer_model(printer, firmware)
    o = cal.CalibrationOptions(printer=pm, layer_height=layer_height, line_width=line_width,
                               temp=temp, bed_temp=bed_temp, bed=tuple(bed))
    r = cal.make(o, outdir, name, stop_kind)
    click.echo(f"printer: {pm.describe()}")
    click.echo(f"{len(r.layout.strokes)} strokes, {r.stops_stock} stops in {r.layout.height:g} mm "
               f"({int(round(r.layout.height / layer_height))} layers)")
    click.echo(f"stock file: {r.stock_summary}")
    if "as G4" in r.stock_summary and pm.firmware == "marlin":
        click.echo("note: on stock Marlin a G4 stop holds the head 100-110 ms longer than its P (the "
                   "planner waits for moves after it): read the stock piece's 300 and 500 ms columns "
                   "and its 0 and 0.05 mm bands as longer; the bulgekit file's values are exact")
    for k in ("bulge", "stock", "map", "png"):
        click.echo(f"wrote {r.paths[k]}")
    click.echo(f"look at {r.paths['png'].name}, print, then: M720 P<dwell> E<extra> and M500 (bulgekit "
               "firmware), or --dwell/--extra (stock firmware)")
