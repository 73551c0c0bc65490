"""Ball images of a stereo pair -> 3D ball centres (the seed's steps 3-5, SPEC J1 "Ball positions").

Per photo the detector (:mod:`stillcap.detect.ball`) finds silhouettes; here the ellipse centres
are matched by epipolar geometry and triangulated, the known-radius outline of each approximate
3D centre is projected into both views, the image centres are refined against it
(:func:`stillcap.detect.ball.refine_ball_centers`) and triangulated again.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from stillcap.camera import Camera
from stillcap.detect.ball import (BallDetections, BallFlag, RefinedCenters, detect_balls, refine_ball_centers,
                                  sphere_outline_px)
from stillcap.detect.ball._foreground import _check_image
from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import triangulate

__all__ = ["StereoBalls", "ball_centers_stereo"]


@dataclass
class StereoBalls:
    """Result of :func:`ball_centers_stereo`: matched ball images of a stereo pair.

    Attributes
    ----------
    points_3d : ndarray, shape (K, 3)
        Final 3D ball centres (world frame, metres) from the refined image centres.
    points_3d_initial : ndarray, shape (K, 3)
        3D centres triangulated from the ellipse centres (step 3).
    centers_a, centers_b : ndarray, shape (K, 2)
        Refined centres in raw (distorted) pixels of camera a and b.
    centers_a_undistorted, centers_b_undistorted : ndarray, shape (K, 2)
        The same as ideal pinhole pixels (``Camera.undistort_points``).
    radius_px : ndarray, shape (K, 2)
        Projected ball radius in camera a and b (pixels).
    pairs : ndarray of int, shape (K, 2)
        Index of each match in ``detections_a`` and ``detections_b``.
    epipolar_px : ndarray, shape (K,)
        Epipolar distance of the matched ellipse centres.
    reproj_error_px : ndarray, shape (K,)
        RMS reprojection error of the final 3D centres.
    flags : ndarray of int, shape (K,)
        :class:`BallFlag` bits of both views, OR-ed.
    detections_a, detections_b : BallDetections
        All detections in each photo (with refined centres where matched).
    """

    points_3d: np.ndarray
    points_3d_initial: np.ndarray
    centers_a: np.ndarray
    centers_b: np.ndarray
    centers_a_undistorted: np.ndarray
    centers_b_undistorted: np.ndarray
    radius_px: np.ndarray
    pairs: np.ndarray
    epipolar_px: np.ndarray
    reproj_error_px: np.ndarray
    flags: np.ndarray
    detections_a: BallDetections
    detections_b: BallDetections

    def __len__(self) -> int:
        return len(self.points_3d)

    @property
    def ok(self) -> np.ndarray:
        """Matches whose centres were refined in both views and triangulated, shape (K,) bool."""
        return ((self.flags & int(BallFlag.REFINE_FAILED)) == 0) & np.all(np.isfinite(self.points_3d), axis=1)


# --------------------------------------------------------------------------------------------
# steps 3-5 for a stereo pair
# --------------------------------------------------------------------------------------------
def ball_centers_stereo(cam_a: Camera, img_a, cam_b: Camera, img_b, ball_radius_m: float,
                        background_a=None, background_b=None, max_epipolar_px: float | None = None,
                        iterations: int = 2, size_tolerance: float = 0.35, shading: bool = True,
                        **detect_kwargs) -> StereoBalls:
    """Ball centres of a stereo pair of multi-exposure photos (steps 1-5 of SPEC J1).

    Parameters
    ----------
    cam_a, cam_b : Camera
        Calibrated cameras (with distortion) of the pair; each photo is linearised through its
        camera's ``response`` for the refinement.
    img_a, img_b : ndarray, shape (H, W, 3)
        Their raw photos (BGR ``uint8``).
    ball_radius_m : float
        Ball radius in metres (baseball: 0.0737 / 2).
    background_a, background_b : ndarray, optional
        Photos of the empty scene (default: dark-room model).
    max_epipolar_px : float, optional
        Largest epipolar distance of matched ellipse centres. Default: half the median ellipse
        radius, at least 3 px (the ellipse centre of a half moon is off by up to ~0.4 r towards
        the light, differently in the two views).
    iterations : int
        Refinement rounds: each projects the outlines from the latest 3D centres, refines the
        image centres and triangulates them again (1 is the seed's procedure; a 2nd round
        starts from the refined centres with a small search window).
    size_tolerance : float
        Relative difference between the ellipse's semi-major axis and the projected radius above
        which a match is flagged ``SIZE_MISMATCH`` (a wrong match triangulates at a wrong depth).
    shading : bool
        Correct the last round's centres for the shading of a lit sphere
        (:func:`refine_ball_centers`' ``shading``), in both views of every match where either
        silhouette is flagged ``PARTIAL`` (a correction in one view only moves the depth).
    **detect_kwargs
        Passed to :func:`detect_balls` (``min_area``, ``threshold``, ...).

    Returns
    -------
    StereoBalls
    """
    if not isinstance(cam_a, Camera) or not isinstance(cam_b, Camera):
        raise ValueError("cam_a and cam_b must be stillcap Camera objects")
    if not (np.isfinite(ball_radius_m) and ball_radius_m > 0):
        raise ValueError(f"ball_radius_m must be a positive number of metres, got {ball_radius_m}")
    if iterations < 1:
        raise ValueError(f"iterations must be at least 1, got {iterations}")
    for cam, img, nm in ((cam_a, img_a, "img_a"), (cam_b, img_b, "img_b")):
        im = _check_image(img, nm)
        if im.shape[:2] != (cam.image_size[1], cam.image_size[0]):
            raise ValueError(f"{nm} is {im.shape[1]}x{im.shape[0]} px, camera {cam.name!r} is "
                             f"{cam.image_size[0]}x{cam.image_size[1]} px")
    det_a = detect_balls(img_a, background_a, **detect_kwargs)
    det_b = detect_balls(img_b, background_b, **detect_kwargs)
    if max_epipolar_px is None:
        rr = np.concatenate([det_a.radii_px, det_b.radii_px])
        max_epipolar_px = max(3.0, 0.5 * float(np.median(rr))) if len(rr) else 3.0
    m = match_epipolar(cam_a, cam_b, det_a.ellipse_centers, det_b.ellipse_centers, max_px=max_epipolar_px)
    K = len(m.pairs)
    if K == 0:
        z3, z2 = np.zeros((0, 3)), np.zeros((0, 2))
        return StereoBalls(z3, z3.copy(), z2, z2.copy(), z2.copy(), z2.copy(), z2.copy(),
                           np.zeros((0, 2), int), np.zeros(0), np.zeros(0), np.zeros(0, int), det_a, det_b)
    ia, ib = m.pairs[:, 0], m.pairs[:, 1]
    xa, xb = det_a.ellipse_centers[ia], det_b.ellipse_centers[ib]
    X0 = triangulate([cam_a, cam_b], np.stack([xa, xb])).points
    X = X0
    ca, cb = xa.copy(), xb.copy()
    search_a = search_b = None
    ref_a = ref_b = None
    part = det_a.has(BallFlag.PARTIAL)[ia] | det_b.has(BallFlag.PARTIAL)[ib]
    for it in range(iterations):
        pa, oa, ra = sphere_outline_px(cam_a, X, ball_radius_m)
        pb, ob, rb = sphere_outline_px(cam_b, X, ball_radius_m)
        # the Hough template is the outline relative to the projected sphere centre, so the
        # refined point is the image of the sphere centre (not the centre of its ellipse)
        # the shading correction only in the last round: earlier rounds only place the outlines
        # (both views of a match, where either silhouette is a half moon: a correction in one view
        # only would move the triangulated depth)
        sh = part if shading and it == iterations - 1 else False
        ref_a = refine_ball_centers(img_a, ca, ra, search_a, oa - pa[:, None], background_a, start_refined=it > 0,
                                    shading=sh, response=cam_a.response)
        ref_b = refine_ball_centers(img_b, cb, rb, search_b, ob - pb[:, None], background_b, start_refined=it > 0,
                                    shading=sh, response=cam_b.response)
        ca, cb = ref_a.centers, ref_b.centers
        tri = triangulate([cam_a, cam_b], np.stack([ca, cb]))  # the last round's is the result
        X = tri.points
        search_a = np.maximum(2.0, 0.1 * ra)
        search_b = np.maximum(2.0, 0.1 * rb)
        if not np.all(np.isfinite(X)):
            X = np.where(np.isfinite(X), X, X0)
    size_bad = ((np.abs(_ellipse_radius(det_a, ia) - ref_a.radii_px) > size_tolerance * ref_a.radii_px)
                | (np.abs(_ellipse_radius(det_b, ib) - ref_b.radii_px) > size_tolerance * ref_b.radii_px))
    # write the refined centres back into the per-view detections
    det_a = _merge_refined(det_a, ia, ref_a)
    det_b = _merge_refined(det_b, ib, ref_b)
    flags = det_a.flags[ia] | det_b.flags[ib]
    flags = np.where(size_bad, flags | int(BallFlag.SIZE_MISMATCH), flags)
    return StereoBalls(
        points_3d=tri.points, points_3d_initial=X0, centers_a=ca.copy(), centers_b=cb.copy(),
        centers_a_undistorted=cam_a.undistort_points(ca), centers_b_undistorted=cam_b.undistort_points(cb),
        radius_px=np.stack([ref_a.radii_px, ref_b.radii_px], axis=1), pairs=m.pairs.copy(),
        epipolar_px=m.distance_px.copy(), reproj_error_px=tri.reproj_error_px, flags=flags.astype(int),
        detections_a=det_a, detections_b=det_b)


def _ellipse_radius(det: BallDetections, idx: np.ndarray) -> np.ndarray:
    """Semi-major axis of the detections' ellipses (split balls: their circle radius)."""
    e = det.ellipses[idx]
    r = 0.5 * np.maximum(e[:, 2], e[:, 3])
    split = det.has(BallFlag.SPLIT)[idx]
    return np.where(split, det.radii_px[idx], r)


def _merge_refined(det: BallDetections, idx: np.ndarray, ref: RefinedCenters) -> BallDetections:
    centers, radii, scores, flags = det.centers.copy(), det.radii_px.copy(), det.scores.copy(), det.flags.copy()
    centers[idx] = ref.centers
    radii[idx] = ref.radii_px
    scores[idx] = ref.scores
    flags[idx] |= ref.flags
    return replace(det, centers=centers, radii_px=radii, scores=scores, flags=flags)
