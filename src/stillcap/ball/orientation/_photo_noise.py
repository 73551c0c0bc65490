"""Each observation's centroid noise read from its own photo, in the global spin fit's weights
(issue 12): the fit's variance of observation ``m`` is scaled by ``(sigma_m / median sigma)^(2p)``
with ``sigma_m`` the centroid's standard error the detector states
(:attr:`MarkerObservations.centroid_sigma_px
<stillcap.ball.orientation._observations.MarkerObservations>`) and ``p`` in [0, 1] estimated
from the fit's own residuals (:func:`photo_noise_exponent`). ``p = 0`` gives the weights without
it, so the fit reweighs only as far as its residuals say the stated sigmas explain them."""

from __future__ import annotations

import numpy as np
from scipy.special import digamma

#: Fewest observations with a stated sigma (and a residual degree of freedom) for the exponent
#: to be estimated; with fewer ``p = 0``. What it rests on: the slope's standard error is about
#: ``sqrt(pi^2/2 / (n var(log sigma^2)))`` (the variance of ``log chi^2_2`` is ``pi^2/4 x 2``
#: per observation), 0.4-0.6 at n = 10 for the spread of sigmas a pitch's markers have, i.e. no
#: evidence within [0, 1]; an earlier session's benchmark runs measured the "everything varied"
#: axis error at 0.52 deg with a minimum of 10, 0.49 with 15 and 0.48 with 20 (the lost code).
MIN_SIGMAS = 20
#: False: :func:`apply_photo_noise` leaves the weights as they are (the fit as before issue 12's
#: per-photo noise).
ENABLED = True


def photo_noise_exponent(e2, dof, sigma, min_obs: int = MIN_SIGMAS) -> float:
    """The exponent ``p`` (in [0, 1]) of the residual variance on the stated centroid sigma.

    Model: ``E[e2_m] = s^2 sigma_m^(2p) dof_m`` with ``e2_m`` an observation's squared (weighted)
    residual length and ``dof_m`` its degrees of freedom (its informative residual components
    less its leverage: a least-squares residual is smaller than its error by that much). Each
    ``log(e2_m / dof_m)`` less its expected bias (``E[log(chi^2_k / k)] = psi(k/2) + log(2/k)``,
    with ``k = dof_m``: an observation with one component is biased lower than one with two) is
    regressed on ``log sigma_m^2``; the slope, clipped to [0, 1], is ``p`` (a log regression:
    an outlier residual that the inlier test let through moves it far less than a variance fit).

    Parameters
    ----------
    e2, dof, sigma : array_like, shape (m,)
        Squared residual lengths, degrees of freedom and stated centroid sigmas (NaN: unknown).
    min_obs : int
        Fewest usable observations (:data:`MIN_SIGMAS`); with fewer 0.

    Returns
    -------
    float
    """
    e2, dof, sigma = (np.asarray(a, float).ravel() for a in (e2, dof, sigma))
    ok = np.isfinite(sigma) & (sigma > 0) & np.isfinite(e2) & (e2 > 0) & (dof > 0.3)
    if np.count_nonzero(ok) < min_obs:
        return 0.0
    k = dof[ok]
    y = np.log(e2[ok] / k) - (digamma(k / 2.0) + np.log(2.0 / k))
    x = np.log(sigma[ok] ** 2)
    xc = x - x.mean()
    sxx = float(xc @ xc)
    if not sxx > 1e-6 * len(x):  # every sigma alike: nothing to regress on
        return 0.0
    return float(np.clip((xc @ (y - y.mean())) / sxx, 0.0, 1.0))


def photo_noise_factors(sigma, p: float) -> np.ndarray:
    """Each observation's weight factor ``(sigma_m / median sigma)^(-p)`` (the fit's weights
    multiply its residuals: the variance goes as ``sigma^(2p)``), 1 where the sigma is unknown
    (NaN: the median observation's). (M,)."""
    s = np.asarray(sigma, float)
    ok = np.isfinite(s) & (s > 0)
    out = np.ones(len(s))
    if p > 0 and ok.any():
        out[ok] = (s[ok] / np.median(s[ok])) ** (-p)
    return out


def apply_photo_noise(prob, r, J, sel, ranks) -> float:
    """Estimate ``p`` on the fit of ``prob`` (a ``_GlobalProblem``) from its residuals ``r`` and
    Jacobian ``J`` at the solution (the inliers ``sel``: ``prob.residuals`` / ``prob.jacobian``,
    which the caller computes for the covariance anyway) and multiply its weights by
    :func:`photo_noise_factors`. ``ranks``: each observation's informative residual components
    (``_residual_ranks``). Returns ``p`` (0: the weights are left as they were)."""
    sigma = prob.obs.centroid_sigma_px
    if not ENABLED or prob.W is None or sigma is None or not np.any(np.isfinite(sigma[sel])):
        return 0.0
    m = len(r) // 2
    h = np.einsum("ij,jk,ik->i", J, np.linalg.pinv(J.T @ J), J)  # the hat matrix's diagonal
    p = photo_noise_exponent(r[:m] ** 2 + r[m:] ** 2, ranks[sel] - (h[:m] + h[m:]), sigma[sel])
    if p > 0:
        prob.W = prob.W * photo_noise_factors(sigma, p)[:, None, None]
    return p
