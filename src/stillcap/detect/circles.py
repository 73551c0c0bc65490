"""Circular bead markers in a photo: the thesis's Hough detector and better ones.

The puppet (SPEC J3) carries painted 6 mm beads, 5-7 px in radius in a 640x480 webcam photo,
on a black figure in front of a black background, lit by the webcam's LEDs. Methods, chosen
by name in :func:`find_circles`:

``"thesis"``
    Exactly the thesis's chain (section 3.3): grey image (ImageJ's unweighted mean of R, G,
    B); automatic IsoData threshold (ImageJ "Default" = :func:`skimage.filters.threshold_isodata`);
    outline (a foreground pixel stays only if not all 8 neighbours are foreground); circular
    Hough transform (:func:`skimage.transform.hough_circle`) for the ``n`` best circles with
    radii ``r_min..r_max`` in 1 px steps. Whole-pixel centres.
``"hough"``
    The thesis's chain, then each centre refined on the original grey image (intensity-weighted
    centroid of the disc around the Hough centre, iterated; see :func:`refine_centers`).
``"blobs"``
    Bright regions of the IsoData mask (connected components), kept if their area fits the
    radius range and they are round; regions that are not round (touching beads) are handed
    to the Hough transform restricted to that region; centres refined as for ``"hough"``.
``"template"`` (default)
    A matched filter: disc-minus-ring contrast (:func:`contrast_map`) for each radius, local
    maxima (:func:`skimage.feature.peak_local_max`) above an automatic contrast threshold,
    centres refined as for ``"hough"``. It needs no global threshold, so limbs brighter than
    the IsoData threshold do not merge with the beads on them, and it returns only what is
    there instead of always ``n`` circles.
``"cv2"``
    OpenCV's gradient Hough transform (:func:`cv2.HoughCircles`, ``HOUGH_GRADIENT``), then
    refined as for ``"hough"``.

``docs/puppet-detection.md`` has the measured centre errors and detection rates.

The module also draws synthetic bead photos with known sub-pixel centres
(:func:`draw_beads`, :func:`random_bead_scene`) for tests and benchmarks.
"""

from __future__ import annotations

import functools

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage
from skimage.filters import threshold_isodata
from skimage.transform import hough_circle, hough_circle_peaks

from stillcap._checks import as_array, as_rng

__all__ = [
    "METHODS",
    "BeadScene",
    "Circles",
    "TemplateInputs",
    "draw_beads",
    "contrast_map",
    "find_circles",
    "grey_image",
    "isodata_threshold",
    "outline",
    "prepare_template",
    "random_bead_scene",
    "refine_centers",
]

#: Detector names :func:`find_circles` accepts.
METHODS = ("thesis", "hough", "blobs", "template", "cv2")


@dataclass(eq=False)
class Circles:
    """Circles found in one image.

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Pixel centres (x, y), origin at the centre of the top-left pixel.
    radii : ndarray, shape (N,)
        Pixels.
    scores : ndarray, shape (N,)
        Strength, higher is better: the Hough accumulator (fraction of the circle's outline
        found) for ``thesis``/``hough``; for ``blobs`` the region's circularity
        ``4 pi area / perimeter^2`` (or the Hough score of a split region); for ``template``
        the disc-minus-ring contrast in grey levels; for ``cv2`` a rank (OpenCV returns no votes).
    method : str
    threshold : float
        The IsoData grey threshold used (NaN for ``template`` and ``cv2``).
    """

    centers: np.ndarray
    radii: np.ndarray
    scores: np.ndarray
    method: str
    threshold: float = np.nan

    def __len__(self) -> int:
        return len(self.centers)


@dataclass(eq=False)
class TemplateInputs:
    """The photo-wide part of :func:`find_circles`'s ``template`` detector
    (:func:`prepare_template`): what depends only on the photo, made by OpenCV and NumPy calls
    that mostly release the GIL, so that another thread can make it (the puppet pipeline does,
    while it decodes the photos) and the detection proper starts from it.

    Attributes
    ----------
    shape : (int, int)
        Height and width of the photo it was made from.
    grey : ndarray, shape (H, W), float32
        :func:`grey_image`.
    median : float or None
        Median grey (None: not a uint8 BGR photo; then computed from ``grey`` when needed).
    coarse_map : ndarray or None
        Half-resolution contrast map of ``radii`` (``coarse``; None for photos under 8 px).
    padded : ndarray or None
        ``grey`` with its replicated border, for the full-resolution contrast at single pixels.
    radii : tuple of float
        The radii it was made for.
    """

    shape: tuple
    grey: np.ndarray
    median: float | None
    coarse_map: np.ndarray | None
    padded: np.ndarray | None
    radii: tuple


def prepare_template(image, radius_range=(5.0, 7.0), coarse: bool = True) -> TemplateInputs:
    """The photo-wide inputs of ``find_circles(image, method="template", coarse=coarse)``
    (:class:`TemplateInputs`; pass them as its ``prepared``: the same circles).

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
    radius_range : (float, float)
        As :func:`find_circles`'s.
    coarse : bool
        Make the half-resolution contrast map too.
    """
    img = _as_image(image)
    rs = _radii(radius_range)
    if img.ndim == 3 and img.dtype == np.uint8 and img.shape[2] == 3:
        # grey_image's own arithmetic, keeping the channel sum for the median
        csum = _channel_sum(img)
        grey = csum.astype(np.float32)
        grey /= np.float32(3.0)
        med = _median_grey(img, csum)
    else:
        grey, med = grey_image(img), None
    h, w = grey.shape
    Ch = gp = None
    if coarse and h >= 8 and w >= 8:
        Ch = _coarse_map(grey, rs)
        pad = _kernel_stack(tuple(float(r) for r in rs)).shape[1] // 2
        gp = cv2.copyMakeBorder(grey, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    return TemplateInputs((h, w), grey, med, Ch, gp, tuple(float(r) for r in rs))


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
    """B + G + R of a uint8 image as uint16 (channel by channel: ~10x faster than
    ``sum(axis=2)`` on a cropped view)."""
    s = img[..., 0].astype(np.uint16)
    s += img[..., 1]
    s += img[..., 2]
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


# -- refinement --------------------------------------------------------------------------------
def refine_centers(image, centers, radii, iterations: int = 3, background=None,
                   local_bg: bool = True) -> np.ndarray:
    """Sub-pixel centres: intensity-weighted centroid of each disc on the grey image, iterated.

    Weights are ``grey - background`` (clipped at 0) over the pixels within ``radius + 1.5``
    of the current centre; the window then moves to the new centroid. For a symmetric bead
    that is unbiased (partly covered rim pixels weigh in proportion). Pixels nearer (relative
    to the radii) to a neighbouring circle are left out, so touching beads do not pull each
    other. Hand-written (vectorised over the circles' small windows): scikit-image's and
    OpenCV's moments need a label image, which touching beads on a limb do not have.

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
    centers : array_like, shape (N, 2)
        Start centres (x, y).
    radii : array_like, shape (N,)
        Pixels.
    iterations : int
    background : float, optional
        Grey level of the background; default the median of the image.
    local_bg : bool
        Subtract, per circle, the median grey of the ring from ``radius + 1`` to
        ``radius + 3.5`` (if brighter than ``background``): a limb under the bead then does not
        pull the centre towards the limb.

    Returns
    -------
    ndarray, shape (N, 2)
        A centre that would move by more than its radius (a false circle) keeps its start value.
    """
    img = np.asarray(image)
    # a float32 grey image (what find_circles passes) is only read here: no copy of it
    grey = img if img.ndim == 2 and img.dtype == np.float32 else grey_image(img)
    c = as_array(centers, (None, 2), "centers").copy()
    r = as_array(radii, (len(c),), "radii")
    if len(c) == 0:
        return c
    bg = float(np.median(grey)) if background is None else float(background)
    h, w = grey.shape
    n = len(c)
    # All circles at once over one window size (the loop over circles cost ~0.5 ms each):
    # pixels (xs, ys) of a (S x S) window per circle, masked to the image; every mask below
    # is the per-circle one of the plain loop (own disc, power-diagram split, ring).
    half = int(np.ceil(r.max() + 3.5))
    off = np.arange(-half, half + 2)  # covers floor(x - B) .. ceil(x + B) for every circle
    S = len(off)
    idx = np.arange(n)
    # every S x S window of the grey image as a zero-copy view: the windows inside the image are
    # gathered per circle (~8x faster than indexing each pixel of each window; the few that
    # cross the border are read with clipped indices, i.e. the replicated border)
    g = np.ascontiguousarray(grey)
    windows = (np.lib.stride_tricks.as_strided(g, (h - S + 1, w - S + 1, S, S), g.strides * 2, writeable=False)
               if h >= S and w >= S else None)
    for _ in range(max(1, iterations)):
        base = np.floor(c).astype(int)  # (n, 2)
        xs = (base[:, 0, None] + off[None])[:, None, :]  # (n, 1, S)
        ys = (base[:, 1, None] + off[None])[:, :, None]  # (n, S, 1)
        wy, wx = base[:, 1] - half, base[:, 0] - half  # window corners
        whole = (wy >= 0) & (wx >= 0) & (wy <= h - S) & (wx <= w - S) if windows is not None else np.zeros(n, bool)
        valid = None if whole.all() else ((xs >= 0) & (xs < w)) & ((ys >= 0) & (ys < h))  # None: all pixels
        if valid is None:
            patch = windows[wy, wx]  # (n, S, S)
        else:
            patch = np.empty((n, S, S), g.dtype)
            patch[whole] = windows[wy[whole], wx[whole]] if whole.any() else 0
            o = ~whole
            patch[o] = grey[np.clip(ys[o], 0, h - 1), np.clip(xs[o], 0, w - 1)]
        # squared distances compared with squared radii (np.hypot over every window pixel cost
        # as much as the rest of the iteration)
        dx, dy = xs - c[:, 0, None, None], ys - c[:, 1, None, None]
        d2_own = dx * dx + dy * dy
        R = (r + 1.5)[:, None, None]
        inside = d2_own <= R * R
        if local_bg:
            r1, r2 = (r + 1.0)[:, None, None], R + 2.0
            ring = (d2_own > r1 * r1) & (d2_own <= r2 * r2)
        if valid is not None:
            inside &= valid
            if local_bg:
                ring &= valid
        near = np.hypot(*(c[:, None] - c[None]).transpose(2, 0, 1)) < (r[None] + r[:, None] + 3.0)
        near[idx, idx] = False
        pi, pj = np.nonzero(near)  # pairs (circle, neighbour): few
        if len(pi):
            ex, ey = xs[pi] - c[pj, 0, None, None], ys[pi] - c[pj, 1, None, None]
            d2_j = ex * ex + ey * ey
            # power-diagram split between neighbouring circles (touching beads):
            # d_own / r_own <= d_j / r_j, squared
            np.logical_and.at(inside, pi, d2_own[pi] * (r[pj] ** 2)[:, None, None] <= d2_j * (r[pi] ** 2)[:, None, None])
            if local_bg:
                rj1 = (r[pj] + 1.0)[:, None, None]
                np.logical_and.at(ring, pi, d2_j > rj1 * rj1)
        if local_bg:
            # local background: median of the ring just outside the bead (a limb under it then
            # weighs nothing), never below the global background; medians of the masked rows
            # by sorting (non-members last) and picking the middle of each row's count
            k = ring.reshape(n, -1).sum(axis=1)
            srt = np.sort(np.where(ring, patch, np.inf).reshape(n, -1), axis=1)
            lo_, hi_ = np.maximum((k - 1) // 2, 0), np.maximum(k // 2, 0)
            med = 0.5 * (srt[idx, lo_] + srt[idx, hi_])
            b = np.where(k > 0, np.maximum(bg, med), bg)
        else:
            b = np.full(n, bg)
        # np.clip(patch - b, 0, None) * inside, the same values with cheaper calls
        wgt = np.where(inside, np.maximum(patch - b[:, None, None], 0), 0)
        s_ = wgt.sum(axis=(1, 2))
        new = c.copy()
        ok = s_ > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            cx = (wgt * xs).sum(axis=(1, 2)) / s_
            cy = (wgt * ys).sum(axis=(1, 2)) / s_
        new[ok] = np.stack([cx, cy], axis=1)[ok]
        moved = np.hypot(*(new - c).T)
        # A refinement that walks away (a false circle on a limb) is undone.
        bad = moved > r
        new[bad] = c[bad]
        c = new
        if moved.max(initial=0) < 1e-3:
            break
    return c


# -- the detector ------------------------------------------------------------------------------
def find_circles(image, n: int = 16, radius_range=(5.0, 7.0), method: str = "template",
                 threshold: float | None = None, min_distance: int | None = None,
                 refine: bool | None = None, min_circularity: float = 0.7,
                 min_contrast: float = 15.0, boxes=None, coarse: bool = False,
                 prepared: TemplateInputs | None = None) -> Circles:
    """Find bead markers (bright discs on a dark scene).

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
        BGR uint8 photo (or grey).
    n : int
        Number of circles the Hough methods return (the thesis's N = 16); ``blobs``,
        ``template`` and ``cv2`` return at most ``n`` (the best).
    radius_range : (float, float)
        Smallest and largest bead radius, pixels (thesis: 5 and 7 px at 640x480).
    method : {"thesis", "hough", "blobs", "template", "cv2"}
        See the module docstring.
    threshold : float, optional
        Grey threshold (image units); default IsoData (:func:`isodata_threshold`).
    min_distance : int, optional
        Smallest distance between two centres along x and along y (Hough peak suppression),
        default ``r_min`` (touching beads stay apart).
    refine : bool, optional
        Sub-pixel refinement (:func:`refine_centers`); default off for ``thesis``, on otherwise.
    min_circularity : float
        ``blobs``: regions less round than this (``4 pi area / perimeter^2``) are split by the
        Hough transform.
    min_contrast : float
        ``template``: smallest disc-minus-ring contrast of a bead, grey levels (0-255); the
        threshold used is the larger of this and 30 % of the median contrast of the ``n``
        strongest peaks.
    boxes : array_like of int, shape (B, 4), optional
        ``template``: look for beads only inside these boxes ``(x0, y0, x1, y1)``, pixels, end
        exclusive (e.g. around the bright parts of the photo); default everywhere.
    coarse : bool
        ``template`` without ``boxes``: find the contrast map's peaks at half resolution, then
        climb the full-resolution contrast from each to its maximum (:func:`_template_coarse`:
        the contrast map costs ~4x less; the same beads on the puppet benchmark's photos).
    prepared : TemplateInputs, optional
        ``template``: :func:`prepare_template` of this ``image`` with this ``radius_range``
        and ``coarse`` (made e.g. on another thread); the same circles as without it.

    Returns
    -------
    Circles
        Sorted by score, best first.
    """
    img = _as_image(image)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n}")
    n = int(n)
    radii = _radii(radius_range)
    r_min, r_max = float(radius_range[0]), float(radius_range[1])
    md = max(1, int(round(r_min))) if min_distance is None else int(min_distance)
    refine = (method != "thesis") if refine is None else bool(refine)
    csum = None
    if prepared is not None:
        if method != "template" or boxes is not None:
            raise ValueError("prepared inputs are for method='template' without boxes")
        if tuple(prepared.shape) != img.shape[:2] or prepared.radii != tuple(float(r) for r in radii) \
                or (coarse and prepared.coarse_map is None and min(img.shape[:2]) >= 8):
            raise ValueError(f"prepared inputs are for a {prepared.shape} photo, radii {prepared.radii} "
                             f"(coarse map: {prepared.coarse_map is not None}); this photo is {img.shape[:2]}, "
                             f"radii {tuple(float(r) for r in radii)}, coarse={coarse}")
        grey = prepared.grey
    elif img.ndim == 3 and img.dtype == np.uint8 and img.shape[2] == 3:
        # grey_image's own arithmetic, keeping the channel sum for the median below
        csum = _channel_sum(img)
        grey = csum.astype(np.float32)
        grey /= np.float32(3.0)
    else:
        grey = grey_image(img)
    needs_t = method in ("thesis", "hough", "blobs")  # the template and cv2 methods use no threshold
    t = (isodata_threshold(grey) if threshold is None else float(threshold)) if needs_t else np.nan
    if n == 0:
        return Circles(np.zeros((0, 2)), np.zeros(0), np.zeros(0), method, t)
    if method == "cv2":
        acc, cx, cy, rr = _cv2_hough(grey, r_min, r_max, n, md)
        t = np.nan
    elif method in ("thesis", "hough"):
        acc, cx, cy, rr = _hough(outline(grey > t), radii, n, md)
    elif method == "template":
        if coarse and boxes is None:
            acc, cx, cy, rr = _template_coarse(grey, radii, n, md, min_contrast, prepared)
        else:
            acc, cx, cy, rr = _template(grey, radii, n, md, min_contrast, boxes)
        t = np.nan
    else:
        acc, cx, cy, rr = _blobs(img, grey, t, radii, r_min, r_max, n, md, min_circularity)
    centers = np.stack([cx, cy], axis=1) if len(cx) else np.zeros((0, 2))
    if refine and len(centers):
        med = prepared.median if prepared is not None else _median_grey(img, csum)
        centers = refine_centers(grey, centers, rr, background=med)
    order = np.argsort(-acc, kind="stable")
    return Circles(centers[order], np.asarray(rr, float)[order], np.asarray(acc, float)[order], method, t)


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


def _disc_kernel(r: float, inner_gap: float = 1.0, ring: float = 2.0) -> np.ndarray:
    """Zero-mean matched filter: mean over a disc of radius r minus mean over the ring
    r + inner_gap .. r + inner_gap + ring (anti-aliased at 8x)."""
    R = int(np.ceil(r + inner_gap + ring))
    g = (np.arange((2 * R + 1) * _SS) + 0.5) / _SS - 0.5 - R
    d = np.hypot(g[None, :], g[:, None])
    disc = _down((d <= r).astype(np.float64), 2 * R + 1, 2 * R + 1)
    ann = _down(((d > r + inner_gap) & (d <= r + inner_gap + ring)).astype(np.float64), 2 * R + 1, 2 * R + 1)
    return (disc / disc.sum() - ann / ann.sum()).astype(np.float32)


@functools.lru_cache(maxsize=32)
def _disc_kernel_cached(r: float, scale: float = 1.0) -> np.ndarray:
    """The kernel of radius ``r`` (full-resolution pixels) for a photo shrunk by ``scale``
    (0.5: half resolution, every length halved)."""
    k = _disc_kernel(r * scale, inner_gap=scale, ring=2.0 * scale)
    k.setflags(write=False)
    return k


# DFT sizes the contrast map pads to: products of 2, 3 and 5 (fast for cv2.dft) that are
# multiples of 32, so that photos cropped to slightly different regions share a size and the
# cached kernel spectra (:func:`_kernel_spectrum`) are reused across views (on the benchmark's
# 624 bright regions: 28 sizes, 22 % more area than the tightest DFT sizes).
_DFT_SIZES = np.array(sorted({2 ** a * 3 ** b * 5 ** c for a in range(5, 14) for b in range(5) for c in range(4)
                              if 2 ** a * 3 ** b * 5 ** c <= 8192}))


def _dft_size(n: int) -> int:
    i = int(np.searchsorted(_DFT_SIZES, n))
    return int(_DFT_SIZES[i]) if i < len(_DFT_SIZES) else cv2.getOptimalDFTSize(n)


@functools.lru_cache(maxsize=96)
def _kernel_spectrum(r: float, h: int, w: int, scale: float = 1.0) -> np.ndarray:
    """cv2.dft (CCS packed) of the disc-minus-ring kernel of radius r, centred at pixel (0, 0)
    of an (h, w) periodic grid: multiplying an image's spectrum by it correlates the image
    with the (symmetric) kernel."""
    k = _disc_kernel_cached(float(r), scale)
    half = k.shape[0] // 2
    buf = np.zeros((h, w), np.float32)
    idx = np.arange(-half, half + 1)
    buf[np.ix_(idx % h, idx % w)] = k  # the kernel wrapped around (0, 0)
    spec = cv2.dft(buf)
    spec.setflags(write=False)
    return spec


def _filter_radii(sub: np.ndarray, rs: np.ndarray, pad: int, scale: float = 1.0) -> np.ndarray:
    """Correlation of ``sub`` with each radius's kernel, replicated border, shape (R, h, w).

    One forward DFT shared by all radii and cached kernel spectra: what ``cv2.filter2D`` does
    per kernel (it switches to a DFT for kernels this large), without transforming the image
    again for every radius (~2.5x faster for three radii). Equal to ``cv2.filter2D(...,
    borderType=cv2.BORDER_REPLICATE)`` to float32 rounding (~1e-5 grey levels)."""
    h, w = sub.shape
    gp = cv2.copyMakeBorder(sub, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    H, W = _dft_size(h + 2 * pad), _dft_size(w + 2 * pad)
    buf = np.zeros((H, W), np.float32)
    buf[:h + 2 * pad, :w + 2 * pad] = gp  # zeros beyond the replicated border: wrap-around stays outside
    F = cv2.dft(buf)
    out = np.empty((len(rs), h, w), np.float32)
    for i, r in enumerate(rs):
        f = cv2.idft(cv2.mulSpectrums(F, _kernel_spectrum(float(r), H, W, scale), 0),
                     flags=cv2.DFT_SCALE | cv2.DFT_REAL_OUTPUT)
        out[i] = f[pad:pad + h, pad:pad + w]
    return out


def contrast_map(grey, radii, boxes=None) -> tuple[np.ndarray, np.ndarray]:
    """Disc-minus-ring contrast of every pixel for each radius, and the best radius.

    ``contrast[y, x]`` is the mean grey over a disc of radius r at (x, y) minus the mean over
    the ring from r + 1 to r + 3 around it (a matched filter for a bright disc; zero on flat
    ground and inside wide limbs), maximised over ``radii`` (correlation with replicated
    borders, as ``cv2.filter2D(..., borderType=cv2.BORDER_REPLICATE)``, computed with one
    shared DFT).

    Parameters
    ----------
    grey : array_like, shape (H, W)
    radii : array_like, shape (R,)
    boxes : array_like of int, shape (B, 4), optional
        Boxes ``(x0, y0, x1, y1)`` (end exclusive) where beads may lie; the map is computed
        only there (exactly: each box is filtered with the grey pixels around it) and is 0
        elsewhere. Default: the whole image.

    Returns
    -------
    contrast : ndarray, shape (H, W), float32, grey units
    best_radius : ndarray, shape (H, W)
    """
    f = _contrast_stack(grey, radii, boxes)
    rs = np.atleast_1d(np.asarray(radii, float))
    return _max_over(f), rs[np.argmax(f, axis=0)]  # first radius wins ties


def _max_over(f: np.ndarray) -> np.ndarray:
    """Maximum over the first axis (pairwise ``np.maximum``: several times faster than
    ``f.max(axis=0)`` over a short first axis)."""
    c = f[0].copy()
    for fi in f[1:]:
        np.maximum(c, fi, out=c)
    return c


def _contrast_stack(grey, radii, boxes=None) -> np.ndarray:
    """The disc-minus-ring contrast of every pixel for every radius, shape (R, H, W), float32
    (0 outside ``boxes``); :func:`contrast_map` maximises it over the radii."""
    g = np.asarray(grey, np.float32)
    if g.ndim != 2:
        raise ValueError(f"grey must have shape (H, W), got {g.shape}")
    rs = np.atleast_1d(np.asarray(radii, float))
    h, w = g.shape
    pad = max(_disc_kernel_cached(float(r)).shape[0] for r in rs) // 2
    if boxes is None:
        # the whole image: replicated border outside it, as filter2D's BORDER_REPLICATE
        return _filter_radii(g, rs, pad)
    boxes = np.asarray(boxes, int).reshape(-1, 4)
    f = np.zeros((len(rs), h, w), np.float32)
    for x0, y0, x1, y1 in boxes:
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        if x1 <= x0 or y1 <= y0:
            continue
        # filter the box with the grey around it (then the values inside are exact)
        X0, Y0, X1, Y1 = max(0, x0 - pad), max(0, y0 - pad), min(w, x1 + pad), min(h, y1 + pad)
        f[:, y0:y1, x0:x1] = _filter_radii(g[Y0:Y1, X0:X1], rs, pad)[:, y0 - Y0:y1 - Y0, x0 - X0:x1 - X0]
    return f


def _local_maxima(C: np.ndarray, md: int, floor: float) -> np.ndarray:
    """Pixels ``(row, col)`` that are the maximum of their ``(2 md + 1)^2`` square and above
    ``floor``, strongest first; plateaus keep one pixel (the first in raster order).

    :func:`skimage.feature.peak_local_max` does the same with a SciPy maximum filter; the
    OpenCV dilation here is ~10x faster on these photos, and only a handful of pixels pass."""
    k = np.ones((2 * md + 1, 2 * md + 1), np.uint8)
    dil = cv2.dilate(C, k, borderType=cv2.BORDER_REPLICATE)
    rows, cols = np.nonzero((C >= dil) & (C > floor))
    if len(rows) == 0:
        return np.zeros((0, 2), int)
    val = C[rows, cols]
    order = np.lexsort((cols, rows, -val))  # strongest first, raster order among equals
    rows, cols = rows[order], cols[order]
    val = val[order]
    keep = np.ones(len(rows), bool)
    # Plateau pixels: keep the first of equal maxima within md. Two maxima within md of each
    # other are each >= the other, so only pixels sharing their value with another one can be
    # dropped: the loop runs over those few only (over all of them it cost ~1 ms per photo).
    _, inv, counts = np.unique(val, return_inverse=True, return_counts=True)
    tied = np.flatnonzero(counts[inv] > 1)
    for a, i in enumerate(tied):
        if keep[i]:
            rest = tied[a + 1:]
            near = (val[rest] == val[i]) & (np.abs(rows[rest] - rows[i]) <= md) & (np.abs(cols[rest] - cols[i]) <= md)
            keep[rest[near]] = False
    return np.stack([rows[keep], cols[keep]], axis=1)


def _template(grey, radii, n, md, min_contrast, boxes=None):
    f = _contrast_stack(grey, radii, boxes)
    C = _max_over(f)
    peaks = _local_maxima(C, md, max(float(min_contrast) / 3, 1e-6))
    if len(peaks) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
    val = C[peaks[:, 0], peaks[:, 1]].astype(float)
    # Automatic acceptance: at least min_contrast and 30 % of the typical strong bead (the
    # median of the n best peaks), so a bright scene does not drown in limb-edge peaks.
    top = np.sort(val)[::-1][:n]
    thr = max(float(min_contrast), 0.3 * float(np.median(top)))
    keep = np.flatnonzero(val >= thr)
    keep = keep[np.argsort(-val[keep], kind="stable")][:n]
    y, x = peaks[keep, 0], peaks[keep, 1]
    best_r = np.asarray(radii, float)[np.argmax(f[:, y, x], axis=0)]  # first radius wins ties
    return val[keep], x.astype(float), y.astype(float), best_r


@functools.lru_cache(maxsize=8)
def _kernel_stack(rs: tuple) -> np.ndarray:
    """The full-resolution kernels of ``rs`` as one (R, K, K) float32 stack (smaller ones
    zero-padded to the largest, centred)."""
    ks = [_disc_kernel_cached(float(r)) for r in rs]
    K = max(k.shape[0] for k in ks)
    out = np.zeros((len(ks), K, K), np.float32)
    for i, k in enumerate(ks):
        o = (K - k.shape[0]) // 2
        out[i, o:o + k.shape[0], o:o + k.shape[0]] = k
    out.setflags(write=False)
    return out


def _contrast_at(gp: np.ndarray, pad: int, rows: np.ndarray, cols: np.ndarray, kst: np.ndarray) -> np.ndarray:
    """Disc-minus-ring contrast at pixels ``(rows, cols)`` for every radius, shape (m, R): the
    values :func:`_contrast_stack` has there (to float32 rounding), from the grey image padded
    by ``pad`` with its replicated border (``gp``), each pixel's window times the kernels."""
    K = kst.shape[1]
    o = pad - K // 2
    # the windows as a zero-copy view (one K x K window per pixel), gathered per pixel: ~7x
    # faster than indexing the pixels of every window one by one (as_strided directly:
    # sliding_window_view's checks cost more than the gather, four calls per photo)
    g = np.ascontiguousarray(gp)
    views = np.lib.stride_tricks.as_strided(g, (g.shape[0] - K + 1, g.shape[1] - K + 1, K, K), g.strides * 2,
                                            writeable=False)
    win = views[rows + o, cols + o]
    # np.einsum, not ``@``: a multi-threaded BLAS call on a matrix this small costs 20x more
    # on a busy machine (measured: 5.5 vs 0.3 ms per photo)
    return np.einsum("ij,kj->ik", win.reshape(len(rows), -1), kst.reshape(len(kst), -1))


#: neighbours of a pixel, (drow, dcol), raster order; index 4 is the pixel itself
_NEIGHBOURS = np.array([(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])


def _coarse_map(g: np.ndarray, rs: np.ndarray) -> np.ndarray:
    """:func:`_template_coarse`'s half-resolution contrast map of a float32 grey image (8 px or more)."""
    h, w = g.shape
    gh = cv2.resize(g[:h // 2 * 2, :w // 2 * 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    pad_h = max(_disc_kernel_cached(float(r), 0.5).shape[0] for r in rs) // 2
    return _max_over(_filter_radii(gh, rs, pad_h, 0.5))


def _template_coarse(grey, radii, n, md, min_contrast, prepared: TemplateInputs | None = None):
    """:func:`_template` with the contrast map computed at half resolution.

    The map (four DFTs per photo, the detector's main cost) is computed on the photo shrunk
    2x (:func:`cv2.resize`, ``INTER_AREA``: 2x2 block means) with the kernels shrunk alike,
    ~4x fewer pixels. Its local maxima (a generous floor, half the full-resolution one) are
    the starts; each climbs the *full-resolution* contrast (evaluated only at the pixels it
    visits, :func:`_contrast_at`) to a pixel no 8-neighbour beats. Those are suppressed as
    :func:`_local_maxima` does (a peak within ``md`` of a stronger one goes), so the scores,
    radii and whole-pixel centres are the full-resolution map's wherever a half-resolution
    peak leads to its maximum (on the benchmark's photos: see ``docs/puppet-detection.md``)."""
    g = np.asarray(grey, np.float32)
    h, w = g.shape
    rs = np.atleast_1d(np.asarray(radii, float))
    if h < 8 or w < 8:
        return _template(g, rs, n, md, min_contrast)
    Ch = _coarse_map(g, rs) if prepared is None else prepared.coarse_map
    floor = max(float(min_contrast) / 3, 1e-6)
    starts = _local_maxima(Ch, max(1, md // 2), 0.5 * float(min_contrast))
    if len(starts) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
    kst = _kernel_stack(tuple(float(r) for r in rs))
    pad = kst.shape[1] // 2
    gp = cv2.copyMakeBorder(g, pad, pad, pad, pad, cv2.BORDER_REPLICATE) if prepared is None else prepared.padded
    # each start: the full-resolution contrast over the 4x4 pixels around its 2x2 block (all
    # starts in one gather and product), its maximum taken; where that lies on the window's
    # edge, 8-neighbour steps climb on from there
    S = 4
    r0 = np.clip(2 * starts[:, 0] - 1, 0, max(h - S, 0))
    c0 = np.clip(2 * starts[:, 1] - 1, 0, max(w - S, 0))
    S_r, S_c = min(S, h), min(S, w)
    rr = (r0[:, None, None] + np.arange(S_r)[None, :, None] + np.zeros(S_c, int)).reshape(len(starts), -1)
    cc = (c0[:, None, None] + np.arange(S_c)[None, None, :] + np.zeros((S_r, 1), int)).reshape(len(starts), -1)
    vals = _contrast_at(gp, pad, rr.ravel(), cc.ravel(), kst).max(axis=1).reshape(rr.shape)
    at = np.argmax(vals, axis=1)  # first in raster order among equals
    rows, cols = r0 + at // S_c, c0 + at % S_c
    edge = ((rows == r0) & (r0 > 0)) | ((rows == r0 + S_r - 1) & (r0 + S_r < h)) \
        | ((cols == c0) & (c0 > 0)) | ((cols == c0 + S_c - 1) & (c0 + S_c < w))
    active = np.flatnonzero(edge)
    for _ in range(2 * md + 4):
        if len(active) == 0:
            break  # a climb longer than the start's own neighbourhood is not a bead
        rr = np.clip(rows[active, None] + _NEIGHBOURS[:, 0], 0, h - 1)
        cc = np.clip(cols[active, None] + _NEIGHBOURS[:, 1], 0, w - 1)
        v = _contrast_at(gp, pad, rr.ravel(), cc.ravel(), kst).max(axis=1).reshape(len(active), 9)
        a = np.arange(len(active))
        best = np.argmax(v, axis=1)  # first (raster order) of equal maxima
        best = np.where(v[a, 4] >= v[a, best], 4, best)  # stay on a tie
        rows[active], cols[active] = rr[a, best], cc[a, best]
        active = active[best != 4]
    key = np.unique(rows * w + cols)
    rows, cols = key // w, key % w
    f = _contrast_at(gp, pad, rows, cols, kst)  # (m, R)
    val = f.max(axis=1).astype(float)
    best_r = rs[np.argmax(f, axis=1)]  # first radius wins ties
    ok = val > floor
    rows, cols, val, best_r = rows[ok], cols[ok], val[ok], best_r[ok]
    order = np.lexsort((cols, rows, -val))  # strongest first, raster order among equals
    rows, cols, val, best_r = rows[order], cols[order], val[order], best_r[order]
    near = (np.abs(rows[:, None] - rows[None]) <= md) & (np.abs(cols[:, None] - cols[None]) <= md)
    out = np.zeros(len(rows), bool)
    for i in range(len(rows)):  # non-maximum suppression within md (Chebyshev), as the dilation test
        if not out[i]:
            out |= near[i] & (np.arange(len(rows)) > i)
    keep = np.flatnonzero(~out)
    val, rows, cols, best_r = val[keep], rows[keep], cols[keep], best_r[keep]
    top = np.sort(val[:n])
    # np.median(top) (the mean of the two middle values; NaN when empty, then the floor wins)
    med = (top[(len(top) - 1) // 2] + top[len(top) // 2]) / 2 if len(top) else np.nan
    thr = max(float(min_contrast), 0.3 * float(med))
    sel = np.flatnonzero(val >= thr)[:n]
    return val[sel], cols[sel].astype(float), rows[sel].astype(float), best_r[sel]


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


# -- synthetic bead photos ---------------------------------------------------------------------
@dataclass(eq=False)
class BeadScene:
    """A drawn bead photo with its ground truth (:func:`random_bead_scene`).

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), uint8
        BGR photo.
    centers : ndarray, shape (K, 2)
        True bead centres (x, y), pixels.
    radii : ndarray, shape (K,)
        True bead radii, pixels.
    labels : ndarray of int, shape (K,)
        Index of each bead's colour in the ``colors_rgb`` that drew it.
    colors_rgb : ndarray, shape (K, 3)
        Colour each bead was drawn with (after the lighting change), sRGB [0, 1].
    occluded : ndarray of float, shape (K,)
        Fraction of each bead's disc hidden by a limb in front of it.
    gain, white_balance : float, ndarray shape (3,)
        Lighting change applied (brightness factor, RGB channel factors).
    """

    image: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    labels: np.ndarray
    colors_rgb: np.ndarray
    occluded: np.ndarray
    gain: float = 1.0
    white_balance: np.ndarray = field(default_factory=lambda: np.ones(3))


_SS = 8  # supersampling factor of the drawings


def _patch_grid(cx, cy, R, shape):
    """Supersampled sample positions (1x pixel units) of a pixel-aligned box around a disc."""
    h, w = shape
    x0, x1 = max(0, int(np.floor(cx - R)) - 1), min(w, int(np.ceil(cx + R)) + 2)
    y0, y1 = max(0, int(np.floor(cy - R)) - 1), min(h, int(np.ceil(cy + R)) + 2)
    if x1 <= x0 or y1 <= y0:
        return None
    # Sample u of the 8x grid sits at (u + 0.5) / 8 - 0.5 in 1x pixel coordinates.
    xs = x0 + (np.arange((x1 - x0) * _SS) + 0.5) / _SS - 0.5
    ys = y0 + (np.arange((y1 - y0) * _SS) + 0.5) / _SS - 0.5
    return x0, x1, y0, y1, xs[None, :], ys[:, None]


def _down(a, ny, nx):
    """Block mean of a supersampled array down to (ny, nx[, C])."""
    return a.reshape(ny, _SS, nx, _SS, *a.shape[2:]).mean(axis=(1, 3))


def _over(canvas, y0, y1, x0, x1, alpha, color_premult):
    canvas[y0:y1, x0:x1] = canvas[y0:y1, x0:x1] * (1 - alpha[..., None]) + color_premult


def _shade(d, R, ambient, specular):
    """Brightness factor of a matte sphere lit from the camera, sRGB-encoded, at distance d."""
    cos = np.sqrt(np.clip(1 - (d / R) ** 2, 0, 1))
    lin = ambient + (1 - ambient) * cos
    return lin ** (1 / 2.2), specular * np.exp(-((d / (0.3 * R)) ** 2))


def _patch_norm(R, ambient):
    """Mean shading over the central 5x5 pixels: bead colours are scaled by its inverse, so
    that the thesis's 5x5 patch measures the colour asked for."""
    g = (np.arange(5 * _SS) + 0.5) / _SS - 2.5
    d = np.hypot(g[None, :], g[:, None])
    return float(_shade(d, R, ambient, 0.0)[0].mean())


def _draw_limb(canvas, p0, p1, width, grey):
    """A flat dark-grey thick segment (a limb of the black puppet), anti-aliased at 8x."""
    h, w = canvas.shape[:2]
    lo = np.floor(np.minimum(p0, p1) - width).astype(int)
    hi = np.ceil(np.maximum(p0, p1) + width).astype(int) + 1
    x0, y0 = max(0, lo[0]), max(0, lo[1])
    x1, y1 = min(w, hi[0]), min(h, hi[1])
    if x1 <= x0 or y1 <= y0:
        return
    big = np.zeros(((y1 - y0) * _SS, (x1 - x0) * _SS), np.uint8)
    # cv2.line with 3 fractional bits, in 8x pixel units: ((p - origin + 0.5) * 8 - 0.5) * 8.
    q = [tuple(int(round(((v - o + 0.5) * _SS - 0.5) * 8)) for v, o in zip(p, (x0, y0))) for p in (p0, p1)]
    cv2.line(big, q[0], q[1], 255, thickness=max(1, int(round(width * _SS))), lineType=cv2.LINE_8, shift=3)
    a = _down(big.astype(np.float32) / 255.0, y1 - y0, x1 - x0)
    _over(canvas, y0, y1, x0, x1, a, a[..., None] * np.asarray(grey, np.float32))


def draw_beads(centers, radii, colors_rgb, size=(480, 640), limbs_behind=(), limbs_front=(),
               background: float = 0.05, ambient: float = 0.15, specular: float = 0.0) -> np.ndarray:
    """Draw shaded beads (matte spheres lit from the camera) and limbs, anti-aliased at 8x.

    Each bead's colour is scaled so that the mean over its central 5x5 pixels equals the
    colour given (how the thesis measured its reference colours). Later beads cover earlier
    ones.

    Parameters
    ----------
    centers : array_like, shape (K, 2)
        Sub-pixel centres (x, y).
    radii : array_like, shape (K,)
        Pixels.
    colors_rgb : array_like, shape (K, 3)
        sRGB in [0, 1].
    size : (int, int)
        Image height and width.
    limbs_behind, limbs_front : sequence of (p0, p1, width, grey)
        Thick segments drawn before / after the beads: end points (x, y), width in pixels, grey
        level in [0, 1].
    background : float
        Grey level of the background, [0, 1].
    ambient, specular : float
        Shading: ambient share of the lighting, strength of a white highlight at the centre.

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        Noise-free BGR image in [0, 1].
    """
    c = as_array(centers, (None, 2), "centers")
    r = as_array(radii, (len(c),), "radii")
    col = as_array(colors_rgb, (len(c), 3), "colors_rgb")
    h, w = int(size[0]), int(size[1])
    canvas = np.full((h, w, 3), background, np.float32)
    for p0, p1, width, grey in limbs_behind:
        _draw_limb(canvas, np.asarray(p0, float), np.asarray(p1, float), float(width), grey)
    for (cx, cy), R, rgb in zip(c, r, col):
        g = _patch_grid(cx, cy, R, (h, w))
        if g is None:
            continue
        x0, x1, y0, y1, xs, ys = g
        d = np.hypot(xs - cx, ys - cy)
        inside = (d <= R).astype(np.float32)
        shade, spec = _shade(d, R, ambient, specular)
        albedo = np.asarray(rgb, np.float32)[::-1] / _patch_norm(R, ambient)
        colour = np.clip(shade[..., None] * albedo + spec[..., None], 0, 1) * inside[..., None]
        ny, nx = y1 - y0, x1 - x0
        _over(canvas, y0, y1, x0, x1, _down(inside, ny, nx), _down(colour.astype(np.float32), ny, nx))
    for p0, p1, width, grey in limbs_front:
        _draw_limb(canvas, np.asarray(p0, float), np.asarray(p1, float), float(width), grey)
    return canvas


def _sensor(canvas, rng, blur, noise, jpeg):
    img = canvas
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    img = img * 255.0 + rng.normal(0.0, noise, img.shape)
    img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if jpeg:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg)])
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return img


def random_bead_scene(colors_rgb, rng=None, size=(480, 640), radius_range=(5.0, 7.0), n_limbs: int = 8,
                      n_touching: int = 2, n_occluded: int = 1, brightness=(0.8, 1.2),
                      white_balance: float = 0.05, noise: float = 3.0, jpeg: int | None = 80,
                      blur: float = 0.5, specular: float = 0.05, limb_grey=(0.05, 0.14),
                      n_beads: int | None = None, margin: float = 20.0) -> BeadScene:
    """A random puppet-like photo: one bead per colour on dark limbs, with known truth.

    With ``n_beads`` only a random subset of the colours is drawn (markers hidden behind the
    puppet in a turntable view); ``labels`` says which.

    Dark grey limbs (thick segments, grey ``limb_grey``) criss-cross the frame; each bead sits on a
    limb; ``n_touching`` beads are placed touching (or overlapping by up to 1 px) another one;
    ``n_occluded`` beads are partly covered (10-35 % of the disc) by a limb in front. The
    light changes by a random brightness factor and a random per-channel white-balance factor
    (1 +- ``white_balance``); the sensor blurs, adds Gaussian noise and saves a JPEG.

    Parameters
    ----------
    colors_rgb : array_like, shape (K, 3)
        Bead colours at nominal light, sRGB [0, 1] (e.g. ``Palette.from_markerset(MarkerSet.puppet()).rgb``).
    rng : numpy.random.Generator or int, optional
    size : (int, int)
        Height, width.
    radius_range : (float, float)
        Bead radii are drawn uniformly from it, pixels.
    n_limbs, n_touching, n_occluded : int
    brightness : (float, float)
        Range of the brightness factor.
    white_balance : float
        Largest relative change of the red and blue channels.
    noise : float
        Standard deviation of the sensor noise, 8-bit units.
    jpeg : int or None
        JPEG quality, or None for no compression.
    blur : float
        Optical blur, Gaussian sigma in pixels.
    specular : float
        White highlight at the bead centre (flat paint: small).
    limb_grey : (float, float)
        Range of the limbs' grey level, [0, 1] (flat black paint under the LEDs: dark grey).
    n_beads : int, optional
        Number of beads drawn (a random subset of the colours); default all.
    margin : float
        Smallest distance of a bead centre from the image border, pixels.

    Returns
    -------
    BeadScene
    """
    rng = as_rng(rng)
    palette = as_array(colors_rgb, (None, 3), "colors_rgb")
    if n_beads is None:
        labels = np.arange(len(palette))
    else:
        if not 0 <= n_beads <= len(palette):
            raise ValueError(f"n_beads must lie in [0, {len(palette)}], got {n_beads}")
        labels = np.sort(rng.choice(len(palette), size=int(n_beads), replace=False))
    base = palette[labels]
    k = len(base)
    h, w = int(size[0]), int(size[1])
    r = rng.uniform(radius_range[0], radius_range[1], k)
    limbs = []
    for _ in range(max(1, n_limbs)):
        p0 = rng.uniform([margin, margin], [w - margin, h - margin])
        ang = rng.uniform(0, np.pi)
        length = rng.uniform(60, 220)
        p1 = np.clip(p0 + length * np.array([np.cos(ang), np.sin(ang)]), 0, [w - 1, h - 1])
        limbs.append((p0, p1, rng.uniform(8, 18), rng.uniform(*limb_grey)))
    centers = np.zeros((k, 2))
    touching = set()
    if k > 1:
        touching = set(rng.choice(np.arange(1, k), size=min(n_touching, k - 1), replace=False).tolist())
    for i in range(k):
        for _attempt in range(500):
            if i in touching:
                j = int(rng.integers(i))
                a = rng.uniform(0, 2 * np.pi)
                p = centers[j] + (r[i] + r[j] + rng.uniform(-1.0, 0.5)) * np.array([np.cos(a), np.sin(a)])
                others = np.delete(np.arange(i), j)
            else:
                p0, p1, width, _ = limbs[int(rng.integers(len(limbs)))]
                t = rng.uniform(0, 1)
                dvec = (p1 - p0) / max(np.linalg.norm(p1 - p0), 1e-9)
                p = p0 + t * (p1 - p0) + rng.uniform(-0.3, 0.3) * width * np.array([-dvec[1], dvec[0]])
                others = np.arange(i)
            if not (margin <= p[0] <= w - 1 - margin and margin <= p[1] <= h - 1 - margin):
                continue
            if len(others) and np.min(np.hypot(*(centers[others] - p).T) - r[others] - r[i]) < 4.0:
                continue
            centers[i] = p
            break
        else:
            centers[i] = rng.uniform([margin, margin], [w - 1 - margin, h - 1 - margin])
    gain = float(rng.uniform(*brightness))
    wb = np.array([1 + rng.uniform(-white_balance, white_balance), 1.0, 1 + rng.uniform(-white_balance, white_balance)])
    colors = np.clip(base * gain * wb, 0, 1)
    front = []
    occluded = np.zeros(k)
    candidates = [i for i in range(k) if i not in touching]
    for i in rng.permutation(candidates)[:n_occluded]:
        a = rng.uniform(0, 2 * np.pi)
        n_vec = np.array([np.cos(a), np.sin(a)])
        width = rng.uniform(8, 14)
        frac = rng.uniform(0.1, 0.35)
        # Distance from the centre to the limb's edge that covers ``frac`` of the disc.
        u = np.linspace(-1, 1, 2001)
        seg = np.cumsum(np.sqrt(1 - u**2))[::-1] / np.sqrt(1 - u**2).sum()
        hdist = u[np.argmin(np.abs(seg - frac))] * r[i]
        mid = centers[i] + (hdist + width / 2) * n_vec
        t_vec = np.array([-n_vec[1], n_vec[0]])
        front.append((mid - 40 * t_vec, mid + 40 * t_vec, width, rng.uniform(*limb_grey)))
    if front:
        # Hidden share of every disc (a front limb may cover more than the bead it was made for).
        g = (np.arange(16) + 0.5) / 16 * 2 - 1
        gx, gy = np.meshgrid(g, g)
        disc = np.stack([gx[gx**2 + gy**2 <= 1], gy[gx**2 + gy**2 <= 1]], axis=1)
        for i in range(k):
            pts = centers[i] + r[i] * disc
            hidden = np.zeros(len(pts), bool)
            for p0, p1, width, _ in front:
                v = p1 - p0
                t = np.clip((pts - p0) @ v / (v @ v), 0, 1)
                hidden |= np.hypot(*(pts - p0 - t[:, None] * v).T) <= width / 2
            occluded[i] = hidden.mean()
    canvas = draw_beads(centers, r, colors, (h, w), limbs, front, background=float(rng.uniform(0.02, 0.07)),
                        specular=specular)
    img = _sensor(canvas, rng, blur, noise, jpeg)
    return BeadScene(img, centers, r, labels, colors, occluded, gain, wb)
