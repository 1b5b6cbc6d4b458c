"""Pieces shared by the command modules (cli.py, cli_io.py)."""
from __future__ import annotations

import functools
import math
import sys

import click

from .strokes import BulgekitError


def friendly(fn):
    """Turn expected failures into one-line messages (exit status 1): our own
    errors (they name the file and line, stroke or layer), map-format errors,
    and I/O errors."""
    @functools.wraps(fn)
    def wrapper(*a, **kw):
        try:
            return fn(*a, **kw)
        except BulgekitError as e:
            raise click.ClickException(str(e)) from None
        except ValueError as e:  # mapformat.MapFormatError and friends
            if type(e).__module__.startswith("bulgekit"):
                raise click.ClickException(str(e)) from None
            raise
        except BrokenPipeError:
            raise  # output piped into `head`: click ends quietly
        except OSError as e:
            raise click.ClickException(f"{e.filename or ''}: {e.strerror or e}") from None
    return wrapper


def progress_option(fn):
    """--quiet, and progress on stderr for the command's passes over its G-code while it runs
    (only on a terminal: a slicer, a pipe or a log gets none)."""
    @functools.wraps(fn)
    def wrapper(*a, quiet=False, **kw):
        from . import progress
        if not quiet and sys.stderr.isatty():
            progress.enable()
        try:
            return fn(*a, **kw)
        finally:
            progress.disable()
    return click.option("-q", "--quiet", is_flag=True,
                        help="No progress on stderr (it is shown only on a terminal).")(wrapper)


class Num(click.ParamType):
    """A finite float, optionally within lo..hi (lo excluded with lo_open);
    click's FloatRange lets nan through."""
    name = "number"

    def __init__(self, lo: float | None = None, hi: float | None = None, lo_open: bool = False):
        self.lo, self.hi, self.lo_open = lo, hi, lo_open

    def convert(self, value, param, ctx):
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        lo_bad = self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo)
        if lo_bad or (self.hi is not None and v > self.hi):
            lo = "" if self.lo is None else (f"> {self.lo:g}" if self.lo_open else f">= {self.lo:g}")
            hi = "" if self.hi is None else f"<= {self.hi:g}"
            self.fail(f"{value} must be {' and '.join(t for t in (lo, hi) if t)}", param, ctx)
        return v


FINITE = Num()
POSITIVE = Num(0.0, lo_open=True)
NONNEG = Num(0.0)


def pair(ctx, param, value):
    """click callback for a "U,V" option in mm."""
    if value is None:
        return None
    try:
        a, b = (float(t) for t in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected two numbers U,V (mm), got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise click.BadParameter(f"U,V must be finite numbers, got {value!r}")
    return (a, b)
