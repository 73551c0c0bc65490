"""Intrinsic calibration on synthetic correspondences and renderings, and bad input."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.calibrate import (CalibrationObject, CharucoTarget, Chessboard, calibrate_intrinsics,
                                calibrate_intrinsics_from_points)


def _rot_deg(A, B):
    return np.degrees(Rotation.from_matrix(A[:3, :3] @ B[:3, :3].T).magnitude())


def _check_K(K, K_true, rel=0.005):
    for (i, j) in [(0, 0), (1, 1), (0, 2), (1, 2)]:
        assert abs(K[i, j] - K_true[i, j]) <= rel * K_true[i, j], (i, j, K[i, j], K_true[i, j])


def test_chessboard_points_recover_K_dist_and_poses(synth):
    rng = np.random.default_rng(1)
    cam = synth.make_camera()
    board = Chessboard(9, 6, 0.04)
    obj = board.object_points()
    poses = synth.board_poses(cam, obj, 15, rng, depth=(0.4, 0.8), tilt_deg=45)
    img = [synth.project(cam, T, obj, 0.05, rng) for T in poses]
    res = calibrate_intrinsics_from_points([obj] * 15, img, cam.image_size, camera_name="c")
    assert res.success and res.camera.name == "c" and res.camera.image_size == (640, 480)
    _check_K(res.camera.K, cam.K)
    np.testing.assert_allclose(res.camera.dist[:2], cam.dist[:2], atol=0.02)
    assert 0.04 < res.rms_px < 0.1  # 0.05 px noise per axis -> about 0.07 px
    assert list(res.per_image_rms_px) == res.images_used == [f"#{i}" for i in range(15)]
    assert max(res.per_image_rms_px.values()) < 0.12
    for i, T in enumerate(poses):
        B = res.board2cam[f"#{i}"]
        assert np.linalg.norm(B[:3, 3] - T[:3, 3]) < 1e-3 and _rot_deg(B, T) < 0.1


def test_charuco_partial_views(synth):
    # ChArUco views see only some corners; each view has its own subset.
    rng = np.random.default_rng(2)
    cam = synth.make_camera(fx=900, fy=900, cx=320, cy=240, dist=(-0.1, 0.0, 0, 0, 0))
    board = CharucoTarget(7, 5, 0.04, 0.03)
    allp = board.object_points()
    objs, imgs = [], []
    for T in synth.board_poses(cam, allp, 15, rng, depth=(0.45, 0.8), tilt_deg=45):
        ids = np.sort(rng.choice(len(allp), 18, replace=False))
        objs.append(allp[ids])
        imgs.append(synth.project(cam, T, allp[ids], 0.05, rng))
    res = calibrate_intrinsics_from_points(objs, imgs, cam.image_size)
    _check_K(res.camera.K, cam.K)


def test_calibration_object_needs_few_views(synth):
    # A 3D object constrains K from a few views (OpenCV needs a starting K: made from the image size).
    rng = np.random.default_rng(3)
    cam = synth.make_camera(dist=(0, 0, 0, 0, 0))
    obj = np.concatenate(CalibrationObject.charuco_box().object_points())
    objs, imgs = [], []
    for T in synth.board_poses(cam, obj, 6, rng, depth=(0.6, 0.9), tilt_deg=25):
        objs.append(obj)
        imgs.append(synth.project(cam, T, obj, 0.02, rng))
    res = calibrate_intrinsics_from_points(objs, imgs, cam.image_size)
    _check_K(res.camera.K, cam.K)


def test_rendered_images_with_a_blank_one_skipped(synth):
    rng = np.random.default_rng(4)
    cam = synth.make_camera(dist=(0, 0, 0, 0, 0))
    board = Chessboard(9, 6, 0.025)
    images = [synth.render_plane(board.texture(48), board.extent, T, cam)
              for T in synth.board_poses(cam, board.object_points(), 6, rng, margin=60)]
    images.insert(2, np.full((480, 640), 128, np.uint8))
    names = [f"view{i}.png" for i in range(len(images))]
    res = calibrate_intrinsics(images, board, names=names)
    assert res.images_skipped == {"view2.png": "9x6 chessboard not found"}
    assert "view2.png" not in res.images_used and len(res.images_used) == 6
    assert res.rms_px < 0.15
    _check_K(res.camera.K, cam.K, rel=0.01)


def test_bad_input():
    board = Chessboard(9, 6)
    blank = np.zeros((48, 64), np.uint8)
    with pytest.raises(ValueError, match="no images given"):
        calibrate_intrinsics([], board)
    with pytest.raises(ValueError, match=r"not found in any of the 2 images: a\.png .*; b\.png"):
        calibrate_intrinsics([blank, blank], board, names=["a.png", "b.png"])
    with pytest.raises(ValueError, match="images differ in size: #0 is 64x48 px, #1 is 48x64 px"):
        calibrate_intrinsics([blank, blank.T.copy()], board)
    obj = board.object_points()
    with pytest.raises(ValueError, match="at least 3 views, got 2"):
        calibrate_intrinsics_from_points([obj, obj], [obj[:, :2]] * 2, (640, 480))
    with pytest.raises(ValueError, match=r"image points of #1 .*must have shape \(54, 2\), got \(53, 2\)"):
        calibrate_intrinsics_from_points([obj] * 3, [obj[:, :2], obj[:-1, :2], obj[:, :2]], (640, 480))
    with pytest.raises(ValueError, match="3 object-point views but 2 image-point views"):
        calibrate_intrinsics_from_points([obj] * 3, [obj[:, :2]] * 2, (640, 480))
