"""How the hand pipeline runs: :class:`HandOptions`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stillcap.ball.layout import BASEBALL_RADIUS
from stillcap.response import check_response_option

__all__ = ["HandOptions"]


@dataclass
class HandOptions:
    """How :func:`analyse_hand` runs.

    Attributes
    ----------
    strobe_position_m : (3,) or None
        The strobe's position in the rig world (m); default from ``capture.json`` meta
        ``strobe_position_m``. Without it the half-lit marker bias stays in the positions.
    overrides : path or None
        Manual label corrections (``docs/hand-labelling.md``).
    personalise : {None, "best", "joint"}
        Scale the hand model to the person from the markers first.
    frame_rate : float
        Frames per second of the interpolated animation.
    interpolation : {"spline", "slerp"}
    marker_radius_m, ball_radius_m : float
    spin : bool
        Try the free ball's spin (needs two free-flight flashes with markers).
    response : None, "auto", Response or str
        The cameras' response (``docs/camera-response.md``): None each camera's own from the
        rig; a Response (or ``"srgb"``, ``"linear"``, ``"gamma:2.2"``) for every camera;
        ``"auto"`` estimated from the ball's shading.
    hand_model, hand_markers : str, path or None
        The person's hand model (a ``stillcap-skeleton`` file or a built-in name) and glove
        marker set (a ``stillcap-markerset`` file or a built-in name); default
        ``capture.json``'s ``hand_model`` / ``hand_markers`` (paths inside the capture folder),
        else the built-in ones (:mod:`stillcap.body.hand_files`, ``docs/hand.md``).
    adapt_model : bool
        Experimental, off by default: adapt the hand model to the capture before labelling
        (:func:`stillcap.body.hand_adapt.label_and_adapt`; ``docs/hand.md`` has what it gave).
    """

    strobe_position_m: tuple | None = None
    overrides: str | Path | None = None
    personalise: str | None = None
    frame_rate: float = 1000.0
    interpolation: str = "spline"
    marker_radius_m: float = 0.005
    ball_radius_m: float = BASEBALL_RADIUS
    spin: bool = True
    response: object = None
    hand_model: str | Path | None = None
    hand_markers: str | Path | None = None
    adapt_model: bool = False

    def __post_init__(self):
        self.response = check_response_option(self.response)
        if self.interpolation not in ("spline", "slerp"):
            raise ValueError(f"interpolation must be 'spline' or 'slerp', got {self.interpolation!r}")
        if self.personalise not in (None, "best", "joint"):
            raise ValueError(f"personalise must be None, 'best' or 'joint', got {self.personalise!r}")
        if not (np.isfinite(self.frame_rate) and self.frame_rate > 0):
            raise ValueError(f"frame_rate must be a positive number of frames per second, got {self.frame_rate}")
