"""Rotation helpers of the spin fits: the exponential map, its left Jacobian, cross-product
matrices, the log-map factor and its derivative, Kabsch alignment, rotation angles, and the mean
and consensus of a set of rotations (all ``ball2world`` matrices, (..., 3, 3))."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.geometry.robust import consensus


def _sq_norms(v: np.ndarray) -> np.ndarray:
    """Squared lengths of rotation vectors (..., 3) -> (...): :func:`_expmap`'s and
    :func:`_left_jacobian`'s ``th2`` (a caller calling both with the same vectors passes it)."""
    return np.einsum("...i,...i->...", v, v)


def _expmap(rotvecs, th2=None) -> np.ndarray:
    """Rotation matrices of rotation vectors, shape (..., 3) -> (..., 3, 3) (Rodrigues).

    Hand-written because it runs inside the least-squares residuals, where building scipy
    ``Rotation`` objects costs more than the rest of the residual. ``th2``: :func:`_sq_norms`
    of ``rotvecs`` if the caller has it.
    """
    v = np.asarray(rotvecs, float)
    th2 = _sq_norms(v) if th2 is None else th2
    th = np.sqrt(th2)
    small = th < 1e-6
    if small.any():
        ths = np.where(small, 1.0, th)
        a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
        b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    else:  # the same numbers without the series branch (most calls: small arrays, no zero angle)
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / (th * th)
    c = (1.0 - b * th2).reshape(-1)  # cos(theta)
    # assembled entry-major, (3, 3, N): every entry's products and sums run over one contiguous
    # row (the (N, 3, 3) layout's 3-long inner loops cost most of the time of the grid scan's
    # large calls); the same products and sums, so the same numbers
    vT = np.ascontiguousarray(v.reshape(-1, 3).T)
    bv = b.reshape(-1) * vT
    R = bv[:, None, :] * vT[None, :, :]  # (b v_i) v_j
    av = a.reshape(-1) * vT
    R[0, 0] += c
    R[1, 1] += c
    R[2, 2] += c
    R[0, 1] -= av[2]
    R[1, 0] += av[2]
    R[0, 2] += av[1]
    R[2, 0] -= av[1]
    R[1, 2] -= av[0]
    R[2, 1] += av[0]
    return np.ascontiguousarray(R.transpose(2, 0, 1)).reshape(v.shape + (3,))


def _skew(v) -> np.ndarray:
    """Cross-product matrices ``[v]x``, shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _left_jacobian(rotvecs, th2=None) -> np.ndarray:
    """Left Jacobian of SO(3), ``d exp(phi + e) = exp(J_l(phi) e) exp(phi)``: (..., 3) -> (..., 3, 3).
    ``th2``: :func:`_sq_norms` of ``rotvecs`` if the caller has it."""
    v = np.asarray(rotvecs, float)
    th2 = _sq_norms(v) if th2 is None else th2
    th = np.sqrt(th2)
    small = th < 1e-4
    if small.any():
        ths = np.where(small, 1.0, th)
        a = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
        b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ths - np.sin(ths)) / (ths ** 3))
    else:
        a = (1.0 - np.cos(th)) / (th * th)
        b = (th - np.sin(th)) / (np.asarray(th) ** 3)  # ndarray power as above (a numpy scalar's differs)
    K = _skew(v)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def _phi_over_sin(c):
    """``arccos(c) / sqrt(1 - c^2)`` (1 at c = 1), for the log-map residual."""
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    small = s < 1e-6
    if not small.any():  # the same numbers without the series branch
        return np.arctan2(s, c) / s
    return np.where(small, 1.0 + (1.0 - c) / 3.0, np.arctan2(s, c) / np.where(small, 1.0, s))


def _dphi_over_sin(c):
    """Derivative of :func:`_phi_over_sin` with respect to c (-1/3 at c = 1)."""
    s2 = np.maximum(1.0 - c * c, 0.0)
    s = np.sqrt(s2)
    small = s < 1e-4
    if not small.any():  # the same numbers without the series branch
        return (-1.0 + np.arctan2(s, c) * c / s) / s2
    ss = np.where(small, 1.0, s)
    return np.where(small, -1.0 / 3.0, (-1.0 + np.arctan2(s, c) * c / ss) / np.where(small, 1.0, s2))


def _kabsch(a, b, w=None):
    """Rotation R minimising sum w |R a_i - b_i|^2 (a, b: (n, 3))."""
    h = (a if w is None else a * w[:, None]).T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    # vt^T diag(1, 1, d) u^T with the diagonal applied as a column sign (exact, no product)
    v = vt.T.copy()
    v[:, 2] *= d
    return v @ u.T


def _rot_angle(Ra, Rb) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _angles_to(R, Rs) -> np.ndarray:
    """:func:`_rot_angle` of ``R`` to each of the rotations ``Rs``: (k, 3, 3) -> (k,)."""
    c = (np.einsum("ab,kab->k", R, Rs) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def _rot_angles(Rs) -> np.ndarray:
    """Pairwise :func:`_rot_angle` of rotations (n, 3, 3) -> (n, n), in one pass
    (``trace(Ra^T Rb)`` is the sum of the elementwise product)."""
    Rs = np.asarray(Rs, float).reshape(-1, 3, 3)
    c = (np.einsum("iab,kab->ik", Rs, Rs) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


class _RotationGroup:
    """The robust model of :func:`_consensus_rotations`: a hypothesis is one of the rotations,
    the residuals the angles (rad) of all of them to it."""

    def __init__(self, angles):
        self.angles = angles

    def estimate(self, i):
        return i

    def residuals(self, i):
        return self.angles[i]

    def residuals_of_all(self, hypotheses):
        return self.angles[hypotheses]


def _consensus_rotations(Rs, tol):
    """Index set of the largest group of rotations within ``tol`` (rad) of one of them (the first
    such group on ties; :func:`stillcap.geometry.robust.consensus` with each rotation a hypothesis)."""
    n = len(Rs)
    if n == 0:
        return np.zeros(0, int)
    found = consensus(_RotationGroup(_rot_angles(Rs)), range(n), tol, inclusive=False, tie_break=False)
    return np.flatnonzero(found.inliers)


def _mean_rotation(Rs):
    return Rotation.from_matrix(np.asarray(Rs)).mean().as_matrix()


def _tangent_bases(u):
    """Two unit vectors (M, 3) each, perpendicular to the unit rows of u and to each other."""
    ref = np.where(np.abs(u[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(u, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(u, t1)
