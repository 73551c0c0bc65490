"""The painted ball and its flight (poses at the flashes), and the truth of a pitch capture:
per pair what it photographed (:class:`PairTruth`), for the pitch (:class:`PitchTruth`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.ball.physics import FlightModel, simulate
from stillcap.camera import Rig
from stillcap.files.jsonable import from_jsonable
from stillcap.studio.pitch._release import ReleaseState
from stillcap.studio.pitch._rig import StrobePair, _in_view
from stillcap.studio.scene import Sphere, SphereMarker

#: Linear-RGB albedo of the ball's white leather.
BALL_ALBEDO = (0.75, 0.75, 0.72)


# --------------------------------------------------------------------------------------------
# The ball and its flight
# --------------------------------------------------------------------------------------------
def _layout(palette, layout=None, radius=None):
    """The painted markers: ``layout`` (a ball file's, :class:`stillcap.ball.layout.BallLayout`),
    default the seed's 12-marker layout (at ``radius``, m, when given), with ``palette``'s colours."""
    from stillcap.ball.layout import BallLayout

    if palette is not None and not isinstance(palette, dict):
        raise ValueError(f"palette must be a dict {{type name: linear RGB}}, got {type(palette).__name__}")
    if layout is None:
        layout = BallLayout.seed() if radius is None else BallLayout.seed(radius=float(radius))
    if palette:
        unknown = set(palette) - set(layout.type_names)
        if unknown:
            raise ValueError(f"palette has unknown marker types {sorted(unknown)}; types: {list(layout.type_names)}")
        layout = layout.with_palette(palette)
    return layout


def ball_sphere(palette: dict | None = None, albedo=BALL_ALBEDO, layout=None, radius=None) -> tuple[Sphere, object]:
    """The painted ball to render and its layout.

    Parameters
    ----------
    palette : dict, optional
        Linear-RGB colour per marker type (``{"blue": (0.1, 0.4, 1.0)}``); the rest keep the
        layout's.
    albedo : RGB
        The leather.
    layout : BallLayout, optional
        The ball's markers and radius (a ball file's); default the seed's baseball.
    radius : float, optional
        Radius of the default baseball, m (a ``layout`` carries its own).

    Returns
    -------
    (Sphere, BallLayout)
    """
    layout = _layout(palette, layout, radius)
    markers = tuple(SphereMarker(d, s, z, 0.0, c, name=n)
                    for d, s, z, c, n in zip(layout.directions, layout.shapes, layout.sizes, layout.colors,
                                             layout.names))
    return Sphere(layout.radius, albedo, markers, layout.name), layout


def _turn_angle(release: ReleaseState, times: np.ndarray, model: FlightModel) -> np.ndarray:
    """Angle the ball has turned at ``times`` since release (rad): ``|w| (t - t0)``, or with the
    Nathan model's spin decay ``exp(-(t - t0) |v(t)| / (tau0 v_ref))`` integrated."""
    rate = float(np.linalg.norm(release.spin))
    dt = times - release.t0
    if model.kind != "nathan" or rate == 0 or len(times) == 0:
        return rate * dt
    grid = np.linspace(0.0, max(dt.max(), 1e-6), 2001)
    tr = simulate(release.p0, release.v0, release.spin, release.t0 + grid, model, t0=release.t0)
    speed = np.linalg.norm(tr.velocities, axis=1)
    n = model.nathan
    w = rate * np.exp(-grid * speed / (n.tau0 * n.v_ref))
    ang = np.concatenate([[0.0], np.cumsum((w[1:] + w[:-1]) / 2 * np.diff(grid))])
    return np.interp(dt, grid, ang)


def _ball_poses(release: ReleaseState, times: np.ndarray, model: FlightModel) -> np.ndarray:
    """``ball2world`` (n, 4, 4) at ``times`` (all after release)."""
    times = np.asarray(times, float)
    out = np.tile(np.eye(4), (len(times), 1, 1))
    if not len(times):
        return out
    tr = simulate(release.p0, release.v0, release.spin, times, model, t0=release.t0)
    if not tr.success:
        raise ValueError(f"the flight could not be integrated: {tr.message}")
    rate = float(np.linalg.norm(release.spin))
    axis = release.spin / rate if rate > 0 else np.array([0.0, 0, 1])
    ang = _turn_angle(release, times, model)
    R = (Rotation.from_rotvec(ang[:, None] * axis) * Rotation.from_matrix(release.ball2world[:3, :3])).as_matrix()
    out[:, :3, :3] = R
    out[:, :3, 3] = tr.positions
    return out


# --------------------------------------------------------------------------------------------
# Truth
# --------------------------------------------------------------------------------------------
@dataclass
class PairTruth:
    """What one strobed pair photographed (field frame, metres; pixels (x, y)).

    Attributes
    ----------
    name : str
    cameras : list of str
    strobe_hz, shutter_s : float
    first_flash_s : float
        Time of the strobe's first flash after the shutters opened (its free-running phase).
    n_flashes : int
        Flashes while the shutters were open.
    light_position : ndarray, shape (3,)
    light_intensity : float
    flash_index : ndarray of int, shape (n,)
        Flashes while the ball flew (release to the carpet behind the plate): flash ``k`` fires
        at ``first_flash_s + k / strobe_hz``.
    times : ndarray, shape (n,)
    ball2world : ndarray, shape (n, 4, 4)
        Ball pose at each of those flashes.
    centers_px : ndarray, shape (2, n, 2)
        Projection of the ball centre in each camera of the pair; NaN when not visible.
    visible : ndarray of bool, shape (2, n)
        The ball centre is in front of the camera and inside its image.
    radius_px : ndarray, shape (2, n)
        Approximate radius of the ball's silhouette (``f r / depth``).
    phase_angle_deg : ndarray, shape (2, n)
        Angle at the ball between the camera and the strobe: 0 = fully lit disc, 90 = half moon.
    markers_px : ndarray, shape (2, n, 12, 2)
        Projection of each painted marker's centre; NaN when it faces away from the camera or
        the ball is not visible.
    rendered : ndarray of bool, shape (n,)
        The flash was rendered: the ball's disc reaches into the image of a camera of the pair
        (a ball cut by the image border is drawn, but ``visible`` only when its centre is inside).
    """

    name: str
    cameras: list
    strobe_hz: float
    shutter_s: float
    first_flash_s: float
    n_flashes: int
    light_position: np.ndarray
    light_intensity: float
    flash_index: np.ndarray
    times: np.ndarray
    ball2world: np.ndarray
    centers_px: np.ndarray
    visible: np.ndarray
    radius_px: np.ndarray
    phase_angle_deg: np.ndarray
    markers_px: np.ndarray
    rendered: np.ndarray

    @property
    def positions(self) -> np.ndarray:
        """Ball centres (n, 3)."""
        return self.ball2world[:, :3, 3]

    def to_dict(self) -> dict:
        return {"name": self.name, "cameras": list(self.cameras), "strobe_hz": self.strobe_hz,
                "shutter_s": self.shutter_s, "first_flash_s": self.first_flash_s, "n_flashes": self.n_flashes,
                "light": {"position": self.light_position, "intensity": self.light_intensity},
                "flash_index": self.flash_index, "times_s": self.times, "positions": self.positions,
                "ball2world": self.ball2world, "centers_px": self.centers_px, "visible": self.visible,
                "radius_px": self.radius_px, "phase_angle_deg": self.phase_angle_deg,
                "markers_px": self.markers_px, "rendered": self.rendered}

    @classmethod
    def from_dict(cls, d: dict, n_markers: int = 12) -> PairTruth:
        n = len(d["times_s"])
        nc = len(d["cameras"])
        return cls(d["name"], list(d["cameras"]), float(d["strobe_hz"]), float(d["shutter_s"]),
                   float(d["first_flash_s"]), int(d["n_flashes"]), np.asarray(d["light"]["position"], float),
                   float(d["light"]["intensity"]), np.asarray(d["flash_index"], int).reshape(n),
                   np.asarray(d["times_s"], float).reshape(n), np.asarray(d["ball2world"], float).reshape(n, 4, 4),
                   from_jsonable(d["centers_px"]).reshape(nc, n, 2), np.asarray(d["visible"], bool).reshape(nc, n),
                   from_jsonable(d["radius_px"]).reshape(nc, n), from_jsonable(d["phase_angle_deg"]).reshape(nc, n),
                   from_jsonable(d["markers_px"]).reshape(nc, n, n_markers, 2),
                   np.asarray(d["rendered"], bool).reshape(n))


@dataclass
class PitchTruth:
    """Ground truth of a pitch capture (field frame, SI; times since the shutters opened).

    Attributes
    ----------
    preset : dict
        The preset used (:meth:`PitchPreset.to_dict`) with ``overrides`` (what was set
        explicitly) and ``variation`` (the bounds, or None).
    model : str
        Flight model kind, ``"seed"`` or ``"nathan"``.
    release : ReleaseState
    plate_time_s : float
        When the ball crosses the front of the plate.
    end_time_s : float
        When it reaches the carpet behind the plate (y = :data:`END_Y`): the flight ends.
    pairs : list of PairTruth
        ``front`` then ``back``.
    metrics : dict
        :func:`stillcap.ball.metrics.pitch_metrics_from_flight` ``(...).to_dict()``: the keys the
        pitch pipeline reports.
    ball : dict
        ``radius`` (m), ``albedo``, ``marker_size`` (rad), ``palette`` and ``markers`` (``name``,
        ``type``, ``shape``, ``direction`` (ball frame), ``color``) of the layout.
    cameras : list of str
        In rig order.
    calibration_error : dict or None
        Per camera, the calibrated rig against the true one (:func:`rig_reprojection_error` over
        the watched corridor); None when the true rig was written.
    studio : dict or None
        The photographic conditions the studio varied (``lights``, ``room_flash``, the sensor's
        ``blur_px``, ``full_well``, ``read_noise``, ``white_balance``, ``jpeg_quality``,
        ``ball_radius_m``); ``camera_response``: each camera's true response in the rig file's
        forms (``"srgb"``, ``"linear"``, ``{"gamma": g}``, ``{"lut": [...]}``).
    """

    preset: dict
    model: str
    release: ReleaseState
    plate_time_s: float
    end_time_s: float
    pairs: list
    metrics: dict
    ball: dict
    cameras: list
    calibration_error: dict | None = None
    studio: dict | None = None

    @property
    def spin(self) -> np.ndarray:
        """Spin vector at release, rad/s, field frame."""
        return self.release.spin

    @property
    def time_offset_s(self) -> float:
        """``back.first_flash_s - front.first_flash_s``: how much later the back strobe's flash
        train is phased than the front one's (s)."""
        return float(self.pair("back").first_flash_s - self.pair("front").first_flash_s)

    def pair(self, name: str) -> PairTruth:
        for p in self.pairs:
            if p.name == name:
                return p
        raise ValueError(f"no pair {name!r} in the truth (pairs: {[p.name for p in self.pairs]})")

    def to_dict(self) -> dict:
        return {
            "kind": "pitch", "frame": "field",
            "units": {"length": "m", "time": "s (since the shutters opened)", "spin": "rad/s",
                      "pixels": "px (x, y), origin top-left pixel centre"},
            "preset": self.preset, "model": self.model, "release": self.release.to_dict(),
            "spin": self.spin, "spin_rpm": self.release.spin_rpm,
            "plate_time_s": self.plate_time_s, "end_time_s": self.end_time_s,
            "time_offset_s": self.time_offset_s,
            "strobe_hz": {p.name: p.strobe_hz for p in self.pairs},
            "cameras": list(self.cameras), "ball": self.ball,
            "pairs": [p.to_dict() for p in self.pairs],
            "metrics": self.metrics,
            "calibration_error": self.calibration_error,
            **({} if self.studio is None else {
                "studio": {k: v for k, v in self.studio.items() if k != "camera_response"},
                "camera_response": self.studio.get("camera_response")}),
        }

    @classmethod
    def from_dict(cls, d: dict) -> PitchTruth:
        return cls(d["preset"], d["model"], ReleaseState.from_dict(d["release"]), float(d["plate_time_s"]),
                   float(d["end_time_s"]), [PairTruth.from_dict(p, len(d["ball"]["markers"])) for p in d["pairs"]],
                   d["metrics"], d["ball"],
                   list(d["cameras"]), d.get("calibration_error"),
                   None if d.get("studio") is None else {**d["studio"], "camera_response": d.get("camera_response")})


def _pair_truth(pair: StrobePair, rig: Rig, release: ReleaseState, t_end: float, first_flash_s: float,
                model: FlightModel, layout) -> PairTruth:
    hz = pair.strobe_hz
    n_flashes = int(np.floor((pair.shutter_s - first_flash_s) * hz - 1e-9)) + 1 if pair.shutter_s > first_flash_s else 0
    k0 = max(int(np.ceil((release.t0 - first_flash_s) * hz - 1e-9)), 0)
    k1 = min(int(np.floor((min(t_end, pair.shutter_s) - first_flash_s) * hz + 1e-9)), n_flashes - 1)
    idx = np.arange(k0, k1 + 1) if k1 >= k0 else np.zeros(0, int)
    times = first_flash_s + idx / hz
    poses = _ball_poses(release, times, model)
    n, nc, nm = len(idx), len(pair.cameras), len(layout)
    centers = np.full((nc, n, 2), np.nan)
    visible = np.zeros((nc, n), bool)
    radius = np.full((nc, n), np.nan)
    phase = np.full((nc, n), np.nan)
    mpx = np.full((nc, n, nm, 2), np.nan)
    rendered = np.zeros(n, bool)
    r = layout.radius
    pos = poses[:, :3, 3]
    to_light = pair.light.position - pos
    to_light /= np.linalg.norm(to_light, axis=1, keepdims=True)
    for ci, name in enumerate(pair.cameras):
        cam = rig[name]
        if not n:
            continue
        depth = cam.world_to_cam(pos)[:, 2]
        radius[ci] = np.where(depth > r, cam.K[0, 0] * r / np.maximum(depth, r), np.nan)
        px, ok = _in_view(cam, pos)
        ok &= depth > r
        visible[ci] = ok
        centers[ci, ok] = px[ok]
        rendered |= _in_view(cam, pos, np.nan_to_num(radius[ci]) + 2)[1] & (depth > r)
        to_cam = cam.center - pos
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        phase[ci] = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", to_cam, to_light), -1, 1)))
        normals = np.einsum("kab,mb->kma", poses[:, :3, :3], layout.directions)  # (n, m, 3)
        marker_centers = pos[:, None] + r * normals
        facing = np.einsum("kma,kma->km", normals, cam.center - marker_centers) > 0
        mp = cam.project(marker_centers.reshape(-1, 3)).reshape(n, nm, 2)
        keep = facing & ok[:, None]
        mpx[ci][keep] = mp[keep]
    return PairTruth(pair.name, list(pair.cameras), hz, pair.shutter_s, float(first_flash_s), n_flashes,
                     pair.light.position.copy(), float(pair.light.intensity), idx.astype(int), times, poses,
                     centers, visible, radius, phase, mpx, rendered)
