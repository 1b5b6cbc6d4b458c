#!/usr/bin/env python3
"""Lithophane benchmark: `bulgekit litho` against CuraEngine 4.13 and PrusaSlicer 2.5 on the same
bodies, every file timed by one estimator (bulgekit.gcode.estimate). Results: DIR/results.md, .json.

    python3 tools/litho_bench.py --out /tmp/lb                # 3 samples + 3 photos x planar, cylinder
    python3 tools/litho_bench.py --out /tmp/lb --images examples/litho/wedge.png --photos --shapes planar

Pictures: the samples drawn here (examples/litho/) and real photographs as scikit-image's wheel
ships them (skimage.data: astronaut, a portrait; camera, a man with a camera; coffee, a cup on a
table), written as PNGs into OUT/photos/ for this run only (nothing downloaded, nothing kept in
the repository). `--photos` with names picks some of them, `--photos` alone none.

Needs: Debian's `cura-engine` and `prusa-slicer`, and CuraEngine's machine definitions from
Debian's `cura` package (not installed, only unpacked: `apt-get download cura && dpkg-deb -x
cura_*.deb DIR`), found under --cura-defs. Not part of `make test` (it takes minutes).

Terms (issue 18), the same for every method:
  bodies       our NAME.stl: planar 100 mm wide (height from the picture), cylinder 54.8 x 60.5 mm,
               arc 120 degrees of a 54.8 mm circle (height from the picture)
  lines        0.2 mm layers (first layer too), 0.4 mm lines, 1.75 mm filament
  speeds       walls 40 mm/s, infill 100 mm/s, travel 150 mm/s; first layer 20 mm/s (slicers: every
               first-layer move; ours: first-layer walls, mid-line at the same fraction of its rate)
  fill         100 % infill, top and bottom layers 0, no skirt or brim
  start/end    the same two lines for everyone (G90/M83; one retraction at the end): no homing,
               heating or purge is timed
  machine      acceleration 1000 (and 3000) mm/s^2 for printing and travel, junction deviation
               0.013 mm, max feedrate X/Y 300, Z 5, E 25 mm/s; the files' own M201-M205 ignored;
               planned with Marlin's 16-block buffer (the figure with unlimited look-ahead is in
               the JSON)
  ours         `bulgekit litho` at its defaults, made once per acceleration with --accel A (the
               mid-line's default flow follows it: 8 mm^3/s at 3000, 4.62 at 1000)
  metrics      time; fill ratio = filament laid by extruding moves x filament area / STL volume;
               extruding moves; filament; E-rate spread = share of extruding time within +-5 % of
               the median extruder rate. Best baseline = fastest baseline with fill ratio >= 0.95.
  rules        (issue 24, per body and acceleration) speed: on photographs (and pictures named
               by --photo-like) ours >= 25 % shorter than the best baseline; bound: on every
               picture the saving within 3 points of the no-acceleration bound; fill: ours 0.98-1.02.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))

from bulgekit.gcode import estimate as es  # noqa: E402
from bulgekit import litho  # noqa: E402

START = "G90\nM83\n"
END = "G1 E-0.8 F2100\n"
FIL_AREA = math.pi * 1.75 ** 2 / 4

# --- PrusaSlicer 2.5 -------------------------------------------------------------------------
PRUSA_COMMON = {
    "layer_height": 0.2, "first_layer_height": 0.2, "nozzle_diameter": 0.4, "filament_diameter": 1.75,
    "extrusion_width": 0.4, "perimeter_extrusion_width": 0.4, "external_perimeter_extrusion_width": 0.4,
    "infill_extrusion_width": 0.4, "solid_infill_extrusion_width": 0.4, "top_infill_extrusion_width": 0.4,
    "first_layer_extrusion_width": 0.4,
    # 100 % infill is printed as solid infill: its pattern and speed are set to the same values
    "fill_density": "100%", "fill_pattern": "rectilinear", "top_fill_pattern": "rectilinear",
    "bottom_fill_pattern": "rectilinear",
    "top_solid_layers": 0, "bottom_solid_layers": 0, "top_solid_min_thickness": 0, "bottom_solid_min_thickness": 0,
    "skirts": 0, "brim_width": 0,
    "perimeter_speed": 40, "external_perimeter_speed": 40, "small_perimeter_speed": 40,
    "infill_speed": 100, "solid_infill_speed": 100, "top_solid_infill_speed": 100, "gap_fill_speed": 100,
    "travel_speed": 150, "first_layer_speed": 20,
    "retract_length": 0.8, "retract_speed": 35, "retract_before_travel": 2,
    "machine_limits_usage": "ignore", "gcode_flavor": "marlin2", "use_relative_e_distances": 1,
    "layer_gcode": "G92 E0", "start_gcode": START.strip().replace("\n", "\\n"),
    "end_gcode": END.strip(), "bed_shape": "0x0,220x0,220x220,0x220", "max_print_height": 250,
}
PRUSA = {
    "prusa classic 1p + rectilinear": {"perimeters": 1, "perimeter_generator": "classic"},
    "prusa arachne 1p": {"perimeters": 1, "perimeter_generator": "arachne"},
    "prusa arachne 2p": {"perimeters": 2, "perimeter_generator": "arachne"},
    "prusa arachne 3p": {"perimeters": 3, "perimeter_generator": "arachne"},
}

# --- CuraEngine 4.13 (its CLI evaluates no formulas: every derived setting is given) ---------
CURA_COMMON = {
    # our STL already stands on the bed at its place: with centre-is-zero the engine adds no offset
    "machine_width": 220, "machine_depth": 220, "machine_height": 250, "machine_center_is_zero": "true",
    "machine_gcode_flavor": "RepRap (Marlin/Sprinter)", "machine_start_gcode": START.strip(),
    "machine_end_gcode": END.strip(), "machine_nozzle_size": 0.4, "material_diameter": 1.75,
    "layer_height": 0.2, "layer_height_0": 0.2,
    "line_width": 0.4, "wall_line_width": 0.4, "wall_line_width_0": 0.4, "wall_line_width_x": 0.4,
    "skin_line_width": 0.4, "infill_line_width": 0.4, "skirt_brim_line_width": 0.4,
    "initial_layer_line_width_factor": 100,
    "top_layers": 0, "bottom_layers": 0, "initial_bottom_layers": 0, "top_bottom_thickness": 0,
    "top_thickness": 0, "bottom_thickness": 0,
    # 100 %: line distance = line width for lines/zigzag/concentric (the formula Cura's frontend runs)
    "infill_sparse_density": 100, "infill_line_distance": 0.4, "infill_sparse_thickness": 0.2,
    "speed_print": 100, "speed_infill": 100, "speed_topbottom": 100, "speed_wall": 40, "speed_wall_0": 40,
    "speed_wall_x": 40, "speed_travel": 150, "speed_layer_0": 20, "speed_print_layer_0": 20,
    "speed_travel_layer_0": 150, "skirt_brim_speed": 20, "speed_slowdown_layers": 1,
    "adhesion_type": "none", "skirt_line_count": 0,
    "retraction_enable": "true", "retraction_amount": 0.8, "retraction_speed": 35,
    "retraction_retract_speed": 35, "retraction_prime_speed": 35, "retraction_min_travel": 2,
    "acceleration_enabled": "false", "jerk_enabled": "false", "relative_extrusion": "true",
}
CURA = {
    "cura 1 wall + concentric": {"wall_line_count": 1, "wall_thickness": 0.4, "infill_pattern": "concentric"},
    "cura 1 wall + zigzag": {"wall_line_count": 1, "wall_thickness": 0.4, "infill_pattern": "zigzag"},
    "cura 1 wall + lines": {"wall_line_count": 1, "wall_thickness": 0.4, "infill_pattern": "lines"},
    "cura 0 walls + zigzag": {"wall_line_count": 0, "wall_thickness": 0, "infill_pattern": "zigzag"},
}
# photographs from scikit-image's wheel: these three load without a network (others need pooch)
PHOTOS = {"astronaut": "a portrait (colour)", "camera": "a man with a camera (grey)",
          "coffee": "a cup of coffee (colour)"}
SPEED_GOAL, BOUND_POINTS, FILL = 25.0, 3.0, (0.98, 1.02)
OURS = "ours: width mode (bulgekit litho)"
PAPER = "ours at the paper's rate (--paper-rate)"


def write_photos(names, d: Path) -> list[Path]:
    """The named skimage.data photographs as PNGs in d (the wheel's own files, decoded and saved)."""
    try:
        import skimage.data
    except ImportError:
        sys.exit("litho_bench: --photos needs scikit-image (pip install scikit-image)")
    from PIL import Image

    d.mkdir(parents=True, exist_ok=True)
    out = []
    for n in names:
        if n not in PHOTOS:
            sys.exit(f"litho_bench: --photos: {n!r} is not one of {', '.join(PHOTOS)}")
        p = d / f"{n}.png"
        Image.fromarray(getattr(skimage.data, n)()).save(p)
        out.append(p)
    return out


def tone_error(stats: dict):
    """Mean |delta L*| between the picture and the predicted look, from the JSON's `look` block,
    if the generator reports one (None otherwise): the picture against the print as sampled."""
    import re
    lk = stats.get("look", {})
    for k, v in dict(lk, **(lk.get("picture_vs_print") or {})).items():
        if isinstance(v, (int, float)) and re.search(r"mean.*(delta|d)_?l|(delta|d)_?l.*mean", k, re.I):
            return float(v)
    return None


def cura_defs(arg: str | None) -> Path:
    cands = [Path(arg)] if arg else [Path("/usr/share/cura/resources/definitions"),
                                     Path("/work/bench/cura/usr/share/cura/resources/definitions")]
    for c in cands:
        if (c / "fdmprinter.def.json").is_file():
            return c
        if (c / "usr/share/cura/resources/definitions/fdmprinter.def.json").is_file():
            return c / "usr/share/cura/resources/definitions"
    sys.exit("litho_bench: CuraEngine's definitions not found: `apt-get download cura && dpkg-deb -x "
             "cura_*.deb DIR`, then --cura-defs DIR")


def slice_cura(stl: Path, out: Path, extra: dict, defs: Path) -> None:
    s = dict(CURA_COMMON, **extra)
    args = [a for k, v in s.items() for a in ("-s", f"{k}={v}")]
    # settings before -e0 are the machine's, after it extruder 0's (whose defaults, e.g. a
    # 2.85 mm filament, would win otherwise)
    cmd = ["CuraEngine", "slice", "-j", str(defs / "fdmprinter.def.json"), *args, "-e0", *args,
           "-l", str(stl), "-o", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, CURA_ENGINE_SEARCH_PATH=str(defs)))
    if r.returncode != 0 or not out.is_file():
        raise RuntimeError(f"CuraEngine failed on {stl}: {r.stderr[-400:]}")


def slice_prusa(stl: Path, out: Path, extra: dict) -> None:
    ini = out.with_suffix(".ini")
    ini.write_text("".join(f"{k} = {v}\n" for k, v in dict(PRUSA_COMMON, **extra).items()))
    r = subprocess.run(["prusa-slicer", "--export-gcode", "--load", str(ini), "-o", str(out), str(stl)],
                       capture_output=True, text=True)
    if r.returncode != 0 or not out.is_file():
        raise RuntimeError(f"PrusaSlicer failed on {stl}: {(r.stdout + r.stderr)[-400:]}")


def machine(accel: float, lookahead) -> es.Machine:
    return es.Machine(accel=accel, travel_accel=accel, retract_accel=accel, junction_deviation=0.013,
                      max_feedrate=es._axes(300, 300, 5, 25), lookahead=lookahead)


def measure(gcode: Path, stl_volume: float, accels) -> dict:
    out = {}
    for a in accels:
        r = es.estimate_file(gcode, machine(a, 16))
        full = es.estimate_file(gcode, machine(a, None))
        b = r.blocks
        ext = es.extruding(r)
        out[str(int(a))] = {
            "time_s": round(r.total_s, 1), "time_full_lookahead_s": round(full.total_s, 1),
            "fill_ratio": round(es.deposited_filament(r) * FIL_AREA / stl_volume, 4),
            "extruding_moves": int(ext.sum()), "filament_mm": round(es.deposited_filament(r), 1),
            "e_rate_spread": round(es.e_rate_share(r), 4),
            "by_feature_s": {k: round(v, 1) for k, v in r.by_feature.items()},
            # the same without acceleration: each move at its own speed from end to end
            "by_feature_ideal_s": _ideal_by_feature(r),
            "ramp_loss_s": round(float(es.block_times(r).sum() - (b["length"] / b["nominal_speed"]).sum()), 1),
        }
        if "mid-line" in r.features:                      # ours: the mid-line alone, and its hops
            mid = (b["feature"] == r.features.index("mid-line"))
            laid = mid & ext
            t = es.block_times(r)
            out[str(int(a))]["mid_line"] = {
                "laid_s": round(float(t[laid].sum()), 1), "laid_ideal_s": round(float((b["length"] / b["nominal_speed"])[laid].sum()), 1),
                "crossing_s": round(float(t[mid & ~ext].sum()), 1),
                "rate_share_cruise": round(es.e_rate_share(r, mask=mid & (b["layer"] >= 1), ref=_mid_rate(gcode), cruise_only=True), 4),
                "rate_share_planned": round(es.e_rate_share(r, mask=mid & (b["layer"] >= 1), ref=_mid_rate(gcode)), 4),
            }
    return out


def _ideal_by_feature(r) -> dict:
    import numpy as np
    b = r.blocks
    t = np.bincount(b["feature"], weights=b["length"] / b["nominal_speed"], minlength=len(r.features))
    return {r.features[i]: round(float(v), 1) for i, v in enumerate(t) if v > 0}


def _mid_rate(gcode: Path) -> float:
    """Our file's mid-line rate, mm/s of filament, from its options block (the first lines)."""
    from litho_rate import mid_rate
    return mid_rate(gcode.read_text()[:6000])


def body_job(image: Path, shape: str, d: Path, kind: str = "drawn sample", photo: bool = False,
             accels=(3000.0,)) -> dict:
    """Our files and the STL for one body: ours made for each acceleration (`bulgekit litho
    --accel A`, as a user of that printer would), the paper's rate and the STL once (the body
    does not depend on it)."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "start.g").write_text(START)
    (d / "end.g").write_text(END)
    name = f"{image.stem}_{shape}"
    kw = dict(shape=shape, start_gcode=str(d / "start.g"), end_gcode=str(d / "end.g"), purge=False)
    if shape == "cylinder":
        kw.update(height=60.5, stretch=True)        # the picture all round, as the earlier rounds
    res = litho.make(image, d, name=name, **kw)
    ours = {}
    for a in accels:
        if a == res.plan.options.accel:
            ours[str(int(a))] = str(res.paths["gcode"])
        else:
            ra = litho.make(image, d / f"accel{int(a)}", name=name, accel=a, **kw)
            ours[str(int(a))] = str(ra.paths["gcode"])
    litho.make(image, d / "paper", name=name, paper_rate=True, **kw)
    return {"name": name, "stl": str(res.paths["stl"]), "stl_volume": res.stats["stl_volume_mm3"],
            "ours": ours, "paper": str(d / "paper" / f"{name}.litho.gcode"),
            "layers": res.stats["layers"], "stats": res.stats, "kind": kind, "photo": photo}


def method_job(method: str, body: dict, d: Path, defs: Path, accels) -> tuple[str, str, dict]:
    t0 = time.time()
    if method == OURS:                               # each acceleration on the file made for it
        m = {}
        for a in accels:
            m.update(measure(Path(body["ours"][str(int(a))]), body["stl_volume"], [a]))
        m["gcode"] = body["ours"]
        m["seconds_to_run"] = round(time.time() - t0, 1)
        return body["name"], method, m
    elif method == PAPER:
        g = Path(body["paper"])
    else:
        g = d / (method.replace(" ", "_").replace("+", "") + ".gcode")
        if method in CURA:
            slice_cura(Path(body["stl"]), g, CURA[method], defs)
        else:
            slice_prusa(Path(body["stl"]), g, PRUSA[method])
    m = measure(g, body["stl_volume"], accels)
    m["gcode"] = str(g)
    m["seconds_to_run"] = round(time.time() - t0, 1)
    return body["name"], method, m


def fmt_t(s: float) -> str:
    return f"{int(s // 3600)}:{int(s % 3600 // 60):02d}:{int(s % 60):02d}"


def best_baseline(r: dict, a: str):
    ok = {k: v[a] for k, v in r.items() if k not in (OURS, PAPER) and v[a]["fill_ratio"] >= 0.95}
    return (min(ok, key=lambda k: ok[k]["time_s"]), ok) if ok else (None, ok)


def bound_saving(o: dict, best_time: float) -> float:
    """Our saving, % of the best baseline, if every move of ours ran at its own speed end to end."""
    fi = o["by_feature_ideal_s"]
    ideal = fi.get("wall", 0) + fi.get("mid-line", 0) + sum(fi.get(k, 0) for k in ("connector", "travel", ""))
    return 100 * (1 - ideal / best_time)


def verdicts(bodies: list, res: dict, a: str) -> list[str]:
    """The issue's three rules per body: one row each, with pass/fail."""
    lines = [f"### The rules at {a} mm/s² (speed: photographs ≥ {SPEED_GOAL:g} %; bound: saving within "
             f"{BOUND_POINTS:g} points of it; fill {FILL[0]}–{FILL[1]})\n",
             "| body | picture | ours | best baseline | saving | bound | bound − saving | fill | mean abs ΔL* | speed | bound | fill |",
             "|---|---|---:|---|---:|---:|---:|---:|---:|---|---|---|"]
    for b in bodies:
        r = res[b["name"]]
        best, ok = best_baseline(r, a)
        o = r[OURS][a]
        if best is None:
            lines.append(f"| {b['name']} | {b['kind']} | {fmt_t(o['time_s'])} | none with fill ≥ 0.95 | | | | | | | | |")
            continue
        bt = ok[best]["time_s"]
        saving, bound = 100 * (1 - o["time_s"] / bt), bound_saving(o, bt)
        fill = o["fill_ratio"]
        dl = tone_error(b["stats"])
        speed = ("pass" if saving >= SPEED_GOAL else "FAIL") if b["photo"] else "–"
        near = "pass" if bound - saving <= BOUND_POINTS else "FAIL"
        fok = "pass" if FILL[0] <= fill <= FILL[1] else "FAIL"
        lines.append(f"| {b['name']} | {b['kind']} | {fmt_t(o['time_s'])} | {best} | {saving:.1f} % | "
                     f"{bound:.1f} % | {bound - saving:.1f} | {fill:.3f} | "
                     f"{'n/a' if dl is None else f'{dl:.2f}'} | {speed} | {near} | {fok} |")
    lines.append("")
    return lines


def report(bodies: list, res: dict, accels) -> str:
    lines = []
    for a in map(lambda x: str(int(x)), accels):
        lines.append(f"## Acceleration {a} mm/s²\n")
        lines += verdicts(bodies, res, a)
        lines.append("| body | ours | best baseline (fill ≥ 0.95) | its time | saving | paper's rate | saving | Arachne 3p | saving |")
        lines.append("|---|---:|---|---:|---:|---:|---:|---:|---:|")
        for b in bodies:
            r = res[b["name"]]
            base = {k: v[a] for k, v in r.items() if k not in (OURS, PAPER)}
            ok = {k: v for k, v in base.items() if v["fill_ratio"] >= 0.95}
            best = min(ok, key=lambda k: ok[k]["time_s"]) if ok else None
            o, p, ar = r[OURS][a]["time_s"], r[PAPER][a]["time_s"], base["prusa arachne 3p"]["time_s"]
            bt = ok[best]["time_s"] if best else float("nan")
            lines.append(f"| {b['name']} | {fmt_t(o)} | {best} | {fmt_t(bt)} | {100 * (1 - o / bt):.1f} % | "
                         f"{fmt_t(p)} | {100 * (1 - p / bt):.1f} % | {fmt_t(ar)} | {100 * (1 - o / ar):.1f} % |")
        lines.append("")
        lines.append("Where the time goes (s; in brackets the same moves without acceleration). Ours: walls, "
                     "mid-line laid, crossings (the head moving on along the mid-line where the walls merge), "
                     "connectors and travel. Best baseline: walls, and the rest (infill, gap fill, travel). "
                     "Bound: our saving if every move of ours ran at its own speed from end to end.\n")
        lines.append("| body | ours: walls | mid-line | crossings | connectors, travel | best: walls | best: rest | bound |")
        lines.append("|---|---:|---:|---:|---:|---:|---:|---:|")
        for b in bodies:
            r = res[b["name"]]
            o = r[OURS][a]
            f, fi = o["by_feature_s"], o["by_feature_ideal_s"]
            mid = o.get("mid_line", {"laid_s": 0.0, "laid_ideal_s": 0.0, "crossing_s": 0.0})  # all white: none
            base = {k: v[a] for k, v in r.items() if k not in (OURS, PAPER) and v[a]["fill_ratio"] >= 0.95}
            best = min(base, key=lambda k: base[k]["time_s"])
            bf = base[best]["by_feature_s"]
            walls_b = sum(v for k, v in bf.items() if "WALL" in k.upper() or "PERIMETER" in k.upper())
            other = sum(f.get(k, 0) for k in ("connector", "travel", ""))
            ideal = fi.get("wall", 0) + fi.get("mid-line", 0) + sum(fi.get(k, 0) for k in ("connector", "travel", ""))
            lines.append(f"| {b['name']} | {f.get('wall', 0):.0f} ({fi.get('wall', 0):.0f}) | "
                         f"{mid['laid_s']:.0f} ({mid['laid_ideal_s']:.0f}) | {mid['crossing_s']:.0f} | {other:.0f} | "
                         f"{walls_b:.0f} | {base[best]['time_s'] - walls_b:.0f} | "
                         f"{100 * (1 - ideal / base[best]['time_s']):.1f} % |")
        lines.append("")
        for b in bodies:
            r = res[b["name"]]
            lines.append(f"### {b['name']} ({b['layers']} layers, STL {b['stl_volume']:.0f} mm³), {a} mm/s²\n")
            lines.append("| method | time | fill ratio | extruding moves | filament mm | E-rate spread |")
            lines.append("|---|---:|---:|---:|---:|---:|")
            for k, v in sorted(r.items(), key=lambda kv: kv[1][a]["time_s"]):
                m = v[a]
                lines.append(f"| {k} | {fmt_t(m['time_s'])} | {m['fill_ratio']:.3f} | {m['extruding_moves']} | "
                             f"{m['filament_mm']:.0f} | {100 * m['e_rate_spread']:.1f} % |")
            lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--images", type=Path, nargs="*",
                    default=[ROOT / "examples/litho" / f"{n}.png" for n in ("wedge", "text", "drawing")])
    ap.add_argument("--photos", nargs="*", default=list(PHOTOS), metavar="NAME",
                    help=f"scikit-image photographs to run besides --images ({', '.join(PHOTOS)}; default all)")
    ap.add_argument("--photo-like", nargs="*", default=[], metavar="STEM",
                    help="stems of --images that are photographs or photo-like (the speed rule applies)")
    ap.add_argument("--shapes", nargs="+", default=["planar", "cylinder"], choices=["planar", "cylinder", "arc"],
                    help="bodies to make (arc: the curved panel, 120 degrees of the 54.8 mm circle, the "
                         "height from the picture)")
    ap.add_argument("--accel", type=float, nargs="+", default=[1000.0, 3000.0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--cura-defs")
    ap.add_argument("--report-only", action="store_true",
                    help="print the tables again from OUT/results.json (no slicing, no timing)")
    a = ap.parse_args(argv)
    if a.report_only:
        try:
            saved = json.loads((a.out / "results.json").read_text())
        except (OSError, ValueError) as e:
            sys.exit(f"litho_bench: --report-only: {a.out / 'results.json'}: {e}")
        print(report(saved["bodies"], saved["results"], a.accel))
        return 0
    for tool in ("CuraEngine", "prusa-slicer"):
        if not shutil.which(tool):
            sys.exit(f"litho_bench: {tool} not found: apt-get install cura-engine prusa-slicer")
    defs = cura_defs(a.cura_defs)
    a.out.mkdir(parents=True, exist_ok=True)
    pictures = [(img, "photo-like" if img.stem in a.photo_like else "drawn sample", img.stem in a.photo_like)
                for img in a.images]
    pictures += [(p, f"photograph: {PHOTOS[p.stem]}", True) for p in write_photos(a.photos, a.out / "photos")]
    t0 = time.time()
    methods = [OURS, PAPER] + list(CURA) + list(PRUSA)
    with cf.ProcessPoolExecutor(a.jobs) as ex:
        jobs = {ex.submit(body_job, img, sh, a.out / f"{img.stem}_{sh}", kind, photo, a.accel): (img, sh)
                for img, kind, photo in pictures for sh in a.shapes}
        bodies = []
        for f in cf.as_completed(jobs):
            bodies.append(f.result())
            print(f"[{time.time() - t0:6.0f} s] body {bodies[-1]['name']} made", file=sys.stderr)
        bodies.sort(key=lambda b: b["name"])
        res: dict = {b["name"]: {} for b in bodies}
        futs = [ex.submit(method_job, m, b, a.out / b["name"], defs, a.accel) for b in bodies for m in methods]
        for i, f in enumerate(cf.as_completed(futs), 1):
            name, method, m = f.result()
            res[name][method] = m
            print(f"[{time.time() - t0:6.0f} s] {i}/{len(futs)} {name}: {method}: "
                  f"{fmt_t(m[str(int(a.accel[0]))]['time_s'])}, fill {m[str(int(a.accel[0]))]['fill_ratio']:.3f}",
                  file=sys.stderr)
    (a.out / "results.json").write_text(json.dumps({"bodies": bodies, "results": res}, indent=1))
    md = report(bodies, res, a.accel)
    run = " ".join(["python3", "tools/litho_bench.py", *(argv if argv is not None else sys.argv[1:])])
    (a.out / "results.md").write_text(f"# litho_bench results\n\nRun: `{run}` ({time.time() - t0:.0f} s, "
                                      f"{a.jobs} jobs)\n\n" + md)
    print(md)
    print(f"wrote {a.out / 'results.md'} and results.json ({time.time() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
