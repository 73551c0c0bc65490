"""The marker palette's types and the per-marker quality flags of :mod:`stillcap.detect.ball_markers`
(which re-exports them): :class:`MarkerType`, :data:`BASEBALL_MARKER_TYPES`, :data:`SHAPES`,
:class:`MarkerFlag`."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

__all__ = ["MarkerType", "MarkerFlag", "BASEBALL_MARKER_TYPES", "SHAPES"]

SHAPES = ("disc", "ring", "square", "triangle")


@dataclass(frozen=True)
class MarkerType:
    """One marker type of the palette.

    Parameters
    ----------
    name : str
    color_bgr : tuple of 3 floats
        Colour of the paint as it looks fully lit in the photo, BGR 0-255.
    shape : {"disc", "ring", "square", "triangle"}
    spread_rad2 : float, optional
        Mean squared angle of the paint from the marker's centre on the ball, rad^2 (from its
        shape and size: ``BallLayout.centroid_depth``): it tells types of one colour apart where
        a marker image is too small for its shape. None: unknown.
    """

    name: str
    color_bgr: tuple
    shape: str
    spread_rad2: float | None = None

    def __post_init__(self):
        c = np.asarray(self.color_bgr, float)
        if c.shape != (3,):
            raise ValueError(f"marker type {self.name!r}: color_bgr must have shape (3,), got {c.shape}")
        if self.shape not in SHAPES:
            raise ValueError(f"marker type {self.name!r}: shape must be one of {SHAPES}, got {self.shape!r}")
        object.__setattr__(self, "color_bgr", tuple(float(v) for v in c))
        if self.spread_rad2 is not None and not (np.isfinite(self.spread_rad2) and 0 < self.spread_rad2 < 1):
            raise ValueError(f"marker type {self.name!r}: spread_rad2 must be in (0, 1) rad^2, got {self.spread_rad2}")


#: The seed's four types. Colours are the studio's baseball paint albedos (linear RGB red
#: 0.80/0.04/0.03, blue 0.03/0.10/0.80, green 0.05/0.60/0.06, black 0.02) through a 2.2 gamma.
BASEBALL_MARKER_TYPES = (
    MarkerType("red", (52, 59, 231), "square"),
    MarkerType("blue", (231, 89, 52), "ring"),
    MarkerType("green", (71, 202, 65), "triangle"),
    MarkerType("black", (43, 43, 43), "disc"),
)


class MarkerFlag(enum.IntFlag):
    """Per-marker quality flags (bit set)."""

    NONE = 0
    #: centroid further than ``limb_fraction`` x radius from the ball centre (seen obliquely)
    NEAR_LIMB = 1
    #: the region is a thin ellipse (minor/major axis below ``min_aspect``): shape unreliable
    FORESHORTENED = 2
    #: the measured shape is not the type's shape
    SHAPE_MISMATCH = 4
    #: too small to measure a shape (``shape`` is "unknown")
    SMALL = 8
    #: the region touches the edge of the ball disc searched (possibly cut)
    AT_EDGE = 16
