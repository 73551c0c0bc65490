"""CSV and JSON export of marker and joint positions (unit named in every header / key).

CSV (long, "tidy" format: one row per frame and point, easy to load in pandas or a
spreadsheet)::

    frame,time_s,kind,name,x_m,y_m,z_m
    0,0,marker,head.1,0.0,0.17,0.012
    0,0,joint,root,0.0,0.11,0.0

``kind`` is ``marker`` or ``joint``; unseen markers have empty x, y, z cells. With
``length_unit="mm"`` the columns are ``x_mm, y_mm, z_mm``.

JSON: ``{"format": "stillcap-export", "version": 1, "length_unit": ..., "markers": {...},
"motion": {...}}`` with an unseen point (any NaN) written as ``null``; ``motion`` holds the skeleton (the skeleton
file format), times, joint positions, ``root2world`` matrices and local rotations as
quaternions (x, y, z, w), enough to rebuild the Animation.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.body.skeleton import LENGTH_UNITS
from stillcap.files.atomic import write_text
from stillcap.io.export._base import ExportData, register

__all__ = ["write_csv", "write_json", "export_dict"]


def _scale(length_unit: str) -> float:
    if length_unit not in LENGTH_UNITS:
        raise ValueError(f"length_unit must be one of {sorted(LENGTH_UNITS)}, got {length_unit!r}")
    return 1.0 / LENGTH_UNITS[length_unit]


def _g(v: float) -> str:
    return "" if not np.isfinite(v) else f"{float(v):.10g}"


def _nan_to_none(a):
    """Nested lists with None for NaN."""
    a = np.asarray(a, float)
    if a.ndim == 0:
        return None if not np.isfinite(a) else float(f"{float(a):.10g}")
    return [_nan_to_none(x) for x in a]


def _points_to_json(a):
    """Nested lists of [x, y, z] points, None for a point with any NaN (unseen)."""
    a = np.asarray(a, float)
    if a.ndim == 1:
        return None if not np.all(np.isfinite(a)) else [float(f"{float(v):.10g}") for v in a]
    return [_points_to_json(x) for x in a]


def _require_something(data: ExportData, fmt: str) -> None:
    if data.animation is None and data.markers is None:
        raise ValueError(f"{fmt} export needs marker trajectories or a pose/animation")


@register(".csv")
def write_csv(path, data: ExportData, length_unit: str = "m") -> Path:
    """Write marker and joint positions as a long-format CSV table.

    Parameters
    ----------
    path : str or PathLike
    data : ExportData
    length_unit : {"m", "cm", "mm"}

    Returns
    -------
    Path
    """
    _require_something(data, "CSV")
    s = _scale(length_unit)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["frame", "time_s", "kind", "name", f"x_{length_unit}", f"y_{length_unit}", f"z_{length_unit}"])
    if data.markers is not None:
        m = data.markers
        for k, t in enumerate(m.times):
            for name, p in zip(m.names, m.points[k]):
                w.writerow([k, _g(t), "marker", name] + [_g(v * s) for v in p])
    if data.animation is not None:
        a = data.animation
        pos = a.positions
        for k, t in enumerate(a.times):
            for name, p in zip(a.skeleton.names, pos[k]):
                w.writerow([k, _g(t), "joint", name] + [_g(v * s) for v in p])
    return write_text(path, buf.getvalue())


def export_dict(data: ExportData, length_unit: str = "m") -> dict:
    """The JSON document :func:`write_json` writes."""
    _require_something(data, "JSON")
    s = _scale(length_unit)
    out: dict = {"format": "stillcap-export", "version": 1, "length_unit": length_unit}
    if data.markers is not None:
        m = data.markers
        md = {
            "names": list(m.names),
            "frame_rate_hz": m.frame_rate,
            "times_s": _nan_to_none(m.times),
            f"positions_{length_unit}": _points_to_json(m.points * s),
        }
        if m.residuals is not None:
            md[f"residuals_{length_unit}"] = _nan_to_none(m.residuals * s)
        out["markers"] = md
    if data.animation is not None:
        a = data.animation
        quat = Rotation.from_matrix(a.local_rotations.reshape(-1, 3, 3)).as_quat().reshape(a.n_frames, -1, 4)
        r2w = a.root2world.copy()
        r2w[:, :3, 3] *= s
        out["motion"] = {
            "skeleton": a.skeleton.to_dict(length_unit),
            "times_s": _nan_to_none(a.times),
            "frame_rate_hz": a.frame_rate,
            "joint_names": list(a.skeleton.names),
            f"positions_{length_unit}": _points_to_json(a.positions * s),
            f"root2world_{length_unit}": _nan_to_none(r2w),
            "local_rotations_xyzw": _nan_to_none(quat),
        }
    return out


@register(".json")
def write_json(path, data: ExportData, length_unit: str = "m") -> Path:
    """Write markers and/or motion as JSON (see the module docstring).

    Parameters
    ----------
    path : str or PathLike
    data : ExportData
    length_unit : {"m", "cm", "mm"}

    Returns
    -------
    Path
    """
    return write_text(path, json.dumps(export_dict(data, length_unit), separators=(",", ":")) + "\n")
