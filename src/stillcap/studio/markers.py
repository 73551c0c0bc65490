"""Marker sets painted on studio balls.

:func:`baseball_markers` paints the seed's 12-marker ball. Its layout (positions, types, shapes
and default colours) is defined once, in :class:`stillcap.ball.layout.BallLayout`, which the
pipelines fit orientations to; the studio only turns it into :class:`SphereMarker` s.
"""

from __future__ import annotations

from stillcap.ball.layout import BallLayout
from stillcap.studio.scene import SphereMarker


def baseball_markers(size: float = 0.16, palette: dict | None = None) -> tuple[SphereMarker, ...]:
    """The 12 markers of the seed's ball (:meth:`BallLayout.seed`).

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
        Named ``"<type>.<k>"`` (e.g. ``"red.0"``), in the layout's order.
    """
    lay = BallLayout.seed(palette=palette, marker_size=size)
    return tuple(SphereMarker(d, s, lay.marker_size, 0.0, c, name=n)
                 for d, s, c, n in zip(lay.directions, lay.shapes, lay.colors, lay.names))
