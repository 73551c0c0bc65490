"""The hand's poses of a capture fitted again, all flashes at once (issue 12, the hand's joint
angles): each marker weighed by its own 3D error covariance, and optionally the joint angles
held to a motion the photos can tell from their noise.

:func:`~stillcap.body.hand_track.fit_hand_sequence` fits each flash on its own with every
marker's error a round ball of one size. :func:`refine_hand_sequence` starts from its poses and

1. **weighs each marker by its covariance** (``point_cov``, e.g.
   :func:`stillcap.geometry.point_covariance.triangulation_covariance`): a marker's residual is
   whitened (``L^-1 (model - measured)``, ``cov = L L^T``), so the direction a stereo pair
   fixes badly (its depth) bends the hand less than the directions it fixes well;
2. with ``smooth``, adds a prior on each joint angle's **acceleration** between flashes (second
   divided differences over the flashes' times): a Gaussian of spread ``accel_sigma`` per degree
   of freedom, estimated from the capture itself (:func:`acceleration_sigma`: the mean square of
   the measured second differences less what the per-flash noise puts in them, the noise from
   each flash's own fit covariance). Nothing is tuned: a degree of freedom whose measured
   motion stands far above its noise gets a loose prior and keeps its per-flash angles; one
   whose motion the photos cannot tell from noise gets a prior no tighter than one second
   difference's noise (smoothed at most halfway); one never seen in three consecutive flashes
   gets none.

One ``scipy.optimize.least_squares`` problem over every flash's root pose and joint angles,
within the joint limits; the Jacobian's marker rows are block-diagonal (one flash each), so a
parameter is stepped in every flash at once (one forward-kinematics call per parameter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.body.hand import _fit_setup
from stillcap.body.hand_track import HandSequence
from stillcap.body.skeleton import Pose

__all__ = ["SequenceRefinement", "acceleration_sigma", "model_misfit", "refine_hand_sequence"]


@dataclass(eq=False)
class SequenceRefinement:
    """Result of :func:`refine_hand_sequence`.

    Attributes
    ----------
    sequence : HandSequence
        The poses fitted again (same flashes, times, hand).
    dofs : list of (joint, axis)
        The degrees of freedom, in the order of the arrays below.
    angle_sigma_deg : ndarray, shape (n, n_dofs)
        Each flash's own 1-sigma of each angle (its fit alone, whitened markers), degrees;
        large where no marker fixes it.
    accel_sigma_deg_s2 : ndarray, shape (n_dofs,)
        The acceleration prior's spread per degree of freedom (deg/s^2); inf where none was
        used (``smooth`` off, or too few flashes see it).
    success : bool
    message : str
    """

    sequence: HandSequence
    dofs: list
    angle_sigma_deg: np.ndarray
    accel_sigma_deg_s2: np.ndarray
    success: bool
    message: str = ""


def _second_difference(times) -> np.ndarray:
    """``D`` (n - 2, n): ``D @ a`` is the second divided difference (acceleration) at each
    interior flash, ``2 [(a+ - a)/h+ - (a - a-)/h-] / (h- + h+)``."""
    t = np.asarray(times, float)
    n = len(t)
    D = np.zeros((max(n - 2, 0), n))
    for k in range(1, n - 1):
        h1, h2 = t[k] - t[k - 1], t[k + 1] - t[k]
        D[k - 1, k - 1:k + 2] = 2.0 / (h1 + h2) * np.array([1.0 / h1, -1.0 / h1 - 1.0 / h2, 1.0 / h2])
    return D


def acceleration_sigma(angles, angle_sigma, times, observed) -> np.ndarray:
    """The spread of each degree of freedom's acceleration that the measured angles show.

    Parameters
    ----------
    angles, angle_sigma : array_like, shape (n, n_dofs)
        Each flash's angle and its 1-sigma (any angle unit; the result is in that unit per s^2).
    times : array_like, shape (n,)
        Seconds, increasing.
    observed : array_like of bool, shape (n, n_dofs)
        The degrees of freedom each flash's markers fix.

    Returns
    -------
    ndarray, shape (n_dofs,)
        ``sqrt(max(mean(acc^2) - mean(noise var), mean(noise var)))`` over the interior flashes
        whose three flashes all fix it: what the measured second differences hold beyond the
        noise, never tighter than one second difference's noise; inf where no interior flash
        qualifies.
    """
    a = np.asarray(angles, float)
    s = np.asarray(angle_sigma, float)
    obs = np.asarray(observed, bool)
    D = _second_difference(times)
    out = np.full(a.shape[1], np.inf)
    if not len(D):
        return out
    acc = D @ a
    noise = (D ** 2) @ (s ** 2)
    ok = np.ones_like(acc, bool)
    for k in range(len(D)):
        ok[k] = obs[k:k + 3].all(axis=0)
    for d in range(a.shape[1]):
        m = ok[:, d] & np.isfinite(acc[:, d]) & np.isfinite(noise[:, d])
        if m.any():
            v_noise = float(np.mean(noise[m, d]))
            out[d] = np.sqrt(max(float(np.mean(acc[m, d] ** 2)) - v_noise, v_noise))
    return out


def refine_hand_sequence(sequence: HandSequence, positions, point_cov, *, observed=None, smooth: bool = True,
                         misfit_from=None, regularise: float = 1e-4, max_nfev: int = 100) -> SequenceRefinement:
    """Fit the poses of ``sequence`` again, all flashes at once (see the module's text).

    Parameters
    ----------
    sequence : HandSequence
        The per-flash fit (its poses are the start; its hand, flashes and times are kept).
    positions : array_like, shape (n, n_markers, 3)
        The labelled markers of the sequence's flashes (m); NaN where unlabelled.
    point_cov : array_like, shape (n, n_markers, 3, 3)
        Each labelled marker's error covariance (m^2); a marker whose covariance is not finite
        and positive definite is left out.
    observed : array_like of bool, shape (n, n_dofs), optional
        The degrees of freedom each flash's markers fix (default: every one whose 1-sigma from
        that flash's fit is below 1 rad); the acceleration prior is estimated on these only.
    smooth : bool
        Add the acceleration prior (off: each flash weighed by covariance only, independently).
    misfit_from : array_like of bool, shape (n, n_markers), optional
        The labelled markers whose residuals measure the model's misfit (default all; e.g. the
        fully seen ones, whose covariance is the triangulation's alone). Each marker's
        covariance gets a round term for what its residuals over the flashes hold beyond its
        covariance (:func:`model_misfit`): the hand model's own error at that marker, which the
        photos' noise does not include (a calibrated model's marker places are known to a few
        tenths of a millimetre; the triangulation to less than a tenth).
    regularise : float
        Pull (m per radian, at the markers' median 1-sigma) of each angle toward its start, as
        :func:`~stillcap.body.hand.fit_hand`'s.

    Returns
    -------
    SequenceRefinement
    """
    sk, ms = sequence.skeleton, sequence.markerset
    n, M = sequence.n, len(ms.names)
    pts = as_array(positions, (n, M, 3), "positions")
    cov = as_array(point_cov, (n, M, 3, 3), "point_cov")
    seen = np.isfinite(pts).all(axis=2) & np.isfinite(cov).all(axis=(2, 3))
    W, seen, ref = _whitening(cov, seen)
    pts0 = np.where(seen[..., None], pts, 0.0)
    from_ = seen if misfit_from is None else seen & as_array(misfit_from, (n, M), "misfit_from").astype(bool)

    frames, dofs, gidx, mg, offsets, moffsets, parents, order, lim = _fit_setup(sk, ms)
    nd = len(dofs)
    npp = 6 + nd
    dof_j = np.array([i for i, _ in dofs])
    dof_a = np.array([a for _, a in dofs])
    lo = np.array([lim[i, a, 0] if np.isfinite(lim[i, a, 0]) else -np.pi for i, a in dofs])
    hi = np.array([lim[i, a, 1] if np.isfinite(lim[i, a, 1]) else np.pi for i, a in dofs])
    X0 = np.empty((n, npp))
    for k, p in enumerate(sequence.poses):
        X0[k, :3] = Rotation.from_matrix(p.root2world[:3, :3]).as_rotvec()
        X0[k, 3:6] = p.root2world[:3, 3]
        ang = np.radians(sk.limit_angles_deg(p.local_rotations))
        X0[k, 6:] = np.clip(ang[dof_j, dof_a], lo + 1e-9, hi - 1e-9)
    a0 = X0[:, 6:].copy()

    def markers_raw(X):
        """The model's markers in every flash, shape (n, M, 3)."""
        R0 = Rotation.from_rotvec(X[:, :3]).as_matrix()
        ang = np.zeros((len(X), sk.n_joints, 3))
        ang[:, dof_j, dof_a] = X[:, 6:]
        local = Rotation.from_euler("XYZ", ang.reshape(-1, 3)).as_matrix().reshape(len(X), sk.n_joints, 3, 3)
        Rj = np.empty((len(X), sk.n_joints, 3, 3))
        tj = np.empty((len(X), sk.n_joints, 3))
        for i in order:
            q = parents[i]
            if q < 0:
                Rj[:, i] = np.einsum("pab,pbc->pac", R0, local[:, i])
                tj[:, i] = X[:, 3:6]
            else:
                tj[:, i] = np.einsum("pab,b->pa", Rj[:, q], offsets[i]) + tj[:, q]
                Rj[:, i] = np.einsum("pab,pbc->pac", Rj[:, q], local[:, i])
        return np.einsum("pmab,mb->pma", Rj[:, frames], moffsets) + tj[:, frames]

    def markers(X):
        """Whitened marker residuals of every flash, shape (n, M * 3); zero where unseen."""
        return np.einsum("pmab,pmb->pma", W * seen[..., None, None], markers_raw(X) - pts0).reshape(len(X), -1)

    def block_jacobian(X):
        """d(markers)/d(params) per flash, shape (n, M * 3, npp), forward differences."""
        h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(X))
        ub = np.concatenate([np.full(6, np.inf), hi])
        h = np.where(X + h > ub[None], -h, h)
        F0 = markers(X)
        J = np.empty((n, F0.shape[1], npp))
        for q in range(npp):
            Xq = X.copy()
            Xq[:, q] += h[:, q]
            J[:, :, q] = (markers(Xq) - F0) / h[:, q][:, None]
        return J

    reg_rows = np.zeros((nd, npp))
    reg_rows[:, 6:] = np.eye(nd) * regularise
    # the model's misfit per marker, from the independent whitened fit's residuals and leverages
    X0 = _solve(markers, block_jacobian, X0, a0, None, regularise, lo, hi, max_nfev)[0]
    J0 = block_jacobian(X0)
    lev = np.zeros((n, M))
    for k in range(n):
        A = np.vstack([J0[k], reg_rows])
        H = np.einsum("ij,jk,ik->i", J0[k], np.linalg.pinv(A.T @ A), J0[k])  # hat matrix diagonal
        lev[k] = H.reshape(M, 3).mean(axis=1)
    r2 = np.sum((markers_raw(X0) - pts0) ** 2, axis=2)
    extra = model_misfit(r2, np.trace(cov, axis1=2, axis2=3), lev, from_)
    if np.any(extra > 0):
        cov = cov + np.eye(3) * extra[None, :, None, None]
        W, seen, ref = _whitening(cov, seen)
        J0 = block_jacobian(X0)
    # each flash's own angle 1-sigma (whitened markers, the regulariser as the only prior)
    angle_sigma = np.empty((n, nd))
    for k in range(n):
        A = np.vstack([J0[k], reg_rows])
        C = np.linalg.pinv(A.T @ A) * ref ** 2
        angle_sigma[k] = np.sqrt(np.clip(np.diag(C)[6:], 0, None))
    obs = angle_sigma < 1.0 if observed is None else as_array(observed, (n, nd), "observed").astype(bool)

    D = _second_difference(sequence.times)
    accel = np.full(nd, np.inf)
    if smooth and len(D):  # the prior's spread from the whitened independent fit
        accel = acceleration_sigma(X0[:, 6:], angle_sigma, sequence.times, obs)
    S = None
    if np.isfinite(accel).any():
        S = (D, np.where(np.isfinite(accel), ref / accel, 0.0))
    X, ok, msg = _solve(markers, block_jacobian, X0, a0, S, regularise, lo, hi, max_nfev)

    poses, angs, res, rms = [], [], [], []
    for k in range(n):
        r2w = np.eye(4)
        r2w[:3, :3] = Rotation.from_rotvec(X[k, :3]).as_matrix()
        r2w[:3, 3] = X[k, 3:6]
        ang = np.zeros((sk.n_joints, 3))
        ang[dof_j, dof_a] = X[k, 6:]
        pose = Pose(sk, r2w, Rotation.from_euler("XYZ", ang).as_matrix())
        d = np.linalg.norm(ms.positions(pose) - pts[k], axis=1)
        d[~np.isfinite(pts[k]).all(axis=1)] = np.nan
        poses.append(pose)
        angs.append(sk.limit_angles_deg(pose.local_rotations))
        res.append(d)
        rms.append(float(np.sqrt(np.nanmean(d ** 2))) if np.isfinite(d).any() else np.nan)
    rms = np.array(rms)
    out = HandSequence(sk, ms, sequence.flashes, sequence.times, poses, np.stack(angs), np.stack(res), rms,
                       sequence.n_markers, np.asarray(sequence.success) & ok & (rms < 0.005), dict(sequence.scales),
                       sequence.personalise)
    return SequenceRefinement(out, list(dofs), np.degrees(angle_sigma), np.degrees(accel), ok, msg)


def model_misfit(r2, cov_trace, leverage, use) -> np.ndarray:
    """Each marker's round error beyond its covariance (m^2 per axis), shape (n_markers,).

    ``r2`` (n, M): squared residual distances of a fit; ``cov_trace`` (n, M): the trace of each
    marker's covariance; ``leverage`` (n, M): each residual's mean hat-matrix diagonal (the
    share of its error the fit absorbed); ``use`` (n, M): the entries to count. By the moments
    ``E[r^2] = (1 - h) (trace + 3 s^2)`` over the flashes:
    ``s^2 = max(sum(r^2 - (1 - h) trace) / sum(3 (1 - h)), 0)``."""
    r2, tr, h = (np.asarray(v, float) for v in (r2, cov_trace, leverage))
    use = np.asarray(use, bool) & np.isfinite(r2) & np.isfinite(tr) & np.isfinite(h) & (h < 1)
    out = np.zeros(r2.shape[1])
    for m in range(r2.shape[1]):
        u = use[:, m]
        if u.any():
            g = 1.0 - h[u, m]
            out[m] = max(float(np.sum(r2[u, m] - g * tr[u, m]) / np.sum(3.0 * g)), 0.0)
    return out


def _whitening(cov, seen):
    """``(W, seen, ref)``: each seen marker's whitening ``ref * L^-1`` (``cov = L L^T``; zero where
    unseen or not positive definite, those then unseen) and ``ref``, the median marker 1-sigma
    (m), which keeps residuals in metres."""
    seen = seen.copy()
    L_inv = np.zeros(cov.shape)
    for k, m in zip(*np.nonzero(seen)):
        try:
            L_inv[k, m] = np.linalg.inv(np.linalg.cholesky(cov[k, m]))
        except np.linalg.LinAlgError:
            seen[k, m] = False
    sig_m = np.sqrt(np.trace(cov[seen], axis1=1, axis2=2) / 3.0)
    if not len(sig_m):
        raise ValueError("refine_hand_sequence: no labelled marker with a valid covariance")
    ref = float(np.median(sig_m))
    return L_inv * ref, seen, ref


def _solve(markers, block_jacobian, X0, a0, S, regularise, lo, hi, max_nfev):
    """The joint least-squares problem: whitened markers of every flash, the regulariser toward
    ``a0`` and (``S = (D, weight per dof)``) the acceleration prior. Returns (X, success, message)."""
    n, npp = X0.shape
    nd = npp - 6

    def residual(x):
        X = x.reshape(n, npp)
        parts = [markers(X).ravel(), regularise * (X[:, 6:] - a0).ravel()]
        if S is not None:
            D, w = S
            parts.append(((D @ X[:, 6:]) * w[None]).ravel())
        return np.concatenate(parts)

    def jacobian(x):
        X = x.reshape(n, npp)
        Jb = block_jacobian(X)
        rows = Jb.shape[1]
        J = np.zeros((n * rows, n * npp))
        for k in range(n):
            J[k * rows:(k + 1) * rows, k * npp:(k + 1) * npp] = Jb[k]
        R = np.zeros((n * nd, n * npp))
        for k in range(n):
            R[k * nd:(k + 1) * nd, k * npp + 6:(k + 1) * npp] = np.eye(nd) * regularise
        blocks = [J, R]
        if S is not None:
            D, w = S
            G = np.zeros((len(D) * nd, n * npp))
            for i in range(len(D)):
                for k in range(n):
                    if D[i, k]:
                        G[i * nd:(i + 1) * nd, k * npp + 6:(k + 1) * npp] = np.diag(D[i, k] * w)
            blocks.append(G)
        return np.vstack(blocks)

    lb = np.tile(np.concatenate([np.full(6, -np.inf), lo]), n)
    ub = np.tile(np.concatenate([np.full(6, np.inf), hi]), n)
    x0 = np.clip(X0.ravel(), lb + 1e-9, ub - 1e-9)
    sol = least_squares(residual, x0, jac=jacobian, bounds=(lb, ub), x_scale="jac", xtol=1e-10, ftol=1e-10,
                        gtol=1e-10, max_nfev=max_nfev)
    return sol.x.reshape(n, npp), bool(sol.success), str(sol.message)
