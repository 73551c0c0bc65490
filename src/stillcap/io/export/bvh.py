"""BVH (Biovision hierarchy) export.

HIERARCHY: one ``ROOT``/``JOINT`` per skeleton joint with its rest ``OFFSET``; the root has
``Xposition Yposition Zposition`` plus rotation channels, other joints rotation channels only.
Every leaf joint gets an ``End Site`` a quarter of its bone length further along its bone.
MOTION: one line per frame, Euler angles in degrees.

Conventions (those of Blender's and assimp's importers):

- rotation channels ``Zrotation Xrotation Yrotation`` (``rotation_order="ZXY"``, default) or
  ``"ZYX"`` etc.: the listed order is the order of multiplication, ``R = Rz @ Rx @ Ry``;
- the root's position channels are its absolute position; the root ``OFFSET`` is written as
  0 0 0 so that readers that add offset and position agree;
- lengths in ``length_unit`` (default ``"cm"``, the most common BVH unit; ``"m"`` and
  ``"mm"`` also possible): BVH files do not say their unit, so readers must be told.

BVH needs uniform frames: an Animation must have a frame rate (uniform times); a single Pose is
written as one frame with ``frame_rate`` (default 30 Hz). Hand-written (a few lines of text):
no maintained Python BVH writer exists among the project's dependencies.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.body.skeleton import LENGTH_UNITS
from stillcap.files.atomic import write_text
from stillcap.io.export._base import ExportData, register

__all__ = ["write_bvh"]


def _euler_channels(rotations: np.ndarray, order: str) -> np.ndarray:
    """Euler angles (degrees) per frame, shape (n_frames, 3), unwrapped over time."""
    ang = Rotation.from_matrix(rotations).as_euler(order, degrees=True)
    return np.rad2deg(np.unwrap(np.deg2rad(ang), axis=0)) if len(ang) > 1 else ang


@register(".bvh")
def write_bvh(
    path,
    data: ExportData,
    length_unit: str = "cm",
    rotation_order: str = "ZXY",
    frame_rate: float | None = None,
) -> Path:
    """Write a pose or animation as BVH.

    Parameters
    ----------
    path : str or PathLike
    data : ExportData
        Needs a pose or an animation with uniform times.
    length_unit : {"cm", "m", "mm"}
        Unit of offsets and root positions in the file.
    rotation_order : str
        A permutation of "XYZ": the order of the rotation channels (and of multiplication).
    frame_rate : float, optional
        Frames per second for a single pose (default 30) or to override the animation's.

    Returns
    -------
    Path
    """
    anim = data.require_motion("BVH")
    if length_unit not in LENGTH_UNITS:
        raise ValueError(f"length_unit must be one of {sorted(LENGTH_UNITS)}, got {length_unit!r}")
    order = rotation_order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"rotation_order must be a permutation of 'XYZ', got {rotation_order!r}")
    rate = frame_rate or anim.frame_rate or (30.0 if anim.n_frames == 1 else None)
    if rate is None:
        raise ValueError("BVH needs uniformly spaced frames: resample the animation or pass frame_rate")
    scale = 1.0 / LENGTH_UNITS[length_unit]
    skel = anim.skeleton
    rot_channels = " ".join(f"{a}rotation" for a in order)

    # Joint rotations as written: the root's includes root2world's rotation.
    rots = anim.local_rotations.copy()
    r = skel.root
    rots[:, r] = anim.root2world[:, :3, :3] @ rots[:, r]
    eulers = np.stack([_euler_channels(rots[:, j], order) for j in range(skel.n_joints)], axis=1)

    lines = ["HIERARCHY"]

    def num(v) -> str:
        return " ".join(f"{float(x):.6f}" for x in v)

    def emit(j: int, depth: int) -> None:
        ind = "  " * depth
        if skel.parents[j] < 0:
            lines.append(f"{ind}ROOT {skel.names[j]}")
            lines.append(ind + "{")
            lines.append(f"{ind}  OFFSET 0.000000 0.000000 0.000000")
            lines.append(f"{ind}  CHANNELS 6 Xposition Yposition Zposition {rot_channels}")
        else:
            lines.append(f"{ind}JOINT {skel.names[j]}")
            lines.append(ind + "{")
            lines.append(f"{ind}  OFFSET {num(skel.offsets[j] * scale)}")
            lines.append(f"{ind}  CHANNELS 3 {rot_channels}")
        kids = skel.children(j)
        for c in kids:
            emit(c, depth + 1)
        if not kids:
            bone = skel.offsets[j] if skel.parents[j] >= 0 else np.zeros(3)
            length = np.linalg.norm(bone)
            tip = 0.25 * bone if length > 1e-9 else np.array([0.0, 0.01, 0.0])
            lines.append(f"{ind}  End Site")
            lines.append(ind + "  {")
            lines.append(f"{ind}    OFFSET {num(tip * scale)}")
            lines.append(ind + "  }")
        lines.append(ind + "}")

    emit(skel.root, 0)
    order_dfs = skel.depth_first
    lines += ["MOTION", f"Frames: {anim.n_frames}", f"Frame Time: {1.0 / rate:.9g}"]
    root_pos = anim.root2world[:, :3, 3] * scale
    for k in range(anim.n_frames):
        vals = [root_pos[k]] + [eulers[k, j] for j in order_dfs]
        lines.append(" ".join(f"{float(v):.6f}" for v in np.concatenate(vals)))
    return write_text(path, "\n".join(lines) + "\n")
