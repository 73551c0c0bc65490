"""Synthetic ground truth for calibration tests (no studio needed): known cameras, board poses,
projected points and simple planar renderings of target textures."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.calibrate.detect import Detection
from stillcap.camera import Camera, look_at, pose_matrix

DATA = (Path(__file__).resolve().parents[2] / "../shared/data").resolve()
STEREO = DATA / "chessboard-stereo"


def make_camera(name="cam", fx=800.0, fy=805.0, cx=330.0, cy=245.0, dist=(-0.2, 0.05, 1e-3, -5e-4, 0.0),
                size=(640, 480), world2cam=None) -> Camera:
    return Camera.from_intrinsics(name, fx, fy, cx, cy, size, dist, world2cam)


def board_poses(cam: Camera, obj: np.ndarray, n: int, rng, depth=(0.35, 0.7), tilt_deg=40.0, margin=20,
                spread=0.45):
    """``n`` board2cam poses with every point of ``obj`` at least ``margin`` px inside the image."""
    center = obj.mean(axis=0)
    w, h = cam.image_size
    out = []
    while len(out) < n:
        R = Rotation.from_rotvec(np.r_[rng.uniform(-1, 1, 2) * np.radians(tilt_deg), rng.uniform(-0.5, 0.5)])
        R = R.as_matrix()
        z = rng.uniform(*depth)
        c = np.r_[rng.uniform(-spread, spread, 2) * z, z]
        T = pose_matrix(R, c - R @ center)
        px = cam.with_pose(T).project(obj)
        if np.all(np.isfinite(px)) and px[:, 0].min() > margin and px[:, 1].min() > margin \
                and px[:, 0].max() < w - margin and px[:, 1].max() < h - margin:
            out.append(T)
    return out


def project(cam: Camera, obj2cam, obj, noise_px=0.0, rng=None) -> np.ndarray:
    px = cam.with_pose(obj2cam).project(obj)
    if noise_px:
        px = px + np.random.default_rng(rng).normal(0, noise_px, px.shape)
    return px


def render_plane(texture, extent, plane2cam, cam: Camera, image=None, background=110, ss=4) -> np.ndarray:
    """Warp a target texture (``extent`` in its plane frame) into an undistorted camera image.

    Rendered ``ss`` times larger and box-filtered down (anti-aliasing); pixel centres at integers.
    """
    w, h = cam.image_size
    th, tw = texture.shape[:2]
    x0, y0, x1, y1 = extent
    sx, sy = (x1 - x0) / tw, (y1 - y0) / th
    A = np.array([[sx, 0, x0 + 0.5 * sx], [0, sy, y0 + 0.5 * sy], [0, 0, 1]])
    S = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1]])
    T = np.asarray(plane2cam)
    H = S @ cam.K @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ A
    big = (w * ss, h * ss)
    warped = cv2.warpPerspective(texture, H, big, flags=cv2.INTER_LINEAR, borderValue=0)
    mask = cv2.warpPerspective(np.full_like(texture, 255), H, big, flags=cv2.INTER_LINEAR, borderValue=0)
    warped = cv2.resize(warped, (w, h), interpolation=cv2.INTER_AREA).astype(float)
    a = cv2.resize(mask, (w, h), interpolation=cv2.INTER_AREA).astype(float) / 255
    base = np.full((h, w), background, np.uint8) if image is None else image
    return np.rint(a * warped + (1 - a) * base).astype(np.uint8)


def synthetic_rig(n_cams=4, n_instants=14, noise_px=0.3, rng=0, square=0.06, names=None):
    """Cameras on an arc in front of a moving chessboard: truth cameras and per-camera views."""
    from stillcap.calibrate.targets import Chessboard

    rng = np.random.default_rng(rng)
    board = Chessboard(9, 6, square)
    obj = board.object_points()
    names = names or [f"cam{i}" for i in range(n_cams)]
    cams = []
    for i, a in enumerate(np.radians(np.linspace(-50, 50, n_cams))):
        eye = np.array([2.2 * np.sin(a), -2.2 * np.cos(a), 1.0 + 0.3 * (i % 2)])
        cams.append(make_camera(names[i], fx=820 + 15 * i, fy=820 + 15 * i, cx=320 + 3 * i, cy=240 - 2 * i,
                                dist=(-0.1, 0.02, 0, 0, 0),
                                # rolled 180 deg (up = -z): the scenario these tests were written for
                                world2cam=look_at(eye, (0, 0, 1.0), up=(0, 0, -1))))
    R0 = np.column_stack([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).astype(float)  # board facing -y, rows down
    views = {c.name: [] for c in cams}
    b2w_true = []
    center = obj.mean(axis=0)
    for _ in range(n_instants):
        R = Rotation.from_rotvec(rng.uniform(-0.45, 0.45, 3)).as_matrix() @ R0
        p = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.8, 1.2)])
        T = pose_matrix(R, p - R @ center)
        b2w_true.append(T)
        for c in cams:
            px = c.project(obj @ T[:3, :3].T + T[:3, 3])
            normal_ok = (T[:3, :3] @ [0, 0, -1]) @ (c.center - p) > 0.3 * np.linalg.norm(c.center - p)
            inside = np.all(np.isfinite(px)) and np.all((px > 5) & (px < np.array(c.image_size) - 5))
            if normal_ok and inside:
                views[c.name].append((obj, px + rng.normal(0, noise_px, px.shape)))
            else:
                views[c.name].append(None)
    return SimpleNamespace(cameras=cams, views=views, board=board, board2world=b2w_true)


def detection(name, obj, px, size=(640, 480)) -> Detection:
    return Detection(name, size, np.asarray(obj, float), np.asarray(px, float), np.arange(len(obj)))


def stereo_detections(rng, n=10, noise=0.1):
    """A stereo pair (left, right cameras) and ``n`` pairs ``(key, left Detection, right Detection)``
    of a 9x6 board with ``noise`` px of Gaussian noise."""
    from stillcap.calibrate.targets import Chessboard

    obj = Chessboard(9, 6, 0.04).object_points()
    left = make_camera("L")
    right_pose = pose_matrix(Rotation.from_euler("y", -8, degrees=True).as_matrix(), [-0.12, 0.005, 0.01])
    right = make_camera("R", fx=790, fy=792, cx=318, cy=250, dist=(-0.15, 0.02, 0, 0, 0), world2cam=right_pose)
    pairs = []
    for i, T in enumerate(board_poses(left, obj, n, rng, depth=(0.5, 0.9), spread=0.2)):
        pl = project(left, T, obj, noise, rng)
        pr = project(right, right_pose @ T, obj, noise, rng)
        pairs.append((f"{i:02d}", detection(f"left{i:02d}", obj, pl), detection(f"right{i:02d}", obj, pr)))
    return left, right, pairs


@pytest.fixture(scope="session")
def synth():
    return SimpleNamespace(make_camera=make_camera, board_poses=board_poses, project=project,
                           render_plane=render_plane, synthetic_rig=synthetic_rig, detection=detection,
                           stereo_detections=stereo_detections)


@pytest.fixture(scope="session")
def stereo_dir():
    if not STEREO.is_dir():
        pytest.skip(f"real chessboard photos not found at {STEREO} (the shared data folder beside the repo)")
    return STEREO
