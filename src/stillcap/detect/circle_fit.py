"""Circles fitted to points on an arc: shared by the bead-arc fit (:mod:`stillcap.detect.bead_arc`)
and the ball detector's crescent and frame-edge fits (:mod:`stillcap.detect.ball._arcs`).

- :func:`kasa_circle`: the algebraic (Kasa) fit, a 3-unknown linear least-squares problem; a
  start, and exact on points that lie on a circle.
- :func:`fit_circle`: robust geometric least squares (soft-L1 loss), with the radius free
  (Newton steps on the loss, ``scipy.optimize.least_squares`` where they do not converge) or
  known (``least_squares``).
- :func:`arc_span_deg`: how much of the circle the points cover, seen from a centre.
- :func:`center_covariance`: the centre's covariance for a given radial noise (the Gauss-Newton
  normal matrix of the fit), which grows as the arc shortens.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from stillcap.detect import _small_linalg

__all__ = ["arc_span_deg", "center_covariance", "fit_circle", "kasa_circle"]


def kasa_circle(points) -> tuple[np.ndarray, float]:
    """Algebraic (Kasa) circle fit of points (N, 2): centre (2,), radius."""
    pts = np.asarray(points, float)
    A = np.column_stack([2 * pts, np.ones(len(pts))])
    b = (pts ** 2).sum(axis=1)
    sol = _small_linalg.lstsq(A, b)  # np.linalg.lstsq's solution, without its per-call set-up
    c = sol[:2]
    return c, float(np.sqrt(max(sol[2] + c @ c, 0.0)))


def fit_circle(points, radius: float | None = None, start=None, f_scale: float = 0.5
               ) -> tuple[np.ndarray, float, float]:
    """Centre (and radius when ``radius`` is None) of the circle through ``points`` (N, 2), by
    robust least squares (soft-L1 loss of scale ``f_scale`` px: a few points off the circle,
    such as a marker's notch, pull little); start ``start`` (default the Kasa centre).

    Returns centre (2,), radius, RMS residual (px).
    """
    points = np.asarray(points, float)
    if start is None:
        start = kasa_circle(points)[0]
    start = np.asarray(start, float)

    def res(x):
        rr = x[2] if radius is None else radius
        return np.hypot(points[:, 0] - x[0], points[:, 1] - x[1]) - rr

    def jac(x):
        # the analytic Jacobian (minus the unit radial direction; -1 for the radius)
        d = points - x[:2]
        u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
        return np.column_stack([-u, -np.ones(len(d))]) if radius is None else -u
    x0 = np.array([start[0], start[1]] + ([float(np.hypot(*(points - start).T).mean())] if radius is None else []))
    # free radius: Newton steps on the loss (fast); not converged (rare), or a known radius (its
    # short arcs have a mirror minimum on the arc's other side, which a trust region keeps away
    # from): scipy's trust-region solver
    x = _soft_l1_newton(points, x0, f_scale) if radius is None else None
    if x is None:
        x = least_squares(res, x0, jac=jac, loss="soft_l1", f_scale=f_scale).x
    r_fit = float(x[2]) if radius is None else float(radius)
    return x[:2], r_fit, float(np.sqrt((res(x) ** 2).mean()))


def _soft_l1_newton(points: np.ndarray, x0: np.ndarray, f_scale: float, tol: float = 1e-8,
                    max_iter: int = 50) -> np.ndarray | None:
    """Centre and radius ``(cx, cy, r)`` of least soft-L1 cost ``sum 2 ((1 + (e/f)^2)^0.5 - 1)``
    (``e`` a point's distance from the circle) near ``x0``: Newton steps on the loss (gradient
    ``J^T (rho' e)``, Gauss-Newton Hessian ``J^T diag(h) J`` with ``h`` the loss's own curvature
    ``rho' + 2 z rho''``, ``z = (e/f)^2``, kept above ``rho'/10`` where a far point makes it
    small or negative), halved while the cost goes up: the same stationary point as
    ``least_squares(..., loss="soft_l1")``. None when the steps do not shrink below ``tol``
    (relative) within ``max_iter``.

    Hand-written for speed: a circle fit has 3 unknowns and a few hundred points, and
    ``scipy.optimize.least_squares`` spends several times the arithmetic on its per-call and
    per-iteration set-up (the ball detector fits ~60 circles a photo; ~0.5 against ~2.4 ms a
    fit of 150 points, best of 5 on a loaded machine). The caller falls back to
    ``least_squares`` when this returns None.
    """
    x = np.array(x0, float)
    # the Jacobian d e / d (cx, cy, r), filled in place each step (its radius column is -1)
    J = np.empty((len(points), 3))
    J[:, 2] = -1.0
    Jc = J[:, :2]

    # Each step's arithmetic is that of the plain expressions (``dx = px - cx``, ``J[:, 0] =
    # -dx / dist``, ``z = (e/f)^2`` once for the cost and again for the step, ``np.abs(step).max()``),
    # in fewer NumPy calls, which on a few dozen points cost more than the arithmetic: the
    # centre's offsets are kept negated (``c - p``: the same numbers with the sign flipped,
    # exactly), so the Jacobian's two columns are one product; the cost's ``z`` and
    # ``sqrt(1 + z)`` serve the next step; 3-vectors are checked as Python floats.
    def at(x):
        nd = x[:2] - points  # -(p - c), exactly
        dist = np.hypot(nd[:, 0], nd[:, 1])
        e = dist - x[2]
        z = (e / f_scale) ** 2
        s = np.sqrt(1.0 + z)
        return nd, dist, e, z, s, float(s.sum())
    nd, dist, e, z, s, cost = at(x)
    for _ in range(max_iter):
        rho1 = 1.0 / s
        h = np.maximum(rho1 - z * rho1 ** 3, 0.1 * rho1)  # rho' + 2 z rho'', rho'' = -(1+z)^-1.5 / 2
        inv = 1.0 / np.maximum(dist, 1e-12)
        np.multiply(nd, inv[:, None], out=Jc)  # -(p - c) / |p - c|
        try:
            # (np.linalg.solve's numbers without its per-call set-up: ~40 % of a step)
            step = _small_linalg.solve((J * h[:, None]).T @ J, -(J.T @ (rho1 * e)))
        except np.linalg.LinAlgError:
            return None
        s0, s1, s2 = step.tolist()
        if not (math.isfinite(s0) and math.isfinite(s1) and math.isfinite(s2)):
            return None
        for _h in range(30):  # halve a step that raises the cost
            xn = x + step
            got = at(xn)
            if got[5] <= cost * (1 + 1e-15):
                break
            step = 0.5 * step
        else:
            return None
        x = xn
        nd, dist, e, z, s, cost = got
        s0, s1, s2 = step.tolist()
        x0_, x1_, x2_ = x.tolist()
        if max(abs(s0), abs(s1), abs(s2)) < tol * (1.0 + max(abs(x0_), abs(x1_), abs(x2_))):
            return x
    return None


def arc_span_deg(points, center) -> float:
    """Angle (degrees) the points cover around ``center``: 360 minus the largest empty gap."""
    p = np.asarray(points, float)
    if len(p) < 2:
        return 0.0
    ang = np.sort(np.arctan2(p[:, 1] - center[1], p[:, 0] - center[0]))
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi]))
    return math.degrees(2 * np.pi - gaps.max())


def center_covariance(points, center, sigma_radial_px: float, radius_known: bool = True) -> np.ndarray:
    """Covariance (2, 2) of a fitted centre when each point's radial distance has independent
    noise ``sigma_radial_px``: ``sigma^2 (J^T J)^-1`` with J the residuals' derivatives (unit
    radial directions; with a free radius also a column of ones, whose correlation with the
    centre is what makes a short arc's centre so loose along its axis). Infinite when singular.
    """
    p = np.asarray(points, float)
    u = p - np.asarray(center, float)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    J = u if radius_known else np.column_stack([u, np.ones(len(u))])
    N = J.T @ J
    try:
        cov = _small_linalg.inv(N)[:2, :2]
    except np.linalg.LinAlgError:
        return np.full((2, 2), np.inf)
    return float(sigma_radial_px) ** 2 * cov
