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

All methods reduce to 3x3 normal equations per point, accumulated and solved over all points at
once (:class:`_Normal3`).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from stillcap._checks import as_array
from stillcap.camera import Camera, Rig
from stillcap.geometry.robust import consensus


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


class _Normal3:
    """Accumulates symmetric 3x3 normal equations ``A x = b`` for N points at once.

    Only the six unique entries of ``A`` are kept as flat (N,) arrays: building (N, 3, 3)
    temporaries costs more than the arithmetic. The system is solved in closed form (Cramer's
    rule); a batched LAPACK call on millions of 3x3 systems is several times slower.
    """

    def __init__(self, n: int):
        self.a = np.zeros((6, n))  # a00, a01, a02, a11, a12, a22
        self.b = np.zeros((3, n))

    def add_rows(self, J: np.ndarray, r: np.ndarray) -> None:
        """Add ``J^T J`` and ``J^T r`` for one scalar equation ``J . x = r`` per point (J (3, N), r (N,))."""
        j0, j1, j2 = J
        a = self.a
        a[0] += j0 * j0
        a[1] += j0 * j1
        a[2] += j0 * j2
        a[3] += j1 * j1
        a[4] += j1 * j2
        a[5] += j2 * j2
        self.b += J * r

    def solve(self, damping: float = 0.0) -> np.ndarray:
        a00, a01, a02, a11, a12, a22 = self.a
        if damping:
            a00, a11, a22 = a00 + damping, a11 + damping, a22 + damping
        b0, b1, b2 = self.b
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        det = a00 * c00 + a01 * c01 + a02 * c02
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = 1.0 / np.where(np.abs(det) > 1e-300, det, np.nan)
            return np.stack([(c00 * b0 + c01 * b1 + c02 * b2) * inv,
                             (c01 * b0 + c11 * b1 + c12 * b2) * inv,
                             (c02 * b0 + c12 * b1 + c22 * b2) * inv], axis=1)


def _dlt(world2cams: np.ndarray, xn: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Inhomogeneous DLT. world2cams (C, 3, 4), xn (C, N, 2) normalised, mask (C, N)."""
    eq = _Normal3(xn.shape[1])
    for P, x, m in zip(world2cams, xn, mask):
        for k in (0, 1):
            c = np.where(m, x[:, k], 0.0)
            # row = c * P[2] - P[k], zeroed where the view is unused
            J = (c[None, :] * P[2, :3, None] - P[k, :3, None]) * m
            eq.add_rows(J, -(c * P[2, 3] - P[k, 3]) * m)
    return eq.solve()


def _midpoint(world2cams: np.ndarray, xn: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Point nearest (least squares) to the back-projection lines of the masked views.

    Each line contributes ``(I - d d^T) X = (I - d d^T) o``; written as the two equations of
    the line's normal directions so it shares the accumulator with DLT.
    """
    eq = _Normal3(xn.shape[1])
    for P, x, m in zip(world2cams, xn, mask):
        R, t = P[:, :3], P[:, 3]
        centre = -R.T @ t
        xs, ys = np.where(m, x[:, 0], 0.0), np.where(m, x[:, 1], 0.0)
        norm = np.sqrt(xs * xs + ys * ys + 1.0)
        # two unit normals of the ray (camera frame): (1, 0, -x) and (-xy, 1+x^2, -y) orthonormalised
        n1 = np.stack([np.ones_like(xs), np.zeros_like(xs), -xs]) / np.sqrt(1 + xs * xs)
        d = np.stack([xs, ys, np.ones_like(xs)]) / norm
        n2 = np.cross(d.T, n1.T).T
        for nc in (n1, n2):
            nw = R.T @ nc * m  # normal in the world frame (3, N)
            eq.add_rows(nw, nw.T @ centre)
    return eq.solve()


def _refine(world2cams, K, xn, mask, X, iterations: int = 4) -> np.ndarray:
    """Gauss-Newton on the reprojection error in undistorted pixels (distortion removed first).

    Hand-written rather than ``scipy.optimize.least_squares`` because it solves millions of
    independent 3-parameter problems at once; a per-point solver call would be ~1e4x slower.
    """
    X = X.copy()
    good = np.all(np.isfinite(X), axis=1)
    for _ in range(iterations):
        eq = _Normal3(len(X))
        for P, k, x, m in zip(world2cams, K, xn, mask):
            R, t = P[:, :3], P[:, 3]
            pc = X @ R.T + t
            w = m & good & (pc[:, 2] > 0)
            iz = np.where(w, 1.0 / np.where(w, pc[:, 2], 1.0), 0.0)
            u, v = pc[:, 0] * iz, pc[:, 1] * iz
            du, dv = (u - np.where(w, x[:, 0], 0.0)) * w, (v - np.where(w, x[:, 1], 0.0)) * w
            # d(u, v)/dX = d(u, v)/d(pc) R, rows (3, N)
            du_dX = (R[0][:, None] - R[2][:, None] * u) * iz
            dv_dX = (R[1][:, None] - R[2][:, None] * v) * iz
            fx, s, fy = k[0, 0], k[0, 1], k[1, 1]
            eq.add_rows(fx * du_dX + s * dv_dX, -(fx * du + s * dv))  # pixel residuals through K
            eq.add_rows(fy * dv_dX, -fy * dv)
        step = eq.solve(damping=1e-12)
        ok = good & np.all(np.isfinite(step), axis=1)
        X[ok] += step[ok]
        if not np.any(np.abs(step[ok]) > 1e-10):
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
    # Blocks of points small enough for the CPU cache: every step streams whole arrays, and
    # on 1e6 points memory bandwidth, not arithmetic, sets the speed.
    parts = [_triangulate_block(cams, x[:, i:i + BLOCK], method, refine, outlier_px, min_views)
             for i in range(0, max(x.shape[1], 1), BLOCK)]
    return Triangulation(*(np.concatenate(arrays, axis=-2 if k == 0 else -1)
                           for k, arrays in enumerate(zip(*parts))))


BLOCK = 1 << 14


def _triangulate_block(cams, x, method, refine, outlier_px, min_views):
    world2cams = np.stack([c.world2cam[:3] for c in cams])
    Ks = np.stack([c.K for c in cams])
    xn = np.stack([c.pixels_to_normalized(xi) for c, xi in zip(cams, x)])
    seen = np.isfinite(xn[..., 0]) & np.isfinite(xn[..., 1])
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
    return X, rms, np.where(seen, errors, np.nan), used


class _PairPoints:
    """The robust model of triangulation (:class:`~stillcap.geometry.robust.RobustModel`): a
    hypothesis is a pair of views, its parameters the points triangulated linearly from those two
    views alone, its residuals every view's reprojection error, shape (n_cams, N)."""

    def __init__(self, cams, world2cams, xn, x, seen, linear):
        self.cams, self.world2cams, self.xn, self.x, self.seen, self.linear = cams, world2cams, xn, x, seen, linear

    def estimate(self, pair):
        i, j = pair
        both = self.seen[i] & self.seen[j]
        mask = np.zeros_like(self.seen)
        mask[i], mask[j] = both, both
        X = self.linear(self.world2cams, self.xn, mask)
        X[~both] = np.nan
        return X

    def residuals(self, X):
        return reprojection_errors(self.cams, X, self.x)


def _consensus(cams, world2cams, xn, x, seen, linear, outlier_px) -> np.ndarray:
    """Views of each point that agree with the best pair hypothesis (RANSAC over view pairs).

    With the handful of cameras of a capture rig all pairs are tried (deterministic, and cheaper
    than random sampling for n_cams <= ~12). Points no pair explains keep all their views.
    """
    model = _PairPoints(cams, world2cams, xn, x, seen, linear)
    found = consensus(model, combinations(range(len(cams)), 2), outlier_px, min_inliers=2)
    return np.where(found.best >= 0, found.inliers, seen)
