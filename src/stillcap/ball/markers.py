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
from stillcap.ball.light import fit_light
from stillcap.ball.orientation import MarkerObservations, direction_information, rays_to_directions
from stillcap.camera import Camera
from stillcap.detect._ball_light import view_to_camera
from stillcap.detect.ball_markers import BallMarkers, MarkerFlag, MarkerType, detect_ball_markers
from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import triangulate
from stillcap.response import Response

__all__ = ["marker_types", "pair_marker_observations"]


def marker_types(layout: BallLayout | None = None, response: Response | None = None) -> tuple:
    """The detector's palette for a ball layout: each type's linear-RGB colour encoded through
    the camera's ``response`` (default sRGB; as a fully lit marker looks in that camera's
    photos), BGR 0-255, with the type's shape and the spread of its paint (its size)."""
    layout = BallLayout.seed() if layout is None else layout
    response = Response.srgb() if response is None else Response.from_json(response, "response")
    out = []
    for name, shape, spread in zip(layout.type_names, layout.type_shapes, layout.centroid_depth):
        rgb = np.clip(np.asarray(layout.palette[name], float), 0.0, 1.0)
        bgr = response.encode(rgb[::-1])
        out.append(MarkerType(name, tuple(np.round(bgr, 1)), shape, float(spread)))
    return tuple(out)


def _triangulated_direction(cam_a, cam_b, xa, xb, center, radius):
    X = triangulate([cam_a, cam_b], np.stack([xa, xb])).points
    v = X - center
    r = np.linalg.norm(v, axis=1)
    ok = np.isfinite(r) & (r > 0.8 * radius) & (r < 1.15 * radius)
    return v / np.where(r > 0, r, 1.0)[:, None], ok


def _ray_directions(cam: Camera, centers_px, ball_centers, radius_px, radius_m, depth, radial=None):
    """Each centroid's pixel ray met with the sphere its centroid lies on (radius
    ``radius_m (1 - depth)``), as a direction from the ball centre, with its information
    (:func:`~stillcap.ball.orientation.direction_information`) and whether the ray hit."""
    o, dirs = cam.rays(centers_px)
    v, hit = rays_to_directions(o, dirs, ball_centers, radius_m * (1.0 - depth))
    view = cam.center[None, :] - ball_centers
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    return v, direction_information(v, view, radius_px, radial=radial), hit, view


def _ball_lights(cams, markers, centers, P):
    """Each ball's light direction in the world frame, (K, 3), from the shading of all the
    pair's balls at once: every ball's shading in each photo
    (:attr:`BallMarkers.light_view <stillcap.detect.ball_markers.BallMarkers>`, turned from the
    view frame of its image centre ``centers`` into the world's; one strobe) is a line from its
    centre ``P`` toward the same light, met by :func:`stillcap.ball.light.fit_light`; with fewer
    than 3 such lines, the mean of the ball's own (NaN where neither photo gave one)."""
    K = len(P)
    pts, dirs, idx = [], [], []
    for cam, M, ctr in zip(cams, markers, centers):
        ok = np.all(np.isfinite(M.light_view), axis=1)
        if ok.any():
            k, first = np.unique(M.ball_index[ok], return_index=True)  # a ball's markers share its light
            ray = cam.rays(np.asarray(ctr, float)[k])[1] @ cam.R.T  # the line of sight, camera frame
            pts.append(P[k])
            dirs.append(view_to_camera(M.light_view[ok][first], ray) @ cam.R)  # R^T l: camera to world
            idx.append(k)
    out = np.full((K, 3), np.nan)
    if not idx:
        return out
    pts, dirs, idx = np.concatenate(pts), np.concatenate(dirs), np.concatenate(idx)
    fit = fit_light(pts, dirs)
    if fit is not None:  # every ball toward the fitted light, those without a shading model too
        fin = np.all(np.isfinite(P), axis=1)
        d = fit.position_h[None, :3] - fit.position_h[3] * P[fin]
        out[fin] = d / np.linalg.norm(d, axis=1, keepdims=True)
        return out
    acc, n = np.zeros((K, 3)), np.zeros(K)
    np.add.at(acc, idx, dirs)
    np.add.at(n, idx, 1)
    lit = n > 0
    out[lit] = acc[lit] / np.linalg.norm(acc[lit], axis=1, keepdims=True)
    return out


def _near_terminator(v, light, reach_rad):
    """Whether a marker's paint may reach the terminator, (M,) bool: its direction ``v`` (M, 3)
    lies less than ``reach_rad`` (M,) (its angular size and the blur's reach) above the great
    circle ``n . l = 0`` of its ball's ``light`` (M, 3, :func:`_ball_lights`), or below it.

    The paint beyond the terminator is as dark as the leather there: the detector finds only the
    lit part, whose centroid lies toward the light by up to the marker's size (1-2.5 px, 5-9 deg,
    on the studio's side-lit 15 px balls and on a drawn one, ``docs/spin.md``). Such a marker
    joins the limb-cut markers' noise class, whose scale the spin fit estimates per capture."""
    s = np.einsum("ma,ma->m", v, light)
    with np.errstate(invalid="ignore"):
        return np.isfinite(s) & (np.arcsin(np.clip(s, -1.0, 1.0)) < reach_rad)


def _combine_directions(va, Ia, vb, Ib):
    """Two cameras' directions of one marker combined by their information (the weighted mean in
    the tangent plane of their mean, normalised): ``(directions (n, 3), information (n, 3, 3))``."""
    u0 = va + vb
    u0 /= np.linalg.norm(u0, axis=1, keepdims=True)
    t1, t2 = _tangent_basis(u0)
    B = np.stack([t1, t2], axis=2)  # (n, 3, 2)
    Bt = np.swapaxes(B, 1, 2)
    Ma, Mb = Bt @ Ia @ B, Bt @ Ib @ B
    rhs = Ma @ (Bt @ va[:, :, None]) + Mb @ (Bt @ vb[:, :, None])
    x = np.linalg.solve(Ma + Mb + 1e-12 * np.eye(2), rhs)[:, :, 0]
    u = u0 + np.einsum("mab,mb->ma", B, x)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, B @ (Ma + Mb) @ Bt


def _tangent_part(d, u):
    """The part of each row of ``d`` (n, 3) across the unit vector ``u`` (n, 3)."""
    return d - np.einsum("ij,ij->i", d, u)[:, None] * u


def _tangent_basis(u):
    """Two unit vectors spanning the tangent plane of each unit vector ``u`` (n, 3)."""
    a = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(u, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(u, t1)


def pair_marker_observations(cam_a: Camera, img_a, cam_b: Camera, img_b, centers_a, centers_b, radius_a, radius_b,
                             positions, types=None, layout: BallLayout | None = None, radius_m: float = BASEBALL_RADIUS,
                             max_px: float = 2.0, directions: str = "rays", blur_px=None):
    """Painted markers of a pair's ball images as directions from the ball centres.

    Per photo the markers are found inside each ball image (colour and shape); per ball the two
    photos' markers are matched (same type, epipolar distance below ``max_px``, optimal
    assignment) and triangulated, and a match is kept when the marker lies on the sphere
    (0.8-1.15 radii: a wrong match does not). Every centroid's pixel ray meets the sphere its
    image centroid lies on (:attr:`BallLayout.centroid_depth
    <stillcap.ball.layout.BallLayout.centroid_depth>`, just inside the ball) at a direction from
    the ball centre; a matched marker's two directions are combined by their information
    (:func:`~stillcap.ball.orientation.direction_information`), a marker seen by one camera (or
    badly triangulated) keeps its own. Every observation carries its information, so the spin
    fit weighs it and estimates the centroid noise in pixels.

    Why rays and not the triangulated marker: a pair's two cameras see the ball from directions
    only 5-15 deg apart, so a triangulated marker's depth is 4-10 times less precise than its
    image position, and the direction from the ball centre inherits that (measured on the
    studio's pitches at 15 px ball radius: 4.2 deg RMS for triangulated markers against 1-2 deg
    for rays, ``docs/spin.md``). A ray needs only the ball centre, whose depth error leaves the
    direction unchanged to first order (the centre moves along the line of sight).
    ``directions="triangulated"`` keeps the triangulated directions (no information).

    ``blur_px``: each photo's lens blur (Gaussian sigma, px; one value or one per camera, e.g.
    the pair's :attr:`StereoBalls.psf_px <stillcap.ball.stereo.StereoBalls.psf_px>`, measured on
    the balls' limbs): the centroids are corrected for the pull of blur over the ball's shading
    (:func:`stillcap.detect.ball_markers.shading_blur_shift`). None: no correction.

    A marker whose paint may reach the terminator of its ball's shading (the light's direction
    the shading of all the pair's balls shows, :func:`_ball_lights`) is found on its lit part only, its centroid pulled toward the light: it joins the limb-cut
    markers' noise class (:func:`_near_terminator`).

    Returns
    -------
    obs : MarkerObservations
        ``flash`` = index of the ball position.
    markers : list of 2 BallMarkers
    stats : dict
        ``n_3d``, ``n_ray``, ``epipolar_px`` (median of the matches).
    """
    if directions not in ("rays", "triangulated"):
        raise ValueError(f"directions must be 'rays' or 'triangulated', got {directions!r}")
    layout = BallLayout.seed() if layout is None else layout
    # the palette as each camera photographs it (its response), unless one is given for both
    types_a = marker_types(layout, cam_a.response) if types is None else types
    types_b = marker_types(layout, cam_b.response) if types is None else types
    P = np.asarray(positions, float)
    K = len(P)
    if K == 0:
        empty = MarkerObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        return empty, [BallMarkers.empty(), BallMarkers.empty()], {"n_3d": 0, "n_ray": 0, "epipolar_px": np.nan}
    blur = [None, None] if blur_px is None else [float(v) for v in np.broadcast_to(np.asarray(blur_px, float), (2,))]
    blur = [b if b is not None and np.isfinite(b) else None for b in blur]
    ma = detect_ball_markers(img_a, centers_a, radius_a, types_a, blur_px=blur[0], response=cam_a.response)
    mb = detect_ball_markers(img_b, centers_b, radius_b, types_b, blur_px=blur[1], response=cam_b.response)
    # The K balls' markers (sorted by ball), matched in one call (a call per ball cost more than
    # the matching): labelled by ball and type, a marker pairs only with one of the same ball
    # and type, and an optimal assignment of such independent blocks is each block's own.
    A, B = ma.select(ma.ball_index < K), mb.select(mb.ball_index < K)
    m = match_epipolar(cam_a, cam_b, A.centers, B.centers, max_px=max_px,
                       labels_a=[f"{k} {t}" for k, t in zip(A.ball_index, A.types)],
                       labels_b=[f"{k} {t}" for k, t in zip(B.ball_index, B.types)])
    ia, ib = m.pairs[:, 0], m.pairs[:, 1]
    ball = A.ball_index[ia]  # of each match
    # a marker cut by the searched disc's edge (the limb) has no trustworthy position toward the
    # ball's centre: only its direction around the line of sight informs the fit
    radial_a = (A.flags & MarkerFlag.AT_EDGE) == 0
    radial_b = (B.flags & MarkerFlag.AT_EDGE) == 0
    # each ball's image radius in each camera, px, from the geometry (what the weights need)
    rad_a = cam_a.K[0, 0] * radius_m / np.linalg.norm(P - cam_a.center, axis=1)
    rad_b = cam_b.K[0, 0] * radius_m / np.linalg.norm(P - cam_b.center, axis=1)
    # each ball's light (its shading in both photos), and how far from the terminator a marker's
    # paint may reach it: its angular size and two blur sigmas (as an angle on the ball)
    light = _ball_lights((cam_a, cam_b), (A, B), (centers_a, centers_b), P)
    size = layout.sizes_of_types
    reach_a, reach_b = (2.0 * (b or 0.0) / rd for b, rd in zip(blur, (rad_a, rad_b)))
    u, info, cut_m = np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(len(ia), bool)
    sig_m = np.full(len(ia), np.nan)
    if len(ia):
        u, ok = _triangulated_direction(cam_a, cam_b, A.centers[ia], B.centers[ib], P[ball], radius_m)
        if directions == "rays":
            depth = layout.centroid_depth[layout.type_index(list(A.types[ia]))]
            va, Ia, _, wa = _ray_directions(cam_a, A.centers[ia], P[ball], rad_a[ball], radius_m, depth, radial_a[ia])
            vb, Ib, _, wb = _ray_directions(cam_b, B.centers[ib], P[ball], rad_b[ball], radius_m, depth, radial_b[ib])
            ti_m = layout.type_index(list(A.types[ia]))
            u, info = _combine_directions(va, Ia, vb, Ib)
            cut_m = (_near_terminator(va, light[ball], size[ti_m] + reach_a[ball])
                     | _near_terminator(vb, light[ball], size[ti_m] + reach_b[ball]))
            views = wa + wb
            # the blur corrections' own errors moved through the same rays and combination
            ea = _ray_directions(cam_a, A.centers[ia] + A.blur_error_px[ia], P[ball], rad_a[ball], radius_m, depth)[0]
            eb = _ray_directions(cam_b, B.centers[ib] + B.blur_error_px[ib], P[ball], rad_b[ball], radius_m, depth)[0]
            blur_mode = _tangent_part(_combine_directions(ea, Ia, eb, Ib)[0] - u, u)
            # the pair's centroid noise: the two photos' inverse variances averaged (equal
            # information; one of them unknown: the other's)
            sab = np.stack([A.centroid_sigma_px[ia], B.centroid_sigma_px[ib]])
            inv = np.where(sab > 0, 1.0 / np.where(sab > 0, sab, 1.0) ** 2, np.nan)
            n_fin = np.isfinite(inv).sum(axis=0)
            mean_inv = np.nansum(inv, axis=0) / np.maximum(n_fin, 1)
            sig_m = np.where(n_fin > 0, 1.0 / np.sqrt(np.where(n_fin > 0, mean_inv, 1.0)), np.nan)
    else:
        ok = np.zeros(0, bool)
    # Single-camera rays, every ball's at once: the unmatched markers, then the matches off the
    # sphere; a stable sort by ball keeps that order within each ball.
    rays = []
    for M, cam, rad, rdl, reach, idx in ((A, cam_a, rad_a, radial_a, reach_a, np.concatenate([m.unmatched_a, ia[~ok]])),
                                         (B, cam_b, rad_b, radial_b, reach_b, np.concatenate([m.unmatched_b, ib[~ok]]))):
        idx = idx[np.argsort(M.ball_index[idx], kind="stable")].astype(int)
        k_ray = M.ball_index[idx]
        ti = layout.type_index(list(M.types[idx]))
        if len(idx):
            # a centroid is the image of a point inside the ball (BallLayout.centroid_depth): the
            # ray meets that smaller sphere where the marker's axis does, the ball's surface
            # closer to the line of sight (a fixed-sign spin error otherwise, "Coverage audit")
            v, I, hit, view = _ray_directions(cam, M.centers[idx], P[k_ray], rad[k_ray], radius_m,
                                              layout.centroid_depth[ti], rdl[idx])
            ve, _, hit_e, _ = _ray_directions(cam, M.centers[idx] + M.blur_error_px[idx], P[k_ray], rad[k_ray],
                                              radius_m, layout.centroid_depth[ti])
            be = np.where(hit_e[:, None], _tangent_part(ve - v, v), 0.0)
            cut = _near_terminator(v, light[k_ray], size[ti] + reach[k_ray])
        else:
            v, I, hit, view = np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, bool), np.zeros((0, 3))
            be, cut = np.zeros((0, 3)), np.zeros(0, bool)
        # a marker cut by the limb (one informative component) or reaching the terminator: the cut ones' noise class
        rays.append((ti, k_ray, v, I, hit, np.where(rdl[idx] & ~cut, 0, 1), view, be, M.centroid_sigma_px[idx]))
    with_info = directions == "rays"
    parts, n3, nray, epi = [], 0, 0, []
    for k in range(K):
        sel = ok & (ball == k)
        if sel.any():
            o = MarkerObservations.from_directions(np.full(int(sel.sum()), k), list(A.types[ia[sel]]), u[sel], layout)
            if with_info:
                o.information = info[sel]
                o.views = views[sel] / np.linalg.norm(views[sel], axis=1, keepdims=True)
            o.noise_class = np.where(radial_a[ia[sel]] & radial_b[ib[sel]] & ~cut_m[sel], 0, 1)
            o.blur_mode = blur_mode[sel] if with_info else None
            o.centroid_sigma_px = sig_m[sel]  # (not positive: unknown, MarkerObservations)
            parts.append(o)
            n3 += int(sel.sum())
            epi += list(m.distance_px[sel])
        for ti, k_ray, v, I, hit, cls, view, be, sg in rays:
            sel = hit & (k_ray == k)
            if sel.any():
                parts.append(MarkerObservations(np.full(int(sel.sum()), k), ti[sel], v[sel],
                                                np.ones(int(sel.sum()), bool), I[sel] if with_info else None,
                                                cls[sel], view[sel] if with_info else None,
                                                be[sel] if with_info else None, sg[sel]))
                nray += int(sel.sum())
    obs = (MarkerObservations.concatenate(parts) if parts
           else MarkerObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3))))
    return obs, [ma, mb], {"n_3d": n3, "n_ray": nray, "epipolar_px": float(np.median(epi)) if epi else np.nan}
