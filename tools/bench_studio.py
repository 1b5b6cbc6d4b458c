#!/usr/bin/env python3
"""Figures for docs/studio.md: how long the studio's server takes to open G-code of two sizes,
to preview a design (without and with the reference-planner check) and to export it. Runs the
server in this process and talks HTTP to it, as the page does (no browser).

    python3 tools/bench_studio.py [--mb 100]
    python3 tools/bench_studio.py --litho     # the lithophane tab: make, and its 3D view's data
"""
import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "host" / "tests"))
from studio_util import GCODE, big_gcode, call, open_gcode, start, wait_job  # noqa: E402

DESIGN = {"name": "bench", "items": [
    {"id": "t", "kind": "text", "text": "HELLO", "at": [4, 7], "size": 6, "rotate": 0}],
    "bulges": {"dwell": 100, "extra": 0.1, "tolerance": 0.25}}


def timed(fn):
    t0 = time.perf_counter()
    r = fn()
    return r, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100, help="size of the large G-code, MB")
    ap.add_argument("--litho", action="store_true",
                    help="instead: a 240 x 220 px photo (scikit-image's astronaut) made into each shape "
                         "at the defaults, and the size of what the 3D view loads")
    a = ap.parse_args()
    if a.litho:
        return litho()
    with tempfile.TemporaryDirectory() as tmp:
        big = big_gcode(Path(tmp) / "tall.gcode", int(a.mb * 1e6))
        print(f"{'file':<26} {'MB':>6} {'open':>7} {'preview':>8} {'check':>7} {'export':>7}")
        for path in (GCODE, big):
            run = start(Path(tmp) / f"w-{path.stem}")
            try:
                job, t_open = timed(lambda: open_gcode(run, path))
                assert job["state"] == "done", job["error"]
                (_, p), t_prev = timed(lambda: call(run, "/api/preview", {"design": DESIGN}))
                (_, c), t_check = timed(lambda: call(run, "/api/preview", {"design": DESIGN, "check": True}))
                assert c["summary"]["stops"] == c["summary"]["points"], c["summary"]
                ex, t_exp = timed(lambda: wait_job(run, call(run, "/api/export", {"design": DESIGN})[1], 1200))
                assert ex["state"] == "done", ex["error"]
                print(f"{path.name:<26} {path.stat().st_size / 1e6:6.1f} {t_open:6.2f}s {t_prev:7.2f}s "
                      f"{t_check:6.2f}s {t_exp:6.2f}s   ({job['result']['layers']} layers, "
                      f"{p['summary']['points']} points)")
            finally:
                run.stop()


def litho():
    import json
    from PIL import Image
    from skimage import data            # bundled with the wheel: nothing downloaded
    with tempfile.TemporaryDirectory() as tmp:
        pic = Path(tmp) / "astronaut.png"
        Image.fromarray(data.astronaut()).resize((240, 220), Image.Resampling.LANCZOS).save(pic)
        run = start(Path(tmp) / "w")
        try:
            _, info = call(run, "/api/asset?name=astronaut.png", pic.read_bytes())
            print(f"{'shape':<9} {'make':>7} {'view':>7} {'view JSON':>10} {'mesh':>9} {'texture':>9}")
            for shape in ("planar", "cylinder"):
                job, t_make = timed(lambda: wait_job(run, call(run, "/api/litho", {
                    "asset": info["name"], "options": {"shape": shape}})[1], 1200))
                assert job["state"] == "done", job["error"]
                (_, v), t_view = timed(lambda: call(run, job["result"]["view"]))
                size = len(json.dumps(v).encode())
                print(f"{shape:<9} {t_make:6.1f}s {t_view:6.2f}s {size / 1e6:8.2f} MB "
                      f"{v['rows']:>4}x{v['cols']:<4} {v['look']['height']:>4}x{v['look']['width']:<4}")
        finally:
            run.stop()


if __name__ == "__main__":
    main()
