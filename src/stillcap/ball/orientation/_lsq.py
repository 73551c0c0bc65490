"""A small robust least-squares solver for the spin fit (:func:`solve_small_lsq`).

Written by hand instead of calling ``scipy.optimize.least_squares`` for each start of the spin
fit: the problem has 6 parameters and ~50-200 residuals, so every SciPy iteration spent ~0.3 ms
in its own set-up, wrappers and bookkeeping against ~0.2 ms for the model's residuals and
Jacobian (issue 16: a pitch's pair fits run 10-20 solves of 5-25 iterations). It is SciPy's
own algorithm for this case, step for step: the trust-region reflective method without bounds
and with the exact trust-region solver (``method="trf"``, ``tr_solver="exact"``; More's
Levenberg-Marquardt parameter search on one SVD per iteration), the same robust losses and
their scaling of residuals and Jacobian, the same trust-radius updates and stopping tests
(``ftol``, ``xtol``, ``gtol``, ``max_nfev``). So it follows the same path to the same minimum,
to rounding; only the overhead is gone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_EPS = np.finfo(float).eps


@dataclass
class SmallLsqResult:
    """The fields of SciPy's ``OptimizeResult`` the spin fit reads."""

    x: np.ndarray
    cost: float
    status: int  # 0 max_nfev, 1 gtol, 2 ftol, 3 xtol, 4 ftol and xtol (SciPy's codes)
    nfev: int
    njev: int


def _rho(f, loss: str, f_scale: float, cost_only: bool = False):
    """SciPy's robust loss of residuals ``f`` scaled by ``f_scale``: the cost, or
    ``(rho, rho', rho'')`` with ``rho`` and ``rho''`` rescaled as SciPy's ``construct_loss_function``
    does. A trial step far out may overflow: its cost is then not finite and the step refused."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        z = (f / f_scale) ** 2
        if loss == "soft_l1":
            t = 1 + z
            r0 = 2 * (t ** 0.5 - 1)
            if cost_only:
                return 0.5 * f_scale ** 2 * np.sum(r0)
            r1, r2 = t ** -0.5, -0.5 * t ** -1.5
        elif loss == "huber":
            mask = z <= 1
            r0, r1, r2 = np.empty_like(z), np.empty_like(z), np.empty_like(z)
            r0[mask] = z[mask]
            r0[~mask] = 2 * z[~mask] ** 0.5 - 1
            if cost_only:
                return 0.5 * f_scale ** 2 * np.sum(r0)
            r1[mask], r1[~mask] = 1, z[~mask] ** -0.5
            r2[mask], r2[~mask] = 0, -0.5 * z[~mask] ** -1.5
        elif loss == "cauchy":
            r0 = np.log1p(z)
            if cost_only:
                return 0.5 * f_scale ** 2 * np.sum(r0)
            t = 1 + z
            r1, r2 = 1 / t, -1 / t ** 2
        else:
            raise ValueError(f"loss must be 'linear', 'soft_l1', 'huber' or 'cauchy', got {loss!r}")
        return r0 * f_scale ** 2, r1, r2 / f_scale ** 2


def _scaled(J, f, loss, f_scale):
    """Cost, and the Jacobian and residuals scaled for the robust loss (SciPy's
    ``scale_for_robust_loss_function``; unchanged for ``"linear"``)."""
    if loss == "linear":
        return 0.5 * np.dot(f, f), J, f
    r0, r1, r2 = _rho(f, loss, f_scale)
    J_scale = r1 + 2 * r2 * f ** 2
    J_scale[J_scale < _EPS] = _EPS
    J_scale **= 0.5
    return 0.5 * np.sum(r0), J * J_scale[:, None], f * (r1 / J_scale)


def _tr_step(n, m, uf, s, V, Delta, alpha):
    """SciPy's ``solve_lsq_trust_region`` (More's Levenberg-Marquardt parameter search, rtol 0.01,
    10 iterations at most): the step of the trust-region subproblem of radius ``Delta``."""
    def phi_and_derivative(alpha):
        denom = s ** 2 + alpha
        p_norm = np.linalg.norm(suf / denom)
        return p_norm - Delta, -np.sum(suf ** 2 / denom ** 3) / p_norm

    suf = s * uf
    full_rank = m >= n and s[-1] > _EPS * m * s[0]
    if full_rank:
        p = -V.dot(uf / s)
        if np.linalg.norm(p) <= Delta:
            return p, 0.0
    alpha_upper = np.linalg.norm(suf) / Delta
    if full_rank:
        phi, phi_prime = phi_and_derivative(0.0)
        alpha_lower = -phi / phi_prime
    else:
        alpha_lower = 0.0
    if not full_rank and alpha == 0:
        alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
    for _ in range(10):
        if alpha < alpha_lower or alpha > alpha_upper:
            alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
        phi, phi_prime = phi_and_derivative(alpha)
        if phi < 0:
            alpha_upper = alpha
        ratio = phi / phi_prime
        alpha_lower = max(alpha_lower, alpha - ratio)
        alpha -= (phi + Delta) * ratio / Delta
        if np.abs(phi) < 0.01 * Delta:
            break
    p = -V.dot(suf / (s ** 2 + alpha))
    p *= Delta / np.linalg.norm(p)
    return p, alpha


def solve_small_lsq(fun, jac, x0, args=(), *, loss: str = "linear", f_scale: float = 1.0, x_scale=1.0,
                    xtol: float = 1e-8, ftol: float = 1e-8, gtol: float = 1e-8,
                    max_nfev: int = 100) -> SmallLsqResult:
    """Minimise ``0.5 f_scale^2 sum(rho((fun(x) / f_scale)^2))`` (``rho`` the ``loss``) from ``x0``,
    as ``scipy.optimize.least_squares(fun, x0, jac, method="trf", tr_solver="exact", ...)`` does
    without bounds.

    ``fun(x, *args)`` returns the residuals (m,), ``jac(x, *args)`` their Jacobian (m, n), asked
    for at accepted points only, after the residuals at the same point.
    """
    x = np.array(x0, float)
    f = fun(x, *args)
    if not np.all(np.isfinite(f)):
        raise ValueError("Residuals are not finite in the initial point.")
    J = jac(x, *args)
    nfev = njev = 1
    m, n = J.shape
    cost, Jw, fw = _scaled(J, f, loss, f_scale)
    g = Jw.T.dot(fw)
    d = np.broadcast_to(np.asarray(x_scale, float), x.shape)
    Delta = np.linalg.norm(x / d)
    if Delta == 0:
        Delta = 1.0
    alpha = 0.0
    status = None
    while True:
        if np.linalg.norm(g, ord=np.inf) < gtol:
            status = 1
        if status is not None or nfev == max_nfev:
            break
        g_h = d * g
        J_h = Jw * d
        U, s, Vt = np.linalg.svd(J_h, full_matrices=False)
        V = Vt.T
        uf = U.T.dot(fw)
        actual = -1
        while actual <= 0 and nfev < max_nfev:
            step_h, alpha = _tr_step(n, m, uf, s, V, Delta, alpha)
            Js = J_h.dot(step_h)
            predicted = -(0.5 * np.dot(Js, Js) + np.dot(step_h, g_h))
            step = d * step_h
            x_new = x + step
            f_new = fun(x_new, *args)
            nfev += 1
            step_h_norm = np.linalg.norm(step_h)
            if not np.all(np.isfinite(f_new)):
                Delta = 0.25 * step_h_norm
                continue
            cost_new = 0.5 * np.dot(f_new, f_new) if loss == "linear" else _rho(f_new, loss, f_scale, True)
            actual = cost - cost_new
            # SciPy's update_tr_radius and check_termination
            if predicted > 0:
                ratio = actual / predicted
            elif predicted == actual == 0:
                ratio = 1
            else:
                ratio = 0
            Delta_new = Delta
            if ratio < 0.25:
                Delta_new = 0.25 * step_h_norm
            elif ratio > 0.75 and step_h_norm > 0.95 * Delta:
                Delta_new = 2.0 * Delta
            f_ok = actual < ftol * cost and ratio > 0.25
            x_ok = np.linalg.norm(step) < xtol * (xtol + np.linalg.norm(x))
            status = 4 if f_ok and x_ok else 2 if f_ok else 3 if x_ok else None
            if status is not None:
                break
            alpha *= Delta / Delta_new
            Delta = Delta_new
        if actual > 0:
            x, f, cost = x_new, f_new, cost_new
            if status is not None:  # stopping: no Jacobian needed at the last point
                break
            J = jac(x, *args)
            njev += 1
            _, Jw, fw = _scaled(J, f, loss, f_scale)
            g = Jw.T.dot(fw)
    return SmallLsqResult(x, float(cost), 0 if status is None else status, nfev, njev)
