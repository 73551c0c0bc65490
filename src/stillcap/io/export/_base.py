"""The exporter registry and what every writer shares: the data to export, the stick-figure mesh,
lazy imports of optional dependencies."""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from stillcap.body.markerset import MarkerTrajectories
from stillcap.body.skeleton import Animation, Pose, Skeleton
from stillcap.files.schema import MAX_COORDINATE

__all__ = ["EXPORTERS", "ExportData", "as_export_data", "export", "register", "known_extensions"]

#: Writer per lower-case extension (with the dot): ``writer(path, data: ExportData, **options) -> Path``.
EXPORTERS: dict[str, Callable[..., Path]] = {}


def register(*extensions: str):
    """Decorator registering a writer for one or more file extensions (``".bvh"`` or ``"bvh"``)."""

    def deco(func):
        for ext in extensions:
            ext = ext.lower()
            EXPORTERS[ext if ext.startswith(".") else "." + ext] = func
        return func

    return deco


def known_extensions() -> list[str]:
    """The registered extensions, sorted."""
    return sorted(EXPORTERS)


@dataclass(eq=False)
class ExportData:
    """What the writers receive.

    Attributes
    ----------
    animation : Animation or None
        Skeleton motion; a single :class:`Pose` becomes a one-frame animation at time 0.
    markers : MarkerTrajectories or None
        Labelled marker positions (metres, NaN = unseen).
    single_pose : bool
        True when the motion came from one Pose (writers then omit animation blocks).
    """

    animation: Animation | None = None
    markers: MarkerTrajectories | None = None
    single_pose: bool = False

    @property
    def skeleton(self) -> Skeleton | None:
        return None if self.animation is None else self.animation.skeleton

    def require_motion(self, fmt: str) -> Animation:
        """The animation, or a ValueError saying ``fmt`` needs a pose or an animation."""
        if self.animation is None:
            raise ValueError(f"{fmt} export needs a Pose or an Animation (skeleton motion), got markers only")
        return self.animation


def as_export_data(result) -> ExportData:
    """Normalise what a caller hands to :func:`export` into :class:`ExportData`.

    Every format gets finite data: joint positions and seen markers must be finite and within
    :data:`~stillcap.files.schema.MAX_COORDINATE` metres (a marker at 1e308 m would become
    infinity in a C3D file's float32 millimetres); ValueError naming the joint or marker otherwise.
    """
    return _check_finite(_normalise(result))


def _check_finite(data: ExportData) -> ExportData:
    if data.animation is not None:
        anim = data.animation
        pos = anim.positions
        bad = ~(np.isfinite(pos) & (np.abs(pos) <= MAX_COORDINATE)).all(axis=-1)
        if bad.any():
            f, j = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(f"cannot export: joint {anim.skeleton.names[j]!r} (frame {f}) is at "
                             f"{pos[f, j].tolist()} m; positions must be finite and within {MAX_COORDINATE:g} m")
    if data.markers is not None:
        pts = data.markers.points
        with np.errstate(invalid="ignore"):
            bad = (~np.isnan(pts) & ~(np.abs(pts) <= MAX_COORDINATE)).any(axis=-1)
        if bad.any():
            f, m = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(f"cannot export: marker {data.markers.names[m]!r} (frame {f}) is at {pts[f, m].tolist()} "
                             f"m; positions must be finite and within {MAX_COORDINATE:g} m (NaN = not seen)")
    return data


def _normalise(result) -> ExportData:
    if isinstance(result, ExportData):
        return result
    if isinstance(result, Pose):
        anim = Animation(result.skeleton, [0.0], result.root2world[None], result.local_rotations[None])
        return ExportData(animation=anim, single_pose=True)
    if isinstance(result, Animation):
        return ExportData(animation=result)
    if isinstance(result, MarkerTrajectories):
        return ExportData(markers=result)
    if isinstance(result, (tuple, list)):
        out = ExportData()
        for item in result:
            part = _normalise(item)
            if part.animation is not None:
                if out.animation is not None:
                    raise ValueError("got two skeleton motions to export; pass one Pose or Animation")
                out.animation, out.single_pose = part.animation, part.single_pose
            if part.markers is not None:
                if out.markers is not None:
                    raise ValueError("got two sets of marker trajectories to export; pass one")
                out.markers = part.markers
        if out.animation is None and out.markers is None:
            raise ValueError("nothing to export: no Pose, Animation or MarkerTrajectories given")
        return out
    motion = next(
        (getattr(result, a) for a in ("animation", "pose") if isinstance(getattr(result, a, None), (Pose, Animation))),
        None,
    )
    markers = next(
        (
            getattr(result, a)
            for a in ("markers", "marker_trajectories", "trajectories")
            if isinstance(getattr(result, a, None), MarkerTrajectories)
        ),
        None,
    )
    if motion is not None or markers is not None:
        return _normalise(tuple(x for x in (motion, markers) if x is not None))
    raise ValueError(
        "cannot export an object of type "
        f"{type(result).__name__}: pass a Pose, Animation, MarkerTrajectories or ExportData"
    )


def export(path: str | os.PathLike, result, **options) -> Path:
    """Write ``result`` to ``path`` in the format its extension names.

    Parameters
    ----------
    path : str or PathLike
        Target file; its extension picks the writer (:data:`EXPORTERS`).
    result
        Pose, Animation, MarkerTrajectories, ExportData, a tuple of them, or an object with
        ``pose`` / ``animation`` / ``markers`` attributes.
    **options
        Passed to the writer (e.g. ``length_unit="cm"`` for BVH); see ``docs/exports.md``.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ValueError
        For an unknown extension (listing the known ones) or data the format cannot hold.
    ImportError
        When the writer's optional dependency is missing (with the pip command to install it).
    """
    path = Path(path)
    ext = path.suffix.lower()
    writer = EXPORTERS.get(ext)
    if writer is None:
        raise ValueError(
            f"cannot export {path.name!r}: unknown extension {ext or '(none)'!r}; "
            f"known: {', '.join(known_extensions())}"
        )
    return writer(path, as_export_data(result), **options)


def require(module: str, pip_name: str, what: str):
    """Import an optional dependency or raise ImportError with an install hint."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ImportError(f"{what} needs the optional package {pip_name!r}: pip install {pip_name}") from e


def stick_mesh(skeleton: Skeleton, joint2world: np.ndarray):
    """A small closed mesh for skinning: one thin octahedron per bone, in the given pose.

    Parameters
    ----------
    skeleton : Skeleton
    joint2world : ndarray, shape (n_joints, 4, 4)
        The bind pose.

    Returns
    -------
    vertices : ndarray, shape (V, 3), metres
    triangles : ndarray of int, shape (T, 3)
    vertex_joint : ndarray of int, shape (V,)
        The joint that moves each vertex (the bone's start joint), weight 1.
    """
    pos = joint2world[:, :3, 3]
    verts, tris, vj = [], [], []
    for c in range(skeleton.n_joints):
        p = skeleton.parents[c]
        if p < 0:
            continue
        a, b = pos[p], pos[c]
        axis = b - a
        length = np.linalg.norm(axis)
        if length < 1e-9:
            continue
        axis = axis / length
        helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
        u = np.cross(axis, helper)
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        r = 0.08 * length
        mid = a + 0.2 * length * axis
        base = len(verts)
        verts += [a, b, mid + r * u, mid + r * v, mid - r * u, mid - r * v]
        vj += [p] * 6
        for i in range(4):
            r0, r1 = base + 2 + i, base + 2 + (i + 1) % 4
            tris += [(base, r1, r0), (base + 1, r0, r1)]
    return np.array(verts, float).reshape(-1, 3), np.array(tris, int).reshape(-1, 3), np.array(vj, int)
