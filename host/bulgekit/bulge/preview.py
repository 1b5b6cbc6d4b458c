"""PNG previews of a bulge drawing: the unrolled outer wall and a 3D view.

Printer hosts cannot show where bulges will appear (the paper, sec. 5.4),
so these pictures are the only look at the result before printing.  Bump
marker area grows linearly with weight, as the dwell (and so the extruded
excess) does.
"""
from __future__ import annotations

import io
import math
import os
from typing import Sequence

import numpy as np

from .. import outputs
from ..errors import InputError

_BUMP_CMAP = "YlOrRd"
_OUT_COLOR = "#1f5fbf"


def _figure(**kw):
    # a Figure on an Agg canvas without pyplot: no figure manager or backend switch is needed to
    # write a PNG (pyplot's import costs about 0.02 s of CPU more; the same bytes)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def warm() -> None:
    """Import what drawing the unrolled preview takes (matplotlib: about 0.4 s here), ahead of
    the drawing, as `bulgekit build`'s forked preview child does while the build reads the file."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    from matplotlib.figure import Figure  # noqa: F401
    from matplotlib.patches import Rectangle  # noqa: F401


def _points_array(points, cols: int, what: str) -> np.ndarray:
    arr = np.asarray(list(points) if not isinstance(points, np.ndarray) else points, dtype=float)
    if arr.size == 0:
        return np.zeros((0, cols))
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise InputError(f"{what}: expected rows of {cols} numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what}: non-finite coordinates")
    return arr


def _marker_area(weights: np.ndarray, full_area: float) -> np.ndarray:
    # Keep weight-0 points visible as pin-pricks so nothing vanishes silently.
    return np.maximum(weights / 255.0 * full_area, 2.0)


def wall_marks(model, max_layers: int = 300) -> dict:
    """The corners and faces of a wall model (wall.Wall.faces) for the unrolled view: "corners",
    (u, v0, v1) lines, each layer's corners over its band (with more than max_layers layers, every
    k-th layer's over the bands up to the next one drawn), and "faces", (u, v, number) labels:
    per run of layers whose faces stay put (the same count, middles within 1 mm), each face's
    number near the run's top, on each piece of it between 0 and the wall's length (face 1
    holds u = 0, so it shows at both ends); "runs": those runs, (v0, v1, faces of their first layer)."""
    walls = model.walls
    step = max(1, math.ceil(len(walls) / max_layers))
    picked = list(range(0, len(walls), step))
    corners: list[tuple[float, float, float]] = []
    runs: list[list] = []                       # [v0, v1, faces, length]
    for j, i in enumerate(picked):
        w = walls[i]
        v0 = w.z - w.height
        v1 = (walls[picked[j + 1]].z - walls[picked[j + 1]].height) if j + 1 < len(picked) else w.z
        corners += [(float(c), v0, v1) for c in w.corners]
        fs = w.faces
        last = runs[-1] if runs else None
        if (last is not None and len(last[2]) == len(fs)
                and all(abs(a.middle - b.middle) <= 1.0 for a, b in zip(last[2], fs))):
            last[1] = v1
        else:
            runs.append([v0, v1, fs, w.length if w.closed else 0.0])
    labels = []
    for v0, v1, fs, L in runs:
        for f in fs:
            pieces = [(f.u0, f.u1)]
            if L and f.u0 < 0:
                pieces = [(0.0, f.u1), (f.u0 + L, L)]
            labels += [((a + b) / 2, v0 + 0.85 * (v1 - v0), f.number) for a, b in pieces
                       if b - a > 1e-6]
    return {"corners": corners, "faces": labels, "runs": [(a, b, fs) for a, b, fs, _ in runs]}


def preview_unrolled(points, wall_length: float, height: float, path, *, title: str | None = None,
                     layer_height: float | None = None, bump_mm: float = 1.2, dpi: int = 150,
                     marks: dict | None = None) -> dict:
    """Draw the unrolled wall (u along the wall, v up) with the bumps.

    points: (u, v, weight) rows.  Bumps outside 0 <= u <= wall_length,
    0 <= v <= height are drawn as blue crosses and counted in the title, so
    a misplaced drawing shows.  bump_mm is the diameter drawn for weight 255.
    marks: wall_marks(model): the corners are drawn as lines, the faces' numbers in circles.
    Returns {"inside": n, "outside": n}.
    """
    if not (wall_length > 0 and height > 0):
        raise InputError(f"preview: wall length and height must be > 0 (got {wall_length}, {height})")
    pts = _points_array(points, 3, "preview points")
    from matplotlib.patches import Rectangle

    # Figure about 10 in wide, height following the wall's aspect, clamped
    # so very tall or very long walls stay legible.
    aspect = height / wall_length
    fig_w = 10.0
    fig_h = min(max(fig_w * aspect + 1.4, 2.6), 12.0)
    fig = _figure(figsize=(fig_w, fig_h), dpi=dpi)
    ax = fig.add_subplot()
    ax.add_patch(Rectangle((0, 0), wall_length, height, facecolor="#eeeeee", edgecolor="#555555", lw=1.0, zorder=0))
    # Layer lines only while they stay distinguishable.
    if layer_height and height / layer_height <= 60:
        for z in np.arange(layer_height, height, layer_height):
            ax.axhline(z, color="#dddddd", lw=0.4, zorder=1)
    ax.axvline(0, color="#888888", lw=1.2, ls="--", zorder=1)
    # inside the wall's top-left corner, clear of both frame lines (bumps draw over it)
    ax.annotate("u = 0", xy=(0, height), xytext=(4, -4), textcoords="offset points", va="top",
                ha="left", fontsize=8, color="#555555", zorder=2)

    if marks:
        _draw_marks(ax, marks)

    u, v, w = (pts[:, 0], pts[:, 1], pts[:, 2]) if len(pts) else (np.zeros(0),) * 3
    inside = (u >= 0) & (u <= wall_length) & (v >= 0) & (v <= height)
    # Marker size in points²: bump_mm converted through the axes' scale.
    # Limits include every point, so bumps outside the wall stay visible.
    umin = min(0.0, float(u.min()) if len(u) else 0.0)
    umax = max(wall_length, float(u.max()) if len(u) else 0.0)
    vmin = min(0.0, float(v.min()) if len(v) else 0.0)
    vmax = max(height, float(v.max()) if len(v) else 0.0)
    pad_u, pad_v = 0.02 * (umax - umin), 0.05 * (vmax - vmin)
    ax.set_xlim(umin - pad_u, umax + pad_u)
    ax.set_ylim(vmin - pad_v, vmax + pad_v)
    ax.set_aspect("equal", adjustable="box")
    ax.apply_aspect()
    bbox = ax.get_window_extent()
    x0, x1 = ax.get_xlim()
    pts_per_mm = bbox.width / (x1 - x0) * 72.0 / fig.dpi
    full_area = (bump_mm * pts_per_mm) ** 2
    if inside.any():
        sc = ax.scatter(u[inside], v[inside], s=_marker_area(w[inside], full_area), c=w[inside],
                        cmap=_BUMP_CMAP, vmin=0, vmax=255, edgecolors="#7a2a00", linewidths=0.3, zorder=3)
        cb = fig.colorbar(sc, ax=ax, fraction=0.025, pad=0.01)
        cb.set_label("weight (dwell share of 255)")
    n_out = int((~inside).sum())
    if n_out:
        ax.scatter(u[~inside], v[~inside], marker="x", color=_OUT_COLOR, s=max(full_area * 0.5, 9), lw=0.8,
                   zorder=4, label=f"{n_out} outside the wall")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("u along the outer wall, counter-clockwise from the reference (mm)")
    ax.set_ylabel("height above bed (mm)")
    head = title or "Unrolled outer wall"
    ax.set_title(f"{head} — {int(inside.sum())} bumps, wall {wall_length:.1f} × {height:.1f} mm"
                 + (f", {n_out} OUTSIDE" if n_out else ""), fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return {"inside": int(inside.sum()), "outside": n_out}


def _draw_marks(ax, marks: dict) -> None:
    """wall_marks' corners (lines) and face numbers (in circles) on the unrolled view."""
    from matplotlib.collections import LineCollection
    segs = [[(u, a), (u, b)] for u, a, b in marks.get("corners", ())]
    if segs:
        ax.add_collection(LineCollection(segs, colors="#2a7a3a", linewidths=1.0, zorder=1.5))
    for u, v, n in marks.get("faces", ()):
        ax.text(u, v, str(n), ha="center", va="center", fontsize=9, color="#2a7a3a", zorder=2,
                bbox=dict(boxstyle="circle,pad=0.25", fc="white", ec="#2a7a3a", lw=0.8, alpha=0.8))


def preview_3d(wall_paths: Sequence, bumps, path, *, title: str | None = None, elev: float = 22.0,
               azim: float | None = None, max_layers: int = 120, dpi: int = 150) -> dict:
    """Draw the printed outer walls as layer outlines with the bumps on them.

    wall_paths: (z, xy) pairs, xy an (N, 2) array of one layer's outer wall.
    bumps: (x, y, z, weight) rows.  With more than max_layers layers an even
    subset of layers is drawn (the title says so); bumps are always all
    drawn.  Without azim the camera faces the side where the bumps are;
    bumps on the far side are faded, since matplotlib does not hide them
    behind the walls.  Returns {"layers_drawn", "layers", "bumps", "far_side", "layers_with_bumps"}.
    """
    layers = []
    for i, item in enumerate(wall_paths):
        try:
            z, xy = item
        except (TypeError, ValueError):
            raise InputError(f"preview: wall path {i} must be a (z, xy) pair") from None
        arr = _points_array(xy, 2, f"preview: wall path {i}")
        layers.append((float(z), arr))
    b = _points_array(bumps, 4, "preview bumps")
    if not layers and not len(b):
        raise InputError("preview: nothing to draw (no wall paths and no bumps)")
    fig = _figure(figsize=(8, 8), dpi=dpi)
    ax = fig.add_subplot(projection="3d")
    step = max(1, math.ceil(len(layers) / max_layers))
    drawn = layers[::step]
    for z, xy in drawn:
        if len(xy) == 0:
            continue
        ax.plot(xy[:, 0], xy[:, 1], np.full(len(xy), z), color="#7f8c9a", lw=0.5, alpha=0.6)
    all_xyz = [np.column_stack([xy, np.full(len(xy), z)]) for z, xy in layers if len(xy)]
    if len(b):
        all_xyz.append(b[:, :3])
    xyz = np.vstack(all_xyz)
    centre = (xyz[:, :2].min(axis=0) + xyz[:, :2].max(axis=0)) / 2
    if azim is None:
        d = (b[:, :2] - centre).mean(axis=0) if len(b) else np.zeros(2)
        azim = math.degrees(math.atan2(d[1], d[0])) if np.hypot(*d) > 1e-9 else -60.0
    n_far = 0
    if len(b):
        look = np.array([math.cos(math.radians(azim)), math.sin(math.radians(azim))])
        near = (b[:, :2] - centre) @ look >= 0
        n_far = int((~near).sum())
        kw = dict(cmap=_BUMP_CMAP, vmin=0, vmax=255, edgecolors="#7a2a00", linewidths=0.3, depthshade=False)
        if n_far:
            f = b[~near]
            ax.scatter(f[:, 0], f[:, 1], f[:, 2], s=_marker_area(f[:, 3], 36.0), c=f[:, 3], alpha=0.2, **kw)
        if near.any():
            nb = b[near]
            sc = ax.scatter(nb[:, 0], nb[:, 1], nb[:, 2], s=_marker_area(nb[:, 3], 36.0), c=nb[:, 3], **kw)
            cb = fig.colorbar(sc, ax=ax, fraction=0.03, pad=0.08, shrink=0.6)
            cb.set_label("weight")
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    span = np.maximum(hi - lo, 1e-6)
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    ax.set_box_aspect(span)  # true proportions, mm for mm
    ax.view_init(elev=elev, azim=azim)
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    ax.set_zlabel("Z (mm)")
    # the print's layers and, apart, those with bumps (the map's layers), so neither is mistaken
    # for the other
    with_bumps = len(np.unique(np.round(b[:, 2], 4))) if len(b) else 0
    note = (f"every {step}th of {len(layers)} layers drawn" if step > 1 else f"{len(layers)} layers")
    note += f", {with_bumps} with bumps"
    far = f", {n_far} on the far side (faded)" if n_far else ""
    # two lines: one this long is cut off at the figure's edges
    ax.set_title((title or "Print preview") + f"\n{len(b)} bumps{far}; " + note, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return {"layers_drawn": len(drawn), "layers": len(layers), "bumps": int(len(b)), "far_side": n_far,
            "layers_with_bumps": with_bumps}


def unrolled_job(result, gcode_name: str) -> tuple[tuple, dict]:
    """preview_unrolled's arguments but the path for a mapbuild.BuildResult placed on the
    G-code gcode_name (the annotated file's name, for the title)."""
    model = result.model
    length = max(w.length for w in model.walls)
    lo, hi = model.v_range
    rows = [(p.u, p.z - model.walls[p.layer].height / 2, p.weight) for p in result.points]
    return (rows, length, hi), dict(title=f"{gcode_name}: bulges on the unrolled outer wall",
                                    layer_height=model.layer_height, marks=wall_marks(model))


def unrolled_png(rows, wall_length: float, height: float, **kw) -> bytes:
    """preview_unrolled's PNG as bytes (the bytes it writes to a file)."""
    buf = io.BytesIO()
    preview_unrolled(rows, wall_length, height, buf, **kw)
    return buf.getvalue()


def build_unrolled(out, path, drawn=None):
    """The unrolled-wall preview of an api.build() result (what `bulgekit build` writes).
    drawn: a parallel.Forked given unrolled_png's job on unrolled_job(out.result, ...)'s
    arguments while the build ran; its PNG is written (the same bytes as drawn here)."""
    if drawn is None:
        args, kw = unrolled_job(out.result, out.gcode_path.name)
        preview_unrolled(*args, path, **kw)
        return path
    png = drawn.result()
    try:
        outputs.write(path, png)
    except OSError as e:
        raise _cannot_write(path, e) from None
    return path


def build_3d(out, path):
    """The 3D preview of an api.build() result (`bulgekit build --preview-3d`)."""
    walls = [(w.z, w.xy) for w in out.result.model.walls]
    bumps = [(p.x, p.y, p.z, p.weight) for p in out.result.points]
    preview_3d(walls, bumps, path, title=f"{out.gcode_path.name}: bulges on the walls")
    return path


def _save(fig, path):
    if isinstance(path, io.BytesIO):
        fig.savefig(path, format="png")
        return
    try:
        with outputs.part(path) as p:         # all or nothing (bulgekit.outputs)
            fig.savefig(p, format=os.path.splitext(os.fspath(path))[1][1:].lower() or "png")
    except OSError as e:
        raise _cannot_write(path, e) from None


def _cannot_write(path, e: OSError) -> InputError:
    return InputError(f"{os.fspath(path)}: cannot write preview: {e.strerror or e}")
