"""Luminous coloured markers (the hand glove's) in multi-exposure photos: colour intervals,
connected regions, sub-pixel centroids, merged-blob splitting.

The glove's markers (:data:`stillcap.body.hand.HAND_COLORS`, given by the caller) are saturated spheres of four
hues far apart on a black glove in a dark room; the only other saturated things in a hand
photo are the ball's painted markers, which an ``exclude`` mask (the ball discs) removes.

Method (:func:`find_color_markers`):

1. HSV of the photo (OpenCV). A pixel is *core* for colour ``c`` if its hue is within
   ``hue_tol`` of ``c``'s reference hue, its saturation at least ``min_saturation`` and its
   value (brightness) at least ``min_brightness``.
2. Connected regions (8-connectivity, OpenCV) of each colour's core, kept if their area is
   within ``[min_area_px, max_area_px]``.
3. Centroid of each region grown by ``grow_px`` pixels (the anti-aliased rim belongs to the
   blob: its pixels keep the marker's hue but lose saturation), each pixel weighted by its
   **linear chroma** (max minus min channel after undoing the sRGB curve) above the noise
   floor, counting only pixels whose hue is this colour's. Chroma drops the grey glove and
   room; linear light makes the weights proportional to radiance, so the centroid is the
   radiance-weighted one the lit-sphere model predicts
   (:func:`stillcap.geometry.marker_points.lit_sphere_centroids`). ``docs/hand-markers.md``
   compares the weightings.
4. A region much larger than a typical one (``merged_area`` times the median area of the
   photo's regions) or elongated is two (or more) touching same-colour markers: it is split by
   a watershed on its chroma from its local maxima when it has several, flagged
   :data:`MERGED` otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage as ndi
from skimage.feature import peak_local_max
from skimage.segmentation import watershed

from stillcap.response import Response

__all__ = ["CLIPPED", "MERGED", "SPLIT", "ColorBlobs", "disc_mask", "find_color_markers"]

#: Blob flags (bit field in :attr:`ColorBlobs.flags`).
#: ``MERGED``: area or shape of two or more discs that could not be split;
#: ``SPLIT``: one part of a region split into several markers (its centroid is less sure);
#: ``CLIPPED``: touches the image border or the excluded area (its centroid may be cut).
MERGED, SPLIT, CLIPPED = 1, 2, 4


@dataclass
class ColorBlobs:
    """Coloured blobs found in one photo.

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Sub-pixel centroids (x, y), pixels.
    colours : list of str, length N
        Colour name of each blob (a key of the ``colours`` mapping used).
    areas : ndarray of int, shape (N,)
        Core pixels of the blob.
    mean_hsb : ndarray, shape (N, 3)
        Mean hue (turns, circular mean), saturation and brightness of the core, in [0, 1].
    flags : ndarray of int, shape (N,)
        Bit field of :data:`MERGED`, :data:`SPLIT`, :data:`CLIPPED`; 0 for a clean blob.
    roundness : ndarray, shape (N,)
        Ratio of the minor to the major axis of the blob's second moments (1 for a disc).
    flux : ndarray, shape (N,)
        Sum of the centroid's pixel weights (with ``"linear-chroma"``: light, up to a factor
        per colour; a partly hidden marker has less of it than its neighbours).
    colour_names : list of str
        The colour names searched for, in order (``codes`` index them).
    """

    centers: np.ndarray
    colors: list
    areas: np.ndarray
    mean_hsb: np.ndarray
    flags: np.ndarray
    roundness: np.ndarray
    flux: np.ndarray = None
    color_names: list = field(default_factory=list)

    def __post_init__(self):
        if self.flux is None:
            self.flux = np.full(len(self.centers), np.nan)

    def __len__(self) -> int:
        return len(self.centers)

    @property
    def codes(self) -> np.ndarray:
        """Colour of each blob as an index into :attr:`colour_names`, shape (N,)."""
        idx = {c: i for i, c in enumerate(self.color_names)}
        return np.array([idx[c] for c in self.colors], int)

    def select(self, keep) -> ColorBlobs:
        """The blobs where ``keep`` (bool mask or indices) holds."""
        keep = np.asarray(keep)
        if keep.dtype == bool:
            keep = np.flatnonzero(keep)
        return ColorBlobs(self.centers[keep], [self.colors[i] for i in keep], self.areas[keep],
                           self.mean_hsb[keep], self.flags[keep], self.roundness[keep], self.flux[keep],
                           list(self.color_names))

    def to_dict(self) -> dict:
        return {"centers": self.centers.tolist(), "colours": list(self.colors), "areas": self.areas.tolist(),
                "mean_hsb": self.mean_hsb.tolist(), "flags": self.flags.tolist(),
                "roundness": self.roundness.tolist(), "flux": self.flux.tolist(), "colour_names": list(self.color_names)}

    @classmethod
    def empty(cls, color_names=()) -> ColorBlobs:
        return cls(np.zeros((0, 2)), [], np.zeros(0, int), np.zeros((0, 3)), np.zeros(0, int), np.zeros(0),
                   np.zeros(0), list(color_names))


def disc_mask(shape, centers, radii, grow_px: float = 0.0) -> np.ndarray:
    """Boolean mask of the pixels inside discs (e.g. ball images to exclude).

    Parameters
    ----------
    shape : (H, W) or (H, W, C)
        Image shape (only the first two entries are used).
    centers : array_like, shape (N, 2)
        Disc centres (x, y), pixels; rows with NaN are skipped.
    radii : float or array_like, shape (N,)
        Radii, pixels.
    grow_px : float
        Added to every radius.

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    if len(shape) < 2:
        raise ValueError(f"shape must be (H, W) or (H, W, C), got {tuple(shape)}")
    h, w = int(shape[0]), int(shape[1])
    c = np.asarray(centers, float).reshape(-1, 2) if np.size(centers) else np.zeros((0, 2))
    if np.asarray(centers, float).ndim != 2 and np.size(centers):
        raise ValueError(f"centers must have shape (N, 2), got {np.shape(centers)}")
    r = np.broadcast_to(np.asarray(radii, float), (len(c),)) + float(grow_px)
    mask = np.zeros((h, w), bool)
    for (x, y), rr in zip(c, r):
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(rr)) or rr <= 0:
            continue
        x0, x1 = max(int(np.floor(x - rr)), 0), min(int(np.ceil(x + rr)) + 1, w)
        y0, y1 = max(int(np.floor(y - rr)), 0), min(int(np.ceil(y + rr)) + 1, h)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        mask[y0:y1, x0:x1] |= (xx - x) ** 2 + (yy - y) ** 2 <= rr * rr
    return mask


def _exclusion(exclude, shape) -> np.ndarray | None:
    if exclude is None:
        return None
    if isinstance(exclude, np.ndarray) and exclude.dtype == bool:
        if exclude.shape != tuple(shape):
            raise ValueError(f"exclude mask must have shape {tuple(shape)}, got {exclude.shape}")
        return exclude
    try:
        centers, radii = exclude
    except (TypeError, ValueError):
        raise ValueError("exclude must be a boolean mask of the image's shape or (centers (N, 2), radii (N,))") from None
    return disc_mask(shape, centers, radii)


def _hue_distance(h, ref) -> np.ndarray:
    d = np.abs(h - ref) % 1.0
    return np.minimum(d, 1.0 - d)


def find_color_markers(image, colors: Mapping[str, tuple], *, min_area_px: int = 4,
                        max_area_px: int | None = 5000, exclude=None, hue_tol: float = 0.06,
                        min_saturation: float = 0.5, min_brightness: float = 0.25, grow_px: int = 1,
                        weighting: str = "linear-chroma", encoding="srgb", split: bool = True,
                        merged_area: float = 1.7, merged_roundness: float = 0.6) -> ColorBlobs:
    """Find the coloured markers of ``colours`` in a photo.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), uint8
        BGR photo (OpenCV order).
    colours : mapping of str to (hue, saturation, brightness)
        Reference colours, HSB in [0, 1] (hue in turns); only the hue is used to classify, the
        saturation and brightness minima are ``min_saturation`` and ``min_brightness``.
        The glove's are :data:`stillcap.body.hand.HAND_COLORS`.
    min_area_px, max_area_px : int
        Core area limits of a region (pixels) before any split; ``max_area_px=None``: no limit.
    exclude : ndarray of bool, shape (H, W), or (centers (N, 2), radii (N,)), optional
        Pixels to ignore (e.g. ball discs from :func:`disc_mask`, so that the ball's painted
        markers are not taken): they never belong to a blob; blobs next to them are flagged
        :data:`CLIPPED`.
    hue_tol : float
        Largest hue difference from a reference hue (turns).
    min_saturation, min_brightness : float
        Core pixels' minimum HSV saturation and value, in [0, 1].
    grow_px : int
        Rim (pixels) added around a region for its centroid.
    weighting : {"linear-chroma", "chroma", "brightness", "binary"}
        Pixel weights of the centroid: chroma in linear light (default), chroma of the encoded
        values, encoded brightness (max channel), or 1 per core pixel.
    encoding : Response, or its rig-file form ("srgb", "linear", {"gamma": g}, ...)
        How the photo encodes light, the camera's response (for ``"linear-chroma"``).
    split : bool
        Split merged regions with several chroma maxima (watershed).
    merged_area, merged_roundness : float
        A region is taken for merged markers when its area exceeds ``merged_area`` times the
        median region area of the photo, or its roundness (minor / major axis) is below
        ``merged_roundness`` (with at least the median area).

    Returns
    -------
    ColorBlobs
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3) (BGR), got {img.shape}")
    if img.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got {img.dtype}")
    if not isinstance(colors, Mapping) or len(colors) == 0:
        raise ValueError("colours must be a non-empty mapping name -> (hue, saturation, brightness)")
    if weighting not in ("linear-chroma", "chroma", "brightness", "binary"):
        raise ValueError(f"weighting must be 'linear-chroma', 'chroma', 'brightness' or 'binary', got {weighting!r}")
    table = Response.from_json(encoding, "encoding").to_linear_lut()
    if not 0 < hue_tol < 0.5:
        raise ValueError(f"hue_tol must be in (0, 0.5) turns, got {hue_tol}")
    names = list(colors)
    refs = np.array([float(np.asarray(colors[n], float).reshape(-1)[0]) for n in names]) % 1.0
    h_img, w_img = img.shape[:2]
    excl = _exclusion(exclude, (h_img, w_img))

    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV_FULL)  # uint8, hue in 256ths of a turn
    # hue -> 1 + nearest reference colour (0 beyond hue_tol) as a 256-entry table: one lookup
    # per pixel instead of a distance per pixel and colour
    hue_dist = np.stack([_hue_distance(np.arange(256) / 256.0, r) for r in refs])
    lut = np.where(hue_dist.min(axis=0) <= hue_tol, hue_dist.argmin(axis=0) + 1, 0).astype(np.uint8)
    cls_full = cv2.LUT(hsv[..., 0].copy(), lut)
    bright_full = cv2.inRange(hsv, (0, int(np.ceil(min_saturation * 255)), int(np.ceil(min_brightness * 255))),
                              (255, 255, 255))
    if excl is not None:
        cls_full[excl] = 0
    union = cv2.bitwise_and(bright_full, cv2.compare(cls_full, 0, cv2.CMP_GT))
    if not union.any():
        return ColorBlobs.empty(names)
    # everything below works on the bounding box of the candidate pixels (a hand photo's
    # markers fill a fraction of it), with a margin for the grown rims
    bx, by, bw, bh = cv2.boundingRect(union)
    m = int(grow_px) + 2
    X0, Y0, X1, Y1 = max(bx - m, 0), max(by - m, 0), min(bx + bw + m, w_img), min(by + bh + m, h_img)
    crop = img[Y0:Y1, X0:X1]
    cls = cls_full[Y0:Y1, X0:X1].astype(np.int16) - 1
    hue8, sat8, val8 = (hsv[Y0:Y1, X0:X1, k] for k in range(3))
    excl_c = None if excl is None else excl[Y0:Y1, X0:X1]
    hi = cv2.max(cv2.max(crop[..., 0], crop[..., 1]), crop[..., 2])
    lo = cv2.min(cv2.min(crop[..., 0], crop[..., 1]), crop[..., 2])
    if weighting == "linear-chroma":
        # the decoding curve is monotonic, so max and min commute with it
        wimg = table[hi] - table[lo]
    elif weighting == "chroma":
        wimg = (hi.astype(np.float32) - lo) / 255.0
    elif weighting == "brightness":
        wimg = hi.astype(np.float32) / 255.0
    else:
        wimg = None
    if wimg is not None:
        # noise floor: the median chroma/brightness of the (mostly dark, grey) photo
        sub = img[::8, ::8]
        if weighting == "brightness":
            floor = float(np.median(sub.max(axis=2))) / 255.0
        else:
            t = table if weighting == "linear-chroma" else np.arange(256, dtype=np.float32) / 255.0
            floor = float(np.median(t[sub.max(axis=2)] - t[sub.min(axis=2)]))
    h_c, w_c = cls.shape

    # one labelling of all colours' core pixels; a component holding several colours (touching
    # markers of different colours) is labelled again per colour in its window
    g = int(grow_px)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(union[Y0:Y1, X0:X1], connectivity=8)
    regions = []  # (colour index, x, y, w, h, area, core mask of the window (h, w))
    for lab in range(1, n):
        x, y, w, h, area = stats[lab]
        if area < min_area_px:
            continue
        win = labels[y:y + h, x:x + w] == lab
        cw = cls[y:y + h, x:x + w]
        present = np.unique(cw[win])
        if len(present) == 1:
            regions.append((int(present[0]), x, y, w, h, int(area), win))
            continue
        for ci in present:
            k, sub, st, _ = cv2.connectedComponentsWithStats((win & (cw == ci)).view(np.uint8), connectivity=8)
            for j in range(1, k):
                sx, sy, sw, sh, sa = st[j]
                regions.append((int(ci), x + sx, y + sy, sw, sh, int(sa), sub[sy:sy + sh, sx:sx + sw] == j))
    regions = [r for r in regions if r[5] >= min_area_px and (max_area_px is None or r[5] <= max_area_px)]
    if not regions:
        return ColorBlobs.empty(names)
    median_area = float(np.median([r[5] for r in regions]))

    out_c, out_col, out_area, out_hsb, out_flag, out_round, out_flux = [], [], [], [], [], [], []
    for ci, x, y, w, h, area, win in regions:
        x0, y0 = max(x - g - 1, 0), max(y - g - 1, 0)
        x1, y1 = min(x + w + g + 1, w_c), min(y + h + g + 1, h_c)
        core = np.zeros((y1 - y0, x1 - x0), bool)
        core[y - y0:y - y0 + h, x - x0:x - x0 + w] = win
        flag = 0
        if x + X0 == 0 or y + Y0 == 0 or x + w + X0 == w_img or y + h + Y0 == h_img:
            flag |= CLIPPED
        if excl_c is not None and np.any(_dilate(core, g + 1) & excl_c[y0:y1, x0:x1]):
            flag |= CLIPPED
        hue_c = cls[y0:y1, x0:x1] == ci
        weights = np.ones(core.shape, np.float32) if wimg is None else np.clip(wimg[y0:y1, x0:x1] - floor, 0, None)
        own = hue_c
        yy, xx = np.mgrid[y0:y1, x0:x1]
        rnd = _roundness(core, xx, yy)
        parts = [core]
        if area > merged_area * median_area or (rnd < merged_roundness and area >= median_area):
            parts = _split(core, weights if wimg is not None else own.astype(np.float32),
                           median_area) if split else [core]
            flag |= SPLIT if len(parts) > 1 else MERGED
        for part in parts:
            if g > 0 and wimg is not None:
                grown = _dilate(part, g) & own
                if len(parts) > 1:  # the rim of a split part stops at the other parts
                    others = core & ~part
                    grown &= ~others
            else:
                grown = part
            wt = np.where(grown, weights, 0.0) if wimg is not None else part.astype(np.float32)
            s = float(wt.sum())
            if s <= 0:
                continue
            out_c.append(((wt * xx).sum() / s + X0, (wt * yy).sum() / s + Y0))
            out_col.append(names[ci])
            out_area.append(int(part.sum()))
            out_flux.append(s)
            hp = hue8[y0:y1, x0:x1][part] / 256.0
            ang = 2 * np.pi * hp
            mh = (np.arctan2(np.sin(ang).mean(), np.cos(ang).mean()) / (2 * np.pi)) % 1.0
            out_hsb.append((mh, float(sat8[y0:y1, x0:x1][part].mean()) / 255, float(val8[y0:y1, x0:x1][part].mean()) / 255))
            out_flag.append(flag)
            out_round.append(_roundness(part, xx, yy) if len(parts) > 1 else rnd)
    if not out_c:
        return ColorBlobs.empty(names)
    return ColorBlobs(np.array(out_c, float), out_col, np.array(out_area, int), np.array(out_hsb, float),
                       np.array(out_flag, int), np.array(out_round, float), np.array(out_flux, float), names)


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def _dilate(mask: np.ndarray, iterations: int) -> np.ndarray:
    """Grow a boolean mask by ``iterations`` 4-connected steps (OpenCV; scipy's is slower on
    hundreds of small windows)."""
    return cv2.dilate(mask.view(np.uint8), _CROSS, iterations=int(iterations)).astype(bool)


def _roundness(mask: np.ndarray, xx: np.ndarray, yy: np.ndarray) -> float:
    """Minor over major axis of the region's second moments (1 = disc)."""
    x, y = xx[mask].astype(float), yy[mask].astype(float)
    if len(x) < 3:
        return 1.0
    cov = np.cov(np.stack([x, y])) + np.eye(2) / 12.0  # a pixel's own spread
    ev = np.linalg.eigvalsh(cov)
    return float(np.sqrt(max(ev[0], 0.0) / ev[1]))


def _split(core: np.ndarray, weights: np.ndarray, median_area: float) -> list:
    """Parts of a merged region: watershed of its (smoothed) weights from their local maxima,
    at least about a marker radius apart. One part (the region) if there is a single maximum."""
    radius = max(np.sqrt(median_area / np.pi), 1.0)
    smooth = ndi.gaussian_filter(np.where(core, weights, 0.0).astype(float), max(radius / 3, 0.7))
    peaks = peak_local_max(smooth, min_distance=max(int(round(radius * 0.8)), 1), labels=core.astype(int),
                           exclude_border=False)
    if len(peaks) < 2:
        return [core]
    markers = np.zeros(core.shape, int)
    markers[tuple(peaks.T)] = np.arange(1, len(peaks) + 1)
    lab = watershed(-smooth, markers, mask=core)
    parts = [lab == k for k in range(1, len(peaks) + 1)]
    return [p for p in parts if p.sum() >= 0.25 * median_area] or [core]
