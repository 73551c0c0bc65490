"""The thesis's steps (grey image, IsoData threshold, outline, circular Hough transform), the
median grey, and the detectors built on the thresholded photo (``blobs``) or on OpenCV's Hough
transform (``cv2``)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage
from skimage.filters import threshold_isodata
from skimage.transform import hough_circle, hough_circle_peaks


# -- the thesis's steps ------------------------------------------------------------------------
def _as_image(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3) or min(img.shape[:2], default=0) < 1:
        raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
    return img


def grey_image(image) -> np.ndarray:
    """Grey version of a BGR (or grey) image as float32 in image units.

    ImageJ's default RGB -> 8-bit conversion, which the thesis used: the unweighted mean
    ``(R + G + B) / 3`` (it keeps blue beads brighter than a luminance conversion would).

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    img = _as_image(image)
    if img.ndim == 2:
        return img.astype(np.float32)
    if img.dtype != np.uint8:
        return img.astype(np.float32).mean(axis=2)
    # the integer sum B + G + R, then / 3 in float32: the same values as ``mean(axis=2)`` in
    # float32 (sums of uint8 are exact), without the float32 copy of all three channels
    f = _channel_sum(img).astype(np.float32)
    f /= np.float32(3.0)
    return f


def _channel_sum(img: np.ndarray) -> np.ndarray:
    """B + G + R of a uint8 image (the sum over its last axis, the channels) as uint16, channel
    by channel: ~10x faster than ``sum(axis=2)`` on a cropped view or on a stack of windows."""
    s = img[..., 0].astype(np.uint16)
    for ch in range(1, img.shape[-1]):
        s += img[..., ch]
    return s


def isodata_threshold(grey) -> float:
    """The thesis's automatic threshold (IsoData), via :func:`skimage.filters.threshold_isodata`.

    Foreground is ``grey > threshold``. A flat image gives ``inf`` (no foreground).
    IsoData can have several fixed points; scikit-image returns the lowest, as ImageJ's
    iteration from the darkest grey does. ImageJ's "Default" also ignores the bins 0 and 255
    and clips the histogram's mode; on the drawn photos of ``docs/puppet-detection.md`` that
    gives even lower thresholds (5-16 grey levels where scikit-image gives 16-78), so the
    plain scikit-image variant is used.
    """
    g = np.asarray(grey)
    if g.ndim != 2:
        raise ValueError(f"grey must have shape (H, W), got {g.shape}")
    if not g.size or g.max() <= g.min():
        return np.inf
    return float(threshold_isodata(g))


def outline(mask) -> np.ndarray:
    """The thesis's edge map: a foreground pixel stays only if not all its 8 neighbours are foreground.

    That is ``mask & ~erosion(mask, 3x3)`` (:func:`scipy.ndimage.binary_erosion`); pixels outside
    the image count as background, so foreground at the border stays.

    Parameters
    ----------
    mask : array_like of bool, shape (H, W)

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    m = np.asarray(mask, bool)
    if m.ndim != 2:
        raise ValueError(f"mask must have shape (H, W), got {m.shape}")
    return m & ~ndimage.binary_erosion(m, np.ones((3, 3), bool), border_value=0)


def _radii(radius_range, step: float = 1.0) -> np.ndarray:
    r0, r1 = (float(v) for v in radius_range)
    if not (0 < r0 <= r1):
        raise ValueError(f"radius_range must be (r_min, r_max) with 0 < r_min <= r_max, got {radius_range}")
    return np.arange(r0, r1 + 1e-9, step)


def _hough(edges: np.ndarray, radii: np.ndarray, n: int, min_distance: int):
    """The ``n`` best circles of an edge map: scores, x, y, r (integer centres)."""
    if not edges.any() or n < 1:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
    # normalize=True divides the votes by the number of outline pixels of each radius: the
    # score is the fraction of a circle found, so radii compete fairly.
    H = hough_circle(edges, radii, normalize=True)
    acc, cx, cy, rr = hough_circle_peaks(H, radii, min_xdistance=min_distance, min_ydistance=min_distance,
                                         threshold=0.0, total_num_peaks=n, normalize=False)
    keep = acc > 0
    return acc[keep], cx[keep].astype(float), cy[keep].astype(float), rr[keep].astype(float)


def _median_grey(image, channel_sum=None) -> float | None:
    """``float(np.median(grey_image(image)))`` of a uint8 BGR photo from a histogram of the
    integer channel sums (the grey image is their monotonic image ``sum / 3``), several times
    faster than partitioning the float grey image; None for other images. ``channel_sum``:
    the image's :func:`_channel_sum` when the caller has it already."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.size == 0:
        return None
    s = _channel_sum(img) if channel_sum is None else channel_sum
    n = s.size
    if n < 2 ** 24 and s.ndim == 2:
        # cv2.calcHist: np.bincount's counts (unit bins of the integer sums; exact in its
        # float32 below 2^24 pixels), 2x faster, and it releases the GIL
        hist = cv2.calcHist([np.ascontiguousarray(s)], [0], None, [766], [0, 766]).ravel().astype(np.int64)
    else:
        hist = np.bincount(s.ravel(), minlength=766)
    cum = np.cumsum(hist)
    lo, hi = (np.searchsorted(cum, [(n - 1) // 2, n // 2], side="right")).astype(np.float32) / np.float32(3.0)
    # np.median's own arithmetic on the two middle float32 values (the same one when n is odd)
    return float(np.mean(np.array([lo, hi], np.float32))) if n % 2 == 0 else float(lo)


def _cv2_hough(grey, r_min, r_max, n, md):
    g8 = cv2.GaussianBlur(np.clip(grey, 0, 255).astype(np.uint8), (0, 0), 1.0)
    # The classic gradient method: HOUGH_GRADIENT_ALT misses circles this small (measured:
    # ~12 % found). param1 = Canny high threshold, param2 = accumulator threshold.
    found = cv2.HoughCircles(g8, cv2.HOUGH_GRADIENT, dp=1.0, minDist=float(md), param1=100, param2=8,
                             minRadius=max(1, int(np.floor(r_min)) - 1), maxRadius=int(np.ceil(r_max)) + 1)
    if found is None:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
    f = found.reshape(-1, found.shape[-1])[:n]
    # OpenCV returns circles sorted by accumulator votes but not the votes: a decreasing score.
    score = np.linspace(1.0, 0.5, len(f)) if len(f) > 1 else np.ones(len(f))
    return score, f[:, 0].astype(float), f[:, 1].astype(float), f[:, 2].astype(float)


def _blobs(img, grey, t, radii, r_min, r_max, n, md, min_circularity):
    mask = (grey > t).astype(np.uint8)
    n_lab, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    a_min = 0.35 * np.pi * r_min**2  # the shaded rim can fall below the threshold
    a_max = 1.6 * np.pi * r_max**2
    acc, cx, cy, rr = [], [], [], []
    for lab in range(1, n_lab):
        area = stats[lab, cv2.CC_STAT_AREA]
        if area < a_min:
            continue
        x, y, w, h = stats[lab, :4]
        sub = (labels[y:y + h, x:x + w] == lab).astype(np.uint8)
        contours, _ = cv2.findContours(np.pad(sub, 1), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        per = max(cv2.arcLength(contours[0], True), 1e-9)
        # Area of the contour polygon + half the boundary pixels: ~ the pixel count.
        circ = 4 * np.pi * (cv2.contourArea(contours[0]) + per / 2) / (per + np.pi) ** 2
        if area <= a_max and circ >= min_circularity and max(w, h) <= 2 * r_max + 3:
            req = np.sqrt(area / np.pi)
            acc.append(min(circ, 1.0))
            cx.append(cents[lab, 0])
            cy.append(cents[lab, 1])
            rr.append(float(np.clip(req, r_min, r_max)))
        elif max(w, h) >= 2 * r_min - 2:
            # Touching or overlapping beads, a bead on a bright limb edge: Hough inside the region.
            pad = int(np.ceil(r_max)) + 2
            x0, y0 = max(0, x - pad), max(0, y - pad)
            x1, y1 = min(grey.shape[1], x + w + pad), min(grey.shape[0], y + h + pad)
            region = labels[y0:y1, x0:x1] == lab
            k = max(1, int(np.ceil(area / (np.pi * r_min**2))))
            a, hx, hy, hr = _hough(outline(region), radii, k, md)
            good = a >= 0.45
            for ai, xi, yi, ri in zip(a[good], hx[good], hy[good], hr[good]):
                if region[int(yi), int(xi)]:
                    acc.append(float(ai))
                    cx.append(xi + x0)
                    cy.append(yi + y0)
                    rr.append(float(ri))
    acc, cx, cy, rr = (np.asarray(v, float) for v in (acc, cx, cy, rr))
    order = np.argsort(-acc, kind="stable")[:n]
    return acc[order], cx[order], cy[order], rr[order]
