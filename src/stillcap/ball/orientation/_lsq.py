"""A small robust least-squares solver for the spin fit (:func:`solve_small_lsq`).

Written by hand instead of calling ``scipy.optimize.least_squares`` for each start of the spin
fit: the problem has 6 parameters and ~50-200 residuals, so every SciPy iteration spent ~0.3 ms
in its own set-up, wrappers, SVD and bookkeeping against ~0.2 ms for the model's residuals and
Jacobian (issue 16: the pair spin fits run 10-20 solves of 5-25 iterations per pitch). This is
Levenberg-Marquardt with Nielsen's damping update on the same cost as SciPy's (the same robust
losses, scaled by ``f_scale``, variables scaled by ``x_scale``) and SciPy's stopping tests
(``ftol``, ``xtol``, ``gtol``, ``max_nfev``): it converges to the same minimum, within those
tolerances, along a different path.
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
    status: int  # 0 max_nfev, 1 gtol, 2 ftol, 3 xtol (SciPy's codes)
    nfev: int
    njev: int


def _loss(f, loss: str, f_scale: float):
    """``(cost, rho'(z), rho'(z) + 2 z rho''(z))`` of residuals ``f`` with ``z = (f / f_scale)^2``
    (SciPy's definitions of the losses and of the robust Gauss-Newton weights). A trial step
    far out may overflow: its cost is then not finite and the step is refused."""
    with np.errstate(over="ignore", invalid="ignore"):
        return _loss_terms(f, loss, f_scale)


def _loss_terms(f, loss, f_scale):
    z = (f / f_scale) ** 2
    if loss == "linear":
        one = np.ones_like(z)
        return 0.5 * float(f @ f), one, one
    if loss == "soft_l1":
        t = 1.0 + z
        rho0 = 2.0 * (np.sqrt(t) - 1.0)
        rho1 = 1.0 / np.sqrt(t)
        rho2 = -0.5 * rho1 / t
    elif loss == "huber":
        big = z > 1.0
        sz = np.sqrt(np.where(big, z, 1.0))
        rho0 = np.where(big, 2.0 * sz - 1.0, z)
        rho1 = np.where(big, 1.0 / sz, 1.0)
        rho2 = np.where(big, -0.5 / (sz * z + ~big), 0.0)
    elif loss == "cauchy":
        t = 1.0 + z
        rho0 = np.log1p(z)
        rho1 = 1.0 / t
        rho2 = -rho1 * rho1
    else:
        raise ValueError(f"loss must be 'linear', 'soft_l1', 'huber' or 'cauchy', got {loss!r}")
    return 0.5 * f_scale ** 2 * float(rho0.sum()), rho1, np.maximum(rho1 + 2.0 * rho2 * z, _EPS)


def solve_small_lsq(fun, jac, x0, args=(), *, loss: str = "linear", f_scale: float = 1.0, x_scale=1.0,
                    xtol: float = 1e-8, ftol: float = 1e-8, gtol: float = 1e-8,
                    max_nfev: int = 100) -> SmallLsqResult:
    """Minimise ``0.5 f_scale^2 sum(rho((fun(x) / f_scale)^2))`` (``rho`` the ``loss``) from ``x0``.

    ``fun(x, *args)`` returns the residuals (m,), ``jac(x, *args)`` their Jacobian (m, n); the
    Jacobian is asked for only at accepted points, after the residuals at the same point.
    Stopping tests as SciPy's: ``gtol`` on the largest scaled gradient component, ``ftol`` on
    the relative decrease of the cost of an accepted step, ``xtol`` on the scaled step relative
    to the scaled parameters, at most ``max_nfev`` residual evaluations.
    """
    x = np.array(x0, float)
    d = np.broadcast_to(np.asarray(x_scale, float), x.shape).copy()
    f = fun(x, *args)
    nfev, njev = 1, 1
    cost, rho1, wgt = _loss(f, loss, f_scale)
    J = jac(x, *args)
    mu, nu = None, 2.0
    status = 0
    while status == 0:
        Jd = J * d  # scaled variables y = x / d
        g = Jd.T @ (rho1 * f)
        if np.max(np.abs(g)) < gtol:
            status = 1
            break
        H = (Jd * wgt[:, None]).T @ Jd
        if mu is None:
            mu = max(1e-3 * float(np.max(np.diag(H))), 1e-12)
        while True:
            if nfev >= max_nfev:
                return SmallLsqResult(x, cost, 0, nfev, njev)
            try:
                step = np.linalg.solve(H + mu * np.eye(len(x)), -g)
            except np.linalg.LinAlgError:
                mu, nu = mu * nu, nu * 2.0
                continue
            if np.linalg.norm(step) <= xtol * (xtol + np.linalg.norm(x / d)):
                status = 3
                break
            x_new = x + step * d
            f_new = fun(x_new, *args)
            nfev += 1
            cost_new, rho1_new, wgt_new = _loss(f_new, loss, f_scale)
            predicted = -(g @ step + 0.5 * step @ H @ step)
            actual = cost - cost_new
            if np.isfinite(cost_new) and actual > 0 and predicted > 0:
                ratio = actual / predicted
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
                nu = 2.0
                done = actual < ftol * cost and ratio > 0.25
                x, f, cost, rho1, wgt = x_new, f_new, cost_new, rho1_new, wgt_new
                if done:  # converged: no Jacobian needed at the last point
                    status = 2
                    break
                J = jac(x, *args)
                njev += 1
                break
            mu, nu = mu * nu, nu * 2.0
    return SmallLsqResult(x, cost, status, nfev, njev)
