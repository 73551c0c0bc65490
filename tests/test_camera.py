import json

import cv2
import numpy as np
import pytest

from stillcap.camera import Camera, Rig, look_at, pose_matrix
from stillcap.calibrate.turntable import turntable_rig

from support import ring_rig


def distorted_camera():
    return Camera.from_intrinsics("c", 900, 905, 650, 470, (1280, 960), dist=(-0.2, 0.08, 0.001, -0.002, -0.01),
                                  world2cam=look_at((1, -2, 0.5), (0, 0, 0.2)))


def test_project_matches_opencv():
    cam = distorted_camera()
    X = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 3))
    rvec, _ = cv2.Rodrigues(cam.R)
    ref, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, cam.dist)
    np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), atol=1e-9)


def test_project_nan_and_behind_camera_give_nan():
    cam = distorted_camera()
    X = np.array([[0, 0, 0.2], [np.nan, 0, 0], cam.center + 2 * (cam.center - [0, 0, 0.2])])
    px = cam.project(X)
    assert np.all(np.isfinite(px[0])) and np.all(np.isnan(px[1:]))


def test_undistort_inverts_distort():
    cam = distorted_camera()
    rng = np.random.default_rng(1)
    xn = rng.uniform(-0.6, 0.6, (500, 2))
    px = cam.normalized_to_pixels(xn)
    np.testing.assert_allclose(cam.pixels_to_normalized(px), xn, atol=1e-9)
    np.testing.assert_allclose(cam.undistort_points(px), cam.normalized_to_pixels(xn, distort=False), atol=1e-6)


def test_rays_pass_through_the_point():
    cam = distorted_camera()
    X = np.random.default_rng(2).uniform(-0.3, 0.3, (50, 3))
    o, d = cam.rays(cam.project(X))
    v = X - o
    # distance from X to the ray
    dist = np.linalg.norm(v - (v * d).sum(1, keepdims=True) * d, axis=1)
    assert dist.max() < 1e-9
    np.testing.assert_allclose(o[0], cam.center)


def test_look_at_keeps_up_up_and_right_right():
    # regression: look_at once built cameras rolled by 180 degrees (upside-down images)
    cam = Camera.from_intrinsics("c", 800, 800, 320, 240, (640, 480), world2cam=look_at((0, -5, 1), (0, 0, 1)))
    center = cam.project([0, 0, 1])
    assert cam.project([0, 0, 2])[1] < center[1]      # world up is up in the image
    assert cam.project([1, 0, 1])[0] > center[0]      # world +x is to the right, seen from -y
    np.testing.assert_allclose(np.linalg.det(cam.R), 1.0)


def test_center_and_cam2world():
    cam = distorted_camera()
    np.testing.assert_allclose(cam.center, [1, -2, 0.5], atol=1e-12)
    np.testing.assert_allclose(cam.cam2world @ cam.world2cam, np.eye(4), atol=1e-12)


def test_undistort_image_moves_a_dot_to_its_ideal_pixel():
    cam = distorted_camera()
    ideal = np.array([1100.0, 150.0])  # near a corner, where distortion is strong
    xn = cam.pixels_to_normalized(cam.normalized_to_pixels(
        ((ideal - cam.K[:2, 2]) / np.diag(cam.K)[:2])[None]))[0]
    dist_px = cam.normalized_to_pixels(xn[None])[0]
    img = np.zeros((960, 1280), np.uint8)
    cv2.circle(img, tuple(int(round(v)) for v in dist_px), 4, 255, -1)
    und = cam.undistort_image(img).astype(float)
    ys, xs = np.nonzero(und > 0)
    w = und[ys, xs]
    c = np.array([(xs * w).sum() / w.sum(), (ys * w).sum() / w.sum()])
    assert np.linalg.norm(c - ideal) < 1.0


def test_undistort_image_checks_size():
    with pytest.raises(ValueError, match="1280x960"):
        distorted_camera().undistort_image(np.zeros((10, 10)))


def test_bad_camera_inputs():
    with pytest.raises(ValueError, match=r"K must have shape \(3, 3\), got \(2, 2\)"):
        Camera("x", np.eye(2))
    with pytest.raises(ValueError, match="not a proper rotation"):
        Camera("x", np.eye(3), world2cam=np.diag([1, 1, -1, 1.0]))
    with pytest.raises(ValueError, match=r"points_world must have shape \(3,\) or \(N, 3\), got \(4, 2\)"):
        distorted_camera().project(np.zeros((4, 2)))


def test_rig_json_round_trip_keeps_order(tmp_path):
    rig = ring_rig(3)
    names = ["cam_10", "cam_2", "cam_1"]
    rig = Rig([c.with_pose(c.world2cam) for c in rig])
    for c, n in zip(rig, names):
        c.name = n
    rig.save(tmp_path / "rig.json")
    back = Rig.load(tmp_path / "rig.json")
    assert back.names == names
    for a, b in zip(rig, back):
        np.testing.assert_allclose(a.K, b.K)
        np.testing.assert_allclose(a.world2cam, b.world2cam)
        assert a.image_size == b.image_size
    assert back["cam_2"].name == "cam_2"


def test_rig_file_in_millimetres(tmp_path):
    d = ring_rig(2).to_dict()
    for c in d["cameras"]:
        T = np.array(c["world2cam"])
        T[:3, 3] *= 1000.0  # the translation in mm; the last row stays [0, 0, 0, 1]
        c["world2cam"] = T.tolist()
    d["units"] = "mm"
    (tmp_path / "r.json").write_text(json.dumps(d))
    np.testing.assert_allclose(Rig.load(tmp_path / "r.json")[0].center, ring_rig(2)[0].center)


def test_rig_bad_files(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        Rig.load(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="bad.json is not valid JSON"):
        Rig.load(tmp_path / "bad.json")
    (tmp_path / "other.json").write_text('{"cameras": []}')
    with pytest.raises(ValueError, match="not a stillcap rig file"):
        Rig.load(tmp_path / "other.json")
    d = ring_rig(1).to_dict()
    del d["cameras"][0]["K"]
    (tmp_path / "nok.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"nok.json: camera 'cam_0': cameras.0.K: field required$"):
        Rig.load(tmp_path / "nok.json")
    with pytest.raises(ValueError, match="duplicate camera names"):
        Rig([ring_rig(1)[0], ring_rig(1)[0]])
    with pytest.raises(KeyError, match="no camera named 'zzz'"):
        ring_rig(2)["zzz"]


def test_save_is_atomic_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "rig.json"
    ring_rig(2).save(path)
    before = path.read_text()
    import stillcap.files.atomic as atomic

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "replace", boom)
    with pytest.raises(OSError):
        ring_rig(3).save(path)
    assert path.read_text() == before
    assert list(tmp_path.iterdir()) == [path]


def test_import_opencv_single_and_stereo(tmp_path):
    cam = distorted_camera()
    fs = cv2.FileStorage(str(tmp_path / "cam.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 960)
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", cam.dist.reshape(1, 5))
    fs.release()
    rig = Rig.from_opencv(tmp_path / "cam.yml")
    np.testing.assert_allclose(rig[0].K, cam.K)
    np.testing.assert_allclose(rig[0].dist, cam.dist)
    assert rig[0].image_size == (1280, 960)

    R = look_at((0, 0, 0), (0.1, 0, 1), up=(0, -1, 0))[:3, :3]
    T = np.array([[-3.3], [0.04], [0.05]])
    fs = cv2.FileStorage(str(tmp_path / "intrinsics.yml"), cv2.FILE_STORAGE_WRITE)
    for k, v in {"M1": cam.K, "D1": cam.dist, "M2": cam.K * [[1.01], [1.01], [1]], "D2": cam.dist}.items():
        fs.write(k, np.asarray(v))
    fs.release()
    fs = cv2.FileStorage(str(tmp_path / "extrinsics.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("R", R)
    fs.write("T", T)
    fs.release()
    st = Rig.from_opencv(tmp_path / "intrinsics.yml", tmp_path / "extrinsics.xml", image_size=(640, 480),
                         square_size=0.025)
    assert st.names == ["left", "right"]
    np.testing.assert_allclose(st["right"].world2cam, pose_matrix(R, T.ravel() * 0.025))
    with pytest.raises(ValueError, match="no image size"):
        Rig.from_opencv(tmp_path / "intrinsics.yml", tmp_path / "extrinsics.xml")
    with pytest.raises(ValueError, match="does not exist"):
        Rig.from_opencv(tmp_path / "missing.yml")


def test_turntable_rig_matches_thesis_geometry():
    rig = turntable_rig()
    assert len(rig) == 12
    for i, cam in enumerate(rig):
        a = np.radians(30 * i)
        np.testing.assert_allclose(cam.center, [-0.4 * np.sin(a), 0.08, 0.4 * np.cos(a)], atol=1e-12)
        # the turn axis point at lens height images at the principal point
        np.testing.assert_allclose(cam.project([0, 0.08, 0]), cam.K[:2, 2], atol=1e-9)
        # world y (up the axis) points up in the image (camera y is down)
        assert cam.project([0, 0.1, 0])[1] < cam.project([0, 0.08, 0])[1]
    with pytest.raises(ValueError, match="n_views"):
        turntable_rig(0)


def test_saved_files_get_normal_permissions(tmp_path):
    import os
    import stat

    path = ring_rig(1).save(tmp_path / "rig.json")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_project_does_not_fold_far_points_back_into_the_image():
    """Barrel distortion r(1 + k1 r^2) peaks at r^2 = -1/(3 k1): a point far outside the view
    used to land back inside the image; now it has no pixel (NaN)."""
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    cam = Camera("c", K, [-0.3, 0, 0, 0, 0], np.eye(4), (640, 480))
    assert cam.max_distortion_r2 == pytest.approx(1 / 0.9)
    far = np.array([[3.0, 0.0, 1.0]])  # r = 3: folded to x_d = 3 (1 - 2.7) = -5.1 before
    near = np.array([[0.2, 0.1, 1.0]])
    assert np.all(np.isnan(cam.project(far)))
    r2 = 0.05
    assert cam.project(near)[0] == pytest.approx([320 + 800 * 0.2 * (1 - 0.3 * r2), 240 + 800 * 0.1 * (1 - 0.3 * r2)])
    assert Camera("p", K, np.zeros(5), np.eye(4), (640, 480)).max_distortion_r2 == np.inf
    cam.dist[0] = -0.15  # changed in place (as bundle adjustment does): the limit follows
    assert cam.max_distortion_r2 == pytest.approx(1 / 0.45)


def test_rig_project_is_each_cameras_projection_exactly():
    """Rig.project (the pinhole cameras in stacked array operations) gives every camera's own
    Camera.project to the bit: skewed and distorted lenses, NaN points, points behind a camera."""
    rng = np.random.default_rng(5)
    cams = [Camera.from_intrinsics(f"c{i}", rng.uniform(400, 3000), rng.uniform(400, 3000), 320, 240, (640, 480),
                                   world2cam=look_at(rng.normal(0, 1.5, 3), rng.normal(0, 0.1, 3)))
            for i in range(7)]
    K = cams[1].K.copy()
    K[0, 1] = 0.7  # skew
    cams[1] = Camera("skew", K, np.zeros(5), cams[1].world2cam, (640, 480))
    cams[2] = distorted_camera()
    rig = Rig(cams)
    X = rng.normal(0, 1.0, (300, 3))
    X[::17] = np.nan
    got = rig.project(X)
    want = np.stack([c.project(X) for c in cams])
    assert got.shape == (7, 300, 2) and np.isnan(got).any() and np.isfinite(got).sum() > 1000
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(rig.project(X[3]), np.stack([c.project(X[3:4]) for c in cams]))
    assert rig.project(np.zeros((0, 3))).shape == (7, 0, 2)


def test_distortion_flags_are_np_any_of_the_coefficients():
    """Camera.distorted / radially_distorted: np.any of all five coefficients / of k1, k2, k3
    (NaN counts as non-zero, -0.0 as zero), also after an in-place change."""
    cam = Camera.from_intrinsics("c", 500.0, 500.0, 320.0, 240.0, (640, 480))
    for d in ([0, 0, 0, 0, 0], [-0.0, 0, 0, 0, 0], [0.1, 0, 0, 0, 0], [0, 0, 1e-3, 0, 0], [0, 0, 0, -2e-3, 0],
              [0, 0, 0, 0, 0.5], [np.nan, 0, 0, 0, 0], [0, 0, np.nan, 0, 0], [0, -0.2, 0, 0, 0]):
        cam.dist[:] = d
        assert cam.distorted == bool(np.any(cam.dist))
        assert cam.radially_distorted == bool(np.any(cam.dist[[0, 1, 4]]))
        assert isinstance(cam.distorted, bool) and isinstance(cam.radially_distorted, bool)
