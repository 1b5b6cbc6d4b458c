"""tools/litho_rate_ends.py on a small band: the mid-line's time split at its stretches' ends
adds up, and the ends (the head starting and stopping) are off the set rate more than the
middle; a file without a mid-line is refused."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
import litho_rate_ends  # noqa: E402

from bulgekit import litho as lt  # noqa: E402


def test_split_at_the_stretch_ends(tmp_path, capsys):
    x = np.linspace(40, 200, 80)[None, :].repeat(8, axis=0).astype(np.uint8)
    Image.fromarray(x).save(tmp_path / "ramp.png")
    start = tmp_path / "s.g"
    start.write_text("G90\nM83\nM204 P1000 T1000 R1000\n")
    res = lt.make(tmp_path / "ramp.png", tmp_path / "o", name="band",
                  options=lt.LithoOptions(width=40.0, height=1.6, foot=0.0, purge=False, start_gcode=str(start)))
    (all_, t_all, s_all, in_all), (_, t_end, s_end, in_end), (_, t_mid, s_mid, in_mid) = \
        litho_rate_ends.split(str(res.paths["gcode"]), 3.0, 3.326)[0]
    assert t_end + t_mid == pytest.approx(t_all) and s_end + s_mid == pytest.approx(1.0)
    assert 0 < s_end < 0.5
    assert in_end < in_mid and in_all == pytest.approx(s_end * in_end + s_mid * in_mid, abs=1e-9)
    # by default the set rate is the file's own (its options block): here a band made for a
    # printer at 1000 mm/s^2, whose mid-line runs at 4.62 mm^3/s
    slow = lt.make(tmp_path / "ramp.png", tmp_path / "s", name="band",
                   options=lt.LithoOptions(width=40.0, height=1.6, foot=0.0, purge=False,
                                           start_gcode=str(start), accel=1000.0))
    path = str(slow.paths["gcode"])
    litho_rate_ends.main([path])
    shown = capsys.readouterr().out
    own = litho_rate_ends.split(path, 3.0, 4.62 / (np.pi * 1.75 ** 2 / 4))[0]
    assert f"{100 * own[0][3]:.1f} % within +-5 %" in shown
    assert litho_rate_ends.split(path, 3.0, 3.326)[0][0][3] < own[0][3]
    gc = tmp_path / "walls.gcode"
    gc.write_text("M83\n;LAYER:0\n;TYPE:wall\nG1 X10 E1 F600\n")
    with pytest.raises(SystemExit, match="no mid-line"):
        litho_rate_ends.split(str(gc), 3.0, 3.326)
