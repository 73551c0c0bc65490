"""The ``template`` detector: a disc-minus-ring matched filter (:func:`contrast_map`, one shared
DFT for all radii), its local maxima, the half-resolution search that climbs the full-resolution
contrast, and its photo-wide inputs made beforehand (:func:`prepare_template`)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from stillcap.detect.circles._thesis import _as_image, _channel_sum, _median_grey, _radii, grey_image

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


_SS = 8  # supersampling factor of the kernels' anti-aliasing


def _down(mask: np.ndarray, n: int) -> np.ndarray:
    """Share of each ``_SS x _SS`` block of a supersampled boolean mask, (n, n): the block's
    count over ``_SS ** 2`` (integer sums, so exactly the mean of its 0/1 values)."""
    starts = np.arange(0, n * _SS, _SS)
    a = np.add.reduceat(mask.view(np.uint8), starts, axis=1, dtype=np.int32)
    return np.add.reduceat(a, starts, axis=0) / (_SS * _SS)


def _disc_kernel(r: float, inner_gap: float = 1.0, ring: float = 2.0) -> np.ndarray:
    """Zero-mean matched filter: mean over a disc of radius r minus mean over the ring
    r + inner_gap .. r + inner_gap + ring (anti-aliased at 8x)."""
    R = int(np.ceil(r + inner_gap + ring))
    n = 2 * R + 1
    g = (np.arange(n * _SS) + 0.5) / _SS - 0.5 - R
    # the sub-pixels' distances from the centre: the squares and their sum are exact (g is a
    # multiple of 1/16), so this is their correctly rounded square root; np.hypot (a libm call
    # per sub-pixel, ~5x slower) differs from it in the last bit for ~1 % of the sub-pixels, and
    # never across a radius: the same kernels (tests/detect/test_template_kernels.py, radii
    # 0.5-30 px at full and half resolution)
    g2 = g * g
    d = np.sqrt(g2[None, :] + g2[:, None])
    disc = _down(d <= r, n)
    ann = _down((d > r + inner_gap) & (d <= r + inner_gap + ring), n)
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
    # (the values are sorted, so equal ones are neighbours: no np.unique, which sorts again)
    eq = val[1:] == val[:-1]
    shared = np.zeros(len(val), bool)
    shared[1:] |= eq
    shared[:-1] |= eq
    tied = np.flatnonzero(shared)
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


def _suppress(rows: np.ndarray, cols: np.ndarray, md: int) -> np.ndarray:
    """Non-maximum suppression of peaks sorted strongest first: the indices of those kept, each
    peak going when a stronger kept one lies within ``md`` (Chebyshev), as the dilation test of
    :func:`_local_maxima` does."""
    # each peak's weaker neighbours within md; only peaks that have some can suppress any
    near = np.triu((np.abs(rows[:, None] - rows[None]) <= md) & (np.abs(cols[:, None] - cols[None]) <= md), 1)
    out = np.zeros(len(rows), bool)
    for i in np.flatnonzero(near.any(axis=1)):
        if not out[i]:
            out |= near[i]
    return np.flatnonzero(~out)


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
    # integer clips as np.minimum(np.maximum(...)): the same values, ~1/3 of np.clip's cost (its
    # Python wrapper checks the bounds' types; ~60 calls per 12-photo capture)
    r0 = np.minimum(np.maximum(2 * starts[:, 0] - 1, 0), max(h - S, 0))
    c0 = np.minimum(np.maximum(2 * starts[:, 1] - 1, 0), max(w - S, 0))
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
        rr = np.minimum(np.maximum(rows[active, None] + _NEIGHBOURS[:, 0], 0), h - 1)
        cc = np.minimum(np.maximum(cols[active, None] + _NEIGHBOURS[:, 1], 0), w - 1)
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
    keep = _suppress(rows, cols, md)
    val, rows, cols, best_r = val[keep], rows[keep], cols[keep], best_r[keep]
    top = np.sort(val[:n])
    # np.median(top) (the mean of the two middle values; NaN when empty, then the floor wins)
    med = (top[(len(top) - 1) // 2] + top[len(top) // 2]) / 2 if len(top) else np.nan
    thr = max(float(min_contrast), 0.3 * float(med))
    sel = np.flatnonzero(val >= thr)[:n]
    return val[sel], cols[sel].astype(float), rows[sel].astype(float), best_r[sel]
