"""Puppet beads in photos (SPEC J3): find and name them, judge how whole each looks, and name
them again after the 3D markers. Stages of :mod:`stillcap.pipelines.puppet`, which wires them.

- :func:`detect_beads`: bead candidates (:func:`stillcap.detect.circles.find_circles`) in the
  photo's bright region (:func:`bright_region`), named by colour
  (:func:`stillcap.detect.identify.identify_markers`).
- :func:`bead_fill`: the share of a bead's expected disc that looks like bead. A bead partly
  hidden behind a limb is centred on its visible part, 1-3 px off its true centre; the pipeline
  leaves such views out of the triangulation while whole ones remain.
- :func:`reidentify`: each view's candidates named after the projected 3D markers (colour as a
  check): the identification consistent with the reconstruction.

Pixels ``(x, y)``, origin at the centre of the top-left pixel (``docs/conventions.md``); see
``docs/puppet.md`` and ``docs/puppet-detection.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from stillcap.camera import Rig
from stillcap.detect.circles import Circles, find_circles
from stillcap.detect.identify import RECOMMENDED, THESIS, Identification, identify_markers
from stillcap.detect.palette import Palette

__all__ = ["DETECTORS", "IDENTIFIERS", "ViewResult", "detect_beads", "bright_region", "bead_fill", "bead_fill_views", "reidentify",
           "expected_radius_px", "roi_box"]

#: Bead detectors (:func:`stillcap.detect.circles.find_circles` methods) the puppet pipeline offers.
DETECTORS = ("template", "thesis", "hough", "blobs", "cv2")
#: Identification presets (:mod:`stillcap.detect.identify`).
IDENTIFIERS = {"recommended": RECOMMENDED, "thesis": THESIS}


@dataclass(eq=False)
class ViewResult:
    """Detection and identification in one photo.

    Attributes
    ----------
    circles : Circles
        Bead candidates.
    identification : Identification
        Which candidate is which marker (palette order).
    time_s : float
        Detection + identification time.
    """

    circles: Circles
    identification: Identification
    time_s: float = 0.0


def detect_beads(image, palette: Palette, detector: str = "template", identify: str = "recommended",
                 radius_range=(5.0, 7.0), n_circles: int = 16, roi: bool = True, coarse: bool = True,
                 region=None) -> ViewResult:
    """Find the bead candidates in one photo and name them by colour.

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
        BGR photo.
    palette : Palette
        Reference colours, in marker-set order.
    detector : str
        :func:`~stillcap.detect.circles.find_circles` method (:data:`DETECTORS`).
    identify : str
        :data:`IDENTIFIERS` preset: ``"recommended"`` or ``"thesis"``.
    radius_range : (float, float)
        Bead radius in the photo, pixels.
    n_circles : int
        Candidates per photo.
    roi : bool
        Detect only inside :func:`bright_region` (the same beads, faster).
    coarse : bool
        Template detector: the contrast map's peaks at half resolution, each then climbed to
        its full-resolution maximum (``find_circles(coarse=True)``; faster, see
        ``docs/puppet-detection.md``); False: the full-resolution map everywhere.
    region : (int, int, int, int), optional
        With ``roi``: this photo's :func:`roi_box` if already computed (e.g. on another thread
        while the previous photo is detected); default computed here.
    """
    if detector not in DETECTORS:
        raise ValueError(f"unknown detector {detector!r}; choose one of {', '.join(DETECTORS)}")
    if identify not in IDENTIFIERS:
        raise ValueError(f"unknown identification {identify!r}; choose one of {', '.join(IDENTIFIERS)}")
    t0 = time.perf_counter()
    img = np.asarray(image)
    x0 = y0 = 0
    if roi:
        x0, y0, x1, y1 = roi_box(img, radius_range) if region is None else (int(v) for v in region)
        img = img[y0:y1, x0:x1]
    circles = find_circles(img, n=n_circles, radius_range=radius_range, method=detector, coarse=coarse)
    if x0 or y0:
        circles = Circles(circles.centers + [x0, y0], circles.radii, circles.scores, circles.method, circles.threshold)
    ident = identify_markers(image, circles, palette, **IDENTIFIERS[identify])
    return ViewResult(circles, ident, time.perf_counter() - t0)


def roi_box(image, radius_range=(5.0, 7.0)) -> tuple[int, int, int, int]:
    """The part of a photo :func:`detect_beads` searches with ``roi``: :func:`bright_region`
    grown by the largest bead radius + 6 px."""
    return bright_region(image, margin=int(np.ceil(radius_range[1])) + 6)


def bright_region(image, margin: int = 13, contrast: float = 15.0) -> tuple[int, int, int, int]:
    """Bounding box ``(x0, y0, x1, y1)`` (pixels, end exclusive) of everything brighter than the
    photo's median grey by ``contrast`` levels (after a 3x3 erosion against noise), grown by
    ``margin``; the whole photo when nothing is. The beads are the brightest things in the dark
    scene, and the template detector's own contrast floor is 15 grey levels, so no bead it could
    find lies outside."""
    img = np.asarray(image)
    g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    h, w = g.shape
    med = float(np.median(g[::4, ::4]))
    mask = cv2.erode((g > med + contrast).astype(np.uint8), np.ones((3, 3), np.uint8))
    # cv2.boundingRect of the mask image itself (its non-zero pixels): the box findNonZero's
    # point list gives, without building the list
    x, y, bw, bh = cv2.boundingRect(mask)
    if bw == 0 or bh == 0:
        return 0, 0, w, h
    return max(0, x - margin), max(0, y - margin), min(w, x + bw + margin), min(h, y + bh + margin)


def bead_fill(image, centers, radii_px) -> np.ndarray:
    """Share of each bead's expected disc that looks like bead, in [0, 1] (NaN where unknown).

    For each centre: the background is the median grey of the ring ``r + 1.5 .. r + 3.5`` px,
    the bead level the 90th percentile within ``r / 2``; the fill is the share of pixels within
    ``r`` brighter than halfway between them. A whole bead gives about 0.75-0.9 (its shaded rim
    is darker), one half hidden behind a limb about 0.4.

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
        The photo (BGR or grey).
    centers : array_like, shape (N, 2)
        Bead centres (x, y), pixels; NaN rows give NaN.
    radii_px : array_like, shape (N,)
        Expected bead radius in this photo, pixels.
    """
    c = np.asarray(centers, float).reshape(-1, 2)
    return bead_fill_views([image], c[None], np.broadcast_to(np.asarray(radii_px, float), (len(c),))[None])[0]


def bead_fill_views(images, centers, radii_px) -> np.ndarray:
    """:func:`bead_fill` of several photos at once (one set of array operations for all their
    beads; the pipeline fills every identified bead of every view).

    Parameters
    ----------
    images : sequence of n_views images, each shape (H, W, 3) or (H, W)
    centers : array_like, shape (n_views, N, 2)
        NaN rows give NaN.
    radii_px : array_like, shape (n_views, N)

    Returns
    -------
    ndarray, shape (n_views, N)
    """
    images = [np.asarray(im) for im in images]
    for img in images:
        if img.ndim not in (2, 3):
            raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
    c_all = np.asarray(centers, float)
    if c_all.ndim != 3 or c_all.shape[0] != len(images) or c_all.shape[2] != 2:
        raise ValueError(f"centers must have shape ({len(images)}, N, 2), got {c_all.shape}")
    r_all = np.broadcast_to(np.asarray(radii_px, float), c_all.shape[:2])
    out = np.full(c_all.shape[:2], np.nan)
    with np.errstate(invalid="ignore"):
        live = np.all(np.isfinite(c_all), axis=2) & np.isfinite(r_all) & (r_all > 0)
    if not live.any():
        return out
    vi, mi = np.nonzero(live)
    c, r = c_all[vi, mi], r_all[vi, mi]
    # All beads at once over one window size (a loop over beads cost ~0.3 ms each, and the fill
    # runs for every identified bead of every view). Each bead's pixels are those of its own
    # box ``round(centre) +- ceil(r + 4)`` inside its photo; its ring, core and disc lie inside
    # that box, so a common larger window with the same masks gives the same sets.
    half = int(math.ceil(r.max() + 4))
    off = np.arange(-half, half + 1)
    S = len(off)
    ci = np.round(c).astype(int)
    xs = (ci[:, 0, None] + off[None])[:, None, :]  # (n, 1, S)
    ys = (ci[:, 1, None] + off[None])[:, :, None]  # (n, S, 1)
    R = np.ceil(r + 4).astype(int)[:, None, None]
    hw = np.array([im.shape[:2] for im in images])[vi]
    h, w = hw[:, 0, None, None], hw[:, 1, None, None]
    valid = ((xs >= 0) & (xs < w) & (ys >= 0) & (ys < h) & (np.abs(xs - ci[:, 0, None, None]) <= R)
             & (np.abs(ys - ci[:, 1, None, None]) <= R))
    patch = np.empty((len(c), S, S))
    for v in np.unique(vi):  # gather each photo's windows
        sel = vi == v
        img = images[v]
        hh, ww = img.shape[:2]
        idx = (np.clip(ys[sel], 0, hh - 1) * ww + np.clip(xs[sel], 0, ww - 1)).ravel()
        if img.ndim == 2:
            p = img.ravel()[idx].astype(float)
        elif img.dtype == np.uint8:
            # (R + G + B) / 3, as the thesis's grey image: channel by channel in integers from
            # the flat pixel index (the same values as a float mean over the channels, 4x faster
            # than gathering (n, S, S, 3) windows and averaging them)
            flat_img = img.reshape(-1, img.shape[2])
            acc = flat_img[idx, 0].astype(np.int32)
            for ch in range(1, img.shape[2]):
                acc += flat_img[idx, ch]
            p = acc / img.shape[2]
        else:
            p = img.reshape(-1, img.shape[2])[idx].astype(float).mean(axis=1)
        patch[sel] = p.reshape(-1, S, S)
    rr = np.hypot(xs - c[:, 0, None, None], ys - c[:, 1, None, None])
    rb = r[:, None, None]
    ring = valid & (rr > rb + 1.5) & (rr < rb + 3.5)
    core = valid & (rr < 0.5 * rb)
    disc = valid & (rr <= rb)
    n_ring, n_core, n_disc = (m.sum(axis=(1, 2)) for m in (ring, core, disc))
    ok = (n_ring > 0) & (n_core > 0) & (n_disc > 0)
    flat = patch.reshape(len(c), -1)
    rows = np.arange(len(c))
    # Only the window cells that can be in some bead's ring (core) are sorted: a centre lies
    # within 0.5 px of its rounded pixel in x and y, so a cell at offset |o| from that pixel is
    # |o| +- 0.71 px from the centre; cells outside those radii are in no bead's mask, and
    # leaving them out keeps the same member sets (the window has ~4x more cells than a ring).
    o = np.hypot(off[:, None], off[None, :]).ravel()
    in_ring = np.flatnonzero((o > r.min() + 1.5 - 0.75) & (o < r.max() + 3.5 + 0.75))
    in_core = np.flatnonzero(o < 0.5 * r.max() + 0.75)
    # masked median and 90th percentile by sorting (non-members last), as np.median and
    # np.percentile(..., 90) (linear interpolation, numpy's own lerp) of each bead's pixels
    srt = np.sort(np.where(ring.reshape(len(c), -1)[:, in_ring], flat[:, in_ring], np.inf), axis=1)
    lo_, hi_ = np.maximum((n_ring - 1) // 2, 0), np.maximum(n_ring // 2, 0)
    bg = (srt[rows, lo_] + srt[rows, hi_]) / 2
    srt = np.sort(np.where(core.reshape(len(c), -1)[:, in_core], flat[:, in_core], np.inf), axis=1)
    q = 0.9 * (np.maximum(n_core, 1) - 1)
    i0 = np.floor(q).astype(int)
    i1 = np.minimum(i0 + 1, np.maximum(n_core - 1, 0))
    g = q - i0
    a0, a1 = srt[rows, i0], srt[rows, i1]
    with np.errstate(invalid="ignore"):
        d = a1 - a0
        peak = np.where(g >= 0.5, a1 - d * (1 - g), a0 + d * g)
        thr = bg + 0.5 * (peak - bg)
        fill = (disc & (patch > thr[:, None, None])).sum(axis=(1, 2)) / np.maximum(n_disc, 1)
    fill = np.where(peak <= bg, 0.0, fill)
    out[vi[ok], mi[ok]] = fill[ok]
    return out


def expected_radius_px(rig: Rig, points: np.ndarray, bead_radius_m: float) -> np.ndarray:
    """Projected bead radius per view and marker, ``f * R / depth`` pixels, shape (n_views, n_markers)."""
    out = np.full((len(rig), len(points)), np.nan)
    for v, cam in enumerate(rig):
        z = (points @ cam.R.T + cam.t)[:, 2]
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            out[v] = np.where(z > 0, f * bead_radius_m / z, np.nan)
    return out


def reidentify(rig: Rig, points_3d, views: Sequence[ViewResult], bead_radius_m: float = 0.003,
               gate_radius: float = 0.6, colour_factor: float = 2.0) -> np.ndarray:
    """Name each view's bead candidates after the 3D markers: the identification consistent
    with the reconstruction.

    Colour alone names a few percent of the beads wrong (a bead partly hidden, its colour
    shifted by the light, a limb edge), and misses some. Once the markers are triangulated,
    every marker with a 3D point projects into every view: the candidate within
    ``gate_radius`` x its projected bead radius (at least 2 px) of that projection, and whose
    colour is within ``colour_factor`` x the identification's acceptance distance of the
    marker's reference, is that marker (:func:`scipy.optimize.linear_sum_assignment` over
    pixel distance / gate + colour distance / colour gate, each candidate used once); a marker
    whose projection matches no candidate is left unidentified (hidden in that view). Markers
    without a 3D point keep their colour identification where its candidate is not taken.

    Parameters
    ----------
    rig : Rig, n_views cameras
    points_3d : array_like, shape (n_markers, 3)
        Triangulated markers, NaN where missing.
    views : sequence of ViewResult, length n_views
        Candidates and colour distances (:func:`detect_beads`).
    bead_radius_m : float
    gate_radius, colour_factor : float
        Pixel gate as a share of the projected bead radius; colour gate as a multiple of the
        identification's ``max_distance``.

    Returns
    -------
    ndarray, shape (n_views, n_markers, 2)
        Pixels of the final identification, NaN where unidentified.
    """
    from scipy.optimize import linear_sum_assignment

    X = np.asarray(points_3d, float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"points_3d must have shape (n_markers, 3), got {X.shape}")
    if len(views) != len(rig):
        raise ValueError(f"need one ViewResult per view ({len(rig)}), got {len(views)}")
    k = len(X)
    have = np.all(np.isfinite(X), axis=1)
    r_exp = expected_radius_px(rig, np.where(have[:, None], X, 0.0), bead_radius_m)
    out = np.full((len(rig), k, 2), np.nan)
    for v, (cam, vr) in enumerate(zip(rig, views)):
        ident = vr.identification
        cand = np.asarray(vr.circles.centers, float).reshape(-1, 2)
        if ident.points.shape[0] != k:
            raise ValueError(f"view {v}: identification has {ident.points.shape[0]} markers, points_3d {k}")
        taken = np.zeros(len(cand), bool)
        if len(cand) and have.any():
            proj = cam.project(np.where(have[:, None], X, np.nan))
            d = np.linalg.norm(cand[:, None, :] - proj[None], axis=2)  # (n_cand, k)
            gate = np.maximum(2.0, gate_radius * r_exp[v])[None]
            cgate = colour_factor * float(ident.max_distance)
            col = np.asarray(ident.cost, float).reshape(len(cand), k)
            with np.errstate(invalid="ignore"):
                ok = (d <= gate) & (col <= cgate) & have[None]
            if ok.any():
                cost = np.where(ok, d / gate + col / cgate, 1e6)
                rows, cols = linear_sum_assignment(cost)
                good = ok[rows, cols]
                out[v, cols[good]] = cand[rows[good]]
                taken[rows[good]] = True
        # markers without 3D: the colour's choice, unless a 3D-consistent marker took its candidate
        for m in np.flatnonzero(~have & (ident.candidate >= 0)):
            c = int(ident.candidate[m])
            if c < len(cand) and not taken[c]:
                out[v, m] = ident.points[m]
    return out
