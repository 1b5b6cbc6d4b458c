#!/usr/bin/env python3
"""Benchmark `bulgekit annotate` on a large G-code (default 100 MB).

The input is made in a temp dir from a real sliced file (PrusaSlicer, M83,
z-hop) by repeating its middle layers upward, each copy with its Z values
offset, so the result looks like one tall print: layer changes, z-hops,
feature comments every layer.  The map has one bulge point on every layer
up to 650 mm, far more than the printer's 2 KiB arena, so the run also
exercises the streamed M721 appends.

    python3 tools/bench_annotate.py [--mb 100] [--keep DIR]

Prints the size, the seconds annotate took and MB/s.  Goal: < 10 s / 100 MB.
"""
from __future__ import annotations

import argparse
import contextlib
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))

from bulgekit.bulge import mapformat  # noqa: E402
from bulgekit.bulge.annotate import annotate_file  # noqa: E402
from bulgekit.bulge.fallback import Settings  # noqa: E402
from bulgekit.bulge.wall import walls_from_gcode  # noqa: E402

SRC = ROOT / "host" / "tests" / "data" / "prusa_cyl_m83.gcode"
_Z = re.compile(r"^(G1 [^;\n]*?Z)([-+]?[0-9]*\.?[0-9]+)", re.M)


def make_gcode(dst: Path, megabytes: float) -> tuple[int, float]:
    text = SRC.read_text()
    parts = text.split(";LAYER_CHANGE\n")
    head, layers = parts[0], parts[1:]
    tail_at = layers[-1].find("; Filament-specific end gcode")
    footer = layers[-1][tail_at:] if tail_at >= 0 else ""
    body = layers[4:-4]                     # sparse-infill middle layers
    z_first = float(re.search(r";Z:([0-9.]+)", body[0]).group(1))
    z_last = float(re.search(r";Z:([0-9.]+)", body[-1]).group(1))
    span = round(z_last - z_first + 0.3, 3)
    target = int(megabytes * 1e6)
    out = [head, ";LAYER_CHANGE\n".join([""] + layers[:4])]
    size = sum(len(p) for p in out)
    k = 0
    n_layers = 4
    while size < target:
        off = k * span
        for blk in body:
            blk = _Z.sub(lambda m: f"{m.group(1)}{float(m.group(2)) + off:.3f}", blk)
            blk = re.sub(r";Z:([0-9.]+)", lambda m: f";Z:{float(m.group(1)) + off:.3f}", blk)
            out.append(";LAYER_CHANGE\n" + blk)
            size += len(blk) + 14
            n_layers += 1
        k += 1
    out.append(footer)
    data = "".join(out)
    dst.write_text(data)
    return len(data.encode()), z_first + k * span


def make_map(z_top: float) -> bytes:
    model = walls_from_gcode(SRC)
    x, y = model.walls[5].xy_of_u(10.0)[0]
    zs = [round(0.3 * i, 2) for i in range(1, int(min(z_top, 650.0) / 0.3))]
    return mapformat.encode_map([(z, [(x, y)]) for z in zs], layer_height_mm=0.3)


def bench_setup(doc: str, more=None):
    """The benchmarks' command line (--mb, --keep; more(parser) adds a benchmark's own) and
    their working folder: --keep's, or a temporary one that goes when the run ends."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100.0, help="input size in MB (default 100)")
    ap.add_argument("--keep", type=Path, help="write the input and outputs here instead of a temp dir")
    if more is not None:
        more(ap)
    a = ap.parse_args()

    @contextlib.contextmanager
    def folder():
        with tempfile.TemporaryDirectory() as tmp:
            d = a.keep or Path(tmp)
            d.mkdir(parents=True, exist_ok=True)
            yield d
    return a, folder()


def main() -> int:
    a, folder = bench_setup(__doc__)
    with folder as d:
        src, dst = d / "big.gcode", d / "big.bulge.gcode"
        t = time.perf_counter()
        size, z_top = make_gcode(src, a.mb)
        data = make_map(z_top)
        print(f"input: {size / 1e6:.1f} MB, top z {z_top:.1f} mm, map {len(data)} bytes "
              f"(made in {time.perf_counter() - t:.1f} s)")
        t = time.perf_counter()
        res = annotate_file(src, dst, data, Settings())
        dt = time.perf_counter() - t
        print(f"annotate: {dt:.2f} s, {size / 1e6 / dt:.1f} MB/s "
              f"({res.markers} markers, {res.initial_records} layers at start, "
              f"{len(res.appends)} appends, {res.lines_added} lines added)")
        print("goal < 10 s per 100 MB:", "met" if dt * 100e6 / size < 10 else "NOT met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
