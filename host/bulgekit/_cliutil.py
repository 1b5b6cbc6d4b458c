"""Pieces shared by the command modules (cli.py, cli_io.py)."""
from __future__ import annotations

import functools

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
        except OSError as e:
            raise click.ClickException(f"{e.filename or ''}: {e.strerror or e}") from None
    return wrapper


def pair(ctx, param, value):
    """click callback for a "U,V" option in mm."""
    if value is None:
        return None
    try:
        a, b = (float(t) for t in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected two numbers U,V (mm), got {value!r}") from None
    return (a, b)
