"""A puppet's own skeleton from captures of it: bone lengths and bead offsets
(``stillcap puppet calibrate-skeleton``), as the hand's personalisation does for hands.

Model: every joint's rest offset is its template's times a scale ``s_k`` (the bone's direction at
rest stays the template's: the T-pose), every bead's offset ``o_m`` in its bone frame is free.
In a pose with joint world rotations ``W`` and root position ``t``, a bead sits at::

    p_m = t + sum_{k on the path root -> frame(m)} W_parent(k) (s_k c_k) + W_frame(m) o_m

which is linear in ``(s, o, t)`` once the rotations are known. :func:`calibrate_skeleton`
alternates: the rotations of every pose by :func:`~stillcap.body.puppet_pose.fit_pose` (the
rest pose's are the identity), then ``(s, o, t)`` by linear least squares over all poses. The
alternation converges slowly (coupled unknowns moved one block at a time), so it only starts
:func:`_joint_fit`: one nonlinear least-squares fit of the scales, offsets and every capture's
pose together, which then names the bones the captures leave open (:func:`_unfixed_bones`).

What the captures fix: the rest pose alone places every bead, but not where along its bone a
joint lies between beads (a joint moved along the bone with its beads' offsets moved back
explains the rest pose equally well); a weak prior then keeps the template's proportions
(``scale_sd``, ``offset_sd_m``). Each further capture in a pose with bent joints fixes the
joints where the beads turn about them. The result says how well the beads fit
(:attr:`SkeletonCalibration.rms_m`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap.body.markerset import Marker, MarkerSet
from stillcap.body.puppet_pose import fit_pose
from stillcap.body.skeleton import Pose, Skeleton

__all__ = ["SkeletonCalibration", "calibrate_skeleton"]


@dataclass(eq=False)
class SkeletonCalibration:
    """Result of :func:`calibrate_skeleton`.

    Attributes
    ----------
    skeleton : Skeleton
        The template's joints, names and limits with the estimated rest offsets (the root's
        offset: its position in the rest capture).
    markerset : MarkerSet
        The template's beads, colours and rules with the estimated offsets.
    scales : ndarray, shape (n_joints,)
        Each bone's length over the template's (1 for the root and zero-length bones).
    rms_m : float
        RMS distance of the measured beads from the calibrated model's, over all captures, metres.
    per_pose_rms_m : list of float
    n_poses : int
    unfixed : dict
        Bone (joint name) -> what the captures lack to fix its length (see :func:`_unfixed_bones`);
        empty when every bone's length is fixed.
    joint_evaluations : int or None
        Residual evaluations of the joint fit (None: not run, e.g. a rest capture alone).
    """

    skeleton: Skeleton
    markerset: MarkerSet
    scales: np.ndarray
    rms_m: float
    per_pose_rms_m: list
    n_poses: int
    unfixed: dict = field(default_factory=dict)
    joint_evaluations: int | None = None


def _paths(skeleton: Skeleton) -> list[list[int]]:
    """For each joint: the non-root joints on the path from the root to it (inclusive)."""
    out = []
    for j in range(skeleton.n_joints):
        path, k = [], j
        while k >= 0 and k != skeleton.root:
            path.append(k)
            k = skeleton.parents[k]
        out.append(path[::-1])
    return out


def calibrate_skeleton(rest_points, template: Skeleton, markerset: MarkerSet, pose_points=(),
                       marker_sigma_m: float = 0.2e-3, scale_sd: float = 0.3, offset_sd_m: float = 0.01,
                       iterations: int = 30, tol_m: float = 1e-6, name: str | None = None,
                       joint: bool = True) -> SkeletonCalibration:
    """Estimate bone lengths and bead offsets (see the module docstring).

    Parameters
    ----------
    rest_points : array_like, shape (n_markers, 3)
        3D beads of the puppet in its rest pose (every joint at rest, the root upright), metres,
        marker-set order, NaN where unseen.
    template : Skeleton
        Joint names, parents, limits and rest directions (e.g. the built-in puppet).
    markerset : MarkerSet
        Which bead is on which bone, colours, rules; its offsets start the estimate.
    pose_points : sequence of array_like, shape (n_markers, 3)
        3D beads of further captures in other poses (optional; they fix the joints).
    marker_sigma_m : float
        Expected 3D bead error, metres.
    scale_sd, offset_sd_m : float
        The weak prior: bone scales about 1, bead offsets about the template's (metres).
    iterations : int
        Most alternations of pose fits and the linear solve (with further poses); they converge
        slowly (on the studio's varied puppets, 4 poses: bone directions 1.5 deg RMS after 6,
        0.7 deg after 20), so they stop only when no offset moves by more than ``tol_m``.
    tol_m : float
        Convergence: largest change of a bead offset or bone length in one alternation, metres.
    name : str, optional
        Name of the calibrated skeleton.
    joint : bool
        Finish with the joint fit (:func:`_joint_fit`) and report what stays open; False keeps
        the alternation's answer alone.

    Returns
    -------
    SkeletonCalibration
    """
    markerset.check_skeleton(template)
    nm, nj = len(markerset), template.n_joints
    rest = np.asarray(rest_points, float)
    if rest.shape != (nm, 3):
        raise ValueError(f"rest_points must have shape ({nm}, 3), got {rest.shape}")
    poses = [np.asarray(p, float) for p in pose_points]
    for i, p in enumerate(poses):
        if p.shape != (nm, 3):
            raise ValueError(f"pose_points[{i}] must have shape ({nm}, 3), got {p.shape}")
    if np.all(np.isfinite(rest), axis=1).sum() < 3:
        raise ValueError("the rest capture needs at least 3 recovered beads to calibrate a skeleton")
    frames = markerset.bone_frames(template)
    c = template.offsets.copy()
    c[template.root] = 0.0
    bones = [k for k in range(nj) if k != template.root and np.linalg.norm(c[k]) > 0]
    col_s = {k: i for i, k in enumerate(bones)}
    n_s = len(bones)
    paths = _paths(template)
    all_points = [rest] + poses
    n_par = n_s + 3 * nm + 3 * len(all_points)

    def solve(rotations: list[np.ndarray]) -> np.ndarray:
        """(s, o, t per pose) by linear least squares given the joint world rotations of the
        first ``len(rotations)`` poses (the others' ``t`` stay 0)."""
        rows, rhs = [], []
        w = 1.0 / marker_sigma_m
        for p_i, (pts, W) in enumerate(zip(all_points, rotations)):
            for m in np.flatnonzero(np.all(np.isfinite(pts), axis=1)):
                f = frames[m]
                A = np.zeros((3, n_par))
                for k in paths[f]:
                    if k in col_s:
                        A[:, col_s[k]] = W[template.parents[k]] @ c[k]
                A[:, n_s + 3 * m:n_s + 3 * m + 3] = W[f]
                A[:, n_s + 3 * nm + 3 * p_i:n_s + 3 * nm + 3 * p_i + 3] = np.eye(3)
                rows.append(A * w)
                rhs.append(pts[m] * w)
        # the weak prior
        n_t = 3 * (len(all_points) - len(rotations))  # poses not yet used: their t held at 0
        P = np.zeros((n_s + 3 * nm + n_t, n_par))
        P[:n_s, :n_s] = np.eye(n_s) / scale_sd
        P[n_s:n_s + 3 * nm, n_s:n_s + 3 * nm] = np.eye(3 * nm) / offset_sd_m
        if n_t:
            P[n_s + 3 * nm:, n_par - n_t:] = np.eye(n_t)
        prior_rhs = np.concatenate([np.ones(n_s) / scale_sd, markerset.offsets.ravel() / offset_sd_m, np.zeros(n_t)])
        A = np.vstack(rows + [P])
        b = np.concatenate(rhs + [prior_rhs])
        return np.linalg.lstsq(A, b, rcond=None)[0]

    def build(x: np.ndarray) -> tuple[Skeleton, MarkerSet, np.ndarray]:
        s = np.ones(nj)
        for k, i in col_s.items():
            s[k] = x[i]
        off = c * s[:, None]
        off[template.root] = x[n_s + 3 * nm:n_s + 3 * nm + 3]  # the root where the rest capture has it
        sk = template.with_offsets(off, name=name or f"{template.name}-calibrated")
        beads = x[n_s:n_s + 3 * nm].reshape(nm, 3)
        ms = MarkerSet(tuple(Marker(mk.name, mk.bone, o, mk.hsb, mk.diameter) for mk, o in zip(markerset.markers, beads)),
                       markerset.rules, markerset.name, sk.name, "<calibrated>")
        return sk, ms, s

    eye = np.tile(np.eye(3), (nj, 1, 1))
    x = solve([eye])  # the rest pose alone first
    sk, ms, s = build(x)
    fits = []
    for _ in range(iterations if poses else 0):
        rots = [eye]
        fits = [fit_pose(sk, ms, pts, marker_sigma_m=marker_sigma_m, root="free") for pts in poses]
        rots += [f.pose.joint2world[:, :3, :3] for f in fits]
        x_new = solve(rots)
        sk, ms, s = build(x_new)
        moved = max(np.abs(x_new[n_s:] - x[n_s:]).max(), float(np.max(np.abs(x_new[:n_s] - x[:n_s]) *
                                                                         np.linalg.norm(c[bones], axis=1))))
        x = x_new
        if moved < tol_m:
            break
    joint_fit, unfixed = None, {}
    if joint:
        fits = [fit_pose(sk, ms, pts, marker_sigma_m=marker_sigma_m, root="free") for pts in poses]
        ts = [x[n_s + 3 * nm:n_s + 3 * nm + 3]] + [f.pose.root2world[:3, 3] for f in fits]
        angles = [sk.limit_angles_deg(f.pose.local_rotations) for f in fits]
        s_j, beads_j, ts_j, _, joint_fit, fitted_bones, _ = _joint_fit(template, markerset, all_points, s, ms.offsets,
                                                                    ts, angles, marker_sigma_m, scale_sd,
                                                                    offset_sd_m)
        x = x.copy()
        for k, i in col_s.items():
            x[i] = s_j[k]
        x[n_s:n_s + 3 * nm] = beads_j.ravel()
        x[n_s + 3 * nm:n_s + 3 * nm + 3] = ts_j[0]
        sk, ms, s = build(x)
        unfixed = _unfixed_bones(template, frames, fitted_bones, joint_fit.jac, c, scale_sd)
    # how well the calibrated model explains every capture
    per = []
    sq = []
    for p_i, pts in enumerate(all_points):
        if p_i == 0:
            model = ms.positions(Pose.rest(sk))
        else:
            model = ms.positions(fit_pose(sk, ms, pts, marker_sigma_m=marker_sigma_m, root="free").pose)
        ok = np.all(np.isfinite(pts), axis=1)
        d = np.linalg.norm(model[ok] - pts[ok], axis=1)
        per.append(float(np.sqrt(np.mean(d ** 2))) if len(d) else float("nan"))
        sq.append(d ** 2)
    allsq = np.concatenate(sq)
    return SkeletonCalibration(sk, ms, s, float(np.sqrt(np.mean(allsq))) if len(allsq) else float("nan"), per,
                               len(all_points), unfixed,
                               None if joint_fit is None else int(joint_fit.nfev))


#: A bone counts as fixed by the captures when its length's 1-sigma uncertainty from the joint
#: fit's information (the captures and the weak prior together) is below this fraction of the
#: prior's alone (``scale_sd`` times its length): a ratio, so it does not hang on the stated
#: bead noise.
FIXED_SD_RATIO = 0.5


def _unfixed_bones(template: Skeleton, frames: np.ndarray, bones: list[int], jac, c: np.ndarray,
                   scale_sd: float) -> dict[str, str]:
    """Which bones' lengths the captures leave open, and what would fix each.

    The scales' covariance is read from the joint fit's Jacobian (``inv(J^T J)``, the residuals
    being in sigmas); a bone whose length's sd exceeds :data:`FIXED_LENGTH_SD_M` is open. Joint
    ``k``'s offset from its parent is fixed by beads that turn about ``k``: beads on ``k``'s
    frame or beyond it, in a capture where ``k`` is bent. Without such beads no pose fixes it.
    """
    J = jac.toarray() if hasattr(jac, "toarray") else np.asarray(jac)
    H = J.T @ J
    try:
        cov = np.linalg.pinv(H)
    except np.linalg.LinAlgError:  # pragma: no cover - pinv by SVD
        return {}
    out = {}
    parents = template.parents
    for i, k in enumerate(bones):
        sd = float(np.sqrt(max(cov[i, i], 0.0))) * float(np.linalg.norm(c[k]))
        if sd <= FIXED_SD_RATIO * scale_sd * float(np.linalg.norm(c[k])):
            continue
        beyond = []
        for f in set(frames.tolist()):
            j = f
            while j >= 0:
                if j == k:
                    beyond.append(f)
                    break
                j = parents[j]
        name, parent = template.names[k], template.names[parents[k]]
        if beyond:
            out[name] = (f"the {parent} -> {name} length is open ({sd * 1e3:.1f} mm 1-sigma): add a capture (--pose) "
                         f"with {name} bent well away from rest, so the beads beyond it turn about it")
        else:
            out[name] = (f"the {parent} -> {name} length is open ({sd * 1e3:.1f} mm 1-sigma): no bead lies on "
                         f"{name}'s side, so no pose fixes it; it keeps the template's proportion")
    return out


def _joint_fit(template: Skeleton, markerset: MarkerSet, all_points: list, s0: np.ndarray, beads0: np.ndarray,
               root_t: list, angles0: list, marker_sigma_m: float, scale_sd: float, offset_sd_m: float,
               loss_scale: float = 3.0, max_nfev: int = 200):
    """One nonlinear least-squares fit of every unknown together (see :func:`calibrate_skeleton`).

    Unknowns: the bone scales, the bead offsets in their bone frames, and per capture the root's
    position and (captures after the rest one) the root's rotation and the free joints' intrinsic
    XYZ Euler angles (degrees, as :func:`~stillcap.body.puppet_pose.fit_pose`'s). The rest capture's
    joints are all at rest and its root upright: that fixes the gauge (where a bone frame's
    beads sit versus its rotation). Residuals: every measured bead over ``marker_sigma_m``, the
    weak priors (scales about 1, offsets about the template's, angles about their start with
    180 deg), soft-L1 loss at ``loss_scale`` sigma. ``scipy.optimize.least_squares`` with
    ``jac_sparsity``: a bead's residual depends only on the scales and angles on its frame's
    path, its own offset and its capture's root, so finite differences need few evaluations.

    Returns ``(s, beads, root_t, angles, result)``.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    from stillcap.body.puppet_pose import _euler_matrices
    from stillcap.body.skeleton import forward_kinematics

    nm, nj = len(markerset), template.n_joints
    frames = markerset.bone_frames(template)
    c = template.offsets.copy()
    c[template.root] = 0.0
    root = template.root
    bones = [k for k in range(nj) if k != root and np.linalg.norm(c[k]) > 0]
    lim = template.limits_deg
    lo = np.where(np.isnan(lim[..., 0]), -np.inf, lim[..., 0])
    hi = np.where(np.isnan(lim[..., 1]), np.inf, lim[..., 1])
    lo[root], hi[root] = -np.inf, np.inf
    free = hi > lo
    pidx = np.argwhere(free)
    n_a = len(pidx)
    n_s = len(bones)
    n_caps = len(all_points)
    # layout: scales | bead offsets | rest root t | per further capture: t (3), angles (n_a)
    o_b = n_s
    o_t0 = o_b + 3 * nm
    per = 3 + n_a
    o_caps = o_t0 + 3

    def cap_slice(p):
        b = o_caps + per * (p - 1)
        return b, b + 3, b + per

    n_par = o_caps + per * (n_caps - 1)
    seen = [np.flatnonzero(np.all(np.isfinite(pts), axis=1)) for pts in all_points]
    # which joints' parameters move frame f: the frame and its ancestors
    chain = []
    for f in range(nj):
        path, k = [], f
        while k >= 0:
            path.append(k)
            k = template.parents[k]
        chain.append(set(path))
    x0 = np.zeros(n_par)
    x0[:n_s] = s0[bones]
    x0[o_b:o_t0] = beads0.ravel()
    x0[o_t0:o_t0 + 3] = root_t[0]
    a_start = []
    for p in range(1, n_caps):
        b, e, end = cap_slice(p)
        x0[b:e] = root_t[p]
        a = np.clip(angles0[p - 1], lo, hi)
        x0[e:end] = a[free]
        a_start.append(a)
    lower = np.full(n_par, -np.inf)
    upper = np.full(n_par, np.inf)
    lower[:n_s] = 0.05
    for p in range(1, n_caps):
        b, e, end = cap_slice(p)
        lower[e:end], upper[e:end] = lo[free], hi[free]
    x0 = np.clip(x0, lower + 1e-9 * np.isfinite(lower), upper - 1e-9 * np.isfinite(upper))
    w = 1.0 / marker_sigma_m
    n_data = 3 * sum(len(s) for s in seen)
    n_prior = n_s + 3 * nm + n_a * (n_caps - 1)
    prior_b = markerset.offsets.ravel()

    def offsets_of(x):
        off = c.copy()
        off[bones] = c[bones] * x[:n_s, None]
        return off

    def residuals(x):
        off = offsets_of(x)
        beads = x[o_b:o_t0].reshape(nm, 3)
        out = np.empty(n_data + n_prior)
        r = 0
        for p in range(n_caps):
            if p == 0:
                local = np.tile(np.eye(3), (nj, 1, 1))
                t = x[o_t0:o_t0 + 3]
            else:
                b, e, end = cap_slice(p)
                t = x[b:e]
                a = a_start[p - 1].copy()
                a[free] = x[e:end]
                Rx, Ry, Rz = _euler_matrices(a)
                local = Rx @ Ry @ Rz
            r2w = np.eye(4)
            r2w[:3, 3] = t
            j2w = _fk(off, local, r2w)
            idx = seen[p]
            model = np.einsum("nij,nj->ni", j2w[frames[idx], :3, :3], beads[idx]) + j2w[frames[idx], :3, 3]
            out[r:r + 3 * len(idx)] = ((model - all_points[p][idx]) * w).ravel()
            r += 3 * len(idx)
        out[r:r + n_s] = (x[:n_s] - 1.0) / scale_sd
        r += n_s
        out[r:r + 3 * nm] = (x[o_b:o_t0] - prior_b) / offset_sd_m
        r += 3 * nm
        for p in range(1, n_caps):
            b, e, end = cap_slice(p)
            out[r:r + n_a] = (x[e:end] - a_start[p - 1][free]) / 180.0
            r += n_a
        return out

    parents = template.parents
    order = template.depth_first

    def _fk(off, local, r2w):
        # forward kinematics with these offsets (Skeleton.with_offsets would validate a new
        # skeleton at every evaluation)
        out = np.empty((nj, 4, 4))
        for i in order:
            m = np.eye(4)
            m[:3, :3] = local[i]
            if parents[i] < 0:
                out[i] = r2w @ m
            else:
                m[:3, 3] = off[i]
                out[i] = out[parents[i]] @ m
        return out

    S = lil_matrix((n_data + n_prior, n_par), dtype=int)
    r = 0
    for p in range(n_caps):
        for m in seen[p]:
            f = frames[m]
            rows = slice(r, r + 3)
            for i, k in enumerate(bones):
                if k in chain[f]:
                    S[rows, i] = 1
            S[rows, o_b + 3 * m:o_b + 3 * m + 3] = 1
            if p == 0:
                S[rows, o_t0:o_t0 + 3] = 1
            else:
                b, e, end = cap_slice(p)
                S[rows, b:e] = 1
                for q, (j, _) in enumerate(pidx):
                    if j in chain[f]:
                        S[rows, e + q] = 1
            r += 3
    for i in range(n_s):
        S[r + i, i] = 1
    r += n_s
    for i in range(3 * nm):
        S[r + i, o_b + i] = 1
    r += 3 * nm
    for p in range(1, n_caps):
        b, e, end = cap_slice(p)
        for q in range(n_a):
            S[r + q, e + q] = 1
        r += n_a
    res = least_squares(residuals, x0, jac_sparsity=S.tocsr(), bounds=(lower, upper), loss="soft_l1",
                        f_scale=loss_scale, x_scale="jac", method="trf", max_nfev=max_nfev)
    x = res.x
    s = np.ones(nj)
    s[bones] = x[:n_s]
    beads = x[o_b:o_t0].reshape(nm, 3)
    ts = [x[o_t0:o_t0 + 3]] + [x[cap_slice(p)[0]:cap_slice(p)[1]] for p in range(1, n_caps)]
    angles = []
    for p in range(1, n_caps):
        a = a_start[p - 1].copy()
        a[free] = x[cap_slice(p)[1]:cap_slice(p)[2]]
        angles.append(a)
    return s, beads, ts, angles, res, bones, n_data
