"""The errors bulgekit reports to its user; every job's errors derive from BulgekitError. Also
the two places where a file's OS errors are put in the user's terms: a picture read
(reading_picture) and an output written all or nothing (output_part).

At the base of the package, so that every floor (gcode, the jobs, cli and studio) may raise
them: `bk.BulgekitError` and `bk.InputError` are the same classes.
"""
from __future__ import annotations

import contextlib
import os


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


@contextlib.contextmanager
def output_part(dst):
    """An output written all or nothing: the body writes dst's part (yielded: dst.part beside it)
    and renames it to dst (os.replace) once the output is whole; a part left behind by an error
    or Ctrl-C is removed. An OSError about the part, or one naming no file (a write's), is said
    of dst, the file the user named."""
    part = f"{os.fspath(dst)}.part"
    try:
        yield part
    except OSError as e:
        if e.filename not in (part, None):
            raise
        raise type(e)(e.errno, e.strerror, os.fspath(dst)) from None
    finally:
        if os.path.exists(part):
            os.unlink(part)
