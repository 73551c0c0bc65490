"""Centres of partly hidden beads from the visible arc of their rim (issue 12, part 4).

A bead that a limb covers in part shows a disc with a bite out of it; its blob's centroid lies
off the bead's centre, towards the visible part (1-2 mm in 3D). The rim that still borders the
background is the bead's own circle, whose radius is known: the radius of whole views of the
beads (the same threshold contour, scaled by depth). :func:`arc_centers` fits that circle to the
visible rim alone.

Per observation, in a window about its detected centre: the background level is the median grey
of the ring ``r + 1.5 .. r + 3.5`` px (as :func:`~stillcap.detect.beads.bead_fill`), the bead
level the 90th percentile within ``r``; the bead's mask is the grey above halfway between them
(the blob nearest the centre). A mask pixel bordering a pixel outside the mask is a rim
point when that outside pixel is at the background level (within a quarter of the contrast):
the bead meets the background there, not an occluder. Each rim point is placed at the
sub-pixel crossing of the halfway level between the two pixels. The circle of the given contour
radius is fitted to them by robust least squares (:func:`stillcap.detect.circle_fit.fit_circle`: ``scipy.optimize.least_squares``,
soft-L1).

Self-check: the fit is kept only when the rim points span at least ``min_span_deg`` around the
fitted centre and their RMS distance from the circle is at most ``max_rms_px``; otherwise the
centre is NaN (the caller leaves that view out). An occluder as dark as the background would
pass as rim, but then the points do not lie on one circle of that radius and the residual
rejects the fit.

Hand-written rather than OpenCV's ``fitEllipse``/``minEnclosingCircle``: those fit every contour
point, including the occluder's edge, which is the bias to remove.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from stillcap.detect.circle_fit import arc_span_deg, fit_circle

__all__ = ["arc_centers", "contour_radii"]


def _grey(image) -> np.ndarray:
    img = np.asarray(image)
    return img.astype(float) if img.ndim == 2 else img.astype(float).mean(axis=2)


def _rim(grey: np.ndarray, center, r: float):
    """Rim points (sub-pixel, image coordinates), all contour points, and the patch's levels;
    None when the bead does not stand out or its window leaves the photo."""
    h, w = grey.shape
    half = int(math.ceil(r + 5))
    cx, cy = int(round(center[0])), int(round(center[1]))
    if cx - half < 0 or cy - half < 0 or cx + half >= w or cy + half >= h:
        return None
    p = grey[cy - half:cy + half + 1, cx - half:cx + half + 1]
    off = np.arange(-half, half + 1)
    dx = (off[None, :] + cx) - center[0]
    dy = (off[:, None] + cy) - center[1]
    d = np.hypot(dx, dy)
    ring = p[(d >= r + 1.5) & (d <= r + 3.5)]
    inner = p[d <= r]
    if len(ring) < 8 or len(inner) < 4:
        return None
    bg, fg = float(np.median(ring)), float(np.percentile(inner, 90))
    contrast = fg - bg
    if abs(contrast) < 8.0:
        return None
    level = (p - bg) / contrast  # 0 background, 1 bead
    mask = (level > 0.5) & (d <= r + 1.5)
    lab, n = ndimage.label(mask)
    if n == 0:
        return None
    if n > 1:  # the blob nearest the detected centre
        dist = ndimage.minimum(d, lab, index=np.arange(1, n + 1))
        mask = lab == (1 + int(np.argmin(dist)))
    rim, edge = [], []
    for sy, sx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb = np.roll(mask, (-sy, -sx), axis=(0, 1))
        nb_level = np.roll(level, (-sy, -sx), axis=(0, 1))
        border = mask & ~nb
        border[[0, -1], :] = False
        border[:, [0, -1]] = False
        ys, xs = np.nonzero(border)
        li, lo = level[ys, xs], nb_level[ys, xs]
        t = np.clip((li - 0.5) / np.maximum(li - lo, 1e-6), 0.0, 1.0)
        px = xs + t * sx - half + cx
        py = ys + t * sy - half + cy
        pts = np.stack([px, py], axis=1)
        edge.append(pts)
        rim.append(pts[np.abs(lo) <= 0.25])
    return np.concatenate(rim), np.concatenate(edge)


def contour_radii(images, centers, radii_px) -> np.ndarray:
    """Radius of the halfway-level contour of each (whole) bead, pixels, shape (n_views, N); NaN
    where it cannot be measured. Divided by the expected radius, it says how much smaller than
    the bead's silhouette its threshold contour is (shading, blur)."""
    c_all = np.asarray(centers, float)
    r_all = np.broadcast_to(np.asarray(radii_px, float), c_all.shape[:2])
    out = np.full(c_all.shape[:2], np.nan)
    for v, img in enumerate(images):
        live = np.flatnonzero(np.all(np.isfinite(c_all[v]), axis=1) & np.isfinite(r_all[v]))
        if not len(live):
            continue
        grey = _grey(img)
        for m in live:
            got = _rim(grey, c_all[v, m], r_all[v, m])
            if got is None or len(got[1]) < 8:
                continue
            _, r_fit, rms = fit_circle(got[1], None, c_all[v, m])
            if rms <= 0.5:
                out[v, m] = r_fit
    return out


def arc_centers(images, centers, contour_radii_px, min_span_deg: float = 120.0, max_rms_px: float = 0.35
                ) -> np.ndarray:
    """Centres of partly hidden beads fitted to the visible arc of their rim (module docstring).

    Parameters
    ----------
    images : sequence of n_views photos
    centers : array_like, shape (n_views, N, 2)
        Detected centres (x, y), pixels; NaN rows are skipped.
    contour_radii_px : array_like, shape (n_views, N)
        The radius a whole bead's halfway contour would have there (:func:`contour_radii` of
        whole views, scaled by depth).
    min_span_deg, max_rms_px : float
        The self-check (module docstring).

    Returns
    -------
    ndarray, shape (n_views, N, 2)
        Corrected centres; NaN where the arc does not fix one.
    """
    c_all = np.asarray(centers, float)
    r_all = np.broadcast_to(np.asarray(contour_radii_px, float), c_all.shape[:2])
    out = np.full(c_all.shape, np.nan)
    for v, img in enumerate(images):
        live = np.flatnonzero(np.all(np.isfinite(c_all[v]), axis=1) & np.isfinite(r_all[v]) & (r_all[v] > 1.0))
        if not len(live):
            continue
        grey = _grey(img)
        for m in live:
            r = float(r_all[v, m])
            got = _rim(grey, c_all[v, m], r + 1.0)
            if got is None or len(got[0]) < 6:
                continue
            rim = got[0]
            c, _, rms = fit_circle(rim, r, c_all[v, m])
            span = arc_span_deg(rim, c)
            if span >= min_span_deg and rms <= max_rms_px:
                out[v, m] = c
    return out
