"""CLI commands for inputs and outputs: `strokes`, `preview`, `send`.

cli/__init__.py calls register(main) to add them to the bulgekit command group.
"""
from __future__ import annotations

import sys
from pathlib import Path

import click

from ..bulge import mapformat as _mapformat
from ._util import AT_HELP, FINITE, NONNEG, POSITIVE, Num, at_for, face_options, friendly, pair

_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".gif", ".tif", ".tiff", ".webp"}


def _stroke_options(fn):
    opts = [
        click.option("--text", help="Lettering in a single-stroke Hershey font."),
        click.option("--size", "--text-size", "text_size", type=POSITIVE, default=6.0, show_default=True,
                     help="Capital height of --text, mm."),
        click.option("--font", default="futural", show_default=True, help="Hershey font of --text."),
        click.option("--letter-spacing", type=FINITE, default=0.0, show_default=True,
                     help="Extra mm between letters of --text."),
        click.option("--at", callback=pair,
                     help="U,V mm: where input goes (text baseline start, SVG/image lower-left). "
                          + AT_HELP),
        click.option("--scale", type=POSITIVE, default=1.0, show_default=True, help="Scale SVG/JSON input."),
        click.option("--mirror", is_flag=True, help="Mirror left-right (paint rollers)."),
        click.option("--curve-tolerance", "curve_tolerance", type=POSITIVE, default=0.05,
                     show_default=True, help="SVG curve flattening tolerance, mm."),
        click.option("--dot-radius", type=NONNEG, default=1.0, show_default=True,
                     help="SVG circles up to this radius (mm) become single dots."),
        click.option("--skip-unsupported", is_flag=True, help="Warn about and skip SVG <text>/<image>."),
        click.option("--image-width", type=POSITIVE, help="Width on the wall (mm) of image input."),
        click.option("--pitch", type=POSITIVE, default=1.5, show_default=True, help="Image dot grid pitch, mm."),
        click.option("--threshold", type=Num(0.0, 1.0), default=0.1, show_default=True,
                     help="Image cells lighter than this darkness (0..1) get no dot."),
        click.option("--invert", is_flag=True, help="Image: light areas get the dots."),
    ]
    for o in reversed(opts):
        fn = o(fn)
    return fn


def collect_strokes(inputs, text, text_size, font, letter_spacing, at, scale, mirror, curve_tolerance, dot_radius,
                    skip_unsupported, image_width, pitch, threshold, invert):
    """Strokes from files (by extension) and --text, placed at `at`."""
    from ..bulge import strokes as st
    out = []
    given = at
    for f in inputs:
        at = at_for(given, f)
        ext = Path(f).suffix.lower()
        if ext == ".svg":
            out += st.load_svg(f, offset=at, scale=scale, tolerance_mm=curve_tolerance, dot_radius_mm=dot_radius,
                               mirror=mirror, skip_unsupported=skip_unsupported)
        elif ext == ".json":
            out += st.load_json(f, offset=at, scale=scale, mirror=mirror)
        elif ext in _IMAGE_EXT:
            if not image_width:
                raise st.InputError(f"{f}: an image needs its width on the wall: --image-width MM")
            out += st.image_dots(f, image_width, u0=at[0], v0=at[1], pitch_mm=pitch, threshold=threshold,
                                 invert=invert, mirror=mirror)
        else:
            raise st.InputError(f"{f}: unknown input type {ext or '(no extension)'!r}; "
                                f"use .svg, .json or an image ({', '.join(sorted(_IMAGE_EXT))})")
    if text is not None:
        at = at_for(given)
        out += st.text_strokes(text, text_size, spacing=letter_spacing, u0=at[0], v0=at[1], mirror=mirror,
                               font=font)
    return out


def _summary_text(strokes) -> str:
    from ..bulge.strokes import summarize
    s = summarize(strokes)
    u, v = s["u_range"], s["v_range"]
    weights = sorted({x.weight for x in strokes})
    wtxt = str(weights[0]) if len(weights) == 1 else f"{weights[0]}..{weights[-1]}"
    return (f"{s['strokes']} strokes ({s['dots']} dots), {s['points']} points, "
            f"{s['length_mm']:.1f} mm of line; u {u[0]:.2f}..{u[1]:.2f} mm, v {v[0]:.2f}..{v[1]:.2f} mm; "
            f"weight {wtxt}")


def register(group: click.Group) -> None:
    """Add `strokes`, `preview` and `send` to the CLI group."""

    @group.command("strokes", short_help="Convert SVG / text / JSON / image to a strokes JSON.")
    @click.argument("inputs", nargs=-1, type=click.Path(exists=True, dir_okay=False))
    @_stroke_options
    @click.option("-o", "--output", type=click.Path(dir_okay=False),
                  help="Strokes JSON to write (see docs/inputs.md). Without it only the summary is printed.")
    @friendly
    def strokes_cmd(inputs, output, **kw):
        """Read INPUTS (.svg, .json, images) and/or --text, print a summary, write -o JSON.

        u runs along the wall (mm), v is the height above the bed (mm).
        """
        from ..bulge.strokes import save_json
        if not inputs and kw["text"] is None:
            raise click.UsageError("give input files and/or --text")
        strokes = collect_strokes(inputs, **kw)
        click.echo(_summary_text(strokes))
        if output:
            save_json(strokes, output)
            click.echo(f"wrote {output}")

    @group.command("preview", short_help="PNG of the bulges: unrolled wall or 3D.")
    @click.argument("gcode", required=False, type=click.Path(exists=True, dir_okay=False))
    @click.option("-s", "--strokes", "inputs", multiple=True, type=click.Path(exists=True, dir_okay=False),
                  help="Stroke input (.svg, .json, image). Repeatable.")
    @click.option("--map", "map_file", type=click.Path(exists=True, dir_okay=False),
                  help="Show this bulge map (.bkm) instead of strokes (needs GCODE).")
    @_stroke_options
    @face_options
    @click.option("--3d", "three_d", is_flag=True, help="3D view of the walls (needs GCODE).")
    @click.option("--wall-length", type=POSITIVE, help="Without GCODE: unrolled wall length, mm.")
    @click.option("--height", type=POSITIVE, help="Without GCODE: wall height, mm.")
    @click.option("--spacing", type=POSITIVE, help="Point spacing along strokes, mm [pipeline default / 1.0].")
    @click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="PNG to write.")
    @friendly
    def preview_cmd(gcode, inputs, map_file, three_d, wall_length, height, spacing, output, face, align,
                    **kw):
        """Draw where the bulges go.

        \b
        With GCODE: strokes (or --map) are placed on its outer walls as the
        `build` command would, shown unrolled or, with --3d, on the part.
        Without GCODE: strokes on a plain wall of --wall-length x --height.
        """
        from ..bulge import preview
        from ..bulge.strokes import sample_strokes
        if map_file and not gcode:
            raise click.UsageError("--map needs the GCODE it was made for")
        strokes = None
        if not map_file:
            if not inputs and kw["text"] is None:
                raise click.UsageError("give -s FILE and/or --text, or --map")
            strokes = collect_strokes(inputs, **kw)
        if (face or align) and not (gcode and strokes):
            raise click.UsageError("--face and --align need GCODE and strokes (the faces are the wall's)")
        if strokes:
            from ..bulge.strokes import on_face
            strokes = on_face(strokes, face, align, at_for(kw["at"])[0])
        if not gcode:
            if three_d:
                raise click.UsageError("--3d needs GCODE (the walls come from the sliced file)")
            if not (wall_length and height):
                raise click.UsageError("without GCODE give --wall-length and --height")
            rows = sample_strokes(strokes, spacing or 1.0)
            r = preview.preview_unrolled(rows, wall_length, height, output, title="Strokes on the unrolled wall")
            click.echo(f"wrote {output}: {r['inside']} points on the wall"
                       + (f", {r['outside']} OUTSIDE it" if r["outside"] else ""))
            return
        from ..bulge import api
        model = api.walls(gcode)
        if map_file:
            from ..bulge import mapformat
            m = mapformat.decode_map(Path(map_file).read_bytes(), source=map_file)
            pts = _map_points(m, model)
        else:
            res = api.build_map(model, strokes, spacing=spacing)
            pts = [(p.x, p.y, p.z, p.u, p.layer, p.weight) for p in res.points]
            for note in res.notes:
                click.echo(f"note: {note}")
            for w in res.warnings:
                click.echo(f"warning: {w}", err=True)
        if three_d:
            walls = [(w.z, w.xy) for w in model.walls]
            r = preview.preview_3d(walls, [(x, y, z, w) for x, y, z, _, _, w in pts], output,
                                   title=Path(gcode).name)
            click.echo(f"wrote {output}: {r['bumps']} bulges on {r['layers']} layers")
        else:
            rows = [(u, model.walls[li].z - model.walls[li].height / 2, w) for _, _, _, u, li, w in pts]
            length = max(w.length for w in model.walls)
            r = preview.preview_unrolled(rows, length, model.v_range[1], output,
                                         title=f"{Path(gcode).name}: unrolled outer wall",
                                         layer_height=model.layer_height,
                                         marks=preview.wall_marks(model))
            click.echo(f"wrote {output}: {r['inside']} bulges")

    @group.command("send", short_help="Stream G-code / M-codes / a map to the printer.")
    @click.argument("files", nargs=-1, type=click.Path(exists=True, dir_okay=False, allow_dash=True))
    @click.option("-p", "--port", required=True, envvar="BULGEKIT_PORT", show_envvar=True,
                  help="Serial device (/dev/ttyUSB0, /dev/ttyACM0, COM3) or pyserial URL (socket://host:port).")
    @click.option("-b", "--baud", type=int, default=115200, show_default=True)
    @click.option("-c", "--command", "commands", multiple=True, help="Send this line first. Repeatable.")
    @click.option("--map", "map_file", type=click.Path(exists=True, dir_okay=False),
                  help="Upload this bulge map (.bkm) with M721 before the files.")
    @click.option("--arena", type=click.IntRange(min=1), default=_mapformat.ARENA_BYTES, show_default=True,
                  help="Printer's map arena (BK_MAP_ARENA_BYTES): a --map larger than it is refused.")
    @click.option("--timeout", type=POSITIVE, default=30.0, show_default=True,
                  help="Seconds to wait for a reply (busy: messages restart it).")
    @click.option("--boot-wait", type=NONNEG, default=2.0, show_default=True,
                  help="Seconds to wait for the board to start after opening the port (0: none).")
    @click.option("--continue-on-error", is_flag=True, help="Go on after a command the printer refuses.")
    @click.option("--progress/--no-progress", default=True, show_default=True)
    @friendly
    def send_cmd(files, port, baud, commands, map_file, arena, timeout, boot_wait, continue_on_error, progress):
        """Send -c commands, then --map, then FILES (- for stdin), line by line with
        line numbers and checksums. Printer messages are shown as they come."""
        from ..printer.sender import Line, Sender, prepare, read_gcode
        batches = []
        if commands:
            batches.append(("commands", prepare([Line(c, f"-c #{i}") for i, c in enumerate(commands, 1)])))
        if map_file:
            from ..bulge import mapformat
            data = Path(map_file).read_bytes()
            mapformat.decode_map(data, source=map_file)
            mapformat.check_upload_fits(data, arena, map_file)
            cmds = mapformat.upload_lines(data)
            batches.append((Path(map_file).name,
                            [Line(c, f"{map_file} upload line {i}") for i, c in enumerate(cmds, 1)]))
        need = None  # (arena an annotated file was made for, the file)
        for f in files:
            if f == "-":
                batches.append(("stdin", prepare(sys.stdin.read().splitlines(), "stdin")))
            else:
                batches.append((Path(f).name, read_gcode(f)))
                a = annotated_arena(f)
                if a is not None and (need is None or a > need[0]):
                    need = (a, f)
        if not batches:
            raise click.UsageError("nothing to send: give FILES, -c COMMAND or --map")

        def show(msg):
            if progress:
                from tqdm import tqdm
                tqdm.write(msg)
            else:
                click.echo(msg)

        with Sender(port, baud, timeout=timeout, boot_wait=boot_wait, on_message=show) as s:
            if need is not None:
                check_printer_arena(s, *need)
            for name, lines in batches:
                if not lines:
                    click.echo(f"{name}: nothing to send")
                    continue
                st = s.send(lines, progress=progress, continue_on_error=continue_on_error, desc=name)
                click.echo(f"{name}: {st.summary()}")
                for src, cmd, why in st.errors:
                    click.echo(f"  refused: {src}: {cmd!r}: {why}")


def annotated_arena(path) -> int | None:
    """The map arena an annotated file was planned for (its "; bulgekit: ...
    arena N" header line, near the top), or None for other files."""
    import re
    with open(path, "rb") as f:
        head = f.read(4096)
    m = re.search(rb"(?m)^; bulgekit: .*\barena (\d+)", head)
    return int(m.group(1)) if m else None


def check_printer_arena(sender, need: int, path) -> None:
    """Before printing an annotated file: the printer's arena (from M721's
    status line) must be at least the one the file was made for. A smaller one
    would refuse a map append in the middle of the print."""
    import re
    from ..printer.sender import PrinterError
    try:
        reply = sender.command("M721", "arena check (M721)")
    except PrinterError as e:
        raise click.ClickException(
            f"{path}: carries a bulge map, but the printer refused M721 ({e}): is it running "
            "bulgekit firmware with BULGE_MAP? For stock firmware use `bulgekit fallback`.") from None
    m = next((re.search(r"bytes:\d+/(\d+)", r) for r in reply if "bytes:" in r), None)
    if m is None:
        raise click.ClickException(
            f"{path}: carries a bulge map, but the printer's M721 reply has no map status "
            f"({' | '.join(reply) or 'nothing'}): is it running bulgekit firmware with BULGE_MAP?")
    have = int(m.group(1))
    if have < need:
        raise click.ClickException(
            f"{path}: was annotated for a {need}-byte map arena, but the printer's is {have} "
            f"(BK_MAP_ARENA_BYTES): its map uploads (the first, or an append mid-print) could be "
            f"refused. Annotate again with "
            f"--arena {have}.")


def _map_points(m, model):
    """(x, y, z, u, layer, weight) of a decoded map's points on the model's walls."""
    import numpy as np
    zs = model.zs
    out = []
    for layer in m.layers:
        z = layer.z_cmm / 100.0
        li = int(np.argmin(np.abs(zs - z)))
        w = model.walls[li]
        pts = m.points_mm(layer)
        weights = layer.weights or (255,) * len(pts)
        for (x, y), wt in zip(pts, weights):
            s, _ = w.project(x, y)
            out.append((x, y, z, float(w.u_of_s(s)), li, wt))
    return out
