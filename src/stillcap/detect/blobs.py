"""Bright blobs on a dark background: connected regions, sub-pixel centroids, mean colours.

The markers of the seed's hand glove and the studio's marker balls are bright coloured regions
in an otherwise black photo: threshold, connected components (OpenCV), then an
intensity-weighted centroid per region (which is unbiased for symmetric blobs, unlike the
binary centroid that moves by whole pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from skimage.filters import threshold_otsu

#: Linear RGB albedos of the built-in single-colour marker balls (``stillcap markers``' default
#: palette; the studio paints its marker balls with them, cycled).
MARKER_BALL_COLORS = {
    "red": (0.75, 0.04, 0.03), "green": (0.05, 0.60, 0.06), "blue": (0.03, 0.10, 0.80),
    "yellow": (0.75, 0.65, 0.03), "magenta": (0.70, 0.04, 0.60), "cyan": (0.03, 0.60, 0.70),
}


@dataclass
class Blobs:
    """Blobs found in one image.

    centers : (N, 2) pixel centroids (x, y); areas : (N,) pixels; colors_bgr : (N, 3) mean
    colour in [0, 255] (BGR, OpenCV order); bboxes : (N, 4) x, y, width, height.
    """

    centers: np.ndarray
    areas: np.ndarray
    colors_bgr: np.ndarray
    bboxes: np.ndarray

    def __len__(self):
        return len(self.centers)


def find_blobs(image, threshold: float | None = None, min_area: int = 4,
               max_area: int | None = None, background=None, centroid: str = "weighted") -> Blobs:
    """Connected bright regions of ``image``.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, 3), uint8 or float
    threshold : float, optional
        Brightness (max over channels, image units) above which a pixel is foreground; default
        Otsu's threshold of the brightness, but never below 4x the median brightness (a dark
        photo with a few blobs).
    min_area, max_area : region size limits in pixels.
    background : ndarray like ``image``, optional
        A photo of the empty scene, subtracted first (colour background subtraction).
    centroid : {"weighted", "silhouette"}
        ``"weighted"``: brightness-weighted centre (best for evenly lit, e.g. retro-reflective,
        markers). ``"silhouette"``: centre of the region's outline, every pixel above the
        threshold counting fully and edge pixels in proportion to their coverage; it ignores
        shading, so a ball lit from one side is not pulled toward its bright side (use with a
        low ``threshold`` that keeps the dim limb).
    """
    if centroid not in ("weighted", "silhouette"):
        raise ValueError(f"centroid must be 'weighted' or 'silhouette', got {centroid!r}")
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
    f = img.astype(np.float32)
    if background is not None:
        bg = np.asarray(background, np.float32)
        if bg.shape != f.shape:
            raise ValueError(f"background has shape {bg.shape}, the image {f.shape}")
        f = np.clip(f - bg, 0, None)
    value = f.max(axis=2) if f.ndim == 3 else f
    if threshold is None:
        threshold = max(float(threshold_otsu(value)) if value.max() > value.min() else np.inf,
                        4.0 * float(np.median(value)) + 1.0)
    mask = (value > threshold).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    area = stats[1:, cv2.CC_STAT_AREA]
    keep = area >= min_area
    if max_area is not None:
        keep &= area <= max_area
    idx = np.flatnonzero(keep) + 1
    if len(idx) == 0:
        z = np.zeros((0, 2))
        return Blobs(z, np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 4), int))
    # Intensity-weighted centroids of all regions at once (bincount). The weights are the
    # brightness above the background over the region grown by one pixel, so that partly
    # covered edge pixels count in proportion: weighting by "brightness - threshold" inside the
    # thresholded region biases centres by ~0.05 px.
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int32)
    grown[labels > 0] = labels[labels > 0]
    ys, xs = np.nonzero(grown)
    lab = grown[ys, xs]
    bg = float(np.median(value))
    w = np.clip(value[ys, xs] - bg, 0, None)
    if centroid == "silhouette":
        w = np.minimum(w / max(threshold - bg, 1e-6), 1.0)
    sw = np.bincount(lab, w, n)
    cx = np.bincount(lab, w * xs, n) / np.where(sw > 0, sw, 1)
    cy = np.bincount(lab, w * ys, n) / np.where(sw > 0, sw, 1)
    ys, xs = np.nonzero(labels)
    lab = labels[ys, xs]
    cnt = np.bincount(lab, None, n)
    if f.ndim == 3:
        col = np.stack([np.bincount(lab, f[ys, xs, c], n) for c in range(3)], axis=1) / np.maximum(cnt, 1)[:, None]
    else:
        col = np.repeat((np.bincount(lab, value[ys, xs], n) / np.maximum(cnt, 1))[:, None], 3, axis=1)
    return Blobs(np.stack([cx[idx], cy[idx]], axis=1), area[idx - 1], col[idx], stats[idx, :4])


def classify_colors(colors_bgr, palette_bgr, names=None, max_distance: float = 40.0,
                    lightness_weight: float = 0.25, min_chroma: float = 0.0) -> np.ndarray:
    """Nearest palette colour of each blob in CIE Lab (perceptual), or ``None`` if too far.

    Lightness differences count ``lightness_weight`` times as much as chroma differences: the
    same paint looks darker or brighter with the light, its hue and chroma change much less.
    Colours with a Lab chroma below ``min_chroma`` (white, grey, black) get ``None``.

    Parameters
    ----------
    colors_bgr : (N, 3) mean blob colours, 0-255
    palette_bgr : (K, 3) reference colours, 0-255
    names : K labels (default: palette indices)
    max_distance : largest accepted Lab distance (delta E 1976)
    """
    c = np.asarray(colors_bgr, np.float32).reshape(-1, 1, 3)
    p = np.asarray(palette_bgr, np.float32).reshape(-1, 1, 3)
    if p.shape[0] == 0:
        raise ValueError("palette_bgr is empty")
    names = list(range(len(p))) if names is None else list(names)
    if len(names) != len(p):
        raise ValueError(f"{len(names)} names for {len(p)} palette colours")
    lab_c = cv2.cvtColor(c / 255.0, cv2.COLOR_BGR2Lab).reshape(-1, 3)
    lab_p = cv2.cvtColor(p / 255.0, cv2.COLOR_BGR2Lab).reshape(-1, 3)
    diff = lab_c[:, None] - lab_p[None]
    diff[..., 0] *= lightness_weight
    d = np.linalg.norm(diff, axis=2)
    best = d.argmin(axis=1) if len(d) else np.zeros(0, int)
    chroma = np.hypot(lab_c[:, 1], lab_c[:, 2])
    return np.array([names[b] if d[i, b] <= max_distance and chroma[i] >= min_chroma else None
                     for i, b in enumerate(best)], object)
