#!/usr/bin/env python3
"""How small the firmware's map arena (BK_MAP_ARENA_BYTES) can be for a print.

    python3 tools/arena_window.py GCODE MAP [GCODE MAP ...]

For each sliced file and its bulge map: the map's size, its largest layer
record, the smallest arena that `bulgekit annotate` can stream the map through
(found by bisection on the annotator itself, so it is the exact window its
streaming needs: the layer in print plus the records sent ahead), and the
appends it writes for a 1024- and a 2048-byte arena. First the bound of the
format: a record holds at most LAYER_POINTS_MAX points, so no print needs more
than two of the largest possible records.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "host"))

from bulgekit.bulge import annotate, mapformat  # noqa: E402
from bulgekit.bulge.fallback import MODE_GEOMETRIC, Settings  # noqa: E402


def largest_record() -> int:
    """Bytes of the largest record the format allows: LAYER_POINTS_MAX points,
    every delta a 3-byte varint (the coordinates swing across int16), weights."""
    n = mapformat.LAYER_POINTS_MAX
    pts = tuple((-32768 if i % 2 else 32767, 32767 if i % 2 else -32768) for i in range(n))
    layer = mapformat.Layer(z_cmm=65535, points=pts, weights=tuple(range(n)))
    return len(mapformat.encode_record(layer, True))


def fits(data: bytes, map_bytes: bytes, arena: int, settings: Settings) -> annotate.AnnotateResult | None:
    res = annotate.AnnotateResult()
    try:
        annotate.annotate_bytes(data, map_bytes, settings, arena=arena, stream=True, result=res)
    except annotate.AnnotateError:
        return None
    return res


def main(argv) -> int:
    if len(argv) % 2:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    big = largest_record()
    print(f"format bound: largest record {big} B; two of them {2 * big} B "
          f"(LAYER_POINTS_MAX {mapformat.LAYER_POINTS_MAX})")
    print("| print | map | largest record | smallest arena | appends at 1024 | appends at 2048 |")
    print("|---|---:|---:|---:|---:|---:|")
    worst = 0
    for gpath, mpath in zip(argv[::2], argv[1::2]):
        with open(gpath, "rb") as f:
            data = f.read()
        with open(mpath, "rb") as f:
            map_bytes = f.read()
        bm = mapformat.decode_map(map_bytes, source=mpath)
        recs = [len(mapformat.encode_record(l, bm.has_weights)) for l in bm.layers]
        lo, hi = max(recs), len(map_bytes)
        # marked walls (M722) when the slicer wrote feature comments, else geometric (M720 S2)
        settings = next((s for s in (Settings(), Settings(mode=MODE_GEOMETRIC))
                         if fits(data, map_bytes, hi, s) is not None), None)
        if settings is None:
            print(f"{gpath}: the map does not stream even through {hi} bytes", file=sys.stderr)
            return 1
        while lo < hi:  # smallest arena that works
            mid = (lo + hi) // 2
            if fits(data, map_bytes, mid, settings) is None:
                lo = mid + 1
            else:
                hi = mid
        worst = max(worst, lo)
        counts = []
        for arena in (1024, 2048):
            res = fits(data, map_bytes, arena, settings)
            counts.append("does not fit" if res is None else str(len(res.appends)))
        print(f"| {os.path.basename(gpath)} | {len(map_bytes)} B, {len(recs)} layers | {max(recs)} B "
              f"| {lo} B | {counts[0]} | {counts[1]} |")
    print(f"largest window needed: {worst} B")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
