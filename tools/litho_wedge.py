#!/usr/bin/env python3
"""How far each tone curve's predicted backlit lightness is from its target, on a 16-step grey
wedge (sRGB values 0, 17, ..., 255, black on the left), planar, the given options otherwise at
`bulgekit litho`'s defaults.

For every step (its middle sample, middle layer): the target L* (the grey's L* scaled onto what the
plate shows, L* of the thickest plate .. 100) and the predicted L* of
  - the curve's thickness (what the tone curve asks for; the field with --min-line 0.001, which
    has no gap the walls share on this wedge),
  - the planned thickness at the defaults (litho.thickness_field; nothing is snapped, so it is
    the curve's),
  - the printed thickness (two walls + the mid-line's gap, litho.printed_thickness).

    python3 tools/litho_wedge.py                       # markdown tables on stdout
    python3 tools/litho_wedge.py --attenuation 2.0 --max 3.0
    python3 tools/litho_wedge.py --edges               # the plate's end columns

With --look PICTURE... (or `astronaut`, `camera`: scikit-image's bundled photographs, nothing
downloaded), also each curve's predicted look against its target on those pictures, planned at
the defaults (planar 100 mm wide): mean |dL*| and SSIM on L*, as the JSON's `look` block.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "host"))

from bulgekit import litho as lt  # noqa: E402
from bulgekit.litho import tone  # noqa: E402

STEPS = 16
STEP_PX = 20


def wedge_png(path) -> np.ndarray:
    """The wedge picture (black left), and its steps' sRGB values."""
    from PIL import Image

    codes = np.round(np.arange(STEPS) * 255 / (STEPS - 1)).astype(np.uint8)
    a = np.repeat(np.repeat(codes[None, :], STEP_PX, axis=0), STEP_PX, axis=1)
    Image.fromarray(a).save(path)
    return codes


def step_errors(o: lt.LithoOptions, picture, printed: bool = True) -> dict:
    """Per step: target, and the predicted L* of the curve's, the planned and the printed thickness."""
    from dataclasses import replace

    codes = wedge_png(picture)
    fld = lt.thickness_field(picture, o)
    curve = lt.thickness_field(picture, replace(o, min_line=1e-3))
    n = len(fld.s)
    cols = [int(round((i + 0.5) * (n - 1) / STEPS)) for i in range(STEPS)]
    kp = (fld.t.shape[0] - fld.n_foot) // 2             # the middle picture layer (the foot's below)
    k = fld.n_foot + kp
    L_lo, _ = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
    grey_L = tone.lightness(tone.grey_to_luminance(codes / 255.0))
    target = tone.target_lightness(grey_L, L_lo, o.invert)
    to_L = lambda t: tone.lightness(tone.plate_luminance(t, o.attenuation, o.min_thickness))
    out = {"codes": codes.tolist(), "target": target, "t_curve": curve.t[k, cols],
           "curve": to_L(curve.t[k, cols]), "t_planned": fld.t[k, cols], "planned": to_L(fld.t[k, cols])}
    if printed:
        plan = lt.plan_lithophane(picture, o)
        pt = lt.printed_thickness(plan)
        out["t_printed"] = pt[kp, cols]
        out["printed"] = to_L(pt[kp, cols])
    return out


def look_table(a) -> None:
    from PIL import Image
    from skimage import data

    print()
    print("| picture | curve | mean abs dL* | SSIM on L* | samples with a thin mid-line / shared by the walls | time s |")
    print("|---|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as d:
        for pic in a.look:
            path = pic
            if pic in ("astronaut", "camera"):
                path = Path(d) / f"{pic}.png"
                Image.fromarray(getattr(data, pic)()).save(path)
            for c in tone.CURVES:
                import time
                t0 = time.time()
                o = lt.LithoOptions(curve=c, attenuation=a.attenuation, min_thickness=a.min_thickness,
                                    max_thickness=a.max_thickness, gamma=a.gamma)
                plan = lt.plan_lithophane(path, o)
                target, pred = (x[plan.field.inside] for x in lt.look(plan))
                sim = tone.similarity(target, pred)
                f = plan.field
                # gaps under a printable mid-line: the walls narrow for a thin one (--light-gaps
                # mid-line, the default) or share the gap (walls)
                narrowed, shared = (x / f.t[f.n_foot:].size for x in (f.narrowed, f.shared))
                print(f"| {Path(pic).name} | {c} | {sim['mean_abs_dL']:.2f} | {sim['ssim_L']:.3f} | "
                      f"{100 * narrowed:.1f} % / {100 * shared:.1f} % | {time.time() - t0:.0f} |", flush=True)


def edges_table() -> None:
    """The predicted look's end columns on a noisy photograph (scikit-image's camera, 256 x 256,
    Gaussian noise sd 25, seed 1), planar defaults: |dL*| between the printed and the planned
    thickness per column. (The probes of 9948163, on the gap's edge, went with the shapely paths;
    their figures are in docs/lithophane.md.)"""
    import time

    from PIL import Image
    from skimage import data

    rng = np.random.default_rng(1)
    cam = data.camera().astype(float)[::2, ::2]
    o = lt.LithoOptions()
    to_L = lambda t: tone.lightness(tone.plate_luminance(t, o.attenuation, o.min_thickness))

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "noisy_camera.png"
        Image.fromarray(np.clip(cam + rng.normal(0, 25, cam.shape), 0, 255).astype(np.uint8)).save(p)
        t0 = time.time()
        plan = lt.plan_lithophane(p, o)
        dL = to_L(lt.printed_thickness(plan)) - to_L(plan.field.t[plan.field.n_foot:])
    cols = {"first": dL[:, 0], "second": dL[:, 1], "second last": dL[:, -2], "last": dL[:, -1],
            "all others": dL[:, 2:-2]}
    print()
    print(f"noisy camera, planar defaults ({time.time() - t0:.0f} s)")
    print()
    print("| column | mean abs dL* | lighter by > 10 L* |")
    print("|---|---:|---:|")
    for k, v in cols.items():
        print(f"| {k} | {np.abs(v).mean():.2f} | {100 * (v > 10).mean():.1f} % |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--attenuation", type=float, default=1.5)
    ap.add_argument("--min", dest="min_thickness", type=float, default=0.8)
    ap.add_argument("--max", dest="max_thickness", type=float, default=2.4)
    ap.add_argument("--gamma", type=float, default=1.0)
    ap.add_argument("--steps-table", action="store_true", help="also every step of every curve")
    ap.add_argument("--look", nargs="*", default=[], metavar="PICTURE",
                    help="pictures (or astronaut, camera from skimage.data) for the look table")
    ap.add_argument("--edges", action="store_true", help="the end columns on a noisy photograph")
    a = ap.parse_args(argv)
    print(f"16-step grey wedge, planar 100 x 2 mm, --attenuation {a.attenuation:g}, --min {a.min_thickness:g}, "
          f"--max {a.max_thickness:g}, --gamma {a.gamma:g}")
    print()
    print("| curve | max abs dL*, curve's thickness | mean | max abs dL*, planned | mean | "
          "max abs dL*, printed | mean |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    rows = {}
    with tempfile.TemporaryDirectory() as d:
        for c in tone.CURVES:
            o = lt.LithoOptions(curve=c, height=2.0, stretch=True, attenuation=a.attenuation, min_thickness=a.min_thickness,
                                max_thickness=a.max_thickness, gamma=a.gamma)
            r = step_errors(o, Path(d) / "wedge.png")
            rows[c] = r
            e = {key: np.abs(r[key] - r["target"]) for key in ("curve", "planned", "printed")}
            print(f"| {c} | " + " | ".join(f"{e[key].max():.2f} | {e[key].mean():.2f}"
                                           for key in ("curve", "planned", "printed")) + " |")
    if a.look:
        look_table(a)
    if a.edges:
        edges_table()
    if a.steps_table:
        for c, r in rows.items():
            print()
            print(f"{c}: step, sRGB value, target L*, curve's thickness mm / L*, planned mm / L*, printed mm / L*")
            print()
            print("| step | value | target L* | curve mm | L* | planned mm | L* | printed mm | L* |")
            print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
            for i in range(STEPS):
                print(f"| {i + 1} | {r['codes'][i]} | {r['target'][i]:.1f} | {r['t_curve'][i]:.3f} | "
                      f"{r['curve'][i]:.1f} | {r['t_planned'][i]:.3f} | {r['planned'][i]:.1f} | "
                      f"{r['t_printed'][i]:.3f} | {r['printed'][i]:.1f} |")


if __name__ == "__main__":
    main()
