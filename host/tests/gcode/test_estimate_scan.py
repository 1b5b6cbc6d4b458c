"""The estimator on the compiled scanner's records (estimate._estimate_scanned) gives the blocks
its text parser gives (estimate_lines), bit for bit: on the test files, on stock files with E-only
stops, and on lines picked at random from what slicers and hosts write (tiny moves dropped and
carried, E-only moves, G92 with and without words, G28, G91/M82, M92, M220, M204, G4, arcs, F0,
line numbers and checksums, non-ASCII comments, words without blanks)."""
from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from bulgekit.gcode import estimate as es
from bulgekit.gcode import movescan

DATA = Path(__file__).parents[1] / "data"
FILES = sorted(DATA.glob("*.gcode")) + [Path(__file__).parents[3] / "examples" / "cylinder40x20.gcode"]
MACHINES = [es.Machine(), es.Machine(min_segment_steps=0), es.Machine(jerk={"X": 10, "Y": 10, "Z": 0.3, "E": 5})]


def _same(path):
    assert movescan.available()
    for m in MACHINES:
        a = es.estimate_file(path, m, scanned=False)
        b = es.estimate_file(path, m, scanned=True)
        assert (a.total_s, a.dwell_s, a.by_feature, a.features, a.lines) == \
            (b.total_s, b.dwell_s, b.by_feature, b.features, b.lines)
        assert len(a.blocks) == len(b.blocks)
        for k in a.blocks.dtype.names:
            assert np.array_equal(a.blocks[k], b.blocks[k]), k


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_records_give_the_text_parsers_blocks(path):
    _same(path)


def test_on_stock_files_with_e_only_stops(tmp_path):
    from bulgekit.bulge import api
    from bulgekit.bulge.strokes import text_strokes
    out = api.build(DATA / "prusa_cyl_m83.gcode", text_strokes("HI", 6.0, u0=5, v0=3), tmp_path,
                    write_fallback=True)
    _same(out.fallback_path)


def _random_gcode(seed: int, n: int) -> str:
    r = random.Random(seed)
    x = y = 50.0
    out = ["G90", "M83"]
    lines = [
        (30, lambda: f"G1 X{x:.3f} Y{y:.3f} E{r.uniform(0, 0.004):.5f}"),           # mostly tiny
        (20, lambda: f"G1 X{x + r.uniform(-1, 1):.3f} Y{y + r.uniform(-1, 1):.3f} E{r.uniform(0, 0.05):.5f}"),
        (8, lambda: f"G1 E{r.uniform(-0.02, 0.02):.5f}"),
        (5, lambda: f"G1 E{r.choice(['-0.8', '0.8'])} F{r.choice([1800, 2400])}"),
        (3, lambda: "G92 E0"), (2, lambda: f"G92 E{r.uniform(0, 3):.3f}"), (0.3, lambda: "G92"),
        (0.5, lambda: "G92 X10 Y10"), (1, lambda: "M400"),
        (1, lambda: f"G4 P{r.randint(0, 99)}"), (1, lambda: f";TYPE:X{r.randint(0, 3)}"),
        (1, lambda: ";LAYER_CHANGE"), (0.5, lambda: "M82"), (0.5, lambda: "M83"), (0.5, lambda: "G91"),
        (0.5, lambda: "G90"), (0.2, lambda: "G28"), (0.2, lambda: "G28 X"),
        (0.5, lambda: f"M220 S{r.choice([50, 100, 150])}"), (0.5, lambda: f"M204 P{r.choice([500, 1500])} T900 R700"),
        (0.3, lambda: f"M92 E{r.choice([415, 93, 400.5])}"), (0.3, lambda: f"G1 X{x:.3f} F0"),
        (1, lambda: f"G1 X{x:.3f} F{r.choice([600, 1200])}"), (0.5, lambda: f"G2 X{x + 1:.3f} Y{y:.3f} I0.5 J0 E0.05"),
        (0.5, lambda: f"G1 Z{r.uniform(0, 2):.2f}"), (0.2, lambda: "G1 X1e1 Y10"),
        (0.3, lambda: f"G1 X{x:.3f} Y{y:.3f} ; café"), (0.2, lambda: f"M203 X{r.choice([100, 300])}"),
        (0.2, lambda: f"M201 E{r.choice([1000, 5000])}"), (0.2, lambda: f"M205 J{r.choice([0.01, 0.05])}"),
        (0.3, lambda: f"N5 G1 X{x:.2f} Y{y:.2f}*7"), (0.2, lambda: "T0"),
        (0.2, lambda: f"G1X{x:.2f}Y{y:.2f}"), (0.2, lambda: f"G1 X{x:.3f} Y{y:.3f} ;TYPE:Infill"),
    ]
    weights = [w for w, _ in lines]
    for _ in range(n):
        x += r.uniform(-0.5, 0.5)
        y += r.uniform(-0.5, 0.5)
        out.append(r.choices(lines, weights)[0][1]())
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("seed", range(6))
def test_records_give_the_text_parsers_blocks_on_odd_lines(seed, tmp_path, monkeypatch):
    monkeypatch.setattr(movescan, "CHUNK_BYTES", 8192)          # many chunk boundaries
    p = tmp_path / "odd.gcode"
    p.write_text(_random_gcode(seed, 6000), encoding="utf-8")
    _same(p)


@pytest.mark.parametrize("bad, said", [("G1 X2 Yabc", "unparsable value 'Yabc' in 'X2 Yabc'"),
                                       ("G1 X", "unparsable value 'X' in 'X'"),
                                       ("G92 E", "unparsable value 'E' in 'E'")])
def test_a_bad_line_is_refused_alike(tmp_path, bad, said):
    """Both ways, and as every other command reads the line (gcode.parse_lines): a move or a
    G92 with a letter and no value is refused, not taken as no word or as 0."""
    from bulgekit.gcode import GcodeError, parse_lines
    p = tmp_path / "bad.gcode"
    p.write_text(f"G90\nM83\nG1 X1 Y1 E0.1\n{bad}\n")
    with pytest.raises(es.EstimateError) as old:
        es.estimate_file(p, scanned=False)
    with pytest.raises(es.EstimateError) as new:
        es.estimate_file(p, scanned=True)
    assert str(new.value) == str(old.value) == f"{p}:4: {said}"
    with pytest.raises(GcodeError, match=f"^{p}:4: {said}$".replace("(", r"\(").replace(")", r"\)")):
        list(parse_lines(p.read_text().splitlines(), str(p)))
