"""Camera intrinsics (K and distortion) from views of a calibration target.

:func:`calibrate_intrinsics` detects the target in photos and calls
:func:`calibrate_intrinsics_from_points`, which runs ``cv2.calibrateCamera`` (default flags, as
OpenCV's reference calibration) on 2D-3D correspondences. Both return an
:class:`IntrinsicsResult`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from stillcap._checks import as_array
from stillcap.calibrate.detect import Detection, Progress, detect_targets
from stillcap.calibrate.outliers import outlier_views
from stillcap.camera import Camera, pose_matrix


@dataclass
class IntrinsicsResult:
    """Intrinsic calibration of one camera.

    Attributes
    ----------
    camera : Camera
        K, distortion ``(k1, k2, p1, p2, k3)`` and image size; ``world2cam`` is the identity.
    rms_px : float
        Reprojection RMS over all points of all views used (OpenCV's definition).
    per_image_rms_px : dict[str, float]
        Reprojection RMS per view, keyed by image name.
    images_used : list[str]
    images_skipped : dict[str, str]
        Image name -> why it was not used.
    board2cam : dict[str, ndarray, shape (4, 4)]
        Pose of the target in each view used (target frame -> camera frame).
    success : bool
        OpenCV converged to finite values.
    outlier_views : list[str]
        Views whose RMS stands far above the others (:mod:`stillcap.calibrate.outliers`).
    without_outliers : IntrinsicsResult or None
        The calibration again without the outlier views (None when there are none, or too few
        views would remain).
    """

    camera: Camera
    rms_px: float
    per_image_rms_px: dict[str, float]
    images_used: list[str]
    images_skipped: dict[str, str] = field(default_factory=dict)
    board2cam: dict[str, np.ndarray] = field(default_factory=dict)
    success: bool = True
    outlier_views: list[str] = field(default_factory=list)
    without_outliers: IntrinsicsResult | None = None

    def summary(self) -> dict:
        """JSON-ready summary (pixels; ``dist`` = k1, k2, p1, p2, k3); ``without_outliers`` holds
        ``rms_px``, the intrinsics and ``images_used`` of the calibration without the outlier
        views, or None."""
        K = self.camera.K
        w = self.without_outliers
        return {"rms_px": self.rms_px, "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
                "dist": self.camera.dist.tolist(), "image_size": list(self.camera.image_size),
                "images_used": list(self.images_used), "images_skipped": dict(self.images_skipped),
                "per_image_rms_px": dict(self.per_image_rms_px), "outlier_views": list(self.outlier_views),
                "without_outliers": None if w is None else
                {k: v for k, v in w.summary().items() if k in ("rms_px", "fx", "fy", "cx", "cy", "dist",
                                                               "images_used")}}


def reprojection_rms(camera: Camera, object_points, image_points, obj2cam) -> float:
    """RMS pixel distance between ``image_points (N, 2)`` and ``object_points (N, 3)`` projected
    through ``camera`` placed at ``obj2cam (4, 4)``."""
    px = camera.with_pose(obj2cam).project(as_array(object_points, (None, 3), "object_points"))
    d = px - as_array(image_points, (None, 2), "image_points")
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def _is_planar(p: np.ndarray) -> bool:
    c = p - p.mean(axis=0)
    s = np.linalg.svd(c, compute_uv=False)
    return s[-1] <= 1e-9 * max(s[0], 1e-12)


def calibrate_intrinsics_from_points(object_points_list, image_points_list, image_size,
                                     names: Sequence[str] | None = None, camera_name: str = "cam0",
                                     flags: int = 0, K_guess=None, min_views: int = 3,
                                     check_outliers: bool = True) -> IntrinsicsResult:
    """Intrinsics from 2D-3D correspondences of several views (``cv2.calibrateCamera``).

    Parameters
    ----------
    object_points_list : sequence of array_like, shape (N_i, 3)
        Target points per view, in the target frame (metres).
    image_points_list : sequence of array_like, shape (N_i, 2)
        Their pixels.
    image_size : (width, height) in pixels.
    names : view names (default ``"#0", "#1", ...``).
    camera_name : name of the returned camera.
    flags : ``cv2.CALIB_*`` flags (default 0 = OpenCV's default model).
    K_guess : array_like, shape (3, 3), optional
        Starting K (adds ``CALIB_USE_INTRINSIC_GUESS``). Needed by OpenCV for non-planar
        targets; without it, one is made from the image size (focal = image width).
    min_views : fewest views accepted.
    check_outliers : flag outlier views and calibrate again without them
        (``outlier_views``, ``without_outliers``).

    Returns
    -------
    IntrinsicsResult
    """
    n = len(object_points_list)
    if len(image_points_list) != n:
        raise ValueError(f"got {n} object-point views but {len(image_points_list)} image-point views")
    names = [f"#{i}" for i in range(n)] if names is None else list(names)
    if len(names) != n:
        raise ValueError(f"got {len(names)} names for {n} views")
    if n < min_views:
        raise ValueError(f"camera {camera_name!r}: intrinsic calibration needs at least {min_views} views, got {n}"
                         + (f" ({', '.join(names)})" if names else ""))
    w, h = (int(v) for v in image_size)
    flags_given = flags
    obj, img = [], []
    for nm, o, p in zip(names, object_points_list, image_points_list):
        o = as_array(o, (None, 3), f"object points of {nm}")
        p = as_array(p, (len(o), 2), f"image points of {nm} (object points are {o.shape})")
        if len(o) < 4:
            raise ValueError(f"view {nm} has {len(o)} points; at least 4 are needed")
        obj.append(o.astype(np.float32))
        img.append(p.astype(np.float32).reshape(-1, 1, 2))
    K0 = None
    if K_guess is not None:
        K0 = as_array(K_guess, (3, 3), "K_guess").copy()
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    elif not all(_is_planar(o) for o in obj):
        K0 = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1]], float)
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), K0, None, flags=flags)
    camera = Camera(camera_name, K, np.ravel(dist)[:5], np.eye(4), (w, h))
    poses, per = {}, {}
    for nm, o, p, rv, tv in zip(names, obj, img, rvecs, tvecs):
        T = pose_matrix(cv2.Rodrigues(rv)[0], tv)
        poses[nm] = T
        per[nm] = reprojection_rms(camera, o, p.reshape(-1, 2), T)
    ok = bool(np.isfinite(rms) and np.all(np.isfinite(K)) and np.all(np.isfinite(dist)))
    res = IntrinsicsResult(camera, float(rms), per, names, {}, poses, ok)
    if check_outliers:
        res.outlier_views = outlier_views(per)
        keep = [i for i, nm in enumerate(names) if nm not in res.outlier_views]
        if res.outlier_views and len(keep) >= min_views:
            res.without_outliers = calibrate_intrinsics_from_points(
                [obj[i].reshape(-1, 3) for i in keep], [img[i].reshape(-1, 2) for i in keep], (w, h),
                [names[i] for i in keep], camera_name, flags_given, K_guess, min_views, check_outliers=False)
    return res


def calibrate_from_detections(detections: Sequence[Detection], camera_name: str = "cam0",
                              flags: int = 0, K_guess=None, min_views: int = 3) -> IntrinsicsResult:
    """Intrinsics from :class:`Detection` s; failed detections are listed as skipped.

    Raises
    ------
    ValueError
        No detections, images of different sizes, or too few views with the target found
        (the message names the images and why each was skipped).
    """
    detections = list(detections)
    if not detections:
        raise ValueError(f"no images given for camera {camera_name!r}")
    sizes = {d.image_size for d in detections}
    if len(sizes) > 1:
        first = detections[0]
        odd = next(d for d in detections if d.image_size != first.image_size)
        raise ValueError(f"camera {camera_name!r}: images differ in size: {first.name} is "
                         f"{first.image_size[0]}x{first.image_size[1]} px, {odd.name} is "
                         f"{odd.image_size[0]}x{odd.image_size[1]} px")
    good = [d for d in detections if d.success]
    skipped = {d.name: d.reason for d in detections if not d.success}
    if not good:
        raise ValueError(f"camera {camera_name!r}: target not found in any of the {len(detections)} images: "
                         + "; ".join(f"{k} ({v})" for k, v in skipped.items()))
    if len(good) < min_views:
        raise ValueError(f"camera {camera_name!r}: target found in only {len(good)} image{'s' * (len(good) != 1)} "
                         f"({', '.join(d.name for d in good)}), need {min_views}"
                         + ("; skipped: " + "; ".join(f"{k} ({v})" for k, v in skipped.items()) if skipped else ""))
    res = calibrate_intrinsics_from_points([d.object_points for d in good], [d.image_points for d in good],
                                           detections[0].image_size, [d.name for d in good], camera_name,
                                           flags, K_guess, min_views)
    res.images_skipped = skipped
    return res


def calibrate_intrinsics(images: Sequence, target, names: Sequence[str] | None = None,
                         camera_name: str = "cam0", flags: int = 0, K_guess=None, min_views: int = 3,
                         progress: Progress | None = None) -> IntrinsicsResult:
    """Intrinsics of one camera from photos of a calibration target.

    Parameters
    ----------
    images : sequence of paths or ndarrays (grey or BGR), all of one size
    target : Chessboard, CharucoTarget or CalibrationObject
    names : image names (default: file names, ``"#i"`` for arrays).
    camera_name, flags, K_guess, min_views : see :func:`calibrate_intrinsics_from_points`.
    progress : ``progress(done, total, name)`` after each image is searched.

    Returns
    -------
    IntrinsicsResult
        Images where the target is not found are in ``images_skipped`` with the reason.

    Raises
    ------
    ValueError
        Empty list, unreadable image (named), images of different sizes, or fewer than
        ``min_views`` images with the target found (all images named with reasons).
    """
    images = list(images)
    if not images:
        raise ValueError(f"no images given for camera {camera_name!r}")
    dets = detect_targets(images, target, names, progress)
    return calibrate_from_detections(dets, camera_name, flags, K_guess, min_views)
