"""CLI command `litho`: a picture -> a lithophane printed in width mode, with its stock-firmware
twin, the body as an STL, the predicted backlit look and the figures.

cli/__init__.py calls register(main) to add it to the bulgekit command group.
"""
from __future__ import annotations

import math

import click

from ._util import NONNEG, POSITIVE, friendly, outdir_option, printer_model, printer_options, progress_option


def _bed(ctx, param, value):
    """--bed X,Y[,Z] (or 220x220x250)."""
    try:
        parts = [float(t) for t in value.replace("x", ",").split(",")]
    except ValueError:
        raise click.BadParameter(f"expected X,Y or X,Y,Z in mm, got {value!r}") from None
    if len(parts) not in (2, 3) or not all(math.isfinite(p) and p > 0 for p in parts):
        raise click.BadParameter(f"expected two or three sizes > 0 mm (X,Y[,Z]), got {value!r}")
    return tuple(parts)


def register(main):
    @main.command(short_help="A picture -> lithophane G-code (width mode + stock), STL, look, stats.")
    @click.argument("image", type=click.Path(exists=True, dir_okay=False), required=False)
    @click.option("--calibration", is_flag=True,
                  help="No picture: a calibration plate, ten steps from --min to --max with their "
                       "thickness written under them, to choose --attenuation for a filament.")
    @click.option("--shape", type=click.Choice(["planar", "cylinder", "arc"]), default="planar", show_default=True,
                  help="Flat plate (flat back, on a foot), a cylinder (round back, picture around it) or an "
                       "arc: a curved panel, part of a cylinder (--angle), that stands by itself.")
    @outdir_option("--out")
    @click.option("--name", help="Base name of the outputs (default: the picture's name).")
    @click.option("--width", type=POSITIVE, default=None,
                  help="Planar: plate width, mm [100, or from --height and the picture's aspect].")
    @click.option("--diameter", type=POSITIVE, default=54.8, show_default=True,
                  help="Cylinder, arc: outer diameter at the thickest point, mm.")
    @click.option("--height", type=POSITIVE, default=None,
                  help="Picture height, mm (default: from its aspect ratio, at most the bed's height). "
                       "The picture keeps its aspect: given with --width or --angle it is cropped, on a "
                       "cylinder alone it sets the angle the picture covers.")
    @click.option("--angle", type=POSITIVE, default=None,
                  help="Degrees of the circle: an arc's [120]; on a cylinder the part the picture covers "
                       "[all round, or what --height leaves], the rest plain at --min.")
    @click.option("--stretch", is_flag=True,
                  help="Stretch the picture to the size given instead of cropping it to keep its aspect.")
    @click.option("--min", "min_thickness", type=POSITIVE, default=0.8, show_default=True,
                  help="Thickness for white, mm (at least two wall lines).")
    @click.option("--max", "max_thickness", type=POSITIVE, default=2.4, show_default=True,
                  help="Thickness for black, mm.")
    @click.option("--invert", is_flag=True, help="Light areas thick (a negative).")
    @click.option("--curve", type=click.Choice(["perceptual", "linear", "transmission"]), default="perceptual",
                  show_default=True,
                  help="Tone curve: perceptual = backlit lightness (L*) linear in the picture's L*; "
                       "linear = thickness linear in 1 - sRGB value (the paper's); transmission = "
                       "backlit luminance linear in the picture's luminance.")
    @click.option("--gamma", type=POSITIVE, default=1.0, show_default=True,
                  help="Contrast: darkness ** gamma before the curve, darkness on the curve's own "
                       "scale (1 - L*/100, 1 - value, 1 - luminance); > 1 lightens mid-tones.")
    @click.option("--attenuation", type=POSITIVE, default=1.5, show_default=True,
                  help="Light attenuation of the filament, 1/mm (Beer-Lambert), for the perceptual "
                       "and transmission curves and the predicted look; measure it with --calibration.")
    @click.option("--frame", type=NONNEG, default=0.0, show_default=True,
                  help="Border at full thickness, mm (planar: all four sides; cylinder: top and bottom).")
    @click.option("--foot", type=NONNEG, default=None,
                  help="Planar: depth of the foot block under the plate, mm (0: none). Default: an "
                       "eighth of the picture's height, at least 6 mm, so the part stands; a "
                       "cylinder stands by itself and gets none.")
    @click.option("--foot-height", type=NONNEG, default=3.0, show_default=True, help="Foot height, mm.")
    @click.option("--layer-height", type=POSITIVE, default=0.2, show_default=True, help="mm; one picture row per layer.")
    @click.option("--line-width", type=POSITIVE, default=0.4, show_default=True, help="Wall line width, mm.")
    @click.option("--pitch", type=POSITIVE, default=0.4, show_default=True,
                  help="Distance between samples along a layer, mm.")
    @click.option("--min-line", type=POSITIVE, default=None,
                  help="Narrowest mid-line, mm; where the gap between the walls is narrower, see "
                       "--light-gaps. Default: the narrowest line laid at --max-speed "
                       "(flow / (max-speed x layer height), 0.27 mm at the defaults) but at least half "
                       "a line width, so that no piece is capped.")
    @click.option("--max-line", type=POSITIVE, default=1.6, show_default=True,
                  help="Widest single mid-line, mm; wider gaps get two or more.")
    @click.option("--light-gaps", type=click.Choice(["mid-line", "walls"]), default="mid-line",
                  show_default=True,
                  help="Where the gap between the walls is narrower than --min-line (light tones): "
                       "mid-line = the walls narrow (to half a line width at least) so that a thin "
                       "mid-line runs on through light areas at the mid-line's rate; walls = the two "
                       "walls widen and share the gap at their own rate, and the mid-line stops there.")
    @click.option("--rate-accel", type=NONNEG, default=1000.0, show_default=True,
                  help="Acceleration the mid-line's speed changes are planned for, mm/s² (with "
                       "--light-gaps mid-line): where the picture changes faster than the head can "
                       "follow at a steady extruder rate, the walls (half to one and a half line "
                       "widths) take the difference. The thickness is the same; 0: off.")
    @click.option("--accel", type=POSITIVE, default=None,
                  help="The printer's print acceleration, mm/s² (M204 P) [the printer model's; "
                       "Marlin's default 3000; on Klipper its max_accel_to_decel, max_accel x "
                       "(1 - minimum_cruise_ratio), which its look-ahead plans the mid-line's "
                       "speed changes with]. "
                       "Printed times assume it; below 3000 the mid-line's default flow is lower "
                       "(see --infill-flow) and --rate-accel is held to it. The file does not set it.")
    @click.option("--block-rate", type=NONNEG, default=120.0, show_default=True,
                  help="Moves per second the printer's board plans: no piece is shorter than its "
                       "speed / this (samples merge). 120 suits an 8-bit ATmega2560 streaming from "
                       "the host; a 32-bit board: 2000; 0: off (pieces still at least 0.075 mm).")
    @click.option("--filament", type=POSITIVE, default=None,
                  help="Filament diameter, mm [the printer model's: 1.75].")
    @click.option("--wall-speed", type=POSITIVE, default=40.0, show_default=True, help="Walls, mm/s.")
    @click.option("--infill-flow", type=POSITIVE, default=None,
                  help="The mid-line's constant volumetric rate, mm^3/s (head speed = flow / (W * H)). "
                       "Default: 8, or 8 x sqrt(accel / 3000) on a printer given an --accel below "
                       "3000 (4.62 at 1000), so that the ramps where the mid-line starts and stops "
                       "stay as short a share of its time.")
    @click.option("--paper-rate", is_flag=True,
                  help="Mid-line at the walls' own rate (line width x layer height x wall speed), "
                       "the paper's literal setting; slower.")
    @click.option("--max-speed", type=POSITIVE, default=150.0, show_default=True,
                  help="Head speed cap for narrow mid-line pieces, mm/s (M723 U).")
    @click.option("--min-speed", type=POSITIVE, default=5.0, show_default=True, help="M723 L, mm/s.")
    @click.option("--first-layer-speed", type=POSITIVE, default=20.0, show_default=True,
                  help="Walls of the first layer, mm/s; its mid-line flow scales by the same ratio.")
    @click.option("--travel-speed", type=POSITIVE, default=150.0, show_default=True, help="mm/s.")
    @click.option("--retract", type=NONNEG, default=0.8, show_default=True,
                  help="Retraction before travels longer than 2 mm, mm of filament.")
    @click.option("--retract-speed", type=POSITIVE, default=35.0, show_default=True, help="mm/s.")
    @click.option("--temp", type=click.IntRange(150, 320), default=210, show_default=True, help="Nozzle, °C.")
    @click.option("--bed-temp", type=click.IntRange(0, 130), default=60, show_default=True, help="Bed, °C.")
    @click.option("--bed", default="220,220,250", show_default=True, callback=_bed,
                  help="Printer's bed X,Y and height Z, mm; the part must fit.")
    @click.option("--words", type=click.Choice(["e", "w"]), default="e", show_default=True,
                  help="Litho file: mid-line width as E (previews show it; prints on any firmware) "
                       "or as W words (bulgekit firmware only).")
    @click.option("--start-gcode", type=click.Path(exists=True, dir_okay=False), default=None,
                  help="File replacing the default start G-code ({temp}, {bed_temp} filled in).")
    @click.option("--end-gcode", type=click.Path(exists=True, dir_okay=False), default=None,
                  help="File replacing the default end G-code.")
    @click.option("--no-purge", is_flag=True, help="No purge line before the part.")
    @printer_options
    @progress_option
    @friendly
    def litho(image, calibration, shape, outdir, name, no_purge, printer, firmware, **kw):
        """Make a lithophane from IMAGE (any picture Pillow reads; sRGB, taken as its luminance),
        or with --calibration a step wedge to measure the filament's --attenuation.

        Printed standing, one picture row per layer: per layer a wall inside the back face, a wall
        inside the relief face, and ONE mid-line whose width is the gap between them at every
        point (Jang & Hong 2017, Algorithm 1). In width mode (M723) the firmware keeps the
        extruder at one rate and sets the width by head speed.

        \b
        Writes to OUTDIR/:
          NAME.litho.gcode        for bulgekit firmware (M723 width mode)
          NAME.stock.gcode        for stock firmware (eq. 2: E and F per piece, same motion)
          NAME.stl                the same body, watertight (for slicer comparisons)
          NAME.transmission.png   the picture, its predicted backlit look, the same stretched
          NAME.litho.json         layers, moves, filament, time, fill, caps, the look in L*

        \b
        Examples:
          bulgekit litho photo.jpg -o out/
          bulgekit litho photo.jpg --shape cylinder --diameter 80 --height 60 -o out/
          bulgekit litho photo.jpg --curve linear --frame 3 --foot 8 -o out/
          bulgekit litho --calibration -o out/       # out/calibration.*: print it, look through it
        """
        from .. import litho as lt
        from .. import progress

        if calibration == (image is not None):
            raise click.UsageError("give a picture (IMAGE) or --calibration, not both" if calibration
                                   else "missing IMAGE (a picture), or --calibration for a step wedge")
        if calibration:
            # the plate has its own size, steps and border: say so rather than ignore these
            ctx = click.get_current_context()
            for p in ("width", "height", "diameter", "angle", "stretch", "curve", "gamma", "invert", "frame"):
                if ctx.get_parameter_source(p) == click.core.ParameterSource.COMMANDLINE:
                    why = ("its size and border are fixed" if p in ("width", "height", "angle", "frame", "stretch")
                           else "no picture")
                    raise click.UsageError(f"--{p} does not apply to --calibration ({why})")
        kw["bed"] = tuple(kw["bed"])
        pm = printer_model(printer, firmware)
        kw["accel"] = pm.rate_accel if kw["accel"] is None else kw["accel"]
        kw["filament"] = pm.filament_diameter if kw["filament"] is None else kw["filament"]
        opts = lt.LithoOptions(shape=shape, purge=not no_purge, printer=pm, **kw)

        def show(done, total):
            if progress.enabled():
                click.echo(f"\rplanning layers: {done}/{total}", err=True, nl=done == total)

        res = lt.make(image, outdir, name=name, progress=show, options=opts)
        s = res.stats
        if s.get("picture"):
            click.echo(s["picture"]["note"])
        click.echo(summary(s))
        if "calibration" in s:
            click.echo(calibration_table(s))
        for key in ("gcode", "stock", "stl", "png", "json"):
            click.echo(f"wrote {res.paths[key]}")


def summary(s: dict) -> str:
    """A few lines a user reads after `bulgekit litho`."""
    est = s.get("estimate", {})
    t = est.get("estimated_time_s_gcode")
    tt = f"{int(t // 3600)}h {int(t % 3600 // 60):02d}m" if t is not None else "n/a"
    m = est.get("machine")
    if m:
        look = "whole file" if m["lookahead_blocks"] is None else f"{m['lookahead_blocks']} blocks"
        corner = (f"junction deviation {m['junction_deviation_mm']:g} mm" if m["classic_jerk"] is None
                  else "classic jerk " + "/".join(f"{j:g}" for j in m["classic_jerk"]) + " mm/s")
        tt += f" (acceleration {m['accel_mm_s2']:g} mm/s², {corner}, look-ahead {look})"
    ml, gp, lk, wl = s["mid_line"], s["gaps"], s["look"], s.get("walls")
    return "\n".join([
        f"{s['name']}: {s['shape']}, {s['layers']} layers, picture {s['size_mm']['picture_width']:g} x "
        f"{s['size_mm']['picture_height']:g} mm" + _foot(s.get("options", {})),
        f"  estimated time {tt}",
        f"  filament {s['filament_mm'] / 1000:.2f} m, fill ratio {s['fill_ratio']:.3f}, "
        f"{s['extruding_moves']} extruding moves",
        f"  mid-line at {s['rates']['mid_line_mm3_s']:g} mm^3/s{_lowered(s['rates'])}: capped at --max-speed "
        f"{100 * ml['capped_time_share']:.1f} % of its time; layers with 2+ mid-lines: "
        f"{ml['layers_with_two_or_more']}",
        *([f"  walls (mm, median and range): back {wl['back_mm']['median']:.3f} ({wl['back_mm']['min']:.2f}-"
           f"{wl['back_mm']['max']:.2f}), front {wl['front_mm']['median']:.3f} ({wl['front_mm']['min']:.2f}-"
           f"{wl['front_mm']['max']:.2f})"] if wl else []),   # a JSON from before this field has none
        f"  gaps narrower than a mid-line: walls narrowed for a thin mid-line at "
        f"{100 * gp['narrowed_share']:.2f} % of samples, shared by the walls at {100 * gp['shared_share']:.2f} %",
        *_versus(lk),
        *_stands(s.get("stands")),
    ])


def _versus(lk: dict) -> list:
    v = lk.get("picture_vs_print")
    if not v:
        return [f"  the plate shows L* {lk['plate_L_range'][0]:.0f}-100 ({lk['curve']} curve)"]
    ssim = "n/a" if v["ssim_L"] is None else format(v["ssim_L"], ".2f")
    return [f"  picture vs the print as sampled ({v['sampled_mm'][0]:g} x {v['sampled_mm'][1]:g} mm, light "
            f"scatter {v['scatter_sigma_mm']:g} mm, L* {lk['plate_L_range'][0]:.0f}-100, {lk['curve']} curve; "
            f"a model, not a measured print): mean |dL*| {v['mean_abs_dL']:.1f}, SSIM {ssim}"]


def _stands(st) -> list:
    if not st:
        return []
    return [f"  stands: centre of mass {st['footprint_margin_mm']:.1f} mm inside its footprint, tips when leaned "
            f"{st['tip_angle_deg']:.1f} degrees" if st["stands"] else
            f"  does NOT stand: centre of mass {-st['footprint_margin_mm']:.1f} mm outside its footprint"]


def calibration_table(s: dict) -> str:
    """The calibration plate's steps and how bright each should look at this --attenuation."""
    c = s["calibration"]
    rows = [f"  step  thickness mm  luminance (thinnest = 1)  L* at --attenuation {c['attenuation_per_mm']:g}"]
    for st in c["steps"]:
        rows.append(f"  {st['step']:>4}  {st['planned_mm']:>12.2f}  {st['relative_luminance']:>24.3f}  "
                    f"{st['predicted_L']:>6.1f}")
    return "\n".join(rows)


def _lowered(rates: dict) -> str:
    a = rates.get("mid_line_lowered_for_accel_mm_s2")
    return (f" (lowered for --accel {a:g}: a steadier extruder rate, a longer print; --infill-flow "
            f"sets it)") if a else ""


def _foot(o: dict) -> str:
    if not o.get("foot") or not o.get("foot_height"):
        return ""
    return f", on a foot {o['foot']:g} mm deep and {o['foot_height']:g} mm tall (--foot 0: none)"
