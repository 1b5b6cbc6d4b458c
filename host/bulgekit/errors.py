"""The errors bulgekit reports to its user; every job's errors derive from BulgekitError.

At the base of the package, so that every floor (gcode, the jobs, cli and studio) may raise
them: `bk.BulgekitError` and `bk.InputError` are the same classes.
"""
from __future__ import annotations


class BulgekitError(Exception):
    """Base class for errors reported to the user (message is user-facing)."""


class InputError(BulgekitError):
    """A stroke input (SVG, JSON, image, text, mesh) could not be used."""
