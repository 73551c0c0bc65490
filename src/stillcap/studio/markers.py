"""Marker sets painted on studio balls.

:func:`baseball_markers` is the seed's 12-marker ball (SPEC J1, section 4.1): 8 markers on the
equator in pairs 30 degrees apart, pairs 60 degrees apart (azimuths 0, 30, 90, 120, 180, 210, 270,
300 degrees), and 4 on the orthogonal great circle through azimuths 60 and 240 degrees, 30 degrees
from each pole. Ball frame: z = the equator's pole. Four types, three markers each:

=========  ========  =======================================================
type       shape     markers (azimuth / polar angle, degrees)
=========  ========  =======================================================
red        square    eq 0, eq 120, eq 270
blue       ring      eq 30, (60, 150), (240, 30)
green      triangle  eq 90, eq 210, eq 300
black      disc      eq 180, (60, 30), (240, 150)
=========  ========  =======================================================

The assignment was chosen by exhaustive search over all 15400 ways to split the 12 positions
into 4 unlabelled groups of 3: it is the one that keeps all 4 types on the visible hemisphere
from every viewing direction and, among those, shows the most types within 80 and 70 degrees of
the view direction (never fewer than 2).
"""

from __future__ import annotations

import numpy as np

from stillcap.studio.scene import SphereMarker

#: Linear RGB albedos of the four marker types (configurable: pass ``palette=``).
BASEBALL_PALETTE = {
    "red": (0.80, 0.04, 0.03),
    "blue": (0.03, 0.10, 0.80),
    "green": (0.05, 0.60, 0.06),
    "black": (0.02, 0.02, 0.02),
}
BASEBALL_SHAPES = {"red": "square", "blue": "ring", "green": "triangle", "black": "disc"}

# (azimuth deg, polar deg, type)
_LAYOUT = [
    (0, 90, "red"), (30, 90, "blue"), (90, 90, "green"), (120, 90, "red"),
    (180, 90, "black"), (210, 90, "green"), (270, 90, "red"), (300, 90, "green"),
    (60, 30, "black"), (60, 150, "blue"), (240, 30, "blue"), (240, 150, "black"),
]


def sphere_direction(azimuth_deg: float, polar_deg: float) -> np.ndarray:
    """Unit vector at ``azimuth`` (from x towards y) and ``polar`` angle (from +z), degrees."""
    a, p = np.radians(azimuth_deg), np.radians(polar_deg)
    return np.array([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)])


def baseball_markers(size: float = 0.16, palette: dict | None = None) -> tuple[SphereMarker, ...]:
    """The 12 markers of the seed's ball.

    Parameters
    ----------
    size : float
        Angular size in radians (disc radius, square half-side, ...); 0.16 rad is a 12 mm
        marker on a 73.7 mm baseball.
    palette : dict, optional
        Colour (linear RGB) per type name ``red, blue, green, black``.

    Returns
    -------
    tuple of SphereMarker
        Named ``"<type>.<k>"`` (e.g. ``"red.0"``), in the order of the table above.
    """
    pal = {**BASEBALL_PALETTE, **(palette or {})}
    count: dict[str, int] = {}
    out = []
    for az, pol, kind in _LAYOUT:
        k = count.get(kind, 0)
        count[kind] = k + 1
        out.append(SphereMarker(sphere_direction(az, pol), BASEBALL_SHAPES[kind], size, 0.0, pal[kind],
                                name=f"{kind}.{k}"))
    return tuple(out)
