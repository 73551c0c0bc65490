"""Epipolar geometry of two calibrated cameras and optimal two-view matching."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from stillcap._checks import as_array
from stillcap.camera import Camera


def _skew(v) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def essential_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """E with ``xn_b^T E xn_a = 0`` for normalised coordinates of the same world point."""
    a2b = cam_b.world2cam @ cam_a.cam2world
    return _skew(a2b[:3, 3]) @ a2b[:3, :3]


def fundamental_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """F with ``x_b^T F x_a = 0`` for undistorted pixels ``x_a`` (camera a), ``x_b`` (camera b)."""
    F = np.linalg.inv(cam_b.K).T @ essential_matrix(cam_a, cam_b) @ np.linalg.inv(cam_a.K)
    return F / np.linalg.norm(F)


def epipolar_distances(cam_a: Camera, cam_b: Camera, pts_a, pts_b) -> np.ndarray:
    """Symmetric epipolar distance (px) between every pair, shape (Na, Nb).

    The mean of the distance of ``b`` to the epipolar line of ``a`` and vice versa, on
    undistorted pixels. NaN points give NaN rows/columns.
    """
    xa = cam_a.undistort_points(as_array(pts_a, (None, 2), "pts_a"))
    xb = cam_b.undistort_points(as_array(pts_b, (None, 2), "pts_b"))
    F = fundamental_matrix(cam_a, cam_b)
    ha = np.concatenate([xa, np.ones((len(xa), 1))], axis=1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1)
    lines_b = ha @ F.T  # epipolar lines in b of points in a, (Na, 3)
    lines_a = hb @ F    # epipolar lines in a of points in b, (Nb, 3)
    num = hb @ lines_b.T  # (Nb, Na): x_b^T F x_a
    da = np.abs(num.T) / np.linalg.norm(lines_b[:, :2], axis=1)[:, None]
    db = np.abs(num.T) / np.linalg.norm(lines_a[:, :2], axis=1)[None, :]
    return 0.5 * (da + db)


@dataclass
class EpipolarMatches:
    """Matched index pairs between two views.

    pairs : (K, 2) int array of (index in a, index in b); distance_px : (K,) epipolar distance.
    """

    pairs: np.ndarray
    distance_px: np.ndarray
    unmatched_a: np.ndarray
    unmatched_b: np.ndarray


def match_epipolar(cam_a: Camera, cam_b: Camera, pts_a, pts_b, max_px: float = 3.0,
                   labels_a=None, labels_b=None) -> EpipolarMatches:
    """Optimal one-to-one matching of two views' points by epipolar distance.

    Minimises the total symmetric epipolar distance (``linear_sum_assignment``) over pairs whose
    distance is below ``max_px`` and, if labels (e.g. marker colours) are given, whose labels are
    equal. Points that have no admissible partner stay unmatched.

    Parameters
    ----------
    pts_a : array_like, shape (Na, 2); pts_b : array_like, shape (Nb, 2)
        Distorted pixels; NaN rows never match.
    labels_a, labels_b : sequence of hashable, optional, lengths Na and Nb
    """
    pa = as_array(pts_a, (None, 2), "pts_a")
    pb = as_array(pts_b, (None, 2), "pts_b")
    empty = np.zeros((0, 2), int)
    if len(pa) == 0 or len(pb) == 0:
        return EpipolarMatches(empty, np.zeros(0), np.arange(len(pa)), np.arange(len(pb)))
    d = epipolar_distances(cam_a, cam_b, pa, pb)
    allowed = np.isfinite(d) & (d <= max_px)
    if labels_a is not None or labels_b is not None:
        if labels_a is None or labels_b is None or len(labels_a) != len(pa) or len(labels_b) != len(pb):
            raise ValueError(
                f"labels must be given for both views with one label per point "
                f"(points {len(pa)} and {len(pb)})"
            )
        la, lb = np.asarray(labels_a, object), np.asarray(labels_b, object)
        allowed &= la[:, None] == lb[None, :]
    # Forbidden pairs get a cost above any sum of admissible ones, then are dropped.
    big = 1e6 * (max_px + 1.0) * (min(d.shape) + 1)
    cost = np.where(allowed, d, big)
    rows, cols = linear_sum_assignment(cost)
    keep = allowed[rows, cols]
    rows, cols = rows[keep], cols[keep]
    return EpipolarMatches(np.stack([rows, cols], axis=1).astype(int), d[rows, cols],
                           np.setdiff1d(np.arange(len(pa)), rows), np.setdiff1d(np.arange(len(pb)), cols))
