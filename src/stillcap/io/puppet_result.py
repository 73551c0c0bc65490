"""Reading a puppet result file back (``result.json`` from ``stillcap puppet run --out``, or the
output of ``--json``): the pose and the 3D markers that exports need (:func:`load_result`).

The pipeline writes the file (:meth:`stillcap.pipelines.puppet.PuppetResult.to_dict`, format
:data:`RESULT_FORMAT`); reading it needs only the skeleton, the pose and the markers, so this
reader sits with the other file formats, below the pipelines.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stillcap.body.markerset import MarkerTrajectories
from stillcap.body.skeleton import Pose, Skeleton
from stillcap.files.jsonfile import read_json

__all__ = ["RESULT_FORMAT", "LoadedResult", "load_result"]

#: The ``format`` entry of a puppet result file.
RESULT_FORMAT = "stillcap-puppet-result"


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
    from stillcap.files.jsonable import from_jsonable

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
    if d.get("version", 0) > 1:
        raise ValueError(f"{where}: result version {d.get('version')} is newer than this stillcap reads (1)")
    try:
        sk = Skeleton.from_dict(d["skeleton"], source=where)
        by = {j["name"]: np.asarray(j["local_rotation"], float) for j in d["joints"]}
        local = np.stack([by[n] for n in sk.names])
        pose = Pose(sk, np.asarray(d["root2world"], float), local)
        names = [m["name"] for m in d["markers"]]
        pts = from_jsonable([m["position"] if m["position"] is not None else [None] * 3 for m in d["markers"]])
        markers = MarkerTrajectories.single(names, np.asarray(pts, float).reshape(len(names), 3))
    except (KeyError, TypeError) as e:
        raise ValueError(f"{where}: incomplete puppet result (missing {e})") from None
    return LoadedResult(pose, markers, d)
