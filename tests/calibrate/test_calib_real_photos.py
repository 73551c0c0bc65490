"""Acceptance on real photos: OpenCV's classic stereo chessboard set (../shared/data/chessboard-stereo).

Reference (data README, OpenCV 5.0 on this machine): left RMS 0.409 px, fx 536.07, fy 536.02,
cx 342.37, cy 235.54; right RMS 0.459 px, fx 542.35, fy 541.62, cx 328.32, cy 246.95; stereo with
intrinsics fixed RMS 0.448 px, T = (-3.344, 0.042, 0.053) squares, |T| = 3.345 squares.
"""

import numpy as np
import pytest

from stillcap.calibrate import Chessboard, calibrate_rig, calibrate_stereo

BOARD = Chessboard(9, 6, 1.0)  # square = 1 unit: translations in squares


@pytest.fixture(scope="module")
def photos(stereo_dir):
    return sorted(stereo_dir.glob("left*.jpg")), sorted(stereo_dir.glob("right*.jpg"))


@pytest.fixture(scope="module")
def stereo(photos):
    return calibrate_stereo(*photos, BOARD)


@pytest.mark.parametrize("side, rms, ref", [
    ("left", 0.409, (536.07, 536.02, 342.37, 235.54)),
    ("right", 0.459, (542.35, 541.62, 328.32, 246.95)),
])
def test_intrinsics_match_opencv_reference(stereo, side, rms, ref):
    res = getattr(stereo, side)
    assert res.success and len(res.images_used) == 13 and not res.images_skipped
    assert res.rms_px <= rms
    K = res.camera.K
    np.testing.assert_allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], ref, atol=0.02)
    assert res.camera.image_size == (640, 480)
    assert set(res.per_image_rms_px) == {f"{side}{i:02d}.jpg" for i in (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14)}


def test_stereo_matches_opencv_reference(stereo):
    assert stereo.success and len(stereo.pairs_used) == 13 and stereo.pairs_used[0] == "01"
    assert stereo.rms_px <= 0.448
    np.testing.assert_allclose(stereo.T, [-3.344, 0.042, 0.053], atol=0.002)
    assert abs(stereo.baseline - 3.345) < 0.01 * 3.345
    assert np.degrees(np.arccos((np.trace(stereo.R) - 1) / 2)) < 1.0  # R close to identity
    assert stereo.rig.names == ["left", "right"]
    np.testing.assert_allclose(stereo.rig["right"].world2cam[:3, 3], stereo.T)


def test_two_camera_rig_with_bundle_adjustment(photos, stereo):
    # The same photos through the N-camera path: detection, intrinsics, spanning tree, bundle adjustment.
    left, right = photos
    res = calibrate_rig({"left": left, "right": right}, BOARD,
                        cameras={"left": stereo.left.camera, "right": stereo.right.camera})
    assert res.success and res.rig.names == ["left", "right"]
    assert res.rms_px < 0.5 and res.rms_px < res.initial_rms_px
    assert abs(np.linalg.norm(res.rig["right"].center) - 3.345) < 0.01 * 3.345
