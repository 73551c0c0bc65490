"""A puppet's own skeleton from captures of it: bone lengths and bead offsets
(``stillcap puppet calibrate-skeleton``), as the hand's personalisation does for hands.

Model: every joint's rest offset is its template's times a scale ``s_k`` (the bone's direction at
rest stays the template's: the T-pose), every bead's offset ``o_m`` in its bone frame is free.
In a pose with joint world rotations ``W`` and root position ``t``, a bead sits at::

    p_m = t + sum_{k on the path root -> frame(m)} W_parent(k) (s_k c_k) + W_frame(m) o_m

which is linear in ``(s, o, t)`` once the rotations are known. :func:`calibrate_skeleton`
alternates: the rotations of every pose by :func:`~stillcap.body.puppet_pose.fit_pose` (the
rest pose's are the identity), then ``(s, o, t)`` by linear least squares over all poses.

What the captures fix: the rest pose alone places every bead, but not where along its bone a
joint lies between beads (a joint moved along the bone with its beads' offsets moved back
explains the rest pose equally well); a weak prior then keeps the template's proportions
(``scale_sd``, ``offset_sd_m``). Each further capture in a pose with bent joints fixes the
joints where the beads turn about them. The result says how well the beads fit
(:attr:`SkeletonCalibration.rms_m`).
"""
from __future__ import annotations

from dataclasses import dataclass

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
    """

    skeleton: Skeleton
    markerset: MarkerSet
    scales: np.ndarray
    rms_m: float
    per_pose_rms_m: list
    n_poses: int


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
                       iterations: int = 30, tol_m: float = 1e-6, name: str | None = None) -> SkeletonCalibration:
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
    for _ in range(iterations if poses else 0):
        rots = [eye]
        for pts in poses:
            fit = fit_pose(sk, ms, pts, marker_sigma_m=marker_sigma_m, root="free")
            rots.append(fit.pose.joint2world[:, :3, :3])
        x_new = solve(rots)
        sk, ms, s = build(x_new)
        moved = max(np.abs(x_new[n_s:] - x[n_s:]).max(), float(np.max(np.abs(x_new[:n_s] - x[:n_s]) *
                                                                         np.linalg.norm(c[bones], axis=1))))
        x = x_new
        if moved < tol_m:
            break
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
                               len(all_points))
