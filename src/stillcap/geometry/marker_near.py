"""3D markers looked for where a model predicts them (issue 12: glove markers seen by two or more
cameras that the blind matching of :func:`~stillcap.geometry.marker_points.triangulate_color_markers`
left out).

The blind matching must decide from the blobs alone: a two-view match that a rival blob on the
same epipolar line could explain as well is dropped, and a marker whose blobs fit no track is
lost. Once a hand is posed, its model says where each unlabelled marker should be. Here every
camera's blobs of the marker's colour near that prediction are combined (at most one blob per
camera, two cameras or more), each combination is triangulated (the half-lit bias removed as
in the blind matching) and kept when its views agree within the blind matching's own tolerance
and the point lies within the prediction's gate. A prediction gets a point only when **one**
explanation remains: every other agreeing combination must be a subset of the best one (most
views, then the smallest reprojection error), so two candidate blobs in one camera, or two
disjoint pairs of views, leave it without a point. Whether the point may carry the marker's
label is the labeller's decision (:func:`stillcap.body.hand_label_fill.label_recovered`).
"""

from __future__ import annotations

from itertools import product

import numpy as np

from stillcap._checks import as_array
from stillcap.camera import Rig
from stillcap.geometry.marker_points import (
    MarkerPoints,
    _blob_arrays,
    _flux_ratios,
    _solve,
)

__all__ = ["triangulate_near"]


def triangulate_near(rig: Rig, blobs_per_camera, predicted, colors, gate_m, *, used=None, light_position=None,
                     radius_m: float = 0.005, max_epipolar_px: float | None = None,
                     reference: MarkerPoints | None = None,
                     max_candidates: int = 3, min_depth_m: float = 0.1) -> tuple[MarkerPoints, np.ndarray]:
    """The one 3D point each predicted marker's blobs give, where there is exactly one.

    Parameters
    ----------
    rig : Rig
    blobs_per_camera : sequence of ColorBlobs (rig order)
        Anything with ``centers`` (N, 2), ``colours`` (N,) and optionally ``flux`` (N,).
    predicted : array_like, shape (M, 3)
        Where the model puts each marker (world, m).
    colours : array_like of str, shape (M,)
    gate_m : float or array_like, shape (M,)
        Largest distance of the point from its prediction (m): the model's uncertainty there.
    used : sequence of sets of int, optional
        Per camera, blob indices that are not available (they belong to other markers).
    light_position : array_like, shape (3,), optional
        The strobe (world): the half-lit centroid bias is removed, and the flux ratio of each
        view reported (normalised with ``reference``'s points).
    radius_m : float
        Marker radius (m).
    max_epipolar_px : float, optional
        The blind matching's epipolar tolerance (default 3 px at 1280 px width, scaled with the
        width); a combination's reprojection RMS must be within half of it, as there.
    reference : MarkerPoints, optional
        The capture's other points: the flux ratios are normalised over them and the new ones
        together (as :func:`triangulate_color_markers` does over its points).
    max_candidates : int
        Blobs tried per camera (the nearest to the prediction).
    min_depth_m : float
        Points closer to a camera than this (or behind it) are rejected.

    Returns
    -------
    points : MarkerPoints
        The points found (``pairs`` ``"predicted"``, ``ambiguous`` False).
    index : ndarray of int
        For each point, the row of ``predicted`` it was found for.
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig must be a Rig, got {type(rig).__name__}")
    cams, names = list(rig.cameras), rig.names
    nc = len(cams)
    blobs = list(blobs_per_camera)
    if len(blobs) != nc:
        raise ValueError(f"blobs_per_camera must have one entry per camera ({nc}), got {len(blobs)}")
    pred = as_array(predicted, (None, 3), "predicted")
    cols = np.asarray(colors, dtype=object).astype(str)
    if cols.shape != (len(pred),):
        raise ValueError(f"colours must have shape ({len(pred)},) like predicted, got {cols.shape}")
    gate = np.broadcast_to(np.asarray(gate_m, float), (len(pred),))
    if not np.all(np.isfinite(gate) & (gate > 0)):
        raise ValueError("gate_m must be positive and finite")
    light = None if light_position is None else as_array(light_position, (3,), "light_position")
    used = [set() for _ in range(nc)] if used is None else [set(u) for u in used]
    obs, col, flux = [], [], []
    for n, b in zip(names, blobs):
        c, k, f = (np.zeros((0, 2)), np.zeros(0, object), np.zeros(0)) if b is None else _blob_arrays(b, n)
        obs.append(c), col.append(np.asarray(k, object).astype(str)), flux.append(f)
    scale = max(c.image_size[0] for c in cams) / 1280.0
    max_epi = 3.0 * scale if max_epipolar_px is None else float(max_epipolar_px)

    found, index = [], []
    for i, X0 in enumerate(pred):
        if not np.all(np.isfinite(X0)):
            continue
        options = []  # per camera: candidate blob indices (-1: camera unused)
        for k, cam in enumerate(cams):
            z = cam.world_to_cam(X0[None])[0, 2]
            opts = [-1]
            if z > min_depth_m and len(obs[k]):
                # the prediction's gate in pixels, plus a partly hidden centroid's shift (up to the
                # marker's radius) and the matching's own tolerance
                r_px = cam.K[0, 0] * (gate[i] + radius_m) / z + max_epi
                d = np.linalg.norm(obs[k] - cam.project(X0[None])[0], axis=1)
                ok = (col[k] == cols[i]) & (d <= r_px)
                ok &= ~np.isin(np.arange(len(d)), list(used[k]))
                near = np.flatnonzero(ok)
                opts += near[np.argsort(d[near])][:max_candidates].tolist()
            options.append(opts)
        combos = [np.array(c) for c in product(*options) if sum(j >= 0 for j in c) >= 2]
        if not combos:
            continue
        tracks = np.array(combos)  # (T, n_cams)
        x = np.full((nc, len(tracks), 2), np.nan)
        for k in range(nc):
            has = tracks[:, k] >= 0
            x[k, has] = obs[k][tracks[has, k]]
        X, _, rms, _ = _solve(cams, x, light, radius_m, 2)
        ok = np.all(np.isfinite(X), axis=1) & (rms <= 0.5 * max_epi)
        ok &= np.linalg.norm(np.nan_to_num(X) - X0, axis=1) <= gate[i]
        for k, cam in enumerate(cams):
            ok &= (tracks[:, k] < 0) | (cam.world_to_cam(np.nan_to_num(X))[:, 2] > min_depth_m)
        good = np.flatnonzero(ok)
        if not len(good):
            continue
        nv = (tracks[good] >= 0).sum(axis=1)
        best = good[np.lexsort((rms[good], -nv))[0]]
        bt = tracks[best]
        # one explanation only: every agreeing combination uses the best one's blobs
        if not all(np.all((tracks[g] < 0) | (tracks[g] == bt)) for g in good):
            continue
        found.append(bt)
        index.append(i)
    if not found:
        return MarkerPoints.empty(names), np.zeros(0, int)
    tracks = np.array(found)
    n = len(tracks)
    x = np.full((nc, n, 2), np.nan)
    for k in range(nc):
        has = tracks[:, k] >= 0
        x[k, has] = obs[k][tracks[has, k]]
    X, _, rms, _ = _solve(cams, x, light, radius_m, 2)
    index = np.array(index, int)
    colors_new = cols[index]
    ratio = np.full((nc, n), np.nan)
    if light is not None:
        # normalised over the capture's points and these together, as the blind matching does
        if reference is not None and len(reference):
            bidx = np.concatenate([reference.blob_index, tracks.T], axis=1)
            allX = np.concatenate([reference.points, X])
            allc = np.concatenate([np.asarray(reference.colors).astype(str), colors_new])
            ratio = _flux_ratios(cams, allX, bidx, flux, allc, radius_m, light)[:, len(reference):]
        else:
            ratio = _flux_ratios(cams, X, tracks.T, flux, colors_new, radius_m, light)
        ratio = np.where(tracks.T >= 0, ratio, np.nan)
    pts = MarkerPoints(X, colors_new, (tracks >= 0).sum(axis=1), rms, x, tracks.T.copy(),
                       np.full(n, "predicted"), np.zeros(n, bool), list(names), light is not None, ratio)
    return pts, index
