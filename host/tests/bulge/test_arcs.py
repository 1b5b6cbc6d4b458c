"""Arc-fitted files (issue 36, item 3): the G2/G3 arcs on which map points lie are written as G1
chords, Marlin's own segments, by `build` (annotated and stock file), `annotate`, `fallback` and
`post-process` alike, so every point stops when printed, in both outputs, and the counts said are
the firmware's. The input: real PrusaSlicer slices (data/prusa_cyl*.gcode) arc-fitted here by
tools/arc_fit.py (Debian's PrusaSlicer 2.5 has no arc fitting)."""
from __future__ import annotations

import importlib.util
import math
import random
import re
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bulgekit import gcode
from bulgekit.bulge import fallback, mapformat
from bulgekit.bulge.annotate import annotate_bytes
from bulgekit.bulge.fallback import RefPlanner, Settings
from bulgekit.cli import main
from bulgekit.gcode import movescan, parse_lines

HERE = Path(__file__).resolve().parents[1]
TOOLS = HERE.parents[1] / "tools"
INSERTED = re.compile(r"^(M72[0-2]\b|; bulgekit)")
ARC = re.compile(r"^\s*G0?[23]\b", re.I)


def _tool():
    spec = importlib.util.spec_from_file_location("arc_fit", TOOLS / "arc_fit.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


arc_fit = _tool()


@pytest.fixture(scope="module", params=["prusa_cyl", "prusa_cyl_m83"])
def fitted(request, tmp_path_factory):
    """(the arc-fitted slice, its source) for M82 and M83 E."""
    src = HERE / "data" / f"{request.param}.gcode"
    out, f = arc_fit.fit_text(src.read_text().splitlines(keepends=True))
    assert f.arcs > 50 and f.deviation <= 0.025
    p = tmp_path_factory.mktemp("arcs") / f"{request.param}_arcs.gcode"
    p.write_text("".join(out))
    return p, src


@pytest.fixture(scope="module")
def built(fitted, tmp_path_factory):
    """`bulgekit build --fallback` of the arc-fitted file: the output folder."""
    p, _ = fitted
    out = tmp_path_factory.mktemp("built")
    r = CliRunner().invoke(main, ["build", str(p), "--text", "HI", "--at", "5,3", "-o", str(out),
                                  "--fallback", "--no-preview", "--quiet"])
    assert r.exit_code == 0, r.output
    return out


def outputs(p: Path, out: Path):
    stem = p.stem
    return ((out / f"{stem}.bkm").read_bytes(), (out / f"{stem}.bulge.gcode").read_text(),
            (out / f"{stem}.stock.gcode").read_text(), (out / f"{stem}.stats.txt").read_text())


def firmware(text: str, bm, settings=Settings()) -> RefPlanner:
    """The firmware printing an annotated file, by its mirror: every G0/G1 move planned, inside
    the outer wall between M722 S1 and M722 S0; a G2/G3 not seen at all (Marlin cuts it into
    segments past bulgekit's hook)."""
    ref = RefPlanner(bm, settings)
    inside = False
    for ln in parse_lines(text.splitlines(keepends=True)):
        if ln.cmd == "M722":
            inside = ln.raw.split()[1] == "S1"
        for m in ln.moves:
            if not m.arc:
                ref.plan(m, outer=inside)
    return ref


def test_arc_fit_turns_the_real_walls_into_arcs_that_keep_the_path_and_the_filament(fitted):
    p, src = fitted
    text = p.read_text()
    assert len(text.splitlines()) < 0.5 * len(src.read_text().splitlines())
    moves = lambda f: [m for ln in parse_lines(f.read_text().splitlines(keepends=True)) for m in ln.moves]
    a, b = moves(src), moves(p)
    # the whole outer wall of a layer: one arc and the move or two left at its seam
    outer_arcs = {m.line_no for m in b if m.arc and m.outer and m.e > 0}
    assert len(outer_arcs) >= 33
    assert sum(m.e for m in a if m.e > 0) == pytest.approx(sum(m.e for m in b if m.e > 0), abs=1e-6)
    ends = lambda ms: [(m.x1, m.y1, m.z1) for m in ms]
    assert ends(a)[-1] == ends(b)[-1]
    # every point of the original path lies within the tolerance of the arcs' chords
    pts = np.array([(m.x1, m.y1) for m in a if m.outer and m.e > 0 and m.z1 == 3.0])
    segs = np.array([(m.x0, m.y0, m.x1, m.y1) for m in b if m.outer and m.e > 0 and m.z1 == 3.0])
    d = np.min([_dist(pts, s) for s in segs], axis=0)
    assert d.max() < 0.025 + gcode.ARC_CHORD_DEVIATION_MM


def _dist(p, s):
    x0, y0, x1, y1 = s
    dx, dy = x1 - x0, y1 - y0
    l2 = dx * dx + dy * dy
    t = np.clip(((p[:, 0] - x0) * dx + (p[:, 1] - y0) * dy) / l2, 0, 1) if l2 else 0.0
    return np.hypot(p[:, 0] - x0 - t * dx, p[:, 1] - y0 - t * dy)


def test_build_annotate_fallback_and_post_process_write_the_same_chords(fitted, built, tmp_path):
    p, _ = fitted
    bkm, ann, stock, stats = outputs(p, built)
    run = lambda *a: CliRunner().invoke(main, [str(x) for x in a])
    r = run("annotate", p, built / f"{p.stem}.bkm", "-o", tmp_path / "a.gcode")
    assert r.exit_code == 0, r.output               # (it refused points on arcs before)
    assert (tmp_path / "a.gcode").read_text() == ann
    n = len(re.findall(r"^; bulgekit: (\d+) G2/G3 arcs", ann, re.M))
    assert n == 1 and re.search(r"\d+ G2/G3 arcs through map points written as \d+ G1 chords", r.output)
    r = run("fallback", p, built / f"{p.stem}.bkm", "-o", tmp_path / "f.gcode")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "f.gcode").read_text() == stock
    # post-process: the same drawing from a placement file, in place, both ways
    place = tmp_path / "p.toml"
    for fb in (False, True):
        place.write_text('[[text]]\ntext = "HI"\nat = [5, 3]\n' + ("[bulges]\nfallback = true\n" if fb else ""))
        q = tmp_path / p.name
        q.write_bytes(p.read_bytes())
        r = run("post-process", "--placement", place, q)
        assert r.exit_code == 0, r.output
        assert re.search(r"\(\d+ G2/G3 arcs through them as G1 chords\)", r.output)
        assert q.read_text() == (stock if fb else ann)


def test_every_point_stops_in_both_outputs_and_the_counts_say_so(fitted, built):
    p, _ = fitted
    bkm, ann, stock, stats = outputs(p, built)
    bm = mapformat.decode_map(bkm)
    assert bm.point_count >= 40
    # the firmware on the annotated file: every point stops ...
    fw = firmware(ann, bm)
    assert fallback.unreached(fw) == [] and len(fw.stops) == bm.point_count
    # ... and the arcs left as they were would have missed them all: the file as sliced
    assert len(firmware(p.read_text(), bm).stops) < bm.point_count / 4
    # the stock file's planner run: the same stops, where the firmware makes them
    res = fallback.RewriteResult()
    "".join(fallback.rewrite(p.read_text().splitlines(keepends=True), bm, Settings(), str(p), res))
    assert res.stats.points_fired == bm.point_count
    key = lambda s: (s.layer_z_cmm, s.point)
    for a, b in zip(sorted(fw.stops, key=key), sorted(res.stops, key=key)):
        assert key(a) == key(b) and a.ms == b.ms
        assert math.hypot(a.x - b.x, a.y - b.y) < 1e-4 and a.z == pytest.approx(b.z, abs=1e-4)
    # one stop move in the stock file per place the head stops
    e_only = lambda t: len(re.findall(r"^G1 E[0-9.]+ F[0-9.]+$", t, re.M))
    assert e_only(stock) - e_only(p.read_text()) == len({(s.line_no, s.x, s.y) for s in res.stops})
    assert f"stops when printed: {bm.point_count} of {bm.point_count} points" in stats
    arcs = re.search(r"^arcs: (\d+) G2/G3 arcs through map points written as (\d+) G1 chords, "
                     r"Marlin's own segments \(at most 1 mm; within (0\.\d+) mm of the arc\)", stats, re.M)
    assert arcs and int(arcs[1]) == len(bm.layers)      # (a layer's outer wall: one arc)
    assert 0 < float(arcs[3]) <= gcode.ARC_CHORD_DEVIATION_MM
    assert f"; bulgekit: {arcs[0][6:]}" in ann and f"; bulgekit fallback: {arcs[0][6:]}" in stock


def _replaced(original: str, annotated: str):
    """Walk the annotated file against its source: the lines bulgekit inserted left out, every
    other line as it was, but the arcs written as chords. Yields (the arc's line, its chord lines,
    the source's parsed line) for those."""
    src = list(parse_lines(original.splitlines(keepends=True)))
    out = [l for l in annotated.splitlines() if not INSERTED.match(l)]
    j = 0
    for ln in src:
        line = ln.raw.rstrip("\r\n")
        if out[j] == line:
            j += 1
            continue
        assert ARC.match(line), (ln.line_no, line, out[j])
        n = len(ln.moves)
        yield line, out[j:j + n], ln
        j += n
        if ";" in line:                         # (the arc's comment: a line of its own after)
            assert out[j] == line[line.index(";"):]
            j += 1
    assert j == len(out)


def test_the_chords_are_marlins_segments_with_the_arcs_e_exactly(fitted, built):
    p, _ = fitted
    bkm, ann, stock, stats = outputs(p, built)
    bm = mapformat.decode_map(bkm)
    n_chords = int(re.search(r"written as (\d+) G1 chords", ann)[1])
    got = list(_replaced(p.read_text(), ann))
    assert got and sum(len(c) for _, c, _ in got) == n_chords
    relative = "M83" in p.read_text()
    for line, chords, ln in got:
        ms = ln.moves
        # Marlin's count, and each chord ends where the parser's (the planner's) does
        w = ln.words
        _, _, r, _, sweep, n = gcode.arc_geometry(ms[0].x0, ms[0].y0, ms[-1].x1, ms[-1].y1, w,
                                                  ln.cmd == "G2", "t")
        assert len(chords) == n == gcode.arc_segments(r, sweep) >= math.ceil(r * abs(sweep))
        words = [dict((k, v) for k, v in re.findall(r"([XYZEF])(-?[0-9.]+)", c)) for c in chords]
        for m, wd in zip(ms, words):
            assert abs(float(wd["X"]) - m.x1) <= 5e-6 and abs(float(wd["Y"]) - m.y1) <= 5e-6
        assert (words[-1]["X"], words[-1]["Y"]) == tuple(re.search(r"X(\S+) Y(\S+)", line).groups())
        assert ("F" in words[0]) == ("F" in w) and all("F" not in wd for wd in words[1:])
        e = re.search(r"E(\S+)", line)[1]
        if relative:                            # the pieces add up to the arc's E, as decimals
            assert sum(Decimal(wd["E"]) for wd in words) == Decimal(e)
            assert max(abs(Decimal(wd["E"]) - Decimal(e) / n) for wd in words) <= Decimal("0.00001")
        else:                                   # the last chord ends on the arc's E
            assert Decimal(words[-1]["E"]) == Decimal(e)
            es = [Decimal(wd["E"]) for wd in words]
            e0 = Decimal(str(round(ms[0].e_start, 5)))
            steps = np.diff([float(e0)] + [float(v) for v in es])
            assert np.allclose(steps, (float(e) - ms[0].e_start) / n, atol=1.1e-5)
    # no arc left in an outer wall where a point lies within the tolerance of one of its chords
    lines = list(parse_lines(ann.splitlines(keepends=True)))
    for ln in lines:
        if ln.moves and ln.moves[0].arc and ln.moves[0].outer and ln.moves[0].e > 0:
            for m in ln.moves:
                layer = [l for l in bm.layers if abs(l.z_cmm - round(m.z1 * 100)) * 2 <= bm.layer_height_cmm]
                q = bm.quantum_um / 1000
                for l in layer:
                    pts = np.array(l.points, float) * q
                    assert _dist(pts, (m.x0, m.y0, m.x1, m.y1)).min() > 0.25, ln.line_no
    # the arcs through no point stay as they were (infill, inner walls, layers without points)
    left = sum(1 for l in ann.splitlines() if ARC.match(l))
    assert left == sum(1 for l in p.read_text().splitlines() if ARC.match(l)) - len(got) > 0


def test_a_helical_arc_and_relative_moves_land_on_the_arcs_own_numbers():
    # G91 X/Y/Z and M83: each chord's pieces are running totals, so they add up to the arc's
    # words exactly; Z rises in equal steps over the chords
    g = ("G90\nM83\nG1 Z0.3 F600\n;TYPE:External perimeter\nG1 X0 Y0 F1800\nG91\n"
         "G2 X20 Y0 Z0.3 I10 J0 E2.123457 ; wall\nG1 X-20 E1.5\nG90\n")
    m = mapformat.encode_map([(0.6, [(10.0, 10.0)])])
    out = annotate_bytes(g.encode(), m, Settings(), source="t.gcode").decode()
    chords = [l for l in out.splitlines() if l.startswith("G1 X") and " Z" in l]
    assert len(chords) == gcode.arc_segments(10.0, math.pi) == 36
    total = lambda k: sum(Decimal(re.search(fr"{k}(-?[0-9.]+)", c)[1]) for c in chords)
    assert (total("X"), total("Y"), total("Z"), total("E")) == (20, 0, Decimal("0.3"), Decimal("2.123457"))
    z = [Decimal(re.search(r"Z(-?[0-9.]+)", c)[1]) for c in chords]
    assert max(z) - min(z) <= Decimal("0.00001")
    assert out.splitlines()[out.splitlines().index(chords[-1]) + 1] == "; wall"
    assert "F1800" not in chords[0]          # (the arc had no F: none is added)
    fw = firmware(out, mapformat.decode_map(m))
    assert len(fw.stops) == 1 and abs(fw.stops[0].z - 0.45) < 0.01


def test_the_compiled_scanner_cuts_arcs_as_the_parser_to_the_bit(tmp_path):
    if not movescan.available():
        pytest.skip("bulgekit.gcode._scan is not built")
    rng = random.Random(36)
    lines = ["G90", "M82", "G92 E0", "G1 X100 Y100 Z0.2 F3000"]
    e = 0.0
    for k in range(400):
        r = rng.choice([0.3, 0.9, 1.2, 5, 11.459, 11.46, 20, 60, 300])
        a = rng.uniform(-math.pi, math.pi)
        e += rng.uniform(0, 2)
        word = rng.choice(["ij", "ij", "r", "circle"])
        cw = rng.random() < 0.5
        if word == "circle":
            lines.append(f"G{2 if cw else 3} I{r * math.cos(a):.4f} J{r * math.sin(a):.4f} E{e:.5f}")
            continue
        x, y = 100 + rng.uniform(-50, 50), 100 + rng.uniform(-50, 50)
        z = f" Z{0.2 + k * 0.01:.2f}" if rng.random() < 0.2 else ""
        if word == "r":
            lines.append(f"G{2 if cw else 3} X{x:.3f} Y{y:.3f}{z} R{rng.choice([-1, 1]) * 80} E{e:.5f}")
        else:
            lines.append(f"G{2 if cw else 3} X{x:.3f} Y{y:.3f}{z} I{rng.uniform(-r, r):.3f} "
                         f"J{rng.uniform(-r, r):.3f} E{e:.5f}")
    p = tmp_path / "arcs.gcode"
    p.write_text("\n".join(lines) + "\n")
    got = [np.concatenate(list(ch)) for ch in (movescan._fast(p), movescan._slow(p, str(p)))]
    assert len(got[0]) == len(got[1]) > 400
    for k in ("x0", "y0", "z0", "x1", "y1", "z1", "e", "e_start", "line_no", "flags"):
        assert np.array_equal(got[0][k], got[1][k]), k
    # and the estimator cuts them the same: one block per segment
    from bulgekit.gcode import estimate
    blocks = estimate.estimate_file(p, estimate.Machine(min_segment_steps=0), blocks=True).blocks
    per_line = np.bincount(got[1]["line_no"])
    assert np.array_equal(np.bincount(blocks["line"], minlength=len(per_line))[5:], per_line[5:])


def test_marlins_segment_count():
    # plan_arc with Marlin 2.1's defaults: whole 1 mm segments, at least 72 a turn, none shorter
    # than 0.1 mm
    s = gcode.arc_segments
    assert s(20, 2 * math.pi) == math.ceil(40 * math.pi) == 126      # 1 mm apart
    assert s(20, 0.275) == 6                                          # 5.5 mm: 6 of 0.92 mm
    assert s(5, math.pi) == 36                                        # 5 degrees: 0.44 mm
    assert s(0.5, math.pi) == 15                                      # not below 0.1 mm
    assert s(1000, 0.0001) == 1
    assert s(1 / math.radians(5), math.radians(5)) == 1
    worst = max(r * (1 - math.cos(abs(a) / (2 * s(r, a))))
                for r in np.linspace(0.2, 400, 4001) for a in (0.3, 2, 2 * math.pi))
    assert worst <= gcode.ARC_CHORD_DEVIATION_MM < 0.011
