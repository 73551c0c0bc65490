"""How much a pair's ball images differ in their error level, and each image's own level.

:func:`stillcap.ball.uncertainty.position_covariances` states each ball position's covariance
as its triangulation shape ``S_k`` at one level ``s^2`` per pair, estimated from the pair's
residuals to the flight. Where the images' errors do not share one level (a light that leaves
some images' centres worse than the shape says, a crescent at the end of the flight), the
errors are a scale mixture: right on average, too many of them outside the 95 % region
(on the studio's photos the images whose own residual was 6-10 times the pair's level fell
outside it 42 % of the time, those under it 2 %; ``docs/pitch.md``, "Each image's own level").

Here the spread of the levels is measured from the residuals themselves and each image's
covariance takes its own level (empirical Bayes):

- each image's whitened residual ``Q_k = 3 m2_k / mean(m2)`` (``m2_k = r_k^T S_k^-1 r_k``) is
  ``lambda_k chi2_3`` with a level ``lambda_k`` of mean 1 and variance ``v``; so the
  ``q_k = Q_k / 3`` have ``Var(q) = 2/3 (1 + v) + v``, and
  ``v = max(0, (3 Var(q) - 2) / 5)`` (:func:`level_dispersion`, pooled over a capture's pairs);
- with an inverse-gamma prior of that mean and variance (``alpha = 2 + 1/v``,
  ``beta = alpha - 1``) an image's level after its own residual is inverse-gamma
  ``(alpha + 3/2, beta + Q_k / 2)``, and its error Student's t with ``2 alpha + 3`` degrees of
  freedom: the factor on ``s^2 S_k`` makes the chi-square 95 % region ``e^T C^-1 e <= 7.81`` the
  t's (:func:`level_factors`). With ``v = 0`` (one level) every factor is 1.
"""
from __future__ import annotations

import numpy as np
# quantiles from scipy.special: importing scipy.stats costs 0.4-2 s per CLI call (as ball.alias)
from scipy.special import chdtri, fdtri

__all__ = ["level_dispersion", "level_factors", "whitened_levels"]


def whitened_levels(residuals, shape_covariance) -> np.ndarray:
    """``m2_k = r_k^T S_k^-1 r_k`` per image, NaN where the residual or the shape is not usable
    (a NaN, or a shape singular to 1e-12 of its largest eigenvalue).

    Parameters
    ----------
    residuals : array_like, shape (K, 3)
    shape_covariance : array_like, shape (K, 3, 3)

    Returns
    -------
    ndarray, shape (K,)
    """
    r = np.asarray(residuals, float)
    S = np.asarray(shape_covariance, float)
    if r.ndim != 2 or r.shape[1] != 3 or S.shape != (len(r), 3, 3):
        raise ValueError(f"residuals must have shape (K, 3) and shape_covariance (K, 3, 3), got {r.shape}, {S.shape}")
    ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(S), axis=(1, 2))
    if ok.any():
        ev = np.linalg.eigvalsh(S[ok])
        ok[np.flatnonzero(ok)[ev[:, 0] <= 1e-12 * np.maximum(ev[:, -1], 1e-300)]] = False
    m2 = np.full(len(r), np.nan)
    if ok.any():
        m2[ok] = np.einsum("ki,ki->k", r[ok], np.linalg.solve(S[ok], r[ok][:, :, None])[:, :, 0])
    return m2


def level_dispersion(levels) -> float:
    """The variance ``v`` of the images' error levels about their pair's (mean 1), from their
    whitened residuals (:func:`whitened_levels`), pooled over pairs.

    Parameters
    ----------
    levels : sequence of array_like, shape (K_i,)
        ``m2`` per image, one array per pair (NaN skipped; pairs with fewer than 2 usable
        images, or a zero mean, left out).

    Returns
    -------
    float
        ``max(0, (3 Var(q) - 2) / 5)`` with ``q = m2 / mean(m2)`` per pair (``Var`` about 1
        with one degree of freedom per pair taken out); 0 with fewer than 3 images in all. With
        few images per pair it is low where the levels spread (a large level raises its pair's
        mean too): 0.15 for 0.25 and 0.31 for 0.5 with 12 images per pair; about right with 40+.
    """
    ss, dof, n = 0.0, 0, 0
    for m2 in levels:
        m2 = np.asarray(m2, float)
        if m2.ndim != 1:
            raise ValueError(f"levels must be 1-D arrays of m2 per image, got shape {m2.shape}")
        m2 = m2[np.isfinite(m2)]
        if len(m2) >= 2 and np.mean(m2) > 0:
            # each pair's mean is its own estimate: one degree of freedom per pair
            ss += float(np.sum((m2 / np.mean(m2) - 1.0) ** 2))
            dof += len(m2) - 1
            n += len(m2)
    if n < 3:
        return 0.0
    return float(max((3.0 * ss / dof - 2.0) / 5.0, 0.0))


def level_factors(levels, dispersion: float) -> np.ndarray:
    """Each image's factor on its pair's covariance level ``s^2``: its own level after its
    residual (the inverse-gamma posterior's scale ``beta' / alpha'``) times
    ``3 F_{3, 2 alpha'}(95 %) / chi2_3(95 %)`` (the t's 95 % region as a chi-square one).

    Parameters
    ----------
    levels : array_like, shape (K,)
        ``m2`` per image of one pair (:func:`whitened_levels`; NaN: factor 1).
    dispersion : float
        ``v`` (:func:`level_dispersion`), >= 0; 0 gives factors of 1.

    Returns
    -------
    ndarray, shape (K,)
    """
    m2 = np.asarray(levels, float)
    if m2.ndim != 1:
        raise ValueError(f"levels must have shape (K,), got {m2.shape}")
    if not (np.isfinite(dispersion) and dispersion >= 0):
        raise ValueError(f"dispersion must be a finite number >= 0, got {dispersion}")
    f = np.ones(len(m2))
    ok = np.isfinite(m2)
    if dispersion == 0 or ok.sum() < 2 or not np.mean(m2[ok]) > 0:
        return f
    a = 2.0 + 1.0 / dispersion
    Q = 3.0 * m2[ok] / np.mean(m2[ok])
    a_post, b_post = a + 1.5, a - 1.0 + Q / 2.0
    f[ok] = (b_post / a_post) * 3.0 * fdtri(3.0, 2.0 * a_post, 0.95) / chdtri(3.0, 0.05)
    return f
