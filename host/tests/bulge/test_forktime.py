"""`estimate` on an annotated file: the fork's stops as its core plans them (bulge/forktime.py).

The wall: straight 10 mm moves along X at 30 mm/s (3000 mm/s^2, Marlin's defaults), so a stop in
the middle of one costs exactly its trapezoids' v/a (braking to rest and starting again) plus the
dwell, less what the fork's stepper saves (the first step 1/MINIMAL_STEP_RATE sooner). The stops
are counted independently, by the reference planner on the original's moves."""
from __future__ import annotations

import pytest
from click.testing import CliRunner

from bulgekit.bulge import forktime, mapformat
from bulgekit.bulge.annotate import annotate_bytes
from bulgekit.bulge.fallback import MODE_GEOMETRIC, MODE_MARKED, RefPlanner, Settings
from bulgekit.cli import main
from bulgekit.gcode import estimate as es, parse_lines
from bulgekit.gcode import movescan
from bulgekit.machine import DEFAULT as PM

V, A = 30.0, 3000.0                              # the wall's speed, the model's acceleration


def wall(layers=((0.3, "External perimeter"),), n=8):
    """Each layer: a travel to X100 Y100, n moves of 10 mm along +X under the feature given."""
    out = ["G90", "M83", "G92 E0"]
    for z, feature in layers:
        out += [f"G1 Z{z} F600", "G1 X100 Y100 F6000", f";TYPE:{feature}", "G1 F1800"]
        out += [f"G1 X{100 + 10 * (i + 1)} Y100 E0.4" for i in range(n)]
        out += [";TYPE:Travel", "G1 X100 Y120 F6000"]
    return "\n".join(out) + "\n"


def points(z, xs, weights=None):
    return (z, [(x, 100.0) for x in xs])


def annotated(tmp_path, text, layers, weights=None, settings=Settings(mode=MODE_MARKED)):
    mp = mapformat.encode_map(layers, weights=weights)
    src = tmp_path / "wall.gcode"
    src.write_text(text)
    out = tmp_path / "wall.bulge.gcode"
    out.write_bytes(annotate_bytes(text.encode(), mp, settings))
    return src, out, mp


def independent_stops(text, mp, settings, outer_of=None):
    """ms of each stop the reference planner makes on the original's moves."""
    p = RefPlanner(mapformat.decode_map(mp), settings)
    ms = []
    for ln in parse_lines(text.splitlines(keepends=True)):
        for m in ln.moves:
            acts = p.plan(m) if outer_of is None else p.plan(m, outer_of(m))
            ms += [a.ms for a in acts if a.kind == "dwell"]
    return ms


def added(src, out):
    m = es.Machine.from_model(PM)
    base = es.estimate_file(src, m, blocks=False).total_s
    fe = forktime.estimate_annotated(out, m, PM)
    return fe.result.total_s - base, fe


def per_stop(ms):
    """A stop mid-cruise: its dwell (at least the 0.5 ms lead), braking to rest and starting again
    (v/a, rest being MINIMUM_PLANNER_SPEED), less the stepper's earlier start (1/120 s)."""
    v0 = es.Machine().min_planner_speed
    return max(ms / 1000, forktime.DWELL_LEAD_S) + (V - v0) ** 2 / (A * V) - 1 / PM.min_step_rate


def test_stops_add_dwell_and_stop_and_start(tmp_path):
    text = wall()
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115, 135, 155])])
    ms = independent_stops(text, mp, Settings(mode=MODE_MARKED))
    assert ms == [100, 100, 100]
    d, fe = added(src, out)
    assert fe.stops == 3 and fe.points == 3 and fe.dwell_s == pytest.approx(0.3)
    assert d == pytest.approx(sum(per_stop(x) for x in ms), abs=1e-9)
    assert fe.extra_mm == pytest.approx(0.3)
    # the estimate of the original (no map) is the plain estimate
    assert not forktime.is_annotated(src) and forktime.is_annotated(out)


def test_weights_scale_the_dwell(tmp_path):
    text = wall()
    w = [[255, 128, 64, 0]]
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115, 135, 145, 155])], weights=w)
    ms = independent_stops(text, mp, Settings(mode=MODE_MARKED))
    assert ms == [(100 * x + 127) // 255 for x in w[0]] == [100, 50, 25, 0]
    d, fe = added(src, out)
    assert fe.dwell_s == pytest.approx(0.175)
    # a 0 ms stop still stops: rest to rest, held for the lead
    assert d == pytest.approx(sum(per_stop(x) for x in ms), abs=1e-9)


def test_m722_gates_the_stops(tmp_path):
    # layer 2's wall is an inner perimeter: M722 S0 there, its points make no stop
    text = wall(((0.3, "External perimeter"), (0.6, "Perimeter")))
    layers = [points(0.3, [115, 135]), points(0.6, [115, 135, 155])]
    src, out, mp = annotated(tmp_path, text, layers)
    ms = independent_stops(text, mp, Settings(mode=MODE_MARKED))
    assert len(ms) == 2
    d, fe = added(src, out)
    assert fe.stops == 2 and d == pytest.approx(2 * per_stop(100), abs=1e-9)
    assert any("3 of 5 map points" in n for n in fe.notes)
    # the markers decide, not the comments: without layer 1's M722 S1 nothing stops there
    cut = out.read_text().replace("M722 S1\n", "", 1)
    out.write_text(cut)
    d, fe = added(src, out)
    assert fe.stops == 0 and d == pytest.approx(0, abs=1e-9)
    # geometric mode (M720 S2) stops every extruding move, markers or not
    src, out, mp = annotated(tmp_path, text, layers, settings=Settings(mode=MODE_GEOMETRIC))
    ms = independent_stops(text, mp, Settings(mode=MODE_GEOMETRIC))
    d, fe = added(src, out)
    assert fe.stops == len(ms) == 5 and d == pytest.approx(5 * per_stop(100), abs=1e-9)


def test_mode_off_and_refused_uploads(tmp_path):
    text = wall()
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115])])
    body = out.read_text()
    out.write_text(body.replace("M720 S1 ", "M720 S0 ", 1))
    d, fe = added(src, out)
    assert d == 0 and fe.stops == 0 and "stops nowhere" in fe.notes[0]
    # a bad CRC: the firmware refuses the upload, no map is in force
    out.write_text(body.replace(f"C{mapformat.crc32(mp)}", f"C{mapformat.crc32(mp) ^ 1}"))
    d, fe = added(src, out)
    assert d == 0 and any("refuses" in n and "CRC" in n for n in fe.notes)


def test_a_new_dwell_mid_print_is_taken_at_its_line(tmp_path):
    """`bulgekit calibrate` changes M720 E between bands: a new dwell or extra is modelled from its
    line on (the stops after M720 P50 are 50 ms), a new mode or tolerance is refused."""
    two = wall(((0.3, "External perimeter"), (0.6, "External perimeter")), n=4)
    cut = two.index("G1 Z0.6")
    text = two[:cut] + "M720 P50\n" + two[cut:]
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115]), points(0.6, [115])])
    d, fe = added(src, out)
    assert fe.stops == 2 and fe.dwell_s == pytest.approx(0.150)
    assert d == pytest.approx(per_stop(100) + per_stop(50), abs=1e-3)
    text = two[:cut] + "M720 T0.4\n" + two[cut:]
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115]), points(0.6, [115])])
    with pytest.raises(forktime.ForkTimeError, match="M720 changes the bulge mode or tolerance"):
        added(src, out)


@pytest.mark.skipif(not movescan.available(), reason="needs the compiled scanner")
def test_text_path_gives_the_same(tmp_path):
    text = wall(((0.3, "External perimeter"), (0.6, "External perimeter")))
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115, 135]), points(0.6, [119.97, 150])],
                             weights=[[255, 10], [200, 255]])
    m = es.Machine.from_model(PM)
    a = forktime.estimate_annotated(out, m, PM, scanned=True)
    b = forktime.estimate_annotated(out, m, PM, scanned=False)
    assert a.stops == b.stops == 4
    assert a.result.total_s == pytest.approx(b.result.total_s, rel=1e-12)
    assert a.result.by_feature == pytest.approx(b.result.by_feature, rel=1e-12)


def test_read_upload_takes_the_lines_the_annotator_and_mcodes_write():
    mp = mapformat.encode_map([(0.3, [(1, 2), (3, 4)]), (0.6, [(5, 6)]), (0.9, [(7, 8)])])
    recs = mapformat.record_bytes(mp)
    first = mp[:mapformat.HEADER_BYTES] + recs[0]
    lines = (["M721 X"] + mapformat.upload_lines(first, checked=True)
             + mapformat.upload_lines(b"".join(recs[1:]), append=True, start_line=7))
    got = mapformat.read_upload([(i, mapformat_code(l)) for i, l in enumerate(lines, 1)])
    assert got.layers == mapformat.decode_map(mp).layers
    with pytest.raises(mapformat.MapFormatError, match=":3: M721 E after 0 of"):
        mapformat.read_upload([(1, "M721 S20 C1"), (3, "M721 E")], "f")
    refused = []
    assert mapformat.read_upload([(1, "M721 S20 C1"), (2, "M721 O0 D!!")], "f", refused) is None
    assert refused == ["f:2: malformed M721 line 'M721 O0 D!!'"]
    # a commit before the last chunk: the upload stays open, as in the firmware
    up = mapformat.upload_lines(mp, chunk_bytes=10)
    refused = []
    got = mapformat.read_upload([(i, l) for i, l in enumerate(up[:2] + [up[-1]] + up[2:], 1)], "f", refused)
    assert got.layers == mapformat.decode_map(mp).layers and "M721 E after 10 of" in refused[0]


def mapformat_code(line):
    from bulgekit.gcode import split_code
    return split_code(line)[0]


def test_cli_estimate_of_an_annotated_file(tmp_path):
    text = wall()
    src, out, mp = annotated(tmp_path, text, [points(0.3, [115, 135, 155])])
    r = CliRunner().invoke(main, ["estimate", str(out)])
    assert r.exit_code == 0, r.output
    assert "3 stops (3 points), dwell 0.3 s" in r.output
    plain = CliRunner().invoke(main, ["estimate", str(src)])
    assert plain.exit_code == 0 and "stops" not in plain.output
    t = lambda o: float(o.split(" s; ")[0].rsplit("(", 1)[1])
    assert t(r.output) - t(plain.output) == pytest.approx(3 * per_stop(100), abs=0.06)


def test_a_cut_off_annotated_file_is_refused(tmp_path):
    from bulgekit.gcode import GcodeError
    src, out, mp = annotated(tmp_path, wall(), [points(0.3, [115])])
    out.write_bytes(out.read_bytes() + b"G1 X2 Y3")
    with pytest.raises(GcodeError, match="does not end with a line end"):
        added(src, out)
