"""3D points of coloured markers seen by stereo pairs, with the half-lit centroid bias removed.

Two parts:

- **Lit-sphere centroids** (:func:`lit_sphere_samples`, :func:`lit_sphere_centroids`,
  :func:`lit_sphere_offsets`): a lambertian sphere lit by a point light appears as a partly lit
  disc (a half moon when the light is to the side); the radiance-weighted centroid of its image
  is not the projection of its centre. The model projects evenly spread surface points, each
  weighted by ``max(n.l, 0) / d_light^2`` times its foreshortening toward the camera (visible
  side only). The studio's truth (:func:`stillcap.studio.hand.lit_centroids`) is this model
  plus occlusion by other bodies.
- **Triangulation** (:func:`triangulate_color_markers`): per stereo pair, every same-colour
  blob pair near each other's epipolar line is a candidate; each candidate is triangulated and
  checked in the other cameras (a same-colour blob where it should appear confirms it); an
  optimal one-to-one assignment (``scipy.optimize.linear_sum_assignment``, with the option of
  leaving a blob unmatched) prefers confirmed, close candidates. The points of both pairs that
  share a blob, or have the same colour and lie within ``merge_mm``, are one marker,
  re-triangulated from all its views. With the light's position the half-lit bias is removed by
  iteration: triangulate, predict each view's centroid offset at the point, subtract, again.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

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
        The stereo pair(s) whose matching made the point, ``"left"``, ``"right"`` or
        ``"left+right"`` (merged).
    ambiguous : ndarray of bool, shape (N,)
        Some blob of the point had another same-colour candidate within the epipolar tolerance
        and the choice was not confirmed by a third view.
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


def _assign_pair(pname, cand, obs, col, max_epi, vetoed) -> list:
    """One stereo pair's optimal one-to-one matches (``linear_sum_assignment``): cost in [0, 1]
    from the epipolar distance, minus one per confirmation not ``vetoed``; leaving a blob
    unmatched costs 0.5 (so an admissible unconfirmed pair beats leaving both blobs alone, and
    a confirmed pair beats any unconfirmed one)."""
    a, b, ia, ib, X, ok, d, extra = cand
    hits = {k: np.array([jj[q] if (pname, q, k) not in vetoed else -1 for q in range(len(ia))], int)
            for k, jj in extra.items()}
    support = np.zeros(len(ia))
    for jj in hits.values():
        support += jj >= 0
    na, nb = len(obs[a]), len(obs[b])
    cost_pairs = d[ia, ib] / max_epi - support
    big = 1e6
    C = np.full((na + nb, nb + na), big)
    C[ia[ok], ib[ok]] = cost_pairs[ok]
    C[np.arange(na), nb + np.arange(na)] = 0.5
    C[na + np.arange(nb), np.arange(nb)] = 0.5
    C[na:, nb:] = 0.0
    rows, cols_ = linear_sum_assignment(C)
    index = {(i, j): q for q, (i, j) in enumerate(zip(ia, ib))}
    count_a = np.bincount(ia[ok], minlength=na)
    count_b = np.bincount(ib[ok], minlength=nb)
    out = []
    for r, c_ in zip(rows, cols_):
        if r >= na or c_ >= nb or C[r, c_] >= big:
            continue
        q = index[(r, c_)]
        views = {a: int(r), b: int(c_)}
        for k, jj in hits.items():
            if jj[q] >= 0:
                views[k] = int(jj[q])
        amb = (count_a[r] > 1 or count_b[c_] > 1) and support[q] == 0
        out.append({"views": views, "pair": pname, "ambiguous": bool(amb), "colour": col[a][r],
                    "point": X[q], "support": support[q], "epi": d[r, c_], "cand": q})
    return out


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

    # ---- 1. candidates per pair, triangulated and checked in the other cameras ----------------
    cands = {}
    for pname, (a, b) in pair_idx.items():
        if len(obs[a]) == 0 or len(obs[b]) == 0:
            continue
        d = epipolar_distances(cams[a], cams[b], obs[a], obs[b])
        allowed = np.isfinite(d) & (d <= max_epi) & (col[a][:, None] == col[b][None, :])
        ia, ib = np.nonzero(allowed)
        if len(ia) == 0:
            continue
        x2 = np.full((nc, len(ia), 2), np.nan)
        x2[a], x2[b] = obs[a][ia], obs[b][ib]
        X, _, _, _ = _solve(cams, x2, light, radius_m, 1)  # one round: enough to tell candidates apart
        ok = np.all(np.isfinite(X), axis=1)
        for k in (a, b):
            z = cams[k].world_to_cam(np.where(ok[:, None], X, 0.0))[:, 2]
            ok &= z > min_depth_m
        # confirmation: a same-colour blob at the predicted centroid in each other camera
        extra = {}
        for k in range(nc):
            if k in (a, b) or len(obs[k]) == 0 or not ok.any():
                continue
            pred = np.full((len(ia), 2), np.nan)
            pred[ok] = cams[k].project(X[ok])
            if light is not None:
                pred[ok] += np.nan_to_num(lit_sphere_offsets(cams[k], X[ok], radius_m, light))
            dist = np.linalg.norm(pred[:, None] - obs[k][None], axis=2)
            dist = np.where(col[a][ia][:, None] == col[k][None, :], dist, np.inf)
            j = np.argmin(dist, axis=1)
            extra[k] = np.where(ok & (dist[np.arange(len(ia)), j] <= conf), j, -1)
        cands[pname] = (a, b, ia, ib, X, ok, d, extra)

    # ---- 1b. assignment per pair, again while a confirmation proves coincidental --------------
    # A confirming blob that the other pair matched directly into a different 3D point (farther
    # than merge_mm) belongs to another marker: the confirmation was a coincidence. It no longer
    # counts, and the pairs are assigned again, so that a coincidental blob cannot make a wrong
    # match win over the right one (issue 12: a flash lost to matching).
    vetoed = set()  # (pair, candidate, camera)
    for _ in range(4):
        hyps = [h for pname, c in cands.items() for h in _assign_pair(pname, c, obs, col, max_epi, vetoed)]
        direct = {}
        for h in hyps:
            for k in pair_idx[h["pair"]]:
                direct[(k, h["views"][k])] = h
        new = set()
        for h in hyps:
            own = {(k, h["views"][k]) for k in pair_idx[h["pair"]]}
            for k, j in h["views"].items():
                g = direct.get((k, j))
                if k in pair_idx[h["pair"]] or g is None or np.linalg.norm(g["point"] - h["point"]) <= merge_mm / 1000.0:
                    continue
                # the other pair's point holds the blob; it is the blob's marker only when a view
                # of this pair confirms it elsewhere than this match's own blobs
                if any(kk in pair_idx[h["pair"]] and (kk, jj) not in own for kk, jj in g["views"].items()):
                    new.add((h["pair"], h["cand"], k))
        if new <= vetoed:
            break
        vetoed |= new
    if not hyps:
        return MarkerPoints.empty(names)

    # ---- 2. merge the pairs' points: shared blobs, or same colour and close -------------------
    parent = list(range(len(hyps)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner = {}
    for h, hy in enumerate(hyps):
        for k, j in hy["views"].items():
            if (k, j) in owner:
                parent[find(h)] = find(owner[(k, j)])
            else:
                owner[(k, j)] = h
    P = np.array([hy["point"] for hy in hyps])
    for h in range(len(hyps)):
        for g in range(h + 1, len(hyps)):
            if (hyps[h]["pair"] != hyps[g]["pair"] and hyps[h]["colour"] == hyps[g]["colour"]
                    and np.linalg.norm(P[h] - P[g]) <= merge_mm / 1000.0):
                parent[find(g)] = find(h)
    groups = {}
    for h in range(len(hyps)):
        groups.setdefault(find(h), []).append(h)

    # one blob per camera per group (the one most members vote for, then the best-supported);
    # a blob claimed by two groups goes to the group that made it in its own pair
    merged = []
    for members in groups.values():
        views = {}
        for k in range(nc):
            votes = {}
            for h in members:
                j = hyps[h]["views"].get(k)
                if j is not None:
                    direct = k in pair_idx[hyps[h]["pair"]]
                    votes[j] = votes.get(j, 0) + (2 if direct else 1) + 0.1 * hyps[h]["support"]
            if votes:
                views[k] = max(votes, key=votes.get)
        merged.append({"views": views, "colour": hyps[members[0]]["colour"],
                       "pairs": "+".join(sorted({hyps[h]["pair"] for h in members})),
                       "ambiguous": all(hyps[h]["ambiguous"] for h in members),
                       "direct": {k for h in members for k in pair_idx[hyps[h]["pair"]]}})
    claims = {}
    for m, g in enumerate(merged):
        for k, j in g["views"].items():
            claims.setdefault((k, j), []).append(m)
    for (k, j), ms in claims.items():
        if len(ms) < 2:
            continue
        keep = [m for m in ms if k in merged[m]["direct"]] or ms
        keep = max(keep, key=lambda m: len(merged[m]["views"]))
        for m in ms:
            if m != keep:
                merged[m]["views"].pop(k, None)
    merged = [g for g in merged if len(g["views"]) >= 2]
    if not merged:
        return MarkerPoints.empty(names)

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
        tri = triangulate(cams, corr[:, multi], outlier_px=max_rep)
        out = (bidx[:, multi] >= 0) & ~tri.used
        out &= tri.used.sum(axis=0)[None] >= 2
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
