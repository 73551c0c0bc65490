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

The same test names the regions of the luma path (:func:`luma_thresholds`): under JPEG 70 a
2-4 px blue or green marker's saturation falls under the leather's chroma noise (which the
blocks raise: the noise ceiling 0.10 -> 0.21 on the studio's 13 px balls) and its value-darkness
under the black detector's core, so neither detector found it (813fc83 on the robustness
benchmark's clean scenes: 60 of 142 blue and 21 of 114 green markers PNG finds); its luma
darkness (0.25-0.36) stays.
"""

from __future__ import annotations

import cv2
import numpy as np

from stillcap._numeric import median_columns
from stillcap.detect._marker_noise import _noise_by_brightness, _robust_ceiling

__all__ = ["MARGIN_DEG", "MAX_ANGLE_DEG", "MAX_SHARE", "MIN_WHITE", "NOISE_Z", "SHARE_COLOR", "SHARE_MIXED",
           "chroma_per_darkness", "luma_thresholds", "recolor_dark"]

#: share of a dark region's darkness a palette colour's chroma must explain for the region to
#: be that colour's paint (half: more colour than black in it)
SHARE_COLOR = 0.5
#: ... from which on (below SHARE_COLOR) the region is mixed evidence and left out
SHARE_MIXED = 0.3
#: the explained darkness must exceed this many sigmas of the leather's chroma noise
NOISE_Z = 3.0
#: a share above this is more chroma than paint gives (1 is paint alone): not paint (measured:
#: 0.47-1.35 on JPEG 70's markers; 3-8 on a side-lit ball's shadow edge, whose residual cast
#: the white balance, divided out of encoded values, leaves)
MAX_SHARE = 2.0
#: regions whose local white is below this share of the lit leather's (median) are in the
#: shadow, where the paint's chroma is buried (detect_ball_markers' ``lit_fraction``)
MIN_WHITE = 0.2
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
    """The leather's own chroma relative to its white (median, (3,): a cast the white balance
    left) and the noise of its chroma per pixel and channel on the 0-1 code scale (a robust
    sigma of what that cast leaves, at least a code value: JPEG can leave smooth leather with
    none) and its median white, from its lit pixels' ``(chroma, white)`` (a list of ((n, 3),
    (n,)) pairs); NaN noise and white without samples."""
    if not samples:
        return np.zeros(3), float("nan"), float("nan")
    ck = np.concatenate([c for c, _ in samples])
    w = np.concatenate([w for _, w in samples])
    med = median_columns(ck / np.maximum(w, 1e-6)[:, None])  # (np.median's numbers, axis 0)
    res = ck - w[:, None] * med
    return (med, max(float(np.mean(1.4826 * median_columns(np.abs(res - median_columns(res))))), 1.0 / 255.0),
            float(np.median(w)))


def chroma_per_darkness(color_bgr) -> np.ndarray:
    """A paint's chroma per unit of luma darkness, ``(c - Y) / (1 - Y)`` (BGR, relative to white)."""
    c = np.asarray(color_bgr, float) / 255.0
    y = float(_LUMA @ c)
    return (c - y) / max(1.0 - y, 1e-3)


def luma_thresholds(classes: list, dark_luma_lit: list, white_lit: list, dark_ratio: float,
                    weak_membership: float, scale: float = 1.0, binned=None):
    """Thresholds for finding coloured paint by its luma darkness alone: ``(d_min, core, weak,
    floor)`` (luma darkness relative to the local white; ``floor``: the noise ceiling per local
    white, ``(white, ceiling)`` for ``np.interp``, or None), or None without classes or lit leather.

    JPEG keeps the luma at full resolution and the chroma at half (4:2:0), quantised more
    coarsely: a marker a few pixels across keeps its luma darkness but its per-pixel saturation
    falls under the leather's chroma noise, which the blocks raise, so neither the colour nor the
    black detector finds it. Every palette colour is darker in luma than white leather (at least
    ``d_min``, the least dark one's ``1 - Y / 255``), so a region of that darkness is a candidate
    whose summed chroma (:func:`recolor_dark`) names its colour. The thresholds are the dark
    detector's shares of the paint's darkness (``1 - dark_ratio`` for the core,
    ``weak_membership`` for the region) at the photo's contrast ``scale``, never below the lit
    leather's luma-darkness noise (median + 6 robust sigmas, ``dark_luma_lit``: arrays per ball),
    nor below its ceiling at the pixel's own local white (``white_lit``, the same pixels'; as
    the dark detector's: relative darkness is noisier on dim leather, where a back-lit crescent's
    noise otherwise passed as paint). ``binned``: the concatenated ``white_lit``'s
    :func:`~stillcap.detect._marker_noise._brightness_bins` when the caller has them.
    """
    if not classes or not dark_luma_lit:
        return None
    d_min = min(1.0 - float(_LUMA @ (np.asarray(t.color_bgr, float) / 255.0)) for tl in classes for t in tl)
    d_min = max(d_min, 0.05)
    dl = np.concatenate(dark_luma_lit)
    noise = _robust_ceiling(dl)
    floor = _noise_by_brightness(None if binned is not None else np.concatenate(white_lit), dl,
                                 binned=binned)
    return (d_min, max((1.0 - dark_ratio) * scale * d_min, noise), max(weak_membership * scale * d_min, noise),
            floor)


def recolor_dark(rw, lab, j: int, st, dark_luma, chroma, disc, pal_u, k_noise: float, classes,
                 leather=(0.0, 0.0, 0.0), mismatch_flag: int = 4, lit_white: float = 0.0, prior=()):
    """A dark region's row (of ``_measure``) kept as black, given the colour whose chroma
    explains most of its darkness, or None (mixed evidence: left out).

    Parameters
    ----------
    rw : tuple
        ``(center, type name, shape, area, confidence, aspect, ball, flags)``.
    lab, j, st : the labels, the region's label and its ``cv2`` stats row.
    dark_luma : ndarray (h, w)
        Luma darkness relative to the local white.
    chroma : (ndarray (h, w, 3), ndarray (h, w))
        BGR chroma ``pixel - luma`` (0-1 code scale) and the local white's luma.
    disc : ndarray of bool (h, w)
    pal_u : ndarray (P, 3)
        The chromatic palette colours' :func:`chroma_per_darkness`.
    k_noise : float
        The leather's chroma noise per pixel and channel, 0-1 code scale (robust sigma).
    classes : list of (types, hue, saturation)
        The chromatic colour classes, in the order of ``pal_u``.
    leather : array_like, shape (3,)
        The leather's own chroma (its median), taken off every pixel first.
    mismatch_flag : int
        The ``MarkerFlag.SHAPE_MISMATCH`` bit (passed in: this module is below ball_markers).
    lit_white : float
        The lit leather's median white (luma, 0-1): regions under ``MIN_WHITE`` of it keep black.
    prior : sequence of rows
        The rows found so far: a region next to a marker of its colour on the same ball (within
        its diameter + 2 px) is the rest of that marker (the dark path takes the pixels the
        colour path left), and is left out.
    """
    if not np.isfinite(k_noise) or len(pal_u) == 0:
        return rw
    bx, by, bw, bh = (int(v) for v in st[:4])
    y0, x0 = max(by - 7, 0), max(bx - 7, 0)
    y1, x1 = min(by + bh + 7, lab.shape[0]), min(bx + bw + 7, lab.shape[1])
    comp = (lab[y0:y1, x0:x1] == j).astype(np.uint8)
    grown = cv2.dilate(comp, _BOX5).astype(bool) & disc[y0:y1, x0:x1]
    # on the code scale, not relative to the local white: dim pixels (a shadow line, a
    # crescent's dark side) carry less paint signal and the same noise, so they weigh less
    # (relative to a dim white, a side-lit ball's shadow edge read as red and green paint)
    ck, white = chroma
    W = white[y0:y1, x0:x1][grown].astype(float)
    D = float((dark_luma[y0:y1, x0:x1][grown] * W).sum())
    if D <= 0:
        return rw
    if not W.mean() >= MIN_WHITE * lit_white:  # in the shadow: no paint signal to read there
        return rw
    # the leather's cast from the leather around the region where there is enough of it (the
    # white balance is divided out of encoded values, so a cast left by it changes with the
    # brightness: a side-lit ball's dim shadow edge has its own), else the ball's lit leather's
    ring = (cv2.dilate(grown.astype(np.uint8), _BOX5, iterations=2).astype(bool) & ~grown & disc[y0:y1, x0:x1]
            & (dark_luma[y0:y1, x0:x1] < 0.1))
    if ring.sum() >= 8:
        leather = median_columns(ck[y0:y1, x0:x1][ring] / np.maximum(white[y0:y1, x0:x1][ring], 1e-6)[:, None])
    K = ck[y0:y1, x0:x1][grown].sum(0) - np.asarray(leather, float) * W.sum()
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
    if a[p] <= NOISE_Z * sig or share < SHARE_MIXED or share > MAX_SHARE:
        return rw
    if share < SHARE_COLOR:
        return None
    cen, _, shape, area, conf, aspect, bi, flags = rw
    types = classes[p][0]
    names = {t.name for t in types}
    reach = 2.0 * np.sqrt(area / np.pi) + 2.0
    if any(q is not None and q[6] == bi and q[1] in names and np.hypot(*(q[0] - cen)) <= reach for q in prior):
        return None
    match = [t for t in types if t.shape == shape]
    t = match[0] if match else types[0]
    flags = flags & ~mismatch_flag
    if not match and shape != "unknown":
        flags |= mismatch_flag
    return cen, t.name, shape, area, conf * min(float(share), 1.0), aspect, bi, flags
