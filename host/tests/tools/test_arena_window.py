"""tools/arena_window.py: the smallest arena a print streams through is found
by bisection on the annotator, so one byte less must fail and it must work."""
import importlib.util
import re
from pathlib import Path

from bulgekit.bulge import annotate, mapformat
from bulgekit.bulge.fallback import Settings
from bulgekit.bulge.mapbuild import build
from bulgekit.bulge.strokes import Stroke
from bulgekit.bulge.wall import walls_from_gcode

TOOL = Path(__file__).resolve().parents[3] / "tools" / "arena_window.py"
spec = importlib.util.spec_from_file_location("arena_window", TOOL)
aw = importlib.util.module_from_spec(spec)
spec.loader.exec_module(aw)


def test_the_format_bound_is_two_largest_records():
    n = mapformat.LAYER_POINTS_MAX
    assert aw.largest_record() == 7 * n + 6 == 454  # 3-byte deltas, weights, 2-byte len
    assert 2 * aw.largest_record() <= 1024


def test_smallest_arena_is_exact(tmp_path, capsys):
    g = Path(__file__).parents[1] / "data" / "prusa_cyl.gcode"
    model = walls_from_gcode(g)
    # many strokes: a map several times the size of its largest record
    r = build([Stroke(((u, 0.5), (u, 9.8))) for u in range(0, 120, 6)], model)
    m = tmp_path / "big.bkm"
    m.write_bytes(r.map_bytes)
    assert aw.main([str(g), str(m)]) == 0
    out = capsys.readouterr().out
    smallest = int(re.search(r"largest window needed: (\d+) B", out).group(1))
    data = g.read_bytes()
    assert aw.fits(data, r.map_bytes, smallest, Settings()) is not None
    assert aw.fits(data, r.map_bytes, smallest - 1, Settings()) is None
    assert smallest < len(r.map_bytes) - mapformat.HEADER_BYTES  # streaming made it smaller
    # the annotator agrees: at that arena it streams, below it refuses
    annotate.annotate_bytes(data, r.map_bytes, Settings(), arena=smallest)
