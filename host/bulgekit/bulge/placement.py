"""Placement files: what to draw on the outer wall, in a small TOML file that a slicer's
post-processing step (`bulgekit post-process`) or `bulgekit build --placement` reads.

    [[text]]                     # any number of these
    text = "HELLO"
    at = [5, 6]                  # u, v mm: baseline start on the unrolled wall
    size = 6                     # capital height, mm
    font = "futural"             # Hershey font
    letter_spacing = 0.0
    mirror = false
    rotate = 0                   # degrees, counter-clockwise about `at`
    face = 2                     # on face 2 of the wall (then at's u is an offset from there)
    align = "center"             # "left", "center" (the default with a face) or "right"

    [[braille]]                  # any number of these: text in braille, the standard's spacing
    text = "HELLO"
    at = [5, 3]                  # u, v mm: the first cell's bottom dots (face and align as in text)
    grade = 1                    # 1 or 2 (Unified English Braille), or:
    table = "de-g2.ctb"          # any liblouis table by name

    [[strokes]]                  # SVG, JSON stroke list or an image; path relative to this file
    file = "wave.json"
    at = [0, 1]                  # default [0, 1]: u 0, 1 mm above the bed ([0, 0] for .json)
    scale = 1.0
    image_width = 20             # images: width on the wall, mm
    curve_tolerance = 0.05
    rotate = 0                   # degrees, counter-clockwise about `at`

    [bulges]                     # M720 settings and how points are placed; all optional
    dwell = 100                  # ms
    extra = 0.1                  # mm of filament
    tolerance = 0.25             # mm
    geometric = false            # no outer-wall markers in the G-code (M720 S2)
    spacing = 0.9                # mm between points along a layer
    line_width = 0.45
    fallback = false             # write stock-firmware G-code (stops + extra E) instead of M720-M722
    stop = "move"                # stock stops: "move" (E-only moves, exact) or "g4" (G4 P<ms>)
    printer = "ender3"           # the printer model: a preset, or a file (an M503 reply, a Klipper
                                 # printer.cfg, a profile TOML) relative to this file
    firmware = "marlin"          # marlin, klipper, prusa or reprap [the printer model's]
    e_steps = 93                 # the printer's E steps/mm (an M92 E in the G-code wins) [the model's]
    stop_e_steps = 6             # E steps laid during each stop (default: the fewest that make a move)

Unknown tables or keys, wrong types and missing files are errors that name the file and key.
Every stroke's source starts with its table ("text[0] ...", "strokes[1] ..."), so a message
about a stroke names the entry it came from. `dump_placement` writes such a file (the studio).
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import InputError, MissingInputError
from .strokes import Stroke, on_face

_TEXT_KEYS = {"text": str, "at": list, "size": (int, float), "font": str, "letter_spacing": (int, float),
              "mirror": bool, "rotate": (int, float), "face": int, "align": str}
_BRAILLE_KEYS = {"text": str, "at": list, "grade": int, "table": str, "face": int, "align": str}
_STROKE_KEYS = {"file": str, "at": list, "scale": (int, float), "image_width": (int, float),
                "curve_tolerance": (int, float), "rotate": (int, float), "face": int, "align": str}
_BULGE_KEYS = {"dwell": int, "extra": (int, float), "tolerance": (int, float), "geometric": bool,
               "spacing": (int, float), "line_width": (int, float), "fallback": bool,
               "stop": str, "e_steps": (int, float), "stop_e_steps": int, "printer": str,
               "firmware": str}


class PlacementError(InputError):
    """A placement file that cannot be used (the message names the file and key)."""


class PlacementFileMissing(PlacementError, MissingInputError):
    """The placement file, or a file it names, is not there (exit status 2 from the CLI)."""


@dataclass
class Placement:
    path: Path
    strokes: list[Stroke]
    bulges: dict = field(default_factory=dict)
    entries: list[str] = field(default_factory=list)   # "text[0]", "strokes[0]" ...: those that drew, in order

    @property
    def printer(self) -> str | None:
        """[bulges] printer: a preset's name, or its file's path taken from this file's folder."""
        v = self.bulges.get("printer")
        if v is None:
            return None
        from ..machine import PRESETS
        if v in PRESETS:
            return v
        f = Path(v) if Path(v).is_absolute() else self.path.parent / v
        if not f.is_file():
            raise PlacementFileMissing(f"{self.path}: bulges.printer: {v} is neither a preset "
                                       f"({', '.join(PRESETS)}) nor a file")
        return str(f)


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


def _at(table: dict, where: str, src: Path, file: str | None = None) -> tuple[float, float]:
    """at = [u, v]; by default [0, 1], 1 mm above the bed (a .json stroke list: [0, 0], as it is)."""
    at = table.get("at", [0, 0] if file is not None and file.lower().endswith(".json") else [0, 1])
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
        raise PlacementFileMissing(f"{src}: placement file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise PlacementError(f"{src}: not valid TOML: {e}") from None
    for k in doc:
        if k not in ("text", "braille", "strokes", "bulges"):
            raise PlacementError(f"{src}: unknown table {k!r} (known: text, braille, strokes, bulges)")
    strokes: list[Stroke] = []
    entries: list[str] = []
    from .braille import braille_strokes
    lettering = (   # (table, its keys, its strokes at (u, v), turned by `rotate`)
        ("text", _TEXT_KEYS, True, lambda t, u, v: text_strokes(
            t["text"], float(t.get("size", 6.0)), spacing=float(t.get("letter_spacing", 0.0)), u0=u, v0=v,
            mirror=t.get("mirror", False), font=t.get("font", "futural"))),
        ("braille", _BRAILLE_KEYS, False, lambda t, u, v: braille_strokes(
            t["text"], u, v, t.get("grade"), t.get("table"))))
    for kind, keys, turns, make in lettering:
        for i, t in enumerate(_tables(doc, kind, src)):
            where = f"{kind}[{i}]"
            _check(t, keys, where, src)
            if "text" not in t:
                raise PlacementError(f"{src}: {where}: 'text' is missing")
            u, v = _at(t, where, src)
            try:
                made = make(t, u, v)
            except InputError as e:
                raise PlacementError(f"{src}: {where}: {e}") from None
            if turns:
                made = _rotated(made, t.get("rotate", 0), (u, v))
            strokes += _tagged(_on_face(made, t, u, where, src), where, src)
            entries.append(where)
    for i, t in enumerate(_tables(doc, "strokes", src)):
        where = f"strokes[{i}]"
        _check(t, _STROKE_KEYS, where, src)
        if "file" not in t:
            raise PlacementError(f"{src}: {where}: 'file' is missing")
        f = (src.parent / t["file"]) if not Path(t["file"]).is_absolute() else Path(t["file"])
        if not f.is_file():
            raise PlacementFileMissing(f"{src}: {where}.file: {f} not found")
        at = _at(t, where, src, t["file"])
        if f.suffix.lower() in api._IMAGE_EXT and "image_width" not in t:
            raise PlacementError(f"{src}: {where}: {t['file']} is a picture: give image_width "
                                 "(its width on the wall, mm)")
        try:
            made = api.load_strokes(f, image_width_mm=t.get("image_width"), offset=at,
                                    scale=float(t.get("scale", 1.0)),
                                    curve_tolerance_mm=float(t.get("curve_tolerance", 0.05)))
        except InputError as e:
            raise PlacementError(f"{src}: {where}: {e}") from None
        strokes += _tagged(_on_face(_rotated(made, t.get("rotate", 0), at), t, at[0], where, src),
                           where, src)
        entries.append(where)
    bulges = doc.get("bulges", {})
    if not isinstance(bulges, dict):
        raise PlacementError(f"{src}: 'bulges' must be a table ([bulges])")
    _check(bulges, _BULGE_KEYS, "bulges", src)
    if not strokes:
        raise PlacementError(f"{src}: nothing to draw: add a [[text]], [[braille]] or [[strokes]] table")
    return Placement(src, strokes, dict(bulges), entries)


def _rotated(strokes: list[Stroke], degrees: float, about: tuple[float, float]) -> list[Stroke]:
    """Strokes turned counter-clockwise (u right, v up) about the entry's `at` point."""
    if not degrees % 360:
        return strokes
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    u0, v0 = about
    return [replace(st, points=tuple((u0 + c * (u - u0) - s * (v - v0), v0 + s * (u - u0) + c * (v - v0))
                                     for u, v in st.points)) for st in strokes]


def _on_face(strokes: list[Stroke], table: dict, u: float, where: str, src: Path) -> list[Stroke]:
    """The entry's strokes to be placed on its face (strokes.on_face), if it names one."""
    try:
        return on_face(strokes, table.get("face"), table.get("align"), u)
    except InputError as e:
        raise PlacementError(f"{src}: {where}: {e}") from None


def _tagged(strokes: list[Stroke], where: str, src: Path) -> list[Stroke]:
    """Strokes whose source starts with their entry, and whose drawing (a message about it
    names the entry's keys, not the CLI's options) knows it."""
    placed: dict = {}
    for st in strokes:
        if st.drawing is not None and id(st.drawing) not in placed:
            placed[id(st.drawing)] = st.drawing.placed(f"{src}: {where}")
    return [replace(st, source=f"{where} {st.source}" if st.source else where,
                    drawing=placed.get(id(st.drawing))) for st in strokes]


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise PlacementError(f"cannot write {v!r} to a placement file (not a finite number)")
        return repr(v)
    if isinstance(v, str):
        # a TOML basic string: JSON's escapes are TOML's (\", \\, \n, \uXXXX)
        import json
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise PlacementError(f"cannot write {v!r} to a placement file")


def dump_placement(texts: list[dict], strokes: list[dict], bulges: dict, header: str = "",
                   braille: list[dict] = ()) -> str:
    """A placement file's text: [[text]] tables, then [[braille]], then [[strokes]] (the order
    load_placement reads them in), then [bulges]. The keys are checked as load_placement checks
    them, so what this writes reads back the same."""
    out = [f"# {ln}" if ln else "#" for ln in header.splitlines()]
    for kind, tables, keys in (("text", texts, _TEXT_KEYS), ("braille", braille, _BRAILLE_KEYS),
                               ("strokes", strokes, _STROKE_KEYS)):
        for i, t in enumerate(tables):
            _check(t, keys, f"{kind}[{i}]", Path("placement"))
            out += ["", f"[[{kind}]]"] + [f"{k} = {_toml_value(v)}" for k, v in t.items()]
    if bulges:
        _check(bulges, _BULGE_KEYS, "bulges", Path("placement"))
        out += ["", "[bulges]"] + [f"{k} = {_toml_value(v)}" for k, v in bulges.items()]
    return "\n".join(out).lstrip("\n") + "\n"


def _tables(doc: dict, key: str, src: Path) -> list[dict]:
    v = doc.get(key, [])
    if isinstance(v, dict):
        v = [v]
    if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
        raise PlacementError(f"{src}: '{key}' must be one or more tables ([[{key}]])")
    return v
