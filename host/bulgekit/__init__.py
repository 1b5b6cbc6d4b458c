"""bulgekit host toolkit: bulge maps for the bulgekit firmware.

Draw on a print's outer wall (text, SVG, images), place the strokes on the
sliced toolpath, and send the printer a compact bulge map plus outer-wall
markers (M720/M721/M722); or rewrite the G-code for stock firmware with
dwells and extra filament (Takahashi & Miyashita, sec. 5.3).
"""
from __future__ import annotations

__version__ = "0.1.0"

from .api import BuildOutput, annotate, build, build_map, fallback, load_strokes, stats, walls
from .fallback import MODE_GEOMETRIC, MODE_MARKED, MODE_OFF, Settings
from .strokes import BulgekitError, InputError, Stroke, text_strokes

__all__ = [
    "BuildOutput", "BulgekitError", "InputError", "MODE_GEOMETRIC", "MODE_MARKED", "MODE_OFF",
    "Settings", "Stroke", "annotate", "build", "build_map", "fallback", "load_strokes", "stats",
    "text_strokes", "walls", "__version__",
]
