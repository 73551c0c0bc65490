"""One camera calibrated in the field from board photos: its intrinsics from all of them, its pose
in the world frame from the boards that stood at surveyed poses.

Close-up photos of a board (any pose) and photos of a large board placed at surveyed spots (its
``board2world`` measured, e.g. from home plate) are detected first
(:func:`stillcap.calibrate.detect.detect_target`); :func:`calibrate_camera_from_surveyed_boards`
turns those detections into a calibrated camera. The studio's pitch rig
(:func:`stillcap.studio.pitch.calibrate_pitch_rig`) renders such photos and calls it per camera.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stillcap.calibrate.detect import Detection
from stillcap.calibrate.extrinsics import pose_from_points
from stillcap.calibrate.intrinsics import calibrate_intrinsics_from_points
from stillcap.camera import Camera

__all__ = ["CameraCalibration", "calibrate_camera_from_surveyed_boards"]


@dataclass
class CameraCalibration:
    """How one camera was calibrated from board photos (:func:`calibrate_camera_from_surveyed_boards`).

    Attributes
    ----------
    name : str
    intrinsics_rms_px : float
        ``cv2.calibrateCamera`` RMS over the board photos used.
    views_used : int
        Board photos used for the intrinsics (close-ups and field-board spots).
    views_skipped : dict[str, str]
        Photos whose board was not found, with the reason.
    extrinsics_rms_px : float
        PnP reprojection RMS over all corners of the large board at its surveyed spots.
    n_points : int
        Corners used for the pose.
    spots_used : list of int
        Which board spots this camera saw (indices into the pair's spots).
    """

    name: str
    intrinsics_rms_px: float
    views_used: int
    views_skipped: dict
    extrinsics_rms_px: float
    n_points: int
    spots_used: list

    def to_dict(self) -> dict:
        return {"intrinsics_rms_px": self.intrinsics_rms_px, "views_used": self.views_used,
                "views_skipped": dict(self.views_skipped), "extrinsics_rms_px": self.extrinsics_rms_px,
                "n_points": self.n_points, "spots_used": list(self.spots_used)}


def calibrate_camera_from_surveyed_boards(name: str, image_size, close_ups: Sequence[Detection],
                                          surveyed: Sequence[tuple[int, np.ndarray, Detection]]
                                          ) -> tuple[Camera, CameraCalibration]:
    """Calibrate one camera from its board detections, as a user would in the field.

    1. Intrinsics: ``cv2.calibrateCamera``
       (:func:`~stillcap.calibrate.intrinsics.calibrate_intrinsics_from_points`) on the corners
       of all of the camera's board photos (the field-board photos reach the image corners the
       close-ups do not), with ``k3`` fixed at 0 as OpenCV advises for ordinary lenses.
    2. Extrinsics: PnP (:func:`~stillcap.calibrate.extrinsics.pose_from_points`, SQPnP + LM) on
       the field-board corners of all spots at once, in world coordinates (several board
       planes: not coplanar).

    Parameters
    ----------
    name : str
        The camera's name.
    image_size : (width, height)
    close_ups : sequence of Detection
        The close-up board photos (board pose unknown).
    surveyed : sequence of (int, ndarray shape (4, 4), Detection)
        The large board's photos: spot index, the board's surveyed ``board2world``, detection.

    Returns
    -------
    (Camera, CameraCalibration)
        The calibrated camera (world frame) and how it was calibrated.

    Raises
    ------
    ValueError
        The boards were found in fewer than 3 photos, the field board at no spot, or PnP failed.
    """
    import cv2

    views, field_views = close_ups, surveyed
    good = [d for d in views if d.success] + [d for _, _, d in field_views if d.success]
    skipped = {d.name: d.reason for d in list(views) + [d for _, _, d in field_views] if not d.success}
    if len(good) < 3:
        raise ValueError(f"camera {name!r}: the boards were found in only {len(good)} photos "
                         f"(need 3); skipped: {skipped}")
    intr = calibrate_intrinsics_from_points([d.object_points for d in good], [d.image_points for d in good],
                                            image_size, [d.name for d in good], name,
                                            flags=cv2.CALIB_FIX_K3)
    used = [(k, T, d) for k, T, d in field_views if d.success]
    if not used:
        raise ValueError(f"camera {name!r}: the field board was not found at any surveyed spot")
    obj = np.concatenate([d.object_points @ T[:3, :3].T + T[:3, 3] for _, T, d in used])
    pose = pose_from_points(intr.camera, obj, np.concatenate([d.image_points for _, _, d in used]))
    if not pose.success:
        raise ValueError(f"camera {name!r}: no pose from the field board (PnP failed)")
    return pose.camera, CameraCalibration(name, intr.rms_px, len(good), skipped, pose.rms_px, pose.n_points,
                                          [k for k, _, _ in used])
