"""The pitch scenario (SPEC J1, seed sections 3-4): a pitched, marked baseball photographed by two
strobed stereo pairs, with the truth.

Everything is in the baseball **field frame** (origin at the back tip of home plate, y toward the
pitcher, z up, x to the catcher's right), SI units; times are seconds since the shutters opened
(all four cameras are triggered together).

The seed's rig (:func:`pitch_rig`), 4 cameras of 2560x1920 px (Olympus C5050 class):

- **front pair** ``front_top``, ``front_bottom``: 3.5 m beside the flight path (on the third-base
  side, so the ball flies from left to right as in the seed's Figure 5), vertical baseline 0.8 m,
  looking across the path at the stretch right after release;
  its field of view spans about 3.3 m of flight (the seed's "6-10 ball images at 80 Hz"); a
  strobe (:class:`~stillcap.studio.scene.PointLight`) beside the pair flashes at 80 Hz and
  lights the balls from the cameras' side (full discs); shutter 1.0 s.
- **back pair** ``back_left``, ``back_right``: 2.8 m high, 4 m apart on both sides of the
  corridor, behind the last third of the flight and looking down it toward home plate; its strobe
  (50 Hz) stands beside the corridor, so the balls are lit from the side and show as half moons;
  shutter 1.3 s.
- The room is black (:class:`~stillcap.studio.scene.Backdrop` near 0); each pair photographs
  only with its own strobe, and the two strobes run free: each has a random phase
  (``first_flash_s``) relative to the shutters, so the time offset between the pairs is unknown
  to a pipeline (it is in the truth).

The ball: the seed's 12-marker layout (:class:`stillcap.ball.layout.BallLayout`) with a
configurable palette; its flight is integrated by :mod:`stillcap.ball.physics` (seed model by
default) from the release state, and its orientation turns with the spin:
``ball2world(t) = [exp([w_hat] theta(t)) R0 | p(t)]`` with ``theta = |w| (t - t0)`` (the
Nathan model's spin decay is integrated into ``theta``).

The rig file of the capture comes from **rendered calibration photos** processed by stillcap's
calibration (:func:`calibrate_pitch_rig`): each camera photographs a chessboard close up and a
large chessboard standing at three surveyed spots in front of its pair; intrinsics from all of
those photos, the pose in the field frame by PnP on the large board's corners. So calibration
error is part of every accuracy measured on the capture; ``calibrate=False`` writes the true rig
instead (flagged ``rig_calibrated: false``).

See ``docs/studio.md`` ("Pitch") for the presets, the truth keys and the measured accuracy.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array, as_rng
from stillcap.ball.metrics import MPH, RPM_PER_RAD_S, pitch_metrics_from_flight, spin_vector
from stillcap.ball.physics import PLATE_FRONT_Y, FlightModel, cross_plane, flight_model, simulate
from stillcap.calibrate.detect import detect_target
from stillcap.calibrate.extrinsics import pose_from_points
from stillcap.calibrate.intrinsics import calibrate_intrinsics_from_points
from stillcap.calibrate.targets import Chessboard
from stillcap.camera import Camera, Rig, pose_matrix
from stillcap.io.capture import Capture, CaptureImage, target_to_dict
from stillcap.files.jsonable import from_jsonable
from stillcap.studio.renderer import render
from stillcap.studio.scene import Backdrop, Exposure, Flash, PointLight, Scene, Sphere, SphereMarker
from stillcap.studio.scenes import chessboard_set, target_scene
from stillcap.studio.sensor import Sensor

__all__ = ["BACK_BOARD_SPOTS", "CALIBRATION_BOARD", "DEFAULT_VARIATION", "FIELD_BOARD", "FRONT_BOARD_SPOTS",
           "PRESETS", "CameraCalibration", "PairTruth", "PitchCalibration", "PitchCapture", "PitchPreset",
           "PitchRig", "PitchTruth", "ReleaseState", "ReleaseVariation", "StrobePair", "ball_sphere",
           "calibrate_pitch_rig", "field_look_at", "pitch_capture", "pitch_rig", "release_state",
           "rig_reprojection_error"]

FT = 0.3048
#: Front of the pitching rubber, y (m).
RUBBER_Y = 60.5 * FT
#: Where the flight ends: the heavy carpet hanging behind home plate, y (m).
END_Y = -0.6
#: Seed release point (three-quarter delivery, right-hander: arm side is -x), m.
SEED_RELEASE = (-0.55, 54.5 * FT, 1.80)
#: A modern right-hander's release point (6.5 ft extension), m.
MLB_RELEASE = (-0.60, 54.0 * FT, 1.78)
#: Camera names, in rig order.
CAMERA_NAMES = ("front_top", "front_bottom", "back_left", "back_right")
#: Linear-RGB albedo of the ball's white leather.
BALL_ALBEDO = (0.75, 0.75, 0.72)


# --------------------------------------------------------------------------------------------
# Presets and the release state
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PitchPreset:
    """A kind of pitch: its nominal release state.

    Attributes
    ----------
    name : str
    speed_mph : float
        Release speed.
    spin_rpm : float
        Total spin rate.
    spin_axis_deg : float
        Statcast spin axis (catcher's view, :func:`stillcap.ball.metrics.spin_axis_deg`):
        180 = pure backspin ("12:00"), 0 = pure topspin, 90 = sidespin moving the ball toward
        first base (a right-hander's slider).
    spin_efficiency : float
        Share of the spin transverse to the flight (0..1); the rest is gyro spin.
    release_m : tuple of 3 floats
        Release point, field frame, metres.
    target_m : tuple of 2 floats
        Where the pitch is aimed: ``(x, z)`` at the front of home plate, metres.
    gyro_sign : float
        Sense of the gyro part (+1 along the velocity).
    description, source : str
    """

    name: str
    speed_mph: float
    spin_rpm: float
    spin_axis_deg: float
    spin_efficiency: float = 0.95
    release_m: tuple = SEED_RELEASE
    target_m: tuple = (0.0, 0.75)
    gyro_sign: float = 1.0
    description: str = ""
    source: str = ""

    def to_dict(self) -> dict:
        return {"name": self.name, "speed_mph": self.speed_mph, "spin_rpm": self.spin_rpm,
                "spin_axis_deg": self.spin_axis_deg, "spin_efficiency": self.spin_efficiency,
                "release_m": list(self.release_m), "target_m": list(self.target_m),
                "gyro_sign": self.gyro_sign, "description": self.description, "source": self.source}


_SEED = "seed Table 1 (speed, rate); axis and efficiency plausible for its three-quarter delivery"
_MLB = "typical MLB right-hander (Statcast averages)"
#: The pitch presets: the seed's five pitches (Table 1 speeds and spin rates) and modern ones.
PRESETS: dict[str, PitchPreset] = {p.name: p for p in (
    PitchPreset("seed-2seam", 63.2, 1596, 225, 0.90, SEED_RELEASE, (-0.05, 0.70),
                description="two-seam fastball: backspin tilted to the arm side (1:30)", source=_SEED),
    PitchPreset("seed-4seam", 64.2, 1612, 210, 0.95, SEED_RELEASE, (0.0, 0.75),
                description="four-seam fastball: backspin (1:00)", source=_SEED),
    PitchPreset("seed-curveball", 61.9, 1623, 30, 0.85, SEED_RELEASE, (0.05, 0.55),
                description="curveball: topspin (7:00)", source=_SEED),
    PitchPreset("seed-slider", 65.7, 1491, 90, 0.85, SEED_RELEASE, (0.15, 0.60),
                description="slider: sidespin toward the glove side (9:00)", source=_SEED),
    PitchPreset("seed-changeup", 60.6, 1258, 235, 0.90, SEED_RELEASE, (-0.10, 0.60),
                description="change-up: backspin, slower (1:45)", source=_SEED),
    PitchPreset("mlb-4seam", 95.0, 2400, 210, 0.95, MLB_RELEASE, (0.0, 0.80),
                description="modern four-seam fastball", source=_MLB),
    PitchPreset("mlb-curveball", 80.0, 2800, 30, 0.70, MLB_RELEASE, (0.05, 0.50),
                description="modern curveball: topspin, above the 80 Hz Nyquist limit (2400 rpm)", source=_MLB),
    PitchPreset("mlb-gyro-slider", 86.0, 2500, 75, 0.25, MLB_RELEASE, (0.20, 0.60),
                description="gyro slider: mostly gyro spin (gyro angle 75 deg), little movement", source=_MLB),
    PitchPreset("mlb-high-spin", 94.0, 3000, 205, 0.97, MLB_RELEASE, (0.0, 0.85),
                description="riding four-seamer at 3000 rpm: 50 rev/s, aliased at 80 Hz (principal 1800 rpm)",
                source=_MLB),
)}
DEFAULT_PRESET = "seed-4seam"


@dataclass(frozen=True)
class ReleaseVariation:
    """A pitcher's scatter from pitch to pitch: uniform random deviations within these bounds.

    Attributes
    ----------
    position_m : float
        Each coordinate of the release point, +- metres.
    speed_mph : float
        Release speed, +- mph.
    direction_deg : float
        The release direction tilts by up to this angle (uniform over the disc).
    spin_rpm : float
        Spin rate, +- rpm.
    axis_deg : float
        The spin axis tilts by up to this angle (uniform over the disc).
    """

    position_m: float = 0.03
    speed_mph: float = 1.0
    direction_deg: float = 1.0
    spin_rpm: float = 50.0
    axis_deg: float = 5.0

    def __post_init__(self):
        for k in ("position_m", "speed_mph", "direction_deg", "spin_rpm", "axis_deg"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"release variation {k} must be a finite number >= 0, got {v}")


#: The default variation (SPEC J1: a few cm, +-1 mph, +-1 deg, +-50 rpm, +-5 deg).
DEFAULT_VARIATION = ReleaseVariation()


@dataclass
class ReleaseState:
    """The ball as it leaves the hand (field frame, SI).

    Attributes
    ----------
    t0 : float
        Release time, s since the shutters opened.
    p0 : ndarray, shape (3,)
        Ball centre, m.
    v0 : ndarray, shape (3,)
        Velocity, m/s.
    spin : ndarray, shape (3,)
        Spin vector, rad/s (right-hand rule; constant in the seed model).
    ball2world : ndarray, shape (4, 4)
        Ball orientation and position at ``t0``.
    """

    t0: float
    p0: np.ndarray
    v0: np.ndarray
    spin: np.ndarray
    ball2world: np.ndarray

    @property
    def speed_mph(self) -> float:
        return float(np.linalg.norm(self.v0) / MPH)

    @property
    def spin_rpm(self) -> float:
        return float(np.linalg.norm(self.spin) * RPM_PER_RAD_S)

    def to_dict(self) -> dict:
        return {"t0_s": self.t0, "p0": self.p0, "v0": self.v0, "spin": self.spin, "ball2world": self.ball2world,
                "speed_mph": self.speed_mph, "spin_rpm": self.spin_rpm}

    @classmethod
    def from_dict(cls, d: dict) -> ReleaseState:
        return cls(float(d["t0_s"]), np.asarray(d["p0"], float), np.asarray(d["v0"], float),
                   np.asarray(d["spin"], float), np.asarray(d["ball2world"], float))


def _tilt(v: np.ndarray, max_deg: float, rng: np.random.Generator) -> np.ndarray:
    """``v`` turned by an angle up to ``max_deg`` (uniform over the disc) in a random direction."""
    n = np.linalg.norm(v)
    if max_deg <= 0 or n == 0:
        return v
    u = v / n
    a = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    phi = rng.uniform(0, 2 * np.pi)
    ang = np.radians(max_deg) * np.sqrt(rng.uniform())
    axis = np.cos(phi) * e1 + np.sin(phi) * e2
    return Rotation.from_rotvec(ang * axis).apply(v)


def _direction(yaw: float, pitch: float) -> np.ndarray:
    """Unit vector toward home (-y) turned by ``yaw`` toward +x and ``pitch`` up (radians)."""
    return np.array([np.sin(yaw) * np.cos(pitch), -np.cos(yaw) * np.cos(pitch), np.sin(pitch)])


def _aim(p0, speed, spin_of, target, model, iters: int = 8) -> np.ndarray:
    """Release velocity of the given ``speed`` that crosses the front of the plate at ``target``
    ``(x, z)``; ``spin_of(v)`` gives the spin for a velocity. Fixed-point iteration on the two
    release angles (the plate position is nearly linear in them)."""
    dist = p0[1] - PLATE_FRONT_Y
    yaw = math.atan2(target[0] - p0[0], dist)
    pitch = math.atan2(target[1] - p0[2], dist) + 0.5 * 9.81 * dist / speed ** 2
    for _ in range(iters):
        v = speed * _direction(yaw, pitch)
        c = cross_plane(p0, v, spin_of(v), model, rtol=1e-8, atol=1e-9)
        if not c.success:
            raise ValueError(f"a {speed / MPH:.1f} mph pitch from {np.round(p0, 2).tolist()} m does not reach "
                             f"the plate ({c.message}); raise the speed")
        miss = np.array([target[0] - c.position[0], target[1] - c.position[2]])
        yaw += miss[0] / dist
        pitch += miss[1] / dist
        if np.all(np.abs(miss) < 1e-5):
            break
    return speed * _direction(yaw, pitch)


def release_state(preset: str | PitchPreset = DEFAULT_PRESET, rng=None, *, speed_mph: float | None = None,
                  spin_rpm: float | None = None, spin_axis_deg: float | None = None,
                  spin_efficiency: float | None = None, release_m=None, target_m=None,
                  variation: ReleaseVariation | None = DEFAULT_VARIATION, model=None,
                  t0: float = 0.0, ball2world_rotation=None) -> ReleaseState:
    """The release state of one pitch: a preset, aimed at its target, with the pitcher's scatter.

    The nominal release velocity is aimed (with ``model``'s physics) so that the pitch crosses
    the front of the plate at the preset's ``target_m``; then ``variation`` perturbs the
    release point, speed, direction, spin rate and spin axis. Quantities given explicitly
    (``speed_mph``, ``spin_rpm``, ``spin_axis_deg``, ``release_m``) are used exactly as given
    (not varied); the release direction is always varied unless ``variation`` is None.

    Parameters
    ----------
    preset : str or PitchPreset
        A name in :data:`PRESETS` or a preset.
    rng : np.random.Generator or int, optional
        The variation and the ball's orientation at release.
    speed_mph, spin_rpm, spin_axis_deg, spin_efficiency : float, optional
        Override the preset (units in the names; axis: Statcast degrees, 180 = backspin).
    release_m : array_like, shape (3,), optional
        Release point, field frame, metres.
    target_m : array_like, shape (2,), optional
        Aim point ``(x, z)`` at the front of the plate, metres.
    variation : ReleaseVariation or None
        None: the exact nominal pitch.
    model : "seed", "nathan" or FlightModel, optional
    t0 : float
        Release time (s since the shutters opened).
    ball2world_rotation : array_like, shape (3, 3), optional
        Orientation at release (default: uniformly random).

    Returns
    -------
    ReleaseState
    """
    rng = as_rng(rng)
    if isinstance(preset, str):
        if preset not in PRESETS:
            raise ValueError(f"unknown pitch preset {preset!r}; known: {', '.join(PRESETS)}")
        preset = PRESETS[preset]
    elif not isinstance(preset, PitchPreset):
        raise ValueError(f"preset must be a preset name or a PitchPreset, got {type(preset).__name__}")
    model = flight_model(model)
    speed = preset.speed_mph if speed_mph is None else float(speed_mph)
    rate = preset.spin_rpm if spin_rpm is None else float(spin_rpm)
    axis = preset.spin_axis_deg if spin_axis_deg is None else float(spin_axis_deg)
    eff = preset.spin_efficiency if spin_efficiency is None else float(spin_efficiency)
    if not (np.isfinite(speed) and 20.0 <= speed <= 110.0):
        raise ValueError(f"speed_mph must be between 20 and 110 mph, got {speed}")
    if not (np.isfinite(rate) and 0.0 <= rate <= 6000.0):
        raise ValueError(f"spin_rpm must be between 0 and 6000 rpm, got {rate}")
    if not (np.isfinite(axis) and 0.0 <= axis <= 360.0):
        raise ValueError(f"spin_axis_deg is a Statcast axis in 0..360 degrees (180 = backspin), got {axis}")
    if not (np.isfinite(eff) and 0.0 <= eff <= 1.0):
        raise ValueError(f"spin_efficiency must be in [0, 1], got {eff}")
    p0 = np.array(preset.release_m if release_m is None else as_array(release_m, (3,), "release_m"), float)
    if not (np.all(np.isfinite(p0)) and 2.0 < p0[1] <= RUBBER_Y + 0.5 and 0.2 < p0[2] < 3.0 and abs(p0[0]) < 3.0):
        raise ValueError(f"release_m must be a field-frame point between the plate and the rubber "
                         f"(2 < y <= {RUBBER_Y + 0.5:.2f} m, 0.2 < z < 3 m, |x| < 3 m), got {p0.tolist()}")
    target = np.array(preset.target_m if target_m is None else as_array(target_m, (2,), "target_m"), float)
    if not (np.all(np.isfinite(target)) and abs(target[0]) < 3 and -0.5 < target[1] < 3):
        raise ValueError(f"target_m is (x, z) at the front of the plate in metres (|x| < 3, -0.5 < z < 3), "
                         f"got {target.tolist()}")
    if variation is not None and not isinstance(variation, ReleaseVariation):
        raise ValueError(f"variation must be a ReleaseVariation or None, got {type(variation).__name__}")

    def spin_of(v, rpm=rate):
        return spin_vector(rpm, axis, v, eff, preset.gyro_sign) if rpm > 0 else np.zeros(3)

    v0 = _aim(p0, speed * MPH, spin_of, target, model)
    spin = spin_of(v0)
    var = variation
    if var is not None:
        if release_m is None:
            p0 = p0 + rng.uniform(-var.position_m, var.position_m, 3)
        if speed_mph is None:
            speed = speed + rng.uniform(-var.speed_mph, var.speed_mph)
        d = _tilt(v0 / np.linalg.norm(v0), var.direction_deg, rng)
        v0 = speed * MPH * d / np.linalg.norm(d)
        if spin_rpm is None:
            rate = max(rate + rng.uniform(-var.spin_rpm, var.spin_rpm), 0.0)
        spin = spin_of(v0, rate)
        if spin_axis_deg is None:
            spin = _tilt(spin, var.axis_deg, rng)
    if ball2world_rotation is None:
        R0 = Rotation.random(random_state=rng).as_matrix()
    else:
        R0 = as_array(ball2world_rotation, (3, 3), "ball2world_rotation")
        if not (np.allclose(R0 @ R0.T, np.eye(3), atol=1e-6) and np.linalg.det(R0) > 0):
            raise ValueError("ball2world_rotation must be a proper rotation matrix")
    return ReleaseState(float(t0), p0, v0, spin, pose_matrix(R0, p0))


# --------------------------------------------------------------------------------------------
# The rig
# --------------------------------------------------------------------------------------------
def field_look_at(eye, target, roll_deg: float = 0.0) -> np.ndarray:
    """``world2cam`` (4, 4) of a camera at ``eye`` looking at ``target`` (field frame, z up),
    upright: world up appears up in the image (camera y points down), turned by ``roll_deg``
    about the optical axis.

    (Built here explicitly: :func:`stillcap.camera.look_at` with its default ``up`` gives an
    image turned by 180 degrees.)
    """
    eye = as_array(eye, (3,), "eye")
    z = as_array(target, (3,), "target") - eye
    if not np.linalg.norm(z) > 0:
        raise ValueError("field_look_at: eye and target are the same point")
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("field_look_at: the camera looks straight up or down")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    if roll_deg:
        R = Rotation.from_rotvec([0, 0, np.radians(roll_deg)]).as_matrix() @ R
    return pose_matrix(R, -R @ eye)


@dataclass(frozen=True)
class StrobePair:
    """A stereo pair with its strobe.

    Attributes
    ----------
    name : str
        ``"front"`` or ``"back"``.
    cameras : tuple of str
        Camera names in the rig.
    strobe_hz : float
    shutter_s : float
        How long the pair's shutters stay open, s (they all open at t = 0).
    light : PointLight
        The strobe, field frame.
    """

    name: str
    cameras: tuple
    strobe_hz: float
    shutter_s: float
    light: PointLight


@dataclass
class PitchRig:
    """The seed's pitch rig in the field frame: 4 cameras in 2 strobed stereo pairs.

    Attributes
    ----------
    rig : Rig
        The true cameras (``world = "field"``), order ``front_top, front_bottom, back_left,
        back_right``.
    pairs : tuple of StrobePair
        ``front`` then ``back``.
    """

    rig: Rig
    pairs: tuple

    def pair(self, name: str) -> StrobePair:
        for p in self.pairs:
            if p.name == name:
                return p
        raise ValueError(f"no pair {name!r} in the rig (pairs: {[p.name for p in self.pairs]})")

    def pair_of(self, camera: str) -> StrobePair:
        for p in self.pairs:
            if camera in p.cameras:
                return p
        raise ValueError(f"camera {camera!r} is in no pair (cameras: {self.rig.names})")


# Camera design (2560 px wide; scaled with the image width): focal length (px), fy/fx, principal
# point offset from the centre (px), distortion (k1, k2, p1, p2, k3), mild barrel as a zoom lens
# at the wide end. Small per-camera differences, like four units of one model.
_INTRINSICS = {
    "front_top": (2800.0, 1.0004, (6.2, -4.1), (-0.085, 0.11, 0.0004, -0.0003, -0.02)),
    "front_bottom": (2812.0, 0.9997, (-3.8, 5.0), (-0.090, 0.12, -0.0002, 0.0004, -0.03)),
    "back_left": (3300.0, 1.0003, (4.5, 3.2), (-0.070, 0.09, 0.0003, 0.0002, -0.01)),
    "back_right": (3288.0, 0.9995, (-5.1, -2.6), (-0.075, 0.10, -0.0003, -0.0001, -0.02)),
}
#: The front pair stands beside the flight, centred this far (m) in front of the release point.
FRONT_CENTER_Y = 14.7
#: Front pair: distance from the flight path (m), camera heights (m), aim height.
FRONT_DISTANCE, FRONT_Z, FRONT_AIM_Z = 3.5, (2.05, 1.25), 1.62
#: Flight path x near release (m).
PATH_X = -0.5
#: Back pair: camera x (m), height (m), y (m) and the point both look at.
BACK_X, BACK_Z, BACK_Y, BACK_AIM = 2.0, 2.8, 9.3, (-0.15, 2.4, 0.9)
#: Strobe positions (field frame, m) and intensities (a facing white surface at distance d gets
#: radiance I / d^2).
FRONT_LIGHT = (PATH_X - FRONT_DISTANCE - 0.1, FRONT_CENTER_Y + 0.55, 1.65)
BACK_LIGHT = (-2.4, 2.5, 3.4)
FRONT_INTENSITY, BACK_INTENSITY = 10.5, 9.0


def _check_hz(name: str, hz) -> float:
    hz = float(hz)
    if not (np.isfinite(hz) and 1.0 <= hz <= 500.0):
        raise ValueError(f"{name} must be a strobe rate between 1 and 500 Hz, got {hz}")
    return hz


def _check_size(image_size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise ValueError(f"image_size must be (width, height) in pixels, got {image_size!r}") from None
    if w < 64 or h < 48 or abs(w / h - 4 / 3) > 0.01:
        raise ValueError(f"image_size must be at least 64x48 pixels with the cameras' 4:3 aspect ratio, "
                         f"got {w}x{h}")
    return w, h


def pitch_rig(front_hz: float = 80.0, back_hz: float = 50.0, image_size=(2560, 1920),
              front_shutter_s: float = 1.0, back_shutter_s: float = 1.3) -> PitchRig:
    """The seed's rig (module docstring) in the field frame.

    Parameters
    ----------
    front_hz, back_hz : float
        Strobe rates of the front and back pair (seed: 80 and 50 Hz).
    image_size : (width, height)
        Default the seed's 2560x1920; smaller 4:3 sizes scale the intrinsics (same field of view).
    front_shutter_s, back_shutter_s : float
        Shutter times (seed: 1.0 and 1.3 s).

    Returns
    -------
    PitchRig
    """
    front_hz, back_hz = _check_hz("front_hz", front_hz), _check_hz("back_hz", back_hz)
    w, h = _check_size(image_size)
    for nm, s in (("front_shutter_s", front_shutter_s), ("back_shutter_s", back_shutter_s)):
        if not (np.isfinite(s) and 0.05 <= s <= 30):
            raise ValueError(f"{nm} must be between 0.05 and 30 s, got {s}")
    s = w / 2560.0
    front_aim = np.array([PATH_X, FRONT_CENTER_Y, FRONT_AIM_Z])
    eyes = {
        "front_top": (np.array([PATH_X - FRONT_DISTANCE, FRONT_CENTER_Y, FRONT_Z[0]]), front_aim, 0.3),
        "front_bottom": (np.array([PATH_X - FRONT_DISTANCE, FRONT_CENTER_Y, FRONT_Z[1]]), front_aim, -0.4),
        "back_left": (np.array([BACK_X, BACK_Y, BACK_Z]), np.array(BACK_AIM), 0.5),
        "back_right": (np.array([-BACK_X, BACK_Y, BACK_Z]), np.array(BACK_AIM), -0.3),
    }
    cams = []
    for name in CAMERA_NAMES:
        f, aspect, (dx, dy), dist = _INTRINSICS[name]
        eye, aim, roll = eyes[name]
        cams.append(Camera.from_intrinsics(name, f * s, f * aspect * s, (w - 1) / 2 + dx * s, (h - 1) / 2 + dy * s,
                                           (w, h), dist=dist, world2cam=field_look_at(eye, aim, roll)))
    pairs = (StrobePair("front", CAMERA_NAMES[:2], front_hz, float(front_shutter_s),
                        PointLight(FRONT_LIGHT, FRONT_INTENSITY)),
             StrobePair("back", CAMERA_NAMES[2:], back_hz, float(back_shutter_s),
                        PointLight(BACK_LIGHT, BACK_INTENSITY)))
    return PitchRig(Rig(cams, world="field"), pairs)


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
class CameraCalibration:
    """How one camera of the pitch rig was calibrated.

    Attributes
    ----------
    name : str
    intrinsics_rms_px : float
        ``cv2.calibrateCamera`` RMS over the board photos used.
    views_used : int
        Board photos used for the intrinsics (close-ups and field-board spots).
    views_skipped : dict[str, str]
        Photos whose board was not found, with the reason.
    extrinsics_rms_px : float
        PnP reprojection RMS over all corners of the large board at its surveyed spots.
    n_points : int
        Corners used for the pose.
    spots_used : list of int
        Which board spots this camera saw (indices into the pair's spots).
    """

    name: str
    intrinsics_rms_px: float
    views_used: int
    views_skipped: dict
    extrinsics_rms_px: float
    n_points: int
    spots_used: list

    def to_dict(self) -> dict:
        return {"intrinsics_rms_px": self.intrinsics_rms_px, "views_used": self.views_used,
                "views_skipped": dict(self.views_skipped), "extrinsics_rms_px": self.extrinsics_rms_px,
                "n_points": self.n_points, "spots_used": list(self.spots_used)}


@dataclass
class PitchCalibration:
    """A pitch rig calibrated from rendered photos.

    Attributes
    ----------
    rig : Rig
        The calibrated cameras (field frame).
    cameras : list of CameraCalibration
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


def _progress(cb, done, total, label):
    if cb is not None:
        cb(done, total, label)


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
    3. Intrinsics: ``cv2.calibrateCamera``
       (:func:`~stillcap.calibrate.intrinsics.calibrate_intrinsics_from_points`) on the corners
       of all of that camera's board photos (the field-board photos reach the image corners the
       close-ups do not), with ``k3`` fixed at 0 as OpenCV advises for ordinary lenses (the
       rendered lenses do have a small ``k3``: that model error is part of the result).
    4. Extrinsics: PnP (:func:`~stillcap.calibrate.extrinsics.pose_from_points`, SQPnP + LM) on
       the field-board corners of all spots at once, in field coordinates (three board planes:
       not coplanar).

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
    import cv2

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
                            progress=lambda i, n, _b=base, _l=label: _progress(progress, _b + i, total, _l))
        done += n_views
        views = [detect_target(im, CALIBRATION_BOARD, name=f"close-up {i}") for i, im in enumerate(cb.images)]
        field_views = []
        for k, T in enumerate(board2world[pair.name]):
            scene = target_scene(cam, FIELD_BOARD, cam.world2cam @ T, rng, supersample)
            det = detect_target(render(cam, scene, sensor, rng, supersample), FIELD_BOARD, name=f"field spot {k}")
            field_views.append((k, T, det))
            done += 1
            _progress(progress, done, total, label)
        good = [d for d in views if d.success] + [d for _, _, d in field_views if d.success]
        skipped = {d.name: d.reason for d in views + [d for _, _, d in field_views] if not d.success}
        if len(good) < 3:
            raise ValueError(f"camera {cam.name!r}: the boards were found in only {len(good)} photos "
                             f"(need 3); skipped: {skipped}")
        intr = calibrate_intrinsics_from_points([d.object_points for d in good], [d.image_points for d in good],
                                                cam.image_size, [d.name for d in good], cam.name,
                                                flags=cv2.CALIB_FIX_K3)
        used = [(k, T, d) for k, T, d in field_views if d.success]
        if not used:
            raise ValueError(f"camera {cam.name!r}: the field board was not found at any surveyed spot")
        obj = np.concatenate([d.object_points @ T[:3, :3].T + T[:3, 3] for _, T, d in used])
        pose = pose_from_points(intr.camera, obj, np.concatenate([d.image_points for _, _, d in used]))
        if not pose.success:
            raise ValueError(f"camera {cam.name!r}: no pose from the field board (PnP failed)")
        cams.append(pose.camera)
        infos.append(CameraCalibration(cam.name, intr.rms_px, len(good), skipped, pose.rms_px, pose.n_points,
                                       [k for k, _, _ in used]))
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


# --------------------------------------------------------------------------------------------
# The ball and its flight
# --------------------------------------------------------------------------------------------
def _layout(palette):
    """The 12-marker layout: :class:`stillcap.ball.layout.BallLayout` (the single source of truth)."""
    from stillcap.ball.layout import BallLayout

    if palette is not None and not isinstance(palette, dict):
        raise ValueError(f"palette must be a dict {{type name: linear RGB}}, got {type(palette).__name__}")
    layout = BallLayout.seed()
    if palette:
        unknown = set(palette) - set(layout.type_names)
        if unknown:
            raise ValueError(f"palette has unknown marker types {sorted(unknown)}; types: {list(layout.type_names)}")
        layout = layout.with_palette(palette)
    return layout


def ball_sphere(palette: dict | None = None, albedo=BALL_ALBEDO) -> tuple[Sphere, object]:
    """The painted baseball to render and its layout.

    Parameters
    ----------
    palette : dict, optional
        Linear-RGB colour per marker type (``{"blue": (0.1, 0.4, 1.0)}``); the rest keep the
        default palette.
    albedo : RGB
        The leather.

    Returns
    -------
    (Sphere, BallLayout)
    """
    layout = _layout(palette)
    markers = tuple(SphereMarker(d, s, layout.marker_size, 0.0, c, name=n)
                    for d, s, c, n in zip(layout.directions, layout.shapes, layout.colors, layout.names))
    return Sphere(layout.radius, albedo, markers, "baseball"), layout


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
        }

    @classmethod
    def from_dict(cls, d: dict) -> PitchTruth:
        return cls(d["preset"], d["model"], ReleaseState.from_dict(d["release"]), float(d["plate_time_s"]),
                   float(d["end_time_s"]), [PairTruth.from_dict(p, len(d["ball"]["markers"])) for p in d["pairs"]],
                   d["metrics"], d["ball"],
                   list(d["cameras"]), d.get("calibration_error"))


def _in_view(cam: Camera, points: np.ndarray, margin_px=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 2)`` of world points and whether each lies in front of the camera, inside
    its field of view and inside the image (-0.5 .. size - 0.5, widened by ``margin_px``, a
    scalar or per point).

    The field-of-view test matters: far outside the image the distortion polynomial folds
    back, so :meth:`Camera.project` can put a point behind the camera's shoulder inside the
    image.
    """
    W, H = cam.image_size
    px = cam.project(points)
    s = np.linspace(0, 1, 33)
    xs, ys, zero = s * (W - 1), s * (H - 1), np.zeros_like(s)
    border = np.concatenate([np.stack([xs, zero], 1), np.stack([xs, zero + H - 1], 1),
                             np.stack([zero, ys], 1), np.stack([zero + W - 1, ys], 1)])
    lim = np.abs(cam.pixels_to_normalized(border)).max(axis=0) * 1.05
    pc = cam.world_to_cam(np.atleast_2d(points))
    with np.errstate(invalid="ignore", divide="ignore"):
        xn = pc[:, :2] / pc[:, 2:]
    ok = (pc[:, 2] > 0) & np.all(np.abs(xn) <= lim, axis=1)
    m = np.asarray(margin_px, float).reshape(-1, 1)
    ok &= np.all(np.isfinite(px), axis=1) & np.all((px >= -0.5 - m) & (px <= np.array([W - 0.5, H - 0.5]) + m), axis=1)
    return px, ok


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
        centres = pos[:, None] + r * normals
        facing = np.einsum("kma,kma->km", normals, cam.center - centres) > 0
        mp = cam.project(centres.reshape(-1, 3)).reshape(n, nm, 2)
        keep = facing & ok[:, None]
        mpx[ci][keep] = mp[keep]
    return PairTruth(pair.name, list(pair.cameras), hz, pair.shutter_s, float(first_flash_s), n_flashes,
                     pair.light.position.copy(), float(pair.light.intensity), idx.astype(int), times, poses,
                     centers, visible, radius, phase, mpx, rendered)


# --------------------------------------------------------------------------------------------
# The capture
# --------------------------------------------------------------------------------------------
#: Smallest image width (px) at which :func:`pitch_capture` calibrates from rendered photos.
MIN_CALIBRATION_WIDTH = 960
#: Radiance of the black room behind the balls (before the sensor), and its texture.
ROOM = Backdrop(level=0.004, contrast=0.3, scale_px=80.0)
#: Ambient light on the ball over the whole shutter (a dark room: almost none).
AMBIENT = 0.002


@dataclass
class PitchCapture:
    """A rendered pitch: the rig, the photos, the truth and what goes into the capture folder.

    Attributes
    ----------
    rig : PitchRig
        The true rig (cameras, strobes, timing).
    images : list of ndarray
        One uint8 BGR photo per camera, in rig order.
    truth : PitchTruth
    capture_rig : Rig
        The rig written to ``rig.json``: calibrated from rendered photos (``calibration``), or
        the true one when ``calibration`` is None.
    calibration : PitchCalibration or None
    scenes : dict[str, Scene]
        The rendered scene of each pair (to re-render, e.g. noise-free radiance in tests).
    known_flash_times : bool
        Whether ``capture.json`` gives each image's ``first_flash_s`` and ``n_flashes``.
    """

    rig: PitchRig
    images: list
    truth: PitchTruth
    capture_rig: Rig
    calibration: PitchCalibration | None = None
    scenes: dict = field(default_factory=dict)
    known_flash_times: bool = False

    @property
    def capture(self) -> Capture:
        """The :class:`~stillcap.io.capture.Capture` (PNG file names; images not attached)."""
        return self.to_capture()[0]

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        """The capture folder content: ``(Capture, {file: image})``.

        Per image: ``strobe_hz`` and ``shutter_s`` of its pair; ``first_flash_s`` and
        ``n_flashes`` only with ``known_flash_times`` (free-running strobes: normally unknown);
        ``meta.pair``. Capture meta: ``rig_calibrated``, ``rig_source``, ``calibration`` (the
        procedure and residuals), ``preset``, ``pairs``, ``flash_times``.
        """
        files = [f"images/{c.name}{ext}" for c in self.rig.rig]
        imgs = []
        for f, cam in zip(files, self.rig.rig):
            p = self.rig.pair_of(cam.name)
            pt = self.truth.pair(p.name)
            timing = (pt.first_flash_s, pt.n_flashes) if self.known_flash_times else (None, None)
            imgs.append(CaptureImage(f, cam.name, p.strobe_hz, p.shutter_s, *timing, meta={"pair": p.name}))
        calibrated = self.calibration is not None
        meta = {
            "synthetic": True,
            "description": (f"synthetic pitch ({self.truth.preset.get('name')}, "
                            f"{self.truth.release.speed_mph:.1f} mph, {self.truth.release.spin_rpm:.0f} rpm): "
                            f"front pair at {self.rig.pair('front').strobe_hz:g} Hz, "
                            f"back pair at {self.rig.pair('back').strobe_hz:g} Hz"),
            "rig_calibrated": calibrated,
            "rig_source": ("calibrated from rendered photos (see calibration)" if calibrated
                           else "true rig (calibration skipped)"),
            "preset": self.truth.preset.get("name"),
            "pairs": {p.name: list(p.cameras) for p in self.rig.pairs},
            "flash_times": "known" if self.known_flash_times else "unknown (free-running strobes)",
        }
        if calibrated:
            meta["calibration"] = self.calibration.to_dict()
        cap = Capture("pitch", self.capture_rig, imgs, self.truth.to_dict(), meta)
        return cap, dict(zip(files, self.images))


def pitch_capture(preset: str | PitchPreset = DEFAULT_PRESET, rng=None, *, calibrate: bool = True,
                  speed_mph: float | None = None, spin_rpm: float | None = None,
                  spin_axis_deg: float | None = None, spin_efficiency: float | None = None,
                  release_m=None, target_m=None, front_hz: float = 80.0, back_hz: float = 50.0,
                  palette: dict | None = None, model="seed",
                  variation: ReleaseVariation | None = DEFAULT_VARIATION, release_time_s: float | None = None,
                  image_size=(2560, 1920), sensor: Sensor | None = None, supersample: int = 3,
                  calibration_views: int = 5, known_flash_times: bool = False,
                  progress: Callable[[int, int, str], None] | None = None) -> PitchCapture:
    """Render a pitch photographed by the seed's rig, with the truth (module docstring).

    Parameters
    ----------
    preset : str or PitchPreset
        :data:`PRESETS` name (default ``"seed-4seam"``).
    rng : np.random.Generator or int, optional
        Same seed, same capture. The pitch, the strobe phases and the photos do not depend on
        ``calibrate``.
    calibrate : bool
        Calibrate the rig from rendered photos (:func:`calibrate_pitch_rig`, slow: ~40 renders
        at full size) or write the true rig (``rig_calibrated: false``).
    speed_mph, spin_rpm, spin_axis_deg, spin_efficiency, release_m, target_m, variation
        See :func:`release_state`.
    front_hz, back_hz : float
        Strobe rates.
    palette : dict, optional
        Marker colours per type (linear RGB).
    model : "seed", "nathan" or FlightModel
    release_time_s : float, optional
        Release time after the shutters opened (default uniform in 0.2..0.3 s).
    image_size : (width, height)
        Default 2560x1920; smaller 4:3 sizes keep the field of view (quick tests).
    sensor : Sensor, optional
        Default ``Sensor()`` (noise); ``Sensor.ideal()`` for noise-free photos.
    supersample : int
        Sub-pixel rays per axis at edges.
    calibration_views : int
        Close-up chessboard views per camera.
    known_flash_times : bool
        Write ``first_flash_s`` and ``n_flashes`` per image (default: unknown, as with
        free-running strobes; the truth has them).
    progress : callable(done, total, label), optional

    Returns
    -------
    PitchCapture
    """
    rng = as_rng(rng)
    if calibrate and _check_size(image_size)[0] < MIN_CALIBRATION_WIDTH:
        raise ValueError(f"calibrate=True needs images at least {MIN_CALIBRATION_WIDTH} px wide (the far field "
                         f"board's squares must stay large enough for corner detection), got {image_size}; "
                         "use calibrate=False for small test images")
    if calibrate and int(calibration_views) < 3:
        raise ValueError(f"calibration needs at least 3 close-up views per camera, got {calibration_views}")
    seeds = rng.integers(0, 2 ** 63 - 1, size=4)
    r_pitch, r_time, r_render, r_calib = (np.random.default_rng(int(s)) for s in seeds)
    flight = flight_model(model)
    rig = pitch_rig(front_hz, back_hz, image_size)
    ball, layout = ball_sphere(palette)
    supersample = int(supersample)
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    sensor = sensor or Sensor()

    t0 = float(r_time.uniform(0.2, 0.3)) if release_time_s is None else float(release_time_s)
    if not (np.isfinite(t0) and 0 <= t0 < min(p.shutter_s for p in rig.pairs)):
        raise ValueError(f"release_time_s must be within the shutter time "
                         f"(0..{min(p.shutter_s for p in rig.pairs)} s), got {t0}")
    phases = {p.name: float(r_time.uniform(0, 1 / p.strobe_hz)) for p in rig.pairs}
    release = release_state(preset, r_pitch, speed_mph=speed_mph, spin_rpm=spin_rpm, spin_axis_deg=spin_axis_deg,
                            spin_efficiency=spin_efficiency, release_m=release_m, target_m=target_m,
                            variation=variation, model=flight, t0=t0)
    preset_obj = PRESETS[preset] if isinstance(preset, str) else preset
    end = cross_plane(release.p0, release.v0, release.spin, flight, t0=t0, plane_point=(0, END_Y, 0))
    plate = cross_plane(release.p0, release.v0, release.spin, flight, t0=t0)
    if not (end.success and plate.success):
        raise ValueError("the pitch does not reach home plate (too slow or thrown away from it)")
    metrics = pitch_metrics_from_flight(release.p0, release.v0, release.spin, flight, t0=t0).to_dict()
    pairs = [_pair_truth(p, rig.rig, release, end.time, phases[p.name], flight, layout) for p in rig.pairs]
    overrides = {k: v for k, v in (("speed_mph", speed_mph), ("spin_rpm", spin_rpm), ("spin_axis_deg", spin_axis_deg),
                                   ("spin_efficiency", spin_efficiency), ("release_m", release_m),
                                   ("target_m", target_m)) if v is not None}
    ball_info = {"radius": layout.radius, "albedo": np.asarray(ball.albedo), "marker_size": layout.marker_size,
                 "palette": {k: list(v) for k, v in layout.palette.items()},
                 "markers": [{"name": n, "type": layout.type_names[t], "shape": s, "direction": d, "color": c}
                             for n, t, s, d, c in zip(layout.names, layout.types, layout.shapes,
                                                      layout.directions, layout.colors)]}
    truth = PitchTruth({**preset_obj.to_dict(), "overrides": overrides,
                        "variation": None if variation is None else vars(variation).copy()},
                       flight.kind, release, float(plate.time), float(end.time), pairs, metrics, ball_info,
                       rig.rig.names)

    n_cal = (calibration_views + len(FRONT_BOARD_SPOTS)) * len(rig.rig) if calibrate else 0
    total = n_cal + len(rig.rig)
    scenes = {}
    for p, pt in zip(rig.pairs, pairs):
        flashes = [Flash([T], float(t)) for T, t, shown in zip(pt.ball2world, pt.times, pt.rendered) if shown]
        exposure = Exposure(flashes, AMBIENT, p.shutter_s, p.strobe_hz, pt.first_flash_s)
        scenes[p.name] = Scene([ball], exposure, [p.light], backdrop=ROOM)
    images = []
    for i, cam in enumerate(rig.rig):
        images.append(render(cam, scenes[rig.pair_of(cam.name).name], sensor, r_render, supersample))
        _progress(progress, i + 1, total, f"rendering {cam.name}")

    calibration, capture_rig = None, rig.rig
    if calibrate:
        calibration = calibrate_pitch_rig(
            rig, r_calib, calibration_views, sensor, supersample,
            progress=lambda i, n, label: _progress(progress, len(rig.rig) + i, total, label))
        capture_rig = calibration.rig
        truth.calibration_error = rig_reprojection_error(
            rig.rig, capture_rig, {c.name: _corridor_points(rig.pair_of(c.name).name) for c in rig.rig})
    _progress(progress, total, total, "done")
    return PitchCapture(rig, images, truth, capture_rig, calibration, scenes, bool(known_flash_times))
