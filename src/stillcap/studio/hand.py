"""The hand scenario (SPEC J2, seed section 5): the pitcher's gloved hand around release,
photographed by four cameras behind and above the pitcher in one 75 Hz strobe's light.

Everything is in the baseball **field frame** (as :mod:`stillcap.studio.pitch`: origin at the
back tip of home plate, y toward the pitcher, z up), metres and seconds since the shutters
opened. See ``docs/hand.md`` for the numbers.

- **Motion** (:class:`HandMotion`): a right-hander's three-quarter delivery over the last
  ~60 ms around release. The ball, held, moves on a circle about the shoulder (radius
  :data:`ARM_RADIUS`) in the plane spanned by the three-quarter arm slot and the release
  velocity, so it leaves the hand with exactly the pitch's release position and velocity
  (:func:`stillcap.studio.pitch.release_state`); the arm speeds up before release and slows
  after. The hand frame follows the arm (fingers along the radius, palm toward the throw) plus
  a wrist snap; finger joint angles follow keyframed smooth curves (index and middle on top of
  the ball extend as it rolls off the fingertips, then flex in the follow-through; ring and
  little stay tucked; the thumb lets go). The held ball sits where it clears the glove
  (:mod:`stillcap.studio.hand_grip`). After release it follows the pitch's flight and spin.
- **Bodies**: the hand (:func:`stillcap.body.hand.hand_skeleton`) as black capsules
  (glove albedo :data:`GLOVE`) along its bones plus the palm, its 18 markers
  (:func:`~stillcap.body.hand.hand_markerset`) as spheres of their colours, the arm in black
  clothes (two capsules to the shoulder), and the seed's painted baseball
  (:func:`stillcap.studio.pitch.ball_sphere`).
- **Rig** (:func:`hand_rig`): four cameras on a half circle behind and above the pitcher, two
  per side (stereo pairs ``left`` and ``right``), all looking at the release region; one strobe
  directly behind the pitcher at 75 Hz; shutter 1 s; a black room. The strobe runs free (its
  phase is random, in the truth); the flashes within the motion window are rendered.

The true rig is written to the capture (``rig_calibrated: false``): calibration is the pitch
scenario's business (:func:`stillcap.studio.pitch.calibrate_pitch_rig` shows how).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array, as_rng
from stillcap.ball.physics import flight_model
from stillcap.body.hand import hand_markerset, hand_pose, hand_skeleton, marker_colors
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Pose, Skeleton
from stillcap.camera import Camera, Rig, pose_matrix
from stillcap.geometry.marker_points import lit_sphere_centroids
from stillcap.io.capture import Capture, CaptureImage
from stillcap.files.jsonable import from_jsonable
from stillcap.studio.pitch import (AMBIENT, DEFAULT_VARIATION, PRESETS, ROOM, ReleaseState, ReleaseVariation,
                                   ball_sphere, field_look_at, release_state)
from stillcap.studio.pitch._rig import _check_size, _in_view
from stillcap.studio.pitch._truth import _ball_poses
from stillcap.studio.hand_grip import BALL_IN_HAND, _hand_parts, held_ball_center  # noqa: F401 (BALL_IN_HAND: studio.hand's name)
from stillcap.studio.puppet import marker_visibility
from stillcap.studio.renderer import _hit, render
from stillcap.studio.scene import Capsule, Exposure, Flash, PointLight, Scene, Sphere
from stillcap.studio.sensor import Sensor, srgb_to_linear

__all__ = ["ARM_RADIUS", "CAMERA_NAMES", "GLOVE", "HandCapture", "HandMotion", "HandRig", "HandTruth",
           "WINDOW_S", "hand_bodies", "hand_capture", "hand_motion", "hand_rig", "lit_centroids"]

#: Albedo of the black glove and of the black clothes.
GLOVE, CLOTHES = 0.04, 0.03
#: Shoulder to ball centre while the ball is held (m).
ARM_RADIUS = 0.65
#: Arm slot: angle of the arm from vertical toward the arm side at release (three-quarter).
ARM_SLOT_DEG = 45.0
#: The motion window rendered, relative to release (s): the last ~60 ms around it.
WINDOW_S = (-0.040, 0.020)
#: Angular acceleration of the arm relative to its speed at release, before / after (1/s).
ARM_ACCEL = (8.0, -12.0)
#: Camera names in rig order; pairs ``left`` (x > 0, the pitcher's glove side) and ``right``.
CAMERA_NAMES = ("left_outer", "left_inner", "right_inner", "right_outer")
#: Camera layout: azimuth from straight behind (deg, + toward the glove side), horizontal
#: distance from the aim point (m), height above it (m), focal length at 2560 px width (px).
_LAYOUT = {"left_outer": (75.0, 2.3, 1.0, 3300.0), "left_inner": (35.0, 2.3, 1.3, 3315.0),
           "right_inner": (-35.0, 2.3, 1.3, 3290.0), "right_outer": (-75.0, 2.3, 1.0, 3305.0)}
_DIST = (-0.08, 0.10, 0.0003, -0.0002, -0.02)
#: Strobe: behind the pitcher (distance behind the aim point, height above it, m) and intensity.
STROBE_BEHIND, STROBE_UP, STROBE_INTENSITY = 3.0, 0.9, 9.0
STROBE_HZ, SHUTTER_S, MARKER_RADIUS = 75.0, 1.0, 0.005
#: Forearm and upper arm capsules: (length, radius), m.
FOREARM, UPPER_ARM = (0.26, 0.032), (0.28, 0.045)
#: Distance from the wrist joint to the start of the forearm capsule (m).
ARM_GAP = 0.04

# Keyframes of the finger joint angles (deg), times relative to release (s):
# joint -> (twist, flexion, abduction) per key time.
_KEY_T = (-0.060, -0.012, 0.0, 0.030)
_KEYS = {
    "thumb-cmc": ((20, 45, -10), (20, 45, -10), (10, 15, 5), (10, 30, 0)),
    "thumb-mcp": ((0, 25, 0), (0, 25, 0), (0, 5, 0), (0, 20, 0)),
    "thumb-ip": ((0, 25, 0), (0, 25, 0), (0, 5, 0), (0, 25, 0)),
    "index-mcp": ((0, 28, 4), (0, 28, 4), (0, -8, 2), (0, 40, 0)),
    "index-pip": ((0, 40, 0), (0, 40, 0), (0, 8, 0), (0, 55, 0)),
    "index-dip": ((0, 15, 0), (0, 15, 0), (0, 0, 0), (0, 30, 0)),
    "middle-mcp": ((0, 28, -3), (0, 28, -3), (0, -8, -1), (0, 40, 0)),
    "middle-pip": ((0, 40, 0), (0, 40, 0), (0, 8, 0), (0, 55, 0)),
    "middle-dip": ((0, 15, 0), (0, 15, 0), (0, 0, 0), (0, 30, 0)),
    "ring-mcp": ((0, 55, -6), (0, 55, -6), (0, 45, -4), (0, 55, -4)),
    "ring-pip": ((0, 85, 0), (0, 85, 0), (0, 70, 0), (0, 80, 0)),
    "ring-dip": ((0, 40, 0), (0, 40, 0), (0, 30, 0), (0, 40, 0)),
    "little-mcp": ((0, 60, -12), (0, 60, -12), (0, 50, -8), (0, 60, -8)),
    "little-pip": ((0, 85, 0), (0, 85, 0), (0, 75, 0), (0, 85, 0)),
    "little-dip": ((0, 40, 0), (0, 40, 0), (0, 30, 0), (0, 40, 0)),
}
#: Wrist: extension (-) to flexion (+) about the hand's radial axis, and pronation about the
#: distal axis (deg), at the key times.
_WRIST_FLEX = (-35.0, -15.0, 10.0, 35.0)
_WRIST_PRONATION = (0.0, 0.0, 5.0, 25.0)


# --------------------------------------------------------------------------------------------
# Motion
# --------------------------------------------------------------------------------------------
@dataclass
class HandMotion:
    """The delivery around release (field frame): hand pose and ball pose at any time.

    Attributes
    ----------
    release : ReleaseState
        The ball as it leaves the hand (time ``t0``, position, velocity, spin, orientation).
    shoulder : ndarray, shape (3,)
        Centre of the arm's circle (m).
    arm_dir, throw_dir : ndarray, shape (3,)
        Unit vectors spanning the arm's plane: the arm at release (the three-quarter slot) and
        the release velocity's direction.
    skeleton : Skeleton
    flight_model : FlightModel
    angle_offsets_deg : ndarray, shape (n_joints, 3), optional
        Another person's own motion (:mod:`stillcap.studio.hand_variation`).
    markerset, ball_radius : MarkerSet, float, optional
        The glove's markers and the ball's radius (m) that seat the ball (default the seed's).
    """

    release: ReleaseState
    shoulder: np.ndarray
    arm_dir: np.ndarray
    throw_dir: np.ndarray
    skeleton: Skeleton
    flight_model: object
    angle_offsets_deg: np.ndarray | None = None
    markerset: MarkerSet | None = None
    ball_radius: float | None = None
    _seat: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def ball_in_hand(self) -> np.ndarray:
        """The held ball's centre in the hand frame (m), seated clear of the glove for this hand
        and motion (:func:`stillcap.studio.hand_grip.held_ball_center`); fixed for the throw."""
        return held_ball_center(self)

    @property
    def omega(self) -> float:
        """Arm angular speed at release (rad/s)."""
        return float(np.linalg.norm(self.release.v0) / ARM_RADIUS)

    def arm_angle(self, t) -> np.ndarray:
        """Angle of the arm past its release position (rad) at times ``t`` (s)."""
        tau = np.asarray(t, float) - self.release.t0
        a = np.where(tau < 0, ARM_ACCEL[0], ARM_ACCEL[1])
        return self.omega * (tau + 0.5 * a * tau ** 2)

    def _arc(self, t):
        phi = self.arm_angle(t)
        c, s = np.cos(phi)[..., None], np.sin(phi)[..., None]
        radial = c * self.arm_dir + s * self.throw_dir
        tangent = -s * self.arm_dir + c * self.throw_dir
        return self.shoulder + ARM_RADIUS * radial, radial, tangent

    def root2world(self, t: float, ball_in_hand=None) -> np.ndarray:
        """The hand's root (back of the hand) frame at ``t`` (4, 4); ``ball_in_hand`` overrides the seat."""
        ball, radial, tangent = self._arc(float(t))
        x, z = radial, -tangent  # fingers along the arm, back of the hand away from the throw
        R = np.column_stack([x, np.cross(z, x), z])
        tau = float(t) - self.release.t0
        flex = float(PchipInterpolator(_KEY_T, _WRIST_FLEX, extrapolate=True)(tau))
        pron = float(PchipInterpolator(_KEY_T, _WRIST_PRONATION, extrapolate=True)(tau))
        R = R @ Rotation.from_euler("YX", [flex, pron], degrees=True).as_matrix()
        return pose_matrix(R, ball - R @ (self.ball_in_hand if ball_in_hand is None else np.asarray(ball_in_hand, float)))

    def angles_deg(self, t: float) -> np.ndarray:
        """Joint angles (twist, flexion, abduction) in degrees at time ``t``, shape (n_joints, 3)."""
        tau = float(t) - self.release.t0
        out = np.zeros((self.skeleton.n_joints, 3))
        for name, keys in _KEYS.items():
            out[self.skeleton.index(name)] = PchipInterpolator(_KEY_T, np.array(keys, float), axis=0,
                                                               extrapolate=True)(tau)
        if self.angle_offsets_deg is not None:
            lim = self.skeleton.limits_deg
            out = np.clip(out + self.angle_offsets_deg, np.nan_to_num(lim[..., 0], nan=-180),
                          np.nan_to_num(lim[..., 1], nan=180))
        return out

    def pose(self, t: float) -> Pose:
        """The hand's pose at time ``t``."""
        return hand_pose(self.skeleton, self.root2world(t), self.angles_deg(t))

    def held(self, t) -> np.ndarray:
        """Whether the ball is still in the hand at ``t`` (before release)."""
        return np.asarray(t, float) < self.release.t0

    def ball2world(self, t) -> np.ndarray:
        """Ball pose at times ``t`` (n, 4, 4): carried by the hand before release (turning with
        it), the pitch's flight and spin after."""
        t = np.atleast_1d(np.asarray(t, float))
        out = np.tile(np.eye(4), (len(t), 1, 1))
        after = ~self.held(t)
        if after.any():
            out[after] = _ball_poses(self.release, t[after], self.flight_model)
        R0h = self.root2world(self.release.t0)[:3, :3]
        for k in np.flatnonzero(~after):
            ball, _, _ = self._arc(float(t[k]))
            Rh = self.root2world(float(t[k]))[:3, :3]
            out[k, :3, :3] = Rh @ R0h.T @ self.release.ball2world[:3, :3]
            out[k, :3, 3] = ball
        return out


def hand_motion(release: ReleaseState, model="seed", skeleton: Skeleton | None = None,
                arm_slot_deg: float = ARM_SLOT_DEG, *, markerset: MarkerSet | None = None,
                angle_offsets_deg=None, ball_radius: float | None = None) -> HandMotion:
    """The delivery whose ball leaves the hand in the ``release`` state (see :class:`HandMotion`).

    The arm's plane holds the release velocity and the arm slot (``arm_slot_deg`` from vertical
    toward the arm side, -x for a right-hander); the shoulder lies :data:`ARM_RADIUS` from the
    release point along the arm.
    """
    v = np.asarray(release.v0, float)
    vhat = v / np.linalg.norm(v)
    slot = np.radians(arm_slot_deg)
    a = np.array([-np.sin(slot), 0.0, np.cos(slot)])
    a = a - (a @ vhat) * vhat
    a /= np.linalg.norm(a)
    return HandMotion(release, release.p0 - ARM_RADIUS * a, a, vhat, skeleton or hand_skeleton(),
                      flight_model(model), angle_offsets_deg, markerset, ball_radius)


# --------------------------------------------------------------------------------------------
# Bodies
# --------------------------------------------------------------------------------------------
def _align_z(v: np.ndarray) -> np.ndarray:
    """A rotation whose z axis is along ``v``."""
    z = v / np.linalg.norm(v)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def hand_bodies(skeleton: Skeleton, markerset: MarkerSet) -> tuple[list, Callable]:
    """The hand and arm as bodies, and a function placing them.

    Returns
    -------
    bodies : list
        Hand capsules (glove), the 18 marker spheres, then the forearm and upper arm (clothes).
    place : callable(pose, shoulder) -> list of (4, 4)
        ``body2world`` of every body for a hand pose and the shoulder position.
    """
    parts = _hand_parts(skeleton)
    bodies = [Capsule(float(np.linalg.norm(b - a)), r, albedo=GLOVE, name=n) for n, _, a, b, r in parts]
    local = [pose_matrix(_align_z(b - a), a) for _, _, a, b, _ in parts]
    frames = [f for _, f, _, _, _ in parts]
    for m in markerset.markers:
        bodies.append(Sphere(m.diameter / 2, albedo=srgb_to_linear(np.array(m.rgb) * 255), name=m.name))
    # the arm: a forearm from the wrist toward the shoulder and an upper arm from the shoulder
    # toward the wrist, fixed lengths that overlap at the elbow (wrist to shoulder is ~0.53 m)
    bodies += [Capsule(FOREARM[0], FOREARM[1], CLOTHES, "forearm"), Capsule(UPPER_ARM[0], UPPER_ARM[1], CLOTHES, "upper-arm")]

    def place(pose: Pose, shoulder) -> list:
        shoulder = np.asarray(shoulder, float)
        j2w = pose.joint2world
        out = [j2w[f] @ T for f, T in zip(frames, local)]
        for p in markerset.positions(pose):
            out.append(pose_matrix(np.eye(3), p))
        wrist = j2w[skeleton.root][:3, 3]
        u = (shoulder - wrist) / np.linalg.norm(shoulder - wrist)
        wrist = wrist + ARM_GAP * u  # the sleeve starts behind the back-of-hand markers
        out.append(pose_matrix(_align_z(u), wrist))
        out.append(pose_matrix(_align_z(wrist - shoulder), shoulder))
        return out

    return bodies, place


# --------------------------------------------------------------------------------------------
# Rig
# --------------------------------------------------------------------------------------------
@dataclass
class HandRig:
    """Four cameras and the strobe (field frame).

    Attributes
    ----------
    rig : Rig
        Cameras in the order of :data:`CAMERA_NAMES` (``world = "field"``).
    pairs : dict
        ``{"left": (left_outer, left_inner), "right": (right_inner, right_outer)}``.
    light : PointLight
        The strobe, directly behind the pitcher.
    strobe_hz, shutter_s : float
    aim : ndarray, shape (3,)
        The point all cameras look at (the middle of the release region).
    """

    rig: Rig
    pairs: dict
    light: PointLight
    strobe_hz: float
    shutter_s: float
    aim: np.ndarray

    def pair_of(self, camera: str) -> str:
        for k, v in self.pairs.items():
            if camera in v:
                return k
        raise ValueError(f"camera {camera!r} is in no pair (cameras: {self.rig.names})")


def _nominal_aim() -> np.ndarray:
    """Middle of the hand's and ball's path over the window for the default pitch (no scatter)."""
    rel = release_state("seed-4seam", 0, variation=None, t0=0.0)
    mo = hand_motion(rel)
    t = np.linspace(*WINDOW_S, 7)
    pts = np.array([mo.root2world(s)[:3, 3] for s in t] + [mo.ball2world([s])[0, :3, 3] for s in t])
    return 0.5 * (pts.min(axis=0) + pts.max(axis=0))


def hand_rig(image_size=(2560, 1920), strobe_hz: float = STROBE_HZ, shutter_s: float = SHUTTER_S,
             layout: dict | None = None, light_offset=None) -> HandRig:
    """The seed's hand rig: 4 cameras in a half circle behind and above the pitcher, two per side
    (stereo pairs ``left`` and ``right``), one strobe directly behind the pitcher.

    Parameters
    ----------
    image_size : (width, height)
        4:3; the intrinsics scale with the width (same field of view).
    strobe_hz, shutter_s : float
        Seed: 75 Hz, 1 s.
    layout : dict, optional
        Camera name -> (azimuth deg, distance m, height m, focal px) replacing the seed's layout
        (another studio's placement: :mod:`stillcap.studio.hand_variation`).
    light_offset : array_like, shape (3,), optional
        Moves the strobe from its seed place (m).
    """
    w, h = _check_size(image_size)
    strobe_hz, shutter_s = float(strobe_hz), float(shutter_s)
    if not (np.isfinite(strobe_hz) and 1 <= strobe_hz <= 500):
        raise ValueError(f"strobe_hz must be between 1 and 500 Hz, got {strobe_hz}")
    if not (np.isfinite(shutter_s) and 0.05 <= shutter_s <= 30):
        raise ValueError(f"shutter_s must be between 0.05 and 30 s, got {shutter_s}")
    aim = _nominal_aim()
    s = w / 2560.0
    cams = []
    for k, name in enumerate(CAMERA_NAMES):
        az, dist, up, f = (layout or _LAYOUT)[name]
        a = np.radians(az)
        eye = aim + np.array([dist * np.sin(a), dist * np.cos(a), up])
        dx, dy = (3.0, -2.0) if k % 2 else (-4.0, 3.5)
        cams.append(Camera.from_intrinsics(name, f * s, f * s * (1.0002 if k % 2 else 0.9997), (w - 1) / 2 + dx * s,
                                           (h - 1) / 2 + dy * s, (w, h), dist=_DIST,
                                           world2cam=field_look_at(eye, aim, 0.4 * (k - 1.5))))
    light = PointLight(aim + np.array([0.0, STROBE_BEHIND, STROBE_UP]) + (0 if light_offset is None else
                                                                         np.asarray(light_offset, float)),
                       STROBE_INTENSITY)
    pairs = {"left": CAMERA_NAMES[:2], "right": CAMERA_NAMES[2:]}
    return HandRig(Rig(cams, world="field"), pairs, light, strobe_hz, shutter_s, aim)


# --------------------------------------------------------------------------------------------
# Truth
# --------------------------------------------------------------------------------------------
@dataclass
class HandTruth:
    """Ground truth of a hand capture (field frame, SI, pixels (x, y); n flashes, 4 cameras).

    Attributes
    ----------
    release : ReleaseState
    preset : str
    strobe_hz, shutter_s, first_flash_s : float
        The strobe (free-running: ``first_flash_s`` is its random phase).
    n_flashes : int
        Flashes while the shutter was open.
    window_s : (float, float)
        The motion window rendered, s relative to release.
    flash_index : ndarray of int, shape (n,)
        The rendered flashes (flash ``k`` fires at ``first_flash_s + k / strobe_hz``).
    times : ndarray, shape (n,)
    held : ndarray of bool, shape (n,)
        The ball is still in the hand.
    root2world : ndarray, shape (n, 4, 4)
        The hand's root (back of the hand) frame.
    local_rotations : ndarray, shape (n, n_joints, 3, 3)
    angles_deg : ndarray, shape (n, n_joints, 3)
        Joint angles (twist, flexion, abduction; intrinsic XYZ Euler), degrees.
    joints : ndarray, shape (n, n_joints, 3)
        Joint positions.
    markers : ndarray, shape (n, 18, 3)
        Labelled marker centres.
    markers_px : ndarray, shape (4, n, 18, 2)
        True pixel of each marker centre; NaN unless ``markers_visible``.
    markers_lit_px : ndarray, shape (4, n, 18, 2)
        Radiance-weighted centroid of the marker's (partly lit) image (:func:`lit_centroids`):
        where an unobstructed blob's centroid lies; NaN unless ``markers_visible``.
    markers_visible : ndarray of bool, shape (4, n, 18)
        The line of sight to the marker centre is clear (glove, arm, ball and other markers of
        the same flash) and the centre is inside the image.
    markers_coverage : ndarray, shape (4, n, 18)
        Share of the marker's silhouette not hidden by other bodies of its flash.
    markers_isolated : ndarray of bool, shape (4, n, 18)
        Visible, and its image disc is at least 2 px away from the disc of every other marker
        (any part of it unhidden) and every ball in the image, of every flash: its blob stands
        alone in the multi-exposure photo.
    ball2world : ndarray, shape (n, 4, 4)
    ball_px : ndarray, shape (4, n, 2)
        Ball centre pixel; NaN unless ``ball_visible``.
    ball_visible : ndarray of bool, shape (4, n)
    ball_radius_px : ndarray, shape (4, n)
    ball_markers_px : ndarray, shape (4, n, 12, 2)
        Painted ball markers facing the camera (NaN otherwise or when the ball is not visible).
    ball : dict
        Ball layout (as in the pitch truth).
    cameras : list of str
    pairs : dict
    marker_names, marker_colours, joint_names : list of str
    """

    release: ReleaseState
    preset: str
    strobe_hz: float
    shutter_s: float
    first_flash_s: float
    n_flashes: int
    window_s: tuple
    flash_index: np.ndarray
    times: np.ndarray
    held: np.ndarray
    root2world: np.ndarray
    local_rotations: np.ndarray
    angles_deg: np.ndarray
    joints: np.ndarray
    markers: np.ndarray
    markers_px: np.ndarray
    markers_lit_px: np.ndarray
    markers_visible: np.ndarray
    markers_coverage: np.ndarray
    markers_isolated: np.ndarray
    ball2world: np.ndarray
    ball_px: np.ndarray
    ball_visible: np.ndarray
    ball_radius_px: np.ndarray
    ball_markers_px: np.ndarray
    ball: dict
    cameras: list
    pairs: dict
    marker_names: list
    marker_colors: list
    joint_names: list
    light: dict = field(default_factory=dict)

    _ARRAYS = ("flash_index", "times", "held", "root2world", "local_rotations", "angles_deg", "joints", "markers",
               "markers_px", "markers_lit_px", "markers_visible", "markers_coverage", "markers_isolated", "ball2world", "ball_px",
               "ball_visible", "ball_radius_px", "ball_markers_px")

    @property
    def n(self) -> int:
        return len(self.times)

    def to_dict(self) -> dict:
        d = {"kind": "hand", "frame": "field",
             "units": {"length": "m", "time": "s (since the shutters opened)", "angle": "deg (angles_deg)",
                       "pixels": "px (x, y), origin top-left pixel centre"},
             "release": self.release.to_dict(), "preset": self.preset, "strobe_hz": self.strobe_hz,
             "shutter_s": self.shutter_s, "first_flash_s": self.first_flash_s, "n_flashes": self.n_flashes,
             "window_s": list(self.window_s), "cameras": list(self.cameras), "pairs": {k: list(v) for k, v in self.pairs.items()},
             "marker_names": list(self.marker_names), "marker_colours": list(self.marker_colors),
             "joint_names": list(self.joint_names), "ball": self.ball, "light": self.light}
        d["flashes"] = {k: getattr(self, k) for k in self._ARRAYS}
        d["flashes"]["times_s"] = d["flashes"].pop("times")
        return d

    @classmethod
    def from_dict(cls, d: dict) -> HandTruth:
        f = dict(d["flashes"])
        f["times"] = f.pop("times_s")
        n, nc, nm, nj = len(f["times"]), len(d["cameras"]), len(d["marker_names"]), len(d["joint_names"])
        shapes = {"flash_index": (n,), "times": (n,), "held": (n,), "root2world": (n, 4, 4),
                  "local_rotations": (n, nj, 3, 3), "angles_deg": (n, nj, 3), "joints": (n, nj, 3),
                  "markers": (n, nm, 3), "markers_px": (nc, n, nm, 2), "markers_lit_px": (nc, n, nm, 2),
                  "markers_visible": (nc, n, nm),
                  "markers_coverage": (nc, n, nm), "markers_isolated": (nc, n, nm), "ball2world": (n, 4, 4),
                  "ball_px": (nc, n, 2), "ball_visible": (nc, n), "ball_radius_px": (nc, n),
                  "ball_markers_px": (nc, n, len(d["ball"]["markers"]), 2)}
        arr = {}
        for k, shp in shapes.items():
            a = from_jsonable(f[k]).reshape(shp)
            if k in ("held", "markers_visible", "markers_isolated", "ball_visible"):
                a = a.astype(bool)
            elif k == "flash_index":
                a = a.astype(int)
            arr[k] = a
        return cls(ReleaseState.from_dict(d["release"]), d["preset"], float(d["strobe_hz"]), float(d["shutter_s"]),
                   float(d["first_flash_s"]), int(d["n_flashes"]), tuple(d["window_s"]), **arr, ball=d["ball"],
                   cameras=list(d["cameras"]), pairs={k: tuple(v) for k, v in d["pairs"].items()},
                   marker_names=list(d["marker_names"]), marker_colors=list(d["marker_colours"]),
                   joint_names=list(d["joint_names"]), light=d.get("light", {}))


# --------------------------------------------------------------------------------------------
# The capture
# --------------------------------------------------------------------------------------------
@dataclass
class HandCapture:
    """A rendered hand capture: the rig, the photos (rig order), the truth, the scene.

    ``to_capture(ext)`` gives the capture folder content ``(Capture, {file: image})``: kind
    ``hand``, per image ``strobe_hz``, ``shutter_s`` and ``meta.pair``; capture meta
    ``rig_calibrated: false``, ``rig_source``, ``pairs``, ``flash_times``, ``strobe_position_m``
    (the strobe, measured with the rig), ``preset``, ``skeleton``, ``markerset``.
    """

    rig: HandRig
    images: list
    truth: HandTruth
    scene: Scene
    motion: HandMotion
    markerset: MarkerSet
    known_flash_times: bool = False

    @property
    def capture(self) -> Capture:
        return self.to_capture()[0]

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        files = [f"images/{c.name}{ext}" for c in self.rig.rig]
        t = self.truth
        timing = (t.first_flash_s, t.n_flashes) if self.known_flash_times else (None, None)
        imgs = [CaptureImage(f, c.name, self.rig.strobe_hz, self.rig.shutter_s, *timing,
                             meta={"pair": self.rig.pair_of(c.name)}) for f, c in zip(files, self.rig.rig)]
        meta = {
            "synthetic": True,
            "description": (f"synthetic hand capture: three-quarter delivery ({t.preset}, "
                            f"{t.release.speed_mph:.1f} mph), {len(t.times)} flashes of a "
                            f"{self.rig.strobe_hz:g} Hz strobe around release, 4 cameras behind the pitcher"),
            "rig_calibrated": False,
            "rig_source": "true rig (calibration skipped)",
            "preset": t.preset,
            "pairs": {k: list(v) for k, v in self.rig.pairs.items()},
            "flash_times": "known" if self.known_flash_times else "unknown (free-running strobe)",
            "strobe_position_m": [float(v) for v in self.rig.light.position],
            "skeleton": self.motion.skeleton.name,
            "markerset": self.markerset.name,
        }
        cap = Capture("hand", self.rig.rig, imgs, t.to_dict(), meta)
        return cap, dict(zip(files, self.images))


def lit_centroids(cam: Camera, centers, radius: float, light_position, occluders=None, own=None) -> np.ndarray:
    """Where the blob of a lambertian sphere lit by a point light appears: the radiance-weighted
    centroid of its image (pixels (N, 2)), for spheres at ``centres`` (N, 3).

    With the strobe behind the pitcher and the cameras to the sides, a marker is partly lit
    (a half moon, like the pitch scenario's back balls): its blob centroid lies up to ~0.6
    marker radii from the projected centre, toward the light. The unoccluded model is the
    pipeline's :func:`stillcap.geometry.marker_points.lit_sphere_centroids` (1200 surface points
    weighted by ``max(n.l, 0) / d_light^2`` times their foreshortening; matches the renderer
    within 0.02 px; ambient light and shadows are neglected). ``occluders`` (``(body,
    body2world)`` pairs) hide the surface points behind them, except the body ``own[i]`` (the
    sphere itself) for sphere ``i``.
    """
    c = np.atleast_2d(np.asarray(centers, float))

    def hide(pts, w):
        sel = w > 0
        to_cam = cam.center - pts[sel]
        t_pt = np.linalg.norm(to_cam, axis=-1)
        d = -to_cam / t_pt[:, None]  # rays from the camera to the surface points
        owner = np.broadcast_to(np.asarray(own)[:, None], w.shape)[sel]
        o = cam.center
        blocked = np.zeros(len(d), bool)
        for j, (body, T) in enumerate(occluders):
            R, p = T[:3, :3], T[:3, 3]
            t = _hit(body, R.T @ (o - p), d @ R)
            blocked |= (t < t_pt - 1e-6) & (owner != j)
        w = w.copy()
        w[sel] = np.where(blocked, 0.0, w[sel])
        return w

    return lit_sphere_centroids(cam, c, radius, light_position, 1200, hide if occluders is not None else None)


def _truth_per_camera(cam: Camera, placed_per_flash: list, marker_idx: list, ball_idx: int, ball_radius: float,
                      ball2world: np.ndarray, layout, light: PointLight) -> dict:
    n, nm = len(placed_per_flash), len(marker_idx)
    vis, cov = np.zeros((n, nm), bool), np.zeros((n, nm))
    bvis = np.zeros(n, bool)
    for k, placed in enumerate(placed_per_flash):
        v, c = marker_visibility(cam, placed, list(marker_idx) + [ball_idx], n_rays=24)
        vis[k], cov[k], bvis[k] = v[:nm], c[:nm], v[nm]
    mpos = np.array([[placed[i][1][:3, 3] for i in marker_idx] for placed in placed_per_flash])  # (n, nm, 3)
    px = cam.project(mpos.reshape(-1, 3)).reshape(n, nm, 2)
    depth = cam.world_to_cam(mpos.reshape(-1, 3))[:, 2].reshape(n, nm)
    rad = cam.K[0, 0] * MARKER_RADIUS / depth
    pos = ball2world[:, :3, 3]
    bpx, ok = _in_view(cam, pos)
    bdepth = cam.world_to_cam(pos)[:, 2]
    ok &= bdepth > ball_radius
    brad = np.where(bdepth > ball_radius, cam.K[0, 0] * ball_radius / np.maximum(bdepth, ball_radius), np.nan)
    bvis &= ok
    # isolation: the disc stays 2 px clear of every other visible marker and ball of any flash
    iso = vis.copy()
    flat_px, flat_r = px.reshape(-1, 2), rad.ravel()
    flat_vis = vis.ravel()
    shown = (cov > 0).ravel() & np.all(np.isfinite(flat_px), axis=1)  # any part of the disc unhidden
    for a in np.flatnonzero(flat_vis):
        d = np.linalg.norm(flat_px - flat_px[a], axis=1) - flat_r - flat_r[a]
        d[a] = np.inf
        clash = np.any((d < 2.0) & shown)
        db = np.linalg.norm(bpx - flat_px[a], axis=1) - np.nan_to_num(brad) - flat_r[a]
        clash |= np.any((db < 2.0) & ok)
        if clash:
            iso.flat[a] = False
    mpx = np.where(vis[..., None], px, np.nan)
    lit = np.stack([lit_centroids(cam, mpos[k], MARKER_RADIUS, light.position, placed, marker_idx)
                    for k, placed in enumerate(placed_per_flash)]) if n else np.zeros((0, nm, 2))
    lit = np.where(vis[..., None], lit, np.nan)
    # painted ball markers facing the camera
    nb = len(layout)
    normals = np.einsum("kab,mb->kma", ball2world[:, :3, :3], layout.directions)
    centers = pos[:, None] + ball_radius * normals
    facing = np.einsum("kma,kma->km", normals, cam.center - centers) > 0
    bm = cam.project(centers.reshape(-1, 3)).reshape(n, nb, 2)
    bm = np.where((facing & bvis[:, None])[..., None], bm, np.nan)
    return {"markers_px": mpx, "markers_lit_px": lit, "markers_visible": vis, "markers_coverage": cov, "markers_isolated": iso,
            "ball_px": np.where(bvis[:, None], bpx, np.nan), "ball_visible": bvis, "ball_radius_px": brad,
            "ball_markers_px": bm}


def hand_capture(rng=None, *, preset: str = "seed-4seam", image_size=(2560, 1920), strobe_hz: float = STROBE_HZ,
                 window_s=WINDOW_S, release_time_s: float | None = None,
                 variation: ReleaseVariation | None = DEFAULT_VARIATION, model="seed", palette: dict | None = None,
                 sensor: Sensor | None = None, supersample: int = 3, known_flash_times: bool = False,
                 person=None, calibration_pose: str | None = None, calibration_motion: str = "curl",
                 progress: Callable[[int, int, str], None] | None = None) -> HandCapture:
    """Render the pitcher's hand around release with the truth (module docstring).

    Parameters
    ----------
    rng : np.random.Generator or int, optional
        Same seed, same capture (pitch scatter, release time, strobe phase, noise).
    preset : str
        Pitch preset of :mod:`stillcap.studio.pitch` (speed, spin) for the ball.
    image_size : (width, height)
        4:3, default the seed's 2560x1920.
    strobe_hz : float
        The strobe (seed: 75 Hz).
    window_s : (float, float)
        Motion window rendered, s relative to release (default the last 40 ms before and 20 ms
        after release: 4-5 flashes at 75 Hz).
    release_time_s : float, optional
        Release time after the shutter opened (default uniform in 0.2..0.3 s).
    variation, model, palette
        As :func:`stillcap.studio.pitch.pitch_capture`.
    sensor : Sensor, optional
        Default ``Sensor()``; ``Sensor.ideal()`` for noise-free photos.
    supersample : int
    known_flash_times : bool
        Write the strobe's phase and flash count per image.
    progress : callable(done, total, label), optional
    person : HandVariation, optional
        Another person's hand, motion, light and camera placement
        (:func:`stillcap.studio.hand_variation.another_hand`); default the seed's.
    calibration_pose : str, optional
        Instead of a throw, a calibration capture for ``stillcap hand-calibrate``: the hand held
        in this pose, then moving (:func:`stillcap.studio.hand_calibration.calibration_motion`).
    calibration_motion : str
        The calibration capture's motion (:data:`~stillcap.studio.hand_calibration.CALIBRATION_MOTIONS`):
        ``protocol`` (the protocol's steps; the window becomes
        :data:`~stillcap.studio.hand_calibration.PROTOCOL_WINDOW_S` unless ``window_s`` is
        given) or ``curl``.

    Returns
    -------
    HandCapture
    """
    rng = as_rng(rng)
    if calibration_pose is not None and calibration_motion.startswith("protocol") and window_s is WINDOW_S:
        from stillcap.studio.hand_calibration import PROTOCOL_WINDOW_S

        window_s = PROTOCOL_WINDOW_S
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}")
    w0, w1 = (float(v) for v in as_array(window_s, (2,), "window_s"))
    if not (-0.2 <= w0 < w1 <= 0.2):
        raise ValueError(f"window_s must be (start, end) within -0.2..0.2 s of release with start < end, got {window_s}")
    supersample = int(supersample)
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    r_pitch, r_time, r_render = (np.random.default_rng(int(s)) for s in rng.integers(0, 2 ** 63 - 1, size=3))
    hrig = hand_rig(image_size, strobe_hz) if person is None else \
        hand_rig(image_size, strobe_hz, layout=person.layout, light_offset=person.light_offset)
    t0 = float(r_time.uniform(0.2, 0.3)) if release_time_s is None else float(release_time_s)
    if not (np.isfinite(t0) and -w0 <= t0 <= hrig.shutter_s - w1):
        raise ValueError(f"release_time_s must leave the motion window inside the shutter "
                         f"({-w0:g}..{hrig.shutter_s - w1:g} s), got {t0}")
    phase = float(r_time.uniform(0, 1 / hrig.strobe_hz))
    flight = flight_model(model)
    release = release_state(preset, r_pitch, variation=variation, model=flight, t0=t0)
    skeleton, markerset = (hand_skeleton(), hand_markerset()) if person is None else (person.skeleton, person.markerset)
    ball, layout = ball_sphere(palette)
    motion = hand_motion(release, flight, skeleton, markerset=markerset, ball_radius=layout.radius,
                         angle_offsets_deg=None if person is None else person.angle_offsets_deg)
    if calibration_pose is not None:
        from stillcap.studio.hand_calibration import calibration_motion as _calibration_motion

        motion = _calibration_motion(motion, calibration_pose, t0, calibration_motion, hrig.strobe_hz)

    hz = hrig.strobe_hz
    n_flashes = int(np.floor((hrig.shutter_s - phase) * hz - 1e-9)) + 1
    k0 = int(np.ceil((t0 + w0 - phase) * hz - 1e-9))
    k1 = int(np.floor((t0 + w1 - phase) * hz + 1e-9))
    idx = np.arange(max(k0, 0), min(k1, n_flashes - 1) + 1)
    times = phase + idx / hz
    poses = [motion.pose(t) for t in times]
    b2w = motion.ball2world(times)

    bodies, place = hand_bodies(skeleton, markerset)
    n_hand = len(_hand_parts(skeleton))
    marker_idx = list(range(n_hand, n_hand + len(markerset)))
    bodies = bodies + [ball]
    ball_idx = len(bodies) - 1
    flashes, placed_per_flash = [], []
    for p, t, B in zip(poses, times, b2w):
        T = place(p, motion.shoulder) + [B]
        flashes.append(Flash(T, float(t)))
        placed_per_flash.append(list(zip(bodies, T)))
    scene = Scene(bodies, Exposure(flashes, AMBIENT, hrig.shutter_s, hz, phase), [hrig.light], backdrop=ROOM)

    per_cam = [_truth_per_camera(c, placed_per_flash, marker_idx, ball_idx, layout.radius, b2w, layout, hrig.light)
               for c in hrig.rig]
    stack = {k: np.stack([pc[k] for pc in per_cam]) for k in per_cam[0]}
    local = np.stack([p.local_rotations for p in poses]) if poses else np.zeros((0, skeleton.n_joints, 3, 3))
    ball_info = {"radius": layout.radius, "albedo": np.asarray(ball.albedo), "marker_size": layout.marker_size,
                 "palette": {k: list(v) for k, v in layout.palette.items()},
                 "markers": [{"name": n, "type": layout.type_names[t], "shape": s, "direction": d, "color": c}
                             for n, t, s, d, c in zip(layout.names, layout.types, layout.shapes,
                                                      layout.directions, layout.colors)]}
    truth = HandTruth(
        release, preset, hz, hrig.shutter_s, phase, n_flashes, (w0, w1), idx.astype(int), times,
        motion.held(times), np.stack([p.root2world for p in poses]), local,
        np.stack([skeleton.limit_angles_deg(p.local_rotations) for p in poses]),
        np.stack([p.positions for p in poses]), np.stack([markerset.positions(p) for p in poses]),
        stack["markers_px"], stack["markers_lit_px"], stack["markers_visible"], stack["markers_coverage"], stack["markers_isolated"],
        b2w, stack["ball_px"], stack["ball_visible"], stack["ball_radius_px"], stack["ball_markers_px"],
        ball_info, hrig.rig.names, dict(hrig.pairs), list(markerset.names), marker_colors(markerset),
        list(skeleton.names), {"position": hrig.light.position, "intensity": hrig.light.intensity})

    sensor = sensor or Sensor()
    hrig = replace(hrig, rig=hrig.rig.with_responses(sensor.response))  # the rig written states the true response
    images = []
    for i, cam in enumerate(hrig.rig):
        images.append(render(cam, scene, sensor, r_render, supersample))
        if progress is not None:
            progress(i + 1, len(hrig.rig), f"rendering {cam.name}")
    return HandCapture(hrig, images, truth, scene, motion, markerset, bool(known_flash_times))
