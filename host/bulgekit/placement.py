"""Placement files: what to draw on the outer wall, in a small TOML file that a slicer's
post-processing step (`bulgekit post-process`) or `bulgekit build --placement` reads.

    [[text]]                     # any number of these
    text = "HELLO"
    at = [5, 6]                  # u, v mm: baseline start on the unrolled wall
    size = 6                     # capital height, mm
    font = "futural"             # Hershey font
    letter_spacing = 0.0
    mirror = false

    [[strokes]]                  # SVG, JSON stroke list or an image; path relative to this file
    file = "wave.json"
    at = [0, 0]
    scale = 1.0
    image_width = 20             # images: width on the wall, mm
    curve_tolerance = 0.05

    [bulges]                     # M720 settings and how points are placed; all optional
    dwell = 100                  # ms
    extra = 0.1                  # mm of filament
    tolerance = 0.25             # mm
    geometric = false            # no outer-wall markers in the G-code (M720 S2)
    spacing = 0.9                # mm between points along a layer
    line_width = 0.45
    fallback = false             # write stock-firmware G-code (G4 + extra E) instead of M720-M722

Unknown tables or keys, wrong types and missing files are errors that name the file and key.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .strokes import InputError, Stroke

_TEXT_KEYS = {"text": str, "at": list, "size": (int, float), "font": str, "letter_spacing": (int, float),
              "mirror": bool}
_STROKE_KEYS = {"file": str, "at": list, "scale": (int, float), "image_width": (int, float),
                "curve_tolerance": (int, float)}
_BULGE_KEYS = {"dwell": int, "extra": (int, float), "tolerance": (int, float), "geometric": bool,
               "spacing": (int, float), "line_width": (int, float), "fallback": bool}


class PlacementError(InputError):
    """A placement file that cannot be used (the message names the file and key)."""


@dataclass
class Placement:
    path: Path
    strokes: list[Stroke]
    bulges: dict = field(default_factory=dict)


def _check(table: dict, keys: dict, where: str, src: Path) -> None:
    for k, v in table.items():
        if k not in keys:
            raise PlacementError(f"{src}: {where}: unknown key {k!r} (known: {', '.join(sorted(keys))})")
        want = keys[k]
        numeric = want is int or want == (int, float)
        if (numeric and isinstance(v, bool)) or not isinstance(v, want):
            raise PlacementError(f"{src}: {where}.{k}: expected {_name(want)}, got {v!r}")
        if isinstance(v, float) and not math.isfinite(v):
            raise PlacementError(f"{src}: {where}.{k}: must be a finite number, got {v!r}")


def _name(t) -> str:
    names = {str: "a string", list: "a list [u, v]", int: "a whole number", bool: "true or false",
             float: "a number"}
    return names[t] if not isinstance(t, tuple) else "a number"


def _at(table: dict, where: str, src: Path) -> tuple[float, float]:
    at = table.get("at", [0, 0])
    if len(at) != 2 or not all(isinstance(a, (int, float)) and not isinstance(a, bool)
                               and math.isfinite(a) for a in at):
        raise PlacementError(f"{src}: {where}.at: expected [u, v] in mm, got {at!r}")
    return float(at[0]), float(at[1])


def load_placement(path) -> Placement:
    """Read and check a placement file; the strokes are made here (fonts, SVG, images)."""
    from . import api
    from .strokes import text_strokes

    src = Path(path)
    try:
        with open(src, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise PlacementError(f"{src}: placement file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise PlacementError(f"{src}: not valid TOML: {e}") from None
    for k in doc:
        if k not in ("text", "strokes", "bulges"):
            raise PlacementError(f"{src}: unknown table {k!r} (known: text, strokes, bulges)")
    strokes: list[Stroke] = []
    for i, t in enumerate(_tables(doc, "text", src)):
        where = f"text[{i}]"
        _check(t, _TEXT_KEYS, where, src)
        if "text" not in t:
            raise PlacementError(f"{src}: {where}: 'text' is missing")
        u, v = _at(t, where, src)
        try:
            strokes += text_strokes(t["text"], float(t.get("size", 6.0)), spacing=float(t.get("letter_spacing", 0.0)),
                                    u0=u, v0=v, mirror=t.get("mirror", False), font=t.get("font", "futural"))
        except InputError as e:
            raise PlacementError(f"{src}: {where}: {e}") from None
    for i, t in enumerate(_tables(doc, "strokes", src)):
        where = f"strokes[{i}]"
        _check(t, _STROKE_KEYS, where, src)
        if "file" not in t:
            raise PlacementError(f"{src}: {where}: 'file' is missing")
        f = (src.parent / t["file"]) if not Path(t["file"]).is_absolute() else Path(t["file"])
        if not f.is_file():
            raise PlacementError(f"{src}: {where}.file: {f} not found")
        strokes += api.load_strokes(f, image_width_mm=t.get("image_width"), offset=_at(t, where, src),
                                    scale=float(t.get("scale", 1.0)),
                                    curve_tolerance_mm=float(t.get("curve_tolerance", 0.05)))
    bulges = doc.get("bulges", {})
    if not isinstance(bulges, dict):
        raise PlacementError(f"{src}: 'bulges' must be a table ([bulges])")
    _check(bulges, _BULGE_KEYS, "bulges", src)
    if not strokes:
        raise PlacementError(f"{src}: nothing to draw: add a [[text]] or [[strokes]] table")
    return Placement(src, strokes, dict(bulges))


def _tables(doc: dict, key: str, src: Path) -> list[dict]:
    v = doc.get(key, [])
    if isinstance(v, dict):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
        raise PlacementError(f"{src}: '{key}' must be one or more tables ([[{key}]])")
    return v
