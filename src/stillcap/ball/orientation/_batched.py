"""Batched pieces of the global spin fit (:mod:`stillcap.ball.orientation._global`): the
observation weights of several sets of the same observations, and the residuals of many copies
of a problem whose observed directions are moved (the centre-shift term of the spin's
covariance), each copy's numbers those it has alone. Speed only (issue 16): one call over all
copies instead of one problem per copy."""

from __future__ import annotations

import numpy as np

from stillcap.ball.orientation._so3 import _phi_over_sin, _tangent_bases


def _observation_weights(t1, t2, information):
    """The weights of :class:`~stillcap.ball.orientation._global._GlobalProblem` for C sets of
    the same M observations at once: tangent bases ``t1``, ``t2`` (C, M, 3) and the
    observations' ``information`` (M, 3, 3) -> ``W`` (C, M, 2, 2) and each set's scale (C,), or
    ``(None, scale)`` when a set's scale is not a positive number (then that problem has no
    weights). Each 2x2 (and each set's median) is computed as for one set alone: the same
    numbers (:func:`_shifted_residuals` needs them for the moved copies of
    :func:`~stillcap.ball.orientation._global._center_shift_cov`)."""
    C, M = t1.shape[:2]
    B = np.stack([t1.reshape(C * M, 3), t2.reshape(C * M, 3)], axis=2)  # (C M, 3, 2)
    info = information if C == 1 else np.tile(information, (C, 1, 1))
    M2 = np.swapaxes(B, 1, 2) @ info @ B
    M2 = 0.5 * (M2 + np.swapaxes(M2, 1, 2))
    scale = np.median((np.trace(M2, axis1=1, axis2=2) / 2.0).reshape(C, M), axis=1)
    if not np.all(np.isfinite(scale) & (scale > 0)):
        return None, scale
    M2 = M2 / np.repeat(scale, M)[:, None, None] + 1e-9 * np.eye(2)
    return np.swapaxes(np.linalg.cholesky(M2), 1, 2).reshape(C, M, 2, 2), scale  # upper: W[..., 1, 0] = 0


def _shifted_residuals(prob, x, R0, j, sel, D, f):
    """The residuals of problems (:class:`~stillcap.ball.orientation._global._GlobalProblem`)
    that differ from ``prob`` only in their directions ``D`` (C, M, 3, not yet unit:
    :class:`~stillcap.ball.orientation.MarkerObservations` normalises them), each with the
    noise classes' weight factors ``f`` (M,) of ``prob`` (None: none), all C at once: (C, 2 m),
    row c the same numbers as ``_GlobalProblem(prob.dt, obs with D[c], prob.layout,
    0.0).residuals(x, R0, j, sel)`` (every step is row-wise, the predicted directions ``p`` do
    not depend on the observed ones, and the weights come from :func:`_observation_weights`).
    None when a copy would have no weights while ``prob`` has (or the other way round): the
    caller then builds each problem. Hand-written batch: the per-copy problems' set-up was most
    of the cost."""
    C, M = D.shape[:2]
    flat = D.reshape(C * M, 3)
    U = flat / np.linalg.norm(flat, axis=1)[:, None]  # (MarkerObservations' _unit_rows)
    t1, t2 = _tangent_bases(U)
    W = None
    if prob.obs.information is not None and M:
        W, _ = _observation_weights(t1.reshape(C, M, 3), t2.reshape(C, M, 3), prob.obs.information)
        if W is None:
            return None
        if f is not None:
            W = W * f[:, None, None]
    if (W is None) != (prob.W is None):
        return None
    p = prob._predict(x, R0, j, sel)[0]  # (m, 3): the same for every copy (u enters only below)
    m = len(p)
    pick = np.flatnonzero(sel) if np.asarray(sel).dtype == bool else np.asarray(sel)
    rows = (np.arange(C)[:, None] * M + pick[None, :]).ravel()  # each copy's observations sel
    P = np.tile(p, (C, 1))
    Us, T1, T2 = U[rows], t1[rows], t2[rows]
    c = np.minimum(np.maximum(np.einsum("ma,ma->m", Us, P), -1.0), 1.0)
    g = _phi_over_sin(c)
    r1 = g * np.einsum("ma,ma->m", T1, P)
    r2 = g * np.einsum("ma,ma->m", T2, P)
    if W is not None:
        Ws = W.reshape(C * M, 2, 2)[rows]
        r1, r2 = Ws[:, 0, 0] * r1 + Ws[:, 0, 1] * r2, Ws[:, 1, 1] * r2
    return np.concatenate([r1.reshape(C, m), r2.reshape(C, m)], axis=1)


def _residuals_in_noise(prob, x, R0, j, d):
    """Every observation's residual length in the units of the fit's noise (the weighted
    residual in centroid pixels, or the angle in rad without weights), (M,)."""
    if prob.W is None:
        return np.asarray(d, float).copy()
    return prob.observation_norms(x, R0, j, np.ones(len(prob.u), bool)) * np.sqrt(prob.info_scale)


def _residual_ranks(prob):
    """How many of each observation's two (weighted) residual components carry information,
    (M,) int: 1 for a marker cut by the limb (its weight's second singular value is the 1e-9
    floor of :func:`_observation_weights`), else 2; 2 for every observation without weights.
    The one definition of the fit's redundancy: ``sum(ranks[inliers]) - 6`` scales the spin's
    covariance in ``fit_spin`` and is the degrees of freedom of
    :func:`stillcap.ball.alias.marker_misfit_test`."""
    if prob.W is None:
        return np.full(len(prob.u), 2)
    sv = np.linalg.svd(prob.W, compute_uv=False)  # (M, 2); the class scales multiply both alike
    return np.sum(sv > 1e-3 * sv[:, :1], axis=1)
