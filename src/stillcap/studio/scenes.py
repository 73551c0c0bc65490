"""Ready-made studio scenarios with ground truth: chessboard sets and multi-camera marker scenes.

Each scenario has an in-memory function returning images and truth (for tests and demos) and a
``to_capture`` method giving the capture folder (:class:`stillcap.io.capture.Capture`) that
``stillcap studio ...`` writes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._progress import report_progress
from stillcap._checks import as_rng
from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard
from stillcap.camera import Camera, Rig, look_at, pose_matrix
from stillcap.response import Response
from stillcap.io.capture import Capture, CaptureImage, target_to_dict
from stillcap.detect.blobs import MARKER_BALL_COLORS
from stillcap.studio.markers import baseball_markers
from stillcap.studio.renderer import render
from stillcap.studio.scene import Backdrop, Exposure, PointLight, Scene, Sphere, target_planes
from stillcap.studio.sensor import Sensor

BASEBALL_RADIUS = 0.0737 / 2  # m



def default_camera(name: str = "cam0", image_size=(1280, 960)) -> Camera:
    """A 1280x960 camera with a mild barrel distortion (the studio's calibration subject)."""
    w, h = image_size
    s = w / 1280
    return Camera.from_intrinsics(name, 1108.0 * s, 1102.5 * s, (w - 1) / 2 + 3.7 * s, (h - 1) / 2 - 2.9 * s,
                                  (w, h), dist=[-0.11, 0.07, 0.0006, -0.0004, -0.01])


def nominal_camera(camera: Camera) -> Camera:
    """An uncalibrated stand-in for ``camera``: same name, size and pose, focal length = image
    width, principal point at the centre, no distortion (what a calibration capture's rig holds)."""
    w, h = camera.image_size
    return Camera.from_intrinsics(camera.name, float(w), float(w), (w - 1) / 2, (h - 1) / 2, (w, h),
                                  world2cam=camera.world2cam)


# --- chessboards -----------------------------------------------------------------------------
@dataclass
class ChessboardSet:
    """Photos of a calibration target in random poses, with the truth.

    Attributes
    ----------
    camera : Camera
        The true camera (its pose is the world frame of ``board2world``).
    target : Chessboard, CharucoTarget or CalibrationObject
    board2cam : np.ndarray, shape (n_views, 4, 4)
    images : list of np.ndarray, each (height, width, 3) uint8 BGR
    corners_px : list of np.ndarray
        True pixel positions of :meth:`target.object_points` per view, ``(n_corners, 2)``
        (for a calibration object: all faces' corners stacked in face order).
    response : Response, optional
        The response the photos are encoded with (the sensor's), recorded in the truth.
    """

    camera: Camera
    target: object
    board2cam: np.ndarray
    images: list
    corners_px: list
    response: Response | None = None

    @property
    def kind(self) -> str:
        return {Chessboard: "chessboard", CharucoTarget: "charuco"}.get(type(self.target), "calibration-object")

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        """The capture folder content: ``(Capture, {file: image})``; the rig holds the nominal
        (uncalibrated) camera, ``truth`` the true one and the board poses."""
        files = [f"images/view_{i:03d}{ext}" for i in range(len(self.images))]
        imgs = [CaptureImage(f, self.camera.name, meta={"view": i}) for i, f in enumerate(files)]
        truth = {"kind": self.kind, "camera": self.camera.to_dict(),
                 "views": [{"file": f, "board2cam": T, "corners_px": c}
                           for f, T, c in zip(files, self.board2cam, self.corners_px)]}
        if self.response is not None:
            truth["response"] = self.response.to_json()
        meta = {"synthetic": True, "rig_calibrated": False, "target": target_to_dict(self.target),
                "description": f"synthetic {self.kind} calibration set, {len(files)} views"}
        cap = Capture(self.kind, Rig([nominal_camera(self.camera)]), imgs, truth, meta)
        return cap, dict(zip(files, self.images))


def _target_points(target) -> np.ndarray:
    pts = target.object_points()
    return np.concatenate(pts) if isinstance(pts, list) else pts


def _outline(target) -> np.ndarray:
    """Points on the printed outline of a target (all faces), target frame ``(N, 3)``."""
    faces = list(zip(target.faces, target.face2object)) if isinstance(target, CalibrationObject) \
        else [(target, np.eye(4))]
    out = []
    s = np.linspace(0, 1, 9)
    for f, T in faces:
        x0, y0, x1, y1 = f.extent
        e = np.concatenate([np.stack([x0 + (x1 - x0) * s, np.full_like(s, y0)], 1),
                            np.stack([np.full_like(s, x1), y0 + (y1 - y0) * s], 1),
                            np.stack([x1 - (x1 - x0) * s, np.full_like(s, y1)], 1),
                            np.stack([np.full_like(s, x0), y1 - (y1 - y0) * s], 1)])
        p = np.concatenate([e, np.zeros((len(e), 1))], 1)
        T = np.asarray(T, float)
        out.append(p @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(out)


def random_board_pose(camera: Camera, target, rng=None, max_tilt_deg: float = 40.0,
                      fill=(0.35, 0.8), margin_px: float = 12.0, max_tries: int = 500) -> np.ndarray:
    """A random ``board2cam`` (4, 4) with the whole target inside the image.

    The board faces the camera, tilted up to ``max_tilt_deg`` about a random in-plane axis and
    turned up to 15 degrees in its plane; its width covers a ``fill`` fraction of the image width.
    A :class:`CalibrationObject` shows its inside corner (looked at along its (1, 1, 1)
    diagonal), tilted up to 15 degrees.
    """
    rng = as_rng(rng)
    W, H = camera.image_size
    outline = _outline(target)
    center = (outline.min(axis=0) + outline.max(axis=0)) / 2
    width = np.ptp(outline[:, :2], axis=0).max()
    Kinv = np.linalg.inv(camera.K)
    probe = Camera(camera.name, camera.K, camera.dist, np.eye(4), camera.image_size)
    base = np.eye(3)
    if isinstance(target, CalibrationObject):  # look into the inside corner along (1, 1, 1)
        base = Rotation.align_vectors([[0, 0, -1]], [np.ones(3) / np.sqrt(3)])[0].as_matrix()
        max_tilt_deg = min(max_tilt_deg, 15.0)  # each face is already 55 degrees off the view axis
    for _ in range(max_tries):
        axis_ang = rng.uniform(0, 2 * np.pi)
        tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform())
        R = (Rotation.from_rotvec(tilt * np.array([np.cos(axis_ang), np.sin(axis_ang), 0]))
             * Rotation.from_rotvec([0, 0, np.radians(rng.uniform(-15, 15))])).as_matrix() @ base
        z = camera.K[0, 0] * width / (rng.uniform(*fill) * W)
        uv = rng.uniform([0.3 * W, 0.3 * H], [0.7 * W, 0.7 * H])
        t = z * (Kinv @ np.array([uv[0], uv[1], 1.0])) - R @ center
        T = pose_matrix(R, t)
        px = probe.project(outline @ R.T + t)
        if np.all(np.isfinite(px)) and np.all(px >= margin_px) and np.all(px <= [W - 1 - margin_px, H - 1 - margin_px]):
            return T
    raise ValueError(f"could not place the target fully inside a {W}x{H} image in {max_tries} tries")


def target_scene(camera: Camera, target, board2cam, rng=None, supersample: int = 3) -> Scene:
    """A still scene of ``target`` at ``board2cam`` on a grey, softly lit background."""
    rng = as_rng(rng)
    board2cam = np.asarray(board2cam, float)
    board2world = camera.cam2world @ board2cam
    pts = _target_points(target) @ board2cam[:3, :3].T + board2cam[:3, 3]
    z = float(np.median(pts[:, 2]))
    square = getattr(target, "square", None) or target.faces[0].square
    sq_px = camera.K[0, 0] * square / z
    pps = int(np.clip(np.ceil(1.5 * supersample * sq_px), 16, 192))  # texel ~ a sub-sample
    # lamp beside the camera, at a random side; brightness independent of the distance
    lamp_cam = z * np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, -0.2), 0.0])
    lamp = camera.cam2world[:3, :3] @ lamp_cam + camera.center
    return Scene.still(target_planes(target, board2world, pps), [PointLight(lamp, 0.55 * z * z)],
                       ambient=0.3, backdrop=Backdrop(0.15, 0.1, 60.0))


def chessboard_set(camera: Camera | None = None, n_views: int = 15, target=None, rng=None,
                   sensor: Sensor | None = None, supersample: int = 3,
                   progress: Callable[[int, int], None] | None = None) -> ChessboardSet:
    """Render ``n_views`` photos of a calibration target in random plausible poses.

    Parameters
    ----------
    camera : Camera, optional
        The camera to calibrate (default :func:`default_camera`).
    n_views : int
    target : Chessboard, CharucoTarget or CalibrationObject, optional
        Default ``Chessboard(9, 6, 0.025)``.
    rng : np.random.Generator or int, optional
    sensor : Sensor, optional
        Default: ``Sensor()`` (shot and read noise).
    progress : callable(i, n), optional
        Called after each rendered view.
    """
    rng = as_rng(rng)
    camera = camera or default_camera()
    target = target if target is not None else Chessboard(9, 6, 0.025)
    if n_views < 1:
        raise ValueError(f"n_views must be >= 1, got {n_views}")
    sensor = sensor or Sensor()
    probe = Camera(camera.name, camera.K, camera.dist, np.eye(4), camera.image_size)
    poses, images, corners = [], [], []
    for i in range(n_views):
        T = random_board_pose(camera, target, rng)
        scene = target_scene(camera, target, T, rng, supersample)
        images.append(render(camera, scene, sensor, rng, supersample))
        corners.append(probe.project(_target_points(target) @ T[:3, :3].T + T[:3, 3]))
        poses.append(T)
        report_progress(progress, i + 1, n_views)
    return ChessboardSet(camera, target, np.array(poses), images, corners, sensor.response)


@dataclass
class RigBoardSet:
    """Photos of one calibration target taken by every camera of a rig at shared instants.

    Attributes
    ----------
    rig : Rig
        The true rig.
    target : Chessboard or CharucoTarget
    board2world : np.ndarray, shape (n_instants, 4, 4)
    images : dict[str, list]
        Per camera name, one image per instant, ``None`` where that camera does not see the
        whole board (it faces away or leaves the image).
    """

    rig: Rig
    target: object
    board2world: np.ndarray
    images: dict

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        """Capture folder content; files are ``images/<camera>/instant_<k>.png`` so that the
        folder is also the input of ``stillcap calibrate rig`` (one subfolder per camera)."""
        imgs, files = [], {}
        for cam in self.rig:
            for k, im in enumerate(self.images[cam.name]):
                if im is not None:
                    f = f"images/{cam.name}/instant_{k:03d}{ext}"
                    imgs.append(CaptureImage(f, cam.name, meta={"instant": k}))
                    files[f] = im
        truth = {"kind": "rig-boards", "rig": self.rig.to_dict(), "board2world": self.board2world}
        meta = {"synthetic": True, "rig_calibrated": False, "target": target_to_dict(self.target),
                "description": f"synthetic rig calibration set, {len(self.board2world)} instants"}
        rig = Rig([nominal_camera(c) for c in self.rig])
        return Capture("rig-boards", rig, imgs, truth, meta), files


def rig_board_set(rig: Rig, n_instants: int = 12, target=None, rng=None, sensor: Sensor | None = None,
                  center=(0.0, 0.0, 1.0), spread: float = 0.35, min_cameras: int = 2,
                  max_view_deg: float = 60.0,
                  supersample: int = 3, progress: Callable[[int, int], None] | None = None) -> RigBoardSet:
    """Render a board held in front of a whole rig at ``n_instants`` random poses.

    The board is placed around ``center`` (world, metres, +-``spread``), facing the mean camera
    direction with a random tilt of up to 35 degrees; a camera photographs it when it sees the
    whole board from its printed side at most ``max_view_deg`` from the board's normal (as a
    person holding a board turns it towards the cameras); a pose is kept when at least
    ``min_cameras`` cameras photograph it.
    """
    rng = as_rng(rng)
    target = target if target is not None else Chessboard(9, 6, 0.06)
    if n_instants < 1:
        raise ValueError(f"n_instants must be >= 1, got {n_instants}")
    sensor = sensor or Sensor()
    center = np.asarray(center, float)
    view = np.mean([c.center for c in rig], axis=0) - center
    outline = _outline(target)
    mid = (outline.min(axis=0) + outline.max(axis=0)) / 2
    poses, images = [], {c.name: [] for c in rig}
    total = n_instants * len(rig)
    for k in range(n_instants):
        for _ in range(500):
            # board z axis points away from the cameras (printed side towards them)
            face = Rotation.align_vectors([-view], [[0.0, 0.0, 1.0]])[0]
            tilt = Rotation.from_rotvec(np.radians(35) * np.sqrt(rng.uniform()) *
                                        np.array([*rng.normal(size=2), 0]) / np.sqrt(2))
            spin = Rotation.from_rotvec([0, 0, rng.uniform(-np.pi, np.pi)])
            R = (face * tilt * spin).as_matrix()
            T = pose_matrix(R, center + rng.uniform(-spread, spread, 3) - R @ mid)
            seen = []
            for cam in rig:
                corners = outline @ T[:3, :3].T + T[:3, 3]
                px = cam.project(corners)
                W, H = cam.image_size
                to_cam = cam.center - T[:3, 3]
                facing = -np.dot(T[:3, 2], to_cam) > np.cos(np.radians(max_view_deg)) * np.linalg.norm(to_cam)
                seen.append(bool(facing and np.all(np.isfinite(px)) and np.all(px >= 10)
                                 and np.all(px <= [W - 11, H - 11])))
            if sum(seen) >= min_cameras:
                break
        else:
            raise ValueError(f"could not place the board where {min_cameras} cameras see it; "
                             "move 'center' in front of the rig")
        poses.append(T)
        for i, cam in enumerate(rig):
            img = None
            if seen[i]:
                board2cam = cam.world2cam @ T
                img = render(cam, target_scene(cam, target, board2cam, rng, supersample), sensor, rng, supersample)
            images[cam.name].append(img)
            report_progress(progress, k * len(rig) + i + 1, total)
    return RigBoardSet(rig, target, np.array(poses), images)


# --- marker scenes ---------------------------------------------------------------------------
def marker_rig(n_cameras: int = 4, image_size=(1280, 960), rng=None, radius: float = 2.5,
               height: float = 1.6, arc_deg: float = 120.0) -> Rig:
    """Cameras on an arc around a ~1 m volume centred at ``(0, 0, 1)`` (world z up).

    Cameras ``cam0 ...`` stand ``radius`` metres from the z axis at ``height``, spread over
    ``arc_deg`` around the -y direction, with slightly different intrinsics and mild distortion.
    """
    if n_cameras < 1:
        raise ValueError(f"n_cameras must be >= 1, got {n_cameras}")
    rng = as_rng(rng)
    w, h = image_size
    cams = []
    az = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, n_cameras)) if n_cameras > 1 else np.zeros(1)
    for i, a in enumerate(az):
        eye = np.array([radius * np.sin(a), -radius * np.cos(a), height])
        target = np.array([0, 0, 1.0]) + rng.normal(0, 0.03, 3)
        f = 1.35 * w * (1 + rng.normal(0, 0.01))
        cams.append(Camera.from_intrinsics(
            f"cam{i}", f, f * (1 + rng.normal(0, 0.002)), (w - 1) / 2 + rng.normal(0, 4), (h - 1) / 2 + rng.normal(0, 4),
            (w, h), dist=[-0.08 + rng.normal(0, 0.01), 0.04, rng.normal(0, 3e-4), rng.normal(0, 3e-4), 0.0],
            world2cam=look_at(eye, target)))
    return Rig(cams)


@dataclass
class MarkerTruth:
    """Ground truth of a marker scene (world frame of the rig, metres; pixels (x, y)).

    Attributes
    ----------
    ball_names, ball_kinds : list of str
        Kind ``"marked"`` (a ball with painted markers) or ``"marker"`` (a single-colour ball).
    ball_radius : np.ndarray, shape (n_balls,)
    ball2world : np.ndarray, shape (n_balls, 4, 4)
    ball_colors : np.ndarray, shape (n_balls, 3)
        Linear RGB albedo (base colour for marked balls).
    marker_names, marker_shapes : list of str
    marker_ball : np.ndarray, shape (n_markers,)
        Index of the ball carrying each painted marker.
    marker_colors : np.ndarray, shape (n_markers, 3)
    marker_centers : np.ndarray, shape (n_markers, 3)
        Centre of each painted marker on the ball surface.
    cameras : list of str
    ball_centers_px : np.ndarray, shape (n_cams, n_balls, 2)
        Projection of each ball centre; NaN if the centre's line of sight is blocked by another
        ball or it falls outside the image. (The centre of the silhouette differs from it by
        the perspective ellipse offset, up to a few tenths of a pixel off-axis.)
    marker_centers_px : np.ndarray, shape (n_cams, n_markers, 2)
        Projection of each marker centre; NaN if it faces away, is hidden or outside the image.
    """

    ball_names: list
    ball_kinds: list
    ball_radius: np.ndarray
    ball2world: np.ndarray
    ball_colors: np.ndarray
    marker_names: list
    marker_shapes: list
    marker_ball: np.ndarray
    marker_colors: np.ndarray
    marker_centers: np.ndarray
    cameras: list
    ball_centers_px: np.ndarray
    marker_centers_px: np.ndarray

    @property
    def ball_centers(self) -> np.ndarray:
        """Ball centres in the world ``(n_balls, 3)``."""
        return self.ball2world[:, :3, 3]

    def to_dict(self) -> dict:
        return {
            "kind": "markers", "units": {"length": "m", "pixels": "px (x, y), origin top-left pixel centre"},
            "cameras": list(self.cameras),
            "balls": [{"name": n, "kind": k, "radius": r, "center": T[:3, 3], "ball2world": T, "color": c}
                      for n, k, r, T, c in zip(self.ball_names, self.ball_kinds, self.ball_radius,
                                               self.ball2world, self.ball_colors)],
            "markers": [{"name": n, "ball": int(b), "shape": s, "color": c, "center": p}
                        for n, b, s, c, p in zip(self.marker_names, self.marker_ball, self.marker_shapes,
                                                 self.marker_colors, self.marker_centers)],
            "ball_centers_px": self.ball_centers_px,
            "marker_centers_px": self.marker_centers_px,
        }

    @classmethod
    def from_dict(cls, d: dict) -> MarkerTruth:
        from stillcap.files.jsonable import from_jsonable

        balls, markers = d["balls"], d["markers"]
        nc = len(d["cameras"])
        return cls([b["name"] for b in balls], [b["kind"] for b in balls],
                   np.array([b["radius"] for b in balls], float),
                   np.array([b["ball2world"] for b in balls], float).reshape(-1, 4, 4),
                   np.array([b["color"] for b in balls], float).reshape(-1, 3),
                   [m["name"] for m in markers], [m["shape"] for m in markers],
                   np.array([m["ball"] for m in markers], int),
                   np.array([m["color"] for m in markers], float).reshape(-1, 3),
                   np.array([m["center"] for m in markers], float).reshape(-1, 3),
                   list(d["cameras"]),
                   from_jsonable(d["ball_centers_px"]).reshape(nc, len(balls), 2),
                   from_jsonable(d["marker_centers_px"]).reshape(nc, len(markers), 2))


@dataclass
class MarkerScene:
    """A rendered multi-camera marker scene: rig, scene, one image per camera, truth."""

    rig: Rig
    scene: Scene
    images: list
    truth: MarkerTruth

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        files = [f"images/{c.name}{ext}" for c in self.rig]
        imgs = [CaptureImage(f, c.name) for f, c in zip(files, self.rig)]
        meta = {"synthetic": True, "rig_calibrated": True,
                "description": f"synthetic marker scene: {len(self.truth.ball_names)} balls, {len(self.rig)} cameras"}
        return Capture("markers", self.rig, imgs, self.truth.to_dict(), meta), dict(zip(files, self.images))


def visible_from(center, points, normals=None, spheres=(), skip=None) -> np.ndarray:
    """Whether each point ``(N, 3)`` is seen from ``center`` (3,).

    A point is hidden when its outward ``normals`` (N, 3) face away from the viewer or the
    segment to the viewer passes through one of ``spheres`` (pairs ``(centre, radius)``);
    ``skip[i]`` is the index of a sphere that point i lies on (ignored for it), or -1.
    """
    p = np.asarray(points, float).reshape(-1, 3)
    ok = np.ones(len(p), bool)
    to_cam = center - p
    if normals is not None:
        ok &= np.einsum("ij,ij->i", np.asarray(normals, float).reshape(-1, 3), to_cam) > 0
    L = np.linalg.norm(to_cam, axis=1)
    u = to_cam / L[:, None]
    skip = np.full(len(p), -1) if skip is None else np.asarray(skip)
    for k, (c, r) in enumerate(spheres):
        w = c - p
        s = np.clip(np.einsum("ij,ij->i", w, u), 0, L)  # closest point of the segment to c
        d = np.linalg.norm(w - s[:, None] * u, axis=1)
        ok &= ~((d < r) & (skip != k))
    return ok


def _place_balls(radii, rng, lo=(-0.45, -0.45, 0.55), hi=(0.45, 0.45, 1.45), gap=0.03):
    centers = []
    for r in radii:
        for _ in range(2000):
            c = rng.uniform(lo, hi)
            if all(np.linalg.norm(c - c2) > r + r2 + gap for c2, r2 in zip(centers, radii)):
                centers.append(c)
                break
        else:
            raise ValueError("could not place the balls without overlap; use fewer balls")
    return np.array(centers).reshape(-1, 3)


def marker_scene(rig: Rig | None = None, n_balls: int = 10, rng=None, sensor: Sensor | None = None,
                 n_marked: int | None = None, supersample: int = 3,
                 progress: Callable[[int, int], None] | None = None) -> MarkerScene:
    """Balls in a ~1 m volume photographed by every camera of a rig, with the truth.

    ``n_marked`` of the ``n_balls`` (default a third, at least one) are baseballs carrying the
    12 painted markers of :func:`~stillcap.studio.markers.baseball_markers` in a random
    orientation; the others are small (12 mm radius) single-colour marker balls. Each camera has
    an LED ring (a point light at its centre); the room is dark with a little ambient light.

    Parameters
    ----------
    rig : Rig, optional
        Default :func:`marker_rig` (4 cameras, 1280x960).
    n_balls : int
    rng : np.random.Generator or int, optional
    sensor : Sensor, optional
    n_marked : int, optional
    progress : callable(i, n), optional
        Called after each camera's image.
    """
    rng = as_rng(rng)
    rig = rig if rig is not None else marker_rig(rng=rng)
    if n_balls < 0:
        raise ValueError(f"n_balls must be >= 0, got {n_balls}")
    n_marked = (max(1, n_balls // 3) if n_balls else 0) if n_marked is None else int(n_marked)
    if not 0 <= n_marked <= n_balls:
        raise ValueError(f"n_marked must be in 0..n_balls ({n_balls}), got {n_marked}")
    sensor = sensor or Sensor()
    colors = list(MARKER_BALL_COLORS.items())
    bodies, names, kinds = [], [], []
    for i in range(n_balls):
        if i < n_marked:
            bodies.append(Sphere(BASEBALL_RADIUS, markers=baseball_markers(), name=f"ball{i}"))
            kinds.append("marked")
        else:
            cname, col = colors[(i - n_marked) % len(colors)]
            bodies.append(Sphere(0.012, albedo=col, name=f"{cname}{i}"))
            kinds.append("marker")
        names.append(bodies[-1].name)
    radii = np.array([b.radius for b in bodies])
    centers = _place_balls(radii, rng)
    rots = Rotation.random(n_balls, random_state=rng) if n_balls else []
    poses = np.array([pose_matrix(rots[i].as_matrix(), centers[i]) for i in range(n_balls)]).reshape(-1, 4, 4)
    lights = [PointLight(c.center, 1.6) for c in rig]
    scene = Scene(bodies, Exposure.single(list(poses), ambient=0.02), lights, backdrop=Backdrop(0.003, 0.3))

    m_names, m_shapes, m_ball, m_cols, m_ctr, m_nrm = [], [], [], [], [], []
    for i, (b, T) in enumerate(zip(bodies, poses)):
        for m in b.markers:
            n = T[:3, :3] @ m.direction
            m_names.append(f"{b.name}.{m.name}")
            m_shapes.append(m.shape)
            m_ball.append(i)
            m_cols.append(m.color)
            m_ctr.append(T[:3, 3] + b.radius * n)
            m_nrm.append(n)
    m_ctr, m_nrm = np.array(m_ctr).reshape(-1, 3), np.array(m_nrm).reshape(-1, 3)
    spheres = list(zip(centers, radii))
    bpx = np.full((len(rig), n_balls, 2), np.nan)
    mpx = np.full((len(rig), len(m_ctr), 2), np.nan)
    images = []
    for ci, cam in enumerate(rig):
        W, H = cam.image_size
        for pts, nrm, skip, out in ((centers, None, np.arange(n_balls), bpx), (m_ctr, m_nrm, np.array(m_ball, int), mpx)):
            if not len(pts):
                continue
            px = cam.project(pts)
            ok = visible_from(cam.center, pts, nrm, spheres, skip)
            ok &= np.all(np.isfinite(px), axis=1) & np.all((px >= -0.5) & (px <= [W - 0.5, H - 0.5]), axis=1)
            out[ci, ok] = px[ok]
        images.append(render(cam, scene, sensor, rng, supersample))
        report_progress(progress, ci + 1, len(rig))
    truth = MarkerTruth(names, kinds, radii, poses, np.array([b.albedo for b in bodies]).reshape(-1, 3),
                        m_names, m_shapes, np.array(m_ball, int), np.array(m_cols).reshape(-1, 3), m_ctr,
                        rig.names, bpx, mpx)
    return MarkerScene(rig, scene, images, truth)
