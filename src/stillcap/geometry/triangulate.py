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

:func:`triangulate_markers` gives :func:`triangulate`'s result for a handful of markers faster:
every view pair's hypothesis of every marker in one call (:func:`view_pair_errors`), and the
views' cameras stacked into arrays (:class:`StackedViews`).
"""

from __future__ import annotations

import functools
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
        return np.isfinite(self.points).all(axis=1)

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
        # Cramer's rule on the stacked entries: the six cofactors in one set of products (the
        # same arithmetic, entry by entry, as writing each out: c00 = a11 a22 - a12 a12, ...), in
        # fewer NumPy calls (the puppet's solves are of 4-16 points, where the calls' fixed cost
        # is the time)
        a = self.a
        if damping:
            a = a + np.array([damping, 0.0, 0.0, damping, 0.0, damping])[:, None]
        c = a[_COF_I] * a[_COF_J] - a[_COF_K] * a[_COF_L]  # c00, c01, c02, c11, c12, c22
        det = (a[:3] * c[:3]).sum(axis=0)  # a00 c00 + a01 c01 + a02 c02
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = 1.0 / np.where(np.abs(det) > 1e-300, det, np.nan)
            return ((c[_SYM] * self.b[None]).sum(axis=1) * inv).T  # row i: c_i0 b0 + c_i1 b1 + c_i2 b2


# _Normal3.solve: the cofactor c_k = a[I_k] a[J_k] - a[K_k] a[L_k] of the six unique entries
# (a00, a01, a02, a11, a12, a22), and the full symmetric matrix's entries as indices into them
_COF_I, _COF_J = np.array([3, 2, 1, 0, 1, 0]), np.array([5, 4, 4, 5, 2, 3])
_COF_K, _COF_L = np.array([4, 1, 2, 2, 0, 1]), np.array([4, 5, 3, 2, 4, 1])
_SYM = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


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
        center = -R.T @ t
        xs, ys = np.where(m, x[:, 0], 0.0), np.where(m, x[:, 1], 0.0)
        norm = np.sqrt(xs * xs + ys * ys + 1.0)
        # two unit normals of the ray (camera frame): (1, 0, -x) and (-xy, 1+x^2, -y) orthonormalised
        n1 = np.stack([np.ones_like(xs), np.zeros_like(xs), -xs]) / np.sqrt(1 + xs * xs)
        d = np.stack([xs, ys, np.ones_like(xs)]) / norm
        n2 = np.cross(d.T, n1.T).T
        for nc in (n1, n2):
            nw = R.T @ nc * m  # normal in the world frame (3, N)
            eq.add_rows(nw, nw.T @ center)
    return eq.solve()


def _refine(world2cams, K, xn, mask, X, iterations: int = 4) -> np.ndarray:
    """Gauss-Newton on the reprojection error in undistorted pixels (distortion removed first).

    Hand-written rather than ``scipy.optimize.least_squares`` because it solves millions of
    independent 3-parameter problems at once; a per-point solver call would be ~1e4x slower.
    """
    X = X.copy()
    good = np.isfinite(X).all(axis=1)
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
        ok = good & np.isfinite(step).all(axis=1)
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

    Examples
    --------
    Three cameras on a circle look at the origin; the second point is not seen by the third:

    >>> import numpy as np
    >>> from stillcap.camera import Camera, Rig, look_at
    >>> rig = Rig([Camera.from_intrinsics(f"cam{i}", 1000, 1000, 639.5, 479.5, (1280, 960),
    ...                                   world2cam=look_at((3 * np.cos(a), 3 * np.sin(a), 1), (0, 0, 0)))
    ...            for i, a in enumerate([0.0, 1.5, 3.0])])
    >>> X = np.array([[0.1, -0.2, 0.3], [0.0, 0.0, 0.0]])
    >>> x = np.stack([cam.project(X) for cam in rig])   # (n_cams, N, 2) pixels
    >>> x[2, 1] = np.nan
    >>> tri = triangulate(rig, x)
    >>> np.round(tri.points, 6).tolist(), tri.n_views.tolist()
    ([[0.1, -0.2, 0.3], [0.0, 0.0, 0.0]], [3, 2])
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
    used = mask & np.isfinite(X).all(axis=1)[None]
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

# --- a handful of markers: the consensus over view pairs, vectorised ----------------------------
# (from the puppet pipeline, whose marker triangulation runs it several times per pose)
def triangulate_markers(rig: Rig, points_2d, method: str = "dlt", refine: bool = True,
                        outlier_px: float | None = None, *, pair_errors: np.ndarray | None = None,
                        views: StackedViews | None = None) -> Triangulation:
    """:func:`triangulate` for a handful of markers, same result, faster.

    The shared triangulation checks the views' consensus by looping over the 66 view pairs of
    a turntable, each time solving and projecting every marker into every view (792 small
    projections, ~100 ms for 16 markers). Here every (pair, marker) hypothesis becomes one
    "point" of a single call (16 x 66 points), projected once per view, and the best pair is
    chosen with array operations; the final solve is the shared one with the chosen views.
    Same choice rule as the shared function (most agreeing views, then the smallest summed
    error, then the first pair), so the same points to rounding.

    Parameters
    ----------
    rig : Rig, n_views cameras
    points_2d : array_like, shape (n_views, n_markers, 2)
        Distorted pixels, NaN where unseen.
    method, refine, outlier_px
        As :func:`triangulate`.
    pair_errors : ndarray, shape (n_views, n_pairs, n_markers), optional
        :func:`view_pair_errors` of observations that include ``points_2d``'s (which may leave
        some out): reused for the pairs still seen.
    views : StackedViews, optional
        The views with those observations (``method="dlt"``), reused.
    """
    x = np.asarray(points_2d, float)
    if x.ndim != 3 or x.shape[0] != len(rig) or x.shape[2] != 2:
        raise ValueError(f"points_2d must have shape ({len(rig)}, N, 2), got {x.shape}")
    return _triangulate_markers(rig, x, method, refine, outlier_px, pair_errors, views)




class StackedViews:
    """The views' cameras as stacked arrays, and the marker observations in normalised
    coordinates, for the many small triangulations of :func:`triangulate_markers`
    (the puppet pipeline's ``solve_markers``).

    :func:`triangulate` loops over the cameras and undistorts the
    observations again at every call (seven calls per pose, ~4 ms each); here the observations
    are undistorted once and every step (DLT, Gauss-Newton refinement, projection) is one set
    of array operations over all views. The arithmetic is the shared function's (same normal
    equations, same Cramer solve, same stopping rule), so the points agree to rounding.
    """

    def __init__(self, rig: Rig, x: np.ndarray):
        cams = list(rig)
        self.P = np.stack([c.world2cam[:3] for c in cams])  # (nv, 3, 4)
        self.K = np.stack([c.K for c in cams])
        self.dist = np.stack([np.asarray(c.dist, float) for c in cams])
        self.r2max = np.array([c.max_distortion_r2 if c.radially_distorted else np.inf for c in cams])
        self.x = x
        # normalised coordinates: the pinhole cameras' closed form (Camera.pixels_to_normalized's
        # arithmetic) for all views at once, a lens with distortion on its own
        K = self.K
        y = (x[..., 1] - K[:, 1, 2, None]) / K[:, 1, 1, None]
        self.xn = np.stack([(x[..., 0] - K[:, 0, 2, None] - K[:, 0, 1, None] * y) / K[:, 0, 0, None], y],
                           axis=-1)  # (nv, n, 2)
        for v, c in enumerate(cams):
            if c.distorted:
                self.xn[v] = c.pixels_to_normalized(x[v])
        self.seen = np.isfinite(self.xn[..., 0]) & np.isfinite(self.xn[..., 1])

    def project(self, X: np.ndarray) -> np.ndarray:
        """Pixels of points ``X`` (N, 3) in every view, (nv, N, 2); as :meth:`Camera.project`."""
        P = self.P
        pc = np.einsum("vij,nj->vni", P[:, :, :3], X) + P[:, None, :, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(pc[..., 2] > 1e-12, pc[..., 2], np.nan)
            x, y = pc[..., 0] / z, pc[..., 1] / z
            r2 = x * x + y * y
            far = r2 > self.r2max[:, None]
        x, y = np.where(far, np.nan, x), np.where(far, np.nan, y)
        r2 = x * x + y * y
        k1, k2, p1, p2, k3 = (self.dist[:, i, None] for i in range(5))
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        K = self.K
        return np.stack([K[:, 0, 0, None] * xd + K[:, 0, 1, None] * yd + K[:, 0, 2, None],
                         K[:, 1, 1, None] * yd + K[:, 1, 2, None]], axis=-1)

    def _rows(self, mask: np.ndarray):
        """DLT rows of every (view, marker): ``J`` (2, nv, n, 3) and ``r`` (2, nv, n), zero where unmasked."""
        P = self.P
        m = mask.astype(float)
        J, r = [], []
        for k in (0, 1):
            c = np.where(mask, self.xn[..., k], 0.0)
            J.append((c[..., None] * P[:, None, 2, :3] - P[:, None, k, :3]) * m[..., None])
            r.append(-(c * P[:, None, 2, 3] - P[:, None, k, 3]) * m)
        return np.stack(J), np.stack(r)

    @staticmethod
    def _normal(J: np.ndarray, r: np.ndarray, axis) -> _Normal3:
        """Normal equations summed over ``axis`` of rows J (..., n, 3), r (..., n)."""
        eq = _Normal3(J.shape[-2])
        if axis == (0, 1) and J.ndim == 4:  # the solves' case: two einsums, the same sums in the same order
            eq.a = np.einsum("kvni,kvnj->ijn", J, J).reshape(9, -1)[_UPPER]
            eq.b = np.einsum("kvni,kvn->in", J, r)
            return eq
        j0, j1, j2 = J[..., 0], J[..., 1], J[..., 2]
        eq.a = np.stack([(j0 * j0).sum(axis), (j0 * j1).sum(axis), (j0 * j2).sum(axis), (j1 * j1).sum(axis),
                         (j1 * j2).sum(axis), (j2 * j2).sum(axis)])
        eq.b = np.stack([(j0 * r).sum(axis), (j1 * r).sum(axis), (j2 * r).sum(axis)])
        return eq

    def dlt(self, mask: np.ndarray) -> np.ndarray:
        J, r = self._rows(mask)
        return self._normal(J, r, (0, 1)).solve()

    def refine(self, mask: np.ndarray, X: np.ndarray, iterations: int = 4) -> np.ndarray:
        """Gauss-Newton on the reprojection error in undistorted pixels (``triangulate``'s ``_refine``).

        The same arithmetic, entry by entry, as ``_refine``'s, in about half the NumPy calls
        (the image's two axes as one array; the arrays are a few hundred numbers, so the calls'
        fixed cost is the time: ~0.43 -> ~0.25 ms per solve of 16 markers in 12 views). Views
        left out (``w`` false) give zero rows, as there. It stops once no step exceeds
        :data:`STACKED_STEP_M` (``_refine``: 1e-10 m), usually one iteration sooner."""
        X = X.copy()
        good = np.isfinite(X).all(axis=1)
        P, K = self.P, self.K
        R, t = P[:, :, :3], P[:, :, 3]
        R01, R2 = R[:, None, :2, :], R[:, None, 2:3, :]  # (nv, 1, 2, 3), (nv, 1, 1, 3)
        fx, s, fy = K[:, 0, 0, None, None], K[:, 0, 1, None, None], K[:, 1, 1, None, None]
        fx1, s1, fy1 = fx[..., 0], s[..., 0], fy[..., 0]
        seen = mask & good[None]
        xn = np.where(seen[..., None], self.xn, 0.0)
        for _ in range(iterations):
            pc = np.einsum("vij,nj->vni", R, np.where(good[:, None], X, 0.0)) + t[:, None]
            w = seen & (pc[..., 2] > 0)
            iz = np.where(w, 1.0 / np.where(w, pc[..., 2], 1.0), 0.0)
            uv = pc[..., :2] * iz[..., None]  # (nv, n, 2): u, v
            d = (uv - xn) * w[..., None]  # du, dv
            D = (R01 - R2 * uv[..., None]) * iz[..., None, None]  # (nv, n, 2, 3): du/dX, dv/dX
            J = np.stack([fx * D[:, :, 0] + s * D[:, :, 1], fy * D[:, :, 1]])
            r = np.stack([-(fx1 * d[..., 0] + s1 * d[..., 1]), -fy1 * d[..., 1]])
            step = self._normal(J, r, (0, 1)).solve(damping=1e-12)
            ok = good & np.isfinite(step).all(axis=1)
            X[ok] += step[ok]
            if not np.any(np.abs(step[ok]) > STACKED_STEP_M):
                break
        return X

    def solve(self, mask: np.ndarray, refine: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Points from the masked observations (NaN with fewer than 2) and their pixel errors
        in every view where seen, (n, 3) and (nv, n)."""
        mask = mask & self.seen
        X = self.dlt(mask)
        if refine:
            X = self.refine(mask, X)
        X[mask.sum(axis=0) < 2] = np.nan
        return X, np.linalg.norm(self.project(X) - self.x, axis=-1)

    def pair_errors(self) -> np.ndarray:
        """:func:`view_pair_errors`: each view pair's linear point of each marker (from the per-view
        normal equations added pairwise), its pixel error in every view, (nv, n_pairs, n)."""
        nv, n = self.seen.shape
        pairs = _view_pairs(nv)
        J, r = self._rows(self.seen)
        eq1 = self._normal(J, r, 0)  # per view: a (6, nv, n), b (3, nv, n)
        both = self.seen[pairs[:, 0]] & self.seen[pairs[:, 1]]  # (n_pairs, n)
        # only the hypotheses of pairs that saw the marker (a quarter of them on a turntable)
        # are solved and projected (element-wise arithmetic: the same numbers as for all)
        pi, mi = np.nonzero(both)
        p0, p1 = pairs[pi, 0], pairs[pi, 1]
        eq = _Normal3(len(pi))
        eq.a = eq1.a[:, p0, mi] + eq1.a[:, p1, mi]
        eq.b = eq1.b[:, p0, mi] + eq1.b[:, p1, mi]
        proj = self.project(eq.solve())  # (nv, m, 2)
        err = np.full((nv, len(pairs), n), np.nan)
        err[:, pi, mi] = np.linalg.norm(proj - self.x[:, mi], axis=-1)
        return err




#: :meth:`StackedViews.refine` stops once no coordinate's step exceeds this, metres. The
#: iterations converge about a thousandfold per step (the puppet's: 7e-5, 1e-7, 1e-10 m), so
#: the point is then ~1e-10 m from ``_refine``'s (which goes on to 1e-10 m steps: one more
#: iteration, ~0.25 ms per solve), against beads measured to ~3e-5 m.
STACKED_STEP_M = 1e-7

#: The six unique entries (00, 01, 02, 11, 12, 22) among a 3 x 3 matrix's nine, as :class:`_Normal3` keeps them.
_UPPER = np.array([0, 1, 2, 4, 5, 8])


@functools.lru_cache(maxsize=16)
def _view_pairs(nv: int) -> np.ndarray:
    """The view pairs ``(i, j)``, ``i < j``, in order, shape (n_pairs, 2), read-only (made once
    per view count: the Python loop cost ~1 ms per call, three calls per pose)."""
    out = np.array([(i, j) for i in range(nv) for j in range(i + 1, nv)], int).reshape(-1, 2)
    out.setflags(write=False)
    return out




def view_pair_errors(rig: Rig, x: np.ndarray, method: str) -> np.ndarray:
    """Reprojection error of every (view pair, marker) hypothesis in every view, shape
    (n_views, n_pairs, n_markers), NaN where the pair did not see the marker or the view
    did not: each pair's linear point, from that pair's two views only, projected once per view."""
    nv, n = x.shape[:2]
    seen = np.isfinite(x[..., 0]) & np.isfinite(x[..., 1])
    pairs = _view_pairs(nv)
    n_pairs = len(pairs)
    # hypotheses: (pair, marker) -> only the pair's two views kept
    keep = np.zeros((nv, n_pairs), bool)
    keep[pairs[:, 0], np.arange(n_pairs)] = True
    keep[pairs[:, 1], np.arange(n_pairs)] = True
    both = seen[pairs[:, 0]] & seen[pairs[:, 1]]  # (n_pairs, n)
    m = keep[:, :, None] & both[None]  # (nv, n_pairs, n)
    xp = np.where(m[..., None], x[:, None], np.nan).reshape(nv, n_pairs * n, 2)
    hyp = triangulate(rig, xp, method=method, refine=False).points  # linear, as the consensus
    proj = np.stack([cam.project(hyp) for cam in rig]).reshape(nv, n_pairs, n, 2)
    return np.linalg.norm(proj - x[:, None], axis=-1)




class _PairErrors:
    """The robust model of :func:`triangulate_markers`: the residuals of every view-pair
    hypothesis computed beforehand, shape (n_views, n_pairs, n_markers); hypothesis ``h`` is the
    pair's index."""

    def __init__(self, errors):
        self.errors = errors

    def estimate(self, h):
        return h

    def residuals(self, h):
        return self.errors[:, h]

    def residuals_of_all(self, hypotheses):
        return np.moveaxis(self.errors[:, hypotheses], 1, 0)  # (n_pairs, n_views, n_markers)


def _triangulate_markers(rig: Rig, x: np.ndarray, method: str, refine: bool, outlier_px: float | None,
                         pair_errors: np.ndarray | None = None, views: StackedViews | None = None) -> Triangulation:
    """:func:`triangulate_markers` on a checked array. ``pair_errors``: :func:`view_pair_errors` of
    observations that include ``x``'s (``x`` may leave some out): a pair's hypothesis depends
    only on its two views, so those of pairs still seen in ``x`` are the same and are reused."""
    nv, n = x.shape[:2]
    seen = np.isfinite(x[..., 0]) & np.isfinite(x[..., 1])
    if outlier_px is None or nv < 3 or n == 0:
        return triangulate(rig, x, method=method, refine=refine, outlier_px=outlier_px)
    pairs = _view_pairs(nv)
    fast = method == "dlt"  # the DLT chain on stacked arrays (StackedViews); midpoint: the shared function
    if fast and views is None:
        views = StackedViews(rig, x)
    if pair_errors is None:
        err = views.pair_errors() if fast else view_pair_errors(rig, x, method)
    else:
        both = seen[pairs[:, 0]] & seen[pairs[:, 1]]  # pairs whose hypothesis x still has
        err = np.where(both[None], pair_errors, np.nan)
    # the shared consensus (stillcap.geometry.robust), each view pair a hypothesis whose residuals
    # were computed above for all pairs at once; views that x does not have are not judged
    found = consensus(_PairErrors(np.where(seen[:, None], err, np.nan)), range(len(pairs)), outlier_px,
                      min_inliers=2)
    mask = np.where(found.best >= 0, found.inliers, seen)
    if fast:
        # views.x may hold more observations than x (x leaves some out): only x's are used
        X, errors = views.solve(mask & seen, refine)
        errors = np.where(seen, errors, np.nan)
    else:
        X = triangulate(rig, np.where(mask[..., None], x, np.nan), method=method, refine=refine).points
        errors = np.linalg.norm(np.stack([cam.project(X) for cam in rig]) - x, axis=-1)
    with np.errstate(invalid="ignore"):
        mask2 = seen & (errors <= outlier_px)
    if np.any(mask2 != mask):
        mask = mask2
        if fast:
            X, errors = views.solve(mask, refine)
            errors = np.where(seen, errors, np.nan)
        else:
            X = triangulate(rig, np.where(mask[..., None], x, np.nan), method=method, refine=refine).points
            errors = np.linalg.norm(np.stack([cam.project(X) for cam in rig]) - x, axis=-1)
    used = mask & np.isfinite(X).all(axis=1)[None]
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.nansum(np.where(used, errors, np.nan) ** 2, axis=0) / used.sum(axis=0))
    return Triangulation(X, rms, np.where(seen, errors, np.nan), used)


