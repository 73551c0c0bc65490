"""How wrong the shading correction of the ball centres is, estimated from the capture itself.

The detector moves each lit ball's centre by a shading correction along its lit direction
(:mod:`stillcap.detect.ball._shading`); the model behind it (the light, the lens blur, the
response, lambertian leather) is an estimate, so part of each correction may be wrong. Taken as
a share ``kappa_c`` of the correction made, the same for all ball images of camera ``c`` (its
light and blur are shared), the error it leaves moves each image's centre by
``kappa_c x made_ck`` px along its lit direction ``u_ck``: a structured error whose pattern in
3-D (the *unit mode* of the camera, :func:`unit_modes`) is known from the geometry, only its
size is not.

:func:`estimate_shading_share` regresses the flight fit's residuals on those patterns
(generalised least squares, weighted with each position's covariance shape). The fit has
already absorbed the part of each pattern a flight can take up (a constant shift moves the
release point, a shift along the flight the clock offset); regressing on the patterns with that
part removed (``(I - H) d``, ``H`` the flight's weighted hat matrix at the fit: :func:`fitted_response`) gives the same estimate as fitting ``kappa`` along with the
flight (Frisch-Waugh-Lovell), and its covariance grows with the residuals' misfit (their
chi-square per degree of freedom). Where the capture cannot tell (the pattern is absorbed, too
few images), the stated prior ``kappa ~ N(0, prior^2)`` (``PitchOptions.shading_model_error``)
decides: the result is the posterior's second moment ``E[kappa_c^2] = m_c^2 + V_cc``, which
tends to ``prior^2`` when the data say nothing and to ``kappa_hat^2 + var`` when they say much.
``docs/pitch.md``, "Uncertainties".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap.ball.physics import simulate

__all__ = ["SCALE_GRID", "ShadingShare", "ShareScale", "estimate_shading_share", "fitted_response", "share_scale_from_pairs",
           "unit_modes"]


@dataclass
class ShadingShare:
    """The estimated share of the shading correction that is wrong, per camera.

    Attributes
    ----------
    cameras : list of str
        ``"pair/camera"`` of each estimated camera, in the order of the arrays.
    kappa_hat : ndarray, shape (C,)
        Least-squares estimate of each camera's share (signed: positive, the correction was too
        small along ``u``; NaN where the capture gives none).
    kappa_sigma : ndarray, shape (C,)
        Its 1-sigma (from the regression, scaled by the residuals' misfit; inf where none).
    kappa_used : ndarray, shape (C,)
        ``sqrt(E[kappa^2])`` under the prior and the data: what sizes the remaining-bias modes.
    prior : float
        The stated prior's 1-sigma (``PitchOptions.shading_model_error``).
    misfit : float
        The regression's residual chi-square per degree of freedom (with each position's
        covariance shape at its stated level: 1 when the shape's level is right).
    dof : int
    """

    cameras: list
    kappa_hat: np.ndarray
    kappa_sigma: np.ndarray
    kappa_used: np.ndarray
    prior: float
    misfit: float = float("nan")
    dof: int = 0
    inflation: float = 1.0
    placebo: np.ndarray | None = None
    notes: list = field(default_factory=list)

    def of(self, name: str) -> float:
        """``kappa_used`` of camera ``"pair/camera"`` (the prior when it was not estimated)."""
        return float(self.kappa_used[self.cameras.index(name)]) if name in self.cameras else self.prior

    def to_dict(self) -> dict:
        def f(x):
            return None if not np.isfinite(x) else float(x)
        return {"prior": self.prior, "misfit": f(self.misfit), "dof": int(self.dof),
                "cameras": {c: {"kappa_hat": f(self.kappa_hat[i]), "kappa_sigma": f(self.kappa_sigma[i]),
                                "kappa_used": f(self.kappa_used[i])} for i, c in enumerate(self.cameras)}}


def unit_modes(cams, centers_px, u, made_px) -> np.ndarray:
    """Position shift (m) of a pair's ball images when each camera's centres move by the whole
    correction made (``made_px``) along their lit direction ``u``: ``kappa_c = 1``.

    Parameters
    ----------
    cams : sequence of 2 Camera
    centers_px, u : array_like, shape (2, K, 2)
    made_px : array_like, shape (2, K)

    Returns
    -------
    ndarray, shape (2, K, 3)
    """
    from stillcap.ball.uncertainty import lit_bias_modes

    x = np.asarray(centers_px, float)
    made = np.nan_to_num(np.asarray(made_px, float))
    K = x.shape[1] if x.ndim == 3 else 0
    m = lit_bias_modes(cams, x, u, made, np.ones(K, bool))  # (12, K, 3): 0 and 6 are "along u, constant"
    return m[[0, 6]]


def fitted_response(fit, model, group_index, modes, shape_covariance=None) -> np.ndarray:
    """How the fitted flight's positions move when the measured positions move by each of
    ``modes``: ``H d``, ``H = J (J^T W J)^-1 J^T W`` the weighted hat matrix of the flight at
    the fit, ``J`` the positions' derivatives by the release point, the velocity, the spin
    vector (world frame) and the clock offsets (central differences through the flight model;
    the offsets' from the velocities), ``W`` the inverse of each position's covariance shape.

    The fit's priors are left out (a positions-only fit's, on the release point and velocity,
    are weak next to its positions; a measured spin's are not: use it on positions-only fits).
    The fit's own linear response (``ReferenceFit.position_gain``) was not used: without a
    measured spin it is taken in the fit's gyro parameters, whose Jacobian is singular where the
    transverse spin is small, and there it reported patterns as absorbed that a refit does not
    absorb. Written by hand: a weighted projection no library offers for a flight model.

    Parameters
    ----------
    fit : ReferenceFit
    model : FlightModel
    group_index : array_like of int, shape (N,)
        Clock group of each position (0: reference clock; ``g``: ``fit.time_offsets[g - 1]``).
    modes : array_like, shape (M, N, 3)
    shape_covariance : array_like, shape (N, 3, 3), optional
        The fit's weights (identity when None).

    Returns
    -------
    ndarray, shape (M, N, 3)
    """
    D = np.nan_to_num(np.asarray(modes, float))
    g = np.asarray(group_index, int)
    N = len(fit.times)
    if D.ndim != 3 or D.shape[1:] != (N, 3) or g.shape != (N,):
        raise ValueError(f"modes must have shape (M, {N}, 3) and group_index ({N},), got {D.shape}, {g.shape}")
    J, ok = _flight_jacobian(fit, model, g)
    J = J[ok]  # (n, 3, P)
    if shape_covariance is None:
        Lw = np.broadcast_to(np.eye(3), (int(ok.sum()), 3, 3))
    else:
        Lw = _whitening(np.asarray(shape_covariance, float)[ok])
    Jw = np.einsum("nij,njp->nip", Lw, J).reshape(-1, J.shape[-1])
    Dw = np.einsum("nij,mnj->mni", Lw, D[:, ok]).reshape(len(D), -1)
    # column scaling (metres, m/s, rad/s and seconds differ by orders): a least-squares solve
    coef = np.linalg.lstsq(Jw, Dw.T, rcond=None)[0]  # (P, M)
    out = np.zeros_like(D)
    out[:, ok] = np.einsum("nip,pm->mni", J, coef)
    return out


def _whitening(S: np.ndarray) -> np.ndarray:
    """``L_n^-1`` (n, 3, 3) of each covariance shape's Cholesky factor (a tiny ridge for flat ones)."""
    return np.linalg.inv(np.linalg.cholesky(S + np.eye(3) * 1e-18 * np.trace(S, axis1=1, axis2=2)[:, None, None]))


def _flight_jacobian(fit, model, g):
    """The positions' derivatives (N, 3, P) by the release point, the velocity, the spin vector
    and the clock offsets at the fit, and the rows with finite residuals (N,)."""
    ok = np.all(np.isfinite(fit.residuals), axis=1)
    x0 = np.concatenate([fit.p0, fit.v0, fit.spin])
    steps = np.r_[np.full(3, 1e-4), np.full(3, 1e-4), np.full(3, 1e-2)]

    def fly(x):
        tr = simulate(x[:3], x[3:6], x[6:9], fit.times, model, t0=fit.t0)
        return tr.positions, tr.velocities

    _, vel = fly(x0)
    cols = []
    for j in range(9):
        dx = np.zeros(9)
        dx[j] = steps[j]
        cols.append((fly(x0 + dx)[0] - fly(x0 - dx)[0]) / (2 * steps[j]))
    for k in range(1, len(fit.time_offsets) + 1):  # a clock offset moves its group along the flight
        cols.append(np.where((g == k)[:, None], vel, 0.0))
    return np.stack(cols, axis=-1), ok


def estimate_shading_share(fit, model, group_index, unit_modes_by_camera, shape_covariance,
                           prior: float, placebo_modes=None, min_images: int = 4) -> ShadingShare:
    """Each camera's share ``kappa_c`` of the shading correction that is wrong, from a flight
    fit's residuals (module docstring).

    Parameters
    ----------
    fit : ReferenceFit
        The positions-only flight fit whose ``residuals`` (N, 3) are regressed.
    model : FlightModel
    group_index : array_like of int, shape (N,)
        Clock group of each position (as the fit's ``time_groups``).
    unit_modes_by_camera : dict
        ``"pair/camera" -> ndarray (N, 3)``: the camera's :func:`unit_modes` at the fit's rows
        (0 on the other pairs' rows).
    shape_covariance : array_like, shape (N, 3, 3)
        Each position's error covariance shape (m^2) the fit weighted with.
    prior : float
        1-sigma of the prior on each ``kappa_c`` (> 0), the fallback when the capture cannot tell.
    min_images : int
        Fewest corrected images a camera needs to be estimated (else: the prior).

    Returns
    -------
    ShadingShare
    """
    names = list(unit_modes_by_camera)
    C = len(names)
    nan = np.full(C, np.nan)
    if not prior > 0:
        raise ValueError(f"prior must be > 0, got {prior}")
    out = ShadingShare(names, nan.copy(), np.full(C, np.inf), np.full(C, float(prior)), float(prior))
    if C == 0:
        return out
    r = -np.asarray(fit.residuals, float)  # measured - fitted: what the modes add to the measurement
    S = np.asarray(shape_covariance, float)
    A = np.stack([np.asarray(unit_modes_by_camera[n], float) for n in names])  # (C, N, 3)
    ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(S), axis=(1, 2)) & np.all(np.isfinite(A), axis=(0, 2))
    n_img = (np.linalg.norm(A, axis=2) > 0).sum(axis=1)
    use = n_img >= min_images
    if not use.any():
        out.notes.append("too few corrected ball images: the prior")
        return out
    # the patterns with what the flight absorbs removed: (I - H) d
    At = A[use] - fitted_response(fit, model, group_index, A[use], S)  # (U, N, 3)
    # whitening with each position's covariance shape: L_n^-1 of its Cholesky factor
    L = np.linalg.cholesky(S[ok] + np.eye(3) * 1e-18)

    def white(v):
        return np.linalg.solve(L, v[ok][:, :, None])[:, :, 0].ravel()

    y = white(r)
    X = np.stack([white(a) for a in At], axis=1)  # (3n, U)
    n_par = int(np.asarray(fit.covariance).shape[0])
    dof = len(y) - n_par - X.shape[1]
    if dof < 3:
        out.notes.append("too few degrees of freedom: the prior")
        return out
    XtX = X.T @ X
    try:
        k_hat = np.linalg.lstsq(X, y, rcond=None)[0]
        e = y - X @ k_hat
        # the residuals' misfit per degree of freedom: the shapes' level is the centre noise
        # assumed (pixel_sigma); above 1 the data are noisier than that and kappa less certain
        misfit = max(float(e @ e / dof), 1e-12)
        Sigma = np.linalg.pinv(XtX) * misfit
        # the placebo: the same patterns across the lit direction, where the shading model
        # predicts no error. Other smooth centre errors project onto the real patterns as much
        # as onto these, so the placebo's coefficients measure how far the regression can be
        # fooled on this capture; their mean square over their sigma^2 inflates the variance
        infl = 1.0
        if placebo_modes is not None:
            Bp = np.stack([np.asarray(placebo_modes[n], float) for n in names])[use]
            Xp = np.stack([white(a) for a in Bp - fitted_response(fit, model, group_index, Bp, S)], axis=1)
            kp = np.linalg.lstsq(Xp, y, rcond=None)[0]
            sp2 = np.diag(np.linalg.pinv(Xp.T @ Xp)) * misfit
            infl = max(1.0, float(np.mean(kp ** 2 / np.maximum(sp2, 1e-300))))
            out.placebo = kp
        Sigma = Sigma * infl
        out.inflation = infl
        # the posterior with the prior kappa ~ N(0, prior^2 I): covariance V, mean m
        Pm = np.linalg.pinv(Sigma)
        V = np.linalg.inv(Pm + np.eye(len(k_hat)) / prior ** 2)
        m = V @ Pm @ k_hat
    except np.linalg.LinAlgError:
        out.notes.append("the cameras' patterns cannot be told apart: the prior")
        return out
    second = m ** 2 + np.diag(V)
    idx = np.flatnonzero(use)
    out.kappa_hat[idx] = k_hat
    out.kappa_sigma[idx] = np.sqrt(np.clip(np.diag(Sigma), 0.0, None))
    out.kappa_used[idx] = np.sqrt(second)
    out.misfit, out.dof = misfit, int(dof)
    return out


@dataclass
class ShareScale:
    """How far the stated share of the shading correction that is wrong fits what the pairs'
    disagreement shows (:func:`share_scale_from_pairs`).

    Attributes
    ----------
    scale_used : float
        ``sqrt(E[s^2])`` under the prior and the data: the stated share is multiplied by it.
    scale_map : float
        The posterior's most probable ``s`` on the grid.
    dof : int
        Independent numbers the pairs' disagreement gave (0: the prior alone, ``scale_used`` 1).
    chi2_stated : float
        The disagreement's chi-square with the share as stated (``s = 1``), over ``dof``.
    prior_log_sigma : float
    note : str
    """

    scale_used: float = 1.0
    scale_map: float = float("nan")
    dof: int = 0
    chi2_stated: float = float("nan")
    prior_log_sigma: float = 0.7
    note: str = ""
    log_likelihood: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        def f(x):
            return None if not np.isfinite(x) else float(x)
        return {"scale_used": f(self.scale_used), "scale_map": f(self.scale_map), "dof": int(self.dof),
                "chi2_stated": f(self.chi2_stated), "prior_log_sigma": self.prior_log_sigma, "note": self.note}


#: the grid of scales ``s`` of :func:`share_scale_from_pairs` (log-spaced: 1/16 to 16 x the stated share)
SCALE_GRID = np.exp(np.linspace(np.log(1.0 / 16.0), np.log(16.0), 49))


def share_scale_from_pairs(fit, model, group_index, pair_index, shape_covariance, modes_at, fixed_modes=None,
                           prior_log_sigma: float = 0.7, grid=SCALE_GRID, min_images: int = 4) -> ShareScale:
    """How much to scale the stated share of the shading correction that is wrong, from how far
    the stereo pairs' positions disagree with each other.

    Each pair sees the ball from its own side, lit by its own flash: a wrong share moves its
    positions by its own pattern (:func:`stillcap.ball.uncertainty.remaining_bias_modes`),
    which the joint flight cannot take up for both pairs at once. The positions-only fit's
    residuals are regressed on a shift and a drift of each pair's positions against the
    reference pair's (3 + 3 columns per other pair, whitened with each position's covariance
    shape, the flight's own columns projected out): ``z``, at most 6 numbers per other pair,
    whose covariance is ``I + B(s) B(s)^T`` for the random centre error (the shapes' stated
    level) and the remaining-bias modes ``modes_at(s)`` at ``s`` times the stated share
    (``fixed_modes``: others, e.g. calibration, at their stated size). The likelihood of ``z``
    on a grid of ``s`` with the prior ``log s ~ N(-sigma^2, sigma^2)`` (``sigma`` =
    ``prior_log_sigma``; its ``E[s^2]`` is 1, the stated share) gives the posterior's
    ``E[s^2]``: the share used is the stated one times ``sqrt(E[s^2])`` (tighter where the pairs
    agree better than the stated share allows, wider where they disagree more).

    This sees what the pairs do not share: a wrong share common to every camera (the same blur
    missed by all four) moves both pairs alike and is sized by the prior alone. With one pair
    (or fewer than ``min_images`` positions in another) the capture cannot tell: ``s = 1``.
    Pairs that see different stretches of the flight (the studio's rig) tell little: a shift of
    one against the other is the flight's direction, which the joint fit takes up
    (``docs/pitch.md``, "Coverage with 12 captures per condition, and the share scaled by the
    pairs?": not adopted). Written by hand: a marginal likelihood over one scale no library offers for these modes.

    Parameters
    ----------
    fit : ReferenceFit
        The positions-only joint fit.
    model : FlightModel
    group_index, pair_index : array_like of int, shape (N,)
        Clock group (as :func:`fitted_response`) and pair of each position.
    shape_covariance : array_like, shape (N, 3, 3)
        Each position's random-error covariance (m^2), the fit's weights.
    modes_at : callable
        ``modes_at(s)`` -> ndarray (M, N, 3): the remaining-bias modes of every pair (m) with
        the stated share times ``s``.
    fixed_modes : array_like, shape (M2, N, 3), optional

    Returns
    -------
    ShareScale
    """
    out = ShareScale(prior_log_sigma=float(prior_log_sigma))
    g = np.asarray(group_index, int)
    pi = np.asarray(pair_index, int)
    r = -np.asarray(fit.residuals, float)
    S = np.asarray(shape_covariance, float)
    N = len(r)
    if g.shape != (N,) or pi.shape != (N,) or S.shape != (N, 3, 3):
        raise ValueError(f"group_index and pair_index must have shape ({N},) and shape_covariance ({N}, 3, 3), "
                         f"got {g.shape}, {pi.shape}, {S.shape}")
    J, ok = _flight_jacobian(fit, model, g)
    ok &= np.all(np.isfinite(S), axis=(1, 2))
    pairs = [i for i in np.unique(pi[ok]) if np.count_nonzero(ok & (pi == i)) >= min_images]
    ref = [i for i in pairs if np.all(g[pi == i] == 0)]
    others = [i for i in pairs if i not in ref[:1]]
    if len(pairs) < 2 or not others:
        out.note = "one pair: the stated share"
        return out
    t = np.asarray(fit.times, float)
    cols = []
    for i in others:  # a shift and a drift of pair i's positions
        m = (ok & (pi == i)).astype(float)
        tc = (t - np.mean(t[ok & (pi == i)])) * m
        for prof in (m, tc / max(np.ptp(t[ok]), 1e-9)):
            for j in range(3):
                c = np.zeros((N, 3))
                c[:, j] = prof
                cols.append(c)
    Lw = _whitening(S[ok])

    def white(v):  # (N, 3) -> (3n,)
        return np.einsum("nij,nj->ni", Lw, v[ok]).ravel()

    Jw = np.stack([white(J[:, :, p]) for p in range(J.shape[-1])], axis=1)
    Uf, sf, _ = np.linalg.svd(Jw, full_matrices=False)
    Qf = Uf[:, sf > 1e-9 * sf[0]]
    X = np.stack([white(c) for c in cols], axis=1)
    X = X - Qf @ (Qf.T @ X)
    Ux, sx, _ = np.linalg.svd(X, full_matrices=False)
    Q = Ux[:, sx > 1e-6 * sx[0]] if sx.size and sx[0] > 0 else Ux[:, :0]
    k = Q.shape[1]
    if k == 0:
        out.note = "the pairs' shifts are the flight's: the stated share"
        return out
    z = Q.T @ white(r)

    def proj(modes):
        D = np.nan_to_num(np.asarray(modes, float))
        return np.stack([Q.T @ white(d) for d in D], axis=1) if len(D) else np.zeros((k, 0))

    F = proj(fixed_modes) if fixed_modes is not None else np.zeros((k, 0))
    base = np.eye(k) + F @ F.T
    grid = np.asarray(grid, float)
    ll = np.empty(len(grid))
    for n, s in enumerate(grid):
        B = proj(modes_at(float(s)))
        C = base + B @ B.T
        _, logdet = np.linalg.slogdet(C)
        ll[n] = -0.5 * (z @ np.linalg.solve(C, z) + logdet)
        if np.isclose(s, 1.0):
            out.chi2_stated = float(z @ np.linalg.solve(C, z))
    sp = float(prior_log_sigma)
    logprior = -0.5 * ((np.log(grid) + sp ** 2) / sp) ** 2  # the grid is uniform in log s
    lp = ll + logprior
    w = np.exp(lp - lp.max())
    w /= w.sum()
    out.log_likelihood = ll
    out.scale_used = float(np.sqrt(w @ grid ** 2))
    out.scale_map = float(grid[int(np.argmax(lp))])
    out.dof = int(k)
    return out
