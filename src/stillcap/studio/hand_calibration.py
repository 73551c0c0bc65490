"""Calibration captures of the hand for ``stillcap hand-calibrate`` (issue 12):
``hand_capture(..., calibration_pose="flat")`` renders the gloved hand where a throw's hand is
at release (facing the cameras the same way), held in the calibration pose for the first
flashes, then curling its fingers and thumb toward a loose fist; the hand drifts 4 cm per
flash (sideways and toward the plate) so that the flashes' markers do not overlap in the
multi-exposure photos. The ball is out of view.

:func:`calibration_motion` wraps the throw's :class:`~stillcap.studio.hand.HandMotion` (so the
person, light and cameras of the throw are kept); the curl's angles are the truth's, not
known to the calibration.
"""

from __future__ import annotations

import numpy as np

from stillcap.body.hand import hand_pose
from stillcap.body.skeleton import Pose

__all__ = ["CalibrationMotion", "calibration_motion", "CURL_DEG"]

#: Flexion (deg) at full curl: finger MCP, PIP, DIP; thumb CMC, MCP, IP.
CURL_DEG = {"mcp": 55.0, "pip": 75.0, "dip": 45.0, "thumb-cmc": 25.0, "thumb-mcp": 30.0, "thumb-ip": 45.0}
#: The hand is still in the pose until this long before the release time, then curls over CURL_S.
POSE_UNTIL_S, CURL_S = 0.024, 0.045
#: Drift per second (m/s): 4 cm per flash at 75 Hz, sideways and toward the plate.
DRIFT = np.array([2.1, -2.1, 0.0])


class CalibrationMotion:
    """The hand held in a calibration pose, then curling (module docstring); the interface of
    :class:`~stillcap.studio.hand.HandMotion` that :func:`~stillcap.studio.hand.hand_capture` uses."""

    def __init__(self, base, pose: str, t0: float):
        from stillcap.body.hand_calibrate import calibration_angles

        self.base, self.pose_name, self.t0 = base, pose, float(t0)
        self.skeleton = base.skeleton
        self.shoulder = base.shoulder
        self.release = base.release
        self.angle_offsets_deg = None
        self._r2w0 = base.root2world(self.t0)
        self._rest = calibration_angles(pose, self.skeleton)
        sk = self.skeleton
        curl = np.zeros((sk.n_joints, 3))
        for i, n in enumerate(sk.names):
            key = n if n.startswith("thumb-") else n.split("-")[-1]
            if key in CURL_DEG:
                curl[i, 1] = CURL_DEG[key]
        lim = sk.limits_deg
        self._curl = np.clip(curl, np.nan_to_num(lim[..., 0], nan=-180), np.nan_to_num(lim[..., 1], nan=180))

    def root2world(self, t: float) -> np.ndarray:
        T = self._r2w0.copy()
        T[:3, 3] = T[:3, 3] + DRIFT * (float(t) - self.t0)
        return T

    def angles_deg(self, t: float) -> np.ndarray:
        u = float(np.clip((float(t) - (self.t0 - POSE_UNTIL_S)) / CURL_S, 0.0, 1.0))
        return self._rest + u * (self._curl - self._rest)

    def pose(self, t: float) -> Pose:
        return hand_pose(self.skeleton, self.root2world(t), self.angles_deg(t))

    def held(self, t) -> np.ndarray:
        return np.zeros(np.shape(np.atleast_1d(t)), bool)

    def ball2world(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, 3] = self._r2w0[:3, 3] + np.array([0.0, 0.0, -30.0])  # under the floor, out of view
        return T


def calibration_motion(base, pose: str, t0: float) -> CalibrationMotion:
    """The calibration motion for the throw ``base`` (its hand, its release time ``t0``)."""
    return CalibrationMotion(base, pose, t0)
