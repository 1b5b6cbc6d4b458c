"""Stroke inputs for bulge drawings.

A stroke is a polyline on the unrolled outer wall: u runs along the wall
(mm, measured from the seam reference), v is the height above the bed (mm).
A single-point stroke is a dot.  Loaders for SVG, text, JSON and images
follow; every error names the file and the element or line at fault.
"""
from __future__ import annotations

from dataclasses import dataclass, field


class BulgekitError(Exception):
    """Base class for errors reported to the user (message is user-facing)."""


class InputError(BulgekitError):
    """A stroke input (SVG, JSON, image, text) could not be used."""


@dataclass(frozen=True)
class Stroke:
    points: tuple[tuple[float, float], ...]
    weight: int = 255
    source: str = ""

    @property
    def is_dot(self) -> bool:
        return len(self.points) == 1
