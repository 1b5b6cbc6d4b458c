#!/usr/bin/env python3
"""Writes the shared bulge-map test vectors into test/vectors/.

    python3 tools/vectors/gen_vectors.py            # (re)write test/vectors
    python3 tools/vectors/gen_vectors.py --check    # exit 1 if test/vectors is stale
    python3 tools/vectors/gen_vectors.py --out DIR  # write elsewhere

Everything is derived deterministically (no randomness) from the definitions
below through host/bulgekit/bulge/mapformat.py, so a rerun gives identical bytes.
Outputs: *.bkm (full maps, or corrupt ones), *.bkr (append records), one
*.json per binary describing its content, *.m721 upload transcripts, and
vectors.h (the C++ suites' copy of the bytes, in PROGMEM on AVR).
"""

from __future__ import annotations

import argparse
import filecmp
import json
import math
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "host"))

from bulgekit.bulge import mapformat as mf  # noqa: E402

ARENA_BYTES = 2048  # the unit tests build the core with a 2 KB arena (platformio.ini), for the streaming plan

# ---- synthetic text on a cylinder ---------------------------------------------------------
# Stroke font in a 4 x 6 cell (u right, v up); polylines.
FONT = {
    "B": [[(0, 0), (0, 6), (3, 6), (4, 5), (4, 4), (3, 3), (4, 2), (4, 1), (3, 0), (0, 0)], [(0, 3), (3, 3)]],
    "U": [[(0, 6), (0, 1), (1, 0), (3, 0), (4, 1), (4, 6)]],
    "L": [[(0, 6), (0, 0), (4, 0)]],
    "G": [[(4, 5), (3, 6), (1, 6), (0, 5), (0, 1), (1, 0), (3, 0), (4, 1), (4, 3), (2, 3)]],
    "E": [[(4, 6), (0, 6), (0, 0), (4, 0)], [(0, 3), (3, 3)]],
    "K": [[(0, 0), (0, 6)], [(4, 6), (0, 2)], [(1, 3), (4, 0)]],
    "I": [[(2, 0), (2, 6)], [(1, 0), (3, 0)], [(1, 6), (3, 6)]],
    "T": [[(2, 0), (2, 6)], [(0, 6), (4, 6)]],
}


def text_layers(
    text: str,
    z0: float,
    scale: float = 10.0 / 6.0,
    radius: float = 20.0,
    center: tuple[float, float] = (110.0, 110.0),
    layer_h: float = 0.3,
    spacing: float = 0.8,
    advance: float = 8.0,
    u0: float = 0.0,
) -> dict[int, list[tuple[float, float]]]:
    """Bulge points of raised text on a cylinder wall, per layer (z in cmm).

    Each stroke contributes, on every layer whose band it crosses, points at
    `spacing` along its part inside the band (a vertical stroke: one point per
    layer; a horizontal one: a row of points on its layer). Points closer than
    half the spacing merge. A layer's points come in wall order (angle).
    """
    per_layer: dict[int, list[float]] = {}
    for k, ch in enumerate(text):
        for poly in FONT.get(ch, []):
            for (ua, va), (ub, vb) in zip(poly, poly[1:]):
                a = (u0 + k * advance + ua * scale, z0 + va * scale)
                b = (u0 + k * advance + ub * scale, z0 + vb * scale)
                lo, hi = min(a[1], b[1]), max(a[1], b[1])
                first = math.ceil((lo - layer_h / 2) / layer_h - 1e-9)
                last = math.floor((hi + layer_h / 2) / layer_h + 1e-9)
                for li in range(first, last + 1):
                    zc = li * layer_h
                    band_lo, band_hi = zc - layer_h / 2, zc + layer_h / 2
                    if a[1] == b[1]:
                        if not band_lo <= a[1] < band_hi:
                            continue
                        t0, t1 = 0.0, 1.0
                    else:
                        t0 = (band_lo - a[1]) / (b[1] - a[1])
                        t1 = (band_hi - a[1]) / (b[1] - a[1])
                        t0, t1 = max(0.0, min(t0, t1)), min(1.0, max(t0, t1))
                        if t1 <= t0:
                            continue
                    ua_ = a[0] + (b[0] - a[0]) * t0
                    ub_ = a[0] + (b[0] - a[0]) * t1
                    n = max(1, math.ceil(abs(ub_ - ua_) / spacing - 1e-9))
                    us = [ua_ + (ub_ - ua_) * (i + 0.5) / n for i in range(n)] if n > 1 else [(ua_ + ub_) / 2]
                    per_layer.setdefault(round(zc * 100), []).extend(us)
    out = {}
    for zc, us in sorted(per_layer.items()):
        us.sort()
        merged: list[float] = []
        for u in us:
            if merged and u - merged[-1] < spacing / 2:
                continue
            merged.append(u)
        out[zc] = [
            (center[0] + radius * math.cos(u / radius), center[1] + radius * math.sin(u / radius)) for u in merged
        ]
    return out


def text_cylinder_layers():
    return text_layers("BULGEKIT", z0=3.0)


def text_tall_layers():
    a = text_layers("BULGEKIT", z0=3.0)
    b = text_layers("KITBULGE", z0=14.1, u0=30.0)
    a.update(b)
    return dict(sorted(a.items()))


def as_mm_layers(d):
    return [(z / 100.0, pts) for z, pts in d.items()]


# ---- corrupt variants ------------------------------------------------------------------------
def rec(z: int, body: bytes, n: int, len_override: int | None = None, n_raw: bytes | None = None) -> bytes:
    """A record with a correct CRC over whatever (possibly wrong) fields are given."""
    r = z.to_bytes(2, "little") + (n_raw if n_raw is not None else mf.varint(n))
    r += mf.varint(len(body) if len_override is None else len_override) + body
    return r + bytes([mf.crc8(r)])


def header(q=50, lh=30, flags=0, version=1, magic=b"BKM", fix_crc=True) -> bytes:
    h = magic + bytes([version, flags, q, lh])
    return h + bytes([mf.crc8(h) if fix_crc else 0])


def pts_body(points) -> bytes:
    out = bytearray()
    px = py = 0
    for x, y in points:
        out += mf.varint(mf.zigzag(x - px)) + mf.varint(mf.zigzag(y - py))
        px, py = x, y
    return bytes(out)


def bad_vectors(tiny: bytes):
    """(name, bytes, expected error code, what is wrong)."""
    good_h = header()
    p3 = [(200, 0), (199, 20), (196, 40)]
    b3 = pts_body(p3)
    flip = bytearray(tiny)
    flip[12] ^= 0x01  # inside the body of the first record
    hdr_flip = bytearray(tiny)
    hdr_flip[5] ^= 0x02  # the quantum byte, CRC left alone
    over_long = bytes([0x80, 0x80, 0x80, 0x01])  # 4-byte varint for 2^21
    vectors = [
        ("bad_short_header", tiny[:5], "truncated", "5 bytes: the header is cut off"),
        ("bad_short_record", tiny[:-2], "truncated", "the record's last body byte and CRC are missing"),
        ("bad_magic", b"BKX" + tiny[3:], "magic", "magic 'BKX'"),
        ("bad_version", header(version=2) + tiny[8:], "version", "version 2 with a valid header CRC"),
        ("bad_flags", header(flags=0x02) + tiny[8:], "flags", "flag bit 1 set, valid header CRC"),
        ("bad_quantum_zero", header(q=0) + tiny[8:], "header_value", "quantum 0, valid header CRC"),
        ("bad_header_crc", bytes(hdr_flip), "header_crc", "one bit of the quantum flipped"),
        ("bad_record_crc", bytes(flip), "record_crc", "one body bit flipped, record CRC left alone"),
        (
            "bad_varint_long",
            good_h + rec(30, over_long + b"\x00", 1),
            "varint",
            "x0 as a 4-byte varint (CRC and len consistent)",
        ),
        (
            "bad_varint_nonminimal",
            good_h + rec(30, bytes([0x80, 0x00, 0x00]), 1),
            "varint",
            "x0 = 0 written as 0x80 0x00 (not minimal)",
        ),
        ("bad_count_zero", good_h + rec(30, b"", 0), "count_zero", "n = 0"),
        (
            "bad_count_max",
            good_h + rec(30, pts_body([(i, 0) for i in range(65)]), 65),
            "count_max",
            "n = 65 > BK_LAYER_POINTS_MAX, body consistent",
        ),
        ("bad_len_long", good_h + rec(30, b3 + b"\x00", 3), "length", "len one byte longer than the 3 points"),
        ("bad_len_short", good_h + rec(30, b3[:-1], 3), "length", "len one byte short of the 3 points"),
        (
            "bad_coord",
            good_h + rec(30, pts_body([(32767, 0)]) + mf.varint(mf.zigzag(1)) + b"\x00", 2),
            "coord",
            "x = 32767 then dx = +1 leaves int16",
        ),
        ("bad_z_equal", tiny + rec(60, b3, 3), "z_order", "second record repeats z 0.60 mm"),
        ("bad_z_down", good_h + rec(60, b3, 3) + rec(30, b3, 3), "z_order", "z 0.60 then 0.30 mm"),
    ]
    return vectors


# ---- output ---------------------------------------------------------------------------------
def layer_json(layer: mf.Layer) -> dict:
    d = {"z_cmm": layer.z_cmm, "points": [list(p) for p in layer.points]}
    if layer.weights is not None:
        d["weights"] = list(layer.weights)
    return d


def map_json(name: str, data: bytes, description: str, **extra) -> dict:
    m = mf.decode_map(data, source=name)
    d = {
        "file": name,
        "kind": "map",
        "description": description,
        "size": len(data),
        "crc32": mf.crc32(data),
        "header": {
            "version": m.version,
            "flags": m.flags,
            "quantum_um": m.quantum_um,
            "layer_height_cmm": m.layer_height_cmm,
        },
        "layer_count": len(m.layers),
        "point_count": m.point_count,
        "bytes_per_point": round(len(data) / m.point_count, 3) if m.point_count else None,
        "layers": [layer_json(layer) for layer in m.layers],
    }
    d.update(extra)
    return d


def c_bytes(data: bytes, indent="    ") -> str:
    rows = []
    for i in range(0, len(data), 16):
        rows.append(indent + ", ".join(f"0x{b:02X}" for b in data[i : i + 16]) + ",")
    return "\n".join(rows)


def c_string(text: str) -> str:
    return "\n".join('    "' + line.replace("\\", "\\\\").replace('"', '\\"') + '\\n"' for line in text.splitlines())


def stream_plan(full: bytes, arena: int = ARENA_BYTES, first_budget: int = 1000, batch_budget: int = 600):
    """Splits a map too big for the arena into a first upload and append batches.

    Returns [(release_below_z or None, data, append)], the release computed as a
    printer would free layers: just enough consumed layers to make room.
    """
    m = mf.decode_map(full)
    recs = [mf.encode_record(layer, m.has_weights) for layer in m.layers]
    head = mf.encode_header(m.quantum_um, m.layer_height_cmm, m.has_weights)
    i = 0
    first = bytearray(head)
    while i < len(recs) and len(first) + len(recs[i]) <= first_budget:
        first += recs[i]
        i += 1
    plan = [(None, bytes(first), False)]
    held = [(m.layers[k].z_cmm, len(recs[k])) for k in range(i)]
    while i < len(recs):
        batch = bytearray()
        zs = []
        while i < len(recs) and len(batch) + len(recs[i]) <= batch_budget:
            batch += recs[i]
            zs.append((m.layers[i].z_cmm, len(recs[i])))
            i += 1
        used = sum(s for _, s in held)
        release = None
        while used + len(batch) > arena:
            z, s = held.pop(0)
            used -= s
            release = held[0][0] if held else z + 1
        plan.append((release, bytes(batch), True))
        held += zs
    return plan


def generate(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*"):
        if old.suffix in (".bkm", ".bkr", ".json", ".m721", ".h"):
            old.unlink()
    files: dict[str, bytes] = {}
    jsons: dict[str, dict] = {}

    def put_map(name, data, description, **extra):
        files[name] = data
        jsons[name] = map_json(name, data, description, **extra)

    tiny = mf.encode_map([(0.6, [(10.0, 0.0), (9.95, 1.0), (9.8, 2.0)])])
    put_map("header_only.bkm", mf.encode_map([]), "A header and no layers: q 50 um, 0.30 mm layers.")
    put_map("tiny.bkm", tiny, "One layer at 0.60 mm, 3 points (the worked example of docs/reference/map-format.md).")
    put_map(
        "weights.bkm",
        mf.encode_map(
            [(0.2, [(-5.0, -5.0), (5.0, -5.0), (5.0, 5.0)]), (0.5, [(-5.0, 5.0), (-5.05, 4.2)])],
            quantum_um=50,
            layer_height_mm=0.3,
            weights=[[255, 128, 0], [1, 200]],
        ),
        "Two layers with dwell weights and negative coordinates.",
    )
    extremes = mf.BulgeMap(
        quantum_um=10,
        layer_height_cmm=255,
        has_weights=False,
        layers=[
            mf.Layer(0, ((-32768, 32767), (32767, -32768), (0, 0))),
            mf.Layer(65535, ((32767, 32767),)),
        ],
    )
    put_map(
        "extremes.bkm",
        mf.encode_map_q(extremes),
        "Range limits: q 10 um, 2.55 mm layers, z 0 and 655.35 mm, int16 corners (3-byte deltas).",
    )
    ring = [(110 + 20 * math.cos(2 * math.pi * i / 64), 110 + 20 * math.sin(2 * math.pi * i / 64)) for i in range(64)]
    put_map(
        "full_layer.bkm",
        mf.encode_map([(3.0, ring)], weights=[[(37 * i) % 256 for i in range(64)]]),
        "One layer of 64 points (BK_LAYER_POINTS_MAX) with weights: a ring of r 20 mm at (110, 110).",
    )
    cyl = text_cylinder_layers()
    put_map(
        "text_cylinder.bkm",
        mf.encode_map(as_mm_layers(cyl)),
        "Realistic case: 'BULGEKIT' raised on a 40 mm cylinder at (110, 110), 10 mm tall letters "
        "(the size Takahashi & Miyashita found legible), 8 mm advance, 0.3 mm layers, points 0.8 mm "
        "apart along strokes, one per layer on vertical strokes.",
    )
    tall = mf.encode_map(as_mm_layers(text_tall_layers()))
    put_map(
        "text_tall.bkm",
        tall,
        "Two bands of text (z 3-13 and 14.1-24.1 mm): larger than the 2048-byte arena, "
        "so the firmware refuses it whole and text_tall_stream.m721 streams it instead.",
        firmware_error="too_large",
    )
    # The tail of text_cylinder as append records (M721 A1).
    cm = mf.decode_map(files["text_cylinder.bkm"])
    half = len(cm.layers) // 2
    head_map = mf.encode_map_q(mf.BulgeMap(cm.quantum_um, cm.layer_height_cmm, False, cm.layers[:half]))
    tail = mf.encode_layers_q(cm.layers[half:], False, cm.layers[half - 1].z_cmm)
    put_map("text_cylinder_head.bkm", head_map, f"The first {half} layers of text_cylinder.bkm.")
    files["text_cylinder_tail.bkr"] = tail
    jsons["text_cylinder_tail.bkr"] = {
        "file": "text_cylinder_tail.bkr",
        "kind": "records",
        "description": "Layer records (no header) for M721 A1 after text_cylinder_head.bkm; "
        "head + tail records == text_cylinder.bkm.",
        "append_to": "text_cylinder_head.bkm",
        "size": len(tail),
        "crc32": mf.crc32(tail),
        "has_weights": False,
        "after_z_cmm": cm.layers[half - 1].z_cmm,
        "layers": [layer_json(layer) for layer in cm.layers[half:]],
    }
    for name, data, code, what in bad_vectors(tiny):
        files[name + ".bkm"] = data
        jsons[name + ".bkm"] = {
            "file": name + ".bkm",
            "kind": "bad",
            "description": what,
            "size": len(data),
            "expect_error": code,
        }

    # Upload transcripts: what the host sends (N numbers and checksums included).
    transcripts = {}
    transcripts["tiny.m721"] = "; M721 upload of tiny.bkm\n" + "\n".join(mf.upload_lines(tiny, start_line=1)) + "\n"
    t = ["; M721 upload of text_cylinder_head.bkm, then text_cylinder_tail.bkr appended"]
    lines = mf.upload_lines(head_map, start_line=1)
    t += lines
    t += mf.upload_lines(tail, append=True, start_line=1 + len(lines), has_weights=False)
    transcripts["text_cylinder.m721"] = "\n".join(t) + "\n"
    t = [
        "; Streaming text_tall.bkm through a 2048-byte arena: a first map, then appends;",
        "; '; @release_below <z_cmm>' marks where printing has consumed the layers below z.",
    ]
    n = 1
    for release, data, append in stream_plan(tall):
        if release is not None:
            t.append(f"; @release_below {release}")
        lines = mf.upload_lines(data, append=append, start_line=n, has_weights=False)
        n += len(lines)
        t += lines
    transcripts["text_tall_stream.m721"] = "\n".join(t) + "\n"

    for name, data in files.items():
        (out / name).write_bytes(data)
    for name, d in jsons.items():
        (out / (Path(name).stem + ".json")).write_text(json.dumps(d, indent=1) + "\n")
    for name, text in transcripts.items():
        (out / name).write_text(text)
    (out / "vectors.h").write_text(c_header(files, jsons, transcripts))
    (out / "planner_streams.h").write_text(planner_streams_header())


# ---- planner streams: the host's RefPlanner decisions, replayed on every target -----------
# The differential test's random streams (host/tests/planner_streams.py) for a few
# seeds, with the actions RefPlanner (the host's float32 mirror of the core) gives
# for each move; test/test_planner_streams replays the same G-code lines through
# the core on the host, the ATmega2560 and both Cortex-M targets. Seed 507's first
# 30 moves hold a point exactly at the tolerance (an ulp decides it). Seeds 1401,
# 2228 and 2729 are the 3 of 3,000 whose stops change when the core's distance
# test and piece ends use fused multiply-adds (as a Cortex-M4F's FPU can).
STREAM_SEEDS = list(range(16)) + [507, 1401, 2228, 2729]


def planner_streams():
    import random

    sys.path.insert(0, str(ROOT / "host" / "tests"))
    from planner_streams import m720_line, mirror_plan, move_lines, random_stream

    from bulgekit.bulge.fallback import RefPlanner

    streams = []
    for seed in STREAM_SEEDS:
        layers, settings, moves, lh = random_stream(random.Random(seed))
        if seed == 507:
            moves = moves[:30]
        data = mf.encode_map(layers, quantum_um=100, layer_height_mm=lh)
        plans = mirror_plan(RefPlanner(mf.decode_map(data), settings), moves)
        # the lines exactly as the differential test sends them
        streams.append((seed, data, m720_line(settings), move_lines(moves), [len(p) for p in plans],
                        [a for p in plans for a in p]))
    return streams


def c_float(v: float) -> str:
    # the shortest text that reads back as the same float32
    import struct

    f = struct.unpack("<f", struct.pack("<f", v))[0]
    for digits in range(6, 10):
        t = f"{f:.{digits}g}"
        if struct.unpack("<f", struct.pack("<f", float(t)))[0] == f:
            break
    if "e" not in t and "." not in t:
        t += ".0"
    return t + "f"


def planner_streams_header() -> str:
    out = [
        "// Generated by tools/vectors/gen_vectors.py: random planner streams (the",
        "// differential test's, host/tests/planner_streams.py) and the actions the host's",
        "// RefPlanner gives for them, for test/test_planner_streams on every target.",
        "// Do not edit: rerun the generator.",
        "#ifndef BK_TEST_PLANNER_STREAMS_H",
        "#define BK_TEST_PLANNER_STREAMS_H",
        "",
        "#include <stdint.h>",
        "#ifdef __AVR__",
        "#include <avr/pgmspace.h>",
        "#define BKS_FLASH PROGMEM",
        "#else",
        "#define BKS_FLASH",
        "#endif",
        "",
        "struct BksAction {",
        "  float x, y, z, e;  // a line: its end and filament",
        "  uint16_t ms;       // a dwell: its length",
        "  uint8_t dwell;     // 1: a dwell, 0: a line",
        "};",
        "struct BksStream {",
        "  uint16_t seed;",
        "  const uint8_t *map;         // the map image (flash)",
        "  uint16_t map_len;",
        "  const char *m720;           // the settings line (flash)",
        "  const char *moves;          // G1 lines, each ending in '\\n' (flash; M83 is in force)",
        "  const uint8_t *per_move;    // actions per move (flash)",
        "  uint8_t n_moves;",
        "  const BksAction *actions;   // all moves' actions in order (flash)",
        "  uint16_t n_actions;",
        "};",
        "",
    ]
    table = []
    for seed, data, m720, lines, per_move, acts in planner_streams():
        out.append(f"// seed {seed}: {len(lines)} moves, {len(acts)} actions, "
                   f"{sum(a.kind == 'dwell' for a in acts)} dwells")
        out.append(f"static const uint8_t bks_{seed}_map[{len(data)}] BKS_FLASH = {{")
        out.append(c_bytes(data))
        out.append("};")
        out.append(f'static const char bks_{seed}_m720[] BKS_FLASH = "{m720}";')
        out.append(f"static const char bks_{seed}_moves[] BKS_FLASH =")
        out.append(c_string("\n".join(lines)) + ";")
        out.append(f"static const uint8_t bks_{seed}_per_move[{len(per_move)}] BKS_FLASH = {{")
        out.append("    " + ", ".join(str(n) for n in per_move) + ",")
        out.append("};")
        out.append(f"static const BksAction bks_{seed}_actions[{len(acts)}] BKS_FLASH = {{")
        for a in acts:
            if a.kind == "dwell":
                out.append(f"    {{0.0f, 0.0f, 0.0f, 0.0f, {a.ms}, 1}},")
            else:
                out.append(f"    {{{c_float(a.x)}, {c_float(a.y)}, {c_float(a.z)}, {c_float(a.e)}, 0, 0}},")
        out.append("};")
        out.append("")
        table.append(f"    {{{seed}, bks_{seed}_map, {len(data)}, bks_{seed}_m720, bks_{seed}_moves, "
                     f"bks_{seed}_per_move, {len(lines)}, bks_{seed}_actions, {len(acts)}}},")
    out.append("static const BksStream bks_streams[] BKS_FLASH = {")
    out += table
    out.append("};")
    out.append(f"static const uint8_t bks_stream_count = {len(table)};")
    out.append("")
    out.append("#endif  // BK_TEST_PLANNER_STREAMS_H")
    return "\n".join(out) + "\n"


def c_points(name: str, m: dict) -> str:
    rows = []
    for layer in m["layers"]:
        w = layer.get("weights")
        for i, (x, y) in enumerate(layer["points"]):
            rows.append(f"    {{{layer['z_cmm']}, {x}, {y}, {w[i] if w else 255}}},")
    return f"static const BkvPoint bkv_{name}_points[] BKV_FLASH = {{\n" + "\n".join(rows) + "\n};\n"


def c_header(files, jsons, transcripts) -> str:
    out = [
        "// Generated by tools/vectors/gen_vectors.py from test/vectors/*.bkm, *.bkr and *.m721.",
        "// Do not edit: rerun the generator (host/tests/bulge/test_mapformat.py checks that this",
        "// file holds exactly the bytes of those files). Include after bulge_map.h.",
        "#ifndef BK_TEST_VECTORS_H",
        "#define BK_TEST_VECTORS_H",
        "",
        "#include <stdint.h>",
        "#ifdef __AVR__",
        "#include <avr/pgmspace.h>",
        "#define BKV_FLASH PROGMEM",
        "#else",
        "#define BKV_FLASH",
        "#endif",
        "",
        "struct BkvPoint {  // expected content, from the vector's JSON",
        "  uint16_t z_cmm;",
        "  int16_t x, y;",
        "  uint8_t w;",
        "};",
        "",
    ]
    embed = [
        "header_only.bkm",
        "tiny.bkm",
        "weights.bkm",
        "extremes.bkm",
        "full_layer.bkm",
        "text_cylinder.bkm",
        "text_tall.bkm",
    ]
    for name in embed:
        ident = Path(name).stem
        out.append(f"// {name}: {jsons[name]['description']}")
        out.append(f"static const uint8_t bkv_{ident}[{len(files[name])}] BKV_FLASH = {{")
        out.append(c_bytes(files[name]))
        out.append("};")
        out.append(f"static const uint32_t bkv_{ident}_crc32 = {jsons[name]['crc32']}UL;")
        if 0 < jsons[name]["point_count"] <= 64:
            out.append(c_points(ident, jsons[name]))
        out.append("")
    bad = [n for n in files if jsons[n]["kind"] == "bad"]
    blob = b"".join(files[n] for n in bad)
    out.append("// The corrupt vectors bad_*.bkm, back to back; bkv_bad[] indexes them.")
    out.append(f"static const uint8_t bkv_bad_blob[{len(blob)}] BKV_FLASH = {{")
    out.append(c_bytes(blob))
    out.append("};")
    out.append("struct BkvBad {")
    out.append("  uint16_t offset, len;")
    out.append("  int8_t error;  // bk::MapError expected")
    out.append("};")
    out.append("static const BkvBad bkv_bad[] BKV_FLASH = {")
    off = 0
    for n in bad:
        code = "bk::MAP_ERR_" + jsons[n]["expect_error"].upper()
        out.append(f"    {{{off}, {len(files[n])}, {code}}},  // {n}")
        off += len(files[n])
    out.append("};")
    out.append(f"static const uint8_t bkv_bad_count = {len(bad)};")
    out.append("")
    for name, text in transcripts.items():
        ident = Path(name).stem
        out.append(f"// {name}")
        out.append(f"static const char bkv_{ident}_m721[] BKV_FLASH =")
        out.append(c_string(text) + ";")
        out.append("")
    out.append("#endif  // BK_TEST_VECTORS_H")
    return "\n".join(out) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "test" / "vectors")
    ap.add_argument("--check", action="store_true", help="compare a fresh run with --out; exit 1 if different")
    args = ap.parse_args()
    if args.check:
        with tempfile.TemporaryDirectory() as tmp:
            generate(Path(tmp))
            names = sorted(p.name for p in Path(tmp).iterdir())
            have = sorted(p.name for p in args.out.iterdir() if p.suffix in (".bkm", ".bkr", ".json", ".m721", ".h"))
            _, mismatch, errors = filecmp.cmpfiles(tmp, args.out, names, shallow=False)
            if names != have or mismatch or errors:
                print(f"{args.out}: stale vectors: {mismatch + errors or sorted(set(names) ^ set(have))}")
                return 1
        print(f"{args.out}: vectors up to date ({len(names)} files)")
        return 0
    generate(args.out)
    cyl = mf.decode_map((args.out / "text_cylinder.bkm").read_bytes())
    size = (args.out / "text_cylinder.bkm").stat().st_size
    print(
        f"text_cylinder.bkm: {len(cyl.layers)} layers, {cyl.point_count} points, {size} bytes, "
        f"{size / cyl.point_count:.2f} bytes/point (header 8 bytes)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
