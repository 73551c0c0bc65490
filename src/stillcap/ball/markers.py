"""The painted markers of a stereo pair's ball images, as directions from the ball centres.

:func:`pair_marker_observations` finds the markers inside every ball image of the pair's two
photos (:func:`stillcap.detect.ball_markers.detect_ball_markers`, with the palette of
:func:`marker_types`), matches them across the pair by ball, type and epipolar distance,
triangulates the matches and keeps those on the ball's sphere; the others become pixel rays
intersected with the sphere (:func:`stillcap.ball.orientation.rays_to_directions`). The pitch
pipeline and the hand capture's ball spin both read their markers this way.
"""

from __future__ import annotations

import numpy as np

from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout
from stillcap.ball.orientation import MarkerObservations, rays_to_directions
from stillcap.camera import Camera
from stillcap.detect.ball_markers import BallMarkers, MarkerType, detect_ball_markers
from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import triangulate
from stillcap.response import Response

__all__ = ["marker_types", "pair_marker_observations"]


def marker_types(layout: BallLayout | None = None, response: Response | None = None) -> tuple:
    """The detector's palette for a ball layout: each type's linear-RGB colour encoded through
    the camera's ``response`` (default sRGB; as a fully lit marker looks in that camera's
    photos), BGR 0-255, with the type's shape."""
    layout = BallLayout.seed() if layout is None else layout
    response = Response.srgb() if response is None else Response.from_json(response, "response")
    out = []
    for name, shape in zip(layout.type_names, layout.type_shapes):
        rgb = np.clip(np.asarray(layout.palette[name], float), 0.0, 1.0)
        bgr = response.encode(rgb[::-1])
        out.append(MarkerType(name, tuple(np.round(bgr, 1)), shape))
    return tuple(out)


def _triangulated_direction(cam_a, cam_b, xa, xb, center, radius):
    X = triangulate([cam_a, cam_b], np.stack([xa, xb])).points
    v = X - center
    r = np.linalg.norm(v, axis=1)
    ok = np.isfinite(r) & (r > 0.8 * radius) & (r < 1.15 * radius)
    return v / np.where(r > 0, r, 1.0)[:, None], ok


def pair_marker_observations(cam_a: Camera, img_a, cam_b: Camera, img_b, centers_a, centers_b, radius_a, radius_b,
                             positions, types=None, layout: BallLayout | None = None, radius_m: float = BASEBALL_RADIUS,
                             max_px: float = 2.0):
    """Painted markers of a pair's ball images as directions from the ball centres.

    Per photo the markers are found inside each ball image (colour and shape); per ball the two
    photos' markers are matched (same type, epipolar distance below ``max_px``, optimal
    assignment) and triangulated, and the direction from the ball centre is kept when the
    marker lies on the sphere (0.8-1.15 radii: a wrong match does not). Markers seen by one
    camera (or badly triangulated) become pixel rays meeting the sphere their image centroids
    lie on (:attr:`BallLayout.centroid_depth <stillcap.ball.layout.BallLayout.centroid_depth>`,
    just inside the ball).

    Returns
    -------
    obs : MarkerObservations
        ``flash`` = index of the ball position.
    markers : list of 2 BallMarkers
    stats : dict
        ``n_3d``, ``n_ray``, ``epipolar_px`` (median of the matches).
    """
    layout = BallLayout.seed() if layout is None else layout
    # the palette as each camera photographs it (its response), unless one is given for both
    types_a = marker_types(layout, cam_a.response) if types is None else types
    types_b = marker_types(layout, cam_b.response) if types is None else types
    P = np.asarray(positions, float)
    K = len(P)
    if K == 0:
        empty = MarkerObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        return empty, [BallMarkers.empty(), BallMarkers.empty()], {"n_3d": 0, "n_ray": 0, "epipolar_px": np.nan}
    ma = detect_ball_markers(img_a, centers_a, radius_a, types_a)
    mb = detect_ball_markers(img_b, centers_b, radius_b, types_b)
    # The K balls' markers (sorted by ball), matched in one call (a call per ball cost more than
    # the matching): labelled by ball and type, a marker pairs only with one of the same ball
    # and type, and an optimal assignment of such independent blocks is each block's own.
    A, B = ma.select(ma.ball_index < K), mb.select(mb.ball_index < K)
    m = match_epipolar(cam_a, cam_b, A.centers, B.centers, max_px=max_px,
                       labels_a=[f"{k} {t}" for k, t in zip(A.ball_index, A.types)],
                       labels_b=[f"{k} {t}" for k, t in zip(B.ball_index, B.types)])
    ia, ib = m.pairs[:, 0], m.pairs[:, 1]
    ball = A.ball_index[ia]  # of each match
    if len(ia):
        u, ok = _triangulated_direction(cam_a, cam_b, A.centers[ia], B.centers[ib], P[ball], radius_m)
    else:
        u, ok = np.zeros((0, 3)), np.zeros(0, bool)
    # Single-camera rays, every ball's at once: the unmatched markers, then the matches off the
    # sphere; a stable sort by ball keeps that order within each ball.
    rays = []
    for M, cam, idx in ((A, cam_a, np.concatenate([m.unmatched_a, ia[~ok]])),
                        (B, cam_b, np.concatenate([m.unmatched_b, ib[~ok]]))):
        idx = idx[np.argsort(M.ball_index[idx], kind="stable")].astype(int)
        k_ray = M.ball_index[idx]
        ti = layout.type_index(list(M.types[idx]))
        if len(idx):
            o, dirs = cam.rays(M.centers[idx])
            # a centroid is the image of a point inside the ball (BallLayout.centroid_depth): the
            # ray meets that smaller sphere where the marker's axis does, the ball's surface
            # closer to the line of sight (a fixed-sign spin error otherwise, "Coverage audit")
            v, hit = rays_to_directions(o, dirs, P[k_ray], radius_m * (1.0 - layout.centroid_depth[ti]))
        else:
            v, hit = np.zeros((0, 3)), np.zeros(0, bool)
        rays.append((ti, k_ray, v, hit))
    parts, n3, nray, epi = [], 0, 0, []
    for k in range(K):
        sel = ok & (ball == k)
        if sel.any():
            parts.append(MarkerObservations.from_directions(np.full(int(sel.sum()), k), list(A.types[ia[sel]]),
                                                            u[sel], layout))
            n3 += int(sel.sum())
            epi += list(m.distance_px[sel])
        for ti, k_ray, v, hit in rays:
            sel = hit & (k_ray == k)
            if sel.any():
                parts.append(MarkerObservations(np.full(int(sel.sum()), k), ti[sel], v[sel],
                                                np.ones(int(sel.sum()), bool)))
                nray += int(sel.sum())
    obs = (MarkerObservations.concatenate(parts) if parts
           else MarkerObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3))))
    return obs, [ma, mb], {"n_3d": n3, "n_ray": nray, "epipolar_px": float(np.median(epi)) if epi else np.nan}
