"""Turntable rigs (SPEC J3): one camera, the subject turned in equal steps = N cameras on a circle.

Puppet frame (the thesis's, in metres here): origin where the turn axis meets the platform,
y up the axis, x to the puppet's right seen from the front, z toward the camera at 0 degrees.
The camera at turn angle ``a`` has its centre at ``(-d sin a, h, d cos a)`` and
``world2cam = Rx(180 deg) Ry(a) T(d sin a, -h, -d cos a)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.camera import Camera, Rig

#: The thesis's webcam intrinsics (px) at 640x480.
THESIS_FX, THESIS_FY, THESIS_CX, THESIS_CY = 859.016, 860.224, 337.318, 288.237


def turntable_world2cam(angle_rad: float, distance: float, height: float) -> np.ndarray:
    """``Rx(180) Ry(a) T(d sin a, -h, -d cos a)`` as a 4x4 matrix."""
    a = float(angle_rad)
    T = np.eye(4)
    T[:3, 3] = (distance * np.sin(a), -height, -distance * np.cos(a))
    Ry = np.eye(4)
    Ry[:3, :3] = Rotation.from_euler("y", a).as_matrix()
    Rx = np.diag([1.0, -1.0, -1.0, 1.0])  # rotation by 180 degrees about x
    return Rx @ Ry @ T


def turntable_rig(n_views: int = 12, step_deg: float = 30.0, distance: float = 0.400,
                  height: float = 0.080, camera: Camera | None = None,
                  start_deg: float = 0.0) -> Rig:
    """A rig of ``n_views`` virtual cameras, one per turntable angle.

    Parameters
    ----------
    n_views : number of photos (turn angles ``start_deg + i * step_deg``).
    distance : camera centre to the turn axis, metres (thesis: 0.400).
    height : lens centre above the platform, metres (thesis: 0.080).
    camera : intrinsics, distortion and image size to use (default: the thesis's webcam).
    """
    if n_views < 1:
        raise ValueError(f"n_views must be >= 1, got {n_views}")
    if distance <= 0:
        raise ValueError(f"distance must be positive (metres), got {distance}")
    if camera is None:
        camera = Camera.from_intrinsics("webcam", THESIS_FX, THESIS_FY, THESIS_CX, THESIS_CY, (640, 480))
    cams = []
    for i in range(n_views):
        deg = start_deg + i * step_deg
        cams.append(Camera(f"turn_{deg:05.1f}deg", camera.K, camera.dist,
                           turntable_world2cam(np.radians(deg), distance, height), camera.image_size, camera.response))
    return Rig(cams, world="puppet")
