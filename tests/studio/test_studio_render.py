"""Renderer: truth consistency, occlusion, lighting, multi-exposure, distortion, sensor, targets."""

import cv2
import numpy as np
import pytest

from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard
from stillcap.camera import Camera, pose_matrix
from stillcap.studio import (Backdrop, Capsule, Exposure, Flash, PointLight, Scene, Sensor, Sphere,
                             SphereMarker, TexturedPlane, render, render_radiance, target_planes)
from stillcap.studio.renderer import _normalized_grid
from stillcap.studio.scenes import default_camera, random_board_pose, target_scene
from stillcap.studio.sensor import jpeg_roundtrip


def T(p, R=np.eye(3)):
    return pose_matrix(R, p)


@pytest.fixture
def cam():
    return Camera.from_intrinsics("c", 600.0, 600.0, 319.5, 239.5, (640, 480))


def conic_center(K, c, r):
    """Centre of the ellipse a sphere (centre c in the camera frame, radius r) projects to."""
    Ki = np.linalg.inv(K)
    C = Ki.T @ (np.outer(c, c) - (c @ c - r * r) * np.eye(3)) @ Ki
    return np.linalg.solve(C[:2, :2], -C[:2, 2])


def centroid(weights):
    ys, xs = np.nonzero(weights)
    w = weights[ys, xs]
    return np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()


def flat_ball_scene(centers, radius=0.03, albedo=1.0):
    """Balls lit only by ambient light: pixel value = coverage, so the centroid is geometric."""
    balls = [Sphere(radius, albedo=albedo) for _ in centers]
    return Scene(balls, Exposure.single([T(c) for c in centers], ambient=1.0))


def test_silhouette_centroid_is_projected_center(cam):
    rng = np.random.default_rng(1)
    for _ in range(6):
        c = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(1.2, 2.0)])
        r = rng.uniform(0.015, 0.04)
        rad = render_radiance(cam, flat_ball_scene([c], r))[..., 0]
        got = centroid(rad)
        assert np.linalg.norm(got - conic_center(cam.K, c, r)) < 0.04  # exact ellipse centre
        assert np.linalg.norm(got - cam.project(c)) < 0.1                 # the truth convention


def test_silhouette_area_matches_ellipse(cam):
    c, r = np.array([0.0, 0.0, 1.5]), 0.04
    rad = render_radiance(cam, flat_ball_scene([c], r))[..., 0]
    rho = 600 * r / np.sqrt(c @ c - r * r)  # on axis the silhouette is a circle of this radius
    assert rad.sum() == pytest.approx(np.pi * rho ** 2, rel=2e-3)


def test_front_sphere_hides_the_one_behind(cam):
    front, back = Sphere(0.05, albedo=(1, 1, 1)), Sphere(0.03, albedo=(1, 0, 0))
    for order in ([front, back], [back, front]):
        poses = [T([0, 0, 1.0]) if b is front else T([0.01, 0, 1.5]) for b in order]
        rad = render_radiance(cam, Scene(order, Exposure.single(poses, ambient=1.0)))
        red_only = rad[..., 0] - rad[..., 1]
        assert red_only.max() < 1e-6, "the sphere behind shows through"
        assert rad[..., 1].sum() > 0


def test_partial_overlap_nearest_wins(cam):
    near, far = Sphere(0.03, albedo=(0, 1, 0)), Sphere(0.05, albedo=(1, 0, 0))
    rad = render_radiance(cam, Scene([far, near], Exposure.single([T([0.05, 0, 1.5]), T([0, 0, 1.0])], ambient=1.0)))
    cx, cy = cam.project([0, 0, 1.0])
    assert rad[int(cy), int(cx), 1] == pytest.approx(1.0) and rad[int(cy), int(cx), 0] == 0
    assert rad[..., 0].max() == pytest.approx(1.0)  # the far one still shows beside the near one


def test_side_light_gives_half_moon(cam):
    c = np.array([0.0, 0.0, 1.5])
    amb = 0.01
    scene = Scene([Sphere(0.05, albedo=0.8)], Exposure.single([T(c)], ambient=amb), [PointLight([2.0, 0, 1.5], 4.0)])
    rad = render_radiance(cam, scene)[..., 1]
    x0, y0 = cam.project(c)
    rho = 600 * 0.05 / 1.5
    ys, xs = np.mgrid[:480, :640]
    inside = (xs - x0) ** 2 + (ys - y0) ** 2 < (0.9 * rho) ** 2
    far_half = inside & (xs < x0 - 0.1 * rho)
    near_half = inside & (xs > x0 + 0.1 * rho)
    assert np.all(rad[far_half] <= 0.8 * amb + 1e-6)  # the unlit half: ambient only, black-ish
    assert rad[near_half].mean() > 30 * 0.8 * amb


def test_multi_exposure_shows_k_silhouettes(cam):
    ball = Sphere(0.03, albedo=0.9)

    def poses(t):
        return [T([-0.4 + 4.0 * t, 0.05, 1.5])]

    ex = Exposure.strobe(poses, 50.0, 6, first_flash_s=0.01, ambient=0.002)
    scene = Scene([ball], ex, [PointLight([0, 0, 0], 2.0)])
    img = render(cam, scene, Sensor.ideal(), rng=0)
    n, labels = cv2.connectedComponents((img[..., 1] > 60).astype(np.uint8))
    assert n - 1 == 6
    truth = cam.project(np.array([poses(f.time)[0][:3, 3] for f in ex.flashes]))
    rad = render_radiance(cam, Scene([ball], Exposure.strobe(poses, 50.0, 6, 0.01, ambient=1.0)))[..., 0]
    for k in range(1, n):
        got = centroid(np.where(labels == k, rad, 0))
        assert np.min(np.linalg.norm(truth - got, axis=1)) < 0.1
    missed = Exposure.strobe(poses, 50.0, 6, 0.01, missed=[2])
    img = render(cam, Scene([ball], missed, [PointLight([0, 0, 0], 2.0)]), Sensor.ideal(), rng=0)
    assert cv2.connectedComponents((img[..., 1] > 60).astype(np.uint8))[0] - 1 == 5


def test_flash_exposures_add_up(cam):
    """Two flashes of a still ball give twice the radiance of one; ambient is counted once."""
    ball, pose = Sphere(0.04, albedo=0.5), T([0, 0, 1.2])
    light = [PointLight([0, 0, 0], 1.0)]
    one = render_radiance(cam, Scene([ball], Exposure([Flash([pose])], ambient=0.1), light))
    two = render_radiance(cam, Scene([ball], Exposure([Flash([pose]), Flash([pose])], ambient=0.1), light))
    y, x = 239, 319
    strobe = one[y, x, 0] - 0.05
    assert two[y, x, 0] == pytest.approx(0.05 + 2 * strobe, rel=1e-5)


def test_ambient_leaves_faint_ghosts_between_flashes(cam):
    """Without strobe light each of K flash positions holds 1/K of the ambient exposure."""
    ball = Sphere(0.03, albedo=0.8)
    ex = Exposure.strobe(lambda t: [T([-0.3 + 6.0 * t, 0, 1.5])], 50.0, 4, ambient=0.02)
    rad = render_radiance(cam, Scene([ball], ex, [], backdrop=Backdrop(0.001)))
    for f in ex.flashes:
        x, y = np.round(cam.project(f.poses[0][:3, 3])).astype(int)
        assert rad[y, x, 0] == pytest.approx(0.001 * 3 / 4 + 0.8 * 0.02 / 4, rel=1e-5)
    assert rad[5, 5, 0] == pytest.approx(0.001)


def test_a_flash_can_fire_its_own_lights(cam):
    """Two strobes at two rates: each flash lists the light that fires."""
    ball = Sphere(0.03, albedo=1.0)
    red, blue = PointLight([0, 0, 0], 1.0, (1, 0, 0)), PointLight([0, 0, 0], 1.0, (0, 0, 1))
    ex = Exposure([Flash([T([-0.2, 0, 1.5])], lights=[red]), Flash([T([0.2, 0, 1.5])], lights=[blue])])
    rad = render_radiance(cam, Scene([ball], ex))
    (xa, ya), (xb, yb) = np.round(cam.project(np.array([[-0.2, 0, 1.5], [0.2, 0, 1.5]]))).astype(int)
    assert rad[ya, xa, 0] > 0.3 and rad[ya, xa, 2] == 0
    assert rad[yb, xb, 2] > 0.3 and rad[yb, xb, 0] == 0


def test_distortion_puts_the_ball_where_project_says():
    cam = Camera.from_intrinsics("d", 700.0, 700.0, 330.0, 245.0, (640, 480), dist=[-0.28, 0.1, 0.001, -0.001, 0.0])
    for p in ([0.28, 0.2, 1.0], [-0.3, -0.18, 1.0], [0.25, -0.2, 0.9]):
        p = np.array(p)
        rad = render_radiance(cam, flat_ball_scene([p], 0.004))[..., 0]
        got = centroid(rad)
        assert np.linalg.norm(got - cam.project(p)) < 0.1
        assert np.linalg.norm(got - cam.project(p, distort=False)) > 5  # distortion did matter


def test_normalized_grid_matches_pixels_to_normalized():
    cam = Camera.from_intrinsics("d", 700.0, 700.0, 330.0, 245.0, (640, 480), dist=[-0.3, 0.12, 0.002, -0.001, -0.02])
    g = _normalized_grid(cam, 0, 0, 640, 480)
    ys, xs = np.mgrid[:480:7, :640:7]
    exact = cam.pixels_to_normalized(np.stack([xs.ravel(), ys.ravel()], 1).astype(float))
    err = cam.normalized_to_pixels(g[::7, ::7].reshape(-1, 2)) - cam.normalized_to_pixels(exact)
    assert np.abs(err).max() < 1e-3


def test_marker_center_and_shapes(cam):
    d = np.array([0.0, 0.0, -1.0])  # faces the camera with the identity ball pose
    c = np.array([0.0, 0.0, 1.0])
    areas = {}
    for shape in ("disc", "ring", "square", "triangle"):
        ball = Sphere(0.05, albedo=(1, 1, 1), markers=[SphereMarker(d, shape, 0.2, color=(1, 0, 0))])
        rad = render_radiance(cam, Scene([ball], Exposure.single([T(c)], ambient=1.0)))
        marker = rad[..., 0] - rad[..., 1]  # red paint only
        areas[shape] = marker.sum()
        assert np.linalg.norm(centroid(marker) - cam.project(c - [0, 0, 0.05])) < 0.15 or shape == "triangle"
        if shape == "ring":
            x, y = np.round(cam.project(c)).astype(int)
            assert marker[y, x] == 0  # the hole
    s = 0.2 * 600 * 0.05 / 0.95  # ~ projected size in px at the marker
    assert areas["disc"] == pytest.approx(np.pi * s * s, rel=0.05)
    assert areas["square"] == pytest.approx(4 * s * s, rel=0.05)
    assert areas["ring"] == pytest.approx(np.pi * s * s * (1 - 0.55 ** 2), rel=0.06)
    assert areas["triangle"] == pytest.approx(3 * np.sqrt(3) / 4 * s * s, rel=0.06)


def test_capsule_width(cam):
    limb = Capsule(0.3, 0.02, albedo=1.0)
    R = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # capsule axis along camera -y
    rad = render_radiance(cam, Scene([limb], Exposure.single([T([0, -0.15, 1.5], R)], ambient=1.0)))[..., 0]
    row = rad[240]
    assert row.sum() == pytest.approx(2 * 0.02 * 600 / 1.5, rel=0.02)


def test_static_wall_hides_a_ball_behind_it_and_lights_up(cam):
    wall = TexturedPlane((-1, -1, 1, 1), albedo=0.5)
    ball = Sphere(0.05, albedo=(1, 0, 0))
    scene = Scene([ball], Exposure.single([T([0, 0, 2.5])], ambient=0.0), [PointLight([0, 0, 0], 4.0)],
                  static=[(wall, T([0, 0, 2.0]))])
    rad = render_radiance(cam, scene)
    assert rad[..., 0].max() == pytest.approx(rad[..., 1].max(), rel=1e-6)  # no red anywhere
    assert rad[240, 320, 1] == pytest.approx(0.5 * 4.0 / 4.0, rel=1e-3)
    scene = Scene([ball], Exposure.single([T([0, 0, 1.5])]), [PointLight([0, 0, 0], 4.0)], static=[(wall, T([0, 0, 2.0]))])
    rad = render_radiance(cam, scene)
    assert rad[240, 320, 0] > 1.0 and rad[240, 320, 1] == 0  # the ball in front of the wall


def test_backdrop_texture_is_dark_and_low_contrast(cam):
    rad = render_radiance(cam, Scene(backdrop=Backdrop(0.01, 0.2, 30.0)), rng=3)
    assert rad.min() >= 0 and abs(rad.mean() - 0.01) < 0.002 and 0.0005 < rad.std() < 0.004


# --- sensor ---------------------------------------------------------------------------------------
def test_saturation_clips_without_wrapping(cam):
    scene = Scene([Sphere(0.05, albedo=1.0)], Exposure.single([T([0, 0, 1.0])]), [PointLight([0, 0, 0], 50.0)])
    img = render(cam, scene, Sensor(), rng=0)
    assert img.dtype == np.uint8 and img.shape == (480, 640, 3)
    x, y = np.round(cam.project([0, 0, 1.0])).astype(int)
    assert np.all(img[y - 10:y + 10, x - 10:x + 10] == 255)


def test_noise_is_seeded_and_sized():
    flat = np.full((200, 300, 3), 0.2, np.float32)
    s = Sensor(full_well=5000.0, read_noise=0.004, gamma=1.0, blur_px=0.0)
    a, b, c = s.expose(flat, 1), s.expose(flat, 1), s.expose(flat, 2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    sd = np.sqrt(0.2 / 5000 + 0.004 ** 2) * 255
    assert a.astype(float).std() == pytest.approx(sd, rel=0.1)
    assert a.astype(float).mean() == pytest.approx(0.2 * 255, abs=0.5)


def test_srgb_encoding_and_bgr_order():
    rad = np.zeros((2, 2, 3), np.float32)
    rad[..., 0] = 0.2  # red only
    img = Sensor.ideal().expose(rad)
    srgb = 1.055 * 0.2 ** (1 / 2.4) - 0.055
    assert img[0, 0, 2] == round(255 * srgb) and img[0, 0, 0] == 0  # OpenCV order: B, G, R


def test_jpeg_roundtrip_is_real(cam):
    scene = Scene([Sphere(0.05, markers=[SphereMarker([0, 0, -1], "square", 0.3)])], Exposure.single([T([0, 0, 1.0])]),
                  [PointLight([0, 0, 0], 0.8)])
    rad = render_radiance(cam, scene)
    png = Sensor().expose(rad, 5)
    jpg = Sensor(jpeg_quality=70).expose(rad, 5)
    assert jpg.shape == png.shape and jpg.dtype == np.uint8
    assert np.array_equal(jpg, jpeg_roundtrip(png, 70))
    diff = np.abs(jpg.astype(int) - png.astype(int))
    assert 0 < diff.mean() < 3 and diff.max() > 5


# --- targets --------------------------------------------------------------------------------------
def _corner_rms(img, target, truth):
    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    ok, c = cv2.findChessboardCorners(g, target.pattern_size)
    assert ok, "OpenCV did not find the rendered board"
    c = cv2.cornerSubPix(g, c, (11, 11), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)).reshape(-1, 2)
    if np.linalg.norm(c[0] - truth[0]) > np.linalg.norm(c[-1] - truth[0]):
        c = c[::-1]  # OpenCV may list the corners from the other end
    return np.sqrt(np.mean(np.sum((c - truth) ** 2, axis=1)))


def test_rendered_chessboard_corners_are_subpixel_exact():
    cam = default_camera()  # 1280x960 with distortion
    board = Chessboard(9, 6, 0.025)
    rng = np.random.default_rng(7)
    for _ in range(2):
        pose = random_board_pose(cam, board, rng)
        img = render(cam, target_scene(cam, board, pose, rng), Sensor.ideal(), rng)
        truth = cam.project(board.object_points() @ pose[:3, :3].T + pose[:3, 3])
        assert _corner_rms(img, board, truth) < 0.1


def test_charuco_board_is_detected_at_its_true_corners():
    cam = Camera.from_intrinsics("c", 900.0, 900.0, 479.5, 359.5, (960, 720), dist=[-0.05, 0.01, 0, 0, 0])
    board = CharucoTarget(6, 4, 0.04, 0.03)
    pose = T([-0.12, -0.08, 0.6], cv2.Rodrigues(np.array([0.3, -0.2, 0.05]))[0])
    img = render(cam, target_scene(cam, board, pose, 0), Sensor.ideal(blur_px=0.5), 0)
    det = cv2.aruco.CharucoDetector(board.board())
    corners, ids, _, _ = det.detectBoard(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    assert ids is not None and len(ids) >= 0.9 * len(board.object_points())
    truth = cam.project(board.object_points()[ids.ravel()] @ pose[:3, :3].T + pose[:3, 3])
    assert np.sqrt(np.mean(np.sum((corners.reshape(-1, 2) - truth) ** 2, axis=1))) < 0.15


def inside_corner_box(square=0.04):
    """Three ChArUco faces on the inside of a corner, each board's z axis pointing into its face
    (so the prints read correctly from the inside, as OpenCV expects)."""
    box = CalibrationObject.charuco_box(square, (5, 5))
    rots = [np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]]),   # z = 0 face
            np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]]),   # x = 0 face
            np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])]   # y = 0 face
    return CalibrationObject(box.faces, tuple(pose_matrix(R, np.zeros(3)) for R in rots))


def test_calibration_object_shows_all_faces():
    cam = default_camera()
    obj = inside_corner_box()
    pose = random_board_pose(cam, obj, 2)
    img = render(cam, target_scene(cam, obj, pose, 2), Sensor.ideal(blur_px=0.5), 2)
    d = cv2.aruco.getPredefinedDictionary(obj.faces[0].dictionary)
    _, ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    ids = set(ids.ravel().tolist())
    per = 12  # markers per 5x5 face
    assert all(len(ids & set(range(k * per, (k + 1) * per))) >= per // 2 for k in range(3))


def test_target_planes_place_the_texture():
    board = Chessboard(4, 3, 0.05)
    (plane, pose), = target_planes(board, np.eye(4), 16)
    assert plane.extent == board.extent and pose.shape == (4, 4)
    assert len(target_planes(CalibrationObject.charuco_box(), np.eye(4))) == 3


# --- input validation -----------------------------------------------------------------------------
def test_bad_inputs_name_the_problem(cam):
    with pytest.raises(ValueError, match="shape"):
        SphereMarker([0, 0, 1], "star")
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        Flash([np.eye(3)])
    with pytest.raises(ValueError, match="1 poses for 2 bodies"):
        Scene([Sphere(0.1), Sphere(0.1)], Exposure.single([np.eye(4)]))
    with pytest.raises(ValueError, match="radius"):
        Sphere(-1.0)
    with pytest.raises(ValueError, match="Camera"):
        render_radiance("cam", Scene())
    with pytest.raises(ValueError, match=r"\(h, w, 3\), got \(4, 4\)"):
        Sensor().expose(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="supersample"):
        render_radiance(cam, Scene(), supersample=0)


def test_lens_blur_near_bodies_only_equals_full_blur(cam):
    from stillcap.studio.renderer import _render_radiance
    from stillcap.studio.sensor import _blur

    balls = [Sphere(0.03, albedo=0.9) for _ in range(3)]
    poses = [T([-0.3, 0, 1.5]), T([0.0, 0.1, 1.5]), T([0.02, 0.12, 1.4])]
    scene = Scene(balls, Exposure.single(poses, ambient=0.1), [PointLight([0, 0, 0], 2.0)],
                  backdrop=Backdrop(0.01, 0.3, 48.0))
    rad, boxes = _render_radiance(cam, scene, 3, 0)
    full = cv2.GaussianBlur(rad, (0, 0), 0.5, borderType=cv2.BORDER_REPLICATE)
    assert np.abs(_blur(rad, 0.5, boxes) - full).max() < 2e-5  # below the 14-bit quantisation step
