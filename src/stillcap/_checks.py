"""Input validation at the package boundary (pytransform3d-style `check_*` helpers).

Every public function converts its array inputs here so that a wrong shape fails with a
``ValueError`` naming the argument and the shape that came, never with an obscure broadcast error.
"""

from __future__ import annotations

import numpy as np


def as_array(x, shape: tuple, name: str, dtype=float) -> np.ndarray:
    """Return ``x`` as an array whose shape matches ``shape`` (``None`` = any length).

    >>> as_array([[1, 2, 3]], (None, 3), "points").shape
    (1, 3)
    """
    a = np.asarray(x, dtype=dtype)
    ok = a.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, a.shape))
    if not ok:
        dims = ["N" if s is None else str(s) for s in shape]
        want = f"({dims[0]},)" if len(dims) == 1 else "(" + ", ".join(dims) + ")"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    return a


def as_points(x, dim: int, name: str) -> tuple[np.ndarray, bool]:
    """Accept one point ``(dim,)`` or many ``(N, dim)``; return ``(N, dim)`` and whether it was one."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 1 and a.shape[0] == dim:
        return a[None, :], True
    if a.ndim == 2 and a.shape[1] == dim:
        return a, False
    raise ValueError(f"{name} must have shape ({dim},) or (N, {dim}), got {a.shape}")


def as_positive(v, name: str) -> float:
    """``v`` as a finite float > 0, or a ``ValueError`` naming ``name`` and what came."""
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {v!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0, got {v}")
    return v


def as_rng(rng) -> np.random.Generator:
    """An ``np.random.Generator`` from a Generator, an int seed or None."""
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


#: ``np.allclose(R @ R.T, np.eye(3), atol)``'s bound per entry: ``atol + rtol * |I|`` (its default rtol 1e-5)
_EYE3 = np.eye(3)
_RTOL_EYE = 1e-5 * _EYE3


def is_rotation(R, atol: float = 1e-6) -> bool:
    """Whether the 3x3 ``R`` is a proper rotation: ``np.allclose(R @ R.T, np.eye(3), atol=atol)``
    and ``det(R) >= 0``, the same answer for every input (NaN: False). Written out because
    ``np.allclose`` and ``np.linalg.det`` cost ~50 us per camera of a rig file, twice each
    (schema and ``Camera``); once ``R R^T`` is within 1.1e-5 of I, ``det(R)`` is within ~2e-5
    of +-1, so its sign from the triple product is exact.

    >>> is_rotation(np.eye(3)), is_rotation(np.diag([1.0, 1.0, -1.0]))
    (True, False)
    """
    R = np.asarray(R, float)
    if not (np.abs(R @ R.T - _EYE3) <= atol + _RTOL_EYE).all():
        return False
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) >= 0
