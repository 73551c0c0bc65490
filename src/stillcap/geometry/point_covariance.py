"""How well triangulation fixes each 3D point: its error covariance from the views that saw it.

A point seen by two cameras of one stereo pair is fixed less well along the pair's viewing
direction than across it (the depth error grows with the distance over the baseline); a fit
that weighs every marker's error as a round ball of one size trusts its depth as much as its
side-to-side place. :func:`triangulation_covariance` gives the first-order (Gauss-Newton)
covariance ``sigma_px**2 * (sum_i J_i^T J_i)^-1`` of each point, ``J_i`` the 2x3 Jacobian of
camera ``i``'s projection at the point, over the cameras that saw it;
:func:`pixel_sigma_from_reprojection` estimates ``sigma_px`` from the points' own reprojection
errors, so that the size comes from the photos, not from a constant.

Written by hand because it is a few lines of NumPy over :meth:`stillcap.camera.Camera.project`
(OpenCV's ``projectPoints`` Jacobian is with respect to the pose, not to the point, and does not
pass NaN through).
"""

from __future__ import annotations

import numpy as np

from stillcap._checks import as_array

__all__ = ["marker_point_covariances", "pixel_sigma_from_reprojection", "triangulation_covariance"]

#: Step of the central differences of the projection (m): a pixel is ~1 mm at the hand's
#: distance, so 0.1 mm keeps the projection linear and far above rounding.
_STEP_M = 1e-4


def triangulation_covariance(rig, pixels, points, sigma_px: float = 1.0) -> np.ndarray:
    """Each point's error covariance (m^2) from the cameras that saw it.

    Parameters
    ----------
    rig : Rig
        The cameras, in the order of ``pixels``' first axis.
    pixels : array_like, shape (n_cams, N, 2)
        The image points used (NaN where a camera did not see the point); only which are
        finite matters.
    points : array_like, shape (N, 3)
        The triangulated points (m, world).
    sigma_px : float
        Each image point's error, 1-sigma per coordinate (pixels).

    Returns
    -------
    ndarray, shape (N, 3, 3)
        NaN for a point seen by fewer than two cameras (or behind one).
    """
    pts = as_array(points, (None, 3), "points")
    px = as_array(pixels, (len(rig), len(pts), 2), "pixels")
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        raise ValueError(f"sigma_px must be a positive number of pixels, got {sigma_px}")
    info = np.zeros((len(pts), 3, 3))
    n_used = np.zeros(len(pts), int)
    eye = np.eye(3) * _STEP_M
    for c, cam in enumerate(rig):
        used = np.isfinite(px[c]).all(axis=1)
        if not used.any():
            continue
        p = pts[used]
        J = np.stack([(cam.project(p + eye[a]) - cam.project(p - eye[a])) / (2 * _STEP_M) for a in range(3)],
                     axis=-1)  # (n, 2, 3)
        ok = np.isfinite(J).all(axis=(1, 2))
        idx = np.flatnonzero(used)[ok]
        info[idx] += np.einsum("nki,nkj->nij", J[ok], J[ok])
        n_used[idx] += 1
    cov = np.full((len(pts), 3, 3), np.nan)
    good = n_used >= 2
    if good.any():
        cov[good] = np.linalg.inv(info[good]) * float(sigma_px) ** 2
    return cov


def pixel_sigma_from_reprojection(reprojection_px, n_views) -> float:
    """The image points' error (1-sigma per coordinate, pixels) that explains the reprojection
    errors of triangulated points: a point of ``n`` views leaves ``2n - 3`` degrees of freedom
    in its ``2n`` coordinates, so ``E[rms^2] = sigma^2 (2n - 3) / n`` for the RMS of the views'
    pixel distances; pooled over the points (NaN when none has two views)."""
    r = np.asarray(reprojection_px, float)
    n = np.asarray(n_views, float)
    ok = np.isfinite(r) & (n >= 2)
    if not ok.any():
        return float("nan")
    dof = (2 * n[ok] - 3) / n[ok]
    return float(np.sqrt(np.sum(r[ok] ** 2) / np.sum(dof)))


def marker_point_covariances(rig, points, hidden_sigma_m: float, sigma_px: float | None = None) -> np.ndarray:
    """Each 3D glove marker's error covariance (m^2), shape (N, 3, 3): its triangulation's
    (:func:`triangulation_covariance`, the pixel noise ``sigma_px`` or, by default, the one its
    fully seen points' reprojection errors show: :func:`pixel_sigma_from_reprojection`), plus for
    a partly hidden point a round error of ``hidden_sigma_m`` over its smallest flux ratio (its
    centroid shifted by the part hidden; a sliver counts as 0.02).

    ``points`` is a :class:`~stillcap.geometry.marker_points.MarkerPoints`. NaN for a point of
    fewer than two views, and everywhere when no pixel noise can be had."""
    whole = ~points.partly_hidden
    if sigma_px is None:
        sigma_px = pixel_sigma_from_reprojection(points.reprojection_px[whole], points.n_views[whole])
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        return np.full((len(points), 3, 3), np.nan)
    cov = triangulation_covariance(rig, points.pixels, points.points, sigma_px)
    flux = np.where(np.isfinite(points.flux_ratio), points.flux_ratio, np.inf).min(axis=0)
    flux = np.clip(np.where(np.isfinite(flux), flux, 1.0), 0.02, 1.0)
    extra = np.where(points.partly_hidden, hidden_sigma_m / flux, 0.0)
    return cov + np.eye(3)[None] * extra[:, None, None] ** 2
