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
(:attr:`SkeletonCalibration.rms_m`), predicts each bone's direction error in a pose fitted with
the calibrated skeleton from the joint fit's covariance (:attr:`SkeletonCalibration.direction_sd_deg`)
and names the bones over a limit with what would fix them (:func:`uncertain_bones`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap._blas import one_blas_thread
from stillcap.body._grouped_jacobian import grouped_jacobian
from stillcap.body.markerset import Marker, MarkerSet
from stillcap.body.puppet_calibrate_sd import direction_sd_in_captures, new_pose_direction_sd, weakly_posed_bones
from stillcap.body.puppet_pose import fit_pose, frame_status
from stillcap.body.skeleton import Pose, Skeleton

__all__ = ["SkeletonCalibration", "calibrate_skeleton", "uncertain_bones", "weakly_posed_bones"]


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
    direction_sd_deg : dict
        Bone (joint name) -> predicted RMS error of its direction in a new pose fitted with the
        calibrated skeleton, degrees: the joint fit's covariance of the body (bone scales and
        bead offsets together) carried through the fit of :data:`~stillcap.body.puppet_calibrate_sd.PROBE_POSES`
        probe poses with every joint anywhere within the template's limits, RMS over them
        (:func:`~stillcap.body.puppet_calibrate_sd.new_pose_direction_var`), for every bone whose
        parent frame carries beads; empty without further captures (the rest capture alone fixes
        no joint).
    direction_sd_captures_deg : dict
        The same carried through the calibration's own further captures' poses instead
        (:func:`~stillcap.body.puppet_calibrate_sd.direction_sd_in_captures`): the poses that
        fixed the body, so it misses what they leave open.
    weakly_posed : dict
        Bone -> what to add, for every bone whose new-pose error is over
        :data:`~stillcap.body.puppet_calibrate_sd.WEAK_POSE_RATIO` times its error in the
        captures' poses and could exceed the per-bone checks' tolerance: the captures do not bend
        the joints it hangs on enough to place them
        (:func:`~stillcap.body.puppet_calibrate_sd.weakly_posed_bones`).
    uncertain : dict
        Bone -> what to add, for every bone whose predicted direction error exceeds
        ``direction_limit_deg``.
    misfit : float
        The joint fit's chi-square of the beads per degree of freedom with ``marker_sigma_m``
        (NaN without further captures); above 1 it widens :attr:`direction_sd_deg`.
    rest_turn_deg : float
        How far the rest capture's root is turned about the vertical from the template's rest
        frame in the calibration, degrees (a puppet set on the turntable at another angle,
        signed): the stated turn, or the estimate where the beads reject the stated one.
    rest_turn_estimated_deg, rest_turn_sd_deg : float
        The joint fit's estimate of that turn and its 1-sigma uncertainty, degrees (NaN without
        the joint fit).
    rest_turn_stated : bool
        The calibration kept the stated turn (the estimate within :data:`REST_TURN_Z` sigmas of it).
    joint_converged : bool or None
        The joint fit whose answer is kept met SciPy's convergence tests (``ftol``/``xtol``/
        ``gtol``) before ``max_nfev`` (None: not run). False means the answer depends on where
        the fit stopped.
    """

    skeleton: Skeleton
    markerset: MarkerSet
    scales: np.ndarray
    rms_m: float
    per_pose_rms_m: list
    n_poses: int
    unfixed: dict = field(default_factory=dict)
    joint_evaluations: int | None = None
    direction_sd_deg: dict = field(default_factory=dict)
    uncertain: dict = field(default_factory=dict)
    misfit: float = float("nan")
    rest_turn_deg: float = 0.0
    rest_turn_estimated_deg: float = float("nan")
    rest_turn_sd_deg: float = float("nan")
    rest_turn_stated: bool = False
    joint_converged: bool | None = None
    direction_sd_captures_deg: dict = field(default_factory=dict)
    weakly_posed: dict = field(default_factory=dict)


def _rest_turn(template: Skeleton, markerset: MarkerSet, rest: np.ndarray) -> np.ndarray:
    """The rest capture's turn about the vertical (the skeleton's y axis, as a turntable turns):
    the angle that best carries the template's rest beads onto the measured ones, both centred
    (the Kabsch solution in the horizontal plane, closed form, any angle), as a matrix, shape
    (3, 3). The template's bead offsets and proportions differ from the puppet's by millimetres
    over a body of a few hundred, so this is a start for the joint fit, which refines the angle.
    Only the turn: a turn about all three axes left free traded against the hips' and the back's
    lengths (0.43 and 0.76 deg on the bones of two puppets whose rest pose was upright, against
    0.18 and 0.16 deg with none)."""
    model = markerset.positions(Pose.rest(template))
    ok = np.all(np.isfinite(rest), axis=1) & np.all(np.isfinite(model), axis=1)
    if ok.sum() < 3:
        return np.eye(3)
    a = rest[ok] - rest[ok].mean(axis=0)
    b = model[ok] - model[ok].mean(axis=0)
    return _turn_y(float(np.arctan2(np.sum(a[:, 0] * b[:, 2] - a[:, 2] * b[:, 0]),
                                    np.sum(a[:, 0] * b[:, 0] + a[:, 2] * b[:, 2]))))


def _turn_y(angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about the y axis (as scipy's ``Rotation.from_euler("y", angle_rad)``)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


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


@one_blas_thread
def calibrate_skeleton(rest_points, template: Skeleton, markerset: MarkerSet, pose_points=(),
                       marker_sigma_m: float = 0.2e-3, scale_sd: float = 0.3, offset_sd_m: float = 0.01,
                       iterations: int = 30, tol_m: float = 1e-6, name: str | None = None,
                       joint: bool = True, direction_limit_deg: float = 1.0,
                       noise_m=None, rest_turn_deg: float | None = 0.0) -> SkeletonCalibration:
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
        Expected 3D bead error per axis, metres, where ``noise_m`` gives none.
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
    direction_limit_deg : float
        A bone whose predicted direction error (:attr:`SkeletonCalibration.direction_sd_deg`)
        exceeds this is named in :attr:`SkeletonCalibration.uncertain` with the capture to add.
    noise_m : sequence of array_like, shape (n_markers,), optional
        Each bead's expected 3D error per axis in each capture (the rest capture first, then
        ``pose_points``' order), metres, as the photos show it
        (:attr:`~stillcap.body.puppet_checks.BeadNoise.sd_m`); NaN or missing entries take
        ``marker_sigma_m``. Without it every bead has ``marker_sigma_m``.
    rest_turn_deg : float or None
        The rest capture's turn about the vertical from the template's rest frame as the user
        states it, degrees (default 0: the puppet set facing the template's way, as
        ``docs/puppet.md`` asks). The joint fit also estimates the turn with its 1-sigma
        uncertainty (:attr:`SkeletonCalibration.rest_turn_estimated_deg`,
        :attr:`~SkeletonCalibration.rest_turn_sd_deg`); the stated turn is kept unless the
        estimate differs from it by more than :data:`REST_TURN_Z` sigmas (then the estimate is
        used and :attr:`~SkeletonCalibration.rest_turn_deg` says so). None: always the estimate.

    Returns
    -------
    SkeletonCalibration

    BLAS runs on one thread during the call (:func:`~stillcap._blas.one_blas_thread`): the joint
    fit's matrices are a few hundred wide, and on a busy machine OpenBLAS's threads made each SVD
    ~50x slower in CPU.
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
    all_points = [rest] + poses
    sigmas = _bead_sigmas(noise_m, len(all_points), nm, marker_sigma_m)
    # the rest capture need not face the template's way (a puppet set on the turntable at another
    # angle: turned 20 deg, its calibration was 19 deg off on the bones): its turn is estimated
    # and the alternation below works on the rest beads turned back; the joint fit frees it
    if rest_turn_deg is not None and not np.isfinite(rest_turn_deg):
        raise ValueError(f"rest_turn_deg must be a finite angle in degrees or None, got {rest_turn_deg}")
    turn0 = _rest_turn(template, markerset, rest)
    center0 = np.nanmean(rest, axis=0)
    rest_upright = (rest - center0) @ turn0 + center0
    frames = markerset.bone_frames(template)
    c = template.offsets.copy()
    c[template.root] = 0.0
    bones = [k for k in range(nj) if k != template.root and np.linalg.norm(c[k]) > 0]
    col_s = {k: i for i, k in enumerate(bones)}
    n_s = len(bones)
    paths = _paths(template)
    n_par = n_s + 3 * nm + 3 * len(all_points)

    def solve(rotations: list[np.ndarray]) -> np.ndarray:
        """(s, o, t per pose) by linear least squares given the joint world rotations of the
        first ``len(rotations)`` poses (the others' ``t`` stay 0)."""
        rows, rhs = [], []
        for p_i, (pts, W) in enumerate(zip([rest_upright] + poses, rotations)):
            for m in np.flatnonzero(np.all(np.isfinite(pts), axis=1)):
                w = 1.0 / sigmas[p_i][m]
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
        fits = [fit_pose(sk, ms, pts, marker_sigma_m=sg, root="free") for pts, sg in zip(poses, sigmas[1:])]
        rots += [f.pose.joint2world[:, :3, :3] for f in fits]
        x_new = solve(rots)
        sk, ms, s = build(x_new)
        moved = max(np.abs(x_new[n_s:] - x[n_s:]).max(), float(np.max(np.abs(x_new[:n_s] - x[:n_s]) *
                                                                         np.linalg.norm(c[bones], axis=1))))
        x = x_new
        if moved < tol_m:
            break
    joint_fit, unfixed, direction_sd, uncertain, misfit = None, {}, {}, {}, float("nan")
    captures_sd, weak = {}, {}
    turn_est = turn_sd = float("nan")
    turn_stated = False
    if joint:
        fits = [fit_pose(sk, ms, pts, marker_sigma_m=sg, root="free") for pts, sg in zip(poses, sigmas[1:])]
        ts = [center0 + turn0 @ (x[n_s + 3 * nm:n_s + 3 * nm + 3] - center0)] + [f.pose.root2world[:3, 3] for f in fits]
        rest_loc = np.tile(np.eye(3), (nj, 1, 1))
        rest_loc[template.root] = turn0
        locals_ = [rest_loc]
        for f in fits:
            loc = f.pose.local_rotations.copy()
            loc[sk.root] = f.pose.root2world[:3, :3] @ loc[sk.root]
            locals_.append(loc)
        fit_args = (template, markerset, all_points)
        out = _joint_fit(*fit_args, s, ms.offsets, ts, locals_, sigmas, scale_sd, offset_sd_m)
        if any(np.any(sg < COARSE_SIGMAS_M[-1]) for sg in sigmas):
            # beads sharper than the coarsest levels: fitted with each level of COARSE_SIGMAS_M in
            # turn (every bead's error at least that), then with their own from there, and the
            # better of that and the direct fit kept. From the template's start the beads sit
            # millimetres off, hundreds of their own sigmas, where the soft-L1 loss treats nearly
            # every bead as an outlier and the fit settles with some bones turned (seed 19 of
            # another_puppet, beads at 0.01-0.03 mm: the direct fit stalled at 1.5 mm RMS, its
            # bones 5.5 deg off; seed 18 with beads turned +-60 deg: after one level at 0.1 mm
            # still 3.5 mm RMS, 18.5 deg on the bones, with levels 1 and 0.25 mm 0.02 mm, 0.18 deg)
            start = (s, ms.offsets, ts, locals_)
            for level in COARSE_SIGMAS_M:
                coarse = [np.maximum(sg, level) for sg in sigmas]
                start = _joint_fit(*fit_args, *start, coarse, scale_sd, offset_sd_m)[:4]
            out2 = _joint_fit(*fit_args, *start, sigmas, scale_sd, offset_sd_m)
            if out2[4].cost < out[4].cost:
                out = out2
        turn_est, turn_sd = _turn_estimate(out, template.root, n_s + 3 * nm + 3)
        turn_stated = False
        if rest_turn_deg is not None and abs(_wrap_deg(turn_est - rest_turn_deg)) <= REST_TURN_Z * turn_sd:
            # the beads do not reject the stated turn: held there (a free turn is a nuisance the
            # rest capture fixes only through where its joints lie, a few tenths of a degree on
            # a puppet set as stated, and every bone's direction carries that error)
            held = [loc.copy() for loc in out[3]]
            held[0][template.root] = _turn_y(np.radians(rest_turn_deg))
            out = _joint_fit(*fit_args, out[0], out[1], out[2], held, sigmas, scale_sd, offset_sd_m,
                             turn_free=False)
            turn_stated = True
        s_j, beads_j, ts_j, locals_j, joint_fit, fitted_bones, _, (dir_sd, misfit) = out
        turn0 = locals_j[0][template.root]
        x = x.copy()
        for k, i in col_s.items():
            x[i] = s_j[k]
        x[n_s:n_s + 3 * nm] = beads_j.ravel()
        x[n_s + 3 * nm:n_s + 3 * nm + 3] = ts_j[0]
        sk, ms, s = build(x)
        unfixed = _unfixed_bones(template, frames, fitted_bones, joint_fit.jac, c, scale_sd)
        status = frame_status(template, markerset)
        shown = [k for k in dir_sd if status[template.names[template.parents[k]]] not in ("locked", "none")]
        captures_sd = {template.names[k]: float(np.degrees(dir_sd[k])) for k in shown}
        new_sd = new_pose_direction_sd(sk, c, frames, beads_j, bones, joint_fit.jac, misfit, sigmas)
        direction_sd = {template.names[k]: new_sd[k] for k in shown}
        uncertain = uncertain_bones(template, markerset, direction_sd, direction_limit_deg)
        weak = weakly_posed_bones(template, captures_sd, direction_sd)
    else:  # the root where the rest capture has it (the alternation worked on it turned back)
        x = x.copy()
        x[n_s + 3 * nm:n_s + 3 * nm + 3] = center0 + turn0 @ (x[n_s + 3 * nm:n_s + 3 * nm + 3] - center0)
        sk, ms, s = build(x)
    # how well the calibrated model explains every capture (in the joint fit's own poses when it
    # ran: a pose fitted again from the start can settle elsewhere, e.g. beads turned +-60 deg
    # round their bones, 3.6 mm RMS refitted against 0.03 mm in the joint fit)
    per = []
    sq = []
    for p_i, pts in enumerate(all_points):
        if p_i == 0:
            r2w = sk.rest_root2world()
            r2w[:3, :3] = turn0 @ r2w[:3, :3]
            model = ms.positions(Pose.rest(sk, r2w))
        elif joint_fit is not None:
            r2w = np.eye(4)
            r2w[:3, 3] = ts_j[p_i]
            model = ms.positions(Pose(sk, r2w, locals_j[p_i]))
        else:
            model = ms.positions(fit_pose(sk, ms, pts, marker_sigma_m=sigmas[p_i], root="free").pose)
        ok = np.all(np.isfinite(pts), axis=1)
        d = np.linalg.norm(model[ok] - pts[ok], axis=1)
        per.append(float(np.sqrt(np.mean(d ** 2))) if len(d) else float("nan"))
        sq.append(d ** 2)
    allsq = np.concatenate(sq)
    return SkeletonCalibration(sk, ms, s, float(np.sqrt(np.mean(allsq))) if len(allsq) else float("nan"), per,
                               len(all_points), unfixed,
                               None if joint_fit is None else int(joint_fit.nfev), direction_sd, uncertain,
                               misfit, float(np.degrees(np.arctan2(turn0[0, 2], turn0[0, 0]))),
                               turn_est, turn_sd, turn_stated,
                               None if joint_fit is None else bool(joint_fit.status > 0), captures_sd, weak)


#: :func:`calibrate_skeleton`: beads whose expected error is below the last level (metres) are
#: first fitted with every bead's error at least each level in turn, coarse to fine (a numerical
#: path for the joint fit, graduated as in graduated non-convexity; not a statement about the
#: beads). The first level is of the order of a template's bead misplacement on another puppet
#: (millimetres), the last a little above a sharp capture's bead noise.
COARSE_SIGMAS_M = (1.0e-3, 0.25e-3)

#: :func:`calibrate_skeleton`: the stated rest turn is kept unless the joint fit's estimate lies
#: more than this many of its own sigmas from it (two-sided normal, a 1e-3 chance that a puppet
#: set as stated is turned by the data instead: :data:`~stillcap.body.puppet_checks.FALSE_ALARM_P`).
REST_TURN_Z = 3.29


def _wrap_deg(a: float) -> float:
    """An angle in degrees wrapped to [-180, 180)."""
    return float((a + 180.0) % 360.0 - 180.0)


def _turn_estimate(out, root: int, col: int) -> tuple[float, float]:
    """The joint fit's rest turn about the vertical and its 1-sigma uncertainty, degrees: the
    ``col``-th unknown's variance from ``inv(J^T J)`` (residuals in sigmas), widened by the fit's
    misfit when above 1, as :func:`~stillcap.body.puppet_calibrate_sd.direction_sd_in_captures`
    widens the directions."""
    turn = out[3][0][root]
    res, misfit = out[4], out[7][1]
    J = res.jac.toarray() if hasattr(res.jac, "toarray") else np.asarray(res.jac)
    var = float(np.linalg.pinv(J.T @ J)[col, col]) * max(float(misfit) if np.isfinite(misfit) else 1.0, 1.0)
    return float(np.degrees(np.arctan2(turn[0, 2], turn[0, 0]))), float(np.degrees(np.sqrt(max(var, 0.0))))


def _bead_sigmas(noise_m, n_caps: int, nm: int, marker_sigma_m: float) -> list[np.ndarray]:
    """Each capture's per-bead expected error (``noise_m`` of :func:`calibrate_skeleton`), metres."""
    if not marker_sigma_m > 0:
        raise ValueError(f"marker_sigma_m must be > 0 metres, got {marker_sigma_m}")
    if noise_m is None:
        return [np.full(nm, float(marker_sigma_m)) for _ in range(n_caps)]
    if len(noise_m) != n_caps:
        raise ValueError(f"noise_m must give one array per capture ({n_caps}: the rest capture and each pose), "
                         f"got {len(noise_m)}")
    out = []
    for i, a in enumerate(noise_m):
        a = np.asarray(a, float)
        if a.shape != (nm,):
            raise ValueError(f"noise_m[{i}] must have shape ({nm},), got {a.shape}")
        if np.any(a <= 0):
            raise ValueError(f"noise_m[{i}] must be > 0 metres where given")
        out.append(np.where(np.isfinite(a), a, float(marker_sigma_m)))
    return out


def uncertain_bones(template: Skeleton, markerset: MarkerSet, direction_sd_deg: dict,
                    limit_deg: float = 1.0) -> dict[str, str]:
    """Bones whose predicted direction error exceeds ``limit_deg``, each with what would fix it.

    A bone's direction in a pose is its parent frame's orientation. A frame with one bead
    (``partial``: a forearm or shin of ``puppet-16``) turns freely about the line from its joint
    to the bead: no capture fixes that, a second bead does. A frame with two or more beads is
    fixed where its beads and the next joint are: bending that joint in a further capture
    places the joint, and with it the frame.
    """
    status = frame_status(template, markerset)
    out = {}
    for name, sd in direction_sd_deg.items():
        if sd <= limit_deg:
            continue
        parent = template.names[template.parents[template.index(name)]]
        if status[parent] == "partial":
            out[name] = (f"the {parent} -> {name} direction is uncertain ({sd:.1f} deg predicted, over "
                         f"{limit_deg:g}): {parent} carries one bead, so its twist about the line to it is open; "
                         f"no capture fixes that, a second bead on it does")
        else:
            out[name] = (f"the {parent} -> {name} direction is uncertain ({sd:.1f} deg predicted, over "
                         f"{limit_deg:g}): add a capture (--pose) with {name} bent well away from rest and from "
                         f"the other captures")
    return out


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
               root_t: list, local0: list, sigmas: list, scale_sd: float, offset_sd_m: float,
               loss_scale: float = 3.0, max_nfev: int = 200, turn_free: bool = True):
    """One nonlinear least-squares fit of every unknown together (see :func:`calibrate_skeleton`).

    Unknowns: the bone scales, the bead offsets in their bone frames, and per capture the root's
    position and (captures after the rest one) every joint's rotation. A joint free about all
    three axes (the root among them) turns by a rotation vector from its start rotation
    (``local0``, e.g. :func:`~stillcap.body.puppet_pose.fit_pose`'s), unbounded: the start's
    intrinsic XYZ Euler angles with the joint limits as bounds (as this fit had until issue 12)
    stalled near gimbal lock against a bound (seed 11 of ``another_puppet``: a shoulder at
    ``x = -90`` with ``y = 95`` where the truth has ``y = 76``, 0.8 deg on the bones against
    0.4 deg from the truth's start). The limits are the template's, a guide for fitting poses, not
    a fact about this puppet. A joint free about only some axes keeps Euler angles on those, within
    its limits. The rest capture's joints are all at rest: that fixes the gauge (where a bone
    frame's beads sit versus its rotation); its root turns by a rotation vector from its start
    (``local0[0]``'s root: the puppet set on the turntable at another angle) about the vertical
    (the skeleton's y axis) only, with no prior; ``turn_free=False`` holds it at ``local0[0]``'s
    (its unknown stays in the layout with no residual depending on it).
    ``local0``: one entry per capture, the rest capture's first. Residuals: every measured bead
    over ``marker_sigma_m``, the weak priors (scales about 1, offsets about the template's,
    rotations about their start with 180 deg), soft-L1 loss at ``loss_scale`` sigma. ``sigmas``: each
    capture's per-bead expected error, metres (:func:`_bead_sigmas`).
    ``scipy.optimize.least_squares`` with ``jac_sparsity``: a bead's residual depends only on the
    scales and rotations on its frame's path, its own offset and its capture's root, so finite
    differences need few evaluations.

    Returns ``(s, beads, root_t, local_rotations, result, bones, n_data, (direction_sd, misfit))``,
    ``local_rotations`` one per capture (the rest capture's: identity but its root's turn).
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix
    from scipy.spatial.transform import Rotation

    from stillcap.body.puppet_pose import _euler_matrices

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
    ball = np.flatnonzero(free.all(axis=1))  # joints turned by rotation vectors
    some = free.copy()
    some[ball] = False
    eidx = np.argwhere(some)  # (joint, axis) Euler angles of partly free joints
    n_v, n_e = 3 * len(ball), len(eidx)
    n_a = n_v + n_e
    n_s = len(bones)
    n_caps = len(all_points)
    # layout: scales | bead offsets | rest root t | rest root turn about y (rad) |
    # per further capture: t (3), rotation vectors (n_v), angles (n_e)
    o_b = n_s
    o_t0 = o_b + 3 * nm
    o_r0 = o_t0 + 3
    per = 3 + n_a
    o_caps = o_r0 + 1

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
    rest_turn = np.asarray(local0[0], float)[root]
    starts, a_start = [], []
    for p in range(1, n_caps):
        b, e, end = cap_slice(p)
        x0[b:e] = root_t[p]
        loc = np.asarray(local0[p], float)
        a = np.clip(template.limit_angles_deg(loc), lo, hi)
        if n_e:
            x0[e + n_v:end] = a[tuple(eidx.T)]
        starts.append(loc[ball])
        a_start.append(a)
    lower = np.full(n_par, -np.inf)
    upper = np.full(n_par, np.inf)
    lower[:n_s] = 0.05
    for p in range(1, n_caps):
        b, e, end = cap_slice(p)
        if n_e:
            lower[e + n_v:end], upper[e + n_v:end] = lo[tuple(eidx.T)], hi[tuple(eidx.T)]
    x0 = np.clip(x0, lower + 1e-9 * np.isfinite(lower), upper - 1e-9 * np.isfinite(upper))
    w = [1.0 / np.asarray(sg, float)[idx, None] for sg, idx in zip(sigmas, seen)]
    n_data = 3 * sum(len(s) for s in seen)
    n_prior = n_s + 3 * nm + n_a * (n_caps - 1)
    prior_b = markerset.offsets.ravel()
    prior_a = np.concatenate([np.full(n_v, np.pi), np.full(n_e, 180.0)])  # rad for vectors, deg for angles

    def offsets_of(x):
        off = c.copy()
        off[bones] = c[bones] * x[:n_s, None]
        return off

    def locals_of(x, p):
        """Local rotations of capture ``p`` (0: the rest capture)."""
        if p == 0:
            local = np.tile(np.eye(3), (nj, 1, 1))
            local[root] = (_turn_y(x[o_r0]) if turn_free else np.eye(3)) @ rest_turn
            return local
        _, e, end = cap_slice(p)
        a = a_start[p - 1].copy()
        if n_e:
            a[tuple(eidx.T)] = x[e + n_v:end]
        Rx, Ry, Rz = _euler_matrices(a)
        local = Rx @ Ry @ Rz
        if n_v:
            local[ball] = starts[p - 1] @ Rotation.from_rotvec(x[e:e + n_v].reshape(-1, 3)).as_matrix()
        return local

    def residuals(x):
        off = offsets_of(x)
        beads = x[o_b:o_t0].reshape(nm, 3)
        out = np.empty(n_data + n_prior)
        r = 0
        for p in range(n_caps):
            if p == 0:
                local = locals_of(x, 0)
                t = x[o_t0:o_t0 + 3]
            else:
                b, e, end = cap_slice(p)
                t = x[b:e]
                local = locals_of(x, p)
            r2w = np.eye(4)
            r2w[:3, 3] = t
            j2w = _fk(off, local, r2w)
            idx = seen[p]
            model = np.einsum("nij,nj->ni", j2w[frames[idx], :3, :3], beads[idx]) + j2w[frames[idx], :3, 3]
            out[r:r + 3 * len(idx)] = ((model - all_points[p][idx]) * w[p]).ravel()
            r += 3 * len(idx)
        out[r:r + n_s] = (x[:n_s] - 1.0) / scale_sd
        r += n_s
        out[r:r + 3 * nm] = (x[o_b:o_t0] - prior_b) / offset_sd_m
        r += 3 * nm
        for p in range(1, n_caps):
            b, e, end = cap_slice(p)
            start = np.zeros(n_a)
            if n_e:
                start[n_v:] = a_start[p - 1][tuple(eidx.T)]
            out[r:r + n_a] = (x[e:end] - start) / prior_a
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

    # the joint of each rotation parameter, in the layout's order
    a_joint = np.concatenate([np.repeat(ball, 3), eidx[:, 0]]).astype(int) if n_a else np.zeros(0, int)
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
                S[rows, o_t0:o_r0 + int(turn_free)] = 1
            else:
                b, e, end = cap_slice(p)
                S[rows, b:e] = 1
                for q, j in enumerate(a_joint):
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
    # the exact trust-region solver on a dense Jacobian (a few hundred unknowns): with
    # ``jac_sparsity`` SciPy solves each step by LSMR, inexactly, and on this ill-conditioned
    # problem (bead noise 0.01-0.1 mm against priors of 10 mm and 180 deg) every fit stopped at
    # max_nfev unconverged, its answer depending on the path (seed 12 of condition 1: 0.42 deg on
    # the bones from the coarse levels, 0.16 without); exact steps converge in 5-70 iterations
    res = least_squares(residuals, x0, jac=grouped_jacobian(residuals, S.tocsc(), lower, upper),
                        bounds=(lower, upper), loss="soft_l1", f_scale=loss_scale, x_scale="jac", method="trf",
                        tr_solver="exact", max_nfev=max_nfev)
    x = res.x
    s = np.ones(nj)
    s[bones] = x[:n_s]
    beads = x[o_b:o_t0].reshape(nm, 3)
    ts = [x[o_t0:o_t0 + 3]] + [x[cap_slice(p)[0]:cap_slice(p)[1]] for p in range(1, n_caps)]
    local_rotations = [locals_of(x, p) for p in range(n_caps)]
    return s, beads, ts, local_rotations, res, bones, n_data, direction_sd_in_captures(
        res, n_data, lambda xx, p: _fk(offsets_of(xx), locals_of(xx, p), np.eye(4)), cap_slice, n_caps, bones,
        template, c, n_v, np.cumsum([0] + [3 * len(s_) for s_ in seen]), o_t0, n_data + n_s + 3 * nm, n_a,
        [{k for k in bones if set(np.flatnonzero(frames == parents[k])) <= set(s_.tolist())} for s_ in seen])
