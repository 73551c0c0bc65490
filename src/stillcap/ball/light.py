"""The light of a flash from the shading of all the balls it lit (issue 12).

One strobe lights every ball of a pair's photos from one place. A single ball's shading (the
matte sphere :func:`stillcap.detect._blur_shift._fit_shading` fits) gives the light's direction
at that ball only roughly: a few degrees off on most balls of the robustness benchmark's studio,
30 deg on a few (markers, texture and the terminator's fall-off bend a 15 px ball's fit). Every
ball's direction is a line from its centre toward the same light, so the light's place is the
point those lines meet (or, for a distant light, their common direction), fitted over all of
them at once: :func:`fit_light`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.orientation._so3 import _skew

__all__ = ["LightFit", "fit_light"]


@dataclass
class LightFit:
    """A light fitted to the directions seen at several points (world frame, SI).

    Attributes
    ----------
    position_h : ndarray, shape (4,)
        The light's place, homogeneous ``(x, y, z, w)`` m: at ``(x, y, z) / w`` for ``w != 0``,
        in the direction ``(x, y, z)`` at infinity for ``w = 0``.
    directions : ndarray, shape (N, 3)
        The fitted unit direction from each point toward the light (NaN where the input was).
    sigma_deg : ndarray, shape (N,)
        Each fitted direction's expected (RMS) angular error, deg: the lines' scatter moved through
        the fit.
    residual_deg : ndarray, shape (N,)
        Angle between each given direction and the fitted one, deg (NaN where not given).
    inliers : ndarray, shape (N,) bool
        The directions the fit kept (the others lie more than 3 robust sigmas off).
    scatter_deg : float
        The robust scatter of one given direction about the fit, deg (per component).
    """

    position_h: np.ndarray
    directions: np.ndarray
    sigma_deg: np.ndarray
    residual_deg: np.ndarray
    inliers: np.ndarray
    scatter_deg: float


def _solve(l, p, w):
    """The homogeneous light ``h`` (normalised coordinates) minimising ``sum w |l x (x - h_w p)|^2``
    (a linear, DLT-like form: the light may be at infinity), sign chosen so the lines point at it."""
    C = _skew(l)
    A = np.concatenate([C, -np.einsum("nij,nj->ni", C, p)[:, :, None]], axis=2) * np.sqrt(w)[:, None, None]
    h = np.linalg.svd(A.reshape(-1, 4), full_matrices=False)[2][-1]
    d = h[None, :3] - h[3] * p
    return -h if np.einsum("ni,ni->", d / np.linalg.norm(d, axis=1, keepdims=True), l) < 0 else h


def fit_light(points, directions, min_points: int = 3) -> LightFit | None:
    """The light's place from directions toward it seen at ``points``, robustly.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Where each direction was seen (e.g. ball centres, m; rows with NaN are left out).
    directions : array_like, shape (N, 3)
        The direction toward the light at each point (e.g. each ball's shading,
        :func:`stillcap.detect._ball_light.fit_ball_light`'s, moved to the world frame);
        normalised here, NaN rows left out.
    min_points : int
        Fewest usable directions (at least 3: two lines fix a place exactly, with no check).

    Returns
    -------
    LightFit or None
        None with fewer than ``min_points`` usable directions.

    The lines ``points + t directions`` are met in the least-squares sense of ``l x (L - p)``
    (homogeneous ``L``, so a distant light's common direction is the same fit), reweighted by
    the distance to the light (an angular error) and robustly (Cauchy weights at the lines'
    robust scatter, three rounds); lines more than 3 robust sigmas off are left out. Each fitted
    direction's error is the scatter moved through the fit's linearisation: near the light's
    common direction it is ``scatter / sqrt(n)``, and it grows at points where the place, not only
    the direction, matters.
    """
    p_in = as_array(points, (None, 3), "points")
    l_in = as_array(directions, (len(p_in), 3), "directions")
    if min_points < 3:
        raise ValueError(f"min_points must be >= 3, got {min_points}")
    n = len(p_in)
    with np.errstate(invalid="ignore", divide="ignore"):
        l_all = l_in / np.linalg.norm(l_in, axis=1, keepdims=True)
    use = np.all(np.isfinite(p_in), axis=1) & np.all(np.isfinite(l_all), axis=1)
    if np.count_nonzero(use) < min_points:
        return None
    p0 = p_in[use].mean(axis=0)
    scale = float(np.sqrt(((p_in[use] - p0) ** 2).sum(axis=1).mean())) or 1.0
    p, l = (p_in[use] - p0) / scale, l_all[use]
    w = np.ones(len(p))
    sig = None
    for _ in range(4):
        h = _solve(l, p, w)
        d = h[None, :3] - h[3] * p
        dist = np.linalg.norm(d, axis=1)
        res = np.arccos(np.clip(np.einsum("ni,ni->n", d / dist[:, None], l), -1.0, 1.0))
        # per component (two per line), robust; at least 0.1 deg so exact data keeps finite weights
        sig = max(1.4826 * float(np.median(res)) / np.sqrt(np.log(4.0)), np.radians(0.1))
        w = 1.0 / (dist ** 2 * (1.0 + (res / (2.0 * sig)) ** 2))
    inl = res < 3.0 * np.sqrt(2.0) * sig
    if np.count_nonzero(inl) >= min_points and not inl.all():
        w = np.where(inl, w, 0.0)
        h = _solve(l, p, w)
        d = h[None, :3] - h[3] * p
        dist = np.linalg.norm(d, axis=1)
        res = np.arccos(np.clip(np.einsum("ni,ni->n", d / dist[:, None], l), -1.0, 1.0))
    dirs = d / dist[:, None]
    # Each fitted direction's error: the lines' scatter through the fit. A finite light L moves the
    # direction at p by (I - d d^T) dL / |L - p|; with J_k that map, cov(L) = s^2 (sum J^T J)^-1
    # over the inliers and cov(d_k) = J_k cov(L) J_k^T (a pseudo-inverse: a distant light's depth
    # along its direction is unconstrained and moves no direction).
    P_t = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    if abs(h[3]) * np.max(dist) > 1e-9 * np.linalg.norm(h[:3]):
        J = P_t / (dist / abs(h[3]))[:, None, None]
    else:  # at infinity: the common direction, n lines' mean
        J = P_t
    cov_L = np.linalg.pinv(np.einsum("nji,njk->ik", J[inl], J[inl]), rcond=1e-10, hermitian=True) * sig ** 2
    cov_d = np.einsum("nij,jk,nlk->nil", J, cov_L, J)
    sd = np.sqrt(np.maximum(np.trace(cov_d, axis1=1, axis2=2), 0.0))  # the RMS angle (both components)
    out_d, out_s, out_r, out_i = np.full((n, 3), np.nan), np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool)
    out_d[use], out_s[use], out_r[use], out_i[use] = dirs, np.degrees(sd), np.degrees(res), inl
    # the place in the input's coordinates: x_n = (x - p0) / scale, so (x, w) -> (scale x_n + w p0, w)
    h_world = np.append(scale * h[:3] + h[3] * p0, h[3])
    # points not used (NaN direction, finite point) still get the fitted direction toward the light
    rest = np.all(np.isfinite(p_in), axis=1) & ~use
    if rest.any():
        dr = h_world[None, :3] - h_world[3] * p_in[rest]
        out_d[rest] = dr / np.linalg.norm(dr, axis=1, keepdims=True)
    return LightFit(h_world / np.linalg.norm(h_world), out_d, out_s, out_r, out_i, float(np.degrees(sig)))
