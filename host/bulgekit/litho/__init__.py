"""Lithophanes printed with one variable-width mid-line per layer (Jang & Hong 2017, Algorithm 1):
`bulgekit litho`. The package by stage, each module using only the ones above it:

    tone.py         the tone model: sRGB, L*, the tone curves, what a plate shows backlit
    options.py      LithoOptions (one field per option), their checks, LithoError
    picture.py      the picture read and laid onto the part's sample grid, through the curve
    thickness.py    the thickness field: frame, foot, the walls' widths (Field, thickness_field)
    calibration.py  the calibration plate, a thickness field of its own (calibration_field)
    paths.py        the paths of every layer (Plan, plan_lithophane; the method in its docstring)
    gcode.py        the width-mode and stock G-code, their estimated times (write_gcode)
    body.py         the body as an STL (body_mesh, write_stl)
    backlit.py      the predicted backlit look and the transmission picture
    stats.py        the figures (plan_stats)
    files.py        every file from a picture, all or nothing (make; bulgekit.outputs)

    plan = litho.plan_lithophane("cat.png", LithoOptions(shape="cylinder"))
    out = litho.make("cat.png", "out/")      # .litho.gcode .stock.gcode .stl .transmission.png .json

This module keeps the public names in one place (`from bulgekit import litho as lt; lt.make`).
"""
from __future__ import annotations

from . import tone
from .body import body_mesh, mesh_volume, write_stl
from .calibration import calibration_field
from .gcode import DEFAULT_END, DEFAULT_START, machine_for, machine_words, write_gcode
from .backlit import look, printed_thickness, write_transmission_png
from .files import LithoResult, make
from .options import (FLOW_ACCEL, INFILL_FLOW, LIGHT_GAPS, SHAPES, WORDS, LithoError, LithoOptions,
                      check_options, default_flow)
from .paths import CHORD_TOL, MIN_MOVE, ROUNDING, WIDTH_TOL, Layer, Plan, Section, plan_lithophane
from .stats import laid_area, laid_deviations, laid_volume, plan_stats
from .thickness import (BACK_SLACK, CENTRE_SLOPE, FOOT_MIN, FOOT_SLOPE, FRONT_HOLD, MID_MARGIN,
                        RATE_ACCEL_SHARE, RATE_STEP, Field, back_wall, foot_depth, thickness_field,
                        wall_max, wall_min, wall_widths)
from .tone import CURVES

__all__ = ["BACK_SLACK", "CENTRE_SLOPE", "CHORD_TOL", "CURVES", "DEFAULT_END", "DEFAULT_START",
           "FLOW_ACCEL", "FOOT_MIN", "FOOT_SLOPE", "FRONT_HOLD", "INFILL_FLOW", "LIGHT_GAPS",
           "MID_MARGIN", "MIN_MOVE", "RATE_ACCEL_SHARE", "RATE_STEP", "ROUNDING", "SHAPES",
           "WIDTH_TOL", "WORDS", "Field", "Layer", "LithoError", "LithoOptions", "LithoResult", "Plan",
           "Section", "back_wall", "body_mesh", "calibration_field", "check_options", "default_flow",
           "foot_depth", "laid_area", "laid_deviations", "laid_volume", "look", "machine_for",
           "machine_words", "make", "mesh_volume", "plan_lithophane", "plan_stats", "printed_thickness",
           "thickness_field", "tone", "wall_max", "wall_min", "wall_widths", "write_gcode", "write_stl",
           "write_transmission_png"]
