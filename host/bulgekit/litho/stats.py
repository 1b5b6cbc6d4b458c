"""The figures of a plan: what the G-code lays against the body, moves, filament, fill, caps,
walls, gaps, the look."""
from __future__ import annotations

import math

import numpy as np

from . import tone
from .backlit import likeness
from .options import INFILL_FLOW
from .paths import Plan, _capped


def laid_area(plan: Plan, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Area (mm^2) laid by layer k's walls and mid-line(s) over each interval between
    neighbouring samples, and the body's area there (as the STL has it). A merged piece is spread
    over the stretch along the layer it spans (in samples, Section.u), a piece across the layer
    (a planar end wall) goes to the interval it stands in; joins laid as connectors of their own
    are not counted."""
    o, fld = plan.options, plan.field
    t = fld.t[k]
    n = len(t)
    closed = o.shape == "cylinder"
    m = n if closed else n - 1
    lo_all, hi_all, a_all = [], [], []
    for s in plan.layers[k].sections:
        on = s.e > 0
        a = (s.e * o.filament_area / o.layer_height)[on]
        ua, ub = s.u[:-1][on], s.u[1:][on]
        if closed:                                  # across the seam: unwrap
            ub = np.where(ub - ua > n / 2, ub - n, np.where(ua - ub > n / 2, ub + n, ub))
        lo_all.append(np.minimum(ua, ub)), hi_all.append(np.maximum(ua, ub)), a_all.append(a)
    lo, hi, a = (np.concatenate(x) for x in (lo_all, hi_all, a_all))
    if closed:
        lo, hi = lo % n, lo % n + (hi - lo)
    laid = np.zeros(m + (1 if not closed else n))
    point = hi - lo < 1e-9
    np.add.at(laid, np.minimum(np.floor(lo[point]).astype(int), m - 1), a[point])
    lo, hi, a = lo[~point], hi[~point], a[~point]
    # each piece lays evenly along [lo, hi]: the laid area up to u is piecewise linear in u
    ev = np.concatenate([lo, hi])
    slope = np.concatenate([a / (hi - lo), -a / (hi - lo)])
    order = np.argsort(ev, kind="stable")
    ev, slope = ev[order], np.cumsum(slope[order])
    cum = np.concatenate([[0.0], np.cumsum(slope[:-1] * np.diff(ev))])
    q = np.arange(len(laid) + 1, dtype=float)
    F = np.interp(q, ev, cum, left=0.0, right=cum[-1])
    laid = laid + np.diff(F)
    if closed:
        laid = laid[:n] + np.concatenate([laid[n:], np.zeros(n - len(laid[n:]))])
        r_in = o.diameter / 2 - o.max_thickness
        r2 = (r_in + t) ** 2 - r_in ** 2
        body = (r2 + np.roll(r2, -1)) / 4 * (2 * math.pi / n)
    else:
        laid = laid[:m]
        body = (t[:-1] + t[1:]) / 2 * np.diff(fld.s)
        if k < fld.n_foot:
            body = np.full(m, o.foot) * np.diff(fld.s)
    return laid, body


def laid_deviations(plan: Plan, first: int | None = None) -> tuple[list[float], list[np.ndarray]]:
    """What the pieces lay (laid_area, from their E) against the body, on layers first.. (the
    picture's first by default): per layer its total's deviation (laid / body - 1), and the
    deviation |laid / body - 1| of each interval between neighbouring samples."""
    fld = plan.field
    totals, dev = [], []
    for k in range(fld.n_foot if first is None else first, len(plan.layers)):
        laid, body = laid_area(plan, k)
        totals.append(float(laid.sum() / body.sum() - 1))
        dev.append(np.abs(laid / np.maximum(body, 1e-12) - 1))
    return totals, dev


def laid_volume(plan: Plan) -> dict:
    """How the filament the pieces lay follows the body's volume, on the picture's layers
    (laid_deviations): the largest deviation of a layer's total, and per interval between
    neighbouring samples the median, 99th percentile and largest (a merged piece averages the
    intervals it spans: the block-rate budget's price), the planar plate's end intervals apart."""
    totals, per = laid_deviations(plan)
    if not per:
        return {}
    dev = np.concatenate(per)
    ends = [max(d[0], d[-1]) for d in per] if plan.options.shape != "cylinder" else []
    r = lambda v: round(float(v), 4)
    return {"layer_total_max_dev": r(max(map(abs, totals))), "interval_median_dev": r(np.median(dev)),
            "interval_p99_dev": r(np.percentile(dev, 99)), "interval_max_dev": r(dev.max()),
            "end_intervals_max_dev": r(max(ends)) if ends else None}


def plan_stats(plan: Plan, stl_volume: float) -> dict:
    """Figures of the plan (the G-code follows it piece by piece)."""
    o, fld = plan.options, plan.field
    area = o.filament_area
    by_kind: dict[str, dict] = {}
    moves = 0
    capped_t = total_mid_t = capped_len = mid_len = 0.0
    for k, L in enumerate(plan.layers):
        for s in L.sections:
            seg = np.linalg.norm(np.diff(s.pts, axis=0), axis=1)
            laid = s.e > 0
            d = by_kind.setdefault(s.kind, {"length_mm": 0.0, "filament_mm": 0.0, "time_no_accel_s": 0.0,
                                            "moves": 0})
            d["length_mm"] += float(seg[laid].sum())
            d["filament_mm"] += float(s.e.sum())
            d["time_no_accel_s"] += (float((seg[laid] / s.v[laid]).sum())
                                     + float((seg[~laid] / o.travel_speed).sum()))
            d["moves"] += int(laid.sum())
            moves += int(laid.sum())
            if s.kind == "mid-line" and laid.any():
                tm = seg[laid] / s.v[laid]
                flow = o.mid_flow * (o.first_layer_speed / o.wall_speed if k == 0 else 1.0)
                cap = _capped(s, o, flow)[laid]
                capped_t += float(tm[cap].sum()); total_mid_t += float(tm.sum())
                capped_len += float(seg[laid][cap].sum()); mid_len += float(seg[laid].sum())
    filament = sum(d["filament_mm"] for d in by_kind.values())
    L_lo, L_hi = tone.plate_range(o.attenuation, o.min_thickness, o.max_thickness)
    pic = fld.t[fld.n_foot:]
    samples = pic.size
    laid = laid_volume(plan)
    return {
        "shape": o.shape,
        "layers": len(plan.layers),
        "samples_per_layer": int(len(fld.s)),
        "size_mm": {"picture_width": round(fld.picture_mm[0], 3), "picture_height": round(fld.picture_mm[1], 3),
                    "height": round(plan.layers[-1].z, 3)},
        "extruding_moves": moves,
        "filament_mm": round(filament, 2),
        "deposited_mm3": round(filament * area, 2),
        "stl_volume_mm3": round(stl_volume, 2),
        "fill_ratio": round(filament * area / stl_volume, 4),
        "time_no_accel_s": round(sum(d["time_no_accel_s"] for d in by_kind.values()), 1),
        "by_kind": {k: {kk: round(vv, 3) for kk, vv in d.items()} for k, d in by_kind.items()},
        "rates": {"wall_mm3_s": round(o.wall_flow, 4), "mid_line_mm3_s": round(o.mid_flow, 4),
                  "mid_line_e_mm_s": round(o.mid_flow / area, 5), "paper_rate": o.paper_rate,
                  # the default rate lowered for a printer that accelerates less (default_flow)
                  "mid_line_lowered_for_accel_mm_s2": o.accel if (o.infill_flow is None and not o.paper_rate
                                                                  and o.flow < INFILL_FLOW) else None},
        "mid_line": {
            "capped_time_share": round(capped_t / total_mid_t, 4) if total_mid_t else 0.0,
            "capped_length_share": round(capped_len / mid_len, 4) if mid_len else 0.0,
            "capped_pieces": plan.counts.get("capped_pieces", 0),
            "given_to_walls_mm3": round(plan.counts.get("shared_mm3", 0.0), 2),
            "layers_with_two_or_more": int((fld.lines > 1).sum()),
            "max_lines_per_layer": int(fld.lines.max()),
        },
        "walls": {name: {"min": round(float(w_.min()), 3), "median": round(float(np.median(w_)), 3),
                         "max": round(float(w_.max()), 3)}
                  for name, w_ in (("back_mm", fld.ww[fld.n_foot:]), ("front_mm", fld.wf[fld.n_foot:]))},
        "gaps": {
            "shared_by_walls": fld.shared,
            "shared_share": round(fld.shared / samples, 4),
            "narrowed_by_walls": fld.narrowed,
            "narrowed_share": round(fld.narrowed / samples, 4),
            "light_gaps": o.light_gaps,
            "min_line_mm": round(o.line_min(), 4), "max_line_mm": o.max_line,
        },
        "laid_volume": laid,
        "look": {"attenuation_per_mm": o.attenuation, "curve": o.curve,
                 "plate_L_range": [round(L_lo, 2), round(L_hi, 2)],
                 # the picture against the print as sampled, with the light's scatter (backlit.likeness)
                 "picture_vs_print": likeness(plan)},
    }
