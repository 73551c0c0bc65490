"""Calibration (SPEC J4): targets, detection, intrinsics, extrinsics, bundle adjustment, a camera
from board photos at surveyed poses (:mod:`.surveyed`).

Detection (:mod:`.detect`) turns photos into 2D-3D correspondences; the solvers work on those
correspondences only, so they can be tested and used without images. See
``docs/calibration.md``.
"""

from stillcap.calibrate.bundle import BundleResult, Observation, bundle_adjust
from stillcap.calibrate.detect import Detection, detect_target, detect_targets, read_gray
from stillcap.calibrate.extrinsics import (PoseResult, RigResult, StereoResult, calibrate_rig,
                                           calibrate_rig_from_points, calibrate_stereo,
                                           calibrate_stereo_from_detections, split_stereo_images, initial_rig_poses,
                                           pair_stereo_images, pose_from_board, pose_from_detection,
                                           pose_from_object, pose_from_points, rig_images_from_folder)
from stillcap.calibrate.intrinsics import (IntrinsicsResult, calibrate_from_detections, calibrate_intrinsics,
                                           calibrate_intrinsics_from_points, reprojection_rms)
from stillcap.calibrate.surveyed import CameraCalibration, calibrate_camera_from_surveyed_boards
from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard, parse_pattern

__all__ = [
    "BundleResult", "CalibrationObject", "CameraCalibration", "CharucoTarget", "Chessboard", "Detection",
    "IntrinsicsResult", "Observation", "PoseResult", "RigResult", "StereoResult", "bundle_adjust",
    "calibrate_camera_from_surveyed_boards", "calibrate_from_detections",
    "calibrate_intrinsics", "calibrate_intrinsics_from_points", "calibrate_rig", "calibrate_rig_from_points",
    "calibrate_stereo", "calibrate_stereo_from_detections", "split_stereo_images", "detect_target", "detect_targets", "initial_rig_poses", "pair_stereo_images",
    "parse_pattern", "pose_from_board", "pose_from_detection", "pose_from_object", "pose_from_points",
    "read_gray", "reprojection_rms", "rig_images_from_folder",
]
