"""``stillcap hand-calibrate``: the person's hand model from a calibration capture (a hand
capture of the gloved hand held in a stated pose, then curling: ``stillcap.body.hand_calibrate``).

The stages are the hand pipeline's (glove markers, 3D markers; no ball), then
:func:`~stillcap.body.hand_calibrate.calibrate_hand_from_points`.
"""

from __future__ import annotations

from pathlib import Path

from stillcap._checks import as_array
from stillcap.body.hand_calibrate import HandCalibration, calibrate_hand_from_points
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.pipelines.hand.options import HandOptions
from stillcap.pipelines.hand.stages import find_glove_markers, triangulate_glove_markers

__all__ = ["calibrate_hand_capture"]


def calibrate_hand_capture(capture: Capture | str | Path, pose: str = "flat", *, skeleton=None,
                           markerset=None, strobe_position_m=None) -> HandCalibration:
    """Calibrate the hand model from a calibration capture (``kind: hand``).

    Raises
    ------
    ValueError
        Not a hand capture, no glove marker in 3D, no flash with a hand pose, or the flash
        nearest the stated pose does not fit it (the capture is not in the pose).
    """
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    where = f"capture {cap.root}" if cap.root is not None else "capture"
    if cap.kind != "hand":
        raise ValueError(f"{where} is a {cap.kind!r} capture, not a hand capture (capture.json \"kind\")")
    specs, messages = stereo_pairs(cap)
    rates = {sp.strobe_hz for sp in specs}
    if len(rates) != 1:
        raise ValueError(f"{where}: the stereo pairs have different strobe rates {sorted(rates)} Hz")
    strobe_hz = rates.pop()
    pairs = {sp.name: sp.cameras for sp in specs}
    light = strobe_position_m if strobe_position_m is not None else cap.meta.get("strobe_position_m")
    if light is not None:
        light = as_array(light, (3,), "strobe_position_m")
    rig = cap.rig
    used = [c for sp in specs for c in sp.cameras]
    images = []
    for name in rig.names:
        ims = cap.images_of(name)
        images.append(cap.read_image(ims[0]) if (name in used and ims) else None)
    blobs = find_glove_markers(images, None)
    points = triangulate_glove_markers(rig, pairs, blobs, light, HandOptions(), messages, where)
    try:
        cal = calibrate_hand_from_points(points.points, points.colors, strobe_hz=strobe_hz, pose=pose,
                                         skeleton=skeleton, markerset=markerset,
                                         reprojection_px=points.reprojection_px)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    cal.messages = messages + cal.messages
    return cal
