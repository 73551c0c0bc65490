"""N-view triangulation, vectorised over points, NaN for "not seen".

Methods
-------
``"dlt"``
    Linear triangulation (Hartley & Zisserman 12.2) on normalised image coordinates, solved in
    its inhomogeneous form (X = (x, y, z, 1)), which is exact for points at finite distance.
``"midpoint"``
    The thesis's method: the least-squares point nearest to all back-projection lines.
Either start can be refined by Gauss-Newton on the reprojection error (``refine=True``) and
guarded by outlier rejection over view subsets (``outlier_px``): every camera pair proposes a
point, the one that most views agree with (reprojection below ``outlier_px``) wins, and the
point is re-estimated from the views that agree.

All 3x3 systems here are solved in closed form over all points at once: a batched LAPACK call
(``np.linalg.solve``) on millions of tiny systems costs several times more than the formula.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from stillcap._checks import as_array
from stillcap.camera import Camera, Rig


@dataclass
class Triangulation:
    """Result of :func:`triangulate`.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        World points; NaN where fewer than ``min_views`` views agree.
    reproj_error_px : ndarray, shape (N,)
        RMS reprojection error over the views used (distorted pixels); NaN if not triangulated.
    errors_px : ndarray, shape (n_cams, N)
        Reprojection error of the point in every view that saw it (NaN where unseen).
    used : ndarray of bool, shape (n_cams, N)
        Views used for each point (outliers and unseen views are False).
    """

    points: np.ndarray
    reproj_error_px: np.ndarray
    errors_px: np.ndarray
    used: np.ndarray

    @property
    def n_views(self) -> np.ndarray:
        """Number of views used per point, shape (N,)."""
        return self.used.sum(axis=0)

    @property
    def ok(self) -> np.ndarray:
        """Points that were triangulated, shape (N,) bool."""
        return np.all(np.isfinite(self.points), axis=1)

    @property
    def success(self) -> bool:
        return bool(np.any(self.ok))


def _cameras(cameras) -> list[Camera]:
    cams = list(cameras.cameras if isinstance(cameras, Rig) else cameras)
    if not all(isinstance(c, Camera) for c in cams):
        raise ValueError("cameras must be a Rig or a sequence of Camera objects")
    return cams


def _solve_sym3(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve symmetric 3x3 systems ``A x = b`` for A of shape (N, 3, 3), b (N, 3) (Cramer's rule)."""
    a00, a01, a02 = A[:, 0, 0], A[:, 0, 1], A[:, 0, 2]
    a11, a12, a22 = A[:, 1, 1], A[:, 1, 2], A[:, 2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = 1.0 / np.where(np.abs(det) > 1e-300, det, np.nan)
        x0 = (c00 * b[:, 0] + c01 * b[:, 1] + c02 * b[:, 2]) * inv
        x1 = (c01 * b[:, 0] + c11 * b[:, 1] + c12 * b[:, 2]) * inv
        x2 = (c02 * b[:, 0] + c12 * b[:, 1] + c22 * b[:, 2]) * inv
    return np.stack([x0, x1, x2], axis=1)


def _dlt(world2cams: np.ndarray, xn: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Inhomogeneous DLT. world2cams (C, 3, 4), xn (C, N, 2) normalised, mask (C, N)."""
    n = xn.shape[1]
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    for P, x, m in zip(world2cams, xn, mask):
        w = m.astype(float)
        xs, ys = np.where(m, x[:, 0], 0.0), np.where(m, x[:, 1], 0.0)
        for row in (xs[:, None] * P[2] - P[0], ys[:, None] * P[2] - P[1]):  # (N, 4)
            r = row * w[:, None]
            A += r[:, :3, None] * r[:, None, :3]
            b -= r[:, :3] * r[:, 3:4]
    return _solve_sym3(A, b)


def _midpoint(world2cams: np.ndarray, xn: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Point nearest (least squares) to the back-projection lines of the masked views."""
    n = xn.shape[1]
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    eye = np.eye(3)
    for P, x, m in zip(world2cams, xn, mask):
        R, t = P[:, :3], P[:, 3]
        centre = -R.T @ t
        d = np.concatenate([np.where(m[:, None], x, 0.0), np.ones((n, 1))], axis=1) @ R
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        proj = (eye[None] - d[:, :, None] * d[:, None, :]) * m[:, None, None]
        A += proj
        b += proj @ centre
    return _solve_sym3(A, b)


def _refine(world2cams, K, xn, mask, X, iterations: int = 5) -> np.ndarray:
    """Gauss-Newton on the reprojection error in undistorted pixels (distortion removed first).

    Hand-written rather than ``scipy.optimize.least_squares`` because it solves millions of
    independent 3-parameter problems at once; a per-point solver call would be ~1e4x slower.
    """
    X = X.copy()
    good = np.all(np.isfinite(X), axis=1)
    for _ in range(iterations):
        JtJ = np.zeros((len(X), 3, 3))
        Jtr = np.zeros((len(X), 3))
        for P, k, x, m in zip(world2cams, K, xn, mask):
            R, t = P[:, :3], P[:, 3]
            pc = X @ R.T + t
            z = np.where(m & good & (pc[:, 2] > 0), pc[:, 2], np.nan)
            u, v = pc[:, 0] / z, pc[:, 1] / z
            w = np.isfinite(z)
            fx, s, fy = k[0, 0], k[0, 1], k[1, 1]
            # residuals in pixels: K (proj - observed)
            du, dv = u - np.where(m, x[:, 0], 0), v - np.where(m, x[:, 1], 0)
            r = np.stack([fx * du + s * dv, fy * dv], axis=1)
            # d(u, v)/d(pc), then through K and R
            iz = 1.0 / z
            dn = np.zeros((len(X), 2, 3))
            dn[:, 0, 0], dn[:, 0, 2] = iz, -u * iz
            dn[:, 1, 1], dn[:, 1, 2] = iz, -v * iz
            Kp = np.array([[fx, s], [0.0, fy]])
            J = np.einsum("ij,njk,kl->nil", Kp, dn, R)
            J[~w] = 0.0
            r[~w] = 0.0
            JtJ += np.einsum("nki,nkj->nij", J, J)
            Jtr += np.einsum("nki,nk->ni", J, r)
        step = _solve_sym3(JtJ + 1e-12 * np.eye(3), -Jtr)
        ok = good & np.all(np.isfinite(step), axis=1)
        X[ok] += step[ok]
        if np.all(np.abs(step[ok]) < 1e-12):
            break
    return X


def reprojection_errors(cameras, points_3d, points_2d) -> np.ndarray:
    """Pixel distance between observed and projected points, shape (n_cams, N); NaN where unseen."""
    cams = _cameras(cameras)
    x = as_array(points_2d, (len(cams), None, 2), "points_2d")
    X = as_array(points_3d, (x.shape[1], 3), "points_3d")
    return np.stack([np.linalg.norm(c.project(X) - xi, axis=1) for c, xi in zip(cams, x)])


def triangulate(cameras, points_2d, method: str = "dlt", refine: bool = True,
                outlier_px: float | None = None, min_views: int = 2) -> Triangulation:
    """Triangulate points seen by several calibrated cameras.

    Parameters
    ----------
    cameras : Rig or sequence of Camera, length n_cams
    points_2d : array_like, shape (n_cams, N, 2)
        Distorted pixel observations; NaN where a camera did not see the point.
    method : {"dlt", "midpoint"}
        Linear start (see module docstring).
    refine : bool
        Minimise the reprojection error (Gauss-Newton) from the linear start.
    outlier_px : float, optional
        Reject views whose reprojection error exceeds this many pixels (needs 3+ views of a
        point to tell which view is wrong).
    min_views : int
        Points with fewer usable views come back as NaN.
    """
    cams = _cameras(cameras)
    x = as_array(points_2d, (len(cams), None, 2), "points_2d")
    if method not in ("dlt", "midpoint"):
        raise ValueError(f"method must be 'dlt' or 'midpoint', got {method!r}")
    if min_views < 2:
        raise ValueError(f"min_views must be at least 2, got {min_views}")
    world2cams = np.stack([c.world2cam[:3] for c in cams])
    Ks = np.stack([c.K for c in cams])
    xn = np.stack([c.pixels_to_normalized(xi) for c, xi in zip(cams, x)])
    seen = np.all(np.isfinite(xn), axis=2)
    linear = _dlt if method == "dlt" else _midpoint

    def solve(mask):
        X = linear(world2cams, xn, mask)
        if refine:
            X = _refine(world2cams, Ks, xn, mask, X)
        X[mask.sum(axis=0) < min_views] = np.nan
        return X

    mask = seen
    if outlier_px is not None and len(cams) >= 3:
        mask = _consensus(cams, world2cams, xn, x, seen, linear, outlier_px)
    X = solve(mask)
    errors = reprojection_errors(cams, X, x)
    if outlier_px is not None:
        # views that disagree with the final point are not used (and the point is re-estimated)
        mask2 = seen & (errors <= outlier_px)
        if np.any(mask2 != mask):
            mask = mask2
            X = solve(mask)
            errors = reprojection_errors(cams, X, x)
    used = mask & np.all(np.isfinite(X), axis=1)[None]
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nansum(np.where(used, errors, np.nan) ** 2, axis=0) / used.sum(axis=0))
    return Triangulation(X, rms, np.where(seen, errors, np.nan), used)


def _consensus(cams, world2cams, xn, x, seen, linear, outlier_px) -> np.ndarray:
    """Views of each point that agree with the best pair hypothesis (RANSAC over view pairs).

    With the handful of cameras of a capture rig all pairs are tried (deterministic, and cheaper
    than random sampling for n_cams <= ~12).
    """
    n_cams, n = seen.shape
    best_count = np.zeros(n, int)
    best_err = np.full(n, np.inf)
    best_mask = seen.copy()
    for i, j in combinations(range(n_cams), 2):
        pair = np.zeros_like(seen)
        pair[i], pair[j] = seen[i] & seen[j], seen[i] & seen[j]
        X = linear(world2cams, xn, pair)
        X[~(seen[i] & seen[j])] = np.nan
        err = reprojection_errors(cams, X, x)
        inl = seen & (err <= outlier_px)
        count = inl.sum(axis=0)
        score = np.where(inl, err, 0.0).sum(axis=0)
        better = (count > best_count) | ((count == best_count) & (count >= 2) & (score < best_err))
        best_count = np.where(better, count, best_count)
        best_err = np.where(better, score, best_err)
        best_mask[:, better] = inl[:, better]
    return best_mask
