"""Step 3 of the ball detector: the exact image outline of a sphere through the lens model
(:func:`sphere_outline_px`)."""

from __future__ import annotations

import numpy as np

from stillcap._checks import as_array
from stillcap.camera import Camera


# --------------------------------------------------------------------------------------------
# step 3: projected outline of a sphere
# --------------------------------------------------------------------------------------------
def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two (N, 3) arrays: its formula, in its order of operations (the same
    numbers), without its generic overhead (this runs 4 times per stereo pair)."""
    out = np.empty(a.shape)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def sphere_outline_px(camera: Camera, centers_world, radius_m: float, n_points: int = 64):
    """Exact image outline of spheres in a (distorted) camera.

    The outline of a sphere is the image of its limb: the circle where the tangent cone from
    the camera centre touches it. It is sampled in 3D and projected through the lens model,
    so it includes the perspective elongation off-axis (an ellipse, not a circle) and the
    distortion.

    Parameters
    ----------
    camera : Camera
    centers_world : array_like, shape (N, 3)
        Sphere centres (world frame, metres).
    radius_m : float
        Sphere radius in metres.
    n_points : int
        Outline samples per sphere.

    Returns
    -------
    centers_px : ndarray, shape (N, 2)
        Projected sphere centres (raw pixels); NaN if the sphere is behind or around the camera.
    outlines_px : ndarray, shape (N, n_points, 2)
        Outline points in raw pixels.
    radii_px : ndarray, shape (N,)
        Mean distance of the outline from the projected centre.
    """
    C = as_array(centers_world, (None, 3), "centers_world")
    if not radius_m > 0:
        raise ValueError(f"radius_m must be positive, got {radius_m}")
    O = camera.center
    w = O[None, :] - C
    d = np.linalg.norm(w, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = w / d[:, None]
        ok = d > radius_m * 1.0001
        # limb circle: centre Q on the line to the camera, radius rho
        Q = C + (radius_m ** 2 / np.where(ok, d, np.nan))[:, None] * w
        rho = radius_m * np.sqrt(np.clip(1.0 - (radius_m / np.where(ok, d, np.nan)) ** 2, 0, None))
    ref = np.where(np.abs(w[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = _cross(w, ref)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    e2 = _cross(w, e1)
    th = np.linspace(0.0, 2 * np.pi, n_points, endpoint=False)
    pts = (Q[:, None, :] + rho[:, None, None] * (np.cos(th)[None, :, None] * e1[:, None, :]
                                                 + np.sin(th)[None, :, None] * e2[:, None, :]))
    outl = camera.project(pts.reshape(-1, 3)).reshape(len(C), n_points, 2)
    cen = camera.project(C)
    bad = ~ok | np.any(~np.isfinite(outl), axis=(1, 2)) | np.any(~np.isfinite(cen), axis=1)
    outl[bad] = np.nan
    cen[bad] = np.nan
    radii = np.linalg.norm(outl - cen[:, None, :], axis=2).mean(axis=1)
    return cen, outl, radii
