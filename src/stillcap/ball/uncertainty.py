"""Uncertainty of a pitch's measurements: the error modes of the ball positions and the metrics' sigmas.

- **Ball-centre bias left by the shading correction** (issue 3, coverage):
  :func:`shading_model_offset_px`, :func:`shading_residual_px` and its table
  :func:`shading_residual_lookup`, :func:`lit_phase_from_area` (in
  :mod:`stillcap.ball._uncertainty_shading`, with the model they rest on; re-exported here).
- **Error modes of a stereo pair's positions**: how its triangulated positions move with each
  camera's focal-length error (:func:`calibration_modes`), a shared shift of one camera's ball
  centres (:func:`center_bias_modes`), or the bias the shading correction leaves
  (:func:`lit_geometry`, :func:`lit_bias_modes`, :func:`remaining_bias_modes`); the random
  centre error (:func:`pixel_sigma`); each image's covariance from them
  (:func:`position_covariances`). ``docs/pitch.md``, "Uncertainties".
- **Metrics** (in :mod:`stillcap.ball.metric_uncertainty`, re-exported here): 1-sigma of every pitch metric from the reference fit's and the marker spin's
  covariances (:func:`metrics_sigma`, first order or Monte Carlo through the flight model), of
  the speed (:func:`speed_sigma`), and the Nathan model's spin decay over the flashes
  (:func:`spin_decay_slope`).
"""

from __future__ import annotations

import cv2
import numpy as np

from stillcap.ball._uncertainty_shading import (
    lit_phase_from_area,
    shading_model_offset_px,
    shading_offset_slope_lookup,
    shading_residual_lookup,
    shading_residual_px,
)
from stillcap.ball.image_levels import level_factors, whitened_levels
from stillcap.ball.metric_uncertainty import (
    ANGLE_KEYS,
    metrics_sigma,
    speed_sigma,
    spin_decay_slope,
)
from stillcap.camera import Camera
from stillcap.detect.ball import BallFlag
from stillcap.geometry.triangulate import triangulate

__all__ = ["ANGLE_KEYS", "calibration_modes", "center_bias_modes", "correction_made", "epipolar_bias_scale",
           "lit_bias_modes", "lit_geometry", "lit_phase_from_area", "metrics_sigma", "misfit_share",
           "phase_error_px", "pixel_sigma", "position_covariances", "remaining_bias_modes",
           "shading_model_offset_px", "shading_offset_slope_lookup", "shading_residual_lookup",
           "shading_residual_px", "share_correlation", "speed_sigma", "spin_decay_slope"]


def position_covariances(residuals, shape_covariance, shared_modes=None, dof_ratio: float = 1.0,
                         level_dispersion: float = 0.0):
    """Per-image 3-D error covariance of one stereo pair's ball positions.

    A pair's triangulated position errors are a thin ellipsoid along its lines of sight (depth
    3-10x worse than across the view), and they grow where the geometry is worse (farther
    balls, narrower angles between the rays), so one isotropic sigma per pair cannot describe
    them: a chi-square test with it covers too little where the error is one-dimensional
    (``3 chi2_1 <= chi2_3(95 %)`` holds 89 % of the time) and mis-sizes the ends of the pair's
    flight (docs/pitch.md, "Coverage audit", sixth pass). Here each image keeps its own shape
    from the triangulation geometry (``shape_covariance``, e.g. a pixel error mapped through the
    re-triangulation), its level is estimated from the pair's residuals to the reference
    trajectory, whitened with that shape (generalised least squares' residual variance), and the
    errors the pair's images share (calibration, remaining centre bias: ``shared_modes``, which
    the residuals cannot show) are added:

    ``C_k = f_k s^2 S_k + sum_m d_mk d_mk^T``,  ``s^2 = dof_ratio * mean_k(r_k^T S_k^-1 r_k) / 3``,

    ``f_k`` each image's own level where the images' levels differ (``level_dispersion`` > 0:
    :func:`stillcap.ball.image_levels.level_factors`, from the image's own residual), else 1.

    Parameters
    ----------
    residuals : array_like, shape (K, 3)
        The pair's positions' residuals to the fitted flight (m; rows with a NaN are skipped).
    shape_covariance : array_like, shape (K, 3, 3)
        Each image's error covariance shape (m^2; its overall scale is re-estimated).
    shared_modes : array_like, shape (M, K, 3), optional
        1-sigma position shifts shared by the pair's images (m).
    dof_ratio : float
        ``m / (m - n)`` of the fit the residuals come from (``m`` observed coordinates, ``n``
        fitted parameters): residuals are smaller than the errors by the fitted degrees of
        freedom, as in the fit's own ``residual_scale``.
    level_dispersion : float
        Variance of the images' error levels about the pair's
        (:func:`stillcap.ball.image_levels.level_dispersion`, pooled over the capture's pairs);
        0: one level for all images.

    Returns
    -------
    cov : ndarray, shape (K, 3, 3) or None
        Covariance per image (m^2); None with fewer than two usable residual rows.
    s2 : float
        The shape's estimated scale (NaN when ``cov`` is None).
    """
    r = np.asarray(residuals, float)
    S = np.asarray(shape_covariance, float)
    m2 = whitened_levels(r, S)  # checks the shapes
    if not dof_ratio >= 1.0:
        raise ValueError(f"dof_ratio must be >= 1, got {dof_ratio}")
    if np.isfinite(m2).sum() < 2:
        return None, float("nan")
    s2 = float(dof_ratio * np.nanmean(m2) / 3.0)
    cov = s2 * level_factors(m2, level_dispersion)[:, None, None] * S
    if shared_modes is not None:
        D = np.asarray(shared_modes, float)
        if D.ndim != 3 or D.shape[1:] != (len(r), 3):
            raise ValueError(f"shared_modes must have shape (M, {len(r)}, 3), got {D.shape}")
        cov = cov + np.einsum("mki,mkj->kij", D, D)
    return cov, s2

# --------------------------------------------------------------------------------------------
# Error modes of a stereo pair's positions
# --------------------------------------------------------------------------------------------
def calibration_modes(cams, centers_px, board_points, focal_sigma: float):
    """How a pair's triangulated positions move with each camera's focal-length error.

    For each camera the focal length is scaled by ``1 + focal_sigma``, the pose re-solved by PnP
    on the board corners it was calibrated with (their pixels as the calibrated camera sees
    them: the error the board cannot reveal), and the ball images re-triangulated.

    Parameters
    ----------
    cams : sequence of 2 Camera
    centers_px : array_like, shape (2, K, 2)
    board_points : sequence of 2 (ndarray, shape (N, 3), or None), or None
        World coordinates of the calibration board corners each camera's pose was solved on
        (:func:`stillcap.io.capture.board_points_world`, from the capture's ``meta.calibration``
        record; None where the record does not say); None without a record.
    focal_sigma : float

    Returns
    -------
    ndarray, shape (2, K, 3) or None
        Position shift per camera at 1 sigma (m); None without usable board points.
    """
    x = np.asarray(centers_px, float)
    if board_points is None or not focal_sigma > 0 or x.shape[1] == 0:
        return None
    X0 = triangulate(list(cams), x).points
    out = np.zeros((2, x.shape[1], 3))
    for i, cam in enumerate(cams):
        W = board_points[i]
        if W is None or len(W) < 6:
            return None
        img = cam.project(W)
        K = cam.K.copy()
        K[0, 0] *= 1.0 + focal_sigma
        K[1, 1] *= 1.0 + focal_sigma
        rvec, _ = cv2.Rodrigues(cam.R)
        ok, rvec, tvec = cv2.solvePnP(W, img, K, cam.dist, rvec.copy(), cam.t.reshape(3, 1).copy(),
                                      useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            return None
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        c2 = Camera(cam.name, K, cam.dist, T, cam.image_size, cam.response)
        pair = [c2, cams[1]] if i == 0 else [cams[0], c2]
        out[i] = triangulate(pair, x).points - X0
    return out


def pixel_sigma(reproj_error_px, default_px: float = 0.1) -> float:
    """Random ball-centre error per image axis, px: ``sqrt(2) x`` the RMS reprojection error of
    a pair's triangulated centres (a two-view reprojection error sees one of the two pixel
    errors' four components' worth of noise per camera), ``default_px`` with fewer than two."""
    e = np.asarray(reproj_error_px, float)
    e = e[np.isfinite(e)]
    s = float(np.sqrt(2.0 * np.mean(e ** 2))) if len(e) >= 2 else 0.0
    return s if s > 0 else default_px


def center_bias_modes(cams, centers_px, sigma_px: float, trend: bool = False):
    """How a pair's triangulated positions move with a systematic shift of one camera's ball
    centres: one mode per camera and image axis, the same shift for all its ball images; with
    ``trend`` also one mode per camera and axis whose shift changes linearly along the pair's
    images (in flight order), from ``-sigma_px`` at the first to ``+sigma_px`` at the last.

    Returns
    -------
    ndarray, shape (4, K, 3), or (8, K, 3) with ``trend``
        Position shift (m) of camera 0 x, 0 y, 1 x, 1 y (then the same four for the trend).
    """
    x = np.asarray(centers_px, float)
    K = x.shape[1]
    profiles = [np.ones(K)]
    if trend:
        profiles.append(np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K))
    out = np.zeros((4 * len(profiles), K, 3))
    if not sigma_px > 0 or K == 0:
        return out
    shifted = []
    for prof in profiles:
        for c in range(2):
            for j in range(2):
                xs = x.copy()
                xs[c, :, j] += sigma_px * prof
                shifted.append(xs)
    return _retriangulated_shifts(cams, x, shifted)


def _retriangulated_shifts(cams, x, shifted) -> np.ndarray:
    """Position shifts (m), shape (len(shifted), K, 3), of a pair's centres ``x`` (2, K, 2)
    re-triangulated as each of the ``shifted`` copies: one triangulation of the centres and all
    copies (a call per copy cost ~8x more)."""
    K = x.shape[1]
    P = triangulate(list(cams), np.concatenate([x, *shifted], axis=1)).points.reshape(1 + len(shifted), K, 3)
    return P[1:] - P[0]


def lit_geometry(stereo, centers_px, flags, radius_px):
    """Per ball image of a pair: the lit direction, the phase angle and whether the shading
    correction ran, from the stereo step's detections.

    Parameters
    ----------
    stereo : StereoBalls
        The pair's :func:`stillcap.ball.stereo.ball_centers_stereo` result (its detections).
    centers_px : array_like, shape (2, K, 2)
        The pair's refined centres (rows of ``stereo.centers_a`` / ``centers_b``).
    flags : array_like of int, shape (K,)
        ``BallFlag`` bits of both views (``PARTIAL``: the correction ran in both views).
    radius_px : array_like, shape (2, K)

    Returns
    -------
    u : ndarray, shape (2, K, 2)
        Unit vector from the refined centre toward the silhouette's ellipse centre (the lit
        side: a lit silhouette's middle lies toward the light); 0 where they coincide.
    phase : ndarray, shape (2, K)
        Phase angle (rad): the one the shading correction used (``stereo.shading_phase_rad``,
        read from the ball image's radiance centroid through the blurred sphere model) where it
        ran, else from the silhouette's area (:func:`lit_phase_from_area`; a thresholded
        silhouette loses the dim terminator and under blur spreads past the disc: +6.5 to +15 deg
        off on sharp studio photos, -14 deg under 1.5 px of blur, ``docs/pitch.md``, "A share
        each capture measures?").
    corrected : ndarray of bool, shape (K,)
    """
    x = np.asarray(centers_px, float)
    if x.ndim != 3 or x.shape[0] != 2 or x.shape[2] != 2:
        raise ValueError(f"centers_px must have shape (2, K, 2), got {x.shape}")
    K = x.shape[1]
    u = np.zeros((2, K, 2))
    phase = np.zeros((2, K))
    for c, (cen, det, col) in enumerate(((stereo.centers_a, stereo.detections_a, 0),
                                         (stereo.centers_b, stereo.detections_b, 1))):
        if K == 0 or len(cen) == 0:
            break
        row = np.argmin(np.linalg.norm(np.asarray(cen)[None] - x[c][:, None], axis=2), axis=1)
        j = stereo.pairs[row, col]
        d = det.ellipse_centers[j] - x[c]
        n = np.linalg.norm(d, axis=1)
        u[c] = np.where(n[:, None] > 1e-9, d / np.maximum(n, 1e-9)[:, None], 0.0)
        phase[c] = lit_phase_from_area(det.areas[j], np.asarray(radius_px, float)[c])
        used = getattr(stereo, "shading_phase_rad", None)
        if used is not None:
            used = np.asarray(used, float)[row, c]
            phase[c] = np.where(np.isfinite(used), used, phase[c])
    corrected = (np.asarray(flags, int) & int(BallFlag.PARTIAL)) > 0
    return u, phase, corrected


def lit_bias_modes(cams, centers_px, u, sigma_px, corrected):
    """How a pair's triangulated positions move with the ball-centre bias that remains after
    the shading correction (:func:`shading_residual_lookup`).

    Per camera: for corrected images a shift of ``sigma_px`` along their lit direction ``u``
    (the correction's model error has that direction), the same for all (constant) and growing
    linearly from ``-sigma_px`` at the pair's first image to ``+sigma_px`` at its last (trend:
    the phase angle changes along the flight); for the others (full discs, no lit direction)
    the same two profiles along each image axis.

    Parameters
    ----------
    cams : sequence of 2 Camera
    centers_px : array_like, shape (2, K, 2)
    u : array_like, shape (2, K, 2)
    sigma_px : array_like, shape (2, K)
    corrected : array_like of bool, shape (K,)

    Returns
    -------
    ndarray, shape (12, K, 3)
        Position shift (m) per camera (6 each: along ``u`` constant, trend; x, y constant;
        x, y trend).
    """
    x = np.asarray(centers_px, float)
    K = x.shape[1] if x.ndim == 3 else 0
    u, s = np.asarray(u, float), np.asarray(sigma_px, float)
    if x.shape != (2, K, 2) or u.shape != (2, K, 2) or s.shape != (2, K):
        raise ValueError(f"centers_px and u must have shape (2, K, 2) and sigma_px (2, K), got "
                         f"{x.shape}, {u.shape}, {s.shape}")
    corr = np.broadcast_to(np.asarray(corrected, bool), (K,))
    out = np.zeros((12, K, 3))
    if K == 0:
        return out
    profiles = [np.ones(K), np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K)]
    e = np.eye(2)
    modes, shifted = [], []
    for c in range(2):
        shifts = [np.where(corr[:, None], u[c], 0.0) * (s[c] * prof)[:, None] for prof in profiles]
        shifts += [np.where(corr[:, None], 0.0, e[j]) * (s[c] * prof)[:, None] for prof in profiles for j in range(2)]
        for m, dx in enumerate(shifts):
            if np.any(dx):
                xs = x.copy()
                xs[c] += dx
                modes.append(6 * c + m)
                shifted.append(xs)
    if shifted:
        out[modes] = _retriangulated_shifts(cams, x, shifted)
    return out


def _stereo_values(stereo, centers_px, name: str) -> np.ndarray | None:
    """``stereo.<name>`` (K_stereo, 2, ...) at the rows of a pair's centres, shape (2, K, ...); None where
    the stereo step did not record it."""
    v = getattr(stereo, name, None)
    x = np.asarray(centers_px, float)
    if v is None or not len(stereo.centers_a) or not x.shape[1]:
        return None
    # the stereo rows of the pair's centres (as lit_geometry finds them)
    row = np.argmin(np.linalg.norm(np.asarray(stereo.centers_a)[None] - x[0][:, None], axis=2), axis=1)
    return np.moveaxis(np.asarray(v, float)[row], 0, 1)


def phase_error_px(stereo, centers_px, phase_rad, radius_px) -> np.ndarray:
    """1-sigma error (px, along the lit direction) of each corrected ball image's centre that the
    uncertainty of the correction's phase angle gives, measured per camera from its own photos.

    Each ball image's phase is read from its radiance centroid, and the correction reports a
    split-half sigma of it (``stereo.shading_phase_sd_rad``,
    :func:`stillcap.detect.ball._shading._phase_split_sd`: the two halves of a lambertian ball
    either side of its lit axis have the same centroid; painted markers, seams, a leather that is
    not lambertian, noise and compression move them apart). One image's split is a single
    difference, so a camera's phase sigma is their RMS over its images; each image's centre error
    is that times the slope of the model's offset with the phase at its own phase, radius and
    the camera's blur (:func:`shading_offset_slope_lookup`). Zero where nothing was reported.

    Returns
    -------
    ndarray, shape (2, K)
    """
    sd = _stereo_values(stereo, centers_px, "shading_phase_sd_rad")
    K = np.asarray(centers_px, float).shape[1]
    out = np.zeros((2, K))
    if sd is None:
        return out
    psf = np.broadcast_to(np.asarray(getattr(stereo, "psf_px", 0.5), float), (2,))
    for c in range(2):
        ok = np.isfinite(sd[c])
        if not ok.any():
            continue
        sig = float(np.sqrt(np.mean(sd[c][ok] ** 2)))
        slope = shading_offset_slope_lookup(phase_rad[c], radius_px[c], psf[c])
        out[c] = np.where(np.isfinite(slope), np.abs(slope) * sig, 0.0)
    return out


def misfit_share(stereo, centers_px, u, made=None, min_images: int = 4) -> np.ndarray:
    """The share of the shading correction a pair's photos say is wrong, per camera: a constant
    and a change along the pair's images, from the shift a least-squares fit of the correction's
    own model to each ball image asks for (``stereo.shading_misfit_px``,
    :func:`stillcap.detect.ball._shading._misfit_shift`).

    The correction places the model so that its Hough centre falls where the photo's does; a fit
    of the same model to all of the ball's pixels is a second estimate of the centre. Where the
    photo is the model they agree to the noise; where it is not (a leather that is not
    lambertian, a second light, paint, a wrong phase or blur) they part, along the lit
    direction, by an amount of the order of the correction's own error. Per camera the shifts
    along ``u`` are regressed on the correction made as the truth is in
    ``benchmarks/bench_shading_share.py``: ``d_k = (alpha + beta t_k) m_k``, ``t`` from -1 at the
    pair's first image to +1 at its last, and the share stated is
    ``sqrt((alpha^2 + beta^2) / 2)``: the noise in the two estimates is left in (it only widens),
    and the two estimates' own disagreement, not which of them is right, is what is measured.

    Parameters
    ----------
    stereo : StereoBalls
    centers_px : array_like, shape (2, K, 2)
    u : array_like, shape (2, K, 2)
        Lit direction per camera and image (:func:`lit_geometry`).
    made : array_like, shape (2, K), optional
        The correction made (:func:`correction_made`, read from ``stereo`` when not given).

    Returns
    -------
    ndarray, shape (2,)
        Per camera; 0 where fewer than ``min_images`` images report a shift.
    """
    d = _stereo_values(stereo, centers_px, "shading_misfit_px")
    m = correction_made(stereo, centers_px) if made is None else np.asarray(made, float)
    out = np.zeros(2)
    if d is None or m is None:
        return out
    K = d.shape[1]
    t = np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K)
    for c in range(2):
        a = np.einsum("kj,kj->k", d[c], np.asarray(u, float)[c])
        ok = np.isfinite(a) & (m[c] > 0)
        if ok.sum() < min_images:
            continue
        A = np.stack([m[c][ok], m[c][ok] * t[ok]], axis=1)
        coef, *_ = np.linalg.lstsq(A, a[ok], rcond=None)
        if np.linalg.matrix_rank(A) < 2:
            coef = np.array([float(np.sum(A[:, 0] * a[ok]) / np.sum(A[:, 0] ** 2)), 0.0])
        out[c] = float(np.sqrt(np.mean(coef ** 2)))
    return out


def correction_made(stereo, centers_px) -> np.ndarray | None:
    """The shading correction's length (px) per camera and ball image of a pair's centres,
    shape (2, K) (``stereo.shading_px`` at the rows the centres came from); None where the
    stereo step did not record it."""
    return _stereo_values(stereo, centers_px, "shading_px")


def _signed_epipolar_px(cams, x) -> np.ndarray:
    """Signed distance (px) of each camera-1 centre from the epipolar line of its camera-0 centre
    (undistorted pixels), ``x`` shape (2, K, 2) raw pixels."""
    from stillcap.geometry.epipolar import fundamental_matrix

    xa, xb = cams[0].undistort_points(x[0]), cams[1].undistort_points(x[1])
    F = fundamental_matrix(cams[0], cams[1])
    lines = np.concatenate([xa, np.ones((len(xa), 1))], axis=1) @ F.T
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1)
    return np.einsum("ij,ij->i", hb, lines) / np.linalg.norm(lines[:, :2], axis=1)


def share_correlation(cams, centers_px, u, s_px, min_images: int = 4) -> np.ndarray:
    """How much of the two cameras' remaining shading bias a pair's epipolar residuals say is
    shared (correlation 1) rather than each camera's own (0), for the constant and the trend mode.

    A bias shared by both cameras (the same light, blur and ball: each centre moved by ``kappa
    s_px`` along its own lit direction ``u``) keeps the two centres on each other's epipolar
    lines; one camera's own part moves them off. The flight absorbs nothing of this: the signed
    epipolar residuals of the pair's ball images are regressed (least squares, their scatter
    scaling the variance) on the response to the difference ``delta`` of the two cameras' shares
    (camera 0 moved by ``+delta/2``, camera 1 by ``-delta/2``), constant and trending along the
    flight. With the former model's prior (each camera's share independent with the same 1-sigma:
    ``delta`` of variance 2 in units of that sigma squared) the posterior's ``E[delta^2] = m2``
    gives the correlation ``1 - m2 / 2``. Where the capture cannot tell (fewer than
    ``min_images``, a light along the epipolar lines), the posterior is the prior: correlation 0,
    the former independent model. Random centre errors show as scatter, not as a difference.

    Parameters
    ----------
    cams : sequence of 2 Camera
    centers_px : array_like, shape (2, K, 2)
    u : array_like, shape (2, K, 2)
        Lit direction per camera and image.
    s_px : array_like, shape (2, K)
        1-sigma of each image's remaining bias along ``u`` (px): the sizes of the modes.

    Returns
    -------
    ndarray, shape (2,)
        Correlation of the constant and of the trend mode, in [0, 1].
    """
    return _correlation_of(_epipolar_delta(cams, centers_px, u, s_px, min_images))


def _correlation_of(fit) -> np.ndarray:
    """:func:`share_correlation` from :func:`_epipolar_delta`'s ``(d, V)`` (None: zeros)."""
    if fit is None:
        return np.zeros(2)
    d, V = fit
    out = np.zeros(2)
    for i in range(2):
        P, v = 2.0, max(float(V[i, i]), 1e-300)  # the prior of delta: two independent unit shares
        post_var = 1.0 / (1.0 / P + 1.0 / v)
        m2 = (post_var * d[i] / v) ** 2 + post_var
        out[i] = float(np.clip(1.0 - m2 / P, 0.0, 1.0))
    return out


def epipolar_bias_scale(cams, centers_px, u, s_px, min_images: int = 4) -> np.ndarray:
    """How much larger than stated the two cameras' own remaining bias is, as the pair's
    epipolar residuals measure it: the variance factor ``lambda >= 1`` of the stated one, for the
    constant and the trend mode.

    The difference ``delta`` of the two cameras' shares (in units of the stated sigma,
    :func:`share_correlation`'s regression) has, with each camera's own share of variance
    ``lambda``, the variance ``2 lambda``; its estimate ``d`` with sampling variance ``V``
    then has ``E[d^2] = 2 lambda + V``: ``(d^2 - V) / 2`` estimates ``lambda``. One difference
    is a noisy estimate of a variance where ``V`` is large (a light along the epipolar lines), so
    its excess over the stated 1 is weighed as ``share_correlation`` weighs ``d`` against the
    prior, by ``2 / (2 + V)``: ``lambda = 1 + 2 / (2 + V) max(0, (d^2 - V) / 2 - 1)``; never
    narrower than stated. A bias both cameras share is not seen (it keeps the centres on each
    other's epipolar lines).

    Returns
    -------
    ndarray, shape (2,)
        1 where the capture cannot tell (as :func:`share_correlation`).
    """
    return _scale_of(_epipolar_delta(cams, centers_px, u, s_px, min_images))


def _scale_of(fit) -> np.ndarray:
    """:func:`epipolar_bias_scale` from :func:`_epipolar_delta`'s ``(d, V)`` (None: ones)."""
    if fit is None:
        return np.ones(2)
    d, V = fit
    v = np.diag(V)
    return 1.0 + 2.0 / (2.0 + v) * np.maximum(0.0, (d ** 2 - v) / 2.0 - 1.0)


def _epipolar_delta(cams, centers_px, u, s_px, min_images: int):
    """The difference of the two cameras' shares (constant, trend; in units of ``s_px``)
    regressed from the pair's signed epipolar residuals, and its covariance; None where the
    capture cannot tell (:func:`share_correlation`)."""
    x = np.asarray(centers_px, float)
    u, s = np.asarray(u, float), np.asarray(s_px, float)
    K = x.shape[1]
    if K < min_images or not np.all(np.isfinite(x)) or not np.any(s > 0):
        return None
    e0 = _signed_epipolar_px(cams, x)
    h = 0.01
    g = np.zeros(K)
    for c, sign in ((0, 0.5), (1, -0.5)):
        xs = x.copy()
        xs[c] += h * sign * s[c][:, None] * u[c]
        g += (_signed_epipolar_px(cams, xs) - e0) / h
    t = np.linspace(-1.0, 1.0, K)
    A = np.stack([g, g * t], axis=1)  # (K, 2): delta constant, delta trend (in units of the sigma)
    ok = np.all(np.isfinite(A), axis=1) & np.isfinite(e0)
    A, e0 = A[ok], e0[ok]
    if len(e0) < min_images:
        return None
    AtA = A.T @ A
    try:
        d = np.linalg.solve(AtA + 1e-12 * np.eye(2), A.T @ e0)
        s2 = float(np.sum((e0 - A @ d) ** 2) / max(len(e0) - 2, 1))
        V = s2 * np.linalg.inv(AtA + 1e-12 * np.eye(2))
    except np.linalg.LinAlgError:
        return None
    return d, V


def remaining_bias_modes(cams, stereo, centers_px, flags, radius_px, model_error=0.0, correlation=0.0,
                         measured: bool = True, epipolar_scale: bool = False) -> np.ndarray:
    """:func:`lit_bias_modes` of a pair, sized by the shading model's remaining error
    (arguments as :func:`lit_geometry`'s, with the pair's 2 cameras).

    Where the stereo step corrected every ball image (``stereo.shading_px``, the correction's
    length per image and camera, set), every image counts as corrected, and its remaining bias is
    the model's own error (:func:`shading_residual_lookup`) and ``model_error`` times the
    correction made, in quadrature: the share of the correction the model may have wrong (its
    light, blur, clipping and lambertian leather are estimates or assumptions), the same share
    for every image of a camera (the ``lit_bias_modes`` are shared by the camera's images: a
    constant and a trend mode per camera; one mode per camera for the share alone was tried,
    ``docs/pitch.md``, "The correction's wrong share").
    ``model_error``: one share for both cameras, or one per camera (shape (2,)).
    ``measured``: the error the correction's own inputs and fit show in this capture added in
    quadrature (:func:`phase_error_px`: the phase angle's split-half sigma carried through the
    model; :func:`misfit_share`: the share the model's misfit to the photos states), so
    ``model_error`` is then the floor for what the photos cannot show.

    ``correlation``: how much of the two cameras' remaining bias along their lit directions is
    shared by them (0: each camera's own, the former model; 1: the same share in both), a number
    or ``"epipolar"`` (:func:`share_correlation`, from the pair's epipolar residuals; one value
    for the constant and one for the trend mode). Each camera's own variance stays the same: the
    along-``u`` modes keep ``1 - rho`` of it and two modes more move both cameras at once.

    ``epipolar_scale``: each camera's own part (the along-``u`` modes) times the factor the
    pair's epipolar residuals measure where they show more than the stated bias
    (:func:`epipolar_bias_scale`: ``sqrt(lambda)``, ``lambda >= 1``, constant and trend mode).

    Returns
    -------
    ndarray, shape (14, K, 3)
        :func:`lit_bias_modes`' 12, then the shared constant and trend modes (zero with a
        correlation of 0).
    """
    u, phase, corr = lit_geometry(stereo, centers_px, flags, radius_px)
    made = correction_made(stereo, centers_px)
    if made is not None:
        corr = corr | np.any(made > 0, axis=0)
    k = np.broadcast_to(np.asarray(model_error, float), (2,))
    if not np.all(np.isfinite(k) & (k >= 0)):
        raise ValueError(f"model_error must be >= 0 (one or one per camera), got {model_error}")
    # full discs (not PARTIAL, phase below ~55 deg) as lit from the camera: there the model's
    # offset swings by ~0.1 px within 10 deg of phase, finer than the silhouette's area resolves
    # (a thresholded full disc loses its dim limb: 0.96-1.11 of pi r^2 from 0 to 30 deg), and
    # against the truth the front pair's (phase ~10 deg) per-camera bias was 0.016-0.020 px
    phase = np.where(corr[None, :], phase, 0.0)
    s = np.stack([shading_residual_lookup(phase[c], radius_px[c], corr) for c in range(2)])
    if made is not None and np.any(k > 0):
        s = np.hypot(s, k[:, None] * made)
    if measured:
        s = np.hypot(s, np.where(corr[None, :], phase_error_px(stereo, centers_px, phase, radius_px), 0.0))
        if made is not None:
            s = np.hypot(s, misfit_share(stereo, centers_px, u, made)[:, None] * made)
    x = np.asarray(centers_px, float)
    K = x.shape[1]
    if isinstance(correlation, str) and correlation != "epipolar":
        raise ValueError(f"correlation must be a number in [0, 1] or 'epipolar', got {correlation!r}")
    # the pair's epipolar regression, once for the correlation and the scale that both read it
    delta = (_epipolar_delta(cams, x, np.where(corr[None, :, None], u, 0.0), np.where(corr[None], s, 0.0),
                             min_images=4) if isinstance(correlation, str) or epipolar_scale else None)
    if isinstance(correlation, str):
        rho = _correlation_of(delta)
    else:
        rho = np.broadcast_to(np.asarray(correlation, float), (2,))
        if not np.all((rho >= 0) & (rho <= 1)):
            raise ValueError(f"correlation must be in [0, 1], got {correlation}")
    out = np.zeros((14, K, 3))
    if K == 0:
        return out
    # the cameras' own parts: the along-u modes (0, 1 and 6, 7) with 1 - rho of the variance
    own = lit_bias_modes(cams, centers_px, u, s, corr)
    out[:12] = own
    lam = _scale_of(delta) if epipolar_scale else np.ones(2)
    for i, m in ((0, 0), (1, 1)):
        out[[m, m + 6]] *= np.sqrt((1.0 - rho[i]) * lam[i])
    if np.any(rho > 0) and np.any(corr):
        profiles = [np.ones(K), np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K)]
        shifted = []
        for i, prof in enumerate(profiles):
            xs = x.copy()
            for c in range(2):
                xs[c] += np.where(corr[:, None], u[c], 0.0) * (np.sqrt(rho[i]) * s[c] * prof)[:, None]
            shifted.append(xs)
        out[12:] = _retriangulated_shifts(cams, x, shifted)
    return out
