"""Ball images of a stereo pair -> 3D ball centres (the seed's steps 3-5, SPEC J1 "Ball positions").

Per photo the detector (:mod:`stillcap.detect.ball`) finds silhouettes; here the ellipse centres
are matched by epipolar geometry (where the gate admits several partners, in the flight's order
along its track in both views: :func:`_track_coordinate`) and triangulated, the known-radius
outline of each approximate 3D centre is projected into both views, the image centres are
refined against it (:func:`stillcap.detect.ball.refine_ball_centers`) and triangulated again.

Balls cut by the photo's border (``EDGE``, issue 12) are matched from their in-frame limb's
circle and their centre is that limb refitted with the projected outline's shape
(:func:`_edge_outline_fit`); each view's own centre sigma, where its centre rests on an arc
(``CRESCENT``, ``EDGE``), is :func:`view_center_sigma_px`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from stillcap.camera import Camera
from stillcap.detect.ball import (BallDetections, BallFlag, RefinedCenters, detect_balls, refine_ball_centers,
                                  sphere_outline_px)
from stillcap.detect.ball._foreground import _check_image
from stillcap.detect.ball._arcs import arc_center_sigma
from stillcap.detect.circle_fit import fit_circle
from stillcap.detect.ball._refine import _linear_max, _response_lut
from stillcap.detect.ball._shading import limb_blur_px
from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import triangulate

__all__ = ["StereoBalls", "ball_centers_stereo", "photo_blur_px", "view_center_sigma_px"]

#: lens blur (Gaussian sigma, px) assumed where a photo's own cannot be read from its ball images
DEFAULT_PSF_PX = 0.5


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
    psf_px : ndarray, shape (2,)
        Lens blur (Gaussian sigma, px) of photo a and b the shading correction used: read from
        the ball images' limbs (:func:`photo_blur_px`) or stated.
    shading_px : ndarray, shape (K, 2)
        Length of the shading correction applied to each match's centre in camera a and b (px;
        0 where none ran).
    shading_phase_rad, shading_phase_sd_rad : ndarray, shape (K, 2)
        The phase angle the shading correction used in camera a and b, and its split-half
        1-sigma (rad; NaN where none ran; ``RefinedCenters``' fields).
    shading_misfit_px : ndarray, shape (K, 2, 2)
        Per match, camera a and b: the centre shift (x, y px) a least-squares fit of the
        correction's model to the photo asks for (``RefinedCenters.shading_misfit_px``; NaN
        where none ran).
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
    psf_px: np.ndarray = None
    shading_px: np.ndarray = None
    shading_phase_rad: np.ndarray = None
    shading_phase_sd_rad: np.ndarray = None
    shading_misfit_px: np.ndarray = None

    def __post_init__(self):
        if self.psf_px is None:
            self.psf_px = np.full(2, DEFAULT_PSF_PX)
        if self.shading_px is None:
            self.shading_px = np.zeros((len(self.points_3d), 2))
        for name in ("shading_phase_rad", "shading_phase_sd_rad"):
            if getattr(self, name) is None:
                setattr(self, name, np.full((len(self.points_3d), 2), np.nan))
        if self.shading_misfit_px is None:
            self.shading_misfit_px = np.full((len(self.points_3d), 2, 2), np.nan)

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
                        psf_px="auto", **detect_kwargs) -> StereoBalls:
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
    shading : bool or "partial"
        Correct the last round's centres for the shading of a lit sphere
        (:func:`refine_ball_centers`' ``shading``): ``True`` (default) in both views of every
        match, ``"partial"`` only in both views of the matches where either silhouette is
        flagged ``PARTIAL`` (the former default; a correction in one view only moves the depth),
        ``False`` nowhere. Full discs lit at 10-30 deg from the camera are biased too: on studio
        pitches with the light beside the cameras the back pair's refined centres sat 0.1-0.25 px
        toward the light uncorrected (its positions 2.8 mm short along the flight, 0.9 mm
        corrected), and clipped (over-exposed) balls more, which the correction models
        (:func:`stillcap.detect.ball._shading._shading_bias`).
    psf_px : "auto", float or pair of floats
        Lens blur (Gaussian sigma, px) of the photos for the shading correction. ``"auto"``
        (default): each photo's own, read from up to 8 of its ball images' limbs after the first round
        (:func:`photo_blur_px`; ``DEFAULT_PSF_PX`` where it cannot be read, e.g. with one round).
        A blur of 1.5 px the correction took for 0.5 px left the back cameras' centres of a
        studio pitch 0.5-0.7 px toward the light.
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
    # EDGE balls are matched (and refined) from their in-frame limb's circle: the cut shape's
    # ellipse centre lies up to a radius inside the frame
    start_a, start_b = _start_centers(det_a), _start_centers(det_b)
    # a flight's images keep their order along its track in both views: where the gate admits
    # several partners (images along the epipolar lines), the matching keeps it
    m = match_epipolar(cam_a, cam_b, start_a, start_b, max_px=max_epipolar_px,
                       order_a=_track_coordinate(start_a), order_b=_track_coordinate(start_b))
    K = len(m.pairs)
    if K == 0:
        z3, z2 = np.zeros((0, 3)), np.zeros((0, 2))
        return StereoBalls(z3, z3.copy(), z2, z2.copy(), z2.copy(), z2.copy(), z2.copy(),
                           np.zeros((0, 2), int), np.zeros(0), np.zeros(0), np.zeros(0, int), det_a, det_b)
    ia, ib = m.pairs[:, 0], m.pairs[:, 1]
    xa, xb = start_a[ia], start_b[ib]
    X0 = triangulate([cam_a, cam_b], np.stack([xa, xb])).points
    X = X0
    ca, cb = xa.copy(), xb.copy()
    search_a = search_b = None
    ref_a = ref_b = None
    part = det_a.has(BallFlag.PARTIAL)[ia] | det_b.has(BallFlag.PARTIAL)[ib]
    psf = _psf_option(psf_px)
    for it in range(iterations):
        pa, oa, ra = sphere_outline_px(cam_a, X, ball_radius_m)
        pb, ob, rb = sphere_outline_px(cam_b, X, ball_radius_m)
        # the Hough template is the outline relative to the projected sphere centre, so the
        # refined point is the image of the sphere centre (not the centre of its ellipse)
        # the shading correction only in the last round: earlier rounds only place the outlines
        # (both views of a match, where either silhouette is a half moon: a correction in one view
        # only would move the triangulated depth)
        sh = (part if shading == "partial" else np.ones(K, bool)) if shading and it == iterations - 1 else False
        views = (_View(img_a, ca, ra, search_a, oa - pa[:, None], background_a, cam_a.response, _faint(det_a)[ia]),
                 _View(img_b, cb, rb, search_b, ob - pb[:, None], background_b, cam_b.response, _faint(det_b)[ib]))

        def refine(v, psf_v, start=None, it=it, sh=sh):
            w = views[v]
            return refine_ball_centers(w.img, w.centers, w.radii_px, w.search_px, w.outlines, w.background,
                                       start_refined=it > 0, shading=sh, response=w.response, psf_px=psf_v,
                                       crescent=w.faint, shading_start=start)
        if psf is None and it == iterations - 1 and it > 0 and shading:
            # the photos' blur from the ball images, read at the refined centres and again at
            # the shading-corrected ones (:func:`_refine_at_photo_blur`)
            (blur_a, ref_a), (blur_b, ref_b) = (_refine_at_photo_blur(v, views[v].img, views[v].centers,
                                                                      views[v].outlines, views[v].response, refine)
                                                for v in (0, 1))
            psf = np.array([blur_a, blur_b])
        else:
            ref_a, ref_b = refine(0, _psf_of(psf, 0)), refine(1, _psf_of(psf, 1))
        # EDGE views: their in-frame limb refitted with the projected outline's shape
        ref_a = _edge_outline_fit(ref_a, det_a, ia, oa - pa[:, None])
        ref_b = _edge_outline_fit(ref_b, det_b, ib, ob - pb[:, None])
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
        detections_a=det_a, detections_b=det_b,
        psf_px=np.array([_psf_of(psf, 0), _psf_of(psf, 1)]),
        shading_px=np.stack([np.linalg.norm(_corr(ref_a), axis=1), np.linalg.norm(_corr(ref_b), axis=1)], axis=1),
        shading_phase_rad=np.stack([_phase(ref_a, "shading_phase_rad"), _phase(ref_b, "shading_phase_rad")], axis=1),
        shading_phase_sd_rad=np.stack([_phase(ref_a, "shading_phase_sd_rad"), _phase(ref_b, "shading_phase_sd_rad")],
                                      axis=1),
        shading_misfit_px=np.stack([_misfit(ref_a), _misfit(ref_b)], axis=1))


def _corr(ref: RefinedCenters) -> np.ndarray:
    return ref.shading_px if ref.shading_px is not None else np.zeros((len(ref), 2))


def _misfit(ref: RefinedCenters) -> np.ndarray:
    v = getattr(ref, "shading_misfit_px", None)
    return np.asarray(v, float) if v is not None else np.full((len(ref), 2), np.nan)


def _phase(ref: RefinedCenters, name: str) -> np.ndarray:
    v = getattr(ref, name, None)
    return np.asarray(v, float) if v is not None else np.full(len(ref), np.nan)


def _psf_option(psf_px):
    """``ball_centers_stereo``'s ``psf_px`` -> None (estimate) or an array (2,) of px."""
    if isinstance(psf_px, str):
        if psf_px != "auto":
            raise ValueError(f"psf_px must be 'auto' or a blur in px, got {psf_px!r}")
        return None
    p = np.broadcast_to(np.asarray(psf_px, float), (2,)).copy()
    if not np.all(np.isfinite(p) & (p >= 0)):
        raise ValueError(f"psf_px must be >= 0 px, got {psf_px}")
    return p


def _psf_of(psf, i: int) -> float:
    if psf is None or not np.isfinite(psf[i]):
        return DEFAULT_PSF_PX
    return float(psf[i])


def photo_blur_px(image, centers, outlines, response=None, max_images: int = 8,
                  start_px: float | None = None) -> float:
    """Lens blur (Gaussian sigma, px) of a photo: the median of :func:`limb_blur_px` over up to
    ``max_images`` of its ball images (spread evenly over them), NaN when none gives one.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3)
        The photo (8-bit scale), linearised through ``response``.
    centers : array_like, shape (N, 2)
        Ball centres (raw px): the limb's model is placed there. At centres refined but not
        corrected for shading the read is too small for partly
        lit balls: the uncorrected centre sits toward the light (8 px half moons under 1.5 px of
        blur: 0.8 px), and the limb model placed there misfits the limb (drawn 8 px half moons:
        1.24 px for 1.5; the studio's back cameras 1.16-1.28 px); at the true centres it is right
        (1.53 px). ``ball_centers_stereo`` reads it again at its refinement's own shading-corrected
        centres (:func:`_refine_at_photo_blur`).
    outlines : array_like, shape (N, M, 2)
        Each ball's projected outline relative to its centre (:func:`sphere_outline_px`).
    response : Response or its rig-file form, optional
        The camera's response (default sRGB).
    start_px : float, optional
        The blur read so far (px), where each image's walk down its misfit starts
        (:func:`limb_blur_px`' ``start_px``).
    """
    img = _check_image(image)
    c = np.asarray(centers, float).reshape(-1, 2)
    off = np.asarray(outlines, float)
    ok = np.flatnonzero(np.all(np.isfinite(c), axis=1) & np.all(np.isfinite(off), axis=(1, 2)))
    if not len(ok):
        return float("nan")
    pick = ok[np.unique(np.linspace(0, len(ok) - 1, min(max_images, len(ok))).round().astype(int))]
    lut = _response_lut(response)
    H, W = img.shape[:2]
    crops = []
    for i in pick:
        ext = float(np.abs(off[i]).max()) + 6.0
        x0, y0 = int(np.floor(c[i, 0] - ext)), int(np.floor(c[i, 1] - ext))
        x1, y1 = int(np.ceil(c[i, 0] + ext)) + 1, int(np.ceil(c[i, 1] + ext)) + 1
        if x0 < 0 or y0 < 0 or x1 > W or y1 > H:
            continue  # a ball cut by the photo's edge: its limb is not all there
        crops.append((_linear_max(img[y0:y1, x0:x1], lut), c[i] - (x0, y0), off[i]))
    # each image's walk down its misfit starts at the blur read so far: ``start_px``, else the
    # first image's own read (one lens blur per photo: the other images' walks are short; the
    # same reads wherever each misfit has one minimum, :func:`limb_blur_px`)
    est = []
    for lin, cc, o in crops:
        est.append(limb_blur_px(lin, cc, o, start_px))
        if start_px is None and np.isfinite(est[-1]):
            start_px = est[-1]
    est = np.asarray(est, float)
    est = est[np.isfinite(est)]
    return float(np.median(est)) if len(est) else float("nan")


class _View(NamedTuple):
    """One view of a :func:`ball_centers_stereo` round: what its :func:`refine_ball_centers` reads."""
    img: np.ndarray
    centers: np.ndarray  # (K, 2) px, the round's start
    radii_px: np.ndarray  # (K,) projected sphere radii
    search_px: np.ndarray | None
    outlines: np.ndarray  # (K, M, 2) offsets from the projected sphere centre
    background: np.ndarray | None
    response: object
    faint: np.ndarray  # (K,) bool, crescents


#: rounds of :func:`_refine_at_photo_blur`: the blur read again at shading-corrected centres
BLUR_ROUNDS = 2


def _blur_rounds(blur: float, correct, read):
    """Up to ``BLUR_ROUNDS`` rounds of a shading correction at the blur read so far
    (``correct(blur, last) -> corrected``, ``last`` the round before's or None) and the blur
    read again at its corrected centres (``read(corrected, blur)``), until the read moves by
    less than 0.02 px. Returns the last blur read, the last correction (None if none was made)
    and the blur that correction was made at."""
    corrected, at = None, float("nan")
    for _ in range(BLUR_ROUNDS):
        if not np.isfinite(blur):
            break
        corrected, at = correct(blur, corrected), blur
        new = read(corrected, blur)
        if not np.isfinite(new):
            break
        done = abs(new - blur) < 0.02
        blur = new
        if done:
            break
    return blur, corrected, at


def _refine_at_photo_blur(v: int, img, centers, outlines, response, refine) -> tuple[float, RefinedCenters]:
    """The photo's blur (:func:`photo_blur_px`) and the shading-corrected refinement at it, for
    view ``v`` of :func:`ball_centers_stereo`'s last round (``refine(v, psf_px, start)``: its
    :func:`refine_ball_centers` at a blur, ``start`` the corrected centres of a round before).

    The blur read at refined but uncorrected centres is too small for partly lit balls
    (:func:`photo_blur_px`); read again at the refinement's own corrected centres,
    it is the one at corrected centres (:func:`_blur_rounds`; the refinement made again from its
    corrected centres at the new blur while the read moves by 0.02 px or more). The blur read's
    corrected centres are the refinement's: computed once, not twice (a separate correction
    for the blur read, removed in issue 16, corrected up to 8 ball images a photo before the
    refinement corrected all of them again)."""
    blur, ref, at = _blur_rounds(photo_blur_px(img, centers, outlines, response),
                                 lambda blur, last: refine(v, blur, None if last is None else last.centers),
                                 lambda ref, blur: photo_blur_px(img, ref.centers, outlines, response, start_px=blur))
    if ref is None or abs(blur - at) >= 0.02:
        # no blur read (the default's refinement), or the last round's read moved by 0.02 px or more
        ref = refine(v, _psf_of([blur], 0), None if ref is None else ref.centers)
    return blur, ref


def _ellipse_radius(det: BallDetections, idx: np.ndarray) -> np.ndarray:
    """Semi-major axis of the detections' ellipses (split balls: their circle radius; EDGE
    balls: their in-frame limb's circle radius, the cut shape's ellipse is smaller)."""
    e = det.ellipses[idx]
    r = 0.5 * np.maximum(e[:, 2], e[:, 3])
    split = det.has(BallFlag.SPLIT)[idx]
    r = np.where(split, det.radii_px[idx], r)
    edge = det.has(BallFlag.EDGE)[idx] & np.isfinite(det.arc_radii_px[idx])
    return np.where(edge, det.arc_radii_px[idx], r)


# --------------------------------------------------------------------------------------------
# balls cut by the frame edge (EDGE) and each view's own centre uncertainty (issue 12)
# --------------------------------------------------------------------------------------------
def _start_centers(det: BallDetections) -> np.ndarray:
    """Centres that stereo matching and the first refinement start from: the ellipse centres,
    but the in-frame limb's circle for ``EDGE`` balls."""
    edge = det.has(BallFlag.EDGE)
    return np.where(edge[:, None], det.centers, det.ellipse_centers) if len(det) else det.ellipse_centers


def _track_coordinate(centers: np.ndarray) -> np.ndarray:
    """Each ball image's place along the flight's track in one photo, shape (N,): its coordinate
    along the principal axis of the photo's ball images (a flight's images lie along a slightly
    curved track and progress along it monotonically; NaN centres: NaN)."""
    c = np.asarray(centers, float).reshape(-1, 2)
    ok = np.all(np.isfinite(c), axis=1)
    if ok.sum() < 2:
        return np.zeros(len(c))
    mid = c[ok].mean(axis=0)
    axis = np.linalg.svd(c[ok] - mid, full_matrices=False)[2][0]
    return (c - mid) @ axis


def _edge_outline_fit(ref: RefinedCenters, det: BallDetections, idx: np.ndarray, outlines) -> RefinedCenters:
    """``ref`` (refined centres of detections ``idx``) with every ``EDGE`` view's centre refitted
    to its in-frame limb (``det.arc_points``) with the shape of the ball's projected outline
    (``outlines``: (K, M, 2) offsets from the projected sphere centre, :func:`sphere_outline_px`),
    its scale free; no longer ``REFINE_FAILED`` (the limb's own self-check passed; its
    uncertainty is the view's ``center_sigma_px``).

    Neither the detector's circle nor the known-radius refinement gives a cut ball's centre:
    off axis the outline is an ellipse (13 % longer radially at 23 deg), which a circle fitted to
    the in-frame side only misplaces, inward, and the refinement's known-radius template on a
    one-sided arc moves with every offset of the blurred limb (lambertian limb darkening, the
    blur: ``d (sum u u^T)^-1 sum u``). Here the limb points are mapped through the outline's
    ellipse to a circle (its shape only, unit determinant), a circle with a free radius is fitted
    there (the silhouette's limb lies ~1-2 px outside the true one all round: the radius takes
    it), and its centre mapped back, less the outline middle's offset from the projected centre.
    Measured on the front pair with a ball cut 0.2-0.9 radii inside the left edge, 28 deg off
    axis (``tests/ball/test_stereo.py``): circle 1.4-3.0 px off, refined 0.07-0.9 px, this fit
    """ + "see docs/ball-detection.md" + """.
    """
    edge = det.has(BallFlag.EDGE)[idx]
    if not edge.any():
        return ref
    from stillcap.detect.ball._shading import _outline_affine
    from stillcap.detect.circle_fit import fit_circle

    out = np.asarray(outlines, float)
    centers = ref.centers.copy()
    fitted = np.zeros(len(idx), bool)
    for k in np.flatnonzero(edge):
        pts = det.arc_points[idx[k]]
        off = out[k]
        if pts is None or len(pts) < 6 or not np.all(np.isfinite(off)):
            continue
        mid = off.mean(axis=0)
        A = _outline_affine(off - mid)
        A = A / np.sqrt(max(float(np.linalg.det(A)), 1e-12))  # the shape only
        Ai = np.linalg.inv(A)
        q = (pts - pts.mean(axis=0)) @ Ai.T
        qc, _, rms = fit_circle(q)
        if not (np.all(np.isfinite(qc)) and rms <= 1.0):
            continue
        centers[k] = pts.mean(axis=0) + A @ qc - mid
        fitted[k] = True
    if not fitted.any():
        return ref
    flags = np.where(fitted, ref.flags & ~int(BallFlag.REFINE_FAILED), ref.flags)
    shading = None if ref.shading_px is None else np.where(fitted[:, None], 0.0, ref.shading_px)
    phase = {k: np.where(fitted, np.nan, getattr(ref, k)) for k in ("shading_phase_rad", "shading_phase_sd_rad")
             if getattr(ref, k, None) is not None}
    if getattr(ref, "shading_misfit_px", None) is not None:
        phase["shading_misfit_px"] = np.where(fitted[:, None], np.nan, ref.shading_misfit_px)
    return replace(ref, centers=centers, shifts=centers - (ref.centers - ref.shifts), flags=flags,
                   shading_px=shading, **phase)


def _faint(det: BallDetections) -> np.ndarray:
    """Which detections are faint crescents (``CRESCENT`` found by the faint-rim search, without
    a silhouette: ``contour_index`` -1), shape (N,) bool."""
    return det.has(BallFlag.CRESCENT) & (det.contour_index < 0)


def view_center_sigma_px(stereo: StereoBalls) -> np.ndarray:
    """Each match's own centre uncertainty in each view (1 sigma, px), shape (K, 2): the arc
    fit's ``center_sigma_px`` for views whose centre rests on an arc (``EDGE``; faint crescents,
    whose thin rim's offset the refinement keeps; ``SPLIT`` balls of a merged silhouette, at the
    refined centre with the photo's blur ``psf_px``), NaN for the others (a whole limb, or a
    crescent silhouette refined on its lit limb: its error is the pair's, from its residuals).

    Crescent silhouettes are left to the pair's sigma: refined and shading-corrected, their
    centres were no worse than the pair's others (studio pitch, clean, 4 crescent views of 11 in
    its back pair: weighed by their arc sigma, ~0.6 px, the direction error went from 0.008 to
    0.011 deg; ``bench_ball_detect.py --only-missed``: their sigma is 1.5x their RMS error)."""
    out = np.full((len(stereo), 2), np.nan)
    for v, det in enumerate((stereo.detections_a, stereo.detections_b)):
        idx = stereo.pairs[:, v] if len(stereo) else np.zeros(0, int)
        arc = (det.has(BallFlag.EDGE) | _faint(det))[idx]
        out[:, v] = np.where(arc, det.center_sigma_px[idx], np.nan)
        # split balls (issue 12): refined with the known radius on their own arc of a merged
        # silhouette, their centre moves with the blurred limb's offset (the photo's blur) by
        # the arc's ``(sum u u^T)^-1 sum u``: arc_center_sigma at the refined centre, the blur
        # read from the photo (the detector only had its default)
        for k in np.flatnonzero(det.has(BallFlag.SPLIT)[idx] & ~arc):
            pts = det.arc_points[idx[k]]
            if pts is not None and len(pts) >= 3:
                out[k, v] = arc_center_sigma(pts, det.centers[idx[k]], fit_circle(pts)[2], float(stereo.psf_px[v]))
    return out


def _merge_refined(det: BallDetections, idx: np.ndarray, ref: RefinedCenters) -> BallDetections:
    centers, radii, scores, flags = det.centers.copy(), det.radii_px.copy(), det.scores.copy(), det.flags.copy()
    centers[idx] = ref.centers
    radii[idx] = ref.radii_px
    scores[idx] = ref.scores
    flags[idx] |= ref.flags
    return replace(det, centers=centers, radii_px=radii, scores=scores, flags=flags)
