"""Braille on the wall: text -> braille cells (liblouis) -> a dome of bulge points per dot.

Braille is read by touch, so it is the bulge pattern whose geometry matters most. Cells are
laid at the common standard's spacing (Marburg Medium, as used in Europe and close to the US
and UK sign standards; docs/host.md, "Braille", gives the ranges): dots 2.5 mm apart within a
cell, cells 6.0 mm apart along a line, lines 10 mm apart.

    dot numbers in a cell        1 o o 4     v = top
                                 2 o o 5     v = top - 2.5 mm
                                 3 o o 6     v = top - 5 mm

A dot is round, about 1.5 mm at its base: over the layers it spans, each gets one point at
the dot's u, weighted by the dome's height at the layer's middle, w = 255 sqrt(1 - (dv / r)^2),
r = 0.75 mm, so the dwell (P x w / 255) is longest on the middle layer and falls off above and
below (a Stroke with `dome`, which the map builder lays on the layers it finds).

Translation uses liblouis (Debian: python3-louis and liblouis-data): grade 1 of Unified
English Braille by default, grade 2 or any other table by name. Its Python binding is
imported as `louis`, or from Debian's python3-louis where the running Python (a venv, pyenv)
does not see Debian's packages: the binding is plain ctypes over liblouis.so.20.
"""
from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass

from ..errors import InputError
from .strokes import Drawing, Stroke, drawn

DOT_PITCH = 2.5       # mm between dots 1-2-3 (and 1-4) of a cell
CELL_PITCH = 6.0      # mm from a cell to the next along a line
LINE_PITCH = 10.0     # mm from a line of cells to the next
DOT_BASE = 1.5        # mm, a dot's base diameter
GRADE_TABLES = {1: "en-ueb-g1.ctb", 2: "en-ueb-g2.ctb"}
DEBIAN_LOUIS = "/usr/lib/python3/dist-packages/louis/__init__.py"
# (du, dv) of dots 1..6 from the cell's top-left dot; 7 and 8 (eight-dot tables) below 3 and 6
_DOT_AT = {1: (0, 0), 2: (0, -1), 3: (0, -2), 4: (1, 0), 5: (1, -1), 6: (1, -2), 7: (0, -3), 8: (1, -3)}


class BrailleError(InputError):
    """Text that cannot be made into braille on this wall (the message says why)."""


_louis_module = None


def louis():
    """liblouis's Python binding: `import louis`, else Debian's python3-louis by its path."""
    global _louis_module
    if _louis_module is not None:
        return _louis_module
    try:
        import louis as mod                               # noqa: F811
    except ImportError:
        if not os.path.exists(DEBIAN_LOUIS):
            raise BrailleError("braille needs liblouis: install Debian's python3-louis and "
                               "liblouis-data (apt-get install python3-louis liblouis-data)") from None
        spec = importlib.util.spec_from_file_location("louis", DEBIAN_LOUIS)
        mod = importlib.util.module_from_spec(spec)
        try:
            spec.loader.exec_module(mod)
        except OSError as e:                               # liblouis.so.20 itself missing
            raise BrailleError(f"braille needs liblouis: {e} (apt-get install liblouis20)") from None
    _louis_module = mod
    return mod


def table_for(grade: int | None = None, table: str | None = None) -> str:
    """The liblouis table: `table` by name (e.g. de-g2.ctb, fr-bfu-g2.ctb), else the grade's."""
    if table:
        return table
    g = 1 if grade is None else grade
    if g not in GRADE_TABLES:
        raise BrailleError(f"braille grade {g}: give 1 or 2 (or a liblouis table by name)")
    return GRADE_TABLES[g]


def translate(text: str, table: str) -> list[str]:
    """Each line of text as braille cells (Unicode U+2800..U+28FF: bit k set = dot k + 1)."""
    lou = louis()
    try:
        lou.checkTable([table])
    except RuntimeError:
        raise BrailleError(f"braille table {table!r} not found (liblouis tables: "
                           "/usr/share/liblouis/tables; grade 1 is en-ueb-g1.ctb)") from None
    out = []
    for line in text.split("\n"):
        cells = lou.translateString([table], line, mode=lou.dotsIO | lou.ucBrl)
        bad = [c for c in cells if not 0x2800 <= ord(c) <= 0x28FF]
        if bad:
            raise BrailleError(f"braille: {table} left {bad[0]!r} untranslated in {line!r}")
        out.append(cells)
    return out


def back_translate(lines: list[str], table: str) -> str:
    """The text liblouis reads from braille cells (the check that placed cells say the text)."""
    lou = louis()
    return "\n".join(lou.backTranslateString([table], cells, mode=lou.ucBrl) for cells in lines)


def dots_of(cell: str) -> list[int]:
    """The raised dots (1..8) of one Unicode braille cell."""
    bits = ord(cell) - 0x2800
    return [k + 1 for k in range(8) if bits >> k & 1]


def cell_of(dots) -> str:
    return chr(0x2800 + sum(1 << (d - 1) for d in set(dots)))


@dataclass(frozen=True, eq=False)
class BrailleDrawing(Drawing):
    """Braille's size is the standard's, not an option: a drawing too tall is told so."""

    @property
    def given(self) -> str:
        return f"the standard spacing ({self.size:g} line{'s' if self.size != 1 else ''})"

    def fit(self, height: float, wall: float) -> str:
        return (f"braille keeps its standard size: give fewer lines (each {LINE_PITCH:g} mm) or "
                "print a taller part")


@dataclass(frozen=True)
class Dot:
    u: float          # mm, the dot's centre on the unrolled wall
    v: float
    line: int         # which line of cells, which cell in it, which dot (1..8)
    cell: int
    dot: int


def layout(lines: list[str], u0: float, v0: float) -> list[Dot]:
    """Dot centres: the first cell's dot 1 at (u0, v0 + 2 x DOT_PITCH), so that its dot 3 (the
    bottom row of six-dot braille) stands on v0, as a text's baseline does; lines go down."""
    out = []
    for li, cells in enumerate(lines):
        top = v0 + 2 * DOT_PITCH - li * LINE_PITCH
        for ci, cell in enumerate(cells):
            for d in dots_of(cell):
                du, dv = _DOT_AT[d]
                out.append(Dot(u0 + ci * CELL_PITCH + du * DOT_PITCH, top + dv * DOT_PITCH, li, ci, d))
    return out


def dome(dot: Dot, source: str) -> Stroke:
    """A dot as a one-point stroke with a dome of DOT_BASE / 2: the map builder gives every layer
    within it a point at the dot's u, weighted by the dome's height at the layer's middle."""
    return Stroke(((dot.u, dot.v),), 255, f"{source} cell {dot.cell + 1} dot {dot.dot}",
                  dome=DOT_BASE / 2)


def braille_strokes(text: str, u0: float = 0.0, v0: float = 0.0, grade: int | None = None,
                    table: str | None = None) -> list[Stroke]:
    """Text as braille domes on the wall, the first line's bottom dots on v0 from u0."""
    if not text.strip():
        raise BrailleError("braille: no text")
    tab = table_for(grade, table)
    lines = translate(text, tab)
    src = f"braille {text!r}"
    strokes = [dome(d, src) for d in layout(lines, u0, v0)]
    if not strokes:
        raise BrailleError(f"braille: {text!r} has no raised dot in {tab}")
    return drawn(strokes, BrailleDrawing(f"the braille {text!r}", len(lines), "--braille", "text",
                                         "lines", False, "its first cell's bottom dots"))


def readable(layer_height: float, dwell_ms: int, spacing: float) -> list[str]:
    """Why this printer cannot make a readable dot, if it cannot (empty: it can). A dot needs
    at least three layers across its base to be round; its bump must stay clear of the next
    dot 2.5 mm away (the over-extrusion paper measured about 1.8 mm at 500 ms, and the size
    grows about with the log of the dwell); and the map's points must not merge two dots."""
    out = []
    if layer_height > DOT_BASE / 3:
        out.append(f"layers of {layer_height:.2f} mm are too thick for a {DOT_BASE} mm braille dot "
                   f"(it needs 3 or more across its base: {DOT_BASE / 3:.2f} mm layers or thinner)")
    if dwell_ms > 500:
        out.append(f"a dwell of {dwell_ms} ms makes bumps larger than the 1.8 mm measured at 500 ms: "
                   f"dots {DOT_PITCH} mm apart would run together (500 ms or less)")
    if dwell_ms < 20:
        out.append(f"a dwell of {dwell_ms} ms makes bumps too small to feel (20 ms or more)")
    if spacing / 2 >= DOT_PITCH:
        out.append(f"point spacing {spacing:.2f} mm merges points closer than {spacing / 2:.2f} mm: "
                   f"two dots {DOT_PITCH} mm apart would become one (spacing under {2 * DOT_PITCH} mm)")
    return out


def wall_check(strokes, dwell_ms: int, spacing: float | None, line_width: float):
    """For api.build's _check_walls: when the strokes hold braille, refuse walls on which a
    readable dot cannot be made (readable()), before anything is written; None without braille."""
    said = next((st.drawing for st in strokes if isinstance(st.drawing, BrailleDrawing)), None)
    if said is None:
        return None

    def check(model):
        why = readable(model.layer_height, dwell_ms, spacing or 2 * line_width)
        if why:
            raise BrailleError(f"{said.entry}{said.what}: this print cannot make a readable dot: "
                               + "; ".join(why))
    return check
