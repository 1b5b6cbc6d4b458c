"""CLI command `estimate`: print time of a G-code file as Marlin 2.1 plans it.

cli/__init__.py calls register(main) to add it to the bulgekit command group.
"""
from __future__ import annotations

import click

from ._util import POSITIVE, friendly, printer_model, printer_options


def _jerk(ctx, param, value):
    if value is None:
        return None
    try:
        x, y, z, e = (float(t) for t in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected four numbers X,Y,Z,E (mm/s), got {value!r}") from None
    if min(x, y, z, e) <= 0:
        raise click.BadParameter(f"jerk values must be > 0, got {value!r}")
    return {"X": x, "Y": y, "Z": z, "E": e}


def register(main):
    @main.command(short_help="Print time of a G-code file, planned as Marlin 2.1 plans it.")
    @click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
    @click.option("--accel", type=POSITIVE, help="M204 P, mm/s^2 [the printer model's].")
    @click.option("--travel-accel", type=POSITIVE, help="M204 T, mm/s^2 [the printer model's].")
    @click.option("--retract-accel", type=POSITIVE, help="M204 R, mm/s^2 [the printer model's].")
    @click.option("--jd", type=POSITIVE, help="Junction deviation (M205 J), mm [the printer model's].")
    @click.option("--jerk", callback=_jerk, default=None,
                  help="Classic jerk X,Y,Z,E (mm/s) instead of junction deviation.")
    @click.option("--lookahead", type=click.IntRange(min=0),
                  help="Planner blocks (BLOCK_BUFFER_SIZE); 0: plan with the whole file "
                       "[the printer model's: 16 on Marlin].")
    @click.option("--honour-file-limits", is_flag=True,
                  help="Apply the file's own M201/M203/M204/M205 wherever they stand (slicers "
                       "write them; those before the first extrusion always apply).")
    @click.option("--e-steps", type=POSITIVE,
                  help="E steps/mm (M92 E; an M92 E in the file wins): whole steps of moves of E "
                       "alone, such as a stock file's stops [the printer model's].")
    @printer_options
    @friendly
    def estimate(gcode, accel, travel_accel, retract_accel, jd, jerk, lookahead, honour_file_limits,
                 e_steps, printer, firmware):
        """Estimate GCODE's print time: trapezoids with acceleration, per-axis limits, junction
        deviation or classic jerk, the planner's look-ahead, dwells, all from the printer model
        (--printer; Marlin's defaults: 300/300/5/25 mm/s, 3000/3000/100/10000 mm/s^2, JD 0.013);
        width mode (M723) as our firmware does it. Prints the total and the time per feature
        (;TYPE: comments)."""
        from ..bulge import forktime
        from ..gcode import estimate as es

        pm = printer_model(printer, firmware, gcode, e_steps)
        over = {k: v for k, v in (("accel", accel), ("travel_accel", travel_accel),
                                  ("retract_accel", retract_accel), ("junction_deviation", jd))
                if v is not None}
        if jerk is not None:
            over["jerk"] = jerk
        if lookahead is not None:
            over["lookahead"] = lookahead or None
        m = es.Machine.from_model(pm, honour_file_limits=honour_file_limits, **over)
        fork = None
        if forktime.is_annotated(gcode):          # a map upload: the fork's stops go in
            fork = forktime.estimate_annotated(gcode, m, pm)
            r = fork.result
        else:
            r = es.estimate_file(gcode, m, blocks=False)
        click.echo(f"printer: {pm.describe()}")
        if fork is not None:
            click.echo(fork.summary())
            for note in fork.notes:
                click.echo(f"note: {note}")
        click.echo(f"{gcode}: {r.summary()} ({r.total_s:.1f} s; {r.n_blocks} moves, "
                   f"dwell {r.dwell_s:.1f} s, filament {es.deposited_filament(r):.1f} mm)")
        width = max((len(k) for k in r.by_feature), default=0)
        for k, v in sorted(r.by_feature.items(), key=lambda kv: -kv[1]):
            click.echo(f"  {k or '(no ;TYPE:)':<{max(width, 12)}} {v:10.1f} s  {100 * v / r.total_s:5.1f} %")
