"""The body as an STL: the same solid the paths lay, watertight."""
from __future__ import annotations

import numpy as np

from .. import outputs
from .paths import Plan, arc_start


# --- the body as an STL --------------------------------------------------------------------

def body_mesh(plan: Plan) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (mm, bed coordinates) and triangles of the printed body, watertight.

    Rows of vertices lie at the layers' mid-heights, so a slicer cutting there (as Cura and
    PrusaSlicer do) gets exactly the layers planned here; the first and last rows are repeated at
    the bottom and the top. A foot is a separate closed box under the plate (the two shells touch).
    """
    o, fld = plan.options, plan.field
    H = o.layer_height
    t = fld.t[fld.n_foot:]
    z0 = fld.n_foot * H
    zs = np.concatenate([[z0], z0 + (np.arange(t.shape[0]) + 0.5) * H, [z0 + t.shape[0] * H]])
    T = np.vstack([t[:1], t, t[-1:]])
    ox, oy = plan.origin
    R, C = T.shape
    if o.shape == "planar":
        X = np.broadcast_to(fld.s, (R, C))
        front = np.stack([X, T, np.broadcast_to(zs[:, None], (R, C))], axis=-1)
        back = np.stack([X, np.zeros((R, C)), np.broadcast_to(zs[:, None], (R, C))], axis=-1)
        closed = False
    elif o.shape == "arc":
        r_in = o.diameter / 2 - o.max_thickness
        a = arc_start(fld) + fld.s
        c, sn = np.cos(a), np.sin(a)
        Z = np.broadcast_to(zs[:, None], (R, C))
        front = np.stack([(r_in + T) * c, (r_in + T) * sn, Z], axis=-1)
        back = np.stack([np.broadcast_to(r_in * c, (R, C)), np.broadcast_to(r_in * sn, (R, C)), Z], axis=-1)
        closed = False
    else:
        r_in = o.diameter / 2 - o.max_thickness
        c, sn = np.cos(fld.s), np.sin(fld.s)
        Z = np.broadcast_to(zs[:, None], (R, C))
        front = np.stack([(r_in + T) * c, (r_in + T) * sn, Z], axis=-1)
        # the back is a plain cylinder: its bottom and top rows are all it needs
        zb = np.broadcast_to(zs[[0, -1], None], (2, C))
        back = np.stack([np.broadcast_to(r_in * c, (2, C)), np.broadcast_to(r_in * sn, (2, C)), zb], axis=-1)
        closed = True
    V = np.concatenate([front.reshape(-1, 3), back.reshape(-1, 3)])
    nf = R * C
    idx_f = np.arange(nf).reshape(R, C)
    idx_b = np.arange(nf, len(V)).reshape(-1, C)
    faces = []

    def grid(idx, flip):
        a = idx[:-1, :-1]; b = idx[:-1, 1:]; c_ = idx[1:, 1:]; d = idx[1:, :-1]
        if closed:
            a = idx[:-1]; b = np.roll(idx[:-1], -1, axis=1); c_ = np.roll(idx[1:], -1, axis=1); d = idx[1:]
        t1 = np.stack([a, b, c_], -1).reshape(-1, 3)
        t2 = np.stack([a, c_, d], -1).reshape(-1, 3)
        tri = np.concatenate([t1, t2])
        return tri[:, ::-1] if flip else tri

    # The outward normal follows the winding; planar front faces +Y, cylinder and arc fronts face
    # outwards (their samples run the other way round as seen from the relief)
    turned = o.shape != "planar"
    faces.append(grid(idx_f, flip=not turned))
    faces.append(grid(idx_b, flip=turned))

    def strip(top_idx, bot_idx, flip):
        """Quads between two vertex rows (a cap or an end), as triangles."""
        a = top_idx[:-1]; b = top_idx[1:]; c_ = bot_idx[1:]; d = bot_idx[:-1]
        if closed:
            a = top_idx; b = np.roll(top_idx, -1); c_ = np.roll(bot_idx, -1); d = bot_idx
        tri = np.concatenate([np.stack([a, b, c_], -1), np.stack([a, c_, d], -1)])
        return tri[:, ::-1] if flip else tri

    faces.append(strip(idx_f[0], idx_b[0], flip=turned))        # bottom cap
    faces.append(strip(idx_f[-1], idx_b[-1], flip=not turned))  # top cap
    if not closed:                                              # the two ends of the plate or arc
        faces.append(strip(idx_f[:, 0], idx_b[:, 0], flip=not turned))
        faces.append(strip(idx_f[:, -1], idx_b[:, -1], flip=turned))
    F = np.concatenate(faces)
    V = V + np.array([ox, oy, 0.0])
    if fld.n_foot:
        y0 = (o.max_thickness - o.foot) / 2
        bx = np.array([[0, y0, 0], [fld.s[-1], y0, 0], [fld.s[-1], y0 + o.foot, 0], [0, y0 + o.foot, 0]], float)
        box = np.vstack([bx, bx + [0, 0, z0]]) + [ox, oy, 0.0]
        q = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5),
             (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
        F = np.concatenate([F, np.array(q) + len(V)])
        V = np.concatenate([V, box])
    return V, F


def mesh_volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def write_stl(V: np.ndarray, F: np.ndarray, path, name="bulgekit lithophane") -> None:
    tri = V[F].astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    rec = np.zeros(len(F), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"], rec["v"] = n, tri
    head = name.encode()[:80].ljust(80, b" ")
    outputs.write(path, [head, np.uint32(len(F)).tobytes(), memoryview(rec).cast("B")])


def standing(V: np.ndarray, F: np.ndarray) -> dict:
    """Whether the body stands by itself: its centre of mass (uniform density) against its
    footprint on the bed (the convex hull of the vertices on the bed), the margin from the centre
    of mass's plumb point to the footprint's edge (negative: outside, it falls over) and the
    angle it may be leaned by before it tips, atan(margin / height of the centre of mass)."""
    import shapely
    from shapely.geometry import MultiPoint

    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0          # tetrahedra from the origin
    com = (vol[:, None] * (a + b + c) / 4.0).sum(axis=0) / vol.sum()
    z0 = V[:, 2].min()
    hull = MultiPoint(V[V[:, 2] <= z0 + 1e-6, :2]).convex_hull
    p = shapely.Point(com[:2])
    margin = hull.exterior.distance(p) * (1 if hull.contains(p) else -1)
    h = com[2] - z0
    return {"centre_of_mass_mm": [round(float(x), 2) for x in com],
            "footprint_margin_mm": round(float(margin), 2),
            "tip_angle_deg": round(float(np.degrees(np.arctan2(margin, h))), 1),
            "stands": bool(margin > 0)}
