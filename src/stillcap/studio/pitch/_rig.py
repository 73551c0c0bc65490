"""The seed's pitch rig in the field frame: four cameras in two strobed stereo pairs
(:func:`pitch_rig`), and which world points a camera sees."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.camera import Camera, Rig, pose_matrix
from stillcap.studio.scene import PointLight

#: Camera names, in rig order.
CAMERA_NAMES = ("front_top", "front_bottom", "back_left", "back_right")


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


#: Where a pair's strobe can stand (:func:`place_lights`).
LIGHT_PLACEMENTS = ("default", "near", "side", "behind")
#: What each pair watches (field frame, m): its strobe's light is aimed here.
_PAIR_AIM = {"front": (PATH_X, FRONT_CENTER_Y, FRONT_AIM_Z), "back": BACK_AIM}


def place_lights(rig: PitchRig, placement: str = "default") -> PitchRig:
    """The rig with each pair's strobe moved (same irradiance where the pair looks).

    Parameters
    ----------
    rig : PitchRig
    placement : {"default", "near", "side", "behind"}
        ``"default"``: the seed's (front strobe beside its pair, back strobe beside the
        corridor: half moons); ``"near"``: 0.25 m beside the middle of the pair's cameras (full
        discs, as a ring light); ``"side"``: 3 m to the side of the pair's line of sight,
        level with the ball (half moons seen by both cameras); ``"behind"``: 1.5 m behind the
        pair's cameras and 0.6 m above them (full discs, softer fall-off).
        The intensity is scaled by the squared distance to the watched point, so the lit side
        of the ball is as bright as with the default strobe.
    """
    if placement not in LIGHT_PLACEMENTS:
        raise ValueError(f"light placement must be one of {', '.join(LIGHT_PLACEMENTS)}, got {placement!r}")
    if placement == "default":
        return rig
    from dataclasses import replace

    pairs = []
    for p in rig.pairs:
        aim = np.asarray(_PAIR_AIM.get(p.name, np.mean([rig.rig[c].center for c in p.cameras], axis=0)), float)
        mid = np.mean([rig.rig[c].center for c in p.cameras], axis=0)
        view = aim - mid
        view /= np.linalg.norm(view)
        up = np.array([0.0, 0.0, 1.0])
        across = np.cross(view, up)
        across /= np.linalg.norm(across)
        if placement == "near":
            pos = mid + 0.25 * across
        elif placement == "side":
            pos = aim + 3.0 * across
        else:  # behind
            pos = mid - 1.5 * view + 0.6 * up
        d_old = np.linalg.norm(p.light.position - aim)
        d_new = np.linalg.norm(pos - aim)
        light = PointLight(pos, p.light.intensity * (d_new / d_old) ** 2, p.light.color)
        pairs.append(replace(p, light=light))
    return PitchRig(rig.rig, tuple(pairs))


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
