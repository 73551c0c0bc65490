"""Reading a puppet result file back (``result.json`` from ``stillcap puppet run --out``, or the
output of ``--json``): the pose and the 3D markers that exports need (:func:`load_result`).

The pipeline writes the file (:meth:`stillcap.pipelines.puppet.PuppetResult.to_dict`, format
:data:`RESULT_FORMAT`); reading it needs only the skeleton, the pose and the markers, so this
reader sits with the other file formats, below the pipelines.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from stillcap.body.markerset import MarkerTrajectories
from stillcap.body.skeleton import Pose, Skeleton
from stillcap.files.jsonfile import read_json
from stillcap.files.schema import Coordinate, Model, Name, PositiveCount, Vec3, validate

__all__ = ["RESULT_FORMAT", "LoadedResult", "load_result"]

#: The ``format`` entry of a puppet result file.
RESULT_FORMAT = "stillcap-puppet-result"
#: How far a joint's stored ``position`` may lie from where the pose puts it (m).
POSITION_TOL_M = 1e-6

_Row3 = tuple[Coordinate, Coordinate, Coordinate]
_Row4 = tuple[Coordinate, Coordinate, Coordinate, Coordinate]


class ResultJoint(Model):
    """One entry of a result's ``joints``."""

    name: Name
    local_rotation: tuple[_Row3, _Row3, _Row3]
    position: Vec3 | None = None


class ResultMarker(Model):
    """One entry of a result's ``markers`` (``position`` null: not reconstructed)."""

    name: Name
    position: Vec3 | None = None


class ResultFile(Model):
    """What :func:`load_result` reads of a puppet result (the other keys are the pipeline's report)."""

    format: Literal["stillcap-puppet-result"]
    version: PositiveCount = 1
    skeleton: dict[str, Any]
    joints: list[ResultJoint]
    root2world: tuple[_Row4, _Row4, _Row4, _Row4]
    markers: list[ResultMarker]


@dataclass(eq=False)
class LoadedResult:
    """A pipeline result read back from its JSON (:func:`load_result`): what exports need.

    Attributes
    ----------
    pose : Pose
    markers : MarkerTrajectories
        One frame of 3D markers (NaN = missing).
    data : dict
        The whole JSON.
    """

    pose: Pose
    markers: MarkerTrajectories
    data: dict


def load_result(path_or_dict) -> LoadedResult:
    """Read a result written by ``stillcap puppet run --out`` (``result.json``) or ``--json``.

    Raises
    ------
    ValueError
        Naming the file when it is not a puppet result or lacks the skeleton or pose.
    """
    if isinstance(path_or_dict, dict):
        d, where = path_or_dict, "<result>"
    else:
        p = Path(path_or_dict)
        if not p.is_file():
            raise ValueError(f"result file {p} does not exist")
        d = read_json(p)
        where = str(p)
    if not isinstance(d, dict) or d.get("format") != RESULT_FORMAT:
        raise ValueError(f"{where} is not a stillcap puppet result (expected \"format\": \"{RESULT_FORMAT}\")")
    version = d.get("version")
    if isinstance(version, int) and not isinstance(version, bool) and version > 1:
        raise ValueError(f"{where}: result version {version} is newer than this stillcap reads (1)")
    f = validate(ResultFile, d, where)
    sk = Skeleton.from_dict(d["skeleton"], source=where, prefix=("skeleton",))
    index = {}
    for k, j in enumerate(f.joints):
        if j.name in index:
            raise ValueError(f"{where}: joints.{k}.name: joint {j.name!r} is listed twice")
        if j.name not in sk:
            raise ValueError(f"{where}: joints.{k}.name: joint {j.name!r} is not in the skeleton "
                             f"(joints: {', '.join(sk.names)})")
        R = np.asarray(j.local_rotation, float)
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1.0) > 1e-6:
            raise ValueError(f"{where}: joints.{k}.local_rotation: must be a rotation matrix (orthonormal, det +1)")
        index[j.name] = k
    missing = [n for n in sk.names if n not in index]
    if missing:
        raise ValueError(f"{where}: joints: no entry for the skeleton's joints {missing}")
    local = np.stack([np.asarray(f.joints[index[n]].local_rotation, float) for n in sk.names])
    try:
        pose = Pose(sk, np.asarray(f.root2world, float), local)
    except ValueError as e:
        raise ValueError(f"{where}: root2world: {e}") from None
    positions = pose.positions
    for n, x in zip(sk.names, positions):
        given = f.joints[index[n]].position
        if given is not None and not np.linalg.norm(np.asarray(given) - x) <= POSITION_TOL_M:
            raise ValueError(f"{where}: joints.{index[n]}.position: joint {n!r} is at {list(given)} but the "
                             f"skeleton, root2world and local rotations put it at {np.round(x, 6).tolist()}")
    names = [m.name for m in f.markers]
    for k, n in enumerate(names):
        if n in names[:k]:
            raise ValueError(f"{where}: markers.{k}.name: marker {n!r} is listed twice")
    pts = np.array([m.position if m.position is not None else (np.nan,) * 3 for m in f.markers], float)
    markers = MarkerTrajectories.single(names, pts.reshape(len(names), 3))
    return LoadedResult(pose, markers, d)
