"""``stillcap hand-calibrate``: the person's hand model from a calibration capture (a hand
capture of the gloved hand held in a stated pose, then moving through the protocol's steps: ``stillcap.body.hand_calibrate``,
docs/hand-calibration.md).

The stages are the hand pipeline's (glove markers, 3D markers; no ball), then
:func:`~stillcap.body.hand_calibrate.calibrate_hand_from_points`.
"""

from __future__ import annotations

from pathlib import Path

from stillcap.body.hand_calibrate import NOISE_M, CalibrationPoints, HandCalibration, calibrate_hand_from_point_sets
from stillcap.io.capture import Capture
from stillcap.pipelines.hand.options import HandOptions
from stillcap.pipelines.hand.stages import (_unconfirmed, find_glove_markers, hand_setup, marker_sigma,
                                            read_hand_photos, triangulate_glove_markers)

__all__ = ["MARKER_NOISES", "MARKER_NOISE", "calibrate_hand_capture", "calibration_points", "calibration_weights"]

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


def calibration_points(capture: Capture | str | Path, *, strobe_position_m=None,
                       marker_noise: str = MARKER_NOISE) -> tuple[CalibrationPoints, str, list]:
    """Stages 1-3 of ``hand-calibrate`` on one capture: its unlabelled 3D glove markers (with
    each one's noise when ``marker_noise`` is ``"own"``), where the capture is (for messages) and
    the stages' messages."""
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    setup = hand_setup(cap, strobe_position_m)
    where, messages = setup.where, setup.messages
    images = read_hand_photos(cap, setup.pairs)
    blobs = find_glove_markers(images, None, cap.rig)  # in linear light through each camera's response
    points = triangulate_glove_markers(cap.rig, setup.pairs, blobs, setup.light, HandOptions(), messages, where)
    weights = calibration_weights(points) if marker_noise == "own" else {}
    return (CalibrationPoints(points.points, points.colors, setup.strobe_hz, points.reprojection_px,
                              weights.get("point_sigma_m"), weights.get("unconfirmed")), where, messages)


def calibrate_hand_capture(capture, pose: str = "flat", *, skeleton=None,
                           markerset=None, strobe_position_m=None, max_length_sigma_m=None,
                           marker_noise: str = MARKER_NOISE) -> HandCalibration:
    """Calibrate the hand model from a calibration capture (``kind: hand``), or from several
    captures of the same hand and glove (a list: their flashes are fitted together,
    :func:`~stillcap.body.hand_calibrate.calibrate_hand_from_point_sets`).

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
    captures = list(capture) if isinstance(capture, (list, tuple)) else [capture]
    if not captures:
        raise ValueError("no calibration capture given")
    sets, wheres, messages = [], [], []
    for c in captures:
        s, where, msgs = calibration_points(c, strobe_position_m=strobe_position_m, marker_noise=marker_noise)
        sets.append(s)
        wheres.append(where)
        messages += msgs
    try:
        cal = calibrate_hand_from_point_sets(sets, pose=pose, skeleton=skeleton, markerset=markerset,
                                             max_length_sigma_m=max_length_sigma_m)
    except ValueError as e:
        raise ValueError(f"{', '.join(wheres)}: {e}") from None
    cal.messages = messages + cal.messages
    return cal
