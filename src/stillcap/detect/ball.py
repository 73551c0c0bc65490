"""Ball images in stroboscopic (multi-exposure) photos: silhouettes, ellipses, known-radius Hough.

The seed's pipeline (SPEC J1 "Ball positions", steps 1-5; seed section 4.3), per stereo pair:

1. **Foreground mask** (:func:`foreground_mask`): colour background subtraction against a photo
   of the empty scene, or, without one, against a robust dark-room model (per-channel median
   and MAD of the photo itself: in a dark room almost every pixel is background). The largest
   channel excess over the background is thresholded and cleaned by a morphological opening.
2. **Silhouettes** (:func:`detect_balls`): external contours (``cv2.findContours``), their convex
   hull (painted dark markers cut small notches into the silhouette; the hull removes them) and
   an ellipse fit (``cv2.fitEllipse``) give a first centre and size. Overlapping consecutive
   ball images (a slow pitch, a fast strobe) merge into one silhouette; its distance transform
   still peaks at every ball centre, so it is flagged ``MERGED`` and split: each ball's centre
   comes from a circle fitted to its own outer arc (flag ``SPLIT``).
3. **Stereo matching** (:func:`stillcap.ball.stereo.ball_centers_stereo`): ellipse centres are matched by epipolar
   geometry (:func:`stillcap.geometry.epipolar.match_epipolar`) and triangulated; from the
   approximate 3D centre and the known ball radius the exact image outline of the ball is
   projected in each camera (:func:`sphere_outline_px`: the limb circle of the tangent cone,
   through the lens distortion), so its radius (and slight perspective elongation) is known.
4. **Refinement** (:func:`refine_centers`): a circular Hough transform of known radius (a 2D
   search over the centre only) in a neighbourhood of the ellipse centre. It scores every
   candidate centre by the gradient that crosses the known outline inward (bright ball, dark
   room), with gradient-direction selectivity, so only the lit limb votes: a half-moon ball
   (lit from the side) still has its lit half-circle exactly on the known circle, while its
   ellipse centre lies ~0.4 r towards the light. Sub-pixel peak by a fine grid and a parabola.
5. The refined centres are triangulated again: final 3D positions.

Pixel convention: detection runs on the **raw (distorted) photo**; every centre returned is a
raw pixel ``(x, y)`` (origin at the centre of the top-left pixel, OpenCV's convention).
Undistort with :meth:`stillcap.camera.Camera.undistort_points`; the stereo result carries both.
Lens distortion is handled exactly where it matters: the known-radius outline of step 3 is
projected through the distortion model, so the Hough template has the shape the ball really
has in the raw photo, and matching / triangulation undistort the centres themselves.
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from stillcap._checks import as_array
from stillcap._numeric import median
from stillcap.camera import Camera

__all__ = [
    "BallFlag", "BallDetections", "RefinedCenters",
    "foreground_mask", "detect_balls", "refine_centers", "sphere_outline_px",
]


class BallFlag(enum.IntFlag):
    """Per-ball quality flags (bit set; ``0`` means nothing to report)."""

    NONE = 0
    #: the silhouette touches the image border (a cut ball: centre and size unreliable)
    TOUCHES_BORDER = 1
    #: the ball came from a silhouette of several overlapping ball images
    MERGED = 2
    #: ... and its centre is a circle fitted to its own outer arc (else it is the distance-
    #: transform maximum, flagged PARTIAL too)
    SPLIT = 4
    #: the silhouette is clearly not round (half moon, partly lit): the ellipse centre is biased
    PARTIAL = 8
    #: Hough refinement failed (weak peak, or the peak on the search border): centre = ellipse centre
    REFINE_FAILED = 16
    #: the ellipse size disagrees with the radius projected from the triangulated centre
    SIZE_MISMATCH = 32


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass
class BallDetections:
    """Ball images found in one photo, sorted left to right (by ellipse centre x).

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Best centre estimate (raw pixels): the refined centre where refinement ran and
        succeeded, else the ellipse centre.
    ellipse_centers : ndarray, shape (N, 2)
        Centre of the ellipse fitted to the convex hull (first estimate, step 2).
    radii_px : ndarray, shape (N,)
        Radius in pixels: the known radius used by the refinement, else the ellipse's
        semi-major axis (a split ball: its circle's radius). The silhouette includes the
        blurred rim down to the (low) dark-room threshold, so this is ~1-2 px above the true
        radius; the refinement uses the radius projected from 3D instead.
    ellipses : ndarray, shape (N, 5)
        ``cv2.fitEllipse`` result per ball: centre x, centre y, full width, full height (px),
        angle (degrees).
    areas : ndarray, shape (N,)
        Contour area in px^2 (for split balls: the area of their piece).
    hull_areas : ndarray, shape (N,)
        Convex-hull area in px^2.
    scores : ndarray, shape (N,)
        Refinement support: the share of the outline with a clear inward edge (about 1 for a
        fully lit ball, 0.5 for a half moon); NaN where not refined.
    flags : ndarray of int, shape (N,)
        :class:`BallFlag` bits.
    contour_index : ndarray of int, shape (N,)
        Index of the silhouette each ball came from (balls split from one silhouette share it).
    """

    centers: np.ndarray
    ellipse_centers: np.ndarray
    radii_px: np.ndarray
    ellipses: np.ndarray
    areas: np.ndarray
    hull_areas: np.ndarray
    scores: np.ndarray
    flags: np.ndarray
    contour_index: np.ndarray
    mask: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.centers)

    @classmethod
    def empty(cls, mask=None) -> BallDetections:
        z2, z1 = np.zeros((0, 2)), np.zeros(0)
        return cls(z2, z2.copy(), z1, np.zeros((0, 5)), z1.copy(), z1.copy(), z1.copy(),
                   np.zeros(0, int), np.zeros(0, int), mask)

    def has(self, flag: BallFlag) -> np.ndarray:
        """Boolean (N,) array: which balls carry ``flag``."""
        return (self.flags & int(flag)) != 0

    def with_refined(self, refined: RefinedCenters) -> BallDetections:
        """A copy whose centres, radii, scores and flags come from :func:`refine_centers`."""
        if len(refined) != len(self):
            raise ValueError(f"refined has {len(refined)} centres for {len(self)} detections")
        return replace(self, centers=refined.centers.copy(), radii_px=refined.radii_px.copy(),
                       scores=refined.scores.copy(), flags=self.flags | refined.flags)


@dataclass
class RefinedCenters:
    """Result of :func:`refine_centers`.

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Refined centres (raw pixels); the input centre where refinement failed.
    radii_px : ndarray, shape (N,)
        The known radius used (mean distance of the outline from its centre).
    scores : ndarray, shape (N,)
        Share of the outline with a clear inward edge at the refined centre (0-1).
    shifts : ndarray, shape (N, 2)
        ``centers - input centres``.
    flags : ndarray of int, shape (N,)
        ``BallFlag.REFINE_FAILED`` where the peak was weak or on the search border.
    """

    centers: np.ndarray
    radii_px: np.ndarray
    scores: np.ndarray
    shifts: np.ndarray
    flags: np.ndarray

    def __len__(self) -> int:
        return len(self.centers)

    @property
    def ok(self) -> np.ndarray:
        """Which centres were refined, shape (N,) bool."""
        return (self.flags & int(BallFlag.REFINE_FAILED)) == 0


# --------------------------------------------------------------------------------------------
# step 1: foreground
# --------------------------------------------------------------------------------------------
def _check_image(image, name: str = "image") -> np.ndarray:
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
        raise ValueError(f"{name} must have shape (H, W) or (H, W, 3), got {img.shape}")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise ValueError(f"{name} must hold numbers (uint8 BGR expected), got dtype {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    return img


def _robust_level(channel: np.ndarray) -> tuple[float, float]:
    """Median and MAD-based sigma of one channel, from a strided subsample (fast on 5 Mpx).

    A subsample of ~1/16 of the pixels gives the median of a dark-room photo to well under one
    grey level; for ``uint8`` both statistics come from a histogram (``cv2.calcHist``: ~10x
    faster than ``np.median``, and ~4x faster than ``np.bincount``, which widens every value to
    an integer index first; its float32 counts are exact below 2^24 pixels).
    """
    step = max(1, int(np.sqrt(channel.size / 2.5e5)))
    s = channel[::step, ::step]
    if s.dtype == np.uint8:
        return _level_of_histogram(cv2.calcHist([s.ravel()], [0], None, [256], [0, 256]))
    s = s.astype(np.float32).ravel()
    med = float(np.median(s))
    return med, 1.4826 * float(np.median(np.abs(s - med)))


def _level_of_histogram(hist: np.ndarray) -> tuple[float, float]:
    """Median and MAD-based sigma of 8-bit values from their histogram (256 counts)."""
    h = np.ravel(hist).astype(np.float64)
    c = np.cumsum(h)
    med = int(np.searchsorted(c, 0.5 * c[-1]))
    # histogram of the absolute deviations |v - med|: each grey level's count moved to its
    # deviation (levels med - d and med + d share one bin)
    hd = np.bincount(np.abs(np.arange(256) - med), weights=h, minlength=256)
    mad = float(np.searchsorted(np.cumsum(hd), 0.5 * c[-1]))
    # a MAD of 0 grey levels (quantised, nearly noiseless) still means ~0.5 level of noise
    return float(med), 1.4826 * max(mad, 0.5)


def _robust_levels(src: np.ndarray, small: np.ndarray | None = None, scale: int = 1) -> list:
    """:func:`_robust_level` of every channel of ``src`` (H, W) or (H, W, 3), as a list.

    For a BGR ``uint8`` photo whose size the subsampling step (a power of 2) divides, the
    subsample of all three channels is taken at once and contiguous (every step-th row is a
    view; ``cv2.resize``, nearest pixel, picks every step-th column), and each channel's
    histogram comes from it directly: the same numbers, without copying each strided channel.
    ``small``: every ``scale``-th pixel of ``src`` (contiguous), if the caller has it; where
    ``scale`` divides the step, the subsample is taken from it (the same pixels, read from a
    smaller image that is in the cache, not from the photo).
    """
    if src.ndim == 2:
        return [_robust_level(src)]
    H, W = src.shape[:2]
    step = max(1, int(np.sqrt(H * W / 2.5e5)))
    if (src.dtype == np.uint8 and src.strides[1:] == (3, 1) and step > 1 and step & (step - 1) == 0
            and H % step == 0 and W % step == 0):
        if small is not None and step % scale == 0 and small.shape == (H // scale, W // scale, 3):
            f = step // scale
            sub = small if f == 1 else cv2.resize(small[::f], (W // step, H // step), interpolation=cv2.INTER_NEAREST)
        else:
            sub = cv2.resize(src[::step], (W // step, H // step), interpolation=cv2.INTER_NEAREST)
        return [_level_of_histogram(cv2.calcHist([sub], [k], None, [256], [0, 256])) for k in range(3)]
    return [_robust_level(src[:, :, k]) for k in range(src.shape[2])]


def _raw_mask(img: np.ndarray, background, threshold, k_sigma: float, min_contrast: float) -> np.ndarray:
    """Foreground mask before clean-up: any channel differs from the background by > threshold."""
    src, hi, _ = _mask_limits(img, background, threshold, k_sigma, min_contrast)
    return _threshold(src, hi)


def _subsample(src: np.ndarray, scale: int) -> np.ndarray:
    """``src`` at 1/``scale`` resolution, nearest pixel (``cv2.resize``)."""
    H, W = src.shape[:2]
    if H % scale == 0 and scale & (scale - 1) == 0:
        # the same pixels, ~2x faster: every scale-th row is a view (its rows' stride), so
        # cv2.resize only samples the columns (nearest pixel of a power-of-2 factor that divides
        # the height: exactly every scale-th row, as the full resize picks)
        return cv2.resize(src[::scale], (W // scale, H // scale), interpolation=cv2.INTER_NEAREST)
    return cv2.resize(src, (W // scale, H // scale), interpolation=cv2.INTER_NEAREST)


def _mask_limits(img: np.ndarray, background, threshold, k_sigma: float, min_contrast: float,
                 scale: int = 0):
    """The image to threshold (the photo, or its difference from the background), each
    channel's upper limit of "background", and (``scale`` > 0) the image at 1/``scale``
    resolution (:func:`_subsample`; else None): ``(src, hi, small)``."""
    if background is not None:
        bg = _check_image(background, "background")
        if bg.shape != img.shape:
            raise ValueError(f"background must have the image's shape {img.shape}, got {bg.shape}")
        if img.dtype == np.uint8 and bg.dtype == np.uint8:
            diff = cv2.absdiff(img, bg)
        else:
            diff = np.abs(img.astype(np.float32) - bg.astype(np.float32))
        small = _subsample(diff, scale) if scale else None
        # |difference of two noisy photos| is half-normal: its median is 0.674 sigma
        sig = [max(m / 0.674, 0.5) for m, _ in _robust_levels(diff, small, scale)]
        base = [0.0] * len(sig)
        src = diff
    else:
        src = img
        small = _subsample(img, scale) if scale else None
        stats = _robust_levels(img, small, scale)
        base = [m for m, _ in stats]
        sig = [s for _, s in stats]
    if threshold is None:
        thr = [max(k_sigma * s, float(min_contrast)) for s in sig]
    else:
        thr = [float(threshold)] * len(base)
    hi = [b + t for b, t in zip(base, thr)]
    return src, hi, small


def _threshold(src: np.ndarray, hi) -> np.ndarray:
    """``uint8`` 0/255 mask: any channel of ``src`` above its limit ``hi``."""
    if src.dtype == np.uint8:
        # "any channel above its limit" = not "all channels within": one cv2.inRange pass
        lim = [min(255, int(np.floor(h))) for h in hi]
        if src.ndim == 2:
            return cv2.bitwise_not(cv2.inRange(src, 0, lim[0]))
        return cv2.bitwise_not(cv2.inRange(src, (0, 0, 0), tuple(lim)))
    over = np.zeros(src.shape[:2], bool)
    for k, h in enumerate(hi):
        over |= (src if src.ndim == 2 else src[:, :, k]) > h
    return over.astype(np.uint8) * 255


def _open(mask: np.ndarray, open_px: int) -> np.ndarray:
    if open_px <= 0:
        return mask
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * open_px + 1, 2 * open_px + 1))
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, k)


def foreground_mask(image, background=None, threshold: float | None = None, k_sigma: float = 6.0,
                    min_contrast: float = 20.0, open_px: int = 1) -> np.ndarray:
    """Binary foreground mask of a photo (step 1), ``uint8`` 0/255, shape (H, W).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        BGR photo, 8-bit scale (``uint8``, or float in 0-255).
    background : ndarray like ``image``, optional
        Photo of the empty scene: a pixel is foreground where any channel differs from it
        (absolute difference) by more than the threshold. Without it, the dark-room model: a
        pixel is foreground where any channel exceeds that channel's median over the photo (in a
        dark room nearly every pixel is background) by more than the threshold.
    threshold : float, optional
        Channel difference (grey levels) above which a pixel is foreground. Default, per
        channel: ``k_sigma`` times the robust noise sigma (MAD) of the photo (or of the
        difference), but at least ``min_contrast`` grey levels.
    open_px : int
        Radius of the morphological opening that removes noise specks and thin spurs (0: none).
        (:func:`detect_balls` opens only around candidate silhouettes, which is faster.)
    """
    img = _check_image(image)
    return _open(_raw_mask(img, background, threshold, k_sigma, min_contrast), open_px)


# --------------------------------------------------------------------------------------------
# step 2: silhouettes -> hull -> ellipse, merged silhouettes
# --------------------------------------------------------------------------------------------
def _fit_circle(pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic (Kasa) circle fit: centre (2,), radius. A 3-unknown least-squares problem."""
    A = np.column_stack([2 * pts, np.ones(len(pts))])
    b = (pts ** 2).sum(axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:2]
    return c, float(np.sqrt(max(sol[2] + c @ c, 0.0)))


def _split_merged(contour: np.ndarray, min_sep: float, min_dip: float = 0.06):
    """Ball images inside one silhouette, from the maxima of its distance transform.

    The distance transform of one disc peaks at its centre (value r); in the union of
    overlapping discs (consecutive ball images of a slow pitch) it still peaks at every centre
    (the notches between two discs are at distance r from both centres) and dips between them.
    Each maximum's circle is then fitted to the contour points that lie on it (points near the
    notches, on two circles, are left out).

    Returns a list of (centre (2,), radius, rms residual) per ball image, empty when the
    silhouette holds one ball; centres are circle fits, or the distance maximum (rms ``inf``)
    where no circle fits (a partly lit ball).
    """
    pts = contour.reshape(-1, 2)
    x0, y0 = pts.min(axis=0) - 2
    x1, y1 = pts.max(axis=0) + 3
    crop = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(crop, [contour.reshape(-1, 1, 2)], -1, 255, -1, offset=(-int(x0), -int(y0)))
    dt = cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    top = float(dt.max())
    if top < 2.0:
        return []
    rad = max(1, int(round(max(min_sep, 0.35 * top))))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1))
    # Candidate centres: local maxima at least half the highest, and at least a quarter of the
    # radius of a disc as large as the hull (a chain of 10 overlapping balls has ~0.28; the
    # thin lit rim of a ball lit from behind, a crescent, ~0.1: it is one ball, not several)
    hull_r = np.sqrt(cv2.contourArea(cv2.convexHull(contour.reshape(-1, 1, 2))) / np.pi)
    peaks = (dt >= cv2.dilate(dt, k) - 1e-6) & (dt >= max(0.5 * top, 0.25 * hull_r))
    n, lab, stats, cents = cv2.connectedComponentsWithStats(peaks.astype(np.uint8), connectivity=8)
    maxima = []
    for j in range(1, n):  # a plateau of equal maxima counts once: its centroid
        ys, xs = np.nonzero(lab == j)
        v = dt[ys, xs].max()
        maxima.append((cents[j][0] + x0, cents[j][1] + y0, float(v)))
    # A maximum is a ball of its own only if it is far enough from every higher one and the
    # distance transform dips between them (a dark marker's notch in one ball makes a second,
    # shallow maximum; two overlapping balls a clear valley, 0.13 r deep at 1 r apart).
    maxima.sort(key=lambda m: -m[2])
    keep = []
    t = np.linspace(0.0, 1.0, 24)
    for m in maxima:
        ok = True
        for q in keep:
            if np.hypot(m[0] - q[0], m[1] - q[1]) < max(min_sep, 0.35 * q[2]):
                ok = False
                break
            xs = np.round(q[0] + t * (m[0] - q[0]) - x0).astype(int)
            ys = np.round(q[1] + t * (m[1] - q[1]) - y0).astype(int)
            along = dt[ys, xs]
            # overlapping discs: the segment between centres stays inside the silhouette (the
            # horns of a crescent are joined through the background instead) and dips
            if along.min() <= 0.0 or min(m[2], q[2]) - along.min() < max(1.5, min_dip * top):
                ok = False
                break
        if ok:
            keep.append(m)
    if len(keep) < 2:
        return []
    P = pts.astype(float)
    cen = np.array([(m[0], m[1]) for m in keep])
    rr = np.array([m[2] for m in keep])
    resid = np.abs(np.linalg.norm(P[:, None, :] - cen[None], axis=2) - rr[None])
    order = np.argsort(resid, axis=1)
    best = order[:, 0]
    r1 = np.take_along_axis(resid, order[:, :1], 1)[:, 0]
    r2 = np.take_along_axis(resid, order[:, 1:2], 1)[:, 0]
    clear = r2 - r1 > 2.0
    out = []
    for j in range(len(keep)):
        sel = P[(best == j) & clear]
        if len(sel) >= 8:
            c, r = _fit_circle(sel)
            rms = float(np.sqrt(np.mean((np.linalg.norm(sel - c, axis=1) - r) ** 2)))
            if rms <= max(1.0, 0.05 * r) and np.hypot(*(c - cen[j])) < 0.5 * rr[j]:
                out.append((c, r, rms))
                continue
        out.append((cen[j], rr[j], np.inf))
    return out


def _clean_contours(raw: np.ndarray, open_px: int, min_area: float, offset=(0, 0)) -> list:
    """External contours of the mask after a morphological opening, done per silhouette.

    Opening the whole 5 Mpx frame costs more than the rest of the detection; opening a crop
    around each candidate silhouette (drawn alone into the crop, so neighbours do not leak in)
    gives the same contours. ``offset`` is added to the returned points (``raw`` a crop).
    """
    ox, oy = int(offset[0]), int(offset[1])
    contours, _ = cv2.findContours(raw, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if open_px <= 0:
        return [c + np.array([ox, oy], c.dtype) for c in contours if cv2.contourArea(c) >= min_area]
    H, W = raw.shape
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * open_px + 1, 2 * open_px + 1))
    out = []
    for c in contours:
        if len(c) < 5 or cv2.contourArea(c) < min_area:
            continue
        x, y, w, h = cv2.boundingRect(c)
        x0, y0 = max(x - 2, 0), max(y - 2, 0)
        x1, y1 = min(x + w + 2, W), min(y + h + 2, H)
        crop = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.drawContours(crop, [c], -1, 255, -1, offset=(-x0, -y0))
        crop &= raw[y0:y1, x0:x1]
        crop = cv2.morphologyEx(crop, cv2.MORPH_OPEN, k)
        sub, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(x0 + ox, y0 + oy))
        out.extend(sub)
    return out


def _merge_boxes(boxes: list) -> list:
    """Union of overlapping (or touching) boxes ``[x0, y0, x1, y1]`` until none overlap."""
    boxes = [list(b) for b in boxes]
    merged = True
    while merged:
        merged = False
        out = []
        for b in boxes:
            for o in out:
                if b[0] <= o[2] and o[0] <= b[2] and b[1] <= o[3] and o[1] <= b[3]:
                    o[:] = [min(o[0], b[0]), min(o[1], b[1]), max(o[2], b[2]), max(o[3], b[3])]
                    merged = True
                    break
            else:
                out.append(b)
        boxes = out
    return boxes


def _foreground_contours(img: np.ndarray, background, threshold, k_sigma: float, min_contrast: float,
                         open_px: int, min_area: float, scale: int = 2, margin: int = 8) -> list:
    """The contours of :func:`_clean_contours` on the full foreground mask, thresholding only
    around the silhouettes.

    Thresholding every pixel of a 5 Mpx photo (``cv2.inRange`` over 3 channels, then the
    contour search over the whole mask) cost more than the rest of the silhouette step. The
    photo is thresholded at 1/``scale`` resolution (nearest pixel) to find where silhouettes
    are, and at full resolution only inside their boxes (grown by ``margin`` px; boxes that
    overlap merged; a box whose full-resolution mask reaches within 3 px of its edge is grown
    and the search repeated), so every silhouette is traced exactly as in the full mask: the
    same contours. A silhouette that falls between the sampled pixels everywhere (thinner than
    ``scale`` px in both directions) is not found; the opening removes such shapes anyway.
    """
    H, W = img.shape[:2]
    if min(H, W) < 16 * scale:
        src, hi, _ = _mask_limits(img, background, threshold, k_sigma, min_contrast)
        return _clean_contours(_threshold(src, hi), open_px, min_area)
    # the low-resolution image also gives the background levels their subsample
    src, hi, small = _mask_limits(img, background, threshold, k_sigma, min_contrast, scale)
    cand, _ = cv2.findContours(_threshold(small, hi), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    boxes = []
    for c in cand:
        x, y, w, h = cv2.boundingRect(c)
        boxes.append([max(x * scale - margin, 0), max(y * scale - margin, 0),
                      min((x + w) * scale + margin, W), min((y + h) * scale + margin, H)])
    band = 3
    while True:
        boxes = _merge_boxes(boxes)
        masks, grown = [], False
        for b in boxes:
            x0, y0, x1, y1 = b
            m = _threshold(src[y0:y1, x0:x1], hi)
            # foreground near an edge of the box that is not the photo's edge: the silhouette
            # may continue outside, grow the box
            g = [x0 > 0 and m[:, :band].any(), y0 > 0 and m[:band].any(),
                 x1 < W and m[:, -band:].any(), y1 < H and m[-band:].any()]
            if any(g):
                b[:] = [max(x0 - margin * g[0], 0), max(y0 - margin * g[1], 0),
                        min(x1 + margin * g[2], W), min(y1 + margin * g[3], H)]
                grown = True
            masks.append(m)
        if not grown:
            break
    out = []
    for (x0, y0, _, _), m in zip(boxes, masks):
        out.extend(_clean_contours(m, open_px, min_area, offset=(x0, y0)))
    return out


def detect_balls(image, background=None, min_area: float = 50.0, max_area: float | None = None,
                 threshold: float | None = None, k_sigma: float = 6.0, min_contrast: float = 20.0,
                 open_px: int = 1, partial_ratio: float = 0.8, partial_fill: float = 0.9,
                 merge_ratio: float = 0.9,
                 merge_solidity: float = 0.97, merge_min_sep: float = 4.0,
                 keep_mask: bool = False) -> BallDetections:
    """Ball silhouettes of one photo: foreground mask, contours, convex hull, ellipse (steps 1-2).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        BGR photo (``uint8``, or float in 0-255), raw (not undistorted).
    background : ndarray like ``image``, optional
        Photo of the empty scene; default: dark-room model (see :func:`foreground_mask`).
    min_area, max_area : float
        Silhouette area limits in px^2 (contour area; a half moon counts half a disc).
    threshold, k_sigma, min_contrast, open_px
        Foreground threshold (see :func:`foreground_mask`).
    merge_ratio, merge_solidity : float
        Silhouettes whose ellipse axis ratio is below ``merge_ratio`` or whose area is below
        ``merge_solidity`` times their hull's are searched for several ball images (maxima of
        the distance transform at least ``merge_min_sep`` px and 0.35 radius apart). Several
        found: the silhouette is ``MERGED`` and each ball is returned (``SPLIT``) with the centre
        of a circle fitted to its own outer arc, or of its distance maximum (``PARTIAL``) where no
        circle fits (overlapping half moons; accepted only for a silhouette at least 1.35 times
        the photo's median silhouette area, since a marker's notch can pinch one half moon).
    partial_ratio, partial_fill : float
        Silhouettes whose ellipse minor/major axis ratio is below ``partial_ratio``, or whose
        hull fills less than ``partial_fill`` of the ellipse, are flagged ``PARTIAL`` (half
        moons and crescents: their ellipse centre is biased towards the light).
    keep_mask : bool
        Keep the cleaned foreground mask (filled silhouettes) in the result (``mask``), for
        display and debugging.

    Returns
    -------
    BallDetections
        ``centers`` are the ellipse centres (the split circle centres for merged silhouettes);
        run :func:`refine_centers` (or :func:`ball_centers_stereo`) for the known-radius Hough
        refinement.
    """
    img = _check_image(image)
    H, W = img.shape[:2]
    contours = _foreground_contours(img, background, threshold, k_sigma, min_contrast, open_px, 0.5 * min_area)
    mask = None
    if keep_mask:
        mask = np.zeros((H, W), np.uint8)
        cv2.drawContours(mask, contours, -1, 255, -1)
    sil = []
    for ci, c in enumerate(contours):
        area = cv2.contourArea(c)
        if area < min_area or (max_area is not None and area > max_area) or len(c) < 5:
            continue
        hull_idx = cv2.convexHull(c, returnPoints=False)
        hull = c[hull_idx.ravel()]
        if len(hull) < 5:
            continue
        sil.append((ci, c, area, cv2.fitEllipse(hull), cv2.contourArea(hull)))
    # the typical silhouette of this photo: ball images of one pitch differ little in size
    typical = float(np.median([s_[2] for s_ in sil])) if len(sil) >= 3 else np.inf
    rows = []
    for ci, c, area, ell, hull_area in sil:
        x, y, bw, bh = cv2.boundingRect(c)
        flag = BallFlag.NONE
        if x <= 0 or y <= 0 or x + bw >= W or y + bh >= H:
            flag |= BallFlag.TOUCHES_BORDER
        (ex, ey), (ew, eh), _ = ell
        semi_major = 0.5 * max(ew, eh)
        pieces = []
        if min(ew, eh) < merge_ratio * max(ew, eh) or area < merge_solidity * hull_area:
            pieces = _split_merged(c, min_sep=merge_min_sep)
            # Pieces that are not discs (partly lit balls) are several balls only if the
            # silhouette is clearly larger than this photo's typical one: a dark marker's notch
            # can pinch a single half moon or crescent into two lobes.
            if pieces and not all(np.isfinite(p_[2]) for p_ in pieces) and area < 1.35 * typical:
                pieces = []
        if pieces:
            for pc, pr, rms in pieces:
                f = flag | BallFlag.MERGED | (BallFlag.SPLIT if np.isfinite(rms) else BallFlag.PARTIAL)
                rows.append((np.asarray(pc, float), pr, ell, area / len(pieces), hull_area, f, ci))
            continue
        # a half moon's hull fits an ellipse badly: too narrow, or filling too little of it
        fill = hull_area / max(np.pi / 4 * ew * eh, 1e-9)
        if min(ew, eh) < partial_ratio * max(ew, eh) or fill < partial_fill:
            flag |= BallFlag.PARTIAL
        rows.append((np.array([ex, ey]), semi_major, ell, area, hull_area, flag, ci))
    if not rows:
        return BallDetections.empty(mask)
    rows.sort(key=lambda r: (r[0][0], r[0][1]))
    centers = np.array([r[0] for r in rows], float)
    ellipses = np.array([[r[2][0][0], r[2][0][1], r[2][1][0], r[2][1][1], r[2][2]] for r in rows], float)
    return BallDetections(
        centers=centers, ellipse_centers=centers.copy(), radii_px=np.array([r[1] for r in rows], float),
        ellipses=ellipses, areas=np.array([r[3] for r in rows], float),
        hull_areas=np.array([r[4] for r in rows], float), scores=np.full(len(rows), np.nan),
        flags=np.array([int(r[5]) for r in rows], int), contour_index=np.array([r[6] for r in rows], int),
        mask=mask)


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


# --------------------------------------------------------------------------------------------
# step 4: known-radius Hough refinement
# --------------------------------------------------------------------------------------------
def _template(offsets: np.ndarray):
    """Inward unit normals and arc-length weights of a closed outline (M, 2) around 0."""
    # next minus previous point, cyclically (np.roll twice, without its generic overhead)
    tang = np.empty_like(offsets)
    tang[1:-1] = offsets[2:] - offsets[:-2]
    tang[0] = offsets[1] - offsets[-1]
    tang[-1] = offsets[0] - offsets[-2]
    tx, ty = tang[:, 0], tang[:, 1]
    length = np.sqrt(tx * tx + ty * ty)  # np.linalg.norm(tang, axis=1), without its overhead
    n = np.empty_like(tang)
    n[:, 0], n[:, 1] = ty, -tx
    n /= np.maximum(length, 1e-12)[:, None]
    # inward: towards the centre (the outline surrounds the origin)
    if np.sum(n * offsets) > 0:
        n = -n
    return n, 0.5 * length


def _score(g, ox, oy, px, py, nx, ny, wt, power):
    """Hough score of candidate centres (T,) for one template (M,).

    Every outline point q = centre + p votes with the gradient component along the inward
    normal (bright ball on dark), times cos^power of the angle between gradient and normal:
    an edge votes only for centres that lie along its gradient, so the terminator of a half
    moon (whose gradient runs across the ball) does not pull the centre.
    """
    # (ox + px) in the inputs' precision (float64 candidates from refine_centers), rounded to the
    # float32 maps cv2.remap takes, without a float64 temporary
    T, M = len(ox), len(px)
    mx = np.add(ox[:, None], px[None, :], out=np.empty((T, M), np.float32))
    my = np.add(oy[:, None], py[None, :], out=np.empty((T, M), np.float32))
    return _score_maps(g, mx, my, nx, ny, wt, power)


def _score_maps(g, mx, my, nx, ny, wt, power):
    """:func:`_score` of the outline points' positions ``mx``, ``my`` (float32, (T, M)).

    Each gradient is sampled by its own single-channel ``cv2.remap``: OpenCV's float path for
    one channel interpolates exactly, while a 2-channel remap (or fixed-point maps from
    ``cv2.convertMaps``) rounds the bilinear weights to 1/32 px, which moves the scores.
    """
    sx = cv2.remap(g[0], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    sy = cv2.remap(g[1], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # gn = max(0, sx nx + sy ny), in place (the remapped arrays are ours): fewer temporaries
    gn = np.multiply(sx, nx, out=sx if not power else None)
    gn += np.multiply(sy, ny, out=sy if not power else None)
    gn = np.maximum(gn, 0.0, out=gn)
    if power:
        mag2 = sx * sx + sy * sy + 1e-12
        gn = gn * (gn * gn / mag2) ** (0.5 * power)
    return gn @ wt, gn


def _gradient(a: np.ndarray):
    """Gradient images (x, y), float32."""
    return (cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3, scale=0.125),
            cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3, scale=0.125))


@functools.lru_cache(maxsize=32)
def _grid_offsets(step: float, k: int):
    """Offsets of a (2k+1)^2 grid of ``step`` (float32): the axis (2k+1,) and the raveled x and
    y offsets (row-major, y slowest); cached (read-only), the grids of the refinement are few."""
    d = (np.arange(-k, k + 1) * step).astype(np.float32)
    DY, DX = np.meshgrid(d, d, indexing="ij")
    out = (d, DX.ravel(), DY.ravel())
    for a in out:
        a.flags.writeable = False
    return out


def _grid_peak(g, x, y, tpl, power, step, k, moves):
    """Best centre on a (2k+1)^2 grid of ``step`` around (x, y); re-centred up to ``moves``
    times while the best lies on the grid border. Returns x, y, the grid scores, the index."""
    d = _grid_offsets(float(step), int(k))[0]
    n = len(d)
    px, py = tpl[0], tpl[1]
    for _ in range(moves + 1):
        # the outline points of every candidate (row-major, y slowest): candidate (i, j) is
        # (x + d[j], y + d[i]), so the x map has only n distinct rows (tiled) and the y map n
        # (each repeated): summed once per row, the same numbers as x + DX + p per candidate
        xs, ys = x + d, y + d  # the candidates' dtype as in x + DX (NumPy's promotion of x)
        mx = np.add(xs[:, None], px[None, :], out=np.empty((n, len(px)), np.float32))
        my = np.add(ys[:, None], py[None, :], out=np.empty((n, len(py)), np.float32))
        sc, _ = _score_maps(g, cv2.repeat(mx, n, 1), my.repeat(n, axis=0), *tpl[2:], power)
        sc = sc.reshape(n, n)
        i, j = divmod(int(np.argmax(sc)), n)  # np.unravel_index on a square grid
        x, y = x + float(d[j]), y + float(d[i])
        if 0 < i < 2 * k and 0 < j < 2 * k:
            break
    return x, y, sc, (i, j)


@functools.lru_cache(maxsize=64)
def _resample_params(n_old: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Parameters of a closed outline's ``n_old`` points (and its first point repeated) and of
    ``m`` points resampled uniformly along them, for ``np.interp``; cached (read-only)."""
    t_old = np.linspace(0, 1, n_old + 1)
    t_new = np.linspace(0, 1, m, endpoint=False)
    t_old.flags.writeable = t_new.flags.writeable = False
    return t_old, t_new


def _percentile(a: np.ndarray, q: float) -> float:
    """``np.percentile(a, q)`` (linear method), by ``np.partition``: the same number (numpy's
    interpolation formula) at a tenth of the cost on the few hundred values of an outline."""
    a = np.ravel(a)
    n = len(a)
    x = q / 100.0 * (n - 1)
    lo = int(np.floor(x))
    hi = min(lo + 1, n - 1)
    t = x - lo
    p = np.partition(a, [lo, hi]) if hi != lo else np.partition(a, lo)
    lo_v, hi_v = p[lo], p[hi]
    d = hi_v - lo_v
    return float(hi_v - d * (1.0 - t) if t >= 0.5 else lo_v + d * t)


def _quad_peak(f: np.ndarray, i: int, j: int) -> tuple[float, float]:
    """Sub-pixel offset (dy, dx) of the maximum of a grid from separable parabolas at (i, j)."""
    def para(a, b, c):
        den = a - 2 * b + c
        # clipped to +-0.5 (np.clip's overhead is large on one number)
        return 0.0 if den >= 0 else float(min(max(0.5 * (a - c) / den, -0.5), 0.5))
    dy = para(f[i - 1, j], f[i, j], f[i + 1, j]) if 0 < i < f.shape[0] - 1 else 0.0
    dx = para(f[i, j - 1], f[i, j], f[i, j + 1]) if 0 < j < f.shape[1] - 1 else 0.0
    return dy, dx


@functools.lru_cache(maxsize=8)
def _gamma_lut(gamma: float) -> np.ndarray:
    """8-bit value -> linear radiance ``(v / 255) ** gamma``, float32 (256,); cached (read-only)."""
    lut = ((np.arange(256, dtype=np.float64) / 255.0) ** gamma).astype(np.float32)
    lut.flags.writeable = False
    return lut


def _linear(a: np.ndarray, gamma: float) -> np.ndarray:
    """Pixel values (8-bit scale) -> linear radiance 0-1, float32."""
    if gamma == 1.0:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint8:
        return _gamma_lut(gamma)[a]
    return (np.clip(a.astype(np.float32), 0, 255) / 255.0) ** gamma


def _linear_max(a: np.ndarray, gamma: float) -> np.ndarray:
    """Brightest channel of a crop in linear radiance (``_linear(a, gamma).max(axis=2)``).

    The linearisation is monotonic, so the channel maximum is taken first on the 8-bit values
    (two ``np.maximum`` on channel views: ``max(axis=2)`` over 3 channels is a slow strided
    reduction) and only the result goes through the lookup table (``cv2.LUT``): the same
    numbers, ~30x faster than converting the three channels to float first.
    """
    if a.ndim == 3:
        if a.dtype == np.uint8:
            a = np.maximum(np.maximum(a[:, :, 0], a[:, :, 1]), a[:, :, 2])
        else:
            return _linear(a, gamma).max(axis=2)
    if a.dtype == np.uint8 and gamma != 1.0:
        return cv2.LUT(a, _gamma_lut(gamma))
    return _linear(a, gamma)


# --------------------------------------------------------------------------------------------
# step 4b: shading bias of a partly lit ball (lambertian sphere model)
# --------------------------------------------------------------------------------------------
def _outline_affine(off: np.ndarray) -> np.ndarray:
    """Symmetric 2x2 ``A`` with ``off ~ A [cos t, sin t]``: the ellipse of an outline (M, 2)
    sampled about uniformly around its centre (its second moment is ``A A^T / 2``)."""
    ev, V = np.linalg.eigh(2.0 * (off.T @ off) / len(off))
    return (V * np.sqrt(np.maximum(ev, 1e-12))) @ V.T


def _lit_sphere_image(shape, centre, A: np.ndarray, light, ss: int = 3, band_px: float | None = None,
                      q=None) -> np.ndarray:
    """Radiance (unit albedo) of a lambertian sphere lit from the direction ``light``
    (unit 3-vector in the frame (x right, y down, z toward the camera)), seen orthographically
    through the outline ellipse ``A`` centred on ``centre`` (crop pixels), each pixel the mean
    of ``ss x ss`` samples; float32 image of ``shape``.

    ``band_px``: supersample only the pixels within about ``band_px`` of the limb (inside) and
    the limb's own pixels; the rest get one sample at their centre (pixels well outside the
    outline are 0 either way; inside it the radiance is smooth, and a pixel farther than the
    blur kernel's reach from the limb does not change the limb's gradient). ``q``: the
    outline-normalised coordinates ``A^-1 (pixel - centre)`` of the pixel centres, shape
    (2, H, W), if the caller has them.
    """
    h, w = shape
    o = (np.arange(ss) + 0.5) / ss - 0.5
    Ai = np.linalg.inv(A)
    lx, ly, lz = light

    def rad_of(qx, qy, r2=None):
        if r2 is None:
            r2 = qx * qx + qy * qy
        qz = np.sqrt(np.maximum(1.0 - r2, 0.0))  # np.clip(., 0, None), without its overhead
        return np.where(r2 < 1.0, np.maximum(qx * lx + qy * ly + qz * lz, 0.0), 0.0)

    if band_px is None:
        ys = (np.arange(h)[:, None] + o[None, :]).ravel() - centre[1]
        xs = (np.arange(w)[:, None] + o[None, :]).ravel() - centre[0]
        qx = Ai[0, 0] * xs[None, :] + Ai[0, 1] * ys[:, None]
        qy = Ai[1, 0] * xs[None, :] + Ai[1, 1] * ys[:, None]
        return rad_of(qx, qy).reshape(h, ss, w, ss).mean(axis=(1, 3)).astype(np.float32)
    if q is None:
        yy, xx = np.mgrid[0:h, 0:w]
        q = np.einsum("ij,jhw->ihw", Ai, np.stack([xx - centre[0], yy - centre[1]]).astype(float))
    sv = np.linalg.svd(A, compute_uv=False)  # the outline's semi-axes (px)
    r2 = q[0] ** 2 + q[1] ** 2
    # a pixel within band_px of the limb lies beyond 1 - band / (largest semi-axis) in these
    # coordinates; a pixel whose samples (<= 0.5 px from its centre) are all outside the outline,
    # beyond 1 + 0.5 / (smallest semi-axis); one more pixel of margin each way
    r_in = max(1.0 - (band_px + 1.0) / sv[0], 0.0)
    r_out = 1.0 + 1.5 / sv[-1]
    out = rad_of(q[0], q[1], r2)
    band = (r2 > r_in * r_in) & (r2 < r_out * r_out)
    qxb, qyb = q[0][band], q[1][band]
    if len(qxb):
        # the samples of pixel (y, x): its centre's coordinates plus A^-1 (o_j, o_i)
        dqx = Ai[0, 0] * o[None, :] + Ai[0, 1] * o[:, None]  # (ss_y, ss_x)
        dqy = Ai[1, 0] * o[None, :] + Ai[1, 1] * o[:, None]
        out[band] = rad_of(qxb[:, None, None] + dqx[None], qyb[:, None, None] + dqy[None]).mean(axis=(1, 2))
    return out.astype(np.float32)


@functools.lru_cache(maxsize=1)
def _centroid_table() -> tuple[np.ndarray, np.ndarray]:
    """Phase angle (rad) -> distance of the radiance centroid of a lambertian sphere from its
    centre, in radii (orthographic; 0 for a full disc, -> 1 as the lit crescent thins).
    Tabulated once on a 1 % grid of the disc."""
    q = (np.arange(200) + 0.5) / 100.0 - 1.0
    qx, qy = np.meshgrid(q, q)
    r2 = qx * qx + qy * qy
    inside = r2 < 1.0
    qz = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    alpha = np.radians(np.arange(0.0, 176.0, 1.0))
    m = np.empty_like(alpha)
    for k, a in enumerate(alpha):
        rad = np.where(inside, np.maximum(qx * np.sin(a) + qz * np.cos(a), 0.0), 0.0)
        m[k] = np.sum(rad * qx) / np.sum(rad)
    return alpha, np.maximum.accumulate(m)


def _phase_from_centroid(m: float) -> float:
    """Phase angle (rad) whose lambertian radiance centroid lies ``m`` radii off the centre."""
    alpha, table = _centroid_table()
    return float(np.interp(m, table, alpha))


def _shading_bias(lin: np.ndarray, centre: np.ndarray, off: np.ndarray, tpl, power: float,
                  blur: float, fine_step: float) -> np.ndarray:
    """Offset (2,) of the Hough peak from the true centre for the shading of this ball image.

    The limb of a lambertian sphere is not a plain step: just inside it the radiance changes
    fast (``n . l`` with ``n_z = sqrt(1 - rho^2)``), falling toward the limb when the ball is
    lit from the front and rising when lit from behind (a half moon's thin bright rim). Blurred,
    that moves the lit limb's gradient peak in or out by a fraction of a pixel, and the Hough
    centre with it along the lit direction (noise-free model: -0.1 px at a 45 deg phase angle,
    +0.1 px at 90 deg, +0.25 px at 110 deg for a 20 px ball). The phase angle is read from the
    image: the radiance centroid of the ball (blur does not move it) lies a known distance from
    the centre for each phase angle (:func:`_centroid_table`), toward the light. The model ball
    lit so is rendered at the Hough centre, blurred like the photo (``blur``: lens PSF and the
    refinement's own smoothing), and the same Hough run on it gives the offset.
    """
    # the outline's own middle: off axis the image of the sphere centre is not the middle of
    # its (elongated) outline; the shading is modelled about the middle, orthographically
    mid = centre + off.mean(axis=0)
    A = _outline_affine(off - off.mean(axis=0))
    Ai = np.linalg.inv(A)
    h, w = lin.shape
    xy = np.empty((2, h, w))
    xy[0] = np.arange(w) - mid[0]
    xy[1] = (np.arange(h) - mid[1])[:, None]
    q = np.einsum("ij,jhw->ihw", Ai, xy)
    r2 = q[0] ** 2 + q[1] ** 2
    ring = (r2 > 1.3 ** 2)
    level = median(lin[ring]) if np.any(ring) else 0.0
    wgt = np.where(r2 < 1.15 ** 2, np.maximum(lin - level, 0.0), 0.0)
    tot = float(wgt.sum())
    if not tot > 0:
        return np.zeros(2)
    mq = np.array([np.sum(wgt * q[0]), np.sum(wgt * q[1])]) / tot
    mn = float(np.hypot(*mq))
    if not np.isfinite(mn) or mn < 1e-6:
        return np.zeros(2)
    a = _phase_from_centroid(mn)
    light = (np.sin(a) * mq[0] / mn, np.sin(a) * mq[1] / mn, np.cos(a))
    # supersampled near the limb only: beyond the blur kernel (cv2's reaches 4 sigma), the Sobel
    # and the Hough's search around the centre from the limb, a pixel cannot change the result
    band = 4.0 * blur + 4.0
    model = cv2.GaussianBlur(_lit_sphere_image(lin.shape, mid, A, light, band_px=band, q=q), (0, 0), blur)
    kf = max(2, int(round(0.3 / fine_step)))
    return np.array(_model_peak(model, centre, tpl, power, fine_step, kf)) - centre


def _model_peak(model: np.ndarray, start, tpl, power: float, step: float, k: int) -> tuple[float, float]:
    """Sub-pixel Hough centre (x, y) of a rendered model ball near ``start``: the ``step`` grid
    (``(2k+1)^2``) followed up to 6 moves, again up to 3, then a parabola (the model's offset in
    :func:`_shading_bias` and :mod:`stillcap.ball.uncertainty`)."""
    g = _gradient(model)
    bx, by, fs, (fi, fj) = _grid_peak(g, float(start[0]), float(start[1]), tpl, power, step, k, moves=6)
    if (fi, fj) != (k, k):
        # (a peak at the grid's centre: the second search would score the same grid again)
        bx, by, fs, (fi, fj) = _grid_peak(g, bx, by, tpl, power, step, k, moves=3)
    ddy, ddx = _quad_peak(fs, fi, fj)
    return bx + ddx * step, by + ddy * step


def refine_centers(image, centers, radius_px, search_px=None, outlines=None, background=None,
                   gamma: float = 2.2, sigma: float = 0.7, power: float = 0.0, fine_step: float = 0.1,
                   min_score: float = 0.2, min_edge: float = 0.004, start_refined: bool = False,
                   shading=False, psf_px: float = 0.5, shading_support: float = 0.7) -> RefinedCenters:
    """Refine ball centres by a circular Hough transform of known radius (step 4).

    The radius is known, so the Hough space is 2D: the centre. Every candidate centre within
    ``search_px`` of the start is scored by the brightness gradient (linearised, smoothed by
    ``sigma``) that crosses the known outline *inward*: ``sum_k w_k max(0, n_k . g(c + p_k))``
    over outline points ``p_k`` with inward normals ``n_k`` and arc-length weights ``w_k``
    (gradient-direction voting: an edge votes for the centres that lie along its gradient; an
    outward gradient, e.g. the rim of a bright neighbour, votes for none). Only the lit limb of
    a half moon has such edges and it lies exactly on the known circle, so its centre comes out
    right while its ellipse centre is pulled towards the light. Search: a 2 px grid over the
    window (on a gradient smoothed to 2 px), 0.5 px and ``fine_step`` grids that follow the
    peak, then a parabola through the peak for the sub-pixel centre.

    Written by hand rather than with ``skimage.transform.hough_circle``: that votes with a
    binary edge map into integer centres, while here the vote is gradient-weighted and
    direction-aware (what makes half moons work), the template may be the exact projected
    outline (an ellipse through the lens distortion, not only a circle), and only a small
    window is evaluated (``cv2.remap`` samples the gradient at all candidate outlines at once).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        The photo the centres were found in (BGR, 8-bit scale).
    centers : array_like, shape (N, 2)
        Start centres (e.g. ellipse centres), raw pixels.
    radius_px : array_like, shape (N,) or scalar
        Known radius of each ball image in pixels (ignored where ``outlines`` is given).
    search_px : array_like, shape (N,) or scalar, optional
        Half size of the square search window. Default ``0.6 * radius`` (at least 3 px): a half
        moon's ellipse centre is ~0.4 r off.
    outlines : array_like, shape (N, M, 2), optional
        Exact outline offsets relative to the centre (e.g. from :func:`sphere_outline_px`,
        ``outlines_px - centers_px[:, None]``), used instead of circles.
    background : ndarray like ``image``, optional
        Photo of the empty scene, subtracted first.
    gamma : float
        The photo's encoding gamma: pixel values are linearised (``(v / 255) ** gamma``) before
        the gradient. In gamma-encoded values a blurred edge is asymmetric and its gradient
        peak lies outside the true limb (by ~0.3-0.6 px for a 0.6 px blur), which the lit half
        of a half moon turns into a centre bias of the same size; in linear values it does not.
        Use 1.0 for linear (raw) data.
    sigma : float
        Gaussian smoothing (px) before the gradient.
    power : float
        Extra direction selectivity: each vote is multiplied by ``cos(angle)^power`` between
        gradient and normal (0: the plain inward component; on drawn balls 0 was best).
    fine_step : float
        Step of the sub-pixel grid (px).
    min_score : float
        Minimum share of the outline with a clear inward edge; below it the refinement fails.
    min_edge : float
        An edge is clear if its inward gradient (linear radiance, full scale 1, per pixel) is at
        least a quarter of the outline's 90th percentile and at least ``min_edge``: a ball's limb
        has ~0.05-0.5, the linearised noise of a dark room ~0.001.
    start_refined : bool
        The start centres are refined ones (e.g. a later round of :func:`ball_centers_stereo`):
        skip the 2 px grid, whose job is to find the peak's basin from a start up to 0.6 r off,
        and search with the 0.5 px grid that follows the peak (up to 6 px) directly.
    shading : bool or array_like of bool, shape (N,)
        (Default off.) ``True``: correct partly lit balls (less than ``shading_support`` of the
        outline with an edge); an array: correct exactly those balls. Corrects for their shading (:func:`_shading_bias`): the limb of a
        lambertian sphere lit from the side or behind is a thin bright rim whose blurred edge
        peaks outside the limb, which puts the Hough centre up to ~0.2 px toward the light
        (0.12 px on average on the studio pitches' back pair, 0.002 px after). The phase angle
        comes from the ball image's radiance centroid; the model is orthographic (a ball far
        from the camera compared with its size).
    psf_px : float
        Lens blur (Gaussian sigma, px) of the photo, for the shading model.
    shading_support : float
        The correction is made where less than this share of the outline has a clear edge
        (a partly lit ball; fully lit balls, 0.77-1.0 on the studio pitches' front pair, have no
        measurable bias, 0.02 px, and the orthographic model does not hold for near ones).

    Returns
    -------
    RefinedCenters
    """
    img = _check_image(image)
    c0 = as_array(centers, (None, 2), "centers")
    n = len(c0)
    if outlines is not None:
        outl = np.asarray(outlines, float)
        if outl.ndim != 3 or outl.shape[0] != n or outl.shape[2] != 2 or outl.shape[1] < 8:
            raise ValueError(f"outlines must have shape ({n}, M, 2) with M >= 8, got {outl.shape}")
        radii = np.linalg.norm(outl, axis=2).mean(axis=1)
        # every outline's length at once (the per-ball resampling below needs it)
        closed_all = np.concatenate([outl, outl[:, :1]], axis=1)
        finite = np.all(np.isfinite(outl), axis=(1, 2))
        with np.errstate(invalid="ignore"):
            lengths = np.sum(np.linalg.norm(np.diff(closed_all, axis=1), axis=2), axis=1)
    else:
        r = np.asarray(radius_px, float)
        radii = np.broadcast_to(r, (n,)).astype(float) if r.ndim == 0 else as_array(r, (n,), "radius_px")
        outl = None
    if search_px is None:
        search = np.maximum(3.0, 0.6 * radii)
    else:
        s = np.asarray(search_px, float)
        search = np.broadcast_to(s, (n,)).astype(float) if s.ndim == 0 else as_array(s, (n,), "search_px")
    if background is not None:
        bg = _check_image(background, "background")
        if bg.shape != img.shape:
            raise ValueError(f"background must have the image's shape {img.shape}, got {bg.shape}")
    shade = None if np.ndim(shading) == 0 else as_array(np.asarray(shading, float), (n,), "shading") > 0
    out_c = c0.copy()
    scores = np.zeros(n)
    flags = np.zeros(n, int)
    H, W = img.shape[:2]
    for i in range(n):
        r = radii[i]
        if not (np.all(np.isfinite(c0[i])) and np.isfinite(r) and r > 1.0 and np.isfinite(search[i])):
            flags[i] = BallFlag.REFINE_FAILED
            scores[i] = np.nan
            continue
        if outl is None:
            m = max(24, int(np.ceil(2 * np.pi * r)))
            th = np.linspace(0, 2 * np.pi, m, endpoint=False)
            off = r * np.stack([np.cos(th), np.sin(th)], axis=1)
        else:
            off = outl[i]
            if not finite[i]:
                flags[i] = BallFlag.REFINE_FAILED
                scores[i] = np.nan
                continue
            # resample to ~1 point per pixel of outline
            m = max(24, int(np.ceil(lengths[i])))
            if m != len(off):
                t_old, t_new = _resample_params(len(off), m)
                closed = closed_all[i]
                off = np.stack([np.interp(t_new, t_old, closed[:, 0]), np.interp(t_new, t_old, closed[:, 1])], 1)
        nrm, wt = _template(off)
        wt = (wt / wt.sum()).astype(np.float32)
        s = float(search[i])
        ext = float(np.abs(off).max()) + s + 3.0 * sigma + 3.0
        x0, y0 = int(np.floor(c0[i, 0] - ext)), int(np.floor(c0[i, 1] - ext))
        x1, y1 = int(np.ceil(c0[i, 0] + ext)) + 1, int(np.ceil(c0[i, 1] + ext)) + 1
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if xb - xa < 3 or yb - ya < 3:
            flags[i] = BallFlag.REFINE_FAILED
            scores[i] = np.nan
            continue
        if background is not None:
            crop = np.abs(_linear(img[ya:yb, xa:xb], gamma) - _linear(bg[ya:yb, xa:xb], gamma))
            if crop.ndim == 3:
                crop = crop.max(axis=2)
        else:
            crop = _linear_max(img[ya:yb, xa:xb], gamma)
        lin = crop
        if sigma > 0:
            crop = cv2.GaussianBlur(crop, (0, 0), sigma)
        g2 = _gradient(crop)
        off32, nrm32 = off.T.astype(np.float32), nrm.T.astype(np.float32)  # contiguous rows
        tpl = (off32[0], off32[1], nrm32[0], nrm32[1], wt)
        cx, cy = c0[i, 0] - xa, c0[i, 1] - ya
        # Coarse to fine: a 2 px grid over the search window on a more smoothed gradient with
        # every 2nd outline point (its peak is wide enough not to fall between grid points),
        # then 0.5 px and ``fine_step`` grids that move with the peak, then a parabola.
        k = int(np.ceil(s / 2.0))
        if k >= 2 and not start_refined:
            extra = np.sqrt(max(2.0 ** 2 - sigma ** 2, 0.0))
            g2c = _gradient(cv2.GaussianBlur(crop, (0, 0), extra)) if extra > 0.1 else g2
            wc = tpl[4][::2] / tpl[4][::2].sum()
            coarse = (tpl[0][::2], tpl[1][::2], tpl[2][::2], tpl[3][::2], wc.astype(np.float32))
            bx, by, _, _ = _grid_peak(g2c, cx, cy, coarse, power, 2.0, k, moves=0)
            bx, by, _, _ = _grid_peak(g2, bx, by, tpl, power, 0.5, 3, moves=3)
        elif k >= 2:
            # a start that is already a refined centre: no basin to find, the 0.5 px grid that
            # follows the peak (up to 6 px) replaces the coarse grid and its smoothed gradient
            bx, by, _, _ = _grid_peak(g2, cx, cy, tpl, power, 0.5, 3, moves=3)
        else:
            bx, by, _, _ = _grid_peak(g2, cx, cy, tpl, power, 0.5, max(2, int(np.ceil(2 * s))), moves=1)
        kf = max(2, int(round(0.3 / fine_step)))
        bx, by, fs, (fi, fj) = _grid_peak(g2, bx, by, tpl, power, fine_step, kf, moves=3)
        ddy, ddx = _quad_peak(fs, fi, fj)
        best = np.array([bx + ddx * fine_step, by + ddy * fine_step])
        # support: share of the outline (by length) with a clear inward edge at the best centre
        _, gn = _score(g2, np.array([best[0]], np.float32), np.array([best[1]], np.float32),
                       *tpl, power)
        gmax = _percentile(gn, 90.0)
        support = float(wt @ (gn[0] > max(0.25 * gmax, min_edge)))
        scores[i] = support
        outside = np.hypot(best[0] - cx, best[1] - cy) > s * np.sqrt(2) + 1.0
        if outside or support < min_score or fs.max() <= 0:
            flags[i] = BallFlag.REFINE_FAILED
            continue
        if shade[i] if shade is not None else (shading and support < shading_support):
            best = best - _shading_bias(lin, best, off, tpl, power, np.hypot(sigma, psf_px), fine_step)
        out_c[i] = best + (xa, ya)
    return RefinedCenters(out_c, radii.copy(), scores, out_c - c0, flags)
