"""The ball-centre bias the shading correction leaves (issue 3, coverage): the model's offset
:func:`shading_model_offset_px`, its residual :func:`shading_residual_px` and their run-time tables
(:func:`shading_residual_lookup`, :func:`shading_offset_slope_lookup`), the phase angle from a
silhouette's area (:func:`lit_phase_from_area`). Re-exported by :mod:`stillcap.ball.uncertainty`.

**The shading bias.** The known-radius Hough centre of a lit lambertian sphere sits off the true centre along the lit
direction (:func:`stillcap.detect.ball._shading._shading_bias`); ``refine_ball_centers(shading=...)`` removes
that offset for partly lit (``PARTIAL``) balls with a model of the ball (phase angle read from
the image, lens blur ``psf_px``). What it leaves is the model's own error: this module sizes it
from the same model, rendered and Hough-refined with the detector's functions, under the
variations the correction cannot know (the lens blur over a plausible range, the phase angle's
estimate), and, for balls it does not correct (full discs), the model's offset itself.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from stillcap.ball._offset_table import OFFSET as _OFFSET
from stillcap.ball._offset_table import OFFSET_PSF as _OFFSET_PSF

__all__ = ["lit_phase_from_area", "shading_model_offset_px", "shading_offset_slope_lookup",
           "shading_residual_lookup", "shading_residual_px"]

#: refinement smoothing of :func:`stillcap.detect.ball.refine_ball_centers` (its ``sigma``)
_REFINE_SIGMA = 0.7


@functools.lru_cache(maxsize=4096)
def _offset_cached(phase_deg: int, radius_q: int, blur_q: int) -> float:
    from stillcap.detect.ball._hough import _template
    from stillcap.detect.ball._shading import _lit_sphere_image, _model_peak

    alpha, r, blur = np.radians(phase_deg), radius_q / 4.0, blur_q / 100.0
    n = int(2 * r + 20)
    m = max(24, int(np.ceil(2 * np.pi * r)))
    th = np.linspace(0, 2 * np.pi, m, endpoint=False)
    off = r * np.stack([np.cos(th), np.sin(th)], axis=1)
    nrm, wt = _template(off)
    wt = (wt / wt.sum()).astype(np.float32)
    tpl = tuple(a.astype(np.float32) for a in (off[:, 0], off[:, 1], nrm[:, 0], nrm[:, 1])) + (wt,)
    light = (np.sin(alpha), 0.0, np.cos(alpha))
    step, kf = 0.1, 3
    res = []
    # the mean over four sub-pixel placements: one placement's pixel grid moves a rendered
    # ball's Hough peak by up to ~0.05 px even where the shading is symmetric (a full disc)
    for sub in ((0.0, 0.0), (0.5, 0.25), (0.25, 0.5), (0.75, 0.75)):
        c = np.array([n / 2 + sub[0], n / 2 + sub[1]])
        img = cv2.GaussianBlur(_lit_sphere_image((n, n), c, np.eye(2) * r, light), (0, 0), blur)
        res.append(_model_peak(img, c, tpl, 0.0, step, kf)[0] - c[0])
    return float(np.mean(res))


def shading_model_offset_px(phase_rad: float, radius_px: float, psf_px: float = 0.5) -> float:
    """Offset (px, positive toward the light) of the detector's known-radius Hough centre from
    the true centre for a lambertian sphere of ``radius_px`` lit at ``phase_rad``, blurred by
    the lens (``psf_px``) and the refinement's own smoothing: the model the shading correction
    subtracts. Inputs are quantised (1 deg, 0.25 px, 0.01 px) and the results cached.

    Parameters
    ----------
    phase_rad : float
        Phase angle (0: lit from the camera, pi/2: from the side), clipped to [0, 150 deg].
    radius_px : float
        Projected ball radius (> 2 px).
    psf_px : float
        Gaussian lens blur, px (>= 0).
    """
    if not (np.isfinite(radius_px) and radius_px > 2.0):
        raise ValueError(f"radius_px must be > 2, got {radius_px}")
    if not (np.isfinite(psf_px) and psf_px >= 0):
        raise ValueError(f"psf_px must be >= 0, got {psf_px}")
    a = round(float(np.clip(np.degrees(phase_rad), 0.0, 150.0)))
    blur = float(np.hypot(_REFINE_SIGMA, psf_px))
    return _offset_cached(a, round(4 * float(radius_px)), round(100 * blur))


def shading_residual_px(phase_rad: float, radius_px: float, corrected: bool, psf_px: float = 0.5,
                        psf_range: tuple = (0.3, 0.8), phase_sigma_rad: float = np.radians(5.0)) -> float:
    """1-sigma centre bias (px, along the lit direction) that remains for one ball image.

    ``corrected`` (the shading correction ran, ``PARTIAL`` balls): the correction's model
    error, the half-spread of the model's offset as the lens blur runs over ``psf_range``
    (the correction assumes ``psf_px``) and as the phase angle moves by ``+-phase_sigma_rad``,
    in quadrature. Not corrected (full discs): the model's offset itself, which the detector
    leaves in (about 0 for a ball lit from near the camera), with the same spread.

    Returns
    -------
    float
    """
    lo, hi = psf_range
    f = functools.partial(shading_model_offset_px, radius_px=radius_px)
    s_psf = 0.5 * abs(f(phase_rad, psf_px=hi) - f(phase_rad, psf_px=lo))
    s_phase = 0.5 * abs(f(phase_rad + phase_sigma_rad, psf_px=psf_px)
                        - f(max(phase_rad - phase_sigma_rad, 0.0), psf_px=psf_px))
    s = float(np.hypot(s_psf, s_phase))
    if not corrected:
        s = float(np.hypot(s, f(phase_rad, psf_px=psf_px)))
    return s


def lit_phase_from_area(area_px2, radius_px):
    """Phase angle (rad) of a lambertian ball from its silhouette's area: the lit part of the
    disc covers ``(1 + cos phase) / 2`` of it (a half disc plus or minus the terminator's half
    ellipse of semi-axis ``r |cos phase|``). A silhouette thresholded from a rendered ball
    loses its dim terminator: about 10 deg at a 90 deg phase, a few deg near 0 and 150."""
    f = np.asarray(area_px2, float) / (np.pi * np.asarray(radius_px, float) ** 2)
    return np.arccos(np.clip(2.0 * f - 1.0, -1.0, 1.0))


# ``shading_residual_px`` tabulated (defaults: psf 0.5 px in 0.3-0.8, phase +-5 deg) on phase
# angles 0, 5, ..., 150 deg (columns) and radii ``_TABLE_RADII`` px (rows): it costs ~10 ms per
# entry, too much per ball image at run time. Regenerated by ``_residual_table`` (checked in
# tests/ball/test_uncertainty.py).
_TABLE_PHASE_DEG = np.arange(0, 151, 5)
_TABLE_RADII = np.array([10.0, 15.0, 20.0, 30.0, 40.0])
_RESIDUAL_CORRECTED = np.array([
    [0.029, 0.068, 0.064, 0.041, 0.028, 0.045, 0.101, 0.103, 0.064, 0.037, 0.035, 0.047, 0.066, 0.067, 0.052, 0.040, 0.032, 0.031, 0.033, 0.065, 0.089, 0.084, 0.064, 0.066, 0.092, 0.133, 0.124, 0.105, 0.144, 0.163, 0.133],
    [0.025, 0.041, 0.022, 0.029, 0.056, 0.070, 0.066, 0.033, 0.030, 0.034, 0.024, 0.025, 0.024, 0.024, 0.029, 0.035, 0.039, 0.040, 0.058, 0.060, 0.040, 0.038, 0.055, 0.062, 0.078, 0.092, 0.086, 0.116, 0.139, 0.134, 0.123],
    [0.024, 0.035, 0.015, 0.067, 0.085, 0.050, 0.014, 0.010, 0.019, 0.022, 0.023, 0.026, 0.033, 0.033, 0.031, 0.027, 0.025, 0.028, 0.031, 0.036, 0.043, 0.055, 0.054, 0.048, 0.059, 0.069, 0.081, 0.105, 0.114, 0.126, 0.118],
    [0.017, 0.010, 0.056, 0.095, 0.069, 0.013, 0.022, 0.024, 0.033, 0.031, 0.020, 0.019, 0.018, 0.019, 0.028, 0.031, 0.026, 0.028, 0.029, 0.029, 0.031, 0.032, 0.032, 0.043, 0.056, 0.062, 0.070, 0.068, 0.076, 0.125, 0.098],
    [0.011, 0.015, 0.092, 0.104, 0.037, 0.017, 0.029, 0.032, 0.031, 0.032, 0.030, 0.022, 0.018, 0.017, 0.018, 0.020, 0.021, 0.022, 0.022, 0.026, 0.029, 0.032, 0.036, 0.040, 0.040, 0.042, 0.051, 0.069, 0.084, 0.091, 0.079],
])
_RESIDUAL_UNCORRECTED = np.array([
    [0.030, 0.087, 0.145, 0.181, 0.198, 0.190, 0.177, 0.113, 0.066, 0.038, 0.038, 0.056, 0.090, 0.134, 0.163, 0.194, 0.215, 0.234, 0.253, 0.279, 0.315, 0.392, 0.427, 0.465, 0.504, 0.575, 0.676, 0.737, 0.792, 0.929, 0.996],
    [0.025, 0.065, 0.085, 0.090, 0.075, 0.070, 0.101, 0.115, 0.109, 0.072, 0.047, 0.031, 0.025, 0.036, 0.056, 0.081, 0.111, 0.139, 0.173, 0.225, 0.251, 0.275, 0.302, 0.351, 0.385, 0.455, 0.507, 0.574, 0.673, 0.776, 0.864],
    [0.024, 0.058, 0.069, 0.076, 0.103, 0.133, 0.151, 0.147, 0.131, 0.111, 0.089, 0.068, 0.047, 0.033, 0.043, 0.064, 0.082, 0.103, 0.126, 0.151, 0.180, 0.214, 0.257, 0.286, 0.322, 0.367, 0.418, 0.482, 0.571, 0.655, 0.756],
    [0.017, 0.036, 0.058, 0.119, 0.184, 0.208, 0.197, 0.174, 0.154, 0.114, 0.092, 0.073, 0.056, 0.039, 0.031, 0.038, 0.052, 0.075, 0.098, 0.120, 0.143, 0.167, 0.190, 0.215, 0.253, 0.295, 0.339, 0.398, 0.445, 0.519, 0.637],
    [0.011, 0.025, 0.096, 0.192, 0.237, 0.236, 0.215, 0.188, 0.159, 0.132, 0.101, 0.074, 0.056, 0.040, 0.026, 0.020, 0.028, 0.045, 0.063, 0.082, 0.105, 0.128, 0.154, 0.182, 0.212, 0.241, 0.274, 0.318, 0.380, 0.450, 0.523],
])


def _residual_table(corrected: bool) -> np.ndarray:
    """``shading_residual_px`` on the table's grid (what ``_RESIDUAL_*`` holds, rounded)."""
    return np.array([[shading_residual_px(np.radians(a), r, corrected) for a in _TABLE_PHASE_DEG]
                     for r in _TABLE_RADII])


# ``shading_model_offset_px`` itself tabulated (``stillcap.ball._offset_table``: lens blurs
# ``_OFFSET_PSF`` px, the radii ``_TABLE_RADII``, the phase angles ``_TABLE_PHASE_DEG``) for its slope
# with the phase at run time (``_offset_table`` regenerates it; checked in tests/ball/test_uncertainty.py)


def _offset_table() -> np.ndarray:
    """``shading_model_offset_px`` on ``_OFFSET``'s grid (what it holds, rounded)."""
    return np.array([[[shading_model_offset_px(np.radians(a), r, p) for a in _TABLE_PHASE_DEG] for r in _TABLE_RADII]
                     for p in _OFFSET_PSF])


def shading_offset_slope_lookup(phase_rad, radius_px, psf_px: float) -> np.ndarray:
    """Slope (px per rad) of the shading model's offset (:func:`shading_model_offset_px`) with the
    phase angle, for many ball images of one photo: central differences of the tabulated offset
    on its 5-deg grid, bilinear in the phase angle and the radius, linear in the lens blur
    (``psf_px`` clipped to 0-2 px). Radii outside 10-40 px take the nearest row scaled by the
    radius (the offset grows about as the ball).

    Parameters
    ----------
    phase_rad, radius_px : array_like, shape (N,)
    psf_px : float

    Returns
    -------
    ndarray, shape (N,)
    """
    a = np.clip(np.degrees(np.asarray(phase_rad, float)), 0.0, 150.0)
    r_in = np.asarray(radius_px, float)
    if a.shape != r_in.shape:
        raise ValueError(f"phase_rad and radius_px must have one shape, got {a.shape} and {r_in.shape}")
    if not np.isfinite(psf_px) or psf_px < 0:
        raise ValueError(f"psf_px must be >= 0, got {psf_px}")
    r = np.clip(r_in, _TABLE_RADII[0], _TABLE_RADII[-1])
    slope = np.gradient(_OFFSET, np.radians(_TABLE_PHASE_DEG), axis=2)  # (P, R, A)
    p = float(np.clip(psf_px, _OFFSET_PSF[0], _OFFSET_PSF[-1]))
    i = int(np.clip(np.searchsorted(_OFFSET_PSF, p) - 1, 0, len(_OFFSET_PSF) - 2))
    wp = (p - _OFFSET_PSF[i]) / (_OFFSET_PSF[i + 1] - _OFFSET_PSF[i])
    T = (1 - wp) * slope[i] + wp * slope[i + 1]  # (R, A)
    rows = np.array([np.interp(a, _TABLE_PHASE_DEG, T[j]) for j in range(len(_TABLE_RADII))])  # (R, N)
    j = np.clip(np.searchsorted(_TABLE_RADII, r) - 1, 0, len(_TABLE_RADII) - 2)
    w = (r - _TABLE_RADII[j]) / (_TABLE_RADII[j + 1] - _TABLE_RADII[j])
    k = np.arange(a.size)
    out = (1 - w.ravel()) * rows.reshape(len(_TABLE_RADII), -1)[j.ravel(), k] + w.ravel() * rows.reshape(
        len(_TABLE_RADII), -1)[j.ravel() + 1, k]
    return out.reshape(a.shape) * np.where(np.isfinite(r_in), r_in / r, np.nan)


def shading_residual_lookup(phase_rad, radius_px, corrected) -> np.ndarray:
    """:func:`shading_residual_px` (default options) for many ball images at once, bilinear in
    the tabulated phase angle and radius (radii outside 10-40 px take the nearest row).

    Parameters
    ----------
    phase_rad, radius_px, corrected : array_like, shape (N,)

    Returns
    -------
    ndarray, shape (N,)
        1-sigma remaining centre bias along the lit direction, px.
    """
    a = np.clip(np.degrees(np.asarray(phase_rad, float)), 0.0, 150.0)
    r = np.clip(np.asarray(radius_px, float), _TABLE_RADII[0], _TABLE_RADII[-1])
    c = np.broadcast_to(np.asarray(corrected, bool), a.shape)
    if a.shape != r.shape:
        raise ValueError(f"phase_rad and radius_px must have one shape, got {a.shape} and {r.shape}")
    out = np.zeros(a.shape)
    for flag, T in ((True, _RESIDUAL_CORRECTED), (False, _RESIDUAL_UNCORRECTED)):
        sel = c == flag
        if not sel.any():
            continue
        # along the phase angle per radius row, then along the radius
        rows = np.array([np.interp(a[sel], _TABLE_PHASE_DEG, T[i]) for i in range(len(_TABLE_RADII))])
        j = np.clip(np.searchsorted(_TABLE_RADII, r[sel]) - 1, 0, len(_TABLE_RADII) - 2)
        w = (r[sel] - _TABLE_RADII[j]) / (_TABLE_RADII[j + 1] - _TABLE_RADII[j])
        k = np.arange(sel.sum())
        out[sel] = (1 - w) * rows[j, k] + w * rows[j + 1, k]
    return out
