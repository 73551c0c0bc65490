"""The detector (:func:`find_circles`): bead candidates by one of the methods, refined, as
:class:`Circles`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stillcap.detect.circles._refine import refine_bead_centers
from stillcap.detect.circles._template import TemplateInputs, _template, _template_coarse
from stillcap.detect.circles._thesis import (_as_image, _blobs, _channel_sum, _cv2_hough, _hough, _median_grey,
                                             _radii, grey_image, isodata_threshold, outline)

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
        See :mod:`stillcap.detect.circles`.
    threshold : float, optional
        Grey threshold (image units); default IsoData (:func:`isodata_threshold`).
    min_distance : int, optional
        Smallest distance between two centres along x and along y (Hough peak suppression),
        default ``r_min`` (touching beads stay apart).
    refine : bool, optional
        Sub-pixel refinement (:func:`refine_bead_centers`); default off for ``thesis``, on otherwise.
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
        centers = refine_bead_centers(grey, centers, rr, background=med)
    order = np.argsort(-acc, kind="stable")
    return Circles(centers[order], np.asarray(rr, float)[order], np.asarray(acc, float)[order], method, t)
