"""Linear algebra on the 2x2 and 3x3 matrices of the ball detector's per-ball fits, without
``np.linalg``'s per-call set-up.

``np.linalg.solve``, ``inv``, ``eigh`` and ``svd`` check their arguments, convert types and enter
an ``np.errstate`` block around the LAPACK call: on a 3x3 system that set-up is ~95 % of the call
(~7 of 7.5 us, while the GIL is held), and the ball detector makes ~1000 such calls a pitch
capture (a circle fit's Newton steps, each ball's shading frame). Here NumPy's own LAPACK
gufuncs (``numpy.linalg._umath_linalg``, the routines those functions call) are called directly
on float64 arrays: the same numbers, bit for bit. Only input LAPACK handles without a flag takes
the fast call: finite, and for ``solve``/``inv`` a 2x2 or 3x3 matrix clearly away from singular
(:func:`_clearly_regular`); anything else (a singular matrix, NaN input, other shapes or types),
or a fast result that is not finite, is ``np.linalg``'s own call, so its result, its error
(``LinAlgError``) and its silence are exactly what they were (the gufuncs called bare would warn
``RuntimeWarning: invalid value`` on a singular matrix, which ``np.linalg``'s ``errstate``
turns into its error). Without the private module (another NumPy) every call is ``np.linalg``'s.

Hand-written rather than a library: the overhead removed is NumPy's own wrapper.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["eigh", "inv", "lstsq", "solve", "svdvals"]

_F64 = np.dtype(np.float64)
_EPS = float(np.finfo(np.float64).eps)


def _lstsq_fast(u, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.lstsq(a, b, rcond=None)[0]`` for a float64 ``a`` (m, n), m >= n >= 1, and ``b``
    (m,), through the gufunc ``u.lstsq`` as ``np.linalg.lstsq`` calls it."""
    m, n = a.shape
    x = u.lstsq(a, b[:, None], _EPS * max(n, m), signature="ddd->ddid")[0]
    return x.squeeze(axis=-1).astype(np.float64, copy=True)


def _gufuncs():
    """NumPy's LAPACK gufuncs, if this NumPy has them under the names and signatures used here
    and they give ``np.linalg``'s numbers on a small example; else None (public functions only)."""
    try:  # private, but the public functions have wrapped them since NumPy 1.8
        from numpy.linalg import _umath_linalg as u

        a = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.25], [0.5, 0.25, 2.0]])
        b = np.array([1.0, -2.0, 0.5])
        ok = (np.array_equal(u.solve1(a, b, signature="dd->d"), np.linalg.solve(a, b))
              and np.array_equal(u.inv(a, signature="d->d"), np.linalg.inv(a))
              and all(np.array_equal(x, y) for x, y in zip(u.eigh_lo(a, signature="d->dd"), np.linalg.eigh(a)))
              and np.array_equal(u.svd(a, signature="d->d"), np.linalg.svd(a, compute_uv=False))
              and np.array_equal(_lstsq_fast(u, a[:, :2], b), np.linalg.lstsq(a[:, :2], b, rcond=None)[0]))
    except (ImportError, AttributeError, TypeError, ValueError, np.linalg.LinAlgError):
        return None  # another layout or signature: the public functions
    return u if ok else None


_U = _gufuncs()


def _fast(*arrays) -> bool:
    return _U is not None and all(type(a) is np.ndarray and a.dtype == _F64 for a in arrays)


_SUM = np.add.reduce


def _finite(x: np.ndarray) -> bool:
    """All of ``x`` finite, or possibly not (then the caller takes np.linalg's result, the same
    numbers): its sum is finite (one call, not ``np.isfinite(x).all()``'s two; a sum that
    overflows only sends a finite result the slow way)."""
    return math.isfinite(_SUM(x, axis=None))


def _clearly_regular(a: np.ndarray) -> bool:
    """A finite 2x2 or 3x3 ``a`` whose determinant (Python floats) is far from 0 relative to the
    product of its rows' largest entries (> 1e-10 of it; below 1e150 so nothing overflows):
    LAPACK's LU cannot meet an exactly zero pivot there (one makes the determinant a few
    rounding errors of that product, ~1e-15), so the fast call never flags a singular matrix
    (and warns); anything else takes ``np.linalg``'s own call."""
    if a.shape == (3, 3):
        (p, q, r), (s, t, u), (v, w, x) = a.tolist()
        det = p * (t * x - u * w) - q * (s * x - u * v) + r * (s * w - t * v)
        scale = max(abs(p), abs(q), abs(r)) * max(abs(s), abs(t), abs(u)) * max(abs(v), abs(w), abs(x))
    elif a.shape == (2, 2):
        (p, q), (s, t) = a.tolist()
        det = p * t - q * s
        scale = max(abs(p), abs(q)) * max(abs(s), abs(t))
    else:
        return False
    return scale < 1e150 and abs(det) > 1e-10 * scale  # (False for NaN and inf)


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)`` of a square float64 ``a`` (n, n) and ``b`` (n,)."""
    if _fast(a, b) and b.ndim == 1 and _clearly_regular(a) and _finite(b):
        x = _U.solve1(a, b, signature="dd->d")
        if _finite(x):
            return x
    return np.linalg.solve(a, b)


def inv(a: np.ndarray) -> np.ndarray:
    """``np.linalg.inv(a)`` of a square float64 ``a`` (n, n)."""
    if _fast(a) and _clearly_regular(a):
        x = _U.inv(a, signature="d->d")
        if _finite(x):
            return x
    return np.linalg.inv(a)


def eigh(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.eigh(a)`` (lower triangle) of a symmetric float64 ``a`` (n, n): eigenvalues
    (ascending) and eigenvectors (columns)."""
    if _fast(a) and a.ndim == 2 and _finite(a):
        w, v = _U.eigh_lo(a, signature="d->dd")
        if _finite(w) and _finite(v):
            return w, v
    w, v = np.linalg.eigh(a)
    return w, v


def svdvals(a: np.ndarray) -> np.ndarray:
    """``np.linalg.svd(a, compute_uv=False)`` of a float64 ``a`` (m, n): singular values, descending."""
    if _fast(a) and a.ndim == 2 and _finite(a):
        s = _U.svd(a, signature="d->d")
        if _finite(s):
            return s
    return np.linalg.svd(a, compute_uv=False)


def lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.lstsq(a, b, rcond=None)[0]`` (the solution only) of a float64 ``a`` (m, n)
    with m >= n >= 1 and ``b`` (m,)."""
    if (_fast(a, b) and a.ndim == 2 and b.ndim == 1 and a.shape[0] == b.shape[0] >= a.shape[1] >= 1
            and _finite(a) and _finite(b)):
        x = _lstsq_fast(_U, a, b)
        if _finite(x):
            return x
    return np.linalg.lstsq(a, b, rcond=None)[0]
