"""Calibration from photos the studio rendered through known cameras recovers those cameras."""

import numpy as np

from stillcap.calibrate import calibrate_intrinsics, calibrate_rig, calibrate_rig_from_points, Chessboard
from stillcap.studio.scenes import chessboard_set, default_camera, marker_rig, rig_board_set


def test_intrinsics_recovered_within_half_a_percent():
    cam = default_camera()
    boards = chessboard_set(cam, 10, Chessboard(9, 6, 0.025), rng=11)
    res = calibrate_intrinsics(boards.images, boards.target)
    assert res.success and res.rms_px < 0.15
    K, K0 = res.camera.K, cam.K
    assert abs(K[0, 0] / K0[0, 0] - 1) < 0.005 and abs(K[1, 1] / K0[1, 1] - 1) < 0.005
    assert abs(K[0, 2] / K0[0, 2] - 1) < 0.005 and abs(K[1, 2] / K0[1, 2] - 1) < 0.005
    assert abs(res.camera.dist[0] - cam.dist[0]) < 0.02


def test_rig_extrinsics_from_shared_board_views():
    rig = marker_rig(3, rng=4)
    shared = rig_board_set(rig, 6, Chessboard(9, 6, 0.06), rng=5, spread=0.4)
    res = calibrate_rig(shared.images, shared.target, cameras=rig)  # intrinsics known, poses not
    assert res.success and res.rms_px < 0.2
    T0 = rig[0].world2cam
    for true, got in zip(rig, res.rig):
        center = (T0 @ np.append(true.center, 1))[:3]
        assert np.linalg.norm(got.center - center) < 2e-3


def test_badly_detected_views_are_left_out_and_named():
    rig = marker_rig(3, rng=4)
    board = Chessboard(9, 6, 0.06)
    rng = np.random.default_rng(0)
    views = {c.name: [] for c in rig}
    for k in range(5):
        T = np.eye(4)
        T[:3, 3] = rng.uniform(-0.2, 0.2, 3) + [0, 0, 1.0]
        T[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]])  # board facing -y (the cameras)
        obj = board.object_points()
        for c in rig:
            px = c.project(obj @ T[:3, :3].T + T[:3, 3]) + rng.normal(0, 0.1, (len(obj), 2))
            if k == 2 and c.name == "cam1":
                px[:18] = px[:18][::-1]  # two corner rows detected in the wrong order
            views[c.name].append((obj, px))
    res = calibrate_rig_from_points(views, cameras=rig, instants=[f"t{k}" for k in range(5)])
    assert "t2" in res.images_skipped["cam1"] and "corners within" in res.images_skipped["cam1"]["t2"]
    assert res.rms_px < 0.2
