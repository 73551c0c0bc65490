"""Telling coloured paint from black paint by a region's summed chroma (issue 12, JPEG).

JPEG keeps the chroma at half resolution (4:2:0) and quantises it more coarsely than the luma,
so a small coloured marker (a few px across) loses most of its per-pixel saturation: under the
colour thresholds of :func:`stillcap.detect.ball_markers.detect_ball_markers`, while its luma
darkness stays, and the dark (black paint) detector took it. Measured on the robustness
benchmark's JPEG 70 capture #11 (``mlb-high-spin``, 15 px balls): of the front cameras' 12
green and blue markers, 10 came out black, and the spin fit's markers lay 18 deg RMS from the
layout. The chroma is spread and damped but its sum over the region and its surroundings
keeps much of it, and black paint adds none: a mix of a share ``f`` of paint over leather of
local white ``W`` has luma darkness ``f d`` and chroma ``W f k`` (``d``, ``k``: the paint's
darkness and chroma relative to white), so the darkness a palette colour's chroma explains,
``(K . u) / |u|^2`` with ``u = k / d``, is compared with the region's darkness ``D``.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["MARGIN_DEG", "MAX_ANGLE_DEG", "NOISE_Z", "SHARE_COLOR", "SHARE_MIXED", "chroma_per_darkness", "recolor_dark"]

#: share of a dark region's darkness a palette colour's chroma must explain for the region to
#: be that colour's paint (half: more colour than black in it)
SHARE_COLOR = 0.5
#: ... from which on (below SHARE_COLOR) the region is mixed evidence and left out
SHARE_MIXED = 0.3
#: the explained darkness must exceed this many sigmas of the leather's chroma noise
NOISE_Z = 3.0
#: the region's chroma direction within this angle of the colour's (a palette's colours lie
#: ~120 deg apart: halfway) ...
MAX_ANGLE_DEG = 60.0
#: ... and this much nearer to it than to the next colour
MARGIN_DEG = 20.0
_BOX5 = np.ones((5, 5), np.uint8)  # grows a region by 2 px: the reach of 4:2:0 chroma
# BGR -> luma weights of cv2.cvtColor(..., COLOR_BGR2GRAY)
_LUMA = np.array([0.114, 0.587, 0.299])


def _hue_distance(hue: np.ndarray, h) -> np.ndarray:
    """``|(hue - h + 180) % 360 - 180|``: hue difference in degrees (0-180), float32.

    Both in [0, 360] (OpenCV's float hue; ``h`` a float32 array broadcasting against ``hue``),
    so ``a = hue - h + 180`` is in [-180, 540] and ``a % 360`` is ``a + 360`` below 0 and
    ``a - 360`` (exact there) from 360 on: the same numbers as NumPy's float remainder, which
    (fmod and a sign fix-up) costs ten times more.
    """
    a = hue - h + 180.0
    a = np.where(a >= 360.0, a - 360.0, np.where(a < 0.0, a + 360.0, a))
    return np.abs(a - 180.0)


def leather_chroma(samples: list) -> tuple:
    """The leather's own chroma (median, (3,): a cast the white balance left) and its noise per
    pixel and channel (a robust sigma, at least a code value: JPEG can leave smooth leather with
    none) from its lit pixels' chroma (a list of (n, 3) arrays); NaN noise without samples."""
    if not samples:
        return np.zeros(3), float("nan")
    allk = np.concatenate(samples)
    med = np.median(allk, 0)
    return med, max(float(np.mean(1.4826 * np.median(np.abs(allk - med), 0))), 1.0 / 255.0)


def chroma_per_darkness(color_bgr) -> np.ndarray:
    """A paint's chroma per unit of luma darkness, ``(c - Y) / (1 - Y)`` (BGR, relative to white)."""
    c = np.asarray(color_bgr, float) / 255.0
    y = float(_LUMA @ c)
    return (c - y) / max(1.0 - y, 1e-3)


def recolor_dark(rw, lab, j: int, st, dark_luma, chroma, disc, pal_u, k_noise: float, classes,
                 leather=(0.0, 0.0, 0.0), mismatch_flag: int = 4):
    """A dark region's row (of ``_measure``) kept as black, given the colour whose chroma
    explains most of its darkness, or None (mixed evidence: left out).

    Parameters
    ----------
    rw : tuple
        ``(center, type name, shape, area, confidence, aspect, ball, flags)``.
    lab, j, st : the labels, the region's label and its ``cv2`` stats row.
    dark_luma : ndarray (h, w)
        Luma darkness relative to the local white.
    chroma : ndarray (h, w, 3)
        BGR chroma ``(pixel - luma)`` relative to the local white.
    disc : ndarray of bool (h, w)
    pal_u : ndarray (P, 3)
        The chromatic palette colours' :func:`chroma_per_darkness`.
    k_noise : float
        The leather's chroma noise per pixel and channel (robust sigma).
    classes : list of (types, hue, saturation)
        The chromatic colour classes, in the order of ``pal_u``.
    leather : array_like, shape (3,)
        The leather's own chroma (its median), taken off every pixel first.
    mismatch_flag : int
        The ``MarkerFlag.SHAPE_MISMATCH`` bit (passed in: this module is below ball_markers).
    """
    if not np.isfinite(k_noise) or len(pal_u) == 0:
        return rw
    bx, by, bw, bh = (int(v) for v in st[:4])
    y0, x0 = max(by - 3, 0), max(bx - 3, 0)
    y1, x1 = min(by + bh + 3, lab.shape[0]), min(bx + bw + 3, lab.shape[1])
    comp = (lab[y0:y1, x0:x1] == j).astype(np.uint8)
    grown = cv2.dilate(comp, _BOX5).astype(bool) & disc[y0:y1, x0:x1]
    D = float(dark_luma[y0:y1, x0:x1][grown].sum())
    if D <= 0:
        return rw
    K = chroma[y0:y1, x0:x1][grown].sum(0) - grown.sum() * np.asarray(leather, float)
    uu = (pal_u * pal_u).sum(1)
    a = (pal_u @ K) / np.maximum(uu, 1e-12)  # darkness each colour's chroma explains
    # the colour whose chroma direction is nearest the region's, decisively: within MAX_ANGLE
    # and MARGIN nearer than the next colour (JPEG's coarse chroma turns the direction by up to
    # ~45 deg; the chroma of a colour not in the palette, e.g. yellow between red and green, is
    # no evidence for either)
    ang = np.degrees(np.arccos(np.clip((pal_u @ K) / np.maximum(np.sqrt(uu) * np.linalg.norm(K), 1e-12), -1, 1)))
    order = np.argsort(ang)
    p = int(order[0])
    if ang[p] > MAX_ANGLE_DEG or (len(ang) > 1 and ang[order[1]] - ang[p] < MARGIN_DEG):
        return rw
    sig = np.sqrt(grown.sum()) * k_noise / np.sqrt(max(uu[p], 1e-12))
    share = a[p] / D
    if a[p] <= NOISE_Z * sig or share < SHARE_MIXED:
        return rw
    if share < SHARE_COLOR:
        return None
    cen, _, shape, area, conf, aspect, bi, flags = rw
    types = classes[p][0]
    match = [t for t in types if t.shape == shape]
    t = match[0] if match else types[0]
    flags = flags & ~mismatch_flag
    if not match and shape != "unknown":
        flags |= mismatch_flag
    return cen, t.name, shape, area, conf * min(float(share), 1.0), aspect, bi, flags
