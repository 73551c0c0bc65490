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
4. **Refinement** (:func:`refine_ball_centers`): a circular Hough transform of known radius (a 2D
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

Where it is:

- :mod:`._types`: :class:`BallFlag`, :class:`BallDetections`, :class:`RefinedCenters`;
- :mod:`._foreground`: step 1, :func:`foreground_mask` (robust levels, thresholds, opening);
- :mod:`._silhouettes`: step 2, :func:`detect_balls` (contours, hull, ellipse, merged
  silhouettes split);
- :mod:`._arcs`: step 2 for crescents (the circle through the outer limb; thin, faint rims) and
  balls cut by the frame edge (the in-frame limb), with their centre uncertainty;
- :mod:`._outline`: step 3, :func:`sphere_outline_px`;
- :mod:`._hough`: the known-radius Hough transform (templates, scores, grid peaks);
- :mod:`._shading`: step 4b, the lit-sphere shading model of a partly lit ball;
- :mod:`._refine`: step 4, :func:`refine_ball_centers`.
"""

from stillcap.detect.ball._foreground import foreground_mask
from stillcap.detect.ball._outline import sphere_outline_px
from stillcap.detect.ball._refine import refine_ball_centers
from stillcap.detect.ball._silhouettes import detect_balls
from stillcap.detect.ball._types import BallDetections, BallFlag, RefinedCenters

__all__ = [
    "BallFlag", "BallDetections", "RefinedCenters",
    "foreground_mask", "detect_balls", "refine_ball_centers", "sphere_outline_px",
]
