"""Ball images of a stereo pair -> 3D ball centres (:func:`stillcap.ball.stereo.ball_centers_stereo`),
on photos drawn by the exact sphere renderer of ``tests/detect/test_ball.py``."""

from __future__ import annotations

import numpy as np
import pytest

from detect.test_ball import FLIGHT, R_BALL, draw_balls_camera, front_pair
from stillcap.ball.stereo import ball_centers_stereo
from stillcap.camera import Camera, look_at
from stillcap.detect.ball import BallFlag, detect_balls


@pytest.mark.parametrize("light, max_mm, init_min_mm", [(None, 1.0, 0.0), ((1.0, 0.0, 0.0), 1.0, 5.0)])
def test_stereo_pair_recovers_3d_centers(light, max_mm, init_min_mm):
    """The front pair (camera b with lens distortion) sees 8 balls; 3D error well below 1 mm.
    Lit from the side (half moons), the ellipse centres triangulate ~6-12 mm off, the refined
    centres still well below 1 mm."""
    a, b = front_pair()
    ia = draw_balls_camera(a, FLIGHT, R_BALL, light_world=light, rng=11)
    ib = draw_balls_camera(b, FLIGHT, R_BALL, light_world=light, rng=12)
    res = ball_centers_stereo(a, ia, b, ib, R_BALL)
    assert len(res) == 8 and np.all(res.ok)
    order = np.argsort(res.points_3d[:, 0])
    err = np.linalg.norm(res.points_3d[order] - FLIGHT, axis=1)
    err0 = np.linalg.norm(res.points_3d_initial[order] - FLIGHT, axis=1)
    assert err.max() * 1e3 < max_mm
    assert err0.mean() * 1e3 >= init_min_mm
    assert np.all(res.reproj_error_px < 0.2)
    # projected radius: f R / distance on the axis; off-axis the outline is an ellipse, its
    # semi-axes about f R / (d cos) and f R / (d cos^2) of the field angle (13% more at 23 deg)
    r_axis = 2400 * R_BALL / np.linalg.norm(FLIGHT - a.center, axis=1)
    assert np.all((res.radius_px[order, 0] > r_axis) & (res.radius_px[order, 0] < 1.2 * r_axis))
    # raw and undistorted centres: the same for the pinhole camera a, not for b
    assert np.allclose(res.centers_a, res.centers_a_undistorted)
    assert np.abs(res.centers_b - res.centers_b_undistorted).max() > 1.0
    assert np.linalg.norm(res.centers_a[order] - a.project(FLIGHT), axis=1).max() < 0.5
    assert np.all((res.flags & BallFlag.SIZE_MISMATCH) == 0)
    # the detections carry the refined centres
    assert np.allclose(res.detections_a.centers[res.pairs[:, 0]], res.centers_a)
    if light is not None:
        assert np.all(res.flags & BallFlag.PARTIAL)


def test_empty_images_give_no_stereo_balls():
    a, b = front_pair()
    z = np.zeros((1920, 2560, 3), np.uint8)
    res = ball_centers_stereo(a, z, b, z, R_BALL)
    assert len(res) == 0 and res.points_3d.shape == (0, 3) and res.pairs.shape == (0, 2)


def test_bad_stereo_input_names_the_shape():
    img = np.zeros((50, 60, 3), np.uint8)
    a, b = front_pair()
    with pytest.raises(ValueError, match=r"img_a is 60x50 px, camera 'front_low' is 2560x1920 px"):
        ball_centers_stereo(a, img, b, img, R_BALL)
    z = np.zeros((1920, 2560, 3), np.uint8)
    with pytest.raises(ValueError, match="ball_radius_m must be a positive number of metres"):
        ball_centers_stereo(a, z, b, z, -1.0)
    with pytest.raises(ValueError, match="stillcap Camera"):
        ball_centers_stereo("a", z, b, z, R_BALL)


def test_stereo_pair_reads_the_lens_blur_and_corrects_every_ball():
    """The photos' lens blur is read from the ball images' limbs (``psf_px="auto"``) and the
    shading correction runs on every match (full discs too); a stated blur is used as given,
    ``shading="partial"`` corrects only half moons, and a wrong ``psf_px`` is named."""
    a, b = front_pair()
    ia = draw_balls_camera(a, FLIGHT, R_BALL, blur=1.2, rng=11)
    ib = draw_balls_camera(b, FLIGHT, R_BALL, blur=1.2, rng=12)
    res = ball_centers_stereo(a, ia, b, ib, R_BALL)
    assert np.all(np.abs(res.psf_px - 1.2) < 0.18), res.psf_px
    assert np.all(res.shading_px > 0)  # full discs are corrected too
    stated = ball_centers_stereo(a, ia, b, ib, R_BALL, psf_px=(0.5, 0.7))
    np.testing.assert_array_equal(stated.psf_px, [0.5, 0.7])
    partial = ball_centers_stereo(a, ia, b, ib, R_BALL, shading="partial")
    assert not np.any(partial.shading_px)  # full discs: not PARTIAL, not corrected
    order = np.argsort(res.points_3d[:, 0])
    assert np.linalg.norm(res.points_3d[order] - FLIGHT, axis=1).max() * 1e3 < 1.0
    with pytest.raises(ValueError, match="psf_px must be 'auto' or a blur in px"):
        ball_centers_stereo(a, ia, b, ib, R_BALL, psf_px="sharp")
    with pytest.raises(ValueError, match="psf_px must be >= 0 px"):
        ball_centers_stereo(a, ia, b, ib, R_BALL, psf_px=-1.0)


def _flight_with_a_cut_ball(cam, inside_r: float):
    """FLIGHT with a 9th ball before the first whose image in ``cam`` has its centre
    ``inside_r`` radii inside the left edge of the photo."""
    from scipy.optimize import brentq

    r_px = 2400 * R_BALL / 3.5
    x0 = brentq(lambda x: cam.project(np.array([[x, 0.0, 1.6]]))[0, 0] - (inside_r * r_px - 0.5), -2.5, -1.5)
    return np.concatenate([[[x0, 0.0, 1.6]], FLIGHT])


@pytest.mark.parametrize("inside_r", [0.4, 0.7])
def test_ball_cut_by_the_edge_in_one_view_keeps_its_in_frame_limb_circle(inside_r):
    """Issue 12: a ball cut by the photo's edge in camera a (its centre ``inside_r`` radii inside,
    28 deg off axis) is matched from its in-frame limb's circle and kept (``EDGE``, not
    ``REFINE_FAILED``); its centre in that view is its in-frame limb refitted with the projected
    (elongated) outline's shape: within half a pixel, where the detector's circle is 1.9-2.4 px off; 3-D
    centre within half a millimetre. Its view's sigma is the arc's (the others' NaN), and covers
    the error."""
    from stillcap.ball.stereo import view_center_sigma_px

    a, b = front_pair()
    flight = _flight_with_a_cut_ball(a, inside_r)
    ia = draw_balls_camera(a, flight, R_BALL, rng=21)
    ib = draw_balls_camera(b, flight, R_BALL, rng=22)
    res = ball_centers_stereo(a, ia, b, ib, R_BALL)
    assert len(res) == 9
    k = int(np.argmin(res.points_3d[:, 0]))
    assert res.flags[k] & BallFlag.EDGE and res.flags[k] & BallFlag.TOUCHES_BORDER
    assert not res.flags[k] & (BallFlag.REFINE_FAILED | BallFlag.SIZE_MISMATCH)
    assert res.ok[k]
    det = detect_balls(ia)
    circle = det.centers[det.has(BallFlag.EDGE)][0]
    truth = a.project(flight[:1])[0]
    err = np.linalg.norm(res.centers_a[k] - truth)
    assert err < 0.5 and np.linalg.norm(circle - truth) > 1.5
    assert np.linalg.norm(res.points_3d[k] - flight[0]) * 1e3 < 0.5
    sig = view_center_sigma_px(res)
    assert np.isfinite(sig[k, 0]) and np.isnan(sig[k, 1])
    assert err < 2.45 * sig[k, 0]
    assert np.all(np.isnan(np.delete(sig, k, axis=0)))


def test_edge_view_is_refitted_with_the_outline_shape():
    """The in-frame limb of a cut ball whose outline is an ellipse (elongated 13 % along x, its
    middle 0.3 px off the projected centre), drawn 1.5 px larger all round (the silhouette's
    blurred rim): the outline-shaped fit gives the projected centre within 0.25 px (a constant
    offset is not quite a scale of the ellipse: 0.18 px here; the circle fitted to the same
    points is ~1 px off), clears REFINE_FAILED; other views are left alone."""
    from stillcap.ball.stereo import _edge_outline_fit
    from stillcap.detect.ball import BallDetections, RefinedCenters
    from stillcap.detect.circle_fit import fit_circle

    th = np.linspace(0, 2 * np.pi, 128, endpoint=False)
    a_x, a_y, mid = 22.6, 20.0, np.array([0.3, 0.0])
    outline = mid + np.stack([a_x * np.cos(th), a_y * np.sin(th)], 1)  # offsets from the projected centre
    truth = np.array([6.0, 300.0])
    limb = truth + mid + np.stack([(a_x + 1.5) * np.cos(th), (a_y + 1.5) * np.sin(th)], 1)
    limb = limb[limb[:, 0] > 1.0]  # in frame
    det = BallDetections(centers=np.array([fit_circle(limb)[0], [200.0, 300.0]]),
                         ellipse_centers=np.array([[12.0, 300.0], [200.0, 300.0]]),
                         radii_px=np.full(2, 20.0), ellipses=np.zeros((2, 5)), areas=np.ones(2),
                         hull_areas=np.ones(2), scores=np.full(2, np.nan),
                         flags=np.array([BallFlag.EDGE | BallFlag.TOUCHES_BORDER, 0]),
                         contour_index=np.arange(2), arc_points=[limb, None])
    assert np.linalg.norm(det.centers[0] - truth) > 0.8
    failed = int(BallFlag.REFINE_FAILED)
    c = np.array([[8.0, 301.0], [201.0, 301.0]])
    ref = RefinedCenters(c, np.full(2, 20.0), np.array([0.1, 0.9]), c - det.ellipse_centers,
                         np.array([failed, 0]), np.ones((2, 2)))
    out = _edge_outline_fit(ref, det, np.array([0, 1]), np.stack([outline, outline]))
    assert np.linalg.norm(out.centers[0] - truth) < 0.25
    assert out.flags[0] == 0 and np.all(out.shading_px[0] == 0)
    assert np.allclose(out.centers[1], c[1]) and out.flags[1] == 0 and np.all(out.shading_px[1] == 1)
    assert np.allclose(out.shifts, out.centers - det.ellipse_centers)


def test_view_sigma_is_the_arcs_for_edge_views_and_faint_crescents_only():
    """Crescent silhouettes (refined and shading-corrected on their lit limb) keep the pair's
    sigma (NaN here); cut balls and faint crescents (no silhouette) carry their arc sigma."""
    from stillcap.ball.stereo import StereoBalls, view_center_sigma_px
    from stillcap.detect.ball import BallDetections

    def det(flags, contour):
        n = len(flags)
        return BallDetections(centers=np.zeros((n, 2)), ellipse_centers=np.zeros((n, 2)), radii_px=np.ones(n),
                              ellipses=np.zeros((n, 5)), areas=np.ones(n), hull_areas=np.ones(n),
                              scores=np.ones(n), flags=np.array(flags), contour_index=np.array(contour),
                              center_sigma_px=np.array([0.4, 0.5, 0.6, 0.7][:n]))

    cres = int(BallFlag.CRESCENT | BallFlag.PARTIAL)
    a = det([0, cres, cres, int(BallFlag.EDGE | BallFlag.TOUCHES_BORDER)], [0, 1, -1, 2])
    b = det([0, 0, 0, 0], [0, 1, 2, 3])
    z = np.zeros((4, 2))
    st = StereoBalls(np.zeros((4, 3)), np.zeros((4, 3)), z, z, z, z, z, np.stack([np.arange(4)] * 2, 1),
                     np.zeros(4), np.zeros(4), a.flags, a, b)
    sig = view_center_sigma_px(st)
    assert np.isnan(sig[:2, 0]).all() and list(sig[2:, 0]) == [0.6, 0.7] and np.isnan(sig[:, 1]).all()



def test_merged_ball_images_carry_their_split_arcs_sigma():
    """Issue 12: three small ball images (6.3 px radius, 14 px apart) blurred 1.5 px merge into
    one silhouette in both views of a 640x480 pair and are split. The known-radius refinement on
    a split ball's own (one-sided) arc moves its centre with the blurred limb's offset: the two
    end balls' centres come out 0.6-0.75 px outward. Each split view carries its arc's sigma (the
    photo's blur as the limb offset), which covers its error; the end balls' (one-sided arcs) is
    larger than the middle one's (two opposite arcs); unsplit views keep the pair's (NaN)."""
    from stillcap.ball.stereo import view_center_sigma_px

    a = Camera.from_intrinsics("a", 600, 600, 319.5, 239.5, (640, 480), world2cam=look_at((0, -3.5, 1.1), (0, 0, 1.5)))
    b = Camera.from_intrinsics("b", 600, 600, 322, 236, (640, 480), dist=(-0.05, 0.01, 0, 0, 0),
                               world2cam=look_at((0, -3.5, 1.9), (0, 0, 1.5)))
    xs = np.array([-0.9, -0.6, -0.3, -0.215, -0.13, 0.25, 0.55, 0.85])
    flight = np.stack([xs, np.zeros(8), 1.6 - 0.02 * xs], axis=1)
    res = ball_centers_stereo(a, draw_balls_camera(a, flight, R_BALL, blur=1.5, rng=10), b,
                              draw_balls_camera(b, flight, R_BALL, blur=1.5, rng=20), R_BALL)
    assert len(res) == 8 and np.all(res.ok)
    order = np.argsort(res.points_3d[:, 0])
    sig = view_center_sigma_px(res)[order]
    split = np.stack([res.detections_a.has(BallFlag.SPLIT)[res.pairs[order, 0]],
                      res.detections_b.has(BallFlag.SPLIT)[res.pairs[order, 1]]], axis=1)
    assert np.array_equal(np.flatnonzero(split.all(axis=1)), [2, 3, 4]) and not split[[0, 1, 5, 6, 7]].any()
    err = np.stack([np.linalg.norm(res.centers_a[order] - a.project(flight), axis=1),
                    np.linalg.norm(res.centers_b[order] - b.project(flight), axis=1)], axis=1)
    assert np.all(np.isfinite(sig[split])) and np.all(np.isnan(sig[~split]))
    assert np.all(err[split] < 2.45 * sig[split])
    assert np.all(sig[[2, 4]] > sig[3])


def test_blur_read_at_the_refinements_own_corrected_centres():
    """8 px half moons under 1.5 px of blur (``tests/detect/test_ball_shading.py``): read at the
    refined but uncorrected centres the limb fits give ~1.24 px; :func:`_refine_at_photo_blur`
    reads it again at the refinement's own shading-corrected centres (within 0.1 px of the
    truth), and the centres it returns are corrected at a blur within 0.02 px of the one it
    returns (under 0.05 px from the true centres along the light)."""
    from detect.test_ball_shading import GAMMA22, _row_of_balls
    from stillcap.ball.stereo import _refine_at_photo_blur, photo_blur_px
    from stillcap.detect.ball import refine_ball_centers

    img, balls, outl = _row_of_balls(8.0, 1.5, 90.0)
    c0 = refine_ball_centers(img, balls[:, :2], balls[:, 2], outlines=outl, response=GAMMA22).centers
    used = []

    def refine(v, psf, start=None):
        used.append((v, psf, start is not None))
        return refine_ball_centers(img, c0, balls[:, 2], outlines=outl, response=GAMMA22, start_refined=True,
                                   shading=np.ones(len(balls), bool), psf_px=psf, shading_start=start)

    blur, ref = _refine_at_photo_blur(0, img, c0, outl, GAMMA22, refine)
    assert photo_blur_px(img, c0, outl, GAMMA22) < 1.35  # the bias the second read removes
    assert abs(blur - 1.5) < 0.1, blur
    assert abs(used[-1][1] - blur) < 0.02 and len(used) >= 2 and used[-1][2]  # redone from corrected centres
    assert np.all(ref.ok)
    assert abs(float(np.mean(ref.centers[:, 0] - balls[:, 0]))) < 0.05


def test_flight_along_the_epipolar_lines_is_matched_in_its_order():
    """A pitch seen by two cameras 3 m apart behind the pitcher, their baseline near the flight's
    line: near the plate the ball images lie along the epipolar lines, 6 px ball images 15-40 px
    apart, each with 2-5 partners within a 3 px gate. Centre noise (0.7 px, the ellipse centres
    of half moons are worse) decides the smallest total epipolar distance; the flight's order
    along its track in each view (``_track_coordinate``, what ``ball_centers_stereo`` passes to
    ``match_epipolar``) does not."""
    from stillcap.ball.stereo import _track_coordinate
    from stillcap.geometry.epipolar import epipolar_distances, match_epipolar

    cams = [Camera.from_intrinsics(n, 1500.0, 1500.0, 640.0, 480.0, (1280, 960),
                                   world2cam=look_at((x, 9.0, 1.8), (0.0, 0.0, 0.8)))
            for n, x in (("l", -1.5), ("r", 1.5))]
    t = np.arange(0.0, 0.62, 0.02)  # 50 Hz strobe
    X = (np.array([-0.5, 16.6, 1.8]) + np.array([0.35, -27.5, 1.0]) * t[:, None]
         - 0.5 * 9.81 * np.outer(t ** 2, [0, 0, 1]))
    x = [c.project(X) for c in cams]
    seen = np.all([np.all((p >= 0) & (p < (1280, 960)), axis=1) for p in x], axis=0) & (X[:, 1] > 0.3)
    xa, xb = x[0][seen], x[1][seen]
    gate = 3.0
    assert (epipolar_distances(*cams, xa, xb) <= gate).sum(axis=1).max() >= 4
    rng = np.random.default_rng(0)
    wrong_plain, wrong_ordered, tried, missed = 0, 0, 0, 0
    for _ in range(100):
        na, nb = xa + rng.normal(0, 0.7, xa.shape), xb + rng.normal(0, 0.7, xb.shape)
        plain = match_epipolar(*cams, na, nb, max_px=gate)
        ordered = match_epipolar(*cams, na, nb, max_px=gate, order_a=_track_coordinate(na),
                                 order_b=_track_coordinate(nb))
        if np.diag(epipolar_distances(*cams, na, nb)).max() > gate:
            # a true pair outside the gate: that image stays unmatched, the others right (the
            # smallest total distance fills the gap with wrong pairs)
            missed += 1
            assert np.all(ordered.pairs[:, 0] == ordered.pairs[:, 1]) and len(ordered.pairs) >= len(na) - 1
            continue
        tried += 1
        wrong_plain += not np.array_equal(plain.pairs, np.stack([np.arange(len(na))] * 2, axis=1))
        wrong_ordered += not np.array_equal(ordered.pairs, np.stack([np.arange(len(na))] * 2, axis=1))
    assert tried >= 80 and missed >= 1 and wrong_plain >= tried // 2
    assert wrong_ordered == 0
