"""Single-camera poses (PnP), stereo calibration from detections, stereo pairing."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.calibrate import (CalibrationObject, Chessboard, calibrate_stereo, calibrate_stereo_from_detections,
                                pair_stereo_images, pose_from_board, pose_from_points, split_stereo_images)
from stillcap.camera import pose_matrix


def _rot_deg(A, B):
    return np.degrees(Rotation.from_matrix(A[:3, :3] @ B[:3, :3].T).magnitude())


@pytest.mark.parametrize("method", ["sqpnp", "iterative"])
def test_pose_from_points_object(synth, method):
    rng = np.random.default_rng(5)
    cam = synth.make_camera()
    obj = np.concatenate(CalibrationObject.charuco_box().object_points())
    T = synth.board_poses(cam, obj, 1, rng, depth=(0.7, 0.8))[0]
    px = synth.project(cam, T, obj, 0.1, rng)
    px[3] = np.nan  # not observed
    res = pose_from_points(cam, obj, px, method=method)
    assert res.success and res.n_points == len(obj) - 1
    assert np.linalg.norm(res.world2cam[:3, 3] - T[:3, 3]) < 1e-3 and _rot_deg(res.world2cam, T) < 0.1
    assert 0.08 < res.rms_px < 0.2 and res.residuals_px.shape == (len(obj) - 1,)
    np.testing.assert_allclose(res.camera.world2cam, res.world2cam)


def test_pose_from_points_bad_input(synth):
    cam = synth.make_camera()
    with pytest.raises(ValueError, match=r"object_points must have shape \(N, 3\), got \(5, 2\)"):
        pose_from_points(cam, np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match="at least 4 observed points, got 3"):
        pose_from_points(cam, np.eye(3), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="method must be"):
        pose_from_points(cam, np.random.rand(6, 3), np.random.rand(6, 2), method="magic")


def test_pose_from_board_image(synth):
    cam = synth.make_camera(dist=(0, 0, 0, 0, 0))
    board = Chessboard(9, 6, 0.025)
    T = synth.board_poses(cam, board.object_points(), 1, np.random.default_rng(6), margin=60)[0]
    img = synth.render_plane(board.texture(48), board.extent, T, cam)
    res = pose_from_board(cam, img, board)
    assert res.success and res.rms_px < 0.15
    assert np.linalg.norm(res.world2cam[:3, 3] - T[:3, 3]) < 1e-3 and _rot_deg(res.world2cam, T) < 0.1
    with pytest.raises(ValueError, match="image: 9x6 chessboard not found"):
        pose_from_board(cam, np.zeros((480, 640), np.uint8), board)


def _stereo_detections(synth, rng, n=10, noise=0.1):
    board = Chessboard(9, 6, 0.04)
    obj = board.object_points()
    left = synth.make_camera("L")
    right_pose = pose_matrix(Rotation.from_euler("y", -8, degrees=True).as_matrix(), [-0.12, 0.005, 0.01])
    right = synth.make_camera("R", fx=790, fy=792, cx=318, cy=250, dist=(-0.15, 0.02, 0, 0, 0), world2cam=right_pose)
    pairs = []
    for i, T in enumerate(synth.board_poses(left, obj, n, rng, depth=(0.5, 0.9), spread=0.2)):
        pl = synth.project(left, T, obj, noise, rng)
        pr = synth.project(right, right_pose @ T, obj, noise, rng)
        pairs.append((f"{i:02d}", synth.detection(f"left{i:02d}", obj, pl), synth.detection(f"right{i:02d}", obj, pr)))
    return left, right, pairs


def test_stereo_from_detections_known_intrinsics(synth):
    left, right, pairs = _stereo_detections(synth, np.random.default_rng(7))
    res = calibrate_stereo_from_detections(pairs, left, right, names=("a", "b"))
    assert res.success and res.rig.names == ["a", "b"]
    np.testing.assert_allclose(res.rig["a"].world2cam, np.eye(4))
    T_true = right.world2cam[:3, 3]
    assert np.linalg.norm(res.T - T_true) < 1e-3 and abs(res.baseline - np.linalg.norm(T_true)) < 1e-3
    assert _rot_deg(pose_matrix(res.R, res.T), right.world2cam) < 0.05
    assert 0.08 < res.rms_px < 0.2 and len(res.per_pair_rms_px) == 10
    np.testing.assert_allclose(res.rig["b"].K, right.K)  # fixed intrinsics stay fixed


def test_stereo_skips_pairs_with_a_missing_board(synth):
    left, right, pairs = _stereo_detections(synth, np.random.default_rng(8))
    k, a, b = pairs[3]
    pairs[3] = (k, a, type(b).failed(b.name, b.image_size, "9x6 chessboard not found"))
    res = calibrate_stereo_from_detections(pairs, left, right)
    assert res.pairs_skipped == {"03": "right03: 9x6 chessboard not found"} and "03" not in res.pairs_used


def test_pairing_by_name_and_index(tmp_path):
    L = [Path(f"/x/left{i:02d}.jpg") for i in (1, 2, 3)]
    R = [Path(f"/x/right{i:02d}.jpg") for i in (3, 1, 2)]
    pairs = pair_stereo_images(L, R)
    assert [(k, a.name, b.name) for k, a, b in pairs] == [
        ("01", "left01.jpg", "right01.jpg"), ("02", "left02.jpg", "right02.jpg"), ("03", "left03.jpg", "right03.jpg")]
    same = pair_stereo_images([Path("c0/001.png")], [Path("c1/001.png")])
    assert same[0][0] == "001"
    with pytest.raises(ValueError, match="no partner for left02.jpg, right04.jpg"):
        pair_stereo_images(L, [Path("/x/right01.jpg"), Path("/x/right03.jpg"), Path("/x/right04.jpg")])
    arr = np.zeros((4, 4), np.uint8)
    with pytest.raises(ValueError, match="2 left images but 3 right images"):
        pair_stereo_images([arr] * 2, [arr] * 3)
    with pytest.raises(ValueError, match="got 0 left"):
        calibrate_stereo([], [arr], Chessboard())
    left, right = split_stereo_images(L + R)
    assert len(left) == len(right) == 3
    with pytest.raises(ValueError, match="cannot tell left from right for other.jpg"):
        split_stereo_images(L + R + [Path("other.jpg")])
