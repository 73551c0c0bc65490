"""Ball images the silhouette step alone misses: thin crescents and balls cut by the frame edge.

- **Crescents** (:func:`faint_mask`, :func:`thin_arcs`). A ball lit from behind (phase angle
  above ~140 deg) shows only a thin, dim rim, one or two pixels wide, that the foreground
  threshold breaks into specks and the opening removes. On a smoothed half-resolution image
  (:func:`faint_mask`) the rim stands out whole; its components that no kept silhouette covers
  are grouped into arcs (pieces whose circles agree are one crescent), and a circle is fitted to each arc's
  **outer** edge: per angle around a first (Kasa) centre, the outermost pixel, half a pixel out
  (the limb against the background). The inner (terminator) edge is left out: it is the shadow
  line, not the ball's outline. The result is the ball's disc centre and radius, a start for the
  known-radius refinement (whose gradient voting also ignores the terminator).
- **Frame edge** (:func:`edge_circle`). A ball cut by the photo's border: its silhouette's
  ellipse is the cut shape's, biased inwards. The circle is fitted to the contour points away
  from the border only (the in-frame limb), robustly (a marker's notch pulls little).

Self-checks: an arc is kept only when its points span at least ``min_span_deg`` around the
fitted centre and lie on the circle within ``max(rms_px, rms_rel r)``. Every kept fit gets a
centre uncertainty (:func:`arc_center_sigma`) from its arc's geometry, its residual and the blur:
the shorter the arc, the larger it is.

Hand-written rather than ``cv2.minEnclosingCircle`` / ``cv2.fitEllipse``: those use every point,
including the terminator and the frame edge, which is the bias to remove.
"""
from __future__ import annotations

import cv2
import numpy as np

from stillcap.detect.circle_fit import arc_span_deg, center_covariance, fit_circle, kasa_circle

__all__ = ["arc_center_sigma", "crescent_circle", "edge_circle", "faint_mask", "thin_arcs"]


#: Gaussian smoothing (px) of the known-radius refinement (``refine_ball_centers``' ``sigma``)
REFINE_SMOOTH_PX = 0.7


def arc_center_sigma(points, center, rms_px: float, blur_px: float = 0.5, radius_known: bool = True,
                     thin: bool = False) -> float:
    """1-sigma centre uncertainty (px, largest axis) of a circle fitted to these arc points.

    Two parts. Random: each point's radial scatter (the fit's RMS, at least 0.1 px), points 2 px
    apart counted as independent, through :func:`center_covariance` (with the radius free or
    known). Systematic, only with a known radius (the refinement of a crescent uses the radius
    projected from 3D): where the limb of a dim, blurred arc lies is uncertain by about the blur
    ``blur_px`` all along the arc, and a common radial offset ``d`` moves a known-radius centre by
    ``d (sum u u^T)^-1 sum u`` (u the points' radial directions): nothing for a whole circle,
    ~1.6 d along the axis of a half circle, more for a shorter arc.

    ``thin``: a faint rim one or two pixels wide (:func:`thin_arcs`). Blurred, it is a line
    whose inward gradient peaks about one total blur sigma (the lens's ``blur_px`` and the
    refinement's smoothing ``REFINE_SMOOTH_PX`` in quadrature) outside the rim's middle, not
    at the limb: ``d`` is that total blur. Measured (``bench_ball_detect.py --only-missed``,
    faint crescents, phase 150-165 deg, 0.6 px blur): the refined centres sat 1.3 px toward
    the light on average (sd 0.8 px); with ``d = blur_px`` the sigma was 0.6 px.
    """
    p = np.asarray(points, float)
    if len(p) < 3:
        return float("inf")
    step = max(1, int(round(2.0 / max(np.median(np.linalg.norm(np.diff(p, axis=0), axis=1)), 0.25)))) if len(p) > 3 else 1
    cov = center_covariance(p[::step], center, max(float(rms_px), 0.1), radius_known=radius_known)
    if not np.all(np.isfinite(cov)):
        return float("inf")
    if radius_known:
        u = p - np.asarray(center, float)
        u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        try:
            g = np.linalg.solve(u.T @ u, u.sum(axis=0))
        except np.linalg.LinAlgError:
            return float("inf")
        d = float(np.hypot(blur_px, REFINE_SMOOTH_PX)) if thin else float(blur_px)
        cov = cov + d ** 2 * np.outer(g, g)
    return float(np.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))


def _outer_points(pts: np.ndarray, center: np.ndarray, n_bins: int, half_px: float = 0.5) -> np.ndarray:
    """Per angular bin around ``center``, the pixel farthest out, moved half a pixel (``half_px``)
    outward."""
    d = pts - center
    rad = np.hypot(d[:, 0], d[:, 1])
    ang = np.arctan2(d[:, 1], d[:, 0])
    b = ((ang + np.pi) / (2 * np.pi) * n_bins).astype(int) % n_bins
    order = np.lexsort((-rad, b))  # by bin, farthest first
    first = order[np.r_[True, b[order][1:] != b[order][:-1]]]
    u = d[first] / np.maximum(rad[first], 1e-9)[:, None]
    return pts[first] + half_px * u


def _good_circle(pts, min_span_deg, rms_px, rms_rel, radius=None, start=None):
    if len(pts) < 6:
        return None
    c, r, rms = fit_circle(pts, radius=radius, start=start)
    if not (np.isfinite(c).all() and r >= 3.0 and rms <= max(rms_px, rms_rel * r)):
        return None
    span = arc_span_deg(pts, c)
    if span < min_span_deg:
        return None
    return c, r, rms, span


def _limb_circle(pts: np.ndarray, half_px: float, image_size, min_span_deg: float, rms_px: float,
                 rms_rel: float, iterations: int = 3):
    """Circle through the outer limb of an arc's points: around a first centre (the Kasa circle
    of all points), the outermost point per angle, a circle fitted to them; repeated around the
    new centre (the terminator, inside the disc, is never outermost once the centre is right).
    Limb points within 2 px of the photo's border are left out. None when the self-check fails."""
    c, r = kasa_circle(pts)
    got = outer = None
    for it in range(iterations):
        if not (np.isfinite(c).all() and r >= 1.5):
            return None
        outer = _outer_points(pts, c, max(24, int(np.ceil(2 * np.pi * r / 2.0))), half_px)
        if image_size is not None:
            W, H = image_size
            outer = outer[(outer[:, 0] > 1.0) & (outer[:, 1] > 1.0) & (outer[:, 0] < W - 2.0) & (outer[:, 1] < H - 2.0)]
        got = _good_circle(outer, 0.0, np.inf, np.inf, start=c if it else None)
        if got is None:
            return None
        c, r = got[0], got[1]
    c, r, rms, span = got
    if span < min_span_deg or rms > max(rms_px, rms_rel * r):
        return None
    return c, r, rms, span, outer


def faint_mask(img: np.ndarray, background=None, k_sigma: float = 4.0, scale: int = 2, smooth_px: float = 1.0):
    """Where a faint thin rim may be: the photo's channel mean (or its difference from the
    background) averaged to 1/``scale`` resolution (``cv2.INTER_AREA``) and smoothed (Gaussian
    ``smooth_px``, in those pixels), above its median by ``k_sigma`` robust (MAD) sigmas.

    Averaging cuts the noise about ``2 scale`` times while a rim one or two pixels wide keeps
    about half its contrast: a crescent a few noise sigmas above the room, which the full-
    resolution 6-sigma threshold breaks into specks, stands out whole. Returns the 0/255 mask at
    1/``scale`` resolution.
    """
    a = np.asarray(img)
    if background is not None:
        bg = np.asarray(background)
        a = cv2.absdiff(a, bg) if a.dtype == np.uint8 and bg.dtype == np.uint8 else \
            np.abs(a.astype(np.float32) - bg.astype(np.float32))
    H, W = a.shape[:2]
    # averaged to 1/scale first (cv2.INTER_AREA on the 8-bit photo: ~20x cheaper than converting
    # the full photo to float), then the channel mean
    small = cv2.resize(a, (max(W // scale, 1), max(H // scale, 1)), interpolation=cv2.INTER_AREA)
    small = small.astype(np.float32)
    if small.ndim == 3:
        small = small.mean(axis=2)
    if smooth_px > 0:
        small = cv2.GaussianBlur(small, (0, 0), smooth_px)
    step = max(1, int(np.sqrt(small.size / 2.5e5)))
    sub = small[::step, ::step].ravel()
    med = float(np.median(sub))
    sig = max(1.4826 * float(np.median(np.abs(sub - med))), 0.2)
    return ((small > med + k_sigma * sig).astype(np.uint8)) * 255


def thin_arcs(mask_small, scale: int, kept_contours, min_pixels: int = 6, min_span_deg: float = 60.0,
              max_cover: float = 0.5, rms_px: float = 1.5, rms_rel: float = 0.08, image_size=None,
              min_radius: float = 3.0):
    """Thin crescents of a faint-rim mask (:func:`faint_mask`) that no kept silhouette covers
    (module docstring).

    Parameters
    ----------
    mask_small : ndarray (h, w) uint8
        The mask at 1/``scale`` resolution.
    kept_contours : list of contours
        The silhouettes already found (full-photo coordinates).
    min_pixels : int
        Smallest piece of a crescent (pixels of the mask).
    image_size : (W, H), optional
        Limb points on the photo's border are left out (a crescent cut by the edge).
    min_radius : float
        Smallest radius of a ball (px).

    Returns
    -------
    list of dict
        ``center`` (2,), ``radius``, ``rms``, ``span_deg``, ``points`` (the outer limb points),
        ``pixels`` (all pixels of the crescent), per crescent, in full-photo pixels.
    """
    pieces = []
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask_small, connectivity=8)
    cover = np.zeros_like(mask_small)
    if kept_contours:
        cv2.drawContours(cover, [np.round((c.astype(np.float64) + 0.5) / scale - 0.5).astype(np.int32)
                                 for c in kept_contours], -1, 255, -1)
        cover = cv2.dilate(cover, np.ones((3, 3), np.uint8))
    for j in range(1, n):
        if stats[j, cv2.CC_STAT_AREA] < min_pixels:
            continue
        x, y, w, h = stats[j, :4]
        sel = lab[y:y + h, x:x + w] == j
        if (cover[y:y + h, x:x + w][sel] > 0).mean() > max_cover:
            continue
        ys, xs = np.nonzero(sel)
        # back to full-photo pixels (the centre of each block of scale x scale pixels)
        pieces.append(np.column_stack([(xs + x + 0.5) * scale - 0.5, (ys + y + 0.5) * scale - 0.5]))
    # each piece's rough circle; pieces of one crescent (split where the rim dims) share theirs
    circ = []
    for p in pieces:
        c, r = kasa_circle(p)
        if np.all(np.isfinite(c)) and 3.0 <= r:
            circ.append([c, r, p])
    groups = []
    for c, r, p in sorted(circ, key=lambda q: -len(q[2])):
        for g in groups:
            if np.hypot(*(c - g[0])) < 0.3 * max(r, g[1]) and abs(r - g[1]) < 0.3 * max(r, g[1]):
                g[2] = np.concatenate([g[2], p])
                g[0], g[1] = kasa_circle(g[2])
                break
        else:
            groups.append([c, r, p])
    out = []
    for c, r, p in groups:
        # the limb: the outer edge of the rim (the pixel cloud's own circle lies inside it)
        got = _limb_circle(p, 0.0, image_size, min_span_deg, rms_px, rms_rel)
        if got is None:
            continue
        cc, rr, rms, span, outer = got
        # a crescent lies along its circle: not a blob with a round side (a filled disc has 12 %
        # of its pixels within 0.35 r of its centre; a small crescent's rim, thickened by the
        # half resolution and the smoothing, up to ~9 %)
        # and it covers a small part of its disc (a filled blob covers all of it; a crescent,
        # thickened as above, up to ~70 %)
        fill = len(p) * scale * scale / (np.pi * rr * rr)
        if rr < min_radius or fill > 0.8 or np.mean(np.hypot(*(p - cc).T) < 0.35 * rr) > 0.1:
            continue
        out.append({"center": cc, "radius": rr, "rms": rms, "span_deg": span, "points": outer, "pixels": p})
    return out


def crescent_circle(contour, area: float, max_fill: float = 0.4, min_span_deg: float = 60.0,
                    rms_px: float = 1.0, rms_rel: float = 0.06, image_size=None):
    """Circle through the outer limb of a crescent silhouette (one the opening kept).

    The silhouette's ellipse (and its centroid) sit on the crescent, up to ~0.9 radius from the
    ball's centre, further than the known-radius refinement searches. Around a first centre (the
    Kasa circle of the whole contour, then the fit's own centre, twice) the outermost contour
    point per angle is the limb; the terminator, inside the disc, is never outermost once the
    centre is right. Kept only for a silhouette filling at most ``max_fill`` of its circle (a
    crescent: a ball lit from more than ~110 deg; half moons and fuller balls keep their ellipse
    and the refinement) and passing the arc self-check.

    Returns
    -------
    dict or None
        ``center``, ``radius``, ``rms``, ``span_deg``, ``points`` (the limb points).
    """
    pts = np.asarray(contour, float).reshape(-1, 2)
    if len(pts) < 12:
        return None
    got = _limb_circle(pts, 0.5, image_size, min_span_deg, rms_px, rms_rel)
    if got is None:
        return None
    c, r, rms, span, outer = got
    if area > max_fill * np.pi * r * r:
        return None
    return {"center": c, "radius": r, "rms": rms, "span_deg": span, "points": outer}


def edge_circle(contour, image_size, min_span_deg: float = 150.0, rms_px: float = 0.75,
                rms_rel: float = 0.05, border_px: float = 1.0):
    """Circle of a silhouette cut by the photo's border, fitted to its in-frame limb only.

    Parameters
    ----------
    contour : ndarray, shape (M, 1, 2) or (M, 2)
        The silhouette's contour (pixel centres of its boundary pixels).
    image_size : (W, H)
    min_span_deg, rms_px, rms_rel : float
        Self-check (module docstring): with less than ``min_span_deg`` of limb in the frame the
        centre is not fixed well enough (None is returned).

    Returns
    -------
    dict or None
        ``center``, ``radius`` (half a pixel added: contour points are the boundary pixels'
        centres), ``rms``, ``span_deg``, ``points``.
    """
    W, H = image_size
    pts = np.asarray(contour, float).reshape(-1, 2)
    b = border_px
    inner = pts[(pts[:, 0] > b) & (pts[:, 1] > b) & (pts[:, 0] < W - 1 - b) & (pts[:, 1] < H - 1 - b)]
    got = _good_circle(inner, min_span_deg, rms_px, rms_rel)
    if got is None:
        return None
    c, r, rms, span = got
    return {"center": c, "radius": r + 0.5, "rms": rms, "span_deg": span, "points": inner}
