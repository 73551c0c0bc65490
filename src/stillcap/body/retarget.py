"""Retargeting: pose the puppet (or any skeleton) like a mocap skeleton, e.g. a BVH file.

Skeletons differ in proportions, joint lists and rest orientations, so local rotations cannot
be copied joint by joint. Directions can: a target bone (named after the joint at its end, as
in :mod:`stillcap.body.skeleton`) points from the source joint mapped to its start joint to the
source joint mapped to its end joint. Each target joint's local rotation is then the rotation
*within the target's joint limits* that best points the bones starting at it along those
directions (bounded least squares over its intrinsic XYZ Euler angles, the convention of
``limits_deg``), walking the hierarchy from the root so every child sees its parent's clamped
rotation.

Frames. Directions are taken relative to the source's pelvis (its root joint frame) by default:
the puppet's pelvis is fixed on the turntable axis, upright and facing the camera at turn
angle 0, so only the body relative to the pelvis is copied (``keep_root_rotation=True`` also
copies the pelvis orientation into ``root2world``). The source's rest axes are matched to the
target's by rounding the source's rest "left" (left hip - right hip) and "up" (feet to head)
to the nearest coordinate axes, so y-up and z-up files both work.

Limits. A joint limit box in intrinsic XYZ Euler angles can only express a middle (Y) angle
within +-90 degrees (the Euler decomposition's range, which is how
:meth:`~stillcap.body.Skeleton.limit_violations` reads angles), so Y ranges are clipped to
+-89.5 degrees here; e.g. the puppet's elbows bend at most 90 degrees.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from stillcap.body.kinematics import normalised
from stillcap.body.skeleton import EULER_LIMIT_SEQUENCE, Animation, Pose, Skeleton

__all__ = ["DEFAULT_JOINT_MAP", "Retargeted", "clamp_to_limits", "euler_bounds_deg", "resolve_joint_map",
           "retarget_animation", "retarget_pose"]

_Y_MAX_DEG = 89.5  # the middle Euler angle must stay inside (-90, 90) to be read back as set


def _mirror(name: str) -> str:
    """The right-side name of a left-side joint name (``LeftArm`` -> ``RightArm``, ``lShldr`` -> ``rShldr``)."""
    if name.startswith("Left"):
        return "Right" + name[4:]
    return "r" + name[1:] if len(name) > 1 and name[0] == "l" and name[1].isupper() else name


def _sides(table: dict) -> dict:
    out = dict(table)
    for k, v in table.items():
        if k.startswith("l-"):
            out["r-" + k[2:]] = tuple(_mirror(n) for n in v)
    return out


#: Puppet joint -> candidate source joint names, first match wins. Covers the common BVH
#: namings (CMU / Mixamo "LeftUpLeg, LeftArm, LeftForeArm", older "LeftHip, LeftKnee,
#: LeftShoulder, LeftElbow, LeftWrist", Poser/DAZ "lThigh, lShldr"); ``<joint>_end`` are the
#: End Sites of :func:`stillcap.io.bvh_read.read_bvh`. Right-side entries mirror the left.
DEFAULT_JOINT_MAP: dict[str, tuple[str, ...]] = _sides({
    "root": ("Hips", "hip", "Hip", "pelvis", "Pelvis", "Root"),
    "l-hip": ("LeftUpLeg", "LeftHip", "LeftThigh", "lThigh"),
    "l-knee": ("LeftLeg", "LeftKnee", "LeftShin", "lShin"),
    "l-foot": ("LeftFoot", "LeftAnkle", "lFoot"),
    "l-toes": ("LeftToeBase", "LeftToe", "LeftFoot_end", "LeftAnkle_end", "lFoot_end"),
    "lower-back": ("Spine", "Chest", "abdomen", "Spine1"),
    "upper-back": ("Neck", "neck", "Neck1"),
    "head": ("Head_end", "HeadTop_End", "head_end", "Head", "head"),
    "l-shoulder": ("LeftArm", "LeftUpArm", "lShldr", "LeftShoulder"),
    "l-elbow": ("LeftForeArm", "LeftElbow", "LeftLowArm", "lForeArm"),
    "l-hand": ("LeftHand", "LeftWrist", "lHand"),
    "l-finger": ("LeftHand_end", "LeftWrist_end", "LeftHandIndex1", "LeftFingerBase", "lHand_end"),
})


def resolve_joint_map(source: Skeleton, joint_map: Mapping | None = None,
                      target: Skeleton | None = None) -> dict[str, str]:
    """Which source joint stands for each target joint.

    Parameters
    ----------
    source : Skeleton
        The mocap skeleton (e.g. ``read_bvh(path).skeleton``).
    joint_map : mapping, optional
        Target joint -> source joint name, a sequence of candidate names (first present wins)
        or None (leave the joint unmapped). Entries override :data:`DEFAULT_JOINT_MAP`.
    target : Skeleton, optional
        Default :meth:`Skeleton.puppet`.

    Returns
    -------
    dict
        Target joint -> source joint, for the joints that could be mapped.

    Raises
    ------
    ValueError
        If ``joint_map`` names a target joint the target lacks, or a single source name the
        source lacks.
    """
    target = target or Skeleton.puppet()
    table: dict = dict(DEFAULT_JOINT_MAP)
    for k, v in (joint_map or {}).items():
        if k not in target:
            raise ValueError(f"joint map names target joint {k!r}, which skeleton {target.name!r} lacks; "
                             f"known: {', '.join(target.names)}")
        if isinstance(v, str):
            if v not in source:
                raise ValueError(f"joint map: source joint {v!r} (for {k!r}) is not in skeleton "
                                 f"{source.name!r}; known: {', '.join(source.names)}")
            v = (v,)
        table[k] = () if v is None else tuple(v)
    out = {}
    for name in target.names:
        hit = next((c for c in table.get(name, ()) if c in source), None)
        if hit is not None:
            out[name] = hit
    return out


def euler_bounds_deg(skeleton: Skeleton) -> np.ndarray:
    """Usable ranges of the intrinsic XYZ Euler angles per joint, shape (n_joints, 3, 2), degrees.

    The skeleton's ``limits_deg`` with free axes as +-180 (X, Z) and the middle (Y) angle clipped
    to +-89.5 degrees (see the module docstring).
    """
    lim = skeleton.limits_deg.copy()
    free = np.isnan(lim)
    lim[free] = np.broadcast_to(np.array([[-180.0, 180.0]] * 3), lim.shape)[free]
    lim[:, 1] = np.clip(lim[:, 1], -_Y_MAX_DEG, _Y_MAX_DEG)
    return lim


def clamp_to_limits(skeleton: Skeleton, local_rotations) -> np.ndarray:
    """Local rotations clipped into the joint limits, shape (n_joints, 3, 3).

    Clips each intrinsic XYZ Euler angle into :func:`euler_bounds_deg` (not the nearest
    rotation in angle, but always one that :meth:`Skeleton.limit_violations` accepts).
    """
    rots = np.asarray(local_rotations, float)
    if rots.shape != (skeleton.n_joints, 3, 3):
        raise ValueError(f"local_rotations must have shape ({skeleton.n_joints}, 3, 3), got {rots.shape}")
    b = euler_bounds_deg(skeleton)
    ang = Rotation.from_matrix(rots).as_euler(EULER_LIMIT_SEQUENCE, degrees=True)
    return Rotation.from_euler(EULER_LIMIT_SEQUENCE, np.clip(ang, b[..., 0], b[..., 1]), degrees=True).as_matrix()


@dataclass
class Retargeted:
    """Result of :func:`retarget_pose`.

    Attributes
    ----------
    pose : Pose
        The target skeleton in the retargeted pose (within its limits).
    joint_map : dict
        Target joint -> source joint used.
    directions : dict
        Target bone -> wanted world direction, shape (3,) (target world frame).
    error_deg : dict
        Target bone -> angle between the posed bone and its wanted direction, degrees.
    at_limit : dict
        Target bone -> whether its start joint has a locked axis or a rotation on a joint
        limit (within 0.5 degrees), i.e. the limits, not the fit, decided it.
    """

    pose: Pose
    joint_map: dict
    directions: dict
    error_deg: dict
    at_limit: dict


def _alignment(source: Skeleton, jmap: dict) -> np.ndarray:
    """Signed permutation A: source rest axes -> target axes (x left, y up, z forward)."""
    P = Pose.rest(source).positions
    at = {k: P[source.index(v)] for k, v in jmap.items()}

    def axis(v, fallback, exclude=None):
        if v is None or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
            return np.array(fallback, float)
        v = np.array(v, float)
        if exclude is not None:
            v[np.argmax(np.abs(exclude))] = 0.0
        out = np.zeros(3)
        k = int(np.argmax(np.abs(v)))
        out[k] = np.sign(v[k])
        return out

    up_v = left_v = None
    feet = [at[k] for k in ("l-foot", "r-foot") if k in at]
    top = next((at[k] for k in ("head", "upper-back") if k in at), None)
    if feet and top is not None:
        up_v = top - np.mean(feet, axis=0)
    if "l-hip" in at and "r-hip" in at:
        left_v = at["l-hip"] - at["r-hip"]
    elif "l-shoulder" in at and "r-shoulder" in at:
        left_v = at["l-shoulder"] - at["r-shoulder"]
    up = axis(up_v, (0, 1, 0))
    left = axis(left_v, (1, 0, 0) if abs(up[0]) < 0.5 else (0, 0, 1), exclude=up)
    return np.array([left, up, np.cross(left, up)])  # rows: target x, y, z in source coordinates


def _directions(source_pose: Pose, target: Skeleton, jmap: dict, keep_root_rotation: bool):
    """Wanted target-world bone directions and the target root rotation."""
    A = _alignment(source_pose.skeleton, jmap)
    j2w = source_pose.joint2world
    src_root = source_pose.skeleton.index(jmap["root"]) if "root" in jmap else source_pose.skeleton.root
    R_root = j2w[src_root, :3, :3]
    to_target = A if keep_root_rotation else A @ R_root.T
    P = j2w[:, :3, 3]
    dirs = {}
    for j, name in enumerate(target.names):
        p = target.parents[j]
        if p < 0 or name not in jmap or target.names[p] not in jmap:
            continue
        v = P[source_pose.skeleton.index(jmap[name])] - P[source_pose.skeleton.index(jmap[target.names[p]])]
        d = normalised(to_target @ v)
        if np.all(np.isfinite(d)):
            dirs[name] = d
    root_rot = A @ R_root @ A.T if keep_root_rotation else np.eye(3)
    return dirs, root_rot


def _fit_joint(parent_rot, rest, wanted, bounds_deg, reg: float = 1e-4) -> np.ndarray:
    """Euler angles (deg, (3,)) within bounds that point ``rest`` (k, 3) along ``wanted`` (k, 3)."""
    lo, hi = bounds_deg[:, 0], bounds_deg[:, 1]
    free = hi > lo
    base = np.where(free, 0.0, lo)
    if not free.any():
        return base
    a_local = wanted @ parent_rot  # parent_rot.T @ wanted_i, row-wise
    guess = Rotation.align_vectors(a_local, rest)[0] if len(rest) > 1 else \
        Rotation.align_vectors(a_local[:1], rest[:1])[0]
    g = guess.as_euler(EULER_LIMIT_SEQUENCE, degrees=True)
    if np.all((g >= lo) & (g <= hi)) and np.allclose(g[~free], base[~free], atol=1e-9) and len(rest) == 1:
        return g  # the minimal rotation is allowed: nothing to trade off

    def residual(x):
        ang = base.copy()
        ang[free] = x
        R = Rotation.from_euler(EULER_LIMIT_SEQUENCE, ang, degrees=True).as_matrix()
        return np.concatenate([(rest @ R.T - a_local).ravel(), np.sqrt(reg) * np.radians(x)])

    best = None
    for s in (np.clip(g, lo, hi), np.clip(0.0, lo, hi)):
        x0 = np.clip(s[free], lo[free] + 1e-9, hi[free] - 1e-9)
        r = least_squares(residual, x0, bounds=(lo[free], hi[free]), x_scale=30.0)
        if best is None or r.cost < best.cost:
            best = r
        if best.cost < 1e-4:  # the (tiny) regulariser alone: a good fit, no second start needed
            break
    out = base.copy()
    out[free] = best.x
    return out


def retarget_pose(source_pose: Pose, target: Skeleton | None = None, joint_map: Mapping | None = None,
                  root2world=None, keep_root_rotation: bool = False) -> Retargeted:
    """Pose ``target`` (default the puppet) like ``source_pose`` (e.g. one BVH frame).

    Parameters
    ----------
    source_pose : Pose
        A pose of the source skeleton (``read_bvh(path)[frame]``); lengths do not matter.
    target : Skeleton, optional
        Default :meth:`Skeleton.puppet`.
    joint_map : mapping, optional
        Target joint -> source joint name(s); see :func:`resolve_joint_map`.
    root2world : array_like, shape (4, 4), optional
        Where the target's root goes (default its rest frame: for the puppet the pelvis centre
        on the turntable axis, 110 mm up, upright, facing +z).
    keep_root_rotation : bool
        Also copy the source pelvis orientation (else the pelvis stays upright, facing +z, and
        directions are taken relative to the source pelvis).

    Returns
    -------
    Retargeted
        The pose (all local rotations within the target's limits) and per-bone diagnostics.

    Raises
    ------
    ValueError
        If fewer than two bones can be mapped (the naming is not recognised: pass ``joint_map``).
    """
    if not isinstance(source_pose, Pose):
        raise ValueError(f"source_pose must be a Pose (e.g. read_bvh(path)[0]), got {type(source_pose).__name__}")
    target = target or Skeleton.puppet()
    jmap = resolve_joint_map(source_pose.skeleton, joint_map, target)
    dirs, root_rot = _directions(source_pose, target, jmap, keep_root_rotation)
    if len(dirs) < 2:
        raise ValueError(f"could map only {len(dirs)} bone(s) of {target.name!r} onto {source_pose.skeleton.name!r} "
                         f"(joints {', '.join(source_pose.skeleton.names)}); pass a joint_map")
    r2w = target.rest_root2world() if root2world is None else np.array(root2world, float)
    r2w[:3, :3] = r2w[:3, :3] @ root_rot
    bounds = euler_bounds_deg(target)
    n = target.n_joints
    angles = np.zeros((n, 3))
    world = np.zeros((n, 3, 3))
    for p in target.depth_first:
        parent_rot = r2w[:3, :3] if target.parents[p] < 0 else world[target.parents[p]]
        kids = [c for c in target.children(p) if target.names[c] in dirs and target.bone_lengths[c] > 0]
        if kids:
            rest = normalised(target.offsets[kids])
            angles[p] = _fit_joint(parent_rot, rest, np.array([dirs[target.names[c]] for c in kids]), bounds[p])
        else:
            angles[p] = np.clip(0.0, bounds[p, :, 0], bounds[p, :, 1])
        world[p] = parent_rot @ Rotation.from_euler(EULER_LIMIT_SEQUENCE, angles[p], degrees=True).as_matrix()
    local = Rotation.from_euler(EULER_LIMIT_SEQUENCE, angles, degrees=True).as_matrix()
    pose = Pose(target, r2w, local)
    got = normalised(pose.bone_vectors())
    free = bounds[..., 1] > bounds[..., 0]
    edge = free & ((angles < bounds[..., 0] + 0.5) | (angles > bounds[..., 1] - 0.5))
    err, limit = {}, {}
    for name, d in dirs.items():
        j = target.index(name)
        err[name] = float(np.degrees(np.arccos(np.clip(got[j] @ d, -1, 1))))
        p = target.parents[j]
        limit[name] = bool(edge[p].any() or not free[p].all())
    return Retargeted(pose, jmap, dirs, err, limit)


def retarget_animation(animation: Animation, target: Skeleton | None = None, joint_map: Mapping | None = None,
                       frames: Sequence[int] | None = None, keep_root_rotation: bool = False) -> Animation:
    """Retarget every frame (or ``frames``) of an animation; see :func:`retarget_pose`.

    Returns
    -------
    Animation
        Of the target skeleton, with the source frames' times.
    """
    target = target or Skeleton.puppet()
    idx = list(range(animation.n_frames)) if frames is None else [int(k) for k in frames]
    for k in idx:
        if not 0 <= k < animation.n_frames:
            raise ValueError(f"frame {k} is out of range: the animation has {animation.n_frames} frames")
    poses = [retarget_pose(animation[k], target, joint_map, keep_root_rotation=keep_root_rotation).pose for k in idx]
    return Animation.from_poses(poses, times=animation.times[idx])
