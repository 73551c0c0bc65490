"""Correspondences across N calibrated views: which detection in each camera is the same point.

Every camera pair proposes points: its detections are matched by epipolar distance (optimal
assignment, optionally per label), triangulated, and projected into the other cameras, where
the nearest detection within ``max_px`` (same label) joins the track. Tracks are then accepted
best-first (most views, then smallest reprojection error), each detection used once.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import _cameras, triangulate


def correspond(cameras, points, labels=None, max_px: float = 3.0, min_views: int = 2):
    """Group per-camera detections into multi-view tracks.

    Parameters
    ----------
    cameras : Rig or sequence of n_cams Camera
    points : sequence of n_cams arrays, shape (N_i, 2)
        Detections (distorted pixels) of each camera, in any order.
    labels : sequence of n_cams sequences, optional
        A label per detection (e.g. a colour name); only equal labels are matched.
    max_px : epipolar and reprojection tolerance in pixels.

    Returns
    -------
    points_2d : ndarray, shape (n_cams, M, 2)
        Pixels of each track in each camera, NaN where the camera has no detection of it.
    index : ndarray of int, shape (n_cams, M)
        Detection index of each track in each camera, -1 where missing.
    track_labels : list of length M (None without labels)
    """
    cams = _cameras(cameras)
    if len(points) != len(cams):
        raise ValueError(f"points must hold one array per camera ({len(cams)}), got {len(points)}")
    pts = [np.asarray(p, float).reshape(-1, 2) for p in points]
    labs = None if labels is None else [np.asarray(list(l), object) for l in labels]
    if labs is not None and any(len(l) != len(p) for l, p in zip(labs, pts)):
        raise ValueError("labels must give one label per detection in every camera")
    n_cams = len(cams)
    candidates = []  # (n_views, error, index (n_cams,))
    for i, j in combinations(range(n_cams), 2):
        m = match_epipolar(cams[i], cams[j], pts[i], pts[j], max_px,
                           None if labs is None else labs[i], None if labs is None else labs[j])
        if len(m.pairs) == 0:
            continue
        obs = np.full((n_cams, len(m.pairs), 2), np.nan)
        obs[i], obs[j] = pts[i][m.pairs[:, 0]], pts[j][m.pairs[:, 1]]
        X = triangulate(cams, obs, refine=False).points
        idx = np.full((n_cams, len(m.pairs)), -1)
        idx[i], idx[j] = m.pairs[:, 0], m.pairs[:, 1]
        for k in range(n_cams):
            if k in (i, j) or len(pts[k]) == 0:
                continue
            proj = cams[k].project(X)
            d = np.linalg.norm(proj[:, None] - pts[k][None], axis=2)
            if labs is not None:
                d = np.where(labs[i][m.pairs[:, 0]][:, None] == labs[k][None], d, np.inf)
            d = np.where(np.isfinite(d), d, np.inf)
            best = d.argmin(axis=1)
            ok = d[np.arange(len(best)), best] <= max_px
            idx[k, ok] = best[ok]
        for t in range(idx.shape[1]):
            candidates.append(idx[:, t])
    if not candidates:
        return np.full((n_cams, 0, 2), np.nan), np.full((n_cams, 0), -1), [] if labs is not None else None
    cand = np.unique(np.stack(candidates, axis=1), axis=1)
    obs = np.full((n_cams,) + (cand.shape[1], 2), np.nan)
    for k in range(n_cams):
        has = cand[k] >= 0
        obs[k, has] = pts[k][cand[k, has]]
    tri = triangulate(cams, obs, outlier_px=max_px if n_cams >= 3 else None)
    n_views = np.where(tri.ok, tri.n_views, 0)
    cand = np.where(tri.used, cand, -1)
    order = np.lexsort((np.nan_to_num(tri.reproj_error_px, nan=np.inf), -n_views))
    taken = [np.zeros(len(p), bool) for p in pts]
    tracks = []
    for t in order:
        if n_views[t] < min_views:
            continue
        members = [(k, cand[k, t]) for k in range(n_cams) if cand[k, t] >= 0]
        if any(taken[k][d] for k, d in members):
            continue
        for k, d in members:
            taken[k][d] = True
        tracks.append(cand[:, t])
    index = np.stack(tracks, axis=1) if tracks else np.full((n_cams, 0), -1)
    out = np.full((n_cams, index.shape[1], 2), np.nan)
    for k in range(n_cams):
        has = index[k] >= 0
        out[k, has] = pts[k][index[k, has]]
    track_labels = None
    if labs is not None:
        track_labels = [next(labs[k][index[k, t]] for k in range(n_cams) if index[k, t] >= 0)
                        for t in range(index.shape[1])]
    return out, index, track_labels
