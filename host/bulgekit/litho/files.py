"""`make`: every file `bulgekit litho` writes from a picture (G-code, stock G-code, STL, transmission
picture, JSON), written all or nothing."""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

from .. import outputs
from .body import body_mesh, mesh_volume, standing, write_stl
from .calibration import calibration_field
from .gcode import machine_for, machine_words, write_gcode
from .backlit import write_transmission_png
from .options import LithoOptions, options_dict
from .paths import Plan, plan_lithophane
from .picture import picture_words
from .stats import plan_stats


@dataclass
class LithoResult:
    plan: Plan
    paths: dict
    stats: dict


def make(image, outdir, name: str | None = None, progress=None, machine=None, **opts) -> LithoResult:
    """Everything `bulgekit litho` writes, from a picture: NAME.litho.gcode, NAME.stock.gcode,
    NAME.stl, NAME.transmission.png, NAME.litho.json. Options: the fields of LithoOptions.
    image None: the calibration plate (calibration_field), NAME "calibration" by default.
    `progress(done, total)` hears the planning; the later phases (writing each file, the
    estimate) are reported through bulgekit.progress. `machine`: the estimate's
    estimate.Machine (default: machine_for(options), Marlin's RAMPS defaults at `accel`)."""
    from .. import progress as pg

    o = opts.pop("options", None) or LithoOptions(**opts)
    calibration = None
    if image is None:                                   # the calibration plate
        image, calibration = calibration_field(o)
    name = name or ("calibration" if calibration else Path(os.fspath(image)).stem)
    out = Path(outdir)
    plan = plan_lithophane(image, o, progress=progress)
    final = {"gcode": out / f"{name}.litho.gcode", "stock": out / f"{name}.stock.gcode",
             "stl": out / f"{name}.stl", "png": out / f"{name}.transmission.png",
             "json": out / f"{name}.litho.json"}
    m = machine or machine_for(o)
    with outputs.Outputs() as staged:                 # all five files or none (bulgekit.outputs)
        staged.folder(out)
        with pg.phase(f"writing {final['stl'].name}", 1, unit="files"):
            V, F = body_mesh(plan)
            write_stl(V, F, final["stl"], name=f"bulgekit lithophane {name}")
            stl_volume = mesh_volume(V, F)
            stands = standing(V, F)
            del V, F
        times = {}
        # the litho file also with every move planned (Klipper, RepRapFirmware): nothing dropped
        every = dataclasses.replace(m, min_segment_steps=0)
        times["gcode"], times["every"] = write_gcode(plan, final["gcode"], "litho", name, estimate_with=[m, every])
        times["stock"], = write_gcode(plan, final["stock"], "stock", name, estimate_with=[m])
        write_transmission_png(plan, final["png"])
        stats = plan_stats(plan, stl_volume)
        stats["stands"] = stands
        if plan.field.layout is not None:
            stats["picture"] = picture_words(plan.field.layout)
        stats["name"] = name
        stats["image"] = None if calibration else os.fspath(image)
        if calibration:
            stats["calibration"] = calibration
        stats["options"] = options_dict(plan.options)
        stats["estimate"] = {"estimated_time_s_gcode": round(times["gcode"], 1),
                             "estimated_time_s_stock": round(times["stock"], 1),
                             "estimated_time_s_gcode_every_move_planned": round(times["every"], 1),
                             "machine": machine_words(m)}
        outputs.write(final["json"], json.dumps(stats, indent=2) + "\n")
    return LithoResult(plan, final, stats)
