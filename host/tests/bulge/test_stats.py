import pytest

from bulgekit.bulge import mapformat
from bulgekit.bulge.fallback import Settings
from bulgekit.bulge.mapbuild import build
from bulgekit.bulge.stats import map_stats, print_stats, slicer_time
from bulgekit.bulge.strokes import Stroke
from bulgekit.bulge.wall import walls_from_gcode


def test_map_stats_counts_and_weighted_dwell():
    m = mapformat.encode_map([(0.3, [(1.0, 0.0), (2.0, 0.0)]), (0.6, [(3.0, 0.0)])],
                             weights=[[255, 51], [255]])
    st = map_stats(m, Settings(dwell_ms=200, extra_e=0.05))
    assert [(l.z, l.points) for l in st.layers] == [(0.3, 2), (0.6, 1)]
    assert st.points == 3
    assert st.dwell_s == pytest.approx((200 + 40 + 200) / 1000)
    assert st.extra_e_mm == pytest.approx(0.15)
    assert st.fits_arena
    text = st.text()
    assert "2 layers, 3 points" in text and "0.30:2" in text


def test_print_stats_counts_real_stops_and_names_missed_points(data_dir):
    g = data_dir / "prusa_cyl.gcode"
    r = build([Stroke(((5.0, 2.0), (5.0, 4.0)))], walls_from_gcode(g))
    bm = r.bulge_map
    # add a point far from any wall at the first layer's z
    layers = [(l.z_cmm / 100, bm.points_mm(l)) for l in bm.layers]
    layers[0] = (layers[0][0], layers[0][1] + [(100.0, 100.0)])
    data = mapformat.encode_map(layers)
    st = print_stats(g, data, Settings())
    assert st.stops == len(r.points)
    assert st.missed == [(layers[0][0], 100.0, 100.0)]
    assert st.dwell_s == pytest.approx(0.1 * len(r.points))
    assert st.decel_s > 0
    assert st.slicer_time_s == pytest.approx(15 * 60 + 8)
    assert "WARNING: 1 points are not within 0.25 mm" in st.text()


def test_slicer_time_dialects():
    assert slicer_time("; estimated printing time (normal mode) = 1h 2m 3s\n") == 3723
    assert slicer_time(";TIME:6666\n") == 6666
    assert slicer_time(";   Build time: 2 hours 5 minutes\n") == 7500
    assert slicer_time("G1 X1\n") is None


def test_slicer_time_is_the_first_match_of_its_dialects_regexes():
    # slicer_time finds a word of the match first and starts the regex at its line: the same
    # answer as the regexes tried on the whole text, also where ";" and "Build time" are lines
    # apart (\s spans them) or a word stands where no match begins
    import random
    from bulgekit.bulge import stats

    def whole(text):                           # the first dialect whose regex matches anywhere
        for rx, _, _ in stats._TIME_RX:
            m = rx.search(text)
            if m:
                return slicer_time(m.group(0) + "\n")
        return None
    pieces = ["; estimated printing time (normal mode) = 1h 2m 3s",
              "; estimated printing time (silent mode) = 2h", "; estimated printing time",
              ";TIME:123", "; TIME:5", "x;TIME:7", " ;TIME:9", ";  Build time: 2 hours 3 minutes",
              "Build time: 1 hour 2 minutes", "; ;Build time: 1 hour 1 minute", ";", ";\t", "",
              "\r", "G1 X1"]
    rng = random.Random(1)
    seen = set()
    for _ in range(20000):
        text = "\n".join(rng.choice(pieces) for _ in range(rng.randint(0, 8)))
        assert slicer_time(text) == whole(text), repr(text)
        seen.add(whole(text))
    assert {None, 3723, 123, 7380, 3720} <= seen


def test_build_stats_give_the_stock_files_stops_as_printed(data_dir, tmp_path):
    from bulgekit.bulge import api
    from bulgekit.bulge.fallback import StockStops, still_s
    g = data_dir / "prusa_cyl.gcode"
    strokes = [Stroke(((5.0, 2.0), (5.0, 4.0)))]
    plain = api.build(g, strokes, tmp_path / "a")
    assert "stock file" not in plain.stats_path.read_text()          # no stock file, no stock line
    out = api.build(g, strokes, tmp_path / "b", write_fallback=True, settings=Settings(dwell_ms=130))
    st = out.stats
    n = st.stops
    # 130 ms: 6 steps at r = 5 / (0.13 - 2/120) = 44.1 steps/s would hold 131.25 ms at 44 on the
    # AVR timer (44 lies between its table's points 40 and 48), so a step more: 7 at 53, 130.50 ms
    held = n * still_s(7, 53)
    assert st.stock.moves == n and st.stock.still_s == pytest.approx(held)
    text = out.stats_path.read_text()
    assert f"stock file: stops as E-only moves: {n} ({held:.1f} s head still" in text
    run = held - n / 120                  # each block: the stillness less the braking's last step
    assert st.stock.run_s == pytest.approx(run)
    assert f"stock file's added time: {run:.1f} s in the stops + {st.decel_s:.1f} s stopping/starting" in text
    g4 = api.build(g, strokes, tmp_path / "c", write_fallback=True, stops=StockStops("g4"))
    assert f"and the planner's drain and refill at each of its {n} G4" in g4.stats_path.read_text()


@pytest.mark.parametrize("byte_path", [True, False], ids=["records", "text"])
def test_stats_on_the_stock_rewrites_planner_run_are_the_stats_of_their_own(data_dir, tmp_path,
                                                                            monkeypatch, byte_path):
    """build runs the planner once: the statistics count on the stock fallback's run (its
    records path, or its text path when the compiled scanner is not there) and give what a run
    of their own gives."""
    from bulgekit import machine
    from bulgekit.bulge import fallback
    from bulgekit.bulge.stats import StopTimer
    g = data_dir / "prusa_cyl.gcode"
    r = build([Stroke(((5.0, 2.0), (5.0, 4.0))), Stroke(((12.0, 3.0), (14.0, 3.0)))], walls_from_gcode(g))
    settings = Settings(extra_e=0.4)
    if not byte_path:
        monkeypatch.setattr(fallback.movescan, "available", lambda: False)
    timers = []

    def on_plan(planner):              # (as build makes it: the default model, timed by its stepper)
        timers.append(StopTimer(planner, machine.DEFAULT.accel, machine.DEFAULT))
        return timers[-1]
    res = fallback.rewrite_file(g, tmp_path / "s.gcode", r.bulge_map, settings,
                                allow_unreached=True, on_plan=on_plan)
    assert len(timers) == 1 and res.planner is timers[0].planner
    shared = print_stats(g, r.map_bytes, settings, planned=timers[0])
    own = print_stats(g, r.map_bytes, settings)
    assert own.stops == len(r.points) > 5 and own.decel_s > 0
    # (the distances between neighbouring stops may differ: the records path does not see the
    # moves its picker skips, the text path sees them all; the time they give is the same here)
    a, b = dict(vars(shared)), dict(vars(own))
    ga, gb = a.pop("gaps"), b.pop("gaps")
    assert a == b and [ms for ms, _ in ga] == [ms for ms, _ in gb]
