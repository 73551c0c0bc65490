"""Target detection on synthetic renderings (planar warps of the printed textures)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.calibrate import (CalibrationObject, CharucoTarget, Chessboard, detect_target, detect_targets,
                                pose_from_object, read_gray)
from stillcap.camera import look_at, pose_matrix


def _view(synth, board, rot_z_deg=0.0, depth=0.45):
    cam = synth.make_camera(dist=(0, 0, 0, 0, 0))
    c = board.object_points().mean(axis=0)
    R = Rotation.from_euler("xyz", [20, -15, rot_z_deg], degrees=True).as_matrix()
    T = pose_matrix(R, np.array([0.0, 0.0, depth]) - R @ c)
    img = synth.render_plane(board.texture(64), board.extent, T, cam)
    return cam, T, img


def test_chessboard_corners_match_projection(synth):
    board = Chessboard(9, 6, 0.025)
    cam, T, img = _view(synth, board)
    d = detect_target(img, board, "synthetic.png")
    assert d.success and d.name == "synthetic.png" and d.image_size == (640, 480)
    truth = synth.project(cam, T, board.object_points())
    assert np.abs(d.image_points - truth).max() < 0.15
    np.testing.assert_array_equal(d.object_points, board.object_points())


@pytest.mark.parametrize("rot", [0.0, 180.0])
def test_chessboard_order_follows_printed_board(synth, rot):
    # A 180-degree turn of the board must not turn the corner order with it (cols + rows odd).
    board = Chessboard(9, 6, 0.025)
    cam, T, img = _view(synth, board, rot_z_deg=rot)
    d = detect_target(img, board)
    truth = synth.project(cam, T, board.object_points())
    assert np.abs(d.image_points - truth).max() < 0.15


def test_charuco_ids_and_corners(synth):
    board = CharucoTarget(7, 5, 0.03, 0.022)
    cam, T, img = _view(synth, board, depth=0.4)
    d = detect_target(img, board)
    assert d.success and len(d.ids) == len(board.object_points()) == 24
    truth = synth.project(cam, T, board.object_points()[d.ids])
    assert np.abs(d.image_points - truth).max() < 0.15
    np.testing.assert_allclose(d.object_points, board.object_points()[d.ids])


def test_calibration_object_detection_and_pose(synth):
    obj = CalibrationObject.charuco_box(square=0.04, squares=(5, 5))
    cam = synth.make_camera(fx=1000, fy=1000, cx=400, cy=300, dist=(0, 0, 0, 0, 0), size=(800, 600))
    # Look from the printed side of every face (board z axes point away from the camera).
    away = sum(np.asarray(F)[:3, 2] for F in obj.face2object)
    center = np.mean([p.mean(axis=0) for p in obj.object_points()], axis=0)
    o2c = look_at(center - 0.55 * away / np.linalg.norm(away), center, up=(0.1, 0.2, 1.0))
    img = None
    for face, F in zip(obj.faces, obj.face2object):
        img = synth.render_plane(face.texture(64), face.extent, o2c @ np.asarray(F), cam, img)
    d = detect_target(img, obj)
    assert d.success
    faces_seen = set(np.searchsorted(np.cumsum([16, 16, 16]), d.ids, side="right"))
    assert faces_seen == {0, 1, 2}  # ids offset per face: 16 corners each
    err = np.linalg.norm(d.image_points - cam.with_pose(o2c).project(d.object_points), axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.15 and err.max() < 0.5  # corners next to another face: worse
    res = pose_from_object(cam, img, obj)
    assert res.success and res.rms_px < 0.2
    assert np.linalg.norm(res.world2cam[:3, 3] - o2c[:3, 3]) < 1e-3
    assert np.degrees(Rotation.from_matrix(res.world2cam[:3, :3] @ o2c[:3, :3].T).magnitude()) < 0.1


def test_board_not_found_is_a_result_not_an_error():
    blank = np.full((480, 640), 200, np.uint8)
    dets = detect_targets([blank, blank], Chessboard(9, 6))
    assert [d.name for d in dets] == ["#0", "#1"]
    assert not dets[0].success and "9x6 chessboard not found" in dets[0].reason
    d = detect_target(blank, CharucoTarget())
    assert not d.success and "ChArUco corners" in d.reason


def test_unreadable_and_missing_files(tmp_path):
    bad = tmp_path / "broken.jpg"
    bad.write_bytes(b"this is not a jpeg")
    with pytest.raises(ValueError, match="broken.jpg"):
        detect_target(bad, Chessboard())
    with pytest.raises(ValueError, match="nothere.png.*does not exist"):
        detect_targets([tmp_path / "nothere.png"], Chessboard())
    with pytest.raises(ValueError, match=r"shape \(H, W\)"):
        read_gray(np.zeros(5))


def test_read_gray_conversions():
    bgr = np.zeros((4, 5, 3), np.uint8)
    bgr[..., 1] = 255
    assert read_gray(bgr).shape == (4, 5)
    assert read_gray(np.ones((4, 5))).max() == 255  # floats are 0..1
    assert read_gray(np.full((4, 5), 65535, np.uint16)).max() == 255
