"""``stillcap hand-calibrate``: the person's hand model from a calibration capture (a hand
capture of the gloved hand held in a stated pose, then moving through the protocol's steps: ``stillcap.body.hand_calibrate``,
docs/hand-calibration.md).

The stages are the hand pipeline's (glove markers, 3D markers; no ball), then
:func:`~stillcap.body.hand_calibrate.calibrate_hand_from_points`.
"""

from __future__ import annotations

from pathlib import Path

from stillcap.body.hand_calibrate import HandCalibration, calibrate_hand_from_points
from stillcap.io.capture import Capture
from stillcap.pipelines.hand.options import HandOptions
from stillcap.pipelines.hand.stages import (find_glove_markers, hand_setup, read_hand_photos,
                                            triangulate_glove_markers)

__all__ = ["calibrate_hand_capture"]


def calibrate_hand_capture(capture: Capture | str | Path, pose: str = "flat", *, skeleton=None,
                           markerset=None, strobe_position_m=None, max_length_sigma_m=None) -> HandCalibration:
    """Calibrate the hand model from a calibration capture (``kind: hand``).

    Raises
    ------
    ValueError
        Not a hand capture, no glove marker in 3D, no flash with a hand pose, or the flash
        nearest the stated pose does not fit it (the capture is not in the pose).
    """
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    setup = hand_setup(cap, strobe_position_m)
    where, messages = setup.where, setup.messages
    images = read_hand_photos(cap, setup.pairs)
    blobs = find_glove_markers(images, None, cap.rig)  # in linear light through each camera's response
    points = triangulate_glove_markers(cap.rig, setup.pairs, blobs, setup.light, HandOptions(), messages, where)
    try:
        cal = calibrate_hand_from_points(points.points, points.colors, strobe_hz=setup.strobe_hz, pose=pose,
                                         skeleton=skeleton, markerset=markerset,
                                         reprojection_px=points.reprojection_px,
                                         max_length_sigma_m=max_length_sigma_m)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    cal.messages = messages + cal.messages
    return cal
