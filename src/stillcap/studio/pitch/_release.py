"""The pitch presets, the pitcher's scatter and the release state of one pitch (aimed at its
target with the flight model): :func:`release_state`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array, as_rng
from stillcap.ball.metrics import MPH, RPM_PER_RAD_S, spin_vector
from stillcap.ball.physics import PLATE_FRONT_Y, cross_plane, flight_model
from stillcap.camera import pose_matrix

FT = 0.3048
#: Front of the pitching rubber, y (m).
RUBBER_Y = 60.5 * FT
#: Where the flight ends: the heavy carpet hanging behind home plate, y (m).
END_Y = -0.6
#: Seed release point (three-quarter delivery, right-hander: arm side is -x), m.
SEED_RELEASE = (-0.55, 54.5 * FT, 1.80)
#: A modern right-hander's release point (6.5 ft extension), m.
MLB_RELEASE = (-0.60, 54.0 * FT, 1.78)


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
