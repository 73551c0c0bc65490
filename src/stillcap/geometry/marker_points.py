"""3D points of coloured markers seen by stereo pairs, with the half-lit centroid bias removed.

Two parts:

- **Lit-sphere centroids** (:func:`lit_sphere_samples`, :func:`lit_sphere_centroids`,
  :func:`lit_sphere_offsets`): a lambertian sphere lit by a point light appears as a partly lit
  disc (a half moon when the light is to the side); the radiance-weighted centroid of its image
  is not the projection of its centre. The model projects evenly spread surface points, each
  weighted by ``max(n.l, 0) / d_light^2`` times its foreshortening toward the camera (visible
  side only). The studio's truth (:func:`stillcap.studio.hand.lit_centroids`) is this model
  plus occlusion by other bodies.
- **Triangulation** (:func:`triangulate_color_markers`): every two cameras (not only the stereo
  pairs: one strobe lights them all) propose same-colour blob pairs near each other's epipolar
  line; each is triangulated and projected into the other cameras, where same-colour blobs near
  its predicted centroid may confirm it. Of all these tracks, the set that explains most blobs
  best, each blob used once, is chosen exactly (a set packing, ``scipy.optimize.milp``); tracks of
  the same colour within ``merge_mm`` that share no camera are one marker, re-triangulated from
  all its views. With the light's position the half-lit bias is removed by iteration:
  triangulate, predict each view's centroid offset at the point, subtract, again.
  ``docs/hand-markers.md`` gives the weights and why.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stillcap._checks import as_array
from stillcap.camera import Camera, Rig
from stillcap.geometry.epipolar import epipolar_distances
from stillcap.geometry.triangulate import triangulate

__all__ = ["MarkerPoints", "lit_sphere_centroids", "lit_sphere_offsets", "lit_sphere_samples",
           "sphere_directions", "triangulate_color_markers"]


def sphere_directions(n: int) -> np.ndarray:
    """``n`` evenly spread unit vectors (Fibonacci sphere), shape (n, 3)."""
    if int(n) < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    k = np.arange(int(n)) + 0.5
    z = 1 - 2 * k / n
    phi = k * np.pi * (3 - np.sqrt(5))
    rr = np.sqrt(1 - z * z)
    return np.stack([rr * np.cos(phi), rr * np.sin(phi), z], 1)


_SAMPLES = {1200: sphere_directions(1200)}


def _directions(n: int) -> np.ndarray:
    if n not in _SAMPLES:
        _SAMPLES[n] = sphere_directions(n)
    return _SAMPLES[n]


def lit_sphere_samples(camera: Camera, centers, radius: float, light_position,
                       n_samples: int = 1200) -> tuple[np.ndarray, np.ndarray]:
    """Surface points of spheres and their image weights (radiance times foreshortening).

    Parameters
    ----------
    camera : Camera
    centres : array_like, shape (N, 3) or (3,)
        Sphere centres (world).
    radius : float
        Sphere radius (world units).
    light_position : array_like, shape (3,)
        The point light (world).
    n_samples : int
        Surface points per sphere (evenly spread).

    Returns
    -------
    points : ndarray, shape (N, n_samples, 3)
    weights : ndarray, shape (N, n_samples)
        ``max(n.l, 0) / d_light^2`` times ``max(n.v, 0)`` (``l`` toward the light, ``v``
        toward the camera); zero on the far side or the dark side.
    """
    c = np.atleast_2d(np.asarray(centers, float))
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"centres must have shape (N, 3), got {np.shape(centers)}")
    light = as_array(light_position, (3,), "light_position")
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be positive, got {radius}")
    n = _directions(int(n_samples))
    pts = c[:, None] + radius * n[None]  # (N, S, 3)
    to_cam = camera.center - pts
    fore = np.einsum("sa,nsa->ns", n, to_cam) / np.linalg.norm(to_cam, axis=-1)
    to_l = light - pts
    dl = np.linalg.norm(to_l, axis=-1)
    lit = np.einsum("sa,nsa->ns", n, to_l) / dl
    w = np.where(fore > 0, fore, 0) * np.clip(lit, 0, None) / dl ** 2
    return pts, w


def _weighted_centroids(camera: Camera, points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    # only the lit, visible samples (about a quarter) are projected: the projection is the cost
    row, col = np.nonzero(weights > 0)
    w = weights[row, col]
    px = camera.project(points[row, col])
    n = len(points)
    sw = np.bincount(row, w, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([np.bincount(row, w * px[:, 0], n), np.bincount(row, w * px[:, 1], n)], axis=1) / sw[:, None]


def lit_sphere_centroids(camera: Camera, centers, radius: float, light_position, n_samples: int = 1200,
                         weights=None) -> np.ndarray:
    """Radiance-weighted centroid of the image of lambertian spheres lit by a point light.

    Parameters
    ----------
    camera : Camera
    centres : array_like, shape (N, 3)
    radius : float
    light_position : array_like, shape (3,)
    n_samples : int
        Surface points per sphere.
    weights : callable(points, weights) -> weights, optional
        Changes the sample weights before the centroid, e.g. zeroes the samples hidden by other
        bodies (the studio's occlusion).

    Returns
    -------
    ndarray, shape (N, 2)
        Distorted pixels; NaN for a sphere with no lit visible surface.
    """
    pts, w = lit_sphere_samples(camera, centers, radius, light_position, n_samples)
    if weights is not None:
        w = weights(pts, w)
    return _weighted_centroids(camera, pts, w)


def lit_sphere_offsets(camera: Camera, centers, radius: float, light_position, n_samples: int = 300) -> np.ndarray:
    """Lit-image centroid minus the projected centre (pixels), shape (N, 2): the bias of a blob
    centroid as the marker's position. NaN where the sphere shows no lit surface."""
    c = np.atleast_2d(np.asarray(centers, float))
    return lit_sphere_centroids(camera, c, radius, light_position, n_samples) - camera.project(c)


# --------------------------------------------------------------------------------------------
# Triangulation of coloured markers
# --------------------------------------------------------------------------------------------
@dataclass
class MarkerPoints:
    """3D markers from coloured blobs (see :func:`triangulate_color_markers`).

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        Marker centres (world, m).
    colours : ndarray of str, shape (N,)
    n_views : ndarray of int, shape (N,)
        Cameras whose blob was used.
    reprojection_px : ndarray, shape (N,)
        RMS reprojection error over the used views (after the bias correction when the light
        was given), pixels.
    pixels : ndarray, shape (n_cams, N, 2)
        The blob centroids used (observed, uncorrected); NaN where a camera did not see the
        point.
    blob_index : ndarray of int, shape (n_cams, N)
        Index of the blob in that camera's :class:`~stillcap.detect.color_markers.ColorBlobs`,
        -1 where unused.
    pairs : ndarray of str, shape (N,)
        The stereo pair(s) both of whose cameras the point uses, ``"left"``, ``"right"`` or
        ``"left+right"``; ``"cross"`` when it uses no stereo pair whole (one camera of each).
    ambiguous : ndarray of bool, shape (N,)
        A two-view point one of whose blobs had another same-colour partner within the epipolar
        tolerance, and no third view decided (the hand pipeline drops such points when partly
        hidden).
    cameras : list of str
        Camera names (rig order).
    bias_corrected : bool
        Whether the half-lit centroid offset was removed.
    flux_ratio : ndarray, shape (n_cams, N)
        Light of each used blob over the lit-sphere model's prediction, normalised so that an
        unhidden marker has ~1 (measured spread +-3 %); below ~0.9 the marker is partly hidden
        and its centroid shifted. NaN where unused, or without the light or the blobs' flux.
    """

    points: np.ndarray
    colors: np.ndarray
    n_views: np.ndarray
    reprojection_px: np.ndarray
    pixels: np.ndarray
    blob_index: np.ndarray
    pairs: np.ndarray
    ambiguous: np.ndarray
    cameras: list
    bias_corrected: bool = False
    flux_ratio: np.ndarray | None = None

    def __post_init__(self):
        if self.flux_ratio is None:
            self.flux_ratio = np.full(self.blob_index.shape, np.nan)

    @property
    def partly_hidden(self) -> np.ndarray:
        """Points with a used view whose flux ratio is below 0.9 (shape (N,)): their position
        carries that view's shifted centroid (~1-3 mm)."""
        return np.any(np.nan_to_num(self.flux_ratio, nan=1.0) < 0.9, axis=0)

    def __len__(self) -> int:
        return len(self.points)

    def select(self, keep) -> MarkerPoints:
        keep = np.asarray(keep)
        return MarkerPoints(self.points[keep], self.colors[keep], self.n_views[keep], self.reprojection_px[keep],
                            self.pixels[:, keep], self.blob_index[:, keep], self.pairs[keep], self.ambiguous[keep],
                            list(self.cameras), self.bias_corrected, self.flux_ratio[:, keep])

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN as None)."""
        def clean(a):
            a = np.asarray(a, float)
            return np.where(np.isfinite(a), a, np.nan).astype(object).tolist() if a.size else a.tolist()

        def nan_none(x):
            if isinstance(x, list):
                return [nan_none(v) for v in x]
            return None if isinstance(x, float) and not np.isfinite(x) else x

        return {"cameras": list(self.cameras), "bias_corrected": bool(self.bias_corrected),
                "points": nan_none(clean(self.points)), "colours": [str(c) for c in self.colors],
                "n_views": self.n_views.astype(int).tolist(), "reprojection_px": nan_none(clean(self.reprojection_px)),
                "pixels": nan_none(clean(self.pixels)), "blob_index": self.blob_index.astype(int).tolist(),
                "pairs": [str(p) for p in self.pairs], "ambiguous": self.ambiguous.astype(bool).tolist(),
                "flux_ratio": nan_none(clean(self.flux_ratio))}

    @classmethod
    def empty(cls, cameras) -> MarkerPoints:
        nc = len(cameras)
        return cls(np.zeros((0, 3)), np.zeros(0, str), np.zeros(0, int), np.zeros(0), np.zeros((nc, 0, 2)),
                   np.zeros((nc, 0), int), np.zeros(0, str), np.zeros(0, bool), list(cameras))


def _blob_arrays(blobs, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        centers, colors = blobs.centers, blobs.colors
    except AttributeError:
        raise ValueError(f"blobs of {name} must have .centers (N, 2) and .colours (N,), "
                         f"got {type(blobs).__name__}") from None
    c = as_array(centers, (None, 2), f"blobs of {name}: centers")
    col = np.asarray(list(colors), object)
    if len(col) != len(c):
        raise ValueError(f"blobs of {name}: {len(c)} centers but {len(col)} colours")
    flux = getattr(blobs, "flux", None)
    flux = np.full(len(c), np.nan) if flux is None else as_array(flux, (len(c),), f"blobs of {name}: flux")
    return c, col, flux


def _solve(cams: list, obs: np.ndarray, light, radius: float, iterations: int):
    """Triangulate ``obs`` (n_cams, N, 2) with the lit-sphere offsets removed (``iterations``
    rounds; none without a light). Returns (points, corrected observations, rms, per-view errors)."""
    tri = triangulate(cams, obs)
    X = tri.points
    corr = obs
    if light is not None:
        for _ in range(iterations):
            ok = np.all(np.isfinite(X), axis=1)
            off = np.zeros_like(obs)
            for k, cam in enumerate(cams):
                if ok.any():
                    o = lit_sphere_offsets(cam, X[ok], radius, light)
                    off[k, ok] = np.nan_to_num(o)
            corr = obs - off
            tri = triangulate(cams, corr)
            X = np.where(ok[:, None], tri.points, X)
    return X, corr, tri.reproj_error_px, tri.errors_px


def _track_pixels(obs, views: dict, nc: int) -> np.ndarray:
    """The pixels of one track, shape (n_cams, 1, 2) (NaN where unused)."""
    x = np.full((nc, 1, 2), np.nan)
    for k, j in views.items():
        x[k, 0] = obs[k][j]
    return x


def _flux_ratios(cams, X, bidx, flux, colors, radius, light) -> np.ndarray:
    """Blob flux over the model's (sum of the lit-sphere sample weights times the pixels per
    unit area, (f / z)^2), normalised by the median per camera and colour (per colour over all
    cameras when a camera has fewer than 4 of that colour). Shape (n_cams, N); NaN where unused."""
    nc, n = bidx.shape
    raw = np.full((nc, n), np.nan)
    ok = np.all(np.isfinite(X), axis=1)
    for k, cam in enumerate(cams):
        use = (bidx[k] >= 0) & ok
        if not use.any():
            continue
        _, w = lit_sphere_samples(cam, X[use], radius, light, 300)
        z = cam.world_to_cam(X[use])[:, 2]
        pred = w.sum(axis=1) * (cam.K[0, 0] / z) ** 2
        with np.errstate(invalid="ignore", divide="ignore"):
            raw[k, use] = flux[k][bidx[k, use]] / pred
    out = np.full_like(raw, np.nan)
    for c in np.unique(colors):
        sel = colors == c
        allv = raw[:, sel]
        ref_all = np.nanmedian(allv) if np.isfinite(allv).any() else np.nan
        for k in range(nc):
            v = raw[k, sel]
            ref = np.nanmedian(v) if np.isfinite(v).sum() >= 4 else ref_all
            out[k, sel] = v / ref
    return out


#: Weight lost by a two-view point that no stereo pair saw alone (a camera of each pair): a
#: stereo pair's own explanation of the same blobs is preferred to it.
CROSS_PAIR_PENALTY = 0.25
#: Weight lost per unit of a candidate's reprojection RMS over its tolerance (half the epipolar
#: tolerance): of two explanations of the same blobs, the better-fitting one wins.
RESIDUAL_PENALTY = 0.5
#: A two-view point across the pairs is kept only when its reprojection RMS is within this many
#: times the centroid noise (estimated from the points with three or more views).
CROSS_PAIR_NOISE_FACTOR = 3.0
#: Confirming blobs tried per other camera (the nearest ones within the confirmation distance).
CONFIRMATIONS_PER_CAMERA = 2


def _seed_tracks(cams, obs, col, a, b, max_epi, light, radius, min_depth, conf):
    """Candidate tracks (blob index per camera, -1 where unused; shape (T, n_cams)) seeded by the
    same-colour blob pairs of cameras ``a`` and ``b`` near each other's epipolar line: each seed
    alone and with every combination of the same-colour blobs near its predicted centroid in
    the other cameras (the nearest :data:`CONFIRMATIONS_PER_CAMERA` within ``conf`` pixels).
    Also the admissible seeds, shape (N_a, N_b) bool."""
    nc = len(cams)
    d = epipolar_distances(cams[a], cams[b], obs[a], obs[b])
    allowed = np.isfinite(d) & (d <= max_epi) & (col[a][:, None] == col[b][None, :])
    ia, ib = np.nonzero(allowed)
    if len(ia) == 0:
        return np.zeros((0, nc), int), allowed
    x2 = np.full((nc, len(ia), 2), np.nan)
    x2[a], x2[b] = obs[a][ia], obs[b][ib]
    X, _, _, _ = _solve(cams, x2, light, radius, 1)  # one round: enough to tell candidates apart
    ok = np.all(np.isfinite(X), axis=1)
    for k in (a, b):
        z = cams[k].world_to_cam(np.where(ok[:, None], X, 0.0))[:, 2]
        ok &= z > min_depth
    allowed[ia[~ok], ib[~ok]] = False
    options = []  # (camera, (S, CONFIRMATIONS_PER_CAMERA) blob indices or -1)
    for k in range(nc):
        if k in (a, b) or len(obs[k]) == 0 or not ok.any():
            continue
        pred = np.full((len(ia), 2), np.nan)
        pred[ok] = cams[k].project(X[ok])
        if light is not None:
            pred[ok] += np.nan_to_num(lit_sphere_offsets(cams[k], X[ok], radius, light))
        dist = np.linalg.norm(pred[:, None] - obs[k][None], axis=2)
        dist = np.where((col[a][ia][:, None] == col[k][None, :]) & ok[:, None], dist, np.inf)
        near = np.argsort(dist, axis=1)[:, :CONFIRMATIONS_PER_CAMERA]
        options.append((k, np.where(np.take_along_axis(dist, near, axis=1) <= conf, near, -1)))
    tracks = []
    for s in np.flatnonzero(ok):
        base = np.full(nc, -1)
        base[a], base[b] = ia[s], ib[s]
        combos = [base]
        for k, near in options:
            more = []
            for c in combos:
                for j in near[s][near[s] >= 0]:
                    c2 = c.copy()
                    c2[k] = j
                    more.append(c2)
            combos += more
        tracks += combos
    return np.array(tracks, int).reshape(-1, nc), allowed


def _partly_hidden_tracks(cams, obs, flux, col, tracks, chosen, light, radius, min_flux_ratio) -> np.ndarray:
    """Tracks (bool, shape (T,)) using a blob that is partly hidden in a chosen track: a view whose
    flux ratio (:func:`_flux_ratios`, normalised over the chosen tracks) is below ``min_flux_ratio``."""
    nc = len(cams)
    sub = tracks[chosen]
    x = np.full((nc, len(sub), 2), np.nan)
    for k in range(nc):
        has = sub[:, k] >= 0
        x[k, has] = obs[k][sub[has, k]]
    X, _, _, _ = _solve(cams, x, light, radius, 1)
    colors = np.array([col[int(np.argmax(t >= 0))][t[np.argmax(t >= 0)]] for t in sub], dtype=object).astype(str)
    ratio = _flux_ratios(cams, X, sub.T, flux, colors, radius, light)  # (n_cams, len(chosen))
    low = (sub.T >= 0) & (ratio < min_flux_ratio)
    out = np.zeros(len(tracks), bool)
    for k in range(nc):
        bad = np.unique(sub[low[k], k])  # this camera's partly hidden blobs
        if len(bad):
            out |= np.isin(tracks[:, k], bad)
    return out


def _consensus_views(cams, X, corr, bidx, flux, colors, multi, max_rep, radius, light, min_flux_ratio) -> np.ndarray:
    """The views (bool, shape (n_cams, multi.sum())) of the points ``multi`` (3+ views) that agree:
    a consensus over view pairs (RANSAC in :func:`triangulate`) on the corrected observations
    ``corr``, views farther than ``max_rep`` pixels dropped.

    With the light: a blob that is no whole marker's image does not vote while two whole views
    remain; it is kept when it agrees with their point. Whole means a flux ratio
    (:func:`_flux_ratios`) within ``min_flux_ratio`` to ``1 / min_flux_ratio``; outside it the blob
    is a sliver of a hidden marker or holds another marker's light, and its centroid is not this
    marker's. Two views of a pair often agree by chance along their epipolar line, so with a
    wrong blob in one of them the consensus was a tie that the wrong pair could win: studio hand
    1, ``middle.dip`` seen whole by two cameras, was put 6.7 mm off (and not flagged) on the
    right pair's blob of ``index.pip`` (flux ratio 1.65; ``middle.dip``'s lit side hidden there),
    the whole blob of the left inner camera dropped."""
    cons = corr[:, multi].copy()
    odd = np.zeros(cons.shape[:2], bool)
    if light is not None and min_flux_ratio is not None:
        ratio = _flux_ratios(cams, X, bidx, flux, colors, radius, light)[:, multi]
        seen = bidx[:, multi] >= 0
        whole = seen & (ratio >= min_flux_ratio) & (ratio <= 1.0 / min_flux_ratio)
        odd = seen & ~whole & (whole.sum(axis=0) >= 2)[None]
        cons[odd] = np.nan
    tri = triangulate(cams, cons, outlier_px=max_rep)
    used = tri.used.copy()
    if odd.any():  # an odd view rejoins when it agrees with the whole views' point
        P = tri.points
        for k in np.flatnonzero(odd.any(axis=1)):
            j = np.flatnonzero(odd[k] & np.all(np.isfinite(P), axis=1))
            if len(j):
                used[k, j] = np.linalg.norm(cams[k].project(P[j]) - corr[k][multi][j], axis=1) <= max_rep
    return used


def _pack_tracks(tracks: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The tracks (indices) that together weigh most with every blob in at most one of them: a set
    packing, solved exactly as a mixed-integer programme (``scipy.optimize.milp``, HiGHS).

    A greedy choice (most views first) or a per-pair assignment lets a wrong match that a
    coincidental blob in a third camera "confirms" take a blob from the marker it belongs to;
    the packing weighs every explanation of all the blobs at once (issue 12: markers seen by
    two or more cameras that were never triangulated)."""
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import csr_matrix

    nt, nc = tracks.shape
    if nt == 0:
        return np.zeros(0, int)
    t_idx, k_idx = np.nonzero(tracks >= 0)
    offset = np.concatenate([[0], np.cumsum(tracks.max(axis=0) + 1)])
    row = offset[k_idx] + tracks[t_idx, k_idx]  # one row per (camera, blob)
    A = csr_matrix((np.ones(len(t_idx)), (row, t_idx)), shape=(offset[-1], nt))
    res = milp(-weights, constraints=LinearConstraint(A, 0, 1), integrality=np.ones(nt),
               bounds=Bounds(0, 1), options={"time_limit": 30.0})
    if res.x is None:  # no solution in the time (never seen): the greedy packing, best first
        chosen, used = [], set()
        for t in np.argsort(-weights, kind="stable"):
            blobs = {(k, tracks[t, k]) for k in range(nc) if tracks[t, k] >= 0}
            if not blobs & used:
                chosen.append(t)
                used |= blobs
        return np.array(sorted(chosen), int)
    return np.flatnonzero(res.x > 0.5)


def triangulate_color_markers(rig: Rig, pairs: Mapping[str, Sequence[str]], blobs_per_camera, *,
                               light_position=None, radius_m: float = 0.005, max_epipolar_px: float | None = None,
                               confirm_px: float | None = None, merge_mm: float = 4.0,
                               max_reprojection_px: float | None = None, iterations: int = 2,
                               min_depth_m: float = 0.1, min_flux_ratio: float | None = 0.9) -> MarkerPoints:
    """3D markers from the coloured blobs of a rig's stereo pairs.

    Parameters
    ----------
    rig : Rig
    pairs : mapping of str to (camera a, camera b)
        Stereo pairs by name, e.g. ``{"left": ("left_outer", "left_inner"), ...}``.
    blobs_per_camera : sequence (rig order) or mapping (by camera name) of ColorBlobs
        Anything with ``centers`` (N, 2) and ``colours`` (N,) per camera; cameras missing from
        a mapping saw nothing.
    light_position : array_like, shape (3,), optional
        The strobe (world). Given, the half-lit centroid bias is removed
        (:func:`lit_sphere_offsets`, iterated ``iterations`` times).
    radius_m : float
        Marker radius (m).
    max_epipolar_px : float, optional
        Largest symmetric epipolar distance of a candidate pair; default 3 px at 1280 px image
        width, scaled with the width (the half-lit offsets alone make up to ~1 px at 1280).
    confirm_px : float, optional
        A candidate is confirmed in a third camera when a same-colour blob lies this close to
        its predicted centroid; default ``max_epipolar_px``.
    merge_mm : float
        Same-colour points of two pairs within this distance are one marker.
    max_reprojection_px : float, optional
        After the merge, views whose reprojection error exceeds this are dropped (consensus
        over view pairs, for points with 3+ views), and points whose RMS error still exceeds
        it are discarded; default 1 px at 1280 px width, scaled with the width.
    iterations : int
        Rounds of the bias correction (2 converge: a third changes points by < 1e-3 mm).
    min_depth_m : float
        Candidates closer to a camera than this (or behind it) are rejected.
    min_flux_ratio : float or None
        With the light given: a view whose blob holds less than this share of the light the
        lit-sphere model predicts (normalised per camera and colour by the median over the
        points) is partly hidden, its centroid shifted; it is dropped while two or more other
        views remain, and reported in :attr:`MarkerPoints.flux_ratio`. ``None``: keep all.

    Returns
    -------
    MarkerPoints
        Sorted by colour, then by the first camera's x pixel.
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig must be a Rig, got {type(rig).__name__}")
    cams = list(rig.cameras)
    nc = len(cams)
    names = rig.names
    if isinstance(blobs_per_camera, Mapping):
        unknown = set(blobs_per_camera) - set(names)
        if unknown:
            raise ValueError(f"blobs_per_camera has unknown cameras {sorted(unknown)}; rig: {names}")
        blobs = [blobs_per_camera.get(n) for n in names]
    else:
        blobs = list(blobs_per_camera)
        if len(blobs) != nc:
            raise ValueError(f"blobs_per_camera must have one entry per camera ({nc}), got {len(blobs)}")
    obs, col, flux = [], [], []
    for n, b in zip(names, blobs):
        if b is None:
            c, k, f = np.zeros((0, 2)), np.zeros(0, object), np.zeros(0)
        else:
            c, k, f = _blob_arrays(b, n)
        obs.append(c)
        col.append(k)
        flux.append(f)
    if not isinstance(pairs, Mapping) or not pairs:
        raise ValueError("pairs must be a non-empty mapping name -> (camera a, camera b)")
    pair_idx = {}
    for p, ab in pairs.items():
        if len(ab) != 2 or any(a not in names for a in ab) or ab[0] == ab[1]:
            raise ValueError(f"pair {p!r} must name two different cameras of the rig {names}, got {ab}")
        pair_idx[str(p)] = (names.index(ab[0]), names.index(ab[1]))
    light = None if light_position is None else as_array(light_position, (3,), "light_position")
    if not (np.isfinite(radius_m) and radius_m > 0):
        raise ValueError(f"radius_m must be positive, got {radius_m}")
    scale = max(c.image_size[0] for c in cams) / 1280.0
    max_epi = 3.0 * scale if max_epipolar_px is None else float(max_epipolar_px)
    conf = max_epi if confirm_px is None else float(confirm_px)
    max_rep = 1.0 * scale if max_reprojection_px is None else float(max_reprojection_px)

    # ---- 1. candidate tracks: seeds of every two cameras, with their confirmations ----------
    # every two cameras, not only the stereo pairs: one strobe lights them all, and a marker seen
    # by one camera of each pair alone was never triangulated (issue 12)
    in_pair = {frozenset(ab) for ab in pair_idx.values()}
    found, admissible = [], {}
    for a in range(nc):
        for b in range(a + 1, nc):
            if len(obs[a]) == 0 or len(obs[b]) == 0:
                continue
            t, allowed = _seed_tracks(cams, obs, col, a, b, max_epi, light, radius_m, min_depth_m, conf)
            found.append(t)
            admissible[(a, b)] = allowed
    tracks = np.unique(np.concatenate(found), axis=0) if found else np.zeros((0, nc), int)
    if len(tracks) == 0:
        return MarkerPoints.empty(names)
    x = np.full((nc, len(tracks), 2), np.nan)
    for k in range(nc):
        has = tracks[:, k] >= 0
        x[k, has] = obs[k][tracks[has, k]]
    _, _, rms, _ = _solve(cams, x, light, radius_m, 1)
    seen = tracks >= 0
    n_views = seen.sum(axis=1)
    err = rms / (0.5 * max_epi)  # two views at the epipolar tolerance: about 1
    cross = np.array([not any(ab <= set(np.flatnonzero(v)) for ab in in_pair) for v in seen])
    weights = n_views - 1.0 - RESIDUAL_PENALTY * np.nan_to_num(err, nan=np.inf) - CROSS_PAIR_PENALTY * (cross & (n_views == 2))
    feasible = (err <= 1.0) & (weights > 0)
    tracks, seen, n_views, cross, weights, rms = (v[feasible] for v in (tracks, seen, n_views, cross, weights, rms))

    # ---- 2. the heaviest set of tracks using each blob at most once --------------------------
    chosen = _pack_tracks(tracks, weights)
    if len(chosen) == 0:
        return MarkerPoints.empty(names)
    # the centroids' noise, from the capture itself: the reprojection RMS of the chosen tracks with
    # three or more views (they pass a test that two views do not); a tolerance's sixth without them
    multi_rms = rms[chosen][n_views[chosen] >= 3]
    noise_px = float(np.median(multi_rms)) if len(multi_rms) >= 5 else max_epi / 6.0
    two = n_views == 2
    # a two-view point across the pairs is what is left when each pair saw the marker once; its
    # wide baseline crosses many same-colour blobs, so it must fit within the noise (a partly hidden
    # centroid is no excuse: a stereo pair's own tolerance is for those), else packed again without it
    loose = two & cross & (rms > CROSS_PAIR_NOISE_FACTOR * noise_px)
    if light is not None and min_flux_ratio is not None:
        # ... nor a partly hidden view: its centroid moves by up to the marker's radius in pixels,
        # so the epipolar check at its own noise cannot tell a match from a chance blob on the long
        # cross-pair epipolar line (another_hand(6): two slivers of hidden markers, one in each
        # pair, met within 2.5x the noise and took a wrong label); no second pair can confirm it
        loose |= two & cross & _partly_hidden_tracks(cams, obs, flux, col, tracks, chosen, light, radius_m,
                                                     min_flux_ratio)
    if loose[chosen].any():
        keep = np.flatnonzero(~loose)
        tracks, seen, n_views, cross, weights, rms, two = (v[keep] for v in (tracks, seen, n_views, cross, weights,
                                                                             rms, two))
        chosen = _pack_tracks(tracks, weights)
    is_chosen = np.zeros(len(tracks), bool)
    is_chosen[chosen] = True
    merged = []
    for t in chosen:
        views = {int(k): int(tracks[t, k]) for k in np.flatnonzero(seen[t])}
        pn = [p for p, ab in pair_idx.items() if set(ab) <= set(views)]
        amb = False
        if len(views) == 2:  # some blob had another admissible partner, and no third view decided
            (a, ja), (b, jb) = sorted(views.items())
            amb = bool(admissible[(a, b)][ja].sum() > 1 or admissible[(a, b)][:, jb].sum() > 1)
            # across the pairs, two views and a rival that fits about as well: a coin toss, no marker
            rival = two & ~is_chosen & seen[:, a] & seen[:, b] & ((tracks[:, a] == ja) ^ (tracks[:, b] == jb))
            if not pn and np.any(rms[rival] < rms[t] + 2.0 * noise_px):
                continue
        merged.append({"views": views, "colour": col[min(views)][views[min(views)]],
                       "pairs": "+".join(sorted(pn)) or "cross", "ambiguous": bool(amb)})
    # a marker whose views the tracks split (a partly hidden view's centroid moved beyond the
    # confirmation distance): same colour, within merge_mm, no camera in common -> one marker
    if len(merged) > 1:
        P = np.array([_solve(cams, _track_pixels(obs, g["views"], nc), light, radius_m, 1)[0][0] for g in merged])
        for h in range(len(merged)):
            for g in range(h + 1, len(merged)):
                A, B = merged[h], merged[g]
                if (A["views"] and B["views"] and A["colour"] == B["colour"] and not set(A["views"]) & set(B["views"])
                        and np.linalg.norm(P[h] - P[g]) <= merge_mm / 1000.0):
                    A["views"].update(B["views"])
                    A["pairs"] = "+".join(sorted({*A["pairs"].split("+"), *B["pairs"].split("+")} - {"cross"})) or "cross"
                    A["ambiguous"] = A["ambiguous"] and B["ambiguous"]
                    B["views"] = {}
        merged = [g for g in merged if g["views"]]

    # ---- 3. final triangulation from all views, bias-corrected; drop views that disagree -----
    n = len(merged)
    x = np.full((nc, n, 2), np.nan)
    bidx = np.full((nc, n), -1)
    for m, g in enumerate(merged):
        for k, j in g["views"].items():
            x[k, m], bidx[k, m] = obs[k][j], j
    colors = np.array([g["colour"] for g in merged], dtype=object).astype(str)
    X, corr, rms, err = _solve(cams, x, light, radius_m, iterations)
    # views that disagree: consensus over view pairs (RANSAC in ``triangulate``) on the
    # corrected observations of points with 3+ views
    multi = (bidx >= 0).sum(axis=0) >= 3
    if multi.any():
        used = _consensus_views(cams, X, corr, bidx, flux, colors, multi, max_rep, radius_m, light, min_flux_ratio)
        out = (bidx[:, multi] >= 0) & ~used
        out &= used.sum(axis=0)[None] >= 2
        if out.any():
            sub_x, sub_b = x[:, multi], bidx[:, multi]
            sub_x[out], sub_b[out] = np.nan, -1
            x[:, multi], bidx[:, multi] = sub_x, sub_b
            X, corr, rms, err = _solve(cams, x, light, radius_m, iterations)
    ratio = np.full((nc, n), np.nan)
    if light is not None and min_flux_ratio is not None:
        # partly hidden blobs: less light than the lit-sphere model predicts; drop such views
        # while two or more fully seen ones remain
        ratio = _flux_ratios(cams, X, bidx, flux, colors, radius_m, light)
        low = (bidx >= 0) & ~(ratio >= min_flux_ratio)
        n_good = ((bidx >= 0) & ~low).sum(axis=0)
        drop = low & (n_good >= 2)[None]
        if drop.any():
            x[drop], bidx[drop] = np.nan, -1
            X, corr, rms, err = _solve(cams, x, light, radius_m, iterations)
    # a point whose views still disagree is no marker (two views of different markers)
    X[~(rms <= max_rep)] = np.nan
    ratio = np.where(bidx >= 0, ratio, np.nan)
    order = np.lexsort((np.nan_to_num(np.nanmin(x[..., 0], axis=0)), colors))
    ok = np.all(np.isfinite(X), axis=1)[order]
    order = order[ok]
    return MarkerPoints(X[order], colors[order], (bidx[:, order] >= 0).sum(axis=0), rms[order], x[:, order],
                        bidx[:, order], np.array([merged[m]["pairs"] for m in order]).astype(str),
                        np.array([merged[m]["ambiguous"] for m in order], bool), names, light is not None,
                        ratio[:, order])
