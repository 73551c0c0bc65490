"""Calibration captures of the hand for ``stillcap hand-calibrate`` (issue 12):
``hand_capture(..., calibration_pose="flat")`` renders the gloved hand where a throw's hand is
at release (facing the cameras the same way), held in the calibration pose for the first
flashes, then moving through the steps of a calibration motion; the hand drifts 12 cm per flash
(sideways, more than its width) so that no flash's markers lie among another's. The ball is out of view.

Two motions (:data:`CALIBRATION_MOTIONS`):

- ``protocol`` (the default; docs/hand-calibration.md): the protocol's steps, one per flash
  (:data:`PROTOCOL_STEPS`): flat (held two flashes), fingers spread, "table top" (knuckles
  bent, fingers straight), hook (knuckles straight, finger joints bent), fist, thumb across the
  palm to the little finger (opposition), a half curl with the knuckles bent back, flat again.
  Every joint bends on its own at least once, by 45-100 deg, so every joint centre is seen
  turning its distal markers, and the knuckles abduct, so their sideways place is seen too;
- ``curl`` (the first calibration motion, kept to compare): flat, then every joint curling
  together toward a loose fist (MCP 55, PIP 75, DIP 45 deg);
- ``protocol-turned``: the protocol with its last two steps (flat again) replaced by a hook
  (PIP and DIP 60 deg, thumb IP 60 deg) with the hand turned 60 deg about its long axis, the
  thumb's side toward the cameras (:data:`PROTOCOL_TURNED_STEPS`, :data:`ROLL_DEG`): more
  flashes in which the end joints bend with their nails in view (docs/hand-calibration.md).

:func:`calibration_motion` wraps the throw's :class:`~stillcap.studio.hand.HandMotion` (so the
person, light and cameras of the throw are kept); the angles after the flat flashes are the
truth's, not known to the calibration.
"""

from __future__ import annotations

import numpy as np

from stillcap.body.hand import hand_pose
from stillcap.body.skeleton import Pose

__all__ = ["CalibrationMotion", "calibration_motion", "CALIBRATION_MOTIONS", "CURL_DEG", "PROTOCOL_STEPS",
           "PROTOCOL_WINDOW_S"]

#: The calibration motions of the studio (module docstring).
CALIBRATION_MOTIONS = ("protocol", "curl", "protocol-turned")
#: Flexion (deg) at full curl of the ``curl`` motion: finger MCP, PIP, DIP; thumb CMC, MCP, IP.
CURL_DEG = {"mcp": 55.0, "pip": 75.0, "dip": 45.0, "thumb-cmc": 25.0, "thumb-mcp": 30.0, "thumb-ip": 45.0}
#: ``curl``: the hand is still in the pose until this long before the release time, then curls over CURL_S.
POSE_UNTIL_S, CURL_S = 0.024, 0.045
#: Drift per second (m/s): 12 cm per flash at 75 Hz, sideways across the cameras' view. More
#: than the hand's width: at 4 cm per flash (the first studio, diagonal) the fingers of one
#: flash lay among the markers of the next, 1-5 cm from where a curled finger of the other flash
#: could be, and the labelling took them (12 of 141 labels wrong on exact markers of
#: another_hand(5); 0-2 of ~150 at 9-12 cm per flash): hand-calibrate then refused its own capture.
DRIFT = np.array([9.0, 0.0, 0.0])
#: The studio's window of a ``protocol`` capture (s about the throw's release time): 9-10
#: flashes at 75 Hz (the throw's window holds 4-5).
PROTOCOL_WINDOW_S = (-0.06, 0.065)


def _f(mcp=0.0, pip=0.0, dip=0.0, abd=None):
    """Finger angles: MCP flexion, PIP, DIP; ``abd`` MCP abduction per finger (index, middle, ring, little)."""
    return {"mcp": mcp, "pip": pip, "dip": dip, "abd": (0.0, 0.0, 0.0, 0.0) if abd is None else abd}


#: The ``protocol`` motion's steps, one per strobe period: (name, fingers, thumb CMC (twist,
#: flexion, abduction), thumb MCP, thumb IP), degrees. Between steps the angles move linearly.
PROTOCOL_STEPS = (
    ("flat", _f(), (0.0, 0.0, 0.0), 0.0, 0.0),
    ("flat", _f(), (0.0, 0.0, 0.0), 0.0, 0.0),
    ("spread", _f(abd=(18.0, 4.0, -12.0, -22.0)), (0.0, 0.0, 35.0), 0.0, 0.0),
    ("table top", _f(mcp=75.0), (0.0, 25.0, 10.0), 40.0, 0.0),
    ("hook", _f(pip=95.0, dip=65.0), (-15.0, 0.0, 0.0), 0.0, 70.0),
    ("fist", _f(mcp=80.0, pip=100.0, dip=55.0), (10.0, 35.0, -10.0), 55.0, 60.0),
    ("opposition", _f(mcp=30.0, pip=45.0, dip=20.0, abd=(-10.0, 0.0, 8.0, 15.0)), (25.0, 50.0, 40.0), 20.0, 30.0),
    ("half curl, knuckles back", _f(mcp=-20.0, pip=50.0, dip=35.0, abd=(10.0, -8.0, 10.0, -15.0)),
     (-20.0, -10.0, 25.0), -5.0, -15.0),
    ("flat", _f(), (0.0, 0.0, 0.0), 0.0, 0.0),
    ("flat", _f(), (0.0, 0.0, 0.0), 0.0, 0.0),
)

#: ``protocol-turned``: the protocol with its last steps replaced by the hook again, the hand
#: turned about its long axis (ROLL_DEG, the thumb's side toward the cameras), so that the
#: nails stay in view while the end joints bend: with the back of the hand toward the cameras a
#: bent end joint turns its nail marker away, and the middle phalanges' lengths (the DIP
#: centres) and the thumb's distal length stay at their prior (docs/hand-calibration.md).
PROTOCOL_TURNED_STEPS = PROTOCOL_STEPS[:8] + (
    ("hook, turned", _f(pip=60.0, dip=60.0), (0.0, 0.0, 20.0), 10.0, 60.0),
    ("hook, turned", _f(pip=60.0, dip=60.0), (0.0, 0.0, 20.0), 10.0, 60.0),
)
#: The hand's turn (deg, about its long axis, the thumb's side toward the cameras) per step name.
ROLL_DEG = {"hook, turned": 60.0}


def _step_angles(skeleton, step) -> np.ndarray:
    _, fing, cmc, tmcp, tip = step
    ang = np.zeros((skeleton.n_joints, 3))
    for k, d in enumerate(("index", "middle", "ring", "little")):
        ang[skeleton.index(f"{d}-mcp")] = (0.0, fing["mcp"], fing["abd"][k])
        ang[skeleton.index(f"{d}-pip"), 1] = fing["pip"]
        ang[skeleton.index(f"{d}-dip"), 1] = fing["dip"]
    ang[skeleton.index("thumb-cmc")] = cmc
    ang[skeleton.index("thumb-mcp"), 1] = tmcp
    ang[skeleton.index("thumb-ip"), 1] = tip
    return ang


class CalibrationMotion:
    """The hand held in a calibration pose, then moving (module docstring); the interface of
    :class:`~stillcap.studio.hand.HandMotion` that :func:`~stillcap.studio.hand.hand_capture` uses."""

    def __init__(self, base, pose: str, t0: float, motion: str = "protocol", strobe_hz: float = 75.0,
                 start_s: float | None = None):
        from stillcap.body.hand_calibrate import calibration_angles

        if motion not in CALIBRATION_MOTIONS:
            raise ValueError(f"unknown calibration motion {motion!r}; known: {', '.join(CALIBRATION_MOTIONS)}")
        self.base, self.pose_name, self.t0, self.motion = base, pose, float(t0), motion
        self.skeleton = base.skeleton
        self.shoulder = base.shoulder
        self.release = base.release
        self.angle_offsets_deg = None
        from stillcap.studio.hand_grip import BALL_IN_HAND

        # placed as before the throw's ball was seated (studio.hand_grip): these captures hold no ball
        self._r2w0 = base.root2world(self.t0, BALL_IN_HAND)
        self._rest = calibration_angles(pose, self.skeleton)
        sk = self.skeleton
        lim = sk.limits_deg
        lo, hi = np.nan_to_num(lim[..., 0], nan=-180), np.nan_to_num(lim[..., 1], nan=180)
        curl = np.zeros((sk.n_joints, 3))
        for i, n in enumerate(sk.names):
            key = n if n.startswith("thumb-") else n.split("-")[-1]
            if key in CURL_DEG:
                curl[i, 1] = CURL_DEG[key]
        self._curl = np.clip(curl, lo, hi)
        # protocol: step k at start + k / strobe_hz; the flat steps are the calibration pose's angles
        self._period = 1.0 / float(strobe_hz)
        self._start = self.t0 + (PROTOCOL_WINDOW_S[0] if start_s is None else float(start_s))
        steps = PROTOCOL_TURNED_STEPS if motion == "protocol-turned" else PROTOCOL_STEPS
        self._steps = np.stack([self._rest if s[0] == "flat" else np.clip(_step_angles(sk, s), lo, hi)
                                for s in steps])
        self._rolls = np.array([ROLL_DEG.get(s[0], 0.0) if motion == "protocol-turned" else 0.0 for s in steps])

    def _step(self, t: float):
        u = float(np.clip((float(t) - self._start) / self._period, 0.0, len(self._steps) - 1))
        k = min(int(np.floor(u)), len(self._steps) - 2)
        return k, u - k

    def root2world(self, t: float) -> np.ndarray:
        T = self._r2w0.copy()
        T[:3, 3] = T[:3, 3] + DRIFT * (float(t) - self.t0)
        if self.motion != "curl" and self._rolls.any():
            from scipy.spatial.transform import Rotation

            k, w = self._step(t)
            roll = (1 - w) * self._rolls[k] + w * self._rolls[k + 1]
            T[:3, :3] = T[:3, :3] @ Rotation.from_euler("x", roll, degrees=True).as_matrix()
        return T

    def angles_deg(self, t: float) -> np.ndarray:
        if self.motion == "curl":
            u = float(np.clip((float(t) - (self.t0 - POSE_UNTIL_S)) / CURL_S, 0.0, 1.0))
            return self._rest + u * (self._curl - self._rest)
        k, w = self._step(t)
        return (1 - w) * self._steps[k] + w * self._steps[k + 1]

    def pose(self, t: float) -> Pose:
        return hand_pose(self.skeleton, self.root2world(t), self.angles_deg(t))

    def held(self, t) -> np.ndarray:
        return np.zeros(np.shape(np.atleast_1d(t)), bool)

    def ball2world(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, 3] = self._r2w0[:3, 3] + np.array([0.0, 0.0, -30.0])  # under the floor, out of view
        return T


def calibration_motion(base, pose: str, t0: float, motion: str = "protocol", strobe_hz: float = 75.0) -> CalibrationMotion:
    """The calibration motion for the throw ``base`` (its hand, its release time ``t0``)."""
    return CalibrationMotion(base, pose, t0, motion, strobe_hz)
