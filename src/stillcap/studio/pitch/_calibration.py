"""The pitch rig calibrated from rendered photos, as a user would in the field: close-up
chessboards and a large board at surveyed spots rendered per camera, their corners detected and
handed to :func:`stillcap.calibrate.surveyed.calibrate_camera_from_surveyed_boards`
(:func:`calibrate_pitch_rig`); the calibrated rig compared with the true one."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._progress import report_progress
from stillcap._checks import as_array, as_rng
from stillcap.calibrate.detect import detect_target
from stillcap.calibrate.surveyed import calibrate_camera_from_surveyed_boards
from stillcap.calibrate.targets import Chessboard
from stillcap.camera import Rig, pose_matrix
from stillcap.io.capture import target_to_dict
from stillcap.studio.pitch._release import END_Y
from stillcap.studio.pitch._rig import FRONT_CENTER_Y, PATH_X, PitchRig, _in_view
from stillcap.studio.renderer import render
from stillcap.studio.scenes import chessboard_set, target_scene
from stillcap.studio.sensor import Sensor


# --------------------------------------------------------------------------------------------
# Calibration from rendered photos
# --------------------------------------------------------------------------------------------
#: Close-up board for the intrinsics (9x6 inner corners, 40 mm squares).
CALIBRATION_BOARD = Chessboard(9, 6, 0.04)
#: The large board placed at surveyed spots for the extrinsics (9x6 inner corners, 0.1 m squares:
#: 1.2 x 0.9 m with its white border).
FIELD_BOARD = Chessboard(9, 6, 0.10)
#: Where the large board's centre stands for each pair (field frame, m), and its turn about the
#: vertical (deg) relative to facing the pair, and its tilt back (deg).
FRONT_BOARD_SPOTS = (((PATH_X, FRONT_CENTER_Y - 0.85, 1.45), 12.0, 6.0),
                     ((PATH_X - 0.3, FRONT_CENTER_Y, 1.85), -5.0, -8.0),
                     ((PATH_X + 0.2, FRONT_CENTER_Y + 0.85, 1.50), -15.0, 4.0))
BACK_BOARD_SPOTS = (((0.0, 5.2, 1.05), 8.0, 5.0),
                    ((-0.3, 3.2, 0.85), -10.0, -5.0),
                    ((0.25, 1.4, 0.95), 5.0, 8.0))


def _board_pose(target, center, facing, turn_deg: float, tilt_deg: float) -> np.ndarray:
    """``board2world``: the board's printed side (-z of the board frame) faces ``facing``,
    turned about the vertical and tilted back, its centre at ``center``."""
    center = np.asarray(center, float)
    n = np.asarray(facing, float) - center
    n[2] = 0.0
    n /= np.linalg.norm(n)  # horizontal direction toward the viewer
    n = Rotation.from_rotvec([0, 0, np.radians(turn_deg)]).apply(n)
    side = np.cross([0.0, 0.0, 1.0], n)
    n = Rotation.from_rotvec(np.radians(tilt_deg) * side).apply(n)
    zb = -n
    xb = np.cross([0.0, 0.0, 1.0], zb)
    xb /= np.linalg.norm(xb)
    yb = np.cross(zb, xb)
    R = np.stack([xb, yb, zb], axis=1)  # board axes in world coordinates (columns)
    x0, y0, x1, y1 = target.extent
    mid = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    return pose_matrix(R, center - R @ mid)


@dataclass
class PitchCalibration:
    """A pitch rig calibrated from rendered photos.

    Attributes
    ----------
    rig : Rig
        The calibrated cameras (field frame).
    cameras : list of :class:`~stillcap.calibrate.surveyed.CameraCalibration`
    board2world : dict[str, ndarray, shape (n_spots, 4, 4)]
        The surveyed board poses per pair.
    n_views : int
        Close-up views rendered per camera.
    """

    rig: Rig
    cameras: list
    board2world: dict
    n_views: int

    #: Largest acceptable reprojection RMS (px) of a camera's boards: above it a corner
    #: detection went wrong and the camera's calibration is not trusted.
    MAX_RMS_PX = 1.0

    @property
    def success(self) -> bool:
        """Every camera's intrinsics and pose reproject their boards within :attr:`MAX_RMS_PX`."""
        return all(c.intrinsics_rms_px <= self.MAX_RMS_PX and c.extrinsics_rms_px <= self.MAX_RMS_PX
                   for c in self.cameras)

    def to_dict(self) -> dict:
        """Capture metadata: the procedure and the residuals."""
        return {
            "procedure": (f"rendered photos per camera: {self.n_views} close-ups of a "
                          f"{CALIBRATION_BOARD.cols}x{CALIBRATION_BOARD.rows} chessboard "
                          f"({CALIBRATION_BOARD.square * 1000:.0f} mm squares) and a "
                          f"{FIELD_BOARD.cols}x{FIELD_BOARD.rows} chessboard ({FIELD_BOARD.square * 1000:.0f} mm "
                          f"squares) at surveyed field poses "
                          f"({', '.join(f'{len(v)} spots for the {k} pair' for k, v in self.board2world.items())}); "
                          "intrinsics: cv2.calibrateCamera on all of them (k3 fixed at 0); extrinsics: PnP "
                          "(SQPnP + LM) on the field-board corners in field coordinates"),
            "intrinsics_target": target_to_dict(CALIBRATION_BOARD),
            "extrinsics_target": target_to_dict(FIELD_BOARD),
            "board2world": {k: v for k, v in self.board2world.items()},
            "cameras": {c.name: c.to_dict() for c in self.cameras},
            "success": self.success,
        }


def calibrate_pitch_rig(pitch: PitchRig, rng=None, n_views: int = 5, sensor: Sensor | None = None,
                        supersample: int = 3,
                        progress: Callable[[int, int, str], None] | None = None) -> PitchCalibration:
    """Calibrate the rig's cameras from rendered photos, as a user would in the field.

    1. Each camera photographs :data:`CALIBRATION_BOARD` close up in ``n_views`` random poses
       (:func:`~stillcap.studio.scenes.chessboard_set`).
    2. The large :data:`FIELD_BOARD` stands at three surveyed spots in front of each pair
       (:data:`FRONT_BOARD_SPOTS`, :data:`BACK_BOARD_SPOTS`: its pose in the field frame is
       known, as if measured from home plate); each camera of the pair photographs it at every
       spot.
    3. Each camera is calibrated from the corners found in its photos
       (:func:`~stillcap.calibrate.surveyed.calibrate_camera_from_surveyed_boards`):
       intrinsics by ``cv2.calibrateCamera`` on all of its board photos (the field-board photos
       reach the image corners the close-ups do not), with ``k3`` fixed at 0 as OpenCV advises
       for ordinary lenses (the rendered lenses do have a small ``k3``: that model error is part
       of the result); extrinsics by PnP (SQPnP + LM) on the field-board corners of all spots
       at once, in field coordinates (three board planes: not coplanar).

    Parameters
    ----------
    pitch : PitchRig
        The true rig (what is rendered).
    rng : np.random.Generator or int, optional
    n_views : int
        Close-up views per camera (>= 3).
    sensor : Sensor, optional
        Default ``Sensor()`` (noise).
    supersample : int
    progress : callable(done, total, label), optional

    Returns
    -------
    PitchCalibration

    Raises
    ------
    ValueError
        A camera whose boards were found in too few photos.
    """
    rng = as_rng(rng)
    n_views = int(n_views)
    if n_views < 3:
        raise ValueError(f"calibration needs at least 3 close-up views per camera, got {n_views}")
    sensor = sensor or Sensor()
    spots = {"front": FRONT_BOARD_SPOTS, "back": BACK_BOARD_SPOTS}
    board2world = {}
    for p in pitch.pairs:
        mean_eye = np.mean([pitch.rig[c].center for c in p.cameras], axis=0)
        board2world[p.name] = np.array([_board_pose(FIELD_BOARD, c, mean_eye, turn, tilt)
                                        for c, turn, tilt in spots.get(p.name, ())]).reshape(-1, 4, 4)
    total = sum(n_views + len(board2world[pitch.pair_of(c.name).name]) for c in pitch.rig)
    done = 0
    cams, infos = [], []
    for cam in pitch.rig:
        pair = pitch.pair_of(cam.name)
        label = f"calibrating {cam.name}"
        base = done
        cb = chessboard_set(cam, n_views, CALIBRATION_BOARD, rng, sensor, supersample,
                            progress=lambda i, n, _b=base, _l=label: report_progress(progress, _b + i, total, _l))
        done += n_views
        views = [detect_target(im, CALIBRATION_BOARD, name=f"close-up {i}") for i, im in enumerate(cb.images)]
        field_views = []
        for k, T in enumerate(board2world[pair.name]):
            scene = target_scene(cam, FIELD_BOARD, cam.world2cam @ T, rng, supersample)
            det = detect_target(render(cam, scene, sensor, rng, supersample), FIELD_BOARD, name=f"field spot {k}")
            field_views.append((k, T, det))
            done += 1
            report_progress(progress, done, total, label)
        camera, info = calibrate_camera_from_surveyed_boards(cam.name, cam.image_size, views, field_views)
        cams.append(camera)
        infos.append(info)
    return PitchCalibration(Rig(cams, world="field"), infos, board2world, n_views)


def rig_reprojection_error(true_rig: Rig, rig: Rig, points_world) -> dict:
    """How far ``rig`` projects points from where ``true_rig`` does, per camera.

    Parameters
    ----------
    true_rig, rig : Rig
        Same camera names.
    points_world : array_like, shape (N, 3) or dict[str, array_like]
        Points to compare (or per camera name); points outside a true camera's image are ignored.

    Returns
    -------
    dict
        Per camera name: ``rms_px``, ``max_px``, ``n_points``, ``center_error_mm`` (camera
        centre distance), ``rotation_error_deg``, ``focal_error_pct``.
    """
    out = {}
    for tc in true_rig:
        c = rig[tc.name]
        pts = points_world[tc.name] if isinstance(points_world, dict) else points_world
        pts = as_array(pts, (None, 3), "points_world")
        a, ok = _in_view(tc, pts)
        d = np.linalg.norm(c.project(pts[ok]) - a[ok], axis=1) if ok.any() else np.zeros(0)
        dR = c.R @ tc.R.T
        out[tc.name] = {
            "rms_px": float(np.sqrt(np.mean(d ** 2))) if len(d) else float("nan"),
            "max_px": float(d.max()) if len(d) else float("nan"),
            "n_points": int(len(d)),
            "center_error_mm": float(np.linalg.norm(c.center - tc.center) * 1000),
            "rotation_error_deg": float(np.degrees(Rotation.from_matrix(dR).magnitude())),
            "focal_error_pct": float(100 * (c.K[0, 0] / tc.K[0, 0] - 1)),
        }
    return out


def _corridor_points(pair: str) -> np.ndarray:
    """A grid filling the part of the flight corridor a pair watches (field frame, m)."""
    if pair == "front":
        x, y, z = np.linspace(-0.9, -0.1, 5), np.linspace(FRONT_CENTER_Y - 2.2, FRONT_CENTER_Y + 2.2, 23), \
            np.linspace(1.1, 2.2, 6)
    else:
        x, y, z = np.linspace(-0.7, 0.6, 6), np.linspace(END_Y, 6.6, 30), np.linspace(0.2, 1.8, 7)
    return np.stack(np.meshgrid(x, y, z, indexing="ij"), -1).reshape(-1, 3)
