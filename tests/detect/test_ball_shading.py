"""The shading model of a lit ball (``stillcap.detect.ball._shading``): the photo's lens blur read
from the ball images' limbs, and clipped (over-exposed) balls, on photos drawn by the exact
sphere renderer of ``tests/detect/test_ball.py`` (orthographic, lambertian, blur in linear light,
gamma 2.2, noise, JPEG)."""

from __future__ import annotations

import numpy as np
import pytest

from detect.test_ball import SIZE, baseball_markers, draw_balls, flight_balls, nearest
from stillcap.ball.stereo import photo_blur_px
from stillcap.detect.ball import detect_balls, refine_ball_centers
from stillcap.response import Response

#: the drawing's response (a pure power law 2.2, stated as the rig would state it)
GAMMA22 = Response.from_json({"gamma": 2.2}, "response")


def _circles(radii, m: int = 96) -> np.ndarray:
    th = np.linspace(0, 2 * np.pi, m, endpoint=False)
    return np.stack([r * np.stack([np.cos(th), np.sin(th)], axis=1) for r in radii])


@pytest.mark.parametrize("light", [(0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.6, 0.0, 0.8)])
@pytest.mark.parametrize("blur", [0.4, 1.0, 1.6])
def test_photo_blur_is_read_from_the_limbs(light, blur):
    """Full discs, half moons and crescents (lit from behind), 14-24 px, painted markers, noise
    and JPEG: the median of the ball images' limb fits is the lens blur to within 15 %. The
    shading of the limb (a soft edge lit from the front, a thin rim lit from behind) is in the
    model, so it is not taken for blur."""
    balls = flight_balls(3, n=8, size=SIZE, r_range=(14, 24), spacing=(2.4, 3.2))
    mk = [baseball_markers(300 + b) for b in range(len(balls))]
    img, _ = draw_balls(SIZE, balls, light=light, blur=blur, markers=mk, rng=3)
    est = photo_blur_px(img, balls[:, :2], _circles(balls[:, 2]), GAMMA22)
    assert abs(est - blur) < 0.15 * blur + 0.03, est


def test_photo_blur_without_balls_is_nan():
    z = np.zeros((200, 200, 3), np.uint8)
    assert np.isnan(photo_blur_px(z, np.zeros((0, 2)), np.zeros((0, 96, 2))))
    # a ball cut by the photo's edge is not used
    assert np.isnan(photo_blur_px(z, [[2.0, 100.0]], _circles([10.0])))


@pytest.mark.parametrize("exposure, before_min, after_max", [(2.0, 0.15, 0.08), (4.0, 0.8, 0.15)])
def test_clipped_balls_shading_correction(exposure, before_min, after_max):
    """Over-exposed balls lit 25 deg from the camera: the clipped lit side has a hard edge and
    the Hough centre sits toward the light (0.23 px at 2x, 1.0 px at 4x the exposure that just
    clips, 20 px balls, no noise); the clipped model (gain from the clipped area, phase from the
    clipped centroid in the corrected centre's frame) leaves 0.04 and 0.08 px. What it leaves is the model's error the pitch pipeline's
    ``shading_model_error`` sizes (``docs/pitch.md``, "Uncertainties")."""
    light = (0.42, 0.0, -0.91)
    u = np.array([1.0, 0.0])
    along = {False: [], True: []}
    corr = []
    for seed in (3, 4):
        balls = flight_balls(seed, n=8, size=SIZE, r_range=(20, 20), spacing=(2.4, 3.2))
        img, _ = draw_balls(SIZE, balls, light=light, exposure=exposure, rng=seed, jpeg=None, noise=0.0)
        det = detect_balls(img)
        idx, _ = nearest(det.centers, balls[:, :2])
        for sh in (False, True):
            ref = refine_ball_centers(img, det.centers[idx], balls[:, 2], shading=np.full(len(idx), sh),
                                      response=GAMMA22, psf_px=0.6)
            assert np.all(ref.ok)
            along[sh] += list((ref.centers - balls[:, :2]) @ u)
            if sh:
                corr += list(ref.shading_px @ u)
            else:
                assert not np.any(ref.shading_px)
    before, after = np.mean(along[False]), np.mean(along[True])
    assert before > before_min
    assert abs(after) < after_max and abs(after) < 0.35 * before
    # the correction recorded is what moved the centres
    np.testing.assert_allclose(np.mean(corr), before - after, atol=1e-9)
