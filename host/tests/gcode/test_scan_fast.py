"""The compiled scanner's fast path for plain G0/G1 lines (_scan.c fast_line) gives what its
general code gives, in every mode: the same records to the byte, move numbers, counts, roles and
errors. The fast path needs 96 bytes after a line's start in the part fed, so the same G-code fed
in parts of 95 bytes never takes it, and fed whole nearly always does."""
from __future__ import annotations

import random

import pytest

from bulgekit import gcode
from bulgekit.gcode import movescan

MODES = {"full": {}, "lean1": {"lean": 1}, "lean2": {"lean": 2}, "events": {"events": True}}


def _number(rng: random.Random) -> str:
    digits = lambda n: "".join(rng.choice("0123456789") for _ in range(n))   # noqa: E731
    lead = digits(rng.choice([0, 1, 1, 2, 3, 3, 4, 5, 7, 8, 9, 10, 16]))
    frac = rng.choice(["", "", "."]) + digits(rng.choice([0, 1, 2, 3, 5, 6, 7, 8, 9, 12]))
    if not (lead + frac).strip(".") and rng.random() < 0.95:
        lead = "1"
    return rng.choice(["", "", "", "-", "+"]) + lead + frac


def _line(rng: random.Random) -> str:
    """Mostly the fast path's shape, and lines just off it: a tab or two blanks, a lower-case or
    other letter, letters glued, a second dot or sign, F0, long numbers, comments after the
    words (the estimator's own among them, one not ASCII), a checksum, a non-ASCII byte."""
    r = rng.random()
    if r < 0.1:
        return rng.choice([";TYPE:External perimeter", "; outer perimeter", ";LAYER:3", "G92 E0",
                           "M83", "G91", "G90", "M82", "G2 X10 Y10 I5 J0 E1", "; \u00e9t\u00e9",
                           "N5 G1 X1", " G1 X1", "G1", "G1 ", "G01 X1"])
    words = [rng.choice("XYZEFXYZEFXYZEFxIS") + _number(rng) for _ in range(rng.randint(0, 5))]
    if rng.random() < 0.03:
        words.append("F0")
    text = rng.choice(["G1", "G1", "G0"]) + "".join(
        rng.choice([" "] * 30 + ["  ", "", "\t", "\u00a0"]) + w for w in words)
    return text + rng.choice(["", "", "", " ", "\t", " ; perimeter", ";c", " ;TYPE:Skirt",
                              " ; \x0bLAYER:2", " ; LAYE", " ; \u00e9", " *45", " (x)"])


def _scan(data: bytes, mode: str, part: int):
    sc = movescan._scan.Scanner(sorted(gcode.OUTER_ROLES), sorted(gcode._S3D_ROLES),
                                movescan._classify, **MODES[mode])
    recs, nums, base = [], [], 0
    while True:
        stop = min(base + part, len(data))
        final = stop == len(data)
        try:
            r, used = sc.feed(data[base:stop], final, base)
        except movescan._scan.ScanUnsupported as e:
            return "unsupported", e.args
        recs.append(r)
        if mode == "lean2":
            nums.append(sc.numbers)
        base += used
        if final:
            return b"".join(recs), b"".join(nums), sc.lines, sc.flagged, sc.line_ends, list(sc.roles)
        if not used:
            part *= 2


@pytest.mark.parametrize("seed", range(6))
def test_fast_path_gives_the_general_codes_results(seed):
    assert movescan.available()
    rng = random.Random(seed)
    lines = [_line(rng) for _ in range(3000)]
    if seed % 2:                       # no refused line: the whole file's records compared
        lines = [ln for ln in lines if _scan((ln + "\n").encode(), "full", 1 << 20)[0] != "unsupported"]
    data = "".join(ln + rng.choice(["\n"] * 6 + ["\r\n", "\r"]) for ln in lines).encode()
    for mode in MODES:
        whole, parts = _scan(data, mode, 1 << 20), _scan(data, mode, 95)
        assert whole == parts, mode
        if seed % 2:                   # every line read, most of them moves
            assert whole[2] == len(lines), mode
            if mode in ("full", "events"):
                assert len(whole[0]) > len(lines) // 2 * movescan.RECORD.itemsize
