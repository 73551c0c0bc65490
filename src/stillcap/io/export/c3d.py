"""C3D export (the biomechanics marker format), via ezc3d.

POINT data in millimetres (``POINT:UNITS = "mm"``), ``POINT:LABELS`` = marker names,
``POINT:RATE`` = frame rate (Hz). An unseen marker (NaN) is written as an invalid point
(residual -1, as the C3D standard says); seen points get residual 0. Residual values are not
written: ezc3d (1.7) stores the residual byte where the ``c3d`` package reads the camera mask, so
the two readers would disagree on any non-zero value; both agree on 0 and -1. With no markers but a pose or animation, the joint positions are written as points
labelled by joint name (``points="joints"``; ``"both"`` writes markers and joints).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stillcap.files.atomic import atomic_path
from stillcap.io.export._base import ExportData, register, require

__all__ = ["write_c3d", "c3d_points"]


def c3d_points(data: ExportData, points: str = "auto", frame_rate: float | None = None):
    """Labels, positions (m, NaN = unseen), residuals (m) and rate for a C3D file.

    Parameters
    ----------
    data : ExportData
    points : {"auto", "markers", "joints", "both"}
        ``"auto"``: markers if any, else joint positions.
    frame_rate : float, optional
        Rate for joint positions of a single pose or non-uniform animation (default 30 Hz).

    Returns
    -------
    labels : list of str
    xyz : ndarray, shape (n_frames, n_points, 3), metres
    residuals : ndarray, shape (n_frames, n_points), metres (NaN = unseen; not written to C3D)
    rate : float
    """
    if points not in ("auto", "markers", "joints", "both"):
        raise ValueError(f"points must be 'auto', 'markers', 'joints' or 'both', got {points!r}")
    use_markers = data.markers is not None and points in ("auto", "markers", "both")
    use_joints = data.animation is not None and (points in ("joints", "both") or (points == "auto" and not use_markers))
    if points == "markers" and data.markers is None:
        raise ValueError("C3D export with points='markers' needs marker trajectories")
    if points in ("joints", "both") and data.animation is None:
        raise ValueError(f"C3D export with points={points!r} needs a Pose or Animation")
    if not (use_markers or use_joints):
        raise ValueError("C3D export needs marker trajectories or a pose/animation")
    labels, xyz, res, rate = [], [], [], None
    if use_markers:
        m = data.markers
        labels += list(m.names)
        xyz.append(m.points)
        r = np.zeros(m.points.shape[:2]) if m.residuals is None else np.nan_to_num(m.residuals, nan=0.0)
        res.append(np.where(m.seen, r, np.nan))
        rate = m.frame_rate
    if use_joints:
        a = data.animation
        jr = a.frame_rate or frame_rate or (30.0 if a.n_frames == 1 else None)
        if jr is None:
            raise ValueError("C3D needs uniformly spaced frames: the animation has no frame rate")
        if rate is not None and (abs(jr - rate) > 1e-6 * rate or a.n_frames != xyz[0].shape[0]):
            raise ValueError("markers and animation differ in frame rate or frame count; export them separately")
        rate = jr if rate is None else rate
        labels += list(a.skeleton.names)
        xyz.append(a.positions)
        res.append(np.zeros(a.positions.shape[:2]))
    if len(set(labels)) != len(labels):
        raise ValueError(f"C3D point labels must be unique, got {labels}")
    return labels, np.concatenate(xyz, axis=1), np.concatenate(res, axis=1), float(frame_rate or rate)


@register(".c3d")
def write_c3d(path, data: ExportData, points: str = "auto", frame_rate: float | None = None) -> Path:
    """Write marker trajectories (and/or joint positions) as C3D, millimetres.

    Parameters
    ----------
    path : str or PathLike
    data : ExportData
    points : {"auto", "markers", "joints", "both"}
        What to write as C3D points (see :func:`c3d_points`).
    frame_rate : float, optional
        Override the rate (Hz).

    Returns
    -------
    Path
    """
    ezc3d = require("ezc3d", "ezc3d", "C3D export")
    labels, xyz, res, rate = c3d_points(data, points, frame_rate)
    n_frames, n_points = xyz.shape[:2]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = tuple("" for _ in labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    pts = np.ones((4, n_points, n_frames))
    pts[:3] = np.transpose(xyz, (2, 1, 0)) * 1000.0
    seen = np.all(np.isfinite(xyz), axis=-1).T  # (n_points, n_frames)
    pts[:3, ~seen] = np.nan  # ezc3d writes NaN points as invalid (residual -1)
    c["data"]["points"] = pts
    residuals = np.where(seen, 0.0, -1.0)
    c["data"]["meta_points"]["residuals"] = residuals[None]
    c["data"]["meta_points"]["camera_masks"] = np.zeros((7, n_points, n_frames), dtype=bool)
    with atomic_path(path) as tmp:
        c.write(str(tmp))
    return Path(path)
