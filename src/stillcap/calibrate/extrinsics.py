"""Camera poses: one camera from known points (PnP), stereo pairs, and N-camera rigs.

- :func:`pose_from_points`, :func:`pose_from_board`, :func:`pose_from_object`: a calibrated
  camera's pose from 2D-3D correspondences (``cv2.solvePnP`` SQPnP, refined by
  ``cv2.solvePnPRefineLM``).
- :func:`calibrate_stereo`: two cameras from shared board views (``cv2.stereoCalibrate``,
  intrinsics fixed by default). The left camera is the world frame.
- :func:`calibrate_rig`: N cameras from board views at shared instants: intrinsics per camera,
  initial poses along a spanning tree of cameras sharing views, then bundle adjustment
  (:mod:`stillcap.calibrate.bundle`). The first camera is the world frame; camera order is kept
  as given.

Translations come out in the unit of the target's square size (metres if it is in metres).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.calibrate.bundle import Observation, bundle_adjust
from stillcap.calibrate.detect import Detection, Progress, detect_target, detect_targets, image_name
from stillcap.calibrate.intrinsics import (IntrinsicsResult, calibrate_from_detections,
                                           calibrate_intrinsics_from_points)
from stillcap.calibrate.outliers import outlier_views
from stillcap.camera import Camera, Rig, pose_matrix

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


def _inv(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return pose_matrix(R.T, -R.T @ t)


# --- single camera pose -------------------------------------------------------------------
@dataclass
class PoseResult:
    """Pose of a calibrated camera.

    Attributes
    ----------
    world2cam : ndarray, shape (4, 4)
        Target/object/world frame -> camera frame.
    camera : Camera
        The input camera placed at ``world2cam``.
    rms_px : float
        Reprojection RMS of the points used.
    residuals_px : ndarray, shape (N,)
        Reprojection error per point used.
    n_points : int
    success : bool
        OpenCV found a pose in front of the camera with a finite error.
    """

    world2cam: np.ndarray
    camera: Camera
    rms_px: float
    residuals_px: np.ndarray
    n_points: int
    success: bool


def pose_from_points(camera: Camera, object_points, image_points, method: str = "sqpnp") -> PoseResult:
    """Pose of ``camera`` from world points and their pixels.

    Parameters
    ----------
    camera : Camera
        Intrinsics and distortion are used; its pose is ignored.
    object_points : array_like, shape (N, 3)
        Points in the world (or object) frame; N >= 4.
    image_points : array_like, shape (N, 2)
        Their distorted pixels; rows with NaN are ignored (not observed).
    method : ``"sqpnp"`` (SQPnP, globally optimal, then Levenberg-Marquardt refinement) or
        ``"iterative"`` (OpenCV's DLT/homography start + Levenberg-Marquardt).

    Returns
    -------
    PoseResult
    """
    obj = as_array(object_points, (None, 3), "object_points")
    img = as_array(image_points, (len(obj), 2), f"image_points (object_points are {obj.shape})")
    ok = np.all(np.isfinite(obj), axis=1) & np.all(np.isfinite(img), axis=1)
    obj, img = obj[ok], img[ok]
    if len(obj) < 4:
        raise ValueError(f"pose_from_points needs at least 4 observed points, got {len(obj)}")
    flags = {"sqpnp": cv2.SOLVEPNP_SQPNP, "iterative": cv2.SOLVEPNP_ITERATIVE}.get(method)
    if flags is None:
        raise ValueError(f"method must be 'sqpnp' or 'iterative', got {method!r}")
    o32, i32 = obj.reshape(-1, 1, 3), img.reshape(-1, 1, 2)
    found, rvec, tvec = cv2.solvePnP(o32, i32, camera.K, camera.dist, flags=flags)
    if found:
        rvec, tvec = cv2.solvePnPRefineLM(o32, i32, camera.K, camera.dist, rvec, tvec)
    T = pose_matrix(cv2.Rodrigues(rvec)[0], tvec) if found else np.eye(4)
    cam = camera.with_pose(T)
    res = np.linalg.norm(cam.project(obj) - img, axis=1)
    rms = float(np.sqrt(np.mean(res ** 2)))
    z = cam.world_to_cam(obj)[:, 2]
    return PoseResult(T, cam, rms, res, len(obj), bool(found and np.isfinite(rms) and np.all(z > 0)))


def pose_from_detection(camera: Camera, detection: Detection, method: str = "sqpnp") -> PoseResult:
    """Pose from a successful :class:`Detection` (ValueError naming the image otherwise)."""
    if not detection.success:
        raise ValueError(f"{detection.name}: {detection.reason}")
    if tuple(detection.image_size) != tuple(camera.image_size):
        raise ValueError(f"{detection.name} is {detection.image_size[0]}x{detection.image_size[1]} px, "
                         f"camera {camera.name!r} is {camera.image_size[0]}x{camera.image_size[1]} px")
    return pose_from_points(camera, detection.object_points, detection.image_points, method)


def pose_from_board(camera: Camera, image, target, method: str = "sqpnp") -> PoseResult:
    """``board2cam`` of a Chessboard or CharucoTarget seen in ``image`` (path or array)."""
    return pose_from_detection(camera, detect_target(image, target), method)


def pose_from_object(camera: Camera, image, calib_object, method: str = "sqpnp") -> PoseResult:
    """``object2cam`` of a 3D :class:`CalibrationObject` seen in ``image`` (path or array)."""
    return pose_from_detection(camera, detect_target(image, calib_object), method)


# --- stereo ---------------------------------------------------------------------------------
@dataclass
class StereoResult:
    """Stereo calibration.

    Attributes
    ----------
    rig : Rig
        ``[left, right]``; the left camera is the world frame.
    rms_px : float
        ``cv2.stereoCalibrate``'s RMS over both images of all pairs used.
    R : ndarray, shape (3, 3)
    T : ndarray, shape (3,)
        Left camera frame -> right camera frame: ``x_right = R x_left + T`` (target units).
    E, F : ndarray, shape (3, 3)
        Essential and fundamental matrices.
    baseline : float
        ``|T|``, in the unit of the target's square size.
    pairs_used : list[str]
    pairs_skipped : dict[str, str]
        Pair name -> why it was not used.
    per_pair_rms_px : dict[str, tuple[float, float]]
        RMS in the left and right image of each pair used.
    left, right : IntrinsicsResult or None
        The intrinsic calibrations made here (None when the camera was given).
    success : bool
    outlier_pairs : list[str]
        Pairs to drop: the pair's RMS (both images) stands far above the other pairs', or one of
        its images is an outlier view of its camera's intrinsics (:mod:`stillcap.calibrate.outliers`).
    pair_images : dict[str, tuple[str, str]]
        Pair name -> (left image name, right image name).
    without_outliers : StereoResult or None
        The whole calibration again without the outlier pairs (None when there are none, or the
        rest cannot be calibrated).
    """

    rig: Rig
    rms_px: float
    R: np.ndarray
    T: np.ndarray
    E: np.ndarray
    F: np.ndarray
    baseline: float
    pairs_used: list[str]
    pairs_skipped: dict[str, str] = field(default_factory=dict)
    per_pair_rms_px: dict[str, tuple[float, float]] = field(default_factory=dict)
    left: IntrinsicsResult | None = None
    right: IntrinsicsResult | None = None
    success: bool = True
    outlier_pairs: list[str] = field(default_factory=list)
    pair_images: dict[str, tuple[str, str]] = field(default_factory=dict)
    without_outliers: StereoResult | None = None


def _pair_key(name: str, word: str) -> str:
    stem = Path(name).stem
    return re.sub(re.escape(word), "", stem, flags=re.IGNORECASE)


def pair_stereo_images(left: Sequence, right: Sequence, keys: tuple[str, str] = ("left", "right"),
                       pair_by: str = "auto") -> list[tuple[str, object, object]]:
    """Pair left and right images of the same captures.

    Parameters
    ----------
    left, right : sequences of paths or arrays
    keys : words removed from the file names before matching (``left01.jpg`` ~ ``right01.jpg``).
    pair_by : ``"name"`` (file names equal once the key words are removed), ``"index"`` (same
        position) or ``"auto"`` (by name when both lists are paths, else by index).

    Returns
    -------
    list of (pair_name, left_image, right_image), in the order of ``left``.

    Raises
    ------
    ValueError
        Empty lists, different lengths, or names without a partner (named).
    """
    left, right = list(left), list(right)
    if not left or not right:
        raise ValueError(f"stereo calibration needs images from both cameras, got {len(left)} left "
                         f"and {len(right)} right")
    paths = all(isinstance(x, (str, Path)) for x in left + right)
    if pair_by == "auto":
        pair_by = "name" if paths else "index"
    if pair_by == "index":
        if len(left) != len(right):
            raise ValueError(f"stereo pairs do not match: {len(left)} left images but {len(right)} right images")
        return [(_pair_key(image_name(a, i), keys[0]) if paths else f"#{i}", a, b)
                for i, (a, b) in enumerate(zip(left, right))]
    if pair_by != "name":
        raise ValueError(f"pair_by must be 'auto', 'name' or 'index', got {pair_by!r}")
    if not paths:
        raise ValueError("pair_by='name' needs file paths")
    lk = {_pair_key(Path(p).name, keys[0]): p for p in left}
    rk = {_pair_key(Path(p).name, keys[1]): p for p in right}
    if len(lk) != len(left) or len(rk) != len(right):
        raise ValueError("stereo pairs are ambiguous: two images of one camera have the same name")
    lonely = [Path(lk[k]).name for k in lk if k not in rk] + [Path(rk[k]).name for k in rk if k not in lk]
    if lonely:
        raise ValueError(f"stereo pairs do not match: no partner for {', '.join(lonely)} "
                         f"(pairs are matched by file name with {keys[0]!r}/{keys[1]!r} removed)")
    return [(k, lk[k], rk[k]) for k in lk]


def split_stereo_images(paths: Sequence, keys: tuple[str, str] = ("left", "right")) -> tuple[list[Path], list[Path]]:
    """Split one list of photos into left and right by a word in the file name (case-insensitive).

    Raises
    ------
    ValueError
        A file name holds neither or both words (named), or one side is empty.
    """
    left, right, odd = [], [], []
    lk, rk = keys[0].lower(), keys[1].lower()
    for p in map(Path, paths):
        n = p.name.lower()
        if (lk in n) == (rk in n):
            odd.append(p.name)
        else:
            (left if lk in n else right).append(p)
    if odd:
        raise ValueError(f"cannot tell left from right for {', '.join(odd)} "
                         f"(file names must contain {keys[0]!r} or {keys[1]!r})")
    if not left or not right:
        raise ValueError(f"stereo calibration needs images from both cameras, got {len(left)} "
                         f"{keys[0]!r} and {len(right)} {keys[1]!r} images")
    return left, right


def _common_points(a: Detection, b: Detection):
    ids, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    return a.object_points[ia], a.image_points[ia], b.image_points[ib]


def calibrate_stereo(left_images: Sequence, right_images: Sequence, target, left_cam: Camera | None = None,
                     right_cam: Camera | None = None, names: tuple[str, str] = ("left", "right"),
                     fix_intrinsics: bool = True, keys: tuple[str, str] = ("left", "right"),
                     pair_by: str = "auto", min_points: int = 6,
                     progress: Progress | None = None) -> StereoResult:
    """Calibrate a stereo pair from photos of a target seen by both cameras.

    Parameters
    ----------
    left_images, right_images : sequences of paths or arrays
        Paired by :func:`pair_stereo_images` (``keys``, ``pair_by``).
    target : Chessboard, CharucoTarget or CalibrationObject
    left_cam, right_cam : Camera, optional
        Known intrinsics; when absent, each camera is calibrated from all its images first.
    names : camera names in the returned rig.
    fix_intrinsics : keep the intrinsics fixed (``CALIB_FIX_INTRINSIC``) or refine them too.
    min_points : fewest target points seen in both images of a pair.
    progress : ``progress(done, total, name)`` after each image is searched.

    Returns
    -------
    StereoResult

    Raises
    ------
    ValueError
        Mismatched pairs, unreadable images, or no pair with the target in both images.
    """
    pairs = pair_stereo_images(left_images, right_images, keys, pair_by)
    lnames = [image_name(a, i) for i, (_, a, _) in enumerate(pairs)]
    rnames = [image_name(b, i) for i, (_, _, b) in enumerate(pairs)]
    n = len(pairs)
    lprog = None if progress is None else (lambda i, _, nm: progress(i, 2 * n, nm))
    rprog = None if progress is None else (lambda i, _, nm: progress(n + i, 2 * n, nm))
    ldet = detect_targets([p[1] for p in pairs], target, lnames, lprog)
    rdet = detect_targets([p[2] for p in pairs], target, rnames, rprog)

    return calibrate_stereo_from_detections([(k, a, b) for (k, _, _), a, b in zip(pairs, ldet, rdet)],
                                            left_cam, right_cam, names, fix_intrinsics, min_points)


def calibrate_stereo_from_detections(pairs: Sequence[tuple[str, Detection, Detection]],
                                     left_cam: Camera | None = None, right_cam: Camera | None = None,
                                     names: tuple[str, str] = ("left", "right"), fix_intrinsics: bool = True,
                                     min_points: int = 6, check_outliers: bool = True) -> StereoResult:
    """Stereo calibration from detections: ``(pair_name, left_detection, right_detection)``.

    Cameras not given are first calibrated from all their detections. Only points seen in both
    images of a pair (same ids) are used. With ``check_outliers``, outlier pairs are flagged and
    the calibration is made again without them (``outlier_pairs``, ``without_outliers``). See
    :func:`calibrate_stereo`.
    """
    pairs = list(pairs)
    if not pairs:
        raise ValueError("stereo calibration needs at least one image pair, got none")
    given = (left_cam, right_cam)
    lres = rres = None
    if left_cam is None:
        lres = calibrate_from_detections([a for _, a, _ in pairs], names[0])
        left_cam = lres.camera
    if right_cam is None:
        rres = calibrate_from_detections([b for _, _, b in pairs], names[1])
        right_cam = rres.camera

    obj, il, ir, used, skipped = [], [], [], [], {}
    for key, a, b in pairs:
        if not (a.success and b.success):
            skipped[key] = "; ".join(f"{d.name}: {d.reason}" for d in (a, b) if not d.success)
            continue
        o, pa, pb = _common_points(a, b)
        if len(o) < min_points:
            skipped[key] = f"only {len(o)} target points seen in both images (need {min_points})"
            continue
        obj.append(o.astype(np.float32))
        il.append(pa.astype(np.float32).reshape(-1, 1, 2))
        ir.append(pb.astype(np.float32).reshape(-1, 1, 2))
        used.append(key)
    if not used:
        raise ValueError("no stereo pair shows the target in both images: "
                         + "; ".join(f"{k} ({v})" for k, v in skipped.items()))
    flags = cv2.CALIB_FIX_INTRINSIC if fix_intrinsics else cv2.CALIB_USE_INTRINSIC_GUESS
    # K and dist are input/output arguments: OpenCV writes the refined values into the arrays it
    # is given. Copies keep the single-camera results (and cameras the caller passed) unchanged.
    rms, K1, d1, K2, d2, R, T, E, F, _, _, per_view = cv2.stereoCalibrateExtended(
        obj, il, ir, left_cam.K.copy(), left_cam.dist.copy(), right_cam.K.copy(), right_cam.dist.copy(),
        left_cam.image_size, None, None, flags=flags)
    T = np.ravel(T).astype(float)
    cl = Camera(names[0], K1, np.ravel(d1)[:5], np.eye(4), left_cam.image_size, left_cam.response)
    cr = Camera(names[1], K2, np.ravel(d2)[:5], pose_matrix(R, T), right_cam.image_size, right_cam.response)
    per = {k: (float(e[0]), float(e[1])) for k, e in zip(used, np.asarray(per_view).reshape(-1, 2))}
    ok = bool(np.isfinite(rms) and np.all(np.isfinite(T)))
    res = StereoResult(Rig([cl, cr]), float(rms), np.asarray(R, float), T, np.asarray(E, float),
                       np.asarray(F, float), float(np.linalg.norm(T)), used, skipped, per, lres, rres, ok,
                       pair_images={k: (a.name, b.name) for k, a, b in pairs})
    if check_outliers:
        # the pair's RMS over both images (the same points in each), and each camera's own outliers
        flagged = set(outlier_views({k: float(np.sqrt((a * a + b * b) / 2)) for k, (a, b) in per.items()}))
        odd = set(lres.outlier_views if lres else ()) | set(rres.outlier_views if rres else ())
        res.outlier_pairs = [k for k, a, b in pairs if k in flagged or a.name in odd or b.name in odd]
        if res.outlier_pairs:
            try:
                res.without_outliers = calibrate_stereo_from_detections(
                    [p for p in pairs if p[0] not in res.outlier_pairs], *given, names, fix_intrinsics, min_points,
                    check_outliers=False)
            except ValueError:  # too few pairs left to calibrate: no comparison to offer
                res.without_outliers = None
    return res


# --- N-camera rigs --------------------------------------------------------------------------
@dataclass
class RigResult:
    """N-camera rig calibration.

    Attributes
    ----------
    rig : Rig
        Cameras in the order given; camera 0 is the world frame (``world2cam`` = identity).
    rms_px : float
        Reprojection RMS over all cameras after bundle adjustment.
    per_camera_rms_px : dict[str, float]
    initial_rms_px : float
        RMS of the spanning-tree initialisation (before bundle adjustment).
    initial_rig : Rig
        The spanning-tree initialisation.
    intrinsics : dict[str, IntrinsicsResult]
        Per camera, when calibrated here.
    board2world : dict[str, ndarray, shape (4, 4)]
        Target pose per instant used in the adjustment.
    instants_used : list[str]
        Instants seen by at least two cameras.
    images_skipped : dict[str, dict[str, str]]
        Camera -> {image: reason}.
    success : bool
    message : str
    per_view_rms_px : dict[str, dict[str, float]]
        Camera -> {instant (image name with :func:`calibrate_rig`): RMS after the adjustment}.
    outlier_views : dict[str, dict[str, str]]
        Camera -> {view to drop: why}: its RMS after the adjustment stands far above the camera's
        other views, or it is an outlier of the camera's own intrinsic calibration
        (:mod:`stillcap.calibrate.outliers`). Cameras without outliers are absent.
    without_outliers : RigResult or None
        The whole calibration again without the outlier views (None when there are none, or the
        rest cannot be calibrated).
    """

    rig: Rig
    rms_px: float
    per_camera_rms_px: dict[str, float]
    initial_rms_px: float
    initial_rig: Rig
    intrinsics: dict[str, IntrinsicsResult]
    board2world: dict[str, np.ndarray]
    instants_used: list[str]
    images_skipped: dict[str, dict[str, str]]
    success: bool
    message: str = ""
    per_view_rms_px: dict[str, dict[str, float]] = field(default_factory=dict)
    outlier_views: dict[str, dict[str, str]] = field(default_factory=dict)
    without_outliers: RigResult | None = None


def _mean_pose(poses: Sequence[np.ndarray], robust: bool = False) -> np.ndarray:
    P = np.stack(poses)
    R = Rotation.from_matrix(P[:, :3, :3]).mean().as_matrix()
    t = np.median(P[:, :3, 3], axis=0) if robust else P[:, :3, 3].mean(axis=0)
    return pose_matrix(R, t)


def initial_rig_poses(names: Sequence[str], board2cam: Sequence[Mapping[int, np.ndarray]]) -> list[np.ndarray]:
    """``world2cam`` per camera from per-instant target poses (camera 0 = world).

    A maximum spanning tree over cameras weighted by shared instants links every camera to
    camera 0; along each edge the relative pose ``board2cam_j inv(board2cam_i)`` is averaged over
    the shared instants (rotation: chordal mean; translation: median).

    Parameters
    ----------
    names : camera names (for messages).
    board2cam : per camera, {instant index: target pose (4, 4)}.
    """
    n = len(names)
    W = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            W[i, j] = len(set(board2cam[i]) & set(board2cam[j]))
    cost = np.where(W > 0, 1.0 / np.maximum(W, 1), 0.0)  # fewest-cost tree = most shared views
    tree = minimum_spanning_tree(csr_matrix(cost))
    order, pred = breadth_first_order(tree, 0, directed=False, return_predecessors=True)
    lost = [names[i] for i in range(n) if i not in set(order)]
    if lost:
        raise ValueError(f"camera(s) {', '.join(lost)} share no target view with camera {names[0]!r} "
                         "or with any camera linked to it")
    w2c = [np.eye(4) for _ in range(n)]
    for j in order[1:]:
        i = pred[j]
        shared = sorted(set(board2cam[i]) & set(board2cam[j]))
        rel = _mean_pose([board2cam[j][k] @ _inv(board2cam[i][k]) for k in shared], robust=True)
        w2c[j] = rel @ w2c[i]
    return w2c


def calibrate_rig_from_points(views: Mapping[str, Sequence], image_size=None, cameras=None,
                              instants: Sequence[str] | None = None, refine_intrinsics: bool = False,
                              loss: str = "soft_l1", f_scale: float = 1.0, min_views: int = 3,
                              max_corner_px: float = 2.0, min_inlier_fraction: float = 0.8,
                              check_outliers: bool = True) -> RigResult:
    """Calibrate N cameras from target correspondences at shared instants.

    Parameters
    ----------
    views : mapping camera name -> sequence over instants of ``(object_points (N, 3),
        image_points (N, 2))`` or None (not seen). All sequences have the same length; the
        mapping's order is the camera order, and the first camera is the world frame.
    image_size : (width, height), or mapping camera name -> (width, height); needed for
        cameras whose intrinsics are calibrated here.
    cameras : mapping name -> Camera or Rig, optional
        Known intrinsics (their poses are ignored); other cameras are calibrated from their views.
    instants : instant names (default ``"#0", "#1", ...``).
    refine_intrinsics : let the bundle adjustment refine intrinsics too.
    loss, f_scale : robust loss for the bundle adjustment (``least_squares``), scale in pixels.
    min_views : fewest views for an intrinsic calibration.
    max_corner_px, min_inlier_fraction : corners farther than ``max_corner_px`` from where their
        own view's board pose puts them are detection errors and left out; a view keeping fewer
        than ``min_inlier_fraction`` of its corners (a detection gone wrong, typically a board
        seen at a grazing angle) is left out whole and listed in ``images_skipped``.
    check_outliers : flag outlier views and calibrate again without them (``outlier_views``,
        ``without_outliers``).

    Returns
    -------
    RigResult
    """
    names = list(views)
    if len(names) < 2:
        raise ValueError(f"a rig needs at least 2 cameras, got {len(names)} ({', '.join(names)})")
    lengths = {nm: len(views[nm]) for nm in names}
    if len(set(lengths.values())) != 1:
        raise ValueError("cameras have different numbers of instants: "
                         + ", ".join(f"{k}: {v}" for k, v in lengths.items()))
    m = lengths[names[0]]
    instants = [f"#{i}" for i in range(m)] if instants is None else [str(s) for s in instants]
    if len(instants) != m or len(set(instants)) != m:
        raise ValueError(f"need {m} distinct instant names, got {len(instants)} ({len(set(instants))} distinct)")
    known = {} if cameras is None else {nm: cameras[nm] for nm in names
                                        if nm in (cameras.names if isinstance(cameras, Rig) else cameras)}

    cams, intr, b2c, rejected, inliers = [], {}, [], {nm: {} for nm in names}, {}
    for nm in names:
        seen = {}
        for i, v in enumerate(views[nm]):
            if v is None:
                continue
            o = as_array(v[0], (None, 3), f"camera {nm!r} instant {instants[i]} object points")
            p = as_array(v[1], (len(o), 2), f"camera {nm!r} instant {instants[i]} image points")
            if len(o) >= 4:
                seen[i] = (o, p)
        if nm in known:
            cam = known[nm]
            b2c.append({i: r.world2cam for i, r in
                        ((i, pose_from_points(cam, o, p)) for i, (o, p) in seen.items()) if r.success})
        else:
            size = image_size.get(nm) if isinstance(image_size, Mapping) else image_size
            if size is None:
                raise ValueError(f"camera {nm!r}: no intrinsics given and no image_size to calibrate them")
            idx = sorted(seen)
            res = calibrate_intrinsics_from_points([seen[i][0] for i in idx], [seen[i][1] for i in idx], size,
                                                   [instants[i] for i in idx], nm, min_views=min_views,
                                                   check_outliers=check_outliers)
            intr[nm] = res
            cam = res.camera
            b2c.append({i: res.board2cam[instants[i]] for i in idx})
        for i, T in list(b2c[-1].items()):
            o, p = seen[i]
            inl = np.linalg.norm(cam.with_pose(T).project(o) - p, axis=1) <= max_corner_px
            if inl.mean() < min_inlier_fraction:
                del b2c[-1][i]
                rejected[nm][instants[i]] = (f"only {inl.sum()} of {len(inl)} corners within {max_corner_px} px "
                                             "of the board pose (detection gone wrong)")
            elif not inl.all():
                seen[i] = (o[inl], p[inl])
        inliers[nm] = seen
        cams.append(cam.with_pose(np.eye(4)))

    w2c = initial_rig_poses(names, b2c)
    cams0 = [c.with_pose(T) for c, T in zip(cams, w2c)]
    used = [i for i in range(m) if sum(i in d for d in b2c) >= 2]
    if not used:
        raise ValueError("no instant shows the target to two or more cameras")
    b2w = np.stack([_mean_pose([_inv(w2c[c]) @ b2c[c][i] for c in range(len(names)) if i in b2c[c]])
                    for i in used])
    obs = [Observation(c, k, *inliers[nm][i]) for k, i in enumerate(used)
           for c, nm in enumerate(names) if i in b2c[c]]
    ba = bundle_adjust(cams0, b2w, obs, refine_intrinsics=refine_intrinsics, loss=loss, f_scale=f_scale)
    per_view = {nm: {} for nm in names}
    for o, e in zip(obs, ba.per_observation_rms_px):
        per_view[names[o.camera]][instants[used[o.instant]]] = float(e)
    res = RigResult(Rig(ba.cameras), ba.rms_px, dict(zip(names, map(float, ba.per_camera_rms_px))),
                    ba.initial_rms_px, Rig(cams0), intr, {instants[i]: T for i, T in zip(used, ba.board2world)},
                    [instants[i] for i in used], rejected, ba.success, ba.message, per_view)
    if check_outliers:
        for nm in names:
            why = {}
            if nm in intr:
                pi = intr[nm].per_image_rms_px
                med = float(np.median(list(pi.values())))
                why.update({k: f"{pi[k]:.3f} px in the camera's intrinsic calibration, {pi[k] / med:.1f}x the "
                               f"median {med:.3f} px" for k in intr[nm].outlier_views})
            med = float(np.median(list(per_view[nm].values())))
            why.update({k: f"{per_view[nm][k]:.3f} px after the adjustment, {per_view[nm][k] / med:.1f}x the "
                           f"median {med:.3f} px" for k in outlier_views(per_view[nm]) if k not in why})
            if why:
                res.outlier_views[nm] = {s: why[s] for s in instants if s in why}
        if res.outlier_views:
            drop = {nm: set(v) for nm, v in res.outlier_views.items()}
            rest = {nm: [None if instants[i] in drop.get(nm, ()) else v for i, v in enumerate(views[nm])]
                    for nm in names}
            try:
                res.without_outliers = calibrate_rig_from_points(
                    rest, image_size, cameras, instants, refine_intrinsics, loss, f_scale, min_views,
                    max_corner_px, min_inlier_fraction, check_outliers=False)
            except ValueError:  # too few views left to calibrate: no comparison to offer
                res.without_outliers = None
    return res


def calibrate_rig(images_per_camera: Mapping[str, Sequence], target, cameras=None,
                  instants: Sequence[str] | None = None, refine_intrinsics: bool = False,
                  loss: str = "soft_l1", f_scale: float = 1.0, min_views: int = 3,
                  progress: Progress | None = None, max_corner_px: float = 2.0,
                  min_inlier_fraction: float = 0.8) -> RigResult:
    """Calibrate N cameras from photos of a target taken at shared instants.

    Parameters
    ----------
    images_per_camera : mapping camera name -> sequence of images (paths or arrays; None where
        the camera has no photo) at the same instants: item ``i`` of every camera was taken at
        instant ``i``. The mapping's order is kept; the first camera is the world frame.
    target : Chessboard (with ``cols + rows`` odd, so its orientation is unambiguous),
        CharucoTarget or CalibrationObject.
    cameras, refine_intrinsics, loss, f_scale, min_views, max_corner_px, min_inlier_fraction : see
        :func:`calibrate_rig_from_points`.
    instants : instant names (default: the file name of the first camera with a photo, or ``"#i"``).
    progress : ``progress(done, total, name)`` after each image is searched.

    Returns
    -------
    RigResult
        ``images_skipped`` lists, per camera, images where the target was not found.
    """
    names = list(images_per_camera)
    if not names:
        raise ValueError("no cameras given")
    lists = {nm: list(images_per_camera[nm]) for nm in names}
    for nm, lst in lists.items():
        if not any(x is not None for x in lst):
            raise ValueError(f"camera {nm!r}: no images given")
    m = max(len(v) for v in lists.values())
    if any(len(v) != m for v in lists.values()):
        raise ValueError("cameras have different numbers of images (one per instant expected): "
                         + ", ".join(f"{k}: {len(v)}" for k, v in lists.items()))
    if instants is None:
        instants = []
        for i in range(m):
            first = next((lists[nm][i] for nm in names if lists[nm][i] is not None), None)
            label = image_name(first, i) if first is not None else f"#{i}"
            instants.append(label if label not in instants else f"{label}#{i}")
    total = sum(x is not None for v in lists.values() for x in v)
    done = 0
    views, sizes, skipped = {}, {}, {}
    for nm in names:
        views[nm], skipped[nm] = [], {}
        for i, im in enumerate(lists[nm]):
            if im is None:
                views[nm].append(None)
                continue
            label = image_name(im, i)
            d = detect_target(im, target, label)
            done += 1
            if progress is not None:
                progress(done, total, f"{nm}/{label}")
            if sizes.setdefault(nm, d.image_size) != d.image_size:
                raise ValueError(f"camera {nm!r}: {label} is {d.image_size[0]}x{d.image_size[1]} px, "
                                 f"earlier images are {sizes[nm][0]}x{sizes[nm][1]} px")
            if d.success:
                views[nm].append((d.object_points, d.image_points))
            else:
                views[nm].append(None)
                skipped[nm][label] = d.reason
        if all(v is None for v in views[nm]):
            raise ValueError(f"camera {nm!r}: target not found in any image: "
                             + "; ".join(f"{k} ({v})" for k, v in skipped[nm].items()))
    res = calibrate_rig_from_points(views, sizes, cameras, instants, refine_intrinsics, loss, f_scale, min_views,
                                    max_corner_px, min_inlier_fraction)
    label_of = {inst: image_name(lists[nm][i], i) for nm in names for i, inst in enumerate(instants)
                if lists[nm][i] is not None}
    for nm, rej in res.images_skipped.items():
        for inst, why in rej.items():
            skipped[nm][label_of.get(inst, inst)] = why
    res.images_skipped = skipped
    for nm, ir in res.intrinsics.items():
        ir.images_skipped = skipped[nm]
    index = {inst: i for i, inst in enumerate(instants)}

    def label(nm, inst):  # the camera's own file name of an instant
        i = index.get(inst)
        return inst if i is None or lists[nm][i] is None else image_name(lists[nm][i], i)

    res.per_view_rms_px = {nm: {label(nm, k): e for k, e in v.items()} for nm, v in res.per_view_rms_px.items()}
    res.outlier_views = {nm: {label(nm, k): why for k, why in v.items()} for nm, v in res.outlier_views.items()}
    return res


def _natural_key(s: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


def rig_images_from_folder(folder) -> tuple[dict[str, list[Path | None]], list[str]]:
    """Images of a rig laid out as ``FOLDER/<camera>/<instant>.<ext>``.

    One subfolder per camera (cameras in natural order of their names, so ``cam2`` comes before
    ``cam10``; the first is the world frame); photos of one instant share a file name (without
    extension) across subfolders.

    Returns
    -------
    images : dict camera -> list of paths (None where that camera has no photo of an instant)
    instants : instant names (file stems, natural order)
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"rig folder {folder} does not exist or is not a folder")
    subs = sorted((p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")),
                  key=lambda p: _natural_key(p.name))
    if not subs:
        raise ValueError(f"rig folder {folder} has no camera subfolders (expected {folder}/<camera>/<image>)")
    files = {}
    for s in subs:
        imgs = {p.stem: p for p in sorted(s.iterdir()) if p.suffix.lower() in IMAGE_EXTENSIONS}
        if not imgs:
            raise ValueError(f"camera folder {s} holds no images ({', '.join(IMAGE_EXTENSIONS)})")
        files[s.name] = imgs
    instants = sorted({k for v in files.values() for k in v}, key=_natural_key)
    return {cam: [v.get(k) for k in instants] for cam, v in files.items()}, instants
