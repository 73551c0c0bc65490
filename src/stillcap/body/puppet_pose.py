"""Puppet pose from 3D markers (SPEC J3): what the markers measure of each joint, and the joint
rotations that put the marker set's beads on them. A stage of :mod:`stillcap.pipelines.puppet`.

:func:`fit_pose` fits every free joint's intrinsic XYZ Euler angles (the limits' own
parameters, so the limits are hard bounds) to the 3D markers by least squares with an analytic
Jacobian. A joint frame that carries two beads not in line with the joint has three points
(its markers and the joint itself): its full orientation, twist included, is measured
(:func:`frame_status`). Where the markers leave a rotation open (forearms and shins carry one
bead each: the rotation about the elbow-to-bead line; hands and feet carry none) a weak prior
pulls each Euler angle toward 0 (clipped into its limits) with a standard deviation of half its
range, so near-hinge joints stay near their hinge. The thesis's bone-direction pose
(:func:`stillcap.body.kinematics.pose_from_markers`) is kept beside it.

Metres and degrees; see ``docs/puppet.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from threadpoolctl import threadpool_limits

from stillcap.body.kinematics import bone_directions, normalised, pose_from_markers
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import EULER_LIMIT_SEQUENCE, Pose, Skeleton, euler_within_limits, forward_kinematics

__all__ = ["PoseFit", "fit_pose", "frame_status"]


def frame_status(skeleton: Skeleton, markerset: MarkerSet) -> dict[str, str]:
    """What the markers measure of each joint's frame (its local rotation).

    ``"full"``: the frame carries 2+ markers not in one line with the joint (or 3+ markers), so
    its whole orientation, twist included, follows from them; ``"partial"``: one marker (or
    markers in line with the joint): a rotation about that line stays open; ``"none"``: no
    marker; ``"locked"``: the joint cannot rotate (all limits ``[0, 0]``).
    """
    frames = markerset.bone_frames(skeleton)
    lim = skeleton.limits_deg
    out = {}
    for j, name in enumerate(skeleton.names):
        if np.all(lim[j, :, 0] == lim[j, :, 1]):
            out[name] = "locked"
            continue
        pts = markerset.offsets[frames == j]
        if len(pts) == 0:
            out[name] = "none"
            continue
        cloud = np.vstack([pts, np.zeros((1, 3))])
        s = np.linalg.svd(cloud - cloud.mean(axis=0), compute_uv=False)
        out[name] = "full" if len(pts) >= 1 and s[1] > 1e-3 * max(s[0], 1e-12) and len(cloud) >= 3 else "partial"
    return out


@dataclass(eq=False)
class PoseFit:
    """Result of :func:`fit_pose`.

    Attributes
    ----------
    pose : Pose
        The fitted pose (every local rotation within the joint limits).
    thesis_pose : Pose
        The thesis's pose from bone directions (:func:`~stillcap.body.kinematics.pose_from_markers`).
    directions : dict
        The thesis's bone directions from the markers (bone -> unit vector, NaN if unmeasured).
    residuals_m : ndarray, shape (n_markers,)
        Distance of each fitted model marker from its measurement, metres (NaN if unseen).
    thesis_residuals_m : ndarray, shape (n_markers,)
        The same for the thesis's pose.
    success : bool
        The optimiser converged.
    n_markers : int
        Markers used.
    time_s : float
    """

    pose: Pose
    thesis_pose: Pose
    directions: dict
    residuals_m: np.ndarray
    thesis_residuals_m: np.ndarray
    success: bool
    n_markers: int
    time_s: float = 0.0

    @property
    def rms_m(self) -> float:
        r = self.residuals_m[np.isfinite(self.residuals_m)]
        return float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan")


def _euler_matrices(angles_deg: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rx(a), Ry(b), Rz(c) for rows (a, b, c) in degrees, each (n, 3, 3).

    Written from cos and sin (the elementary rotations) rather than with
    ``Rotation.from_euler``: the fit builds them at every residual and Jacobian evaluation, and
    the quaternion round trip cost ~12 ms of the ~30 ms fit; the same matrices to ~1e-16."""
    a = np.radians(np.asarray(angles_deg, float))
    c, s = np.cos(a), np.sin(a)
    n = len(a)
    one, zero = np.ones(n), np.zeros(n)
    cx, cy, cz = c.T
    sx, sy, sz = s.T
    Rx = np.stack([one, zero, zero, zero, cx, -sx, zero, sx, cx], axis=1).reshape(n, 3, 3)
    Ry = np.stack([cy, zero, sy, zero, one, zero, -sy, zero, cy], axis=1).reshape(n, 3, 3)
    Rz = np.stack([cz, -sz, zero, sz, cz, zero, zero, zero, one], axis=1).reshape(n, 3, 3)
    return Rx, Ry, Rz


def _rotations_about(axis: np.ndarray, angles_rad: np.ndarray) -> np.ndarray:
    """Rotations about one unit axis by each angle, shape (n, 3, 3)."""
    return Rotation.from_rotvec(np.outer(angles_rad, axis)).as_matrix()


def _start_angles(skeleton: Skeleton, markerset: MarkerSet, pts: np.ndarray, r2w: np.ndarray, lo, hi, centre,
                  sd) -> np.ndarray:
    """A start for :func:`fit_pose`, joint by joint from the root (degrees, (n_joints, 3)).

    Each joint's parent frame is known by then, so the joint's world position is too. A frame
    with 2+ seen markers not in line with the joint: the rotation about the joint that best
    maps the markers' offsets onto the measured markers (Wahba / Kabsch). One seen marker: the
    rotations that put it exactly on its measurement form a one-parameter family (turning about
    the joint-to-marker line); the one whose Euler angles the prior likes best, within the
    limits, is taken. No marker: the prior's centre.
    """
    n = skeleton.n_joints
    lim = np.stack([lo, hi], axis=-1)
    frames = markerset.bone_frames(skeleton)
    seen = np.all(np.isfinite(pts), axis=1)
    offs = markerset.offsets
    ang = np.zeros((n, 3))
    world = np.zeros((n, 3, 3))
    origin = np.zeros((n, 3))
    parents = skeleton.parents
    phis = np.radians(np.arange(0.0, 360.0, 3.0))
    for j in skeleton.depth_first:
        p = parents[j]
        Wp = r2w[:3, :3] if p < 0 else world[p]
        origin[j] = r2w[:3, 3] if p < 0 else origin[p] + world[p] @ skeleton.offsets[j]
        locked = np.all(hi[j] <= lo[j])
        sel = np.flatnonzero((frames == j) & seen)
        cands = None
        if not locked and len(sel):
            meas = (pts[sel] - origin[j]) @ Wp  # measured offsets in the parent's frame (rows: Wp.T @ v)
            model = offs[sel]
            cloud = np.vstack([model, np.zeros((1, 3))])
            sv = np.linalg.svd(cloud - cloud.mean(axis=0), compute_uv=False)
            if len(sel) >= 2 and sv[1] > 1e-3 * sv[0]:
                cands = Rotation.align_vectors(meas, model)[0].as_matrix()[None]
            else:
                a, b = normalised(meas.mean(axis=0)), normalised(model.mean(axis=0))
                if np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
                    R0 = Rotation.align_vectors(a[None], b[None])[0].as_matrix()
                    cands = _rotations_about(a, phis) @ R0
        if cands is None:
            ang[j] = np.where(locked, lo[j], centre[j])
        else:
            e, viol = euler_within_limits(cands, np.where(np.isfinite(lim[j]), lim[j], np.nan))
            cost = 100.0 * viol + np.sum(((e - centre[j]) / sd[j]) ** 2, axis=1)
            ang[j] = np.clip(e[int(np.argmin(cost))], lo[j], hi[j])
        world[j] = Wp @ Rotation.from_euler(EULER_LIMIT_SEQUENCE, ang[j], degrees=True).as_matrix()
    return ang


def fit_pose(skeleton: Skeleton, markerset: MarkerSet, marker_positions, root2world=None,
             initial: Pose | None = None, marker_sigma_m: float = 0.2e-3, robust: bool = True) -> PoseFit:
    """Joint rotations that put the marker set's beads on the measured markers.

    The free joints' intrinsic XYZ Euler angles (:data:`~stillcap.body.skeleton.EULER_LIMIT_SEQUENCE`,
    the angles ``limits_deg`` bounds) are fitted by least squares (``scipy.optimize.least_squares``,
    trust region with the limits as bounds, analytic Jacobian: turning joint ``j`` about the
    world axis ``u`` moves every point beyond it by ``u x (p - o_j)``) to

    - every seen marker: ``(model - measured) / marker_sigma_m``;
    - a weak prior per angle: ``(angle - clip(0, limits)) / (half the range, >= 5 deg)``, which
      only matters for what the markers leave open (see the module docstring).

    The start is built joint by joint from the root (:func:`_start_angles`: Kabsch where a
    frame has 2+ markers, the prior's favourite of the exact one-marker solutions otherwise);
    if some marker then still misses by more than 5 sigma, ``initial`` and the thesis's pose
    are tried as starts too and the best fit is kept. With ``robust`` a soft-L1 loss (scale
    5 sigma) keeps one wrong marker from bending the whole skeleton.

    Parameters
    ----------
    skeleton : Skeleton
    markerset : MarkerSet
    marker_positions : array_like, shape (n_markers, 3)
        Measured markers, metres, marker-set order; NaN for missing ones.
    root2world : array_like, shape (4, 4), optional
        The root's frame (puppet: the pelvis, fixed on the turntable axis); default rest.
    initial : Pose, optional
        Start instead of the thesis's pose.
    marker_sigma_m : float
        Expected marker error, metres.

    Returns
    -------
    PoseFit
    """
    t0 = time.perf_counter()
    pts = np.asarray(marker_positions, float)
    if pts.shape != (len(markerset), 3):
        raise ValueError(f"marker_positions must have shape ({len(markerset)}, 3), got {pts.shape}")
    r2w = skeleton.rest_root2world() if root2world is None else np.asarray(root2world, float)
    thesis = pose_from_markers(skeleton, markerset, pts, r2w)
    dirs = bone_directions(markerset, pts, r2w)
    n = skeleton.n_joints
    lim = skeleton.limits_deg
    lo = np.where(np.isnan(lim[..., 0]), -np.inf, lim[..., 0])
    hi = np.where(np.isnan(lim[..., 1]), np.inf, lim[..., 1])
    free = hi > lo  # (n, 3)
    centre = np.clip(0.0, lo, hi)
    width = np.where(np.isfinite(hi - lo), 0.5 * (hi - lo), 180.0)
    sd = np.maximum(width, 5.0)
    starts = [_start_angles(skeleton, markerset, pts, r2w, lo, hi, centre, sd)]
    for other in ((initial,) if initial is not None else ()) + (thesis,):
        a0 = np.clip(skeleton.limit_angles_deg(other.local_rotations), lo, hi)
        starts.append(np.where(np.isfinite(lo) & ~free, lo, a0))
    ang = starts[0]
    frames = markerset.bone_frames(skeleton)
    offs = markerset.offsets
    seen = np.all(np.isfinite(pts), axis=1)
    parents = skeleton.parents
    # chain[j]: joints whose rotation moves points of frame j (j and its ancestors)
    chain = np.zeros((n, n), bool)
    for j in range(n):
        k = j
        while k >= 0:
            chain[j, k] = True
            k = parents[k]
    pidx = np.argwhere(free)  # (n_params, 2): joint, axis
    mf = frames[seen]
    meas = pts[seen]

    def unpack(x):
        a = ang.copy()
        a[free] = x
        return a

    def model(x):
        a = unpack(x)
        Rx, Ry, Rz = _euler_matrices(a)
        local = Rx @ Ry @ Rz  # intrinsic XYZ
        j2w = forward_kinematics(skeleton, r2w, local)
        return a, Rx, Ry, j2w

    def residuals(x):
        a, _, _, j2w = model(x)
        m = np.einsum("nij,nj->ni", j2w[mf, :3, :3], offs[seen]) + j2w[mf, :3, 3]
        return np.concatenate([((m - meas) / marker_sigma_m).ravel(), ((a - centre) / sd)[free]])

    pj, pax = pidx[:, 0], pidx[:, 1]
    n_res = 3 * len(mf)
    prior_rows = n_res + np.arange(len(pidx))
    moves = chain[mf][:, pj].T  # (n_params, n_seen): parameter moves the marker
    k_scale = math.pi / 180.0 / marker_sigma_m

    def jacobian(x):
        a, Rx, Ry, j2w = model(x)
        m = np.einsum("nij,nj->ni", j2w[mf, :3, :3], offs[seen]) + j2w[mf, :3, 3]
        W = np.concatenate([r2w[None, :3, :3], j2w[:, :3, :3]])[parents[pj] + 1]  # parent world rotations
        # world axis of each Euler angle: x, then Rx y, then Rx Ry z (intrinsic XYZ)
        axes = np.where((pax == 0)[:, None], [1.0, 0.0, 0.0],
                        np.where((pax == 1)[:, None], Rx[pj][:, :, 1], (Rx[pj] @ Ry[pj])[:, :, 2]))
        u = np.einsum("pij,pj->pi", W, axes)
        d = np.cross(u[:, None, :], m[None] - j2w[pj, None, :3, 3]) * k_scale  # (n_params, n_seen, 3)
        J = np.zeros((n_res + len(pidx), len(pidx)))
        J[:n_res] = (d * moves[..., None]).reshape(len(pidx), n_res).T
        J[prior_rows, np.arange(len(pidx))] = 1.0 / sd[pj, pax]
        return J

    lb, ub = lo[free], hi[free]
    inner = (np.where(np.isfinite(lb), lb + 1e-9, lb), np.where(np.isfinite(ub), ub - 1e-9, ub))
    kw = dict(loss="soft_l1", f_scale=5.0) if robust else {}
    # tr_solver="exact": the dense trust-region solve (an SVD of the small Jacobian per step) is
    # 15 ms per fit against 22 ms with LSMR (~40 pure-Python iterations per step), and ends nearer
    # the optimum: on the 52 benchmark poses its joints are within 5.5 um of a fit run to 1e-12
    # tolerances, LSMR's within 36 um. It needs BLAS on one thread: on a busy machine OpenBLAS's
    # threads spin on these small matrices (225-240 ms per fit measured on 2 shared cores), hence
    # the threadpoolctl limit, which holds for this call only.
    # Tolerances 1e-6 instead of SciPy's 1e-8: the steps after them move the joints by at most
    # 5.5 um (see above; the fit's joint error is ~110 um) and cost ~40 % of the time.
    opts = dict(jac=jacobian, bounds=(lb, ub), x_scale=10.0, method="trf", tr_solver="exact",
                ftol=1e-6, xtol=1e-6, gtol=1e-6, **kw)
    best = None
    with threadpool_limits(1, user_api="blas"):
        for a0 in starts:  # the joint-by-joint start; the others only when it ends in a poor fit
            r = least_squares(residuals, np.clip(a0[free], *inner), **opts)
            if best is None or r.cost < best.cost:
                best = r
            if np.max(np.abs(best.fun[:3 * len(mf)]), initial=0.0) < 5.0:  # every marker within 5 sigma
                break
    a = unpack(best.x)
    local = Rotation.from_euler(EULER_LIMIT_SEQUENCE, a, degrees=True).as_matrix()
    pose = Pose(skeleton, r2w, local)
    res = np.full(len(markerset), np.nan)
    res[seen] = np.linalg.norm(markerset.positions(pose)[seen] - meas, axis=1)
    tres = np.full(len(markerset), np.nan)
    tres[seen] = np.linalg.norm(markerset.positions(thesis)[seen] - meas, axis=1)
    return PoseFit(pose, thesis, dirs, res, tres, bool(best.success), int(seen.sum()), time.perf_counter() - t0)
