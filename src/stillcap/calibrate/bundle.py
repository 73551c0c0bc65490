"""Bundle adjustment of a camera rig observing a rigid target at several instants.

Unknowns: the pose of every camera but the first (the world frame, kept fixed), the pose of the
target at every instant, and optionally every camera's intrinsics (fx, fy, cx, cy, k1, k2, p1,
p2, k3). Residuals: pixel reprojection errors of the target points. Solved with
``scipy.optimize.least_squares`` (trust-region reflective, robust loss, sparse finite-difference
Jacobian via ``jac_sparsity``; rotations as rotation vectors).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.camera import Camera, pose_matrix

N_INTR = 9  # fx, fy, cx, cy, k1, k2, p1, p2, k3


@dataclass
class Observation:
    """Target points seen by one camera at one instant.

    Attributes
    ----------
    camera : int
        Index into the camera list.
    instant : int
        Index into the target poses.
    object_points : ndarray, shape (N, 3)
        Target points in the target frame (metres).
    image_points : ndarray, shape (N, 2)
        Their pixels.
    """

    camera: int
    instant: int
    object_points: np.ndarray
    image_points: np.ndarray


@dataclass
class BundleResult:
    """Result of :func:`bundle_adjust`.

    Attributes
    ----------
    cameras : list[Camera]
        Refined cameras, same order and names as given; camera 0 unchanged if ``fix_first``.
    board2world : ndarray, shape (M, 4, 4)
        Refined target pose per instant.
    rms_px, initial_rms_px : float
        Reprojection RMS over all observed points after / before the adjustment.
    per_camera_rms_px : ndarray, shape (n_cams,)
        RMS per camera after the adjustment (NaN for a camera without observations).
    n_points : int
        Observed points used.
    success : bool
        ``least_squares`` reported convergence and the RMS is finite.
    message : str
    per_observation_rms_px : ndarray, shape (n_observations,)
        RMS of each observation (one camera at one instant) after the adjustment, in the order
        given (NaN for an observation without finite points).
    """

    cameras: list[Camera]
    board2world: np.ndarray
    rms_px: float
    initial_rms_px: float
    per_camera_rms_px: np.ndarray
    n_points: int
    success: bool
    message: str
    per_observation_rms_px: np.ndarray | None = None


def _pose_to_vec(T: np.ndarray) -> np.ndarray:
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def _vec_to_pose(v: np.ndarray) -> np.ndarray:
    return pose_matrix(Rotation.from_rotvec(v[:3]).as_matrix(), v[3:6])


def _intr_vec(c: Camera) -> np.ndarray:
    K = c.K
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], c.dist])


def _camera_from(c: Camera, intr: np.ndarray | None, world2cam: np.ndarray) -> Camera:
    if intr is None:
        return c.with_pose(world2cam)
    K = c.K.copy()
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = intr[:4]
    return Camera(c.name, K, intr[4:], world2cam, c.image_size, c.response)


def bundle_adjust(cameras: Sequence[Camera], board2world, observations: Sequence[Observation],
                  refine_intrinsics: bool = False, fix_first: bool = True, loss: str = "soft_l1",
                  f_scale: float = 1.0, max_nfev: int | None = None) -> BundleResult:
    """Jointly refine camera poses, target poses (and optionally intrinsics).

    Parameters
    ----------
    cameras : sequence of Camera
        Initial cameras (``world2cam`` = starting pose). With ``fix_first`` camera 0 stays fixed
        and defines the world frame.
    board2world : array_like, shape (M, 4, 4)
        Initial target pose per instant.
    observations : sequence of Observation
    refine_intrinsics : also refine fx, fy, cx, cy and the 5 distortion terms of every camera.
    loss, f_scale : robust loss of ``least_squares`` and its inlier scale in pixels.
    max_nfev : evaluation budget (default: SciPy's).

    Returns
    -------
    BundleResult
    """
    cams = list(cameras)
    n_cams = len(cams)
    B0 = as_array(board2world, (None, 4, 4), "board2world")
    n_b = len(B0)
    if not observations:
        raise ValueError("bundle_adjust: no observations")
    cam_idx, b_idx, obs_idx, obj, img = [], [], [], [], []
    for k, o in enumerate(observations):
        if not (0 <= o.camera < n_cams and 0 <= o.instant < n_b):
            raise ValueError(f"observation refers to camera {o.camera} / instant {o.instant}, "
                             f"but there are {n_cams} cameras and {n_b} instants")
        p = as_array(o.object_points, (None, 3), "object_points")
        q = as_array(o.image_points, (len(p), 2), f"image_points (object_points are {p.shape})")
        keep = np.all(np.isfinite(q), axis=1)
        cam_idx.append(np.full(keep.sum(), o.camera))
        b_idx.append(np.full(keep.sum(), o.instant))
        obs_idx.append(np.full(keep.sum(), k))
        obj.append(p[keep])
        img.append(q[keep])
    cam_idx, b_idx, obs_idx = np.concatenate(cam_idx), np.concatenate(b_idx), np.concatenate(obs_idx)
    obj, img = np.concatenate(obj), np.concatenate(img)
    n_pts = len(obj)

    free = list(range(1 if fix_first else 0, n_cams))
    col_cam = {c: 6 * k for k, c in enumerate(free)}
    off_b = 6 * len(free)
    off_i = off_b + 6 * n_b
    n_par = off_i + (N_INTR * n_cams if refine_intrinsics else 0)
    x0 = np.concatenate([_pose_to_vec(cams[c].world2cam) for c in free]
                        + [_pose_to_vec(T) for T in B0]
                        + ([_intr_vec(c) for c in cams] if refine_intrinsics else []))
    fixed_w2c = np.stack([c.world2cam for c in cams])
    masks = [cam_idx == c for c in range(n_cams)]
    work = [c.with_pose(np.eye(4)) for c in cams]  # private copies whose K/dist the solver may set

    def unpack(x):
        w2c = fixed_w2c.copy()
        for c in free:
            w2c[c] = _vec_to_pose(x[col_cam[c]:col_cam[c] + 6])
        bv = x[off_b:off_i].reshape(n_b, 6)
        b2w = np.tile(np.eye(4), (n_b, 1, 1))
        b2w[:, :3, :3] = Rotation.from_rotvec(bv[:, :3]).as_matrix()
        b2w[:, :3, 3] = bv[:, 3:]
        intr = x[off_i:].reshape(n_cams, N_INTR) if refine_intrinsics else [None] * n_cams
        return w2c, b2w, intr

    def residuals(x):
        w2c, b2w, intr = unpack(x)
        pw = np.einsum("pij,pj->pi", b2w[b_idx, :3, :3], obj) + b2w[b_idx, :3, 3]
        pc = np.einsum("pij,pj->pi", w2c[cam_idx, :3, :3], pw) + w2c[cam_idx, :3, 3]
        xn = pc[:, :2] / pc[:, 2:3]
        px = np.empty_like(img)
        for c in range(n_cams):
            if masks[c].any():
                cam = work[c]
                if refine_intrinsics:  # in place: skips Camera's validation on every evaluation
                    cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2] = intr[c][:4]
                    cam.dist[:] = intr[c][4:]
                # Camera.normalized_to_pixels: the library's own distortion model, vectorised
                px[masks[c]] = cam.normalized_to_pixels(xn[masks[c]])
        return (px - img).ravel()

    # Jacobian sparsity: each point's two residuals depend on its camera's pose (if free),
    # its instant's target pose and (if refined) its camera's intrinsics.
    blocks = [off_b + 6 * b_idx[:, None] + np.arange(6)]
    cam_cols = np.array([col_cam.get(c, -1) for c in range(n_cams)])[cam_idx]
    blocks.append(np.where(cam_cols[:, None] >= 0, cam_cols[:, None] + np.arange(6), -1))
    if refine_intrinsics:
        blocks.append(off_i + N_INTR * cam_idx[:, None] + np.arange(N_INTR))
    cols = np.concatenate(blocks, axis=1)  # (n_pts, n_dep), -1 = none
    pr = np.broadcast_to(np.arange(n_pts)[:, None], cols.shape)
    keep = cols >= 0
    r = np.concatenate([2 * pr[keep], 2 * pr[keep] + 1])
    cc = np.concatenate([cols[keep], cols[keep]])
    A = coo_matrix((np.ones(len(r), np.uint8), (r, cc)), shape=(2 * n_pts, n_par)).tocsr()

    r0 = residuals(x0)
    # ftol 1e-6: stop when the cost changes by less than a millionth (about 1e-7 px of RMS); with
    # free intrinsics the cost valley is flat and SciPy's default (1e-8) creeps on for long.
    sol = least_squares(residuals, x0, jac_sparsity=A, x_scale="jac", loss=loss, f_scale=f_scale,
                        method="trf", ftol=1e-6, max_nfev=max_nfev)
    w2c, b2w, intr = unpack(sol.x)
    out = [_camera_from(c, intr[i], w2c[i]) for i, c in enumerate(cams)]
    err2 = (sol.fun.reshape(-1, 2) ** 2).sum(axis=1)
    per_cam = np.array([np.sqrt(err2[m].mean()) if m.any() else np.nan for m in masks])
    n_per_obs = np.bincount(obs_idx, minlength=len(observations))
    with np.errstate(invalid="ignore", divide="ignore"):
        per_obs = np.sqrt(np.bincount(obs_idx, err2, minlength=len(observations)) / n_per_obs)
    rms = float(np.sqrt(err2.mean()))
    rms0 = float(np.sqrt((r0.reshape(-1, 2) ** 2).sum(axis=1).mean()))
    ok = bool(sol.success and np.isfinite(rms))
    return BundleResult(out, b2w, rms, rms0, per_cam, n_pts, ok, str(sol.message), per_obs)
