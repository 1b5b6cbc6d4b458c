"""tools/trace_stops.py's leveling mesh (--mesh): bilinear inside, edge values
outside, fade, and the inverse used to read a stop's layer."""
import importlib.util
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[3] / "tools" / "trace_stops.py"
spec = importlib.util.spec_from_file_location("trace_stops", TOOL)
ts = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ts)


def mesh(tmp_path, text, fade=0.0):
    f = tmp_path / "mesh.txt"
    f.write_text(text)
    return ts.Mesh(str(f), fade)


def test_bilinear_inside_and_edge_values_outside(tmp_path):
    m = mesh(tmp_path, "# x y z\n0 0 0\n10 0 0.1\n0 10 -0.1\n10 10 0.2\n20 0 0\n20 10 0\n")
    assert m.at(0, 0) == 0 and m.at(10, 10) == pytest.approx(0.2)
    assert m.at(5, 0) == pytest.approx(0.05)
    assert m.at(5, 5) == pytest.approx((0 + 0.1 - 0.1 + 0.2) / 4)
    assert m.at(15, 10) == pytest.approx(0.1)
    assert m.at(-5, 0) == 0 and m.at(25, 12) == 0 and m.at(10, 30) == pytest.approx(0.2)


def test_fade_and_unlevel_invert_level(tmp_path):
    m = mesh(tmp_path, "0 0 0.05\n10 0 0.05\n0 10 -0.04\n10 10 -0.04\n", fade=10.0)
    assert m.level(5, 0, 0.0) == pytest.approx(0.05)
    assert m.level(5, 0, 5.0) == pytest.approx(5.025)        # half faded
    assert m.level(5, 0, 12.0) == 12.0                         # above the fade height
    for x, y, z in ((1, 2, 0.3), (9, 9, 1.2), (5, 5, 9.9), (3, 7, 11.0)):
        assert m.unlevel(x, y, m.level(x, y, z)) == pytest.approx(z, abs=1e-9)
    flat = mesh(tmp_path, "0 0 0.05\n10 0 0.05\n0 10 0.05\n10 10 0.05\n")
    assert flat.unlevel(4, 4, 1.25) == pytest.approx(1.2)


@pytest.mark.parametrize("text, why", [("0 0 0\n10 0 0\n0 10 0\n", "rectangular grid"),
                                       ("0 0 0\n10 0 x\n", r"mesh.txt:2: expected 'x y z'"),
                                       ("0 0 0\n0 0 0.1\n10 0 0\n0 10 0\n10 10 0\n", "rectangular grid")])
def test_bad_mesh_files_are_named(tmp_path, text, why):
    with pytest.raises(SystemExit, match=why):
        mesh(tmp_path, text)
