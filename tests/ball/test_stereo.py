"""Ball images of a stereo pair -> 3D ball centres (:func:`stillcap.ball.stereo.ball_centers_stereo`),
on photos drawn by the exact sphere renderer of ``tests/detect/test_ball.py``."""

from __future__ import annotations

import numpy as np
import pytest

from detect.test_ball import FLIGHT, R_BALL, draw_balls_camera, front_pair
from stillcap.ball.stereo import ball_centers_stereo
from stillcap.detect.ball import BallFlag


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
