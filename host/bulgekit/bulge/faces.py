"""Drawings on the faces of the wall (its stretches between corners, wall.Wall.faces).

* place(): a drawing asked for on a face (--face N --align left|center|right, or a placement
  entry's face/align keys; strokes.on_face) is moved along u onto that face of the layer at the
  middle of its height: its strokes' u extent starts at the face's start (left), has its middle
  at the face's middle (center) or ends at the face's end (right), then U of --at U,V is added.
  V is the height as without a face.
* warnings(): one line per drawing that crosses a corner of a layer it is on (it bends round
  the corner), and per drawing on the first layer of the wall.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from ..errors import InputError
from .strokes import Stroke, resample
from .wall import Wall, WallModel

CORNER_MARGIN_MM = 0.5      # a drawing crosses a corner when it reaches past it by more than this
_PITCH_MM = 0.25            # its strokes are followed this finely


class FaceError(InputError):
    """A face that the wall does not have."""


def _name(st: Stroke) -> str:
    d = st.drawing
    return f"{d.entry}{d.what}" if d is not None else (st.source or "a stroke")


def _groups(strokes: Sequence[Stroke]) -> list[list[int]]:
    """Indices of the strokes of each drawing (a stroke of none: by its source), in order."""
    by: dict = {}
    for i, st in enumerate(strokes):
        key = ("d", id(st.drawing)) if st.drawing is not None else ("s", st.source)
        by.setdefault(key, []).append(i)
    return list(by.values())


def layer_near(model: WallModel, v: float) -> Wall:
    """The wall of the layer holding height v, or of the nearest layer when none does."""
    i = int(model.layer_of_v(v)[0])
    if i < 0:
        i = int(np.argmin(np.abs(model.zs - v)))
    return model.walls[i]


def place(strokes: Sequence[Stroke], model: WallModel) -> list[Stroke]:
    """The strokes, those of drawings asked for on a face moved there (see the module)."""
    out = list(strokes)
    for g in _groups(strokes):
        d = strokes[g[0]].drawing
        if d is None or d.face is None or d.aligned:
            continue
        pts = np.array([p for i in g for p in strokes[i].points], dtype=float)
        umin, umax = float(pts[:, 0].min()), float(pts[:, 0].max())
        vmid = (float(pts[:, 1].min()) + float(pts[:, 1].max())) / 2
        wall = layer_near(model, vmid)
        faces = wall.faces
        if d.face > len(faces):
            raise FaceError(f"{d.entry}{d.what}: face {d.face}, but the wall at its middle "
                            f"(z {wall.z:.2f} mm) has {len(faces)} face(s), 1..{len(faces)}"
                            + ("" if len(faces) > 1 else " (no corners: a round wall)"))
        f = faces[d.face - 1]
        anchor = {"left": (f.u0, umin), "center": (f.middle, (umin + umax) / 2),
                  "right": (f.u1, umax)}[d.align]
        shift = anchor[0] + d.offset_u - anchor[1]
        moved = replace(d, aligned=True)
        if hasattr(moved, "u0"):                  # a picture's grid moves with its dots
            moved = replace(moved, u0=moved.u0 + shift)
        for i in g:
            st = strokes[i]
            out[i] = replace(st, points=tuple((u + shift, v) for u, v in st.points), drawing=moved)
    return out


def warnings(strokes: Sequence[Stroke], model: WallModel) -> list[str]:
    """Per drawing: that it crosses a corner (the one it crosses on most layers), and that it is
    on the first layer of the wall."""
    out = []
    first = model.walls[0]
    for g in _groups(strokes):
        pts = np.array([p for i in g for p in resample(strokes[i], _PITCH_MM)], dtype=float)
        layer = model.layer_of_v(pts[:, 1])
        name = _name(strokes[g[0]])
        d = strokes[g[0]].drawing
        crossed: dict[tuple[int, int], list[tuple[float, float]]] = {}   # faces -> (z, corner u)
        for li in np.unique(layer[layer >= 0]).tolist():
            wall = model.walls[li]
            if not wall.closed or not len(wall.corners):
                continue
            us = pts[layer == li, 0]
            lo, hi = float(us.min()) + CORNER_MARGIN_MM, float(us.max()) - CORNER_MARGIN_MM
            L = wall.length
            for c in wall.corners.tolist():
                k = np.arange(np.ceil((lo - c) / L), np.floor((hi - c) / L) + 1)
                for u in (c + k * L).tolist():
                    if lo < u < hi:
                        key = (wall.face_of_u(u - 1e-3).number, wall.face_of_u(u + 1e-3).number)
                        crossed.setdefault(key, []).append((wall.z, u))
        if crossed:
            (fa, fb), at = max(crossed.items(), key=lambda kv: len(kv[1]))
            z, u = at[len(at) // 2]
            zs = f"z {at[0][0]:.2f}-{at[-1][0]:.2f} mm" if len(at) > 1 else f"z {at[0][0]:.2f} mm"
            how = "face = N" if d is not None and d.entry else "--face N"
            out.append(f"{name} crosses the corner between faces {fa} and {fb} at u {u:.1f} mm "
                       f"({zs}): it bends round it ({how} puts it on one face)")
        if (layer == 0).any():
            at = "at = [U, V]" if d is not None and d.entry else "--at U,V"
            out.append(f"{name} is on the first layer (z {first.z:.2f} mm): bumps there are "
                       f"pressed flat on the bed; start it 1 mm up or more (V of {at})")
    return out
