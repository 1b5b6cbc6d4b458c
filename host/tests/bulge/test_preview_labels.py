"""The preview's words (issue 26): the 3D title tells the print's layers from those with bumps,
and the unrolled wall's "u = 0" label sits clear of the frame lines."""
from __future__ import annotations

import numpy as np
import pytest

from bulgekit.bulge import preview


@pytest.fixture
def saved(monkeypatch):
    """The figures the previews save, kept open to read their texts."""
    figs = []
    real = preview._save

    def keep(fig, path):
        fig.canvas.draw()
        figs.append((fig, fig.canvas.get_renderer()))
        real(fig, path)
    monkeypatch.setattr(preview, "_save", keep)
    return figs


def test_3d_title_says_layers_and_layers_with_bumps_apart(tmp_path, saved):
    t = np.linspace(0, 2 * np.pi, 60)
    xy = np.column_stack([20 * np.cos(t), 20 * np.sin(t)])
    walls = [(round(0.2 * k, 2), xy) for k in range(1, 68)]                  # 67 layers
    bumps = [(20.0, 0.0, z, 255) for z in [round(0.2 * k, 2) for k in range(10, 39)]]  # 29 of them
    r = preview.preview_3d(walls, bumps, tmp_path / "p.png", title="part.gcode: bulges on the walls")
    assert r["layers"] == 67 and r["layers_with_bumps"] == 29
    fig, renderer = saved[-1]
    title = fig.axes[0].get_title()
    head, figures = title.split("\n")
    assert head == "part.gcode: bulges on the walls"
    assert figures.endswith("; 67 layers, 29 with bumps")
    # the whole title inside the picture (one long line was cut off at both edges)
    box = fig.axes[0].title.get_window_extent(renderer)
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width


def test_3d_title_when_layers_are_thinned(tmp_path, saved):
    xy = np.array([[20.0, 0.0], [0.0, 20.0], [-20.0, 0.0], [20.0, 0.0]])
    walls = [(0.2 * k, xy) for k in range(1, 301)]
    preview.preview_3d(walls, [(20.0, 0.0, 1.0, 255)], tmp_path / "p.png", max_layers=100)
    assert saved[-1][0].axes[0].get_title().endswith("every 3th of 300 layers drawn, 1 with bumps")


@pytest.mark.parametrize("length, height", [(124.2, 20.1), (80.0, 14.0), (300.0, 8.0), (40.0, 60.0)])
def test_u0_label_is_clear_of_the_frame_lines(tmp_path, saved, length, height):
    preview.preview_unrolled([(10.0, 3.0, 255)], length, height, tmp_path / "u.png")
    fig, renderer = saved[-1]
    ax = fig.axes[0]
    (label,) = [t for t in ax.texts if t.get_text().strip() == "u = 0"]
    box = label.get_window_extent(renderer)
    x0, top = ax.transData.transform((0.0, height))                   # the dashed u = 0 line, the wall's top
    _, bottom = ax.transData.transform((0.0, 0.0))
    assert box.x0 > x0 + 1                                             # right of the u = 0 line
    assert box.y1 < top - 1 and box.y0 > bottom                        # below the top edge, inside the wall
