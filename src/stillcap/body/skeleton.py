"""Skeletons as data, poses and animations (forward kinematics).

A :class:`Skeleton` is an ordered tuple of :class:`Joint` s. Each joint names its parent and
its *rest offset*: the position of the joint in its parent's frame at rest, in metres. At rest
every joint frame is parallel to the skeleton's frame (for the puppet: the puppet frame, y up,
x to the puppet's left, z forward), so a rest offset is also the rest bone vector in that frame.

A bone is named after the joint at its end (the thesis's and jMonkeyEngine's convention): the
bone ``"l-elbow"`` is the upper arm, from ``l-shoulder`` to ``l-elbow``. It is moved by the
rotation of the joint at its start (its parent joint).

Forward kinematics (:func:`forward_kinematics`), with ``T(v)`` a translation and ``R_j`` the
local rotation of joint ``j``::

    joint2world[root] = root2world @ R_root
    joint2world[j]    = joint2world[parent(j)] @ T(offset_j) @ R_j

``root2world`` is the root joint's frame in the world; the root's rest offset is the root's
position at rest in the skeleton frame, used by :meth:`Pose.rest`.

File format: see ``docs/skeleton.md``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Annotated, Iterator, Literal, Sequence

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.files.atomic import write_text
from stillcap.files.jsonfile import read_json, read_package_json
from stillcap.files.schema import Finite, Model, Name, PositiveCount, Vec3, validate

__all__ = [
    "Joint",
    "Skeleton",
    "Pose",
    "Animation",
    "forward_kinematics",
    "LENGTH_UNITS",
    "EULER_LIMIT_SEQUENCE",
    "euler_within_limits",
    "BUILTIN_SKELETONS",
]

#: Skeletons shipped with stillcap that :meth:`Skeleton.builtin` loads by name.
BUILTIN_SKELETONS = {"puppet": "puppet_skeleton.json"}

#: Length units accepted in files, in metres per unit.
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}

#: Joint limits are ranges of the intrinsic Euler angles of the local rotation in this
#: sequence (scipy's upper-case = intrinsic): ``R = Rx(a) @ Ry(b) @ Rz(c)``. A rotation is
#: within the limits when some Euler triple producing it lies within them
#: (:meth:`Skeleton.limit_angles_deg`), so the middle angle may exceed +-90 degrees.
EULER_LIMIT_SEQUENCE = "XYZ"

_FORMAT = "stillcap-skeleton"
_ROT_TOL = 1e-6

_Limit = tuple[Finite, Finite]


class JointEntry(Model):
    """One entry of a skeleton file's ``joints`` (``docs/skeleton.md``)."""

    name: Name
    parent: Name | None = None
    offset: Vec3 = (0.0, 0.0, 0.0)
    limits_deg: tuple[_Limit | None, _Limit | None, _Limit | None] | None = None


class SkeletonFile(Model):
    """A skeleton file (``stillcap-skeleton``): the schema checked on load."""

    format: Literal["stillcap-skeleton"] = _FORMAT
    version: PositiveCount = 1
    name: str = "skeleton"
    length_unit: Literal["m", "cm", "mm"] = "m"
    joints: Annotated[list[JointEntry], Field(min_length=1)]


@dataclass(frozen=True, eq=False)
class Joint:
    """One joint of a skeleton.

    Parameters
    ----------
    name : str
        Unique joint name; the bone that ends at this joint has the same name.
    parent : str or None
        Name of the parent joint, None for the root.
    offset : array_like, shape (3,)
        Rest position of the joint in its parent's frame, metres (for the root: its rest
        position in the skeleton frame).
    limits_deg : sequence of 3 (min, max) pairs or None, or None
        Allowed range of the local rotation's intrinsic X, Y, Z Euler angles
        (:data:`EULER_LIMIT_SEQUENCE`), degrees; None (for one axis or all) means free,
        ``(0, 0)`` means locked.
    """

    name: str
    parent: str | None
    offset: np.ndarray
    limits_deg: tuple | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"joint name must be a non-empty string, got {self.name!r}")
        object.__setattr__(self, "offset", as_array(self.offset, (3,), f"offset of joint {self.name!r}"))
        if not np.all(np.isfinite(self.offset)):
            raise ValueError(f"offset of joint {self.name!r} must be finite, got {self.offset}")
        object.__setattr__(self, "limits_deg", _check_limits(self.limits_deg, self.name))

    @property
    def is_root(self) -> bool:
        return self.parent is None


def _check_limits(limits, name: str):
    if limits is None:
        return None
    if len(limits) != 3:
        raise ValueError(f"limits_deg of joint {name!r} must have 3 entries (x, y, z), got {len(limits)}")
    out = []
    for axis, lim in zip("xyz", limits):
        if lim is None:
            out.append(None)
            continue
        lo, hi = (float(v) for v in as_array(lim, (2,), f"limits_deg[{axis}] of joint {name!r}"))
        if not lo <= hi:
            raise ValueError(f"limits_deg[{axis}] of joint {name!r} must have min <= max, got {[lo, hi]}")
        out.append((lo, hi))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class Skeleton:
    """An ordered set of joints forming one tree.

    Parameters
    ----------
    joints : sequence of Joint
        Exactly one root; parents may come after their children in the sequence.
    name : str
        A name for the skeleton (written to files).
    source : str
        Where it came from (a file name), used in error messages.

    Raises
    ------
    ValueError
        On a duplicate name, an unknown parent, a cycle, or not exactly one root.
    """

    joints: tuple[Joint, ...]
    name: str = "skeleton"
    source: str = field(default="<skeleton>", compare=False)

    def __post_init__(self):
        joints = tuple(self.joints)
        object.__setattr__(self, "joints", joints)
        where = f" in {self.source}"
        if not joints:
            raise ValueError(f"a skeleton needs at least one joint{where}")
        index: dict[str, int] = {}
        for i, j in enumerate(joints):
            if not isinstance(j, Joint):
                raise ValueError(f"joints must be Joint objects, got {type(j).__name__} at index {i}{where}")
            if j.name in index:
                raise ValueError(f"duplicate joint name {j.name!r}{where}")
            index[j.name] = i
        for j in joints:
            if j.parent is not None and j.parent not in index:
                raise ValueError(f"joint {j.name!r} has unknown parent {j.parent!r}{where}")
            if j.parent == j.name:
                raise ValueError(f"joint {j.name!r} is its own parent (cycle){where}")
        for j in joints:  # walk up from every joint: more steps than joints means a cycle
            seen, cur = {j.name}, j.parent
            while cur is not None:
                if cur in seen:
                    raise ValueError(f"joint {j.name!r} is in a cycle of parents (via {cur!r}){where}")
                seen.add(cur)
                cur = joints[index[cur]].parent
        roots = [j.name for j in joints if j.parent is None]
        if len(roots) != 1:
            raise ValueError(f"a skeleton needs exactly one root joint, got {roots}{where}")
        object.__setattr__(self, "_index", index)

    # -- structure -------------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return len(self.joints)

    def __len__(self) -> int:
        return len(self.joints)

    @cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def index(self, name: str) -> int:
        """Index of the joint ``name``; ValueError naming the known joints if absent."""
        try:
            return self._index[name]
        except KeyError:
            raise ValueError(f"unknown joint {name!r}; known: {', '.join(self.names)}") from None

    def __contains__(self, name: str) -> bool:
        return name in self._index

    @cached_property
    def parents(self) -> np.ndarray:
        """Parent index per joint, shape (n_joints,), -1 for the root."""
        return np.array([-1 if j.parent is None else self._index[j.parent] for j in self.joints], dtype=int)

    @cached_property
    def root(self) -> int:
        """Index of the root joint."""
        return int(np.flatnonzero(self.parents < 0)[0])

    @cached_property
    def offsets(self) -> np.ndarray:
        """Rest offsets, shape (n_joints, 3), metres."""
        return np.array([j.offset for j in self.joints])

    def children(self, joint: int | str) -> list[int]:
        """Indices of the children of a joint (in skeleton order)."""
        i = joint if isinstance(joint, (int, np.integer)) else self.index(joint)
        return [int(c) for c in np.flatnonzero(self.parents == i)]

    @cached_property
    def depth_first(self) -> tuple[int, ...]:
        """Joint indices in depth-first (pre-)order from the root: every parent before its children."""
        order: list[int] = []
        stack = [self.root]
        while stack:
            i = stack.pop()
            order.append(i)
            stack.extend(reversed(self.children(i)))
        return tuple(order)

    @cached_property
    def depth_levels(self) -> tuple[np.ndarray, ...]:
        """Joint indices by depth from the root (the root's level first; every joint after its
        parent's level), each level in :attr:`depth_first` order."""
        parents = self.parents
        depth = np.zeros(self.n_joints, int)
        for j in self.depth_first:
            depth[j] = 0 if parents[j] < 0 else depth[parents[j]] + 1
        order = np.asarray(self.depth_first, int)
        return tuple(order[depth[order] == d] for d in range(depth.max() + 1))

    @cached_property
    def bone_lengths(self) -> np.ndarray:
        """Length of the bone ending at each joint, shape (n_joints,), metres (0 for the root)."""
        lengths = np.linalg.norm(self.offsets, axis=1)
        lengths[self.root] = 0.0
        return lengths

    @cached_property
    def limits_deg(self) -> np.ndarray:
        """Joint limits, shape (n_joints, 3, 2), degrees; NaN where free."""
        out = np.full((self.n_joints, 3, 2), np.nan)
        for i, j in enumerate(self.joints):
            if j.limits_deg is not None:
                for a, lim in enumerate(j.limits_deg):
                    if lim is not None:
                        out[i, a] = lim
        return out

    def limit_angles_deg(self, local_rotations) -> np.ndarray:
        """Euler angles of local rotations as the limits read them, shape (n_joints, 3), degrees.

        Every rotation has two intrinsic XYZ Euler triples, ``(a, b, c)`` and
        ``(a + 180, 180 - b, c + 180)`` (each angle also modulo 360), and a whole line of them
        at gimbal lock (``b = +-90``: only ``a + c`` or ``a - c`` is fixed). scipy's
        ``as_euler`` always returns the one with ``-90 <= b <= 90``, so a limit such as the
        elbow's ``[-150, 0]`` on Y could never be met beyond 90 degrees of bend. This returns,
        per joint, the representation that lies within the joint's limits if one does, else
        the one with the smallest total violation (degrees outside the limits, summed over the
        axes). Free axes take any value.

        Parameters
        ----------
        local_rotations : array_like, shape (n_joints, 3, 3)

        Returns
        -------
        ndarray, shape (n_joints, 3)
            X, Y, Z angles in degrees (:data:`EULER_LIMIT_SEQUENCE`).
        """
        rots = as_array(local_rotations, (self.n_joints, 3, 3), "local_rotations")
        return _angles_within(rots, self.limits_deg)[0]

    def limit_violations(self, local_rotations, tol_deg: float = 1e-6) -> np.ndarray:
        """Which joints' local rotations leave their limits.

        A rotation is within the limits when *some* intrinsic XYZ Euler triple that produces it
        lies within them (see :meth:`limit_angles_deg`); so limits beyond +-90 degrees on the
        middle (Y) axis, like the elbows' ``[-150, 0]``, work as written.

        Parameters
        ----------
        local_rotations : array_like, shape (n_joints, 3, 3)
        tol_deg : float
            Tolerance in degrees.

        Returns
        -------
        ndarray of bool, shape (n_joints, 3)
            True where the X/Y/Z angle of the best representation (:meth:`limit_angles_deg`)
            is outside its limit.
        """
        rots = as_array(local_rotations, (self.n_joints, 3, 3), "local_rotations")
        angles, _ = _angles_within(rots, self.limits_deg)
        lim = self.limits_deg
        with np.errstate(invalid="ignore"):
            low = angles < lim[..., 0] - tol_deg
            high = angles > lim[..., 1] + tol_deg
        return np.where(np.isnan(lim[..., 0]), False, low | high)

    def rest_root2world(self) -> np.ndarray:
        """The root's rest frame: a translation to the root's rest offset, shape (4, 4)."""
        m = np.eye(4)
        m[:3, 3] = self.joints[self.root].offset
        return m

    def rest_pose(self) -> "Pose":
        """The rest pose (all local rotations identity, root at its rest offset)."""
        return Pose.rest(self)

    # -- files -----------------------------------------------------------------------------
    def to_dict(self, length_unit: str = "m") -> dict:
        """A JSON-ready dict (see ``docs/skeleton.md``), lengths in ``length_unit``."""
        scale = _unit_scale(length_unit, "length_unit")
        joints = []
        for j in self.joints:
            d = {"name": j.name, "parent": j.parent, "offset": [_round(v / scale) for v in j.offset]}
            if j.limits_deg is not None:
                d["limits_deg"] = [None if lim is None else [lim[0], lim[1]] for lim in j.limits_deg]
            joints.append(d)
        return {"format": _FORMAT, "version": 1, "name": self.name, "length_unit": length_unit, "joints": joints}

    @classmethod
    def from_dict(cls, data: dict, source: str = "<dict>", prefix: tuple = ()) -> "Skeleton":
        """Build a skeleton from :meth:`to_dict` output; ValueError naming ``source`` and the key
        path on bad data (``prefix``: the key path of ``data`` inside its file)."""
        if isinstance(data, dict) and data.get("format", _FORMAT) != _FORMAT:
            raise ValueError(f"{source}: {_path(prefix, 'format')}: not a skeleton file: format is "
                             f"{data.get('format')!r}, expected {_FORMAT!r}")
        f = validate(SkeletonFile, data, source, prefix)
        scale = LENGTH_UNITS[f.length_unit]
        names = [j.name for j in f.joints]
        for k, j in enumerate(f.joints):
            if j.name in names[:k]:
                raise ValueError(f"{source}: {_path(prefix, 'joints', k, 'name')}: duplicate joint name {j.name!r}")
            if j.parent is not None and j.parent not in names:
                raise ValueError(f"{source}: {_path(prefix, 'joints', k, 'parent')}: joint {j.name!r} has unknown "
                                 f"parent {j.parent!r} (joints: {', '.join(names)})")
        joints = []
        for k, j in enumerate(f.joints):
            try:
                joints.append(Joint(j.name, j.parent, np.asarray(j.offset, float) * scale, j.limits_deg))
            except ValueError as e:
                raise ValueError(f"{source}: {_path(prefix, 'joints', k)}: {e}") from None
        return cls(tuple(joints), name=f.name, source=source)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Skeleton":
        """Read a skeleton JSON file."""
        return cls.from_dict(read_json(path), source=str(path))

    def save(self, path: str | os.PathLike, length_unit: str = "m") -> Path:
        """Write the skeleton as JSON (atomically), lengths in ``length_unit``; return the path."""
        return write_text(path, json.dumps(self.to_dict(length_unit), indent=1) + "\n")

    @classmethod
    def puppet(cls) -> "Skeleton":
        """The thesis's 210 mm lay figure (``data/puppet_skeleton.json``), puppet frame, metres."""
        return cls.builtin("puppet")

    @classmethod
    def builtin(cls, name: str) -> "Skeleton":
        """A skeleton shipped with stillcap, by name (:data:`BUILTIN_SKELETONS`)."""
        if name not in BUILTIN_SKELETONS:
            raise ValueError(f"unknown built-in skeleton {name!r}; built-in: {', '.join(BUILTIN_SKELETONS)}")
        data, source = read_package_json(BUILTIN_SKELETONS[name])
        return cls.from_dict(data, source=source)

    @classmethod
    def resolve(cls, spec: "Skeleton | str | os.PathLike | dict | None", default: str = "puppet") -> "Skeleton":
        """A skeleton from whatever names one: a :class:`Skeleton` (returned as is), a built-in
        name (``"puppet"``), the path of a skeleton JSON file, a :meth:`to_dict` dict, or None
        for ``default``. A string is a built-in name if it is one, else a file path."""
        if spec is None:
            spec = default
        if isinstance(spec, Skeleton):
            return spec
        if isinstance(spec, dict):
            return cls.from_dict(spec, source="<embedded skeleton>")
        if isinstance(spec, str) and spec in BUILTIN_SKELETONS:
            return cls.builtin(spec)
        if isinstance(spec, (str, os.PathLike)):
            path = Path(spec)
            if not path.is_file():
                raise ValueError(f"skeleton {str(spec)!r} is neither a built-in ({', '.join(BUILTIN_SKELETONS)}) "
                                 "nor an existing file")
            return cls.load(path)
        raise ValueError(f"a skeleton must be a Skeleton, a built-in name, a file or a dict, got {type(spec).__name__}")

    def with_offsets(self, offsets, name: str | None = None) -> "Skeleton":
        """A copy with other rest offsets (shape (n_joints, 3), metres), same names, parents and limits."""
        off = as_array(offsets, (self.n_joints, 3), "offsets")
        return Skeleton(tuple(Joint(j.name, j.parent, o, j.limits_deg) for j, o in zip(self.joints, off)),
                        name=self.name if name is None else name, source=self.source)


def _wrap_into(angle: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``angle`` plus the multiple of 360 degrees that brings it nearest to the middle of
    ``[lo, hi]`` (so into the range whenever some shift does, for ranges up to 360 wide);
    free axes (NaN limits) go to [-180, 180]."""
    lo_, hi_ = np.where(np.isnan(lo), -180.0, lo), np.where(np.isnan(hi), 180.0, hi)
    mid = 0.5 * (lo_ + hi_)
    return angle + 360.0 * np.round((mid - angle) / 360.0)


def _violation(angles: np.ndarray, lim: np.ndarray) -> np.ndarray:
    """Degrees outside the limits, summed over the axes (free axes count 0), shape (...,)."""
    with np.errstate(invalid="ignore"):
        out = np.maximum(lim[..., 0] - angles, 0.0) + np.maximum(angles - lim[..., 1], 0.0)
    return np.where(np.isnan(out), 0.0, out).sum(axis=-1)


_GIMBAL_DEG = 1e-4


def euler_within_limits(rotations, limits_deg) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsic XYZ Euler angles of rotations, choosing the representation that meets limits.

    Parameters
    ----------
    rotations : array_like, shape (n, 3, 3)
    limits_deg : array_like, shape (n, 3, 2) or (3, 2)
        ``[min, max]`` per axis in degrees, NaN = free (as :attr:`Skeleton.limits_deg`).

    Returns
    -------
    angles : ndarray, shape (n, 3)
        Degrees; within the limits whenever some representation is (see
        :meth:`Skeleton.limit_angles_deg`).
    violation : ndarray, shape (n,)
        Degrees outside the limits, summed over the axes (0 = within).
    """
    rots = np.asarray(rotations, float).reshape(-1, 3, 3)
    lim = np.broadcast_to(np.asarray(limits_deg, float), (len(rots), 3, 2))
    return _angles_within(rots, lim)


def _angles_within(rots: np.ndarray, lim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per rotation the intrinsic XYZ Euler triple (degrees) that best meets ``lim`` (n, 3, 2),
    and its violation in degrees (0 = within the limits). See :meth:`Skeleton.limit_angles_deg`."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # gimbal lock: handled below
        a = Rotation.from_matrix(rots).as_euler(EULER_LIMIT_SEQUENCE, degrees=True)
    lo, hi = lim[..., 0], lim[..., 1]
    # the two representations, each angle shifted by 360 degrees toward its range
    first = _wrap_into(a, lo, hi)
    second = _wrap_into(np.stack([a[:, 0] + 180.0, 180.0 - a[:, 1], a[:, 2] + 180.0], axis=1), lo, hi)
    cands = [first, second]
    # gimbal lock (b = +-90): only a + c (b = +90) or a - c (b = -90) is fixed; slide a within
    # its range and let c follow, for both signs of the lock
    lock = np.abs(np.abs(a[:, 1]) - 90.0) < _GIMBAL_DEG
    if lock.any():
        sign = np.where(a[:, 1] > 0, 1.0, -1.0)  # c = s - a (b = +90) or c = a - s (b = -90)
        s = a[:, 0] + sign * a[:, 2]
        alo, ahi = np.where(np.isnan(lo[:, 0]), -180.0, lo[:, 0]), np.where(np.isnan(hi[:, 0]), 180.0, hi[:, 0])
        clo, chi = np.where(np.isnan(lo[:, 2]), -180.0, lo[:, 2]), np.where(np.isnan(hi[:, 2]), 180.0, hi[:, 2])
        for k in (-1.0, 0.0, 1.0):
            t = s + 360.0 * k
            # the a for which c lands in its range: b = +90: c = t - a; b = -90: c = a - t
            a_lo = np.where(sign > 0, t - chi, t + clo)
            a_hi = np.where(sign > 0, t - clo, t + chi)
            ai = np.clip(np.clip(a[:, 0], np.maximum(alo, a_lo), np.minimum(ahi, a_hi)), alo, ahi)
            ci = np.where(sign > 0, t - ai, ai - t)
            cand = np.stack([ai, a[:, 1], ci], axis=1)
            cands.append(np.where(lock[:, None], cand, first))
    cands = np.stack(cands)  # (n_cands, n, 3)
    viol = _violation(cands, lim[None])
    best = np.argmin(viol, axis=0)
    idx = np.arange(len(rots))
    return cands[best, idx], viol[best, idx]


def _path(prefix: tuple, *keys) -> str:
    """A key path ``a.0.b`` for messages."""
    return ".".join(str(k) for k in (*prefix, *keys))


def _unit_scale(unit, what: str) -> float:
    if unit not in LENGTH_UNITS:
        raise ValueError(f"{what} must be one of {sorted(LENGTH_UNITS)}, got {unit!r}")
    return LENGTH_UNITS[unit]


def _round(v: float) -> float:
    return float(f"{v:.10g}")


def _check_rotations(rots: np.ndarray, name: str) -> None:
    """ValueError unless every 3x3 in ``rots`` (shape (..., 3, 3)) is a proper rotation."""
    eye = np.eye(3)
    err = np.abs(np.einsum("...ji,...jk->...ik", rots, rots) - eye).max(axis=(-2, -1))
    det = np.linalg.det(rots)
    bad = (err > _ROT_TOL) | (np.abs(det - 1.0) > _ROT_TOL) | ~np.isfinite(det)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} must hold rotation matrices (orthonormal, det +1); entry {idx} is not")


def _check_rigid(m: np.ndarray, name: str) -> None:
    """ValueError unless every 4x4 in ``m`` (shape (..., 4, 4)) is a rigid transform."""
    if not np.allclose(m[..., 3, :], [0, 0, 0, 1], atol=1e-9) or not np.all(np.isfinite(m)):
        raise ValueError(f"{name} must be rigid 4x4 transforms with last row (0, 0, 0, 1)")
    _check_rotations(m[..., :3, :3], name + " (rotation part)")


def forward_kinematics(skeleton: Skeleton, root2world, local_rotations) -> np.ndarray:
    """Joint frames in the world for one or many poses.

    Parameters
    ----------
    skeleton : Skeleton
    root2world : array_like, shape (..., 4, 4)
        The root joint's frame in the world (rigid).
    local_rotations : array_like, shape (..., n_joints, 3, 3)
        Local rotation of every joint (identity at rest).

    Returns
    -------
    joint2world : ndarray, shape (..., n_joints, 4, 4)
    """
    root2world = np.asarray(root2world, float)
    local_rotations = np.asarray(local_rotations, float)
    n = skeleton.n_joints
    if root2world.shape[-2:] != (4, 4) or local_rotations.shape[-3:] != (n, 3, 3):
        raise ValueError(
            f"root2world must have shape (..., 4, 4) and local_rotations (..., {n}, 3, 3), "
            f"got {root2world.shape} and {local_rotations.shape}"
        )
    batch = np.broadcast_shapes(root2world.shape[:-2], local_rotations.shape[:-3])
    local = np.zeros(batch + (n, 4, 4))
    local[..., :3, :3] = local_rotations
    local[..., :3, 3] = skeleton.offsets
    local[..., 3, 3] = 1.0
    out = np.empty_like(local)
    parents = skeleton.parents
    r = skeleton.root
    local_root = local[..., r, :, :].copy()
    local_root[..., :3, 3] = 0.0  # the root's offset is its rest position, not part of FK
    out[..., r, :, :] = root2world @ local_root
    # the joints of one depth in one stacked product, after their parents' depth (NumPy's
    # stacked matmul makes each joint's 4 x 4 product as one product alone does: the same
    # numbers; a product per joint cost ~4 us each, ~10 kinematics per puppet pose fit)
    for level in skeleton.depth_levels[1:]:
        out[..., level, :, :] = out[..., parents[level], :, :] @ local[..., level, :, :]
    return out


@dataclass(eq=False)
class Pose:
    """A skeleton in one pose.

    Parameters
    ----------
    skeleton : Skeleton
    root2world : array_like, shape (4, 4)
        The root joint's frame in the world (rigid).
    local_rotations : array_like, shape (n_joints, 3, 3)
        Local rotation of every joint relative to its rest frame (identity at rest).
    """

    skeleton: Skeleton
    root2world: np.ndarray
    local_rotations: np.ndarray

    def __post_init__(self):
        self.root2world = as_array(self.root2world, (4, 4), "root2world")
        _check_rigid(self.root2world, "root2world")
        n = self.skeleton.n_joints
        self.local_rotations = as_array(self.local_rotations, (n, 3, 3), "local_rotations")
        _check_rotations(self.local_rotations, "local_rotations")

    @classmethod
    def rest(cls, skeleton: Skeleton, root2world=None) -> "Pose":
        """The rest pose; ``root2world`` defaults to :meth:`Skeleton.rest_root2world`."""
        r2w = skeleton.rest_root2world() if root2world is None else root2world
        return cls(skeleton, r2w, np.tile(np.eye(3), (skeleton.n_joints, 1, 1)))

    @cached_property
    def joint2world(self) -> np.ndarray:
        """Joint frames in the world, shape (n_joints, 4, 4)."""
        return forward_kinematics(self.skeleton, self.root2world, self.local_rotations)

    @property
    def positions(self) -> np.ndarray:
        """Joint positions in the world, shape (n_joints, 3), metres."""
        return self.joint2world[:, :3, 3]

    def position(self, name: str) -> np.ndarray:
        """World position of one joint, shape (3,), metres."""
        return self.positions[self.skeleton.index(name)]

    def bone_vectors(self) -> np.ndarray:
        """World vector of the bone ending at each joint (parent to joint), shape (n_joints, 3); 0 at the root."""
        pos = self.positions
        par = self.skeleton.parents
        return np.where((par >= 0)[:, None], pos - pos[np.maximum(par, 0)], 0.0)


@dataclass(eq=False)
class Animation:
    """A sequence of poses of one skeleton with times.

    Parameters
    ----------
    skeleton : Skeleton
    times : array_like, shape (n_frames,)
        Strictly increasing times, seconds.
    root2world : array_like, shape (n_frames, 4, 4)
    local_rotations : array_like, shape (n_frames, n_joints, 3, 3)
    """

    skeleton: Skeleton
    times: np.ndarray
    root2world: np.ndarray
    local_rotations: np.ndarray

    def __post_init__(self):
        self.times = as_array(self.times, (None,), "times")
        f, n = len(self.times), self.skeleton.n_joints
        if f == 0:
            raise ValueError("an animation needs at least one frame, got 0 times")
        if not np.all(np.isfinite(self.times)) or np.any(np.diff(self.times) <= 0):
            raise ValueError("times must be finite and strictly increasing")
        self.root2world = as_array(self.root2world, (f, 4, 4), "root2world")
        _check_rigid(self.root2world, "root2world")
        self.local_rotations = as_array(self.local_rotations, (f, n, 3, 3), "local_rotations")
        _check_rotations(self.local_rotations, "local_rotations")

    @classmethod
    def from_poses(cls, poses: Sequence[Pose], times=None, frame_rate: float | None = None) -> "Animation":
        """Stack poses of one skeleton into an animation.

        Parameters
        ----------
        poses : sequence of Pose
            All with the same Skeleton object.
        times : array_like, shape (n_frames,), optional
            Seconds. Without it the times are ``k / frame_rate``.
        frame_rate : float, optional
            Frames per second when ``times`` is not given; default 30.
        """
        poses = list(poses)
        if not poses:
            raise ValueError("from_poses needs at least one pose")
        skel = poses[0].skeleton
        if any(p.skeleton is not skel for p in poses):
            raise ValueError("all poses of an animation must share one Skeleton object")
        if times is None:
            rate = 30.0 if frame_rate is None else float(frame_rate)
            times = np.arange(len(poses)) / rate
        return cls(
            skel,
            times,
            np.stack([p.root2world for p in poses]),
            np.stack([p.local_rotations for p in poses]),
        )

    @property
    def n_frames(self) -> int:
        return len(self.times)

    def __len__(self) -> int:
        return len(self.times)

    def __getitem__(self, k: int) -> Pose:
        return Pose(self.skeleton, self.root2world[k], self.local_rotations[k])

    def __iter__(self) -> Iterator[Pose]:
        return (self[k] for k in range(self.n_frames))

    @cached_property
    def joint2world(self) -> np.ndarray:
        """Joint frames in the world, shape (n_frames, n_joints, 4, 4)."""
        return forward_kinematics(self.skeleton, self.root2world, self.local_rotations)

    @property
    def positions(self) -> np.ndarray:
        """Joint positions in the world, shape (n_frames, n_joints, 3), metres."""
        return self.joint2world[..., :3, 3]

    @property
    def frame_rate(self) -> float | None:
        """Frames per second if the times are uniformly spaced (relative 1e-6), else None.

        A single frame has no rate: None.
        """
        if self.n_frames < 2:
            return None
        dt = np.diff(self.times)
        if np.ptp(dt) > 1e-6 * dt.mean():
            return None
        return float(1.0 / dt.mean())
