"""build in marked mode keeps only the lean records (movescan.Scan(..., lean=True): outer-wall
moves, the first move after one, every arc chord, numbered): its walls, planner runs, stock file
and statistics are those of the scan that keeps every record, held in memory or in the temporary
file, also on a file with arcs inside and outside the outer wall."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bulgekit.bulge import api, mapformat
from bulgekit.bulge.fallback import RefPlanner, Settings, plan_records
from bulgekit.bulge.strokes import text_strokes
from bulgekit.bulge.wall import walls_from_gcode
from bulgekit.gcode import movescan

HERE = Path(__file__).resolve().parents[1]
FILES = [HERE / "data" / n for n in ("cura_cyl.gcode", "prusa_cyl.gcode", "prusa_cyl_m83.gcode",
                                     "prusa_vase.gcode")]


@pytest.fixture(autouse=True)
def _compiled_scanner():
    # lean records come from the compiled scanner only: without it these tests would prove nothing
    if not movescan.available():
        pytest.fail("bulgekit.gcode._scan is not built (lean records need it)")


def arcs_gcode(path: Path) -> Path:
    """A 10 mm cylinder (r 10 mm) whose outer wall is two G2 half circles and a few G1 moves,
    with an inner wall, a travel arc outside the wall (G3, no E), an E-only retract, and
    move-less lines outside the wall, one of them all that parts the wall's pieces."""
    out = [";FLAVOR:Marlin", ";Layer height: 0.2", "G90", "M82", "G92 E0", "G1 F1800"]
    e = 0.0
    for k in range(50):
        z = round(0.2 * (k + 1), 2)
        out.append(f";LAYER:{k}")
        out.append(f"G0 X30 Y20 Z{z}")
        out.append(";TYPE:WALL-OUTER")
        e += 3.1
        out.append(f"G2 X10 Y20 I-10 J0 E{e:.5f}")
        e += 3.1
        out.append(f"G2 X30 Y20 I10 J0 E{e:.5f}")
        out.append(";TYPE:WALL-INNER")
        out.append("G1 F1200")                              # moves nothing, outside the wall
        out.append("G3 X29.5 Y20 R0.3")                     # a travel arc right after the wall
        for a in range(0, 360, 30):
            e += 0.2
            out.append(f"G1 X{20 + 9.5 * math.cos(math.radians(a)):.3f} "
                       f"Y{20 + 9.5 * math.sin(math.radians(a)):.3f} E{e:.5f}")
        out.append(f"G1 E{e - 0.8:.5f}")                   # retract
        out.append("G3 X30 Y20 R6")                        # a travel arc
        out.append(f"G1 E{e:.5f}")
        out.append(";TYPE:WALL-OUTER")
        for a in range(0, 361, 45):
            if a == 180:                           # left for a line that moves nothing
                out += [";TYPE:WALL-INNER", "G1 F1500", ";TYPE:WALL-OUTER"]
            e += 0.3
            out.append(f"G1 X{20 + 10.6 * math.cos(math.radians(a)):.3f} "
                       f"Y{20 + 10.6 * math.sin(math.radians(a)):.3f} E{e:.5f}")
        out.append(";TYPE:FILL")
        e += 0.5
        out.append(f"G1 X20 Y20 E{e:.5f}")
    p = path / "arcs.gcode"
    p.write_text("\n".join(out) + "\nM84\n")
    return p


@pytest.fixture(params=[*FILES, "arcs"], ids=lambda p: p if isinstance(p, str) else p.name)
def gcode_file(request, tmp_path):
    return arcs_gcode(tmp_path) if request.param == "arcs" else request.param


def _full_records(path):
    return movescan.run(path, lambda ch: np.concatenate(list(ch)), fast=True)


def test_a_lean_scan_keeps_the_outer_wall_their_followers_and_every_arc_chord(gcode_file, monkeypatch):
    full = _full_records(gcode_file)
    c, _, top_line = movescan.classes(full)
    want = ((full["flags"] & movescan.OUTER) != 0) | ((c & movescan.ARC) != 0)
    follow = False
    for i in range(len(full)):
        if full["flags"][i] & movescan.OUTER:
            follow = True
        elif follow and not c[i] & (movescan.NULL | movescan.ARC):
            want[i], follow = True, False
    for memory in (0, 1 << 30):                 # in the temporary file, in memory
        monkeypatch.setattr(movescan, "LEAN_MEMORY", memory)
        scan = movescan.Scan(gcode_file, lean=True)
        try:
            assert (scan._held is None) == (memory == 0)
            got = scan.run(lambda ch: (list(ch), ch.numbers, ch.tops))
        finally:
            scan.close()
        recs, numbers, tops = got
        assert np.concatenate(recs).tobytes() == full[want].tobytes()
        assert np.concatenate(numbers).tolist() == np.flatnonzero(want).tolist()
        seen = [t for t in tops if t is not None]
        assert max(seen) == top_line
        assert want.sum() < len(full)


def _random_map(path, settings) -> mapformat.BulgeMap:
    """Map points on the outer wall of every third layer, near moves' ends, among them where
    the wall is left (what the move after it must stop)."""
    full = _full_records(path)
    is_outer = (full["flags"] & movescan.OUTER) != 0
    leave = np.flatnonzero(is_outer[:-1] & ~is_outer[1:])
    outer = np.concatenate([full[leave], full[is_outer][::7]])
    by_z: dict = {}
    for r in outer:
        z = round(float(r["z1"]), 2)
        if round(z * 100) % 60 == 0 and len(by_z.get(z, ())) < 3:
            by_z.setdefault(z, []).append((float(r["x1"]) + 0.03, float(r["y1"])))
    return mapformat.decode_map(mapformat.encode_map(sorted(by_z.items())))


@pytest.mark.parametrize("chunk", [997, 1 << 21])
def test_planner_runs_on_a_lean_scan_are_those_on_every_record(gcode_file, monkeypatch, chunk):
    # (small chunks: a move owed to the next chunk, chunks with no lean record)
    monkeypatch.setattr(movescan, "CHUNK_BYTES", chunk)
    settings = Settings(mode=1, extra_e=0.5, dwell_ms=100)
    bm = _random_map(gcode_file, settings)
    for bypass in (False, True):
        for lazy in (False, True):
            got = []
            for lean in (False, True):
                p = RefPlanner(bm, settings)
                scan = movescan.Scan(gcode_file, lean=lean)
                with scan.kept():
                    movescan.run(gcode_file, lambda ch: plan_records(p, ch, arcs_bypass=bypass, lazy=lazy))
                got.append(p)
            full, lean = got
            assert full.stops, "the map must make stops for this test to mean something"
            assert lean.stops == full.stops and lean.stats == full.stats
            assert lean.top_z == full.top_z


@pytest.mark.parametrize("chunk", [997, 1 << 21])
def test_walls_from_a_lean_scan_are_those_from_every_record(gcode_file, monkeypatch, chunk):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", chunk)
    got = []
    for lean in (False, True):
        with movescan.Scan(gcode_file, lean=lean).kept():
            got.append(walls_from_gcode(gcode_file))
    full, lean = got
    assert len(full.walls) == len(lean.walls) > 0
    for a, b in zip(full.walls, lean.walls):
        assert (a.z, a.closed, a.ccw, a.centroid, a.s_ref) == (b.z, b.closed, b.ccw, b.centroid, b.s_ref)
        assert a.xy.tobytes() == b.xy.tobytes() and a.move_index.tolist() == b.move_index.tolist()
    with movescan.Scan(gcode_file, lean=True).kept():
        with pytest.raises(ValueError, match="lean chunks"):
            walls_from_gcode(gcode_file, geometric=True)


@pytest.mark.parametrize("memory, chunk", [(0, 997), (1 << 30, 1 << 21)], ids=["file", "memory"])
def test_build_on_lean_records_writes_the_bytes_of_build_on_every_record(gcode_file, tmp_path,
                                                                          monkeypatch, memory, chunk):
    strokes = text_strokes("HI", 4.0, u0=5, v0=3)
    api.build(gcode_file, strokes, tmp_path / "lean", write_fallback=True)
    real = movescan.Scan
    monkeypatch.setattr(movescan, "Scan", lambda path, source=None, lean=False: real(path, source))
    api.build(gcode_file, strokes, tmp_path / "full", write_fallback=True)
    monkeypatch.setattr(movescan, "Scan", real)
    monkeypatch.setattr(movescan, "LEAN_MEMORY", memory)
    monkeypatch.setattr(movescan, "CHUNK_BYTES", chunk)
    out = api.build(gcode_file, strokes, tmp_path / "lean2", write_fallback=True)
    assert out.stats.stops
    names = sorted(p.name for p in (tmp_path / "full").iterdir())
    assert len(names) == 4
    for n in names:
        full = (tmp_path / "full" / n).read_bytes()
        assert (tmp_path / "lean" / n).read_bytes() == full, n
        assert (tmp_path / "lean2" / n).read_bytes() == full, n
