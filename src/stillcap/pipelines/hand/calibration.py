"""``stillcap hand-calibrate``: the person's hand model from a calibration capture (a hand
capture of the gloved hand held in a stated pose, then moving through the protocol's steps: ``stillcap.body.hand_calibrate``,
docs/hand-calibration.md).

The stages are the hand pipeline's (glove markers, 3D markers; no ball), then
:func:`~stillcap.body.hand_calibrate.calibrate_hand_from_points`.
"""

from __future__ import annotations

from pathlib import Path

from stillcap.body.hand_calibrate import NOISE_M, HandCalibration, calibrate_hand_from_points
from stillcap.io.capture import Capture
from stillcap.pipelines.hand.options import HandOptions
from stillcap.pipelines.hand.stages import (_unconfirmed, find_glove_markers, hand_setup, marker_sigma,
                                            read_hand_photos, triangulate_glove_markers)

__all__ = ["MARKER_NOISES", "MARKER_NOISE", "calibrate_hand_capture", "calibration_weights"]

#: How the calibration weighs its 3D markers (:func:`calibrate_hand_capture`'s ``marker_noise``).
MARKER_NOISES = ("own", "common")
#: The default (benchmarks/bench_hand_cal_weighting.py, docs/hand-calibration.md).
MARKER_NOISE = "own"


def calibration_weights(points) -> dict:
    """The keyword arguments of :func:`~stillcap.body.hand_calibrate.calibrate_hand_from_points`
    that weigh each 3D marker by its own noise, as the throw's pose fit does: ``point_sigma_m``
    (fully seen markers at :data:`~stillcap.body.hand_calibrate.NOISE_M`, partly hidden ones at
    :func:`~stillcap.pipelines.hand.stages.marker_sigma`'s larger noise, from the share of their
    light the photos show) and ``unconfirmed`` (partly hidden points of two views, as the
    throw's labelling takes them)."""
    return {"point_sigma_m": marker_sigma(points, seen_m=NOISE_M), "unconfirmed": _unconfirmed(points)}


def calibrate_hand_capture(capture: Capture | str | Path, pose: str = "flat", *, skeleton=None,
                           markerset=None, strobe_position_m=None, max_length_sigma_m=None,
                           marker_noise: str = MARKER_NOISE) -> HandCalibration:
    """Calibrate the hand model from a calibration capture (``kind: hand``).

    ``marker_noise``: ``"own"`` weighs each 3D marker by its own noise from the photos
    (:func:`calibration_weights`: a partly hidden marker less), ``"common"`` every marker at
    :data:`~stillcap.body.hand_calibrate.NOISE_M` (before 26 November).

    Raises
    ------
    ValueError
        Not a hand capture, no glove marker in 3D, no flash with a hand pose, or the flash
        nearest the stated pose does not fit it (the capture is not in the pose).
    """
    if marker_noise not in MARKER_NOISES:
        raise ValueError(f"marker noise {marker_noise!r} is not one of {', '.join(MARKER_NOISES)}")
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    setup = hand_setup(cap, strobe_position_m)
    where, messages = setup.where, setup.messages
    images = read_hand_photos(cap, setup.pairs)
    blobs = find_glove_markers(images, None, cap.rig)  # in linear light through each camera's response
    points = triangulate_glove_markers(cap.rig, setup.pairs, blobs, setup.light, HandOptions(), messages, where)
    weights = calibration_weights(points) if marker_noise == "own" else {}
    try:
        cal = calibrate_hand_from_points(points.points, points.colors, strobe_hz=setup.strobe_hz, pose=pose,
                                         skeleton=skeleton, markerset=markerset,
                                         reprojection_px=points.reprojection_px,
                                         max_length_sigma_m=max_length_sigma_m, **weights)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    cal.messages = messages + cal.messages
    return cal
