"""The hand model adapted to the person (issue 12, part 2): every bone's length and direction
(per phalanx, the knuckles' splay, the thumb's axis) and every marker's place on its bone (its
height over the skin included), estimated from the labelled markers of a capture together with
the hand's poses.

:func:`adapt_hand_model` is one regularised least-squares problem over all the flashes given:
per flash the root pose and the 21 joint angles (as :func:`~stillcap.body.hand.fit_hand`), and
shared by all flashes

- the size of the back-of-hand triangle (one factor: without a known pose the three markers
  define the hand frame, so their shape is the model's and only its size is free), and with
  ``back_sigma_m`` (a calibration: a flash of known angles defines the frame by the bones) each
  back marker's own place;
- the offset (3D) of every joint from its parent: per phalanx lengths, the knuckles' places on
  the palm (splay) and the thumb's direction (its axis);
- the offset (3D) of every digit marker on its bone: its height and place along the bone.

Each shape parameter has a Gaussian prior centred on the model given (``joint_sigma`` of the
bone's length plus 2 mm per component, ``marker_sigma_m`` per component for markers): what the
poses in the capture do not fix (a joint that never bends, a point along a hinge's axis) stays
near the model, what they fix follows the markers. The marker residuals use a soft-L1 loss so
that a wrong label of a first labelling pass bends the model little.

:func:`label_and_adapt` is the labelling the pipeline uses: label with the model scaled to the
hand's size and wider gates (:func:`~stillcap.body.hand_label.label_hand_markers`), adapt the
model to the labelled flashes, label again with the adapted model and the normal gates (scaled
with the hand's size).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from stillcap._blas import one_blas_thread
from stillcap._checks import as_array
from stillcap.body.hand import BACK_MARKERS, DIGITS, hand_dofs
from stillcap.body.kinematics import rigid_alignment
from stillcap.body.markerset import Marker, MarkerSet
from stillcap.body.skeleton import Joint, Pose, Skeleton

__all__ = ["HandAdaptation", "adapt_hand_model", "label_and_adapt", "ADAPT_GATE_FACTOR"]

#: The first labelling pass's assignment gate relative to the normal one: the model is not yet
#: this hand's, so its markers may lie farther from their points.
ADAPT_GATE_FACTOR = 1.75
#: Assumed noise of a labelled 3D marker (m) for the weights of the adaptation's residuals.
NOISE_M = 0.0005


@dataclass(eq=False)
class HandAdaptation:
    """Result of :func:`adapt_hand_model`.

    Attributes
    ----------
    skeleton, markerset : Skeleton, MarkerSet
        The adapted hand.
    poses : list of Pose
        One per flash given (of :attr:`skeleton`).
    residuals : ndarray, shape (n_flashes, n_markers)
        Fitted-to-measured marker distance (m), NaN where unseen.
    rms : float
        RMS of the residuals (m).
    n_flashes : int
    success : bool
    message : str
    joint_cov, marker_cov : ndarray, shape (n_joints, 3, 3) and (n_markers, 3, 3)
        Covariance (m^2) of every joint offset and every marker offset of the adapted model
        (zero for components held), from the solution's Jacobian (the Gauss-Newton
        approximation, priors included), the data's rows weighed down by their reduced
        chi-square when that exceeds 1 (the noise was larger than ``noise_m``): a parameter the
        data do not fix keeps its prior's spread, never more.
    joint_prior_z, marker_prior_z : ndarray, shape (n_joints,) and (n_markers,)
        Largest change of a component from the model started from, in its prior's sigmas (a
        model that had to move far from the template to fit: a pose that is not what was stated).
    joint_prior_sigma : ndarray, shape (n_joints,)
        The prior's spread (m) of each component of every joint offset (0 for the root).
    marker_prior_sigma : float
        The prior's spread (m) of each component of every digit marker's offset.
    chi2_scale : float
        The data's reduced chi-square when above 1 (else 1): the data's weight in the
        covariance is divided by it (the priors keep theirs).
    cost : float
        The solution's objective: the sum of the loss over every residual row (data, priors,
        angle pull; for the linear loss the sum of squares), SciPy's ``2 * cost``.
    """

    skeleton: Skeleton
    markerset: MarkerSet
    poses: list
    residuals: np.ndarray
    rms: float
    n_flashes: int
    success: bool
    message: str = ""
    joint_cov: np.ndarray | None = None
    marker_cov: np.ndarray | None = None
    joint_prior_z: np.ndarray | None = None
    marker_prior_z: np.ndarray | None = None
    joint_prior_sigma: np.ndarray | None = None
    marker_prior_sigma: float | None = None
    chi2_scale: float = 1.0
    cost: float = float("nan")

    def digit_rms(self) -> dict:
        """RMS residual (m) of each digit's markers and of the back of the hand (NaN if unseen)."""
        return _digit_rms(self.markerset, self.skeleton, self.residuals)


def _digit_rms(markerset: MarkerSet, skeleton: Skeleton, residuals) -> dict:
    frames = markerset.bone_frames(skeleton)
    names = skeleton.names
    res = np.asarray(residuals, float).reshape(-1, len(markerset))
    out = {}
    for d in ("back",) + DIGITS:
        if d == "back":
            sel = np.array([m.name in BACK_MARKERS for m in markerset.markers])
        else:
            sel = np.array([names[f].split("-")[0] == d and m.name not in BACK_MARKERS
                            for m, f in zip(markerset.markers, frames)])
        v = res[:, sel]
        v = v[np.isfinite(v)]
        out[d] = float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")
    return out


@one_blas_thread
def adapt_hand_model(skeleton: Skeleton, markerset: MarkerSet, marker_positions, *, initial=None,
                     joint_sigma: float = 0.12, marker_sigma_m: float = 0.004, noise_m: float = NOISE_M,
                     regularise: float = 1e-4, max_nfev: int = 60, known_deg=None, loss: str = "soft_l1",
                     point_sigma_m=None, back_sigma_m: float | None = None, start=None) -> HandAdaptation:
    """Adapt the hand model to the person from labelled markers of one or more flashes.

    Parameters
    ----------
    skeleton, markerset : Skeleton, MarkerSet
        The model to start from (e.g. scaled to the hand's size).
    marker_positions : array_like, shape (n_flashes, n_markers, 3)
        Labelled markers (m), NaN where unseen; every flash needs its back-of-hand markers.
    initial : sequence of Pose, optional
        A start per flash (default: the rest pose, the root from the back of the hand).
    joint_sigma : float
        Prior spread of each joint offset component: this share of the bone's length plus 2 mm.
    marker_sigma_m : float
        Prior spread of each marker offset component (m).
    noise_m : float
        Noise of the measured markers (m): weighs the data against the priors.
    regularise : float
        Pull of each angle toward its start (m per radian, as :func:`~stillcap.body.hand.fit_hand`).
    known_deg : sequence of (None or array_like (n_joints, 3)), optional
        Per flash, the joint angles (degrees) when the hand was held in a known pose (a
        calibration pose, :mod:`stillcap.body.hand_calibrate`): they are held fixed, so the
        marker places cannot trade against the angles; None for a flash in an unknown pose.
    loss : str
        SciPy's loss of the residuals (default soft-L1, see below).
    point_sigma_m : array_like, shape (n_flashes, n_markers), optional
        Each labelled marker's noise (m) in place of ``noise_m`` (a partly hidden marker's
        larger, as the pose fit weighs it).
    back_sigma_m : float, optional
        Also estimate every back-of-hand marker's own place (3D), with this prior spread (m)
        about the template's triangle (scaled): the hand frame is then the bones' (a flash of
        known angles fixes it: every phalanx along the frame's x), not the three markers'. None
        (the default): the triangle keeps the template's shape and only its size is free, as a
        capture without a known pose needs (there the frame's tilt would trade with every angle).
    start : HandAdaptation, optional
        A solution of the same problem with fewer shape parameters free (the triangle held) to
        start from: its shape and poses (the priors stay on ``skeleton`` and ``markerset``).

    Returns
    -------
    HandAdaptation

    BLAS runs on one thread during the call (:func:`~stillcap._blas.one_blas_thread`): the
    solver's SVDs are a few hundred columns wide, where OpenBLAS's threads only spin; on the busy
    2-core machine a 900 x 400 SVD took 3.3 CPU-s with its default threads against 0.08 on one
    (a hand calibration: 30-60 minutes of wall time, docs/hand-calibration.md).
    """
    pts = as_array(marker_positions, (None, len(markerset), 3), "marker_positions")
    F = len(pts)
    if F == 0:
        raise ValueError("adapting the hand model needs at least one flash, got 0")
    markerset.check_skeleton(skeleton)
    seen = np.all(np.isfinite(pts), axis=2)
    back = np.array([markerset.index(b) for b in BACK_MARKERS])
    if not seen[:, back].all():
        raise ValueError("adapting the hand model needs the back-of-hand markers seen in every flash")
    frames = markerset.bone_frames(skeleton)
    root = skeleton.root
    parents, order = skeleton.parents, skeleton.depth_first
    J, M = skeleton.n_joints, len(markerset)
    o0, m0 = skeleton.offsets.copy(), markerset.offsets.copy()
    joints_free = np.array([i for i in range(J) if i != root])
    # a bone the model lays along an axis of the hand frame (the fingers' phalanges along x)
    # keeps that direction: it defines the joint's zero angle (a straight finger), and with one
    # marker per phalanx a free direction would trade the angle for the marker's place
    axial = np.array([np.count_nonzero(np.abs(o0[i]) > 1e-9) == 1 and parents[i] != root for i in joints_free])
    comp_free = np.ones((len(joints_free), 3), bool)
    comp_free[axial] = np.abs(o0[joints_free][axial]) > 1e-9
    cf = comp_free.ravel()
    mk_free = np.array([k for k in range(M) if k not in set(back.tolist())])
    dofs = hand_dofs(skeleton)
    nd = len(dofs)
    dof_j = np.array([i for i, _ in dofs])
    dof_a = np.array([a for _, a in dofs])
    lim = np.radians(skeleton.limits_deg)
    lo = np.array([lim[i, a, 0] if np.isfinite(lim[i, a, 0]) else -np.pi for i, a in dofs])
    hi = np.array([lim[i, a, 1] if np.isfinite(lim[i, a, 1]) else np.pi for i, a in dofs])
    nj_free = int(cf.sum())
    nb = 3 * len(back) if back_sigma_m is not None else 0  # the back markers' own places (optional)
    if back_sigma_m is not None and not back_sigma_m > 0:
        raise ValueError(f"back_sigma_m must be positive (m), got {back_sigma_m}")
    nm = 1 + nj_free + 3 * len(mk_free)
    ns = nm + nb
    npp = 6 + nd
    sig_j = joint_sigma * np.linalg.norm(o0[joints_free], axis=1) + 0.002
    # each marker's noise (every coordinate), 1 where unseen (those rows are left out)
    if point_sigma_m is None:
        s3 = np.full((F, M, 3), noise_m)
    else:
        ps = as_array(point_sigma_m, (F, M), "point_sigma_m")
        if np.any(~(ps[seen] > 0)):
            raise ValueError("point_sigma_m must be positive for every seen marker")
        s3 = np.repeat(np.where(seen, ps, 1.0)[..., None], 3, axis=2)

    # start: per flash, the root from the back of the hand, the angles from ``initial``
    known = [None] * F if known_deg is None else list(known_deg)
    if len(known) != F:
        raise ValueError(f"known_deg must have {F} entries (one per flash), got {len(known)}")
    x0, a0s = [np.zeros(ns)], []
    if start is not None:  # the shape of a solution (its joint and marker offsets) as the start
        ob, m0b = start.markerset.offsets[back], m0[back]
        sc = float(np.sum(ob * m0b) / np.sum(m0b * m0b))
        x0[0][0] = np.log(sc)
        x0[0][1:1 + nj_free] = (start.skeleton.offsets[joints_free] - o0[joints_free]).ravel()[cf]
        x0[0][1 + nj_free:nm] = (start.markerset.offsets[mk_free] - m0[mk_free]).ravel()
        if nb:
            x0[0][nm:ns] = (ob - m0b * sc).ravel()
        initial = start.poses
    for k in range(F):
        ang = np.zeros((J, 3))
        if known[k] is not None:
            ang = np.radians(as_array(known[k], (J, 3), "known_deg"))
        elif initial is not None and initial[k] is not None:
            ang = np.radians(skeleton.limit_angles_deg(initial[k].local_rotations))
        a = np.clip([ang[i, ax] for i, ax in dofs], lo + 1e-9, hi - 1e-9)
        if start is not None:  # the start's root pose
            r2w = start.poses[k].root2world
            rt = np.concatenate([Rotation.from_matrix(r2w[:3, :3]).as_rotvec(), r2w[:3, 3]])
        else:
            fit0 = rigid_alignment(m0[back], pts[k, back])
            rt = np.concatenate([fit0.rotation.as_rotvec(), fit0.translation])
        x0.append(np.concatenate([rt, a]))
        a0s.append(a)
    x0 = np.concatenate(x0)
    a0s = np.array(a0s)

    def shape(X):
        P = len(X)
        ls = X[:, 0]
        joff = np.broadcast_to(o0, (P, J, 3)).copy()
        dj = np.zeros((P, len(joints_free) * 3))
        dj[:, cf] = X[:, 1:1 + nj_free]
        joff[:, joints_free] = o0[joints_free][None] + dj.reshape(P, -1, 3)
        moff = np.broadcast_to(m0, (P, M, 3)).copy()
        moff[:, back] = m0[back][None] * np.exp(ls)[:, None, None]
        if nb:
            moff[:, back] += X[:, nm:ns].reshape(P, -1, 3)
        moff[:, mk_free] = m0[mk_free][None] + X[:, 1 + nj_free:nm].reshape(P, -1, 3)
        return joff, moff

    def markers_at(joff, moff, Y):
        """Model markers (P, F', M, 3) for poses ``Y`` (P, F', npp); ``joff``/``moff`` (P or 1, ...)."""
        P, Fk = Y.shape[:2]
        R0 = Rotation.from_rotvec(Y[..., :3].reshape(-1, 3)).as_matrix().reshape(P, Fk, 3, 3)
        ang = np.zeros((P, Fk, J, 3))
        ang[:, :, dof_j, dof_a] = Y[..., 6:]
        local = Rotation.from_euler("XYZ", ang.reshape(-1, 3)).as_matrix().reshape(P, Fk, J, 3, 3)
        Rj = np.empty((P, Fk, J, 3, 3))
        tj = np.empty((P, Fk, J, 3))
        for i in order:
            q = parents[i]
            if q < 0:
                Rj[:, :, i] = R0 @ local[:, :, i]
                tj[:, :, i] = Y[..., 3:6]
            else:
                tj[:, :, i] = (Rj[:, :, q] @ joff[:, None, i, :, None])[..., 0] + tj[:, :, q]
                Rj[:, :, i] = Rj[:, :, q] @ local[:, :, i]
        return (Rj[:, :, frames] @ moff[:, None, :, :, None])[..., 0] + tj[:, :, frames]

    def residuals(X):
        P = len(X)
        joff, moff = shape(X)
        Y = X[:, ns:].reshape(P, F, npp)
        m = markers_at(joff, moff, Y)
        data = ((m - pts[None]) / s3[None])[:, seen].reshape(P, -1)
        prior_j = ((joff[:, joints_free] - o0[joints_free][None]) / sig_j[None, :, None]).reshape(P, -1)
        prior_m = ((moff[:, mk_free] - m0[mk_free][None]) / marker_sigma_m).reshape(P, -1)
        prior_s = X[:, :1] / 0.2
        prior_b = X[:, nm:ns] / back_sigma_m if nb else X[:, :0]
        reg = (regularise / noise_m) * (Y[..., 6:] - a0s[None]).reshape(P, -1)
        return np.concatenate([data, prior_j, prior_m, prior_s, prior_b, reg], axis=1)

    lb = np.concatenate([np.full(ns, -np.inf)] + [np.concatenate([np.full(6, -np.inf), lo]) for _ in range(F)])
    ub = np.concatenate([np.full(ns, np.inf)] + [np.concatenate([np.full(6, np.inf), hi]) for _ in range(F)])
    lb[0], ub[0] = np.log(0.7), np.log(1.4)
    for k in range(F):
        if known[k] is not None:  # a known pose: its angles are held (a sliver of room for the solver)
            sl = slice(ns + k * npp + 6, ns + (k + 1) * npp)
            lb[sl], ub[sl] = a0s[k] - 1e-9, a0s[k] + 1e-9

    def fun(x):
        return residuals(x[None])[0]

    n_seen = seen.sum(axis=1) * 3
    data_at = np.concatenate([[0], np.cumsum(n_seen)])
    reg_at = int(data_at[-1]) + len(joints_free) * 3 + len(mk_free) * 3 + 1 + nb

    def jac(x):
        # forward differences, vectorised: the shape's columns in one call over all flashes, each
        # flash's pose columns in one call over that flash alone (they move nothing else)
        h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x))
        h = np.where(x + h > ub, -h, h)
        f0 = fun(x)
        Jm = np.zeros((len(f0), len(x)))
        Xs = np.vstack([x[None]] * ns) + np.diag(h)[:ns]
        Jm[:, :ns] = ((residuals(Xs) - f0) / h[:ns, None]).T
        joff, moff = shape(x[None])
        for k in range(F):
            sl = slice(ns + k * npp, ns + (k + 1) * npp)
            yk = x[sl]
            Yk = (yk[None] + np.diag(h[sl]))[:, None]
            sig_k = s3[k][seen[k]].ravel()
            mk = markers_at(joff, moff, Yk)[:, 0][:, seen[k]].reshape(npp, -1) / sig_k
            Jm[data_at[k]:data_at[k + 1], sl] = ((mk - (f0[data_at[k]:data_at[k + 1]] + pts[k][seen[k]].ravel() / sig_k))
                                                 / h[sl, None]).T
            r = reg_at + k * nd
            Jm[r:r + nd, sl][np.arange(nd), 6 + np.arange(nd)] = regularise / noise_m
        return Jm

    x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
    # SciPy's soft-L1 loss (f_scale 3 noise sigmas) applies to every row: it also softens the
    # priors beyond 3 sigmas, which only matters for a model far off
    sol = least_squares(fun, x0, jac=jac, bounds=(lb, ub), x_scale="jac", loss=loss, f_scale=3.0,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
    joff, moff = shape(sol.x[None])
    joints = tuple(Joint(j.name, j.parent, o, j.limits_deg) for j, o in zip(skeleton.joints, joff[0]))
    sk = Skeleton(joints, name=skeleton.name, source=f"{skeleton.source} (adapted)")
    markers = tuple(Marker(m.name, m.bone, o, m.hsb, m.diameter) for m, o in zip(markerset.markers, moff[0]))
    ms = MarkerSet(markers, markerset.rules, markerset.name, markerset.skeleton_name, markerset.source)
    poses, res = [], np.full((F, M), np.nan)
    for k in range(F):
        y = sol.x[ns + k * npp: ns + (k + 1) * npp]
        r2w = np.eye(4)
        r2w[:3, :3] = Rotation.from_rotvec(y[:3]).as_matrix()
        r2w[:3, 3] = y[3:6]
        ang = np.zeros((J, 3))
        ang[dof_j, dof_a] = y[6:]
        p = Pose(sk, r2w, Rotation.from_euler("XYZ", ang).as_matrix())
        poses.append(p)
        d = np.linalg.norm(ms.positions(p) - pts[k], axis=1)
        res[k] = np.where(seen[k], d, np.nan)
    rms = float(np.sqrt(np.nanmean(res ** 2)))
    # uncertainty of the shape (Gauss-Newton covariance; the pseudo-inverse for parameters no
    # residual touches) and how far the shape moved in its priors' sigmas
    Jm = jac(sol.x)
    n_data = int(seen.sum()) * 3
    chi2 = float(np.sum(fun(sol.x)[:n_data] ** 2))
    scale = max(1.0, chi2 / max(1, n_data - len(sol.x)))
    # noisier data than assumed weigh less against the priors: only the data's rows are scaled
    # (scaling the whole covariance would also widen a parameter the data do not touch beyond
    # its prior: 1.35x measured, the nail heights of another_hand(5)'s protocol capture)
    Jd, Jp = Jm[:n_data], Jm[n_data:]
    cov = np.linalg.pinv(Jd.T @ Jd / scale + Jp.T @ Jp)[:ns, :ns]
    jcov = np.zeros((J, 3, 3))
    jidx = np.full(len(joints_free) * 3, -1)
    jidx[cf] = 1 + np.arange(nj_free)
    jidx = jidx.reshape(-1, 3)
    for r, i in enumerate(joints_free):
        ok = jidx[r] >= 0
        sub = np.zeros((3, 3))
        sub[np.ix_(ok, ok)] = cov[np.ix_(jidx[r][ok], jidx[r][ok])]
        jcov[i] = sub
    mcov = np.zeros((M, 3, 3))
    for r, k in enumerate(mk_free):
        q = 1 + nj_free + 3 * r + np.arange(3)
        mcov[k] = cov[np.ix_(q, q)]
    for r, k in enumerate(back if nb else ()):
        q = nm + 3 * r + np.arange(3)
        mcov[k] = cov[np.ix_(q, q)]
    jz = np.zeros(J)
    jz[joints_free] = np.abs((joff[0, joints_free] - o0[joints_free]) / sig_j[:, None]).max(axis=1)
    mz = np.zeros(M)
    mz[mk_free] = np.abs(moff[0, mk_free] - m0[mk_free]).max(axis=1) / marker_sigma_m
    if nb:
        mz[back] = np.abs(moff[0, back] - m0[back] * np.exp(sol.x[0])).max(axis=1) / back_sigma_m
    jsig = np.zeros(J)
    jsig[joints_free] = sig_j
    return HandAdaptation(sk, ms, poses, res, rms, F, bool(sol.success), str(sol.message), jcov, mcov, jz, mz,
                          jsig, float(marker_sigma_m), float(scale), 2.0 * float(sol.cost))


def label_and_adapt(points, colors, *, strobe_hz: float, skeleton: Skeleton, markerset: MarkerSet,
                    adapt: bool = True, reprojection_px=None, overrides=None, hand_scale: float | None = None,
                    min_flashes: int = 1, unconfirmed=None):
    """Label a capture's markers with the model adapted to the person.

    1. :func:`~stillcap.body.hand_label.label_hand_markers` with the model scaled to the hand's
       size (estimated) and the assignment gate widened by :data:`ADAPT_GATE_FACTOR`;
    2. :func:`adapt_hand_model` on the reconstructed flashes;
    3. labelled again with the adapted model, the normal gates times the hand's size.

    ``unconfirmed`` (a bool per point: partly hidden points no third view checked) goes to every
    labelling, as :func:`~stillcap.body.hand_label.label_hand_markers` takes it.

    Returns
    -------
    labels : HandLabels
        Of the adapted hand (its ``skeleton`` and ``markerset``) when adapted.
    adaptation : HandAdaptation or None
        None when not adapted (``adapt`` False or fewer than ``min_flashes`` flashes with a pose).
    """
    from stillcap.body.hand_label import GATE_M, GRID_GATE_M, TRIANGLE_TOL_M, label_hand_markers

    kw = dict(strobe_hz=strobe_hz, reprojection_px=reprojection_px, unconfirmed=unconfirmed)
    if not adapt:
        return label_hand_markers(points, colors, skeleton=skeleton, markerset=markerset, overrides=overrides,
                                  hand_scale=hand_scale, **kw), None
    # the adaptation learns from flashes posed from their back-of-hand triplets only (fill=False)
    first = label_hand_markers(points, colors, skeleton=skeleton, markerset=markerset, hand_scale=hand_scale,
                               gate_m=GATE_M * ADAPT_GATE_FACTOR, fill=False, **kw)
    rec = np.flatnonzero(first.reconstructed)
    if len(rec) < min_flashes:
        return label_hand_markers(points, colors, skeleton=skeleton, markerset=markerset, overrides=overrides,
                                  hand_scale=first.hand_scale, **kw), None
    ad = adapt_hand_model(first.skeleton, first.markerset, first.positions[rec],
                          initial=[first.fits[k].pose for k in rec])
    s = first.hand_scale
    labels = label_hand_markers(points, colors, skeleton=ad.skeleton, markerset=ad.markerset, hand_scale=1.0,
                                overrides=overrides, triangle_tol_m=TRIANGLE_TOL_M * s, gate_m=GATE_M * s,
                                grid_gate_m=GRID_GATE_M * s, **kw)
    labels.hand_scale = s
    return labels, ad
