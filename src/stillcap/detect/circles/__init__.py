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
    centroid of the disc around the Hough centre, iterated; see :func:`refine_bead_centers`).
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

Where it is:

- :mod:`._find`: :func:`find_circles`, :class:`Circles`, :data:`METHODS`;
- :mod:`._thesis`: the thesis's steps (:func:`grey_image`, :func:`isodata_threshold`,
  :func:`outline`, the circular Hough transform) and the ``blobs`` and ``cv2`` methods;
- :mod:`._template`: the ``template`` method (:func:`contrast_map`, :func:`prepare_template`,
  :class:`TemplateInputs`);
- :mod:`._refine`: :func:`refine_bead_centers` (:func:`refine_bead_centers_views`: several photos' at once).

Synthetic bead photos with known sub-pixel centres are drawn by :mod:`stillcap.studio.beads`.
"""

from stillcap.detect.circles._find import METHODS, Circles, find_circles
from stillcap.detect.circles._refine import refine_bead_centers, refine_bead_centers_views
from stillcap.detect.circles._template import TemplateInputs, contrast_map, prepare_template
from stillcap.detect.circles._thesis import grey_image, isodata_threshold, outline

__all__ = [
    "METHODS",
    "Circles",
    "TemplateInputs",
    "contrast_map",
    "find_circles",
    "grey_image",
    "isodata_threshold",
    "outline",
    "prepare_template",
    "refine_bead_centers",
    "refine_bead_centers_views",
]
