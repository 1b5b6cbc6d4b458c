"""The compiled move scanner (bulgekit/gcode/_scan.c) and the planner's skipping of moves that cannot
matter (fallback.Skipper) give exactly what the Python parser and a planner run over every move
give: same numbers to the bit, same stops, same files."""
from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from bulgekit.bulge import mapformat
from bulgekit.gcode import movescan
from bulgekit.bulge.fallback import (RefPlanner, RewriteResult, Settings, StockStops, plan_records, rewrite,
                               rewrite_file)
from bulgekit.gcode import GcodeError, parse_lines

DATA = Path(__file__).parents[1] / "data"
FILES = sorted(DATA.glob("*.gcode"))

TRICKY = (b"; generated\r\n;TYPE:External perimeter\r\nG1 X10 Y10 E1 F1200\rG01 x20 y10 e2\n"
          b"N12 G1 X30 Y5 E3*45\n  g1  X31 Y6 E3.5 ; hi\n; \xc3\xa9t\xc3\xa9 comment\n"
          b";FEATURE: Outer wall\nG2 X40 Y5 I5 J0 E4\nG3 X30 Y5 R5 E5\nG91\nG1 X1 Y1 E0.1\nG90\nM83\n"
          b"G1 X5 Y5 E.2 Z.3\nG92 E0 X1\nG1 X2 Y2 E1\n; outer perimeter\nG1 X3 Y3 E1e5\n"
          b"G1X5 Y5\nG1.5 X1\nG1 X-.5 Y+.5 E+1. ,Z3\n;TYPE:Outer wall \xe2\x80\x94 x\nG1 X9 Y9 E1\n"
          b"; TYPE:Perimeter\n\xc2\xa0;TYPE:WALL-OUTER\nG1 X8 Y8 E1\r\rG1 X7 Y7 E1\n\nG0 X1 Y1")


def _all(chunks):
    parts = list(chunks)
    a = np.concatenate(parts) if parts else np.empty(0, movescan.RECORD)
    return a, [chunks.roles[i] if i >= 0 else None for i in a["role"]], chunks.lines


def _same(p, q):
    (a, ra, la), (b, rb, lb) = p, q
    assert (len(a), la, ra) == (len(b), lb, rb)
    for k in ("x0", "y0", "z0", "x1", "y1", "z1", "e", "e_start", "f"):
        assert np.array_equal(a[k].view(np.uint64), b[k].view(np.uint64)), k   # to the bit
    for k in ("line_no", "flags"):
        assert np.array_equal(a[k], b[k]), k


def test_the_compiled_scanner_is_built():
    # make deps builds it (host/setup.py); without it every pass reads G-code in Python
    assert movescan.available(), "bulgekit.gcode._scan is not built: pip install -e host with a C compiler"
    from click.testing import CliRunner
    from bulgekit.cli import main
    assert "(G-code scanner: compiled)" in CliRunner().invoke(main, ["--version"]).output


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_scanner_gives_the_python_parsers_moves(path):
    _same(movescan.run(path, _all, fast=True), movescan.run(path, _all, fast=False))


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 64, 1 << 20])
def test_scanner_on_odd_lines_and_every_chunk_boundary(tmp_path, monkeypatch, chunk):
    # CR, CRLF and lone CR line ends (a CR at a chunk's end), line numbers and checksums, arcs,
    # G91/M83, words split by letters ("1e5"), a command without a blank ("G1X5" is none),
    # roles from FEATURE:, Simplify3D and non-ASCII comments (one behind a no-break space)
    g = tmp_path / "t.gcode"
    g.write_bytes(TRICKY)
    monkeypatch.setattr(movescan, "CHUNK_BYTES", chunk)
    fast = movescan.run(g, _all, fast=True)
    _same(fast, movescan.run(g, _all, fast=False))
    a, roles, lines = fast
    # the same G-code given as bytes is scanned in windows of it: the same records and offsets
    mem = movescan.run(TRICKY, _all, fast=True)
    _same(mem, fast)
    assert np.array_equal(mem[0]["offset"], a["offset"])
    assert lines == 31 and len(a) > 40
    assert roles[0] == "external perimeter" and "wall-outer" in roles and "outer wall — x" in roles
    assert a["offset"][0] == TRICKY.index(b"G1 X10")


def test_lines_the_scanner_refuses_go_to_the_python_parser(tmp_path):
    bad = tmp_path / "bad.gcode"
    bad.write_bytes(b"G1 X1 Y1\nG1 X1O Y2\n")
    with pytest.raises(movescan.Unsupported):
        movescan.run(bad, _all, fast=True)
    with pytest.raises(GcodeError, match=r"bad.gcode:2: unparsable value 'X1O'"):
        movescan.run(bad, _all)
    odd = tmp_path / "odd.gcode"              # a no-break space inside a command line
    odd.write_bytes("G1 X1 Y1\nG1 X2\u00a0Y3 E1\n".encode())
    a, _, _ = movescan.run(odd, _all)
    assert a["y1"][-1] == 3.0


def _random_map(path: Path, rng: random.Random, geometric: bool):
    """Points on, near and just beyond the ends of outer-wall moves (deferred points), some
    merged, some on layers the print never reaches, and weights."""
    moves = [m for ln in parse_lines(path.read_text().splitlines(keepends=True))
             for m in ln.moves if m.e > 0 and (m.outer or geometric) and not m.arc]
    by_z: dict[float, list] = {}
    for m in rng.sample(moves, min(400, len(moves))):
        t = rng.choice([0.0, 1.0, 1.002, rng.random(), rng.random()])
        x, y = m.x0 + t * (m.x1 - m.x0), m.y0 + t * (m.y1 - m.y0)
        x += rng.uniform(-0.12, 0.12)
        y += rng.uniform(-0.12, 0.12)
        by_z.setdefault(round(m.z1, 2), []).append((x, y))
        if rng.random() < 0.1:
            by_z[round(m.z1, 2)].append((x + 0.02, y))       # merged with the one before
    by_z[round(max(by_z) + 5.0, 2)] = [(10.0, 10.0)]
    layers = sorted(by_z.items())
    weights = [[rng.randint(1, 255) for _ in pts] for _, pts in layers]
    return mapformat.decode_map(mapformat.encode_map(layers, weights=weights))


def _full(path, bm, settings, arcs_bypass):
    ref = RefPlanner(bm, settings)
    for ln in parse_lines(path.read_text().splitlines(keepends=True), str(path)):
        for m in ln.moves:
            if not (arcs_bypass and m.arc):      # (bypassed: the firmware never sees an arc)
                ref.plan(m)
    return ref


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_skipping_moves_changes_nothing_the_planner_does(path):
    rng = random.Random(path.name)
    for trial in range(4):
        geometric = trial % 2 == 1 or path.name.startswith("slic3r")
        settings = Settings(mode=2 if geometric else 1, dwell_ms=rng.choice([0, 100, 700]),
                            extra_e=rng.choice([0.0, 0.1, 0.9]),
                            tolerance=rng.choice([0.05, 0.15, 0.6]))
        bm = _random_map(path, rng, geometric)
        for bypass in (False, True):
            ref = _full(path, bm, settings, bypass)
            assert ref.stops, "the map must make stops for this test to mean something"
            # lazy: the move after a picked one only when owed; lean (annotate's reach check in
            # marked mode): from the scanner's records of outer-wall moves, extruding arc chords
            # and the first moving move after an outer-wall one only
            runs = [(False, False), (True, False)] + [(True, True)] * (bypass and not geometric)
            for lazy, lean in runs:
                fast = RefPlanner(bm, settings)
                movescan.run(path, lambda ch: plan_records(fast, ch, arcs_bypass=bypass, lazy=lazy),
                             lean=lean)
                assert fast.stops == ref.stops
                assert fast.stats == ref.stats and fast.top_z == ref.top_z


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_skipping_the_layers_no_map_layer_is_near_changes_nothing(path):
    """A map on a few layers (a text on a tall print): the moves of layers with no map layer
    within half a layer height are not planned, yet the stops, the window's layer loads and the
    drops are those of a planner that saw every move; also with a layer record without points
    (a BulgeMap built in code), which the window loads like any other."""
    rng = random.Random("sparse" + path.name)
    geometric = path.name.startswith("slic3r")
    full = _random_map(path, rng, geometric)
    zs = sorted({l.z_cmm for l in full.layers})
    keep = set(zs[len(zs) // 3: len(zs) // 3 + 3])
    layers = [l for l in full.layers if l.z_cmm in keep]
    empty = mapformat.Layer(zs[len(zs) // 2], ())
    bm = mapformat.BulgeMap(full.quantum_um, full.layer_height_cmm, full.has_weights,
                            sorted(layers + [empty], key=lambda l: l.z_cmm))
    settings = Settings(mode=2 if geometric else 1, extra_e=0.9)
    for bypass in (False, True):
        ref = _full(path, bm, settings, bypass)
        lazy = RefPlanner(bm, settings)
        movescan.run(path, lambda ch: plan_records(lazy, ch, arcs_bypass=bypass, lazy=True))
        assert lazy.stops == ref.stops and lazy.stats == ref.stats
        fast = RefPlanner(bm, settings)
        picked = []
        movescan.run(path, lambda ch: plan_records(fast, ch, lambda m, a: picked.append(m),
                                                   arcs_bypass=bypass))
        assert ref.stops and ref.stats.layers_loaded >= 3
        assert fast.stops == ref.stops
        assert fast.stats == ref.stats and fast.top_z == ref.top_z
        # and the layers far from the map's went by unplanned
        half = bm.layer_height_cmm / 2
        assert all(any(abs(round(m.z1 * 100) - l.z_cmm) <= half + 1 for l in bm.layers)
                   or m.e <= 0 for m in picked)


@pytest.mark.parametrize("stops", [StockStops(), StockStops("g4"), StockStops(e_steps=415, stop_e_steps=9)],
                         ids=["move", "g4", "move415"])
@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_fallback_file_is_the_same_by_either_path(path, tmp_path, stops):
    rng = random.Random("fallback" + path.name)
    geometric = path.name.startswith("slic3r")
    settings = Settings(mode=2 if geometric else 1, extra_e=0.3)
    bm = _random_map(path, rng, geometric)
    out = tmp_path / "out.gcode"
    res = rewrite_file(path, out, bm, settings, allow_unreached=True, stops=stops)    # bytes copied
    text_res = RewriteResult()
    text = "".join(rewrite(path.read_text().splitlines(keepends=True), bm, settings, str(path),
                           text_res, stops))
    assert res.moves_split > 10
    assert out.read_text() == text
    assert (res.lines_in, res.moves_split, res.stops, res.stats, res.unreached) == \
        (text_res.lines_in, text_res.moves_split, text_res.stops, text_res.stats, text_res.unreached)
    assert res.stock.summary() == text_res.stock.summary()
    assert vars(res.stock) == vars(text_res.stock)


def test_scanner_numbers_are_floats_bit_for_bit():
    """The scanner's short-number path (digits over a power of ten) and its strtod path give
    float()'s double, sign of zero included, for values of 1 to 20 digits."""
    rnd = random.Random(7)
    vals = ["-0", "0", "+5", ".5", "-.25", "5.", "123456789012345", "1234567890.12345",
            "1234567890123456", "0.30000000000000004", "9007199254740993"]
    for _ in range(20000):
        a, b = str(rnd.randint(0, 10 ** rnd.randint(0, 10))), str(rnd.randint(0, 10 ** rnd.randint(0, 9)))
        vals.append(rnd.choice(["", "-"]) + a + rnd.choice(["", "." + b[:rnd.randint(0, 9)]]))
    text = "".join(f"G1 X{v} Y1\n" for v in vals).encode()
    got = movescan.run(text, lambda ch: np.concatenate(list(ch)), fast=True)["x1"]
    assert np.array_equal(got.view(np.uint64), np.array([float(v) for v in vals]).view(np.uint64))


def test_move_classes_compiled_are_numpys():
    """movescan.classes from the compiled scanner (one pass over the records) gives numpy's
    bits and highest z to the bit, on every test file's moves and on edge values: coordinates
    equal in float32 but not in double, an E that float32 rounds to 0, -0.0, inf, a NaN z."""
    assert movescan.available()
    arrays = [a.copy() for path in FILES for a in movescan.run(path, lambda ch: list(ch))]
    rng = np.random.default_rng(26)
    edge = np.zeros(4000, movescan.RECORD)
    vals = np.array([0.0, -0.0, 1.0, 1.0 + 1e-12, 1e-46, -1e-46, 0.3, np.inf, -np.inf, 2.5, 1e39])
    for k in ("x0", "y0", "z0", "x1", "y1", "z1", "e"):
        edge[k] = rng.choice(vals, len(edge))
    edge["z1"][rng.choice(len(edge), 5)] = np.nan
    edge["flags"] = rng.integers(0, 16, len(edge))
    arrays += [edge, edge[:0], edge[edge["e"] <= 0][:50]]
    bits = 0
    for a in arrays:
        c, top, top_line = movescan.classes(a)
        n, ntop, ntop_line = movescan._classes_np(a)
        assert np.array_equal(c, n)
        for x, y in ((top, ntop), (top_line, ntop_line)):
            assert (x is None and y is None) or np.array(x).tobytes() == np.array(y).tobytes()
        bits |= int(np.bitwise_or.reduce(c)) if len(c) else 0
    assert bits == 63                               # every bit seen set


def test_scanner_counts_the_line_ends_it_consumes():
    """Scanner.line_ends, which Scan takes in place of counting each part's bytes, is bytes.count
    of \\n, \\r and \\r\\n over what feed() consumed, a \\r\\n cut between two feeds counted once."""
    from bulgekit import gcode
    rng = random.Random(26)
    for trial in range(200):
        data = b"".join(rng.choice([b"G1 X1 E1", b"; c", b"", b"M83"]) + rng.choice([b"\n", b"\r\n", b"\r"])
                        for _ in range(rng.randint(0, 30)))
        if trial % 3 == 0:
            data += b"G1 X2"                                   # no line end at the end
        sc = movescan._scan.Scanner(sorted(gcode.OUTER_ROLES), sorted(gcode._S3D_ROLES),
                                    movescan._classify)
        buf, pos = b"", 0
        while True:
            step = rng.randint(0, 9)
            piece = data[pos:pos + step]
            pos += len(piece)
            final = pos >= len(data) and (step > 0 or rng.random() < 0.5)
            buf += piece
            _, used = sc.feed(buf, final)
            consumed = buf[:used]
            buf = buf[used:]
            if final:
                break
        assert sc.line_ends == (data.count(b"\n"), data.count(b"\r"), data.count(b"\r\n")), data


def test_z_cmm_of_runs_is_z_cmm_of_each():
    """z_cmm takes each run of one z once (a file's layers): the same as one value at a time,
    -0.0 in a run of 0.0, halves, and values beyond an int's range included."""
    rng = np.random.default_rng(26)
    vals = np.array([0.2, 0.3, -0.0, 0.0, 0.25, -0.35, 0.005, 0.015, 0.125, 1234.565, -0.004999])
    z = np.repeat(rng.choice(vals, 5000), rng.integers(1, 30, 5000))
    runs = movescan.z_cmm(z)
    assert len(np.flatnonzero(np.diff(z))) * 4 < len(z)            # the runs path was taken
    assert np.array_equal(runs, movescan._z_cmm(z))
    assert np.array_equal(runs, [fallback_cmm(v) for v in z])
    short = z[:50]
    assert np.array_equal(movescan.z_cmm(short), movescan._z_cmm(short))


def fallback_cmm(v):
    return RefPlanner._cmm(v)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_lean_records_are_the_full_ones_a_lazy_reach_check_can_plan(path):
    """lean=True: the scanner's records are the full scan's records (the same bytes) of every
    outer-wall move, every extruding arc chord, and each first move after an outer-wall one
    that moves and is no chord, no others; Chunks.tops holds classes()' top_not_arc of all
    moves; a lean run is refused where it would not hold what the planning needs."""
    full, _, _ = movescan.run(path, _all, fast=True)
    got = []

    def lean_all(ch):
        got.append(_all(ch))
        got.append(list(ch.tops))
    movescan.run(path, lean_all, fast=True, lean=True)
    (lean, _, _), tops = got
    c, _, top_line = movescan.classes(full)
    keep = ((full["flags"] & movescan.OUTER) != 0) | (((c & movescan.ARC) != 0) & (full["e"] > 0))
    follow = False
    want = keep.copy()
    for i in range(len(full)):
        if full["flags"][i] & movescan.OUTER:
            follow = True
        elif follow and not c[i] & (movescan.NULL | movescan.ARC):
            want[i], follow = True, False
    assert lean.tobytes() == full[want].tobytes()
    assert len(lean) < len(full) or not len(full)
    seen = [t for t in tops if t is not None]
    assert (max(seen) if seen else None) == top_line
    with pytest.raises(ValueError, match="lean chunks"):
        movescan.run(path, lambda ch: plan_records(RefPlanner(None, Settings()), ch), lean=True)
