"""bulgekit host toolkit: bulge maps for the bulgekit firmware.

Draw on a print's outer wall (text, SVG, images), place the strokes on the
sliced toolpath, and send the printer a compact bulge map plus outer-wall
markers (M720/M721/M722); or rewrite the G-code for stock firmware with
dwells and extra filament (Takahashi & Miyashita, sec. 5.3).
"""
from __future__ import annotations

import os as _os
import sys as _sys

__version__ = "0.1.0"

# The host's numpy work is element by element, never BLAS: without this, OpenBLAS starts a thread
# per core when numpy is imported, about 0.06 s of CPU in every command (docs/host.md, "Speed and
# memory on one large file"). Only when numpy is not loaded yet and the user has not chosen.
if "numpy" not in _sys.modules:
    _os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from .errors import BulgekitError, InputError

# Function names differ from the module names (bulge/annotate.py, bulge/fallback.py,
# bulge/stats.py) so that `from bulgekit.bulge import annotate` keeps meaning the module. Each name
# is imported when first asked for (PEP 562): a command that needs none of build's modules
# (`bulgekit annotate`: mapbuild, strokes, wall, stats) does not pay for them (docs/host.md).
_LAZY = {**dict.fromkeys(["BuildOutput", "annotate_gcode", "build", "build_map", "bulge_stats",
                          "fallback_gcode", "load_strokes", "walls"], "bulge.api"),
         **dict.fromkeys(["MODE_GEOMETRIC", "MODE_MARKED", "MODE_OFF", "Settings", "StockStops"],
                         "bulge.fallback"),
         **dict.fromkeys(["Stroke", "text_strokes"], "bulge.strokes")}


def __getattr__(name: str):
    where = _LAZY.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    value = globals()[name] = getattr(importlib.import_module("." + where, __name__), name)
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "BuildOutput", "BulgekitError", "InputError", "MODE_GEOMETRIC", "MODE_MARKED", "MODE_OFF",
    "Settings", "StockStops", "Stroke", "annotate_gcode", "build", "build_map", "bulge_stats",
    "fallback_gcode", "load_strokes", "text_strokes", "walls", "__version__",
]
