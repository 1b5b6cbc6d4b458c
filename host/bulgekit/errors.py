"""The errors bulgekit reports to its user; every job's errors derive from BulgekitError. Also
where a picture's OS errors are put in the user's terms (reading_picture; an output's are in
bulgekit.outputs, which writes every output all or nothing).

At the base of the package, so that every floor (gcode, the jobs, cli and studio) may raise
them: `bk.BulgekitError` and `bk.InputError` are the same classes.
"""
from __future__ import annotations

import contextlib


class BulgekitError(Exception):
    """Base class for errors reported to the user (message is user-facing)."""


class InputError(BulgekitError):
    """A stroke input (SVG, JSON, image, text, mesh) could not be used."""


class MissingInputError(InputError):
    """An input file that is not there, named inside another file (a placement file's
    strokes[0].file): a usage error, exit status 2, as click's own for a file named on the
    command line."""


@contextlib.contextmanager
def reading_picture(path: str):
    """Pillow's errors while a picture file is opened and read, as one InputError naming it."""
    from PIL import UnidentifiedImageError

    try:
        yield
    except FileNotFoundError:
        raise InputError(f"{path}: image file not found") from None
    except UnidentifiedImageError:
        raise InputError(f"{path}: cannot read image (not a format Pillow recognizes)") from None
    except (OSError, ValueError, SyntaxError) as e:
        raise InputError(f"{path}: cannot read image: {e}") from None
