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
from stillcap.detect.circles import Circles, TemplateInputs, find_circles, prepare_template, refine_bead_centers_views
from stillcap.detect.circles._thesis import _channel_sum
from stillcap.detect.identify import (RECOMMENDED, THESIS, Identification, identify_markers,
                                      identify_markers_views)
from stillcap.detect.palette import Palette

__all__ = ["DETECTORS", "IDENTIFIERS", "ViewResult", "PreparedView", "detect_beads", "find_bead_candidates",
           "refine_bead_candidates", "identify_views", "prepare_view", "bright_region", "bead_fill", "bead_fill_views",
           "bead_contrast_views", "reidentify", "one_name_per_bead", "REID_CONTRAST_SHARE",
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


@dataclass(eq=False)
class PreparedView:
    """The photo-wide part of :func:`detect_beads` (:func:`prepare_view`), made before the
    detection proper, e.g. on another thread.

    Attributes
    ----------
    region : (int, int, int, int) or None
        :func:`roi_box` of the photo (None without ``roi``).
    template : TemplateInputs or None
        :func:`~stillcap.detect.circles.prepare_template` of the searched part of the photo
        (None for the other detectors).
    """

    region: tuple | None
    template: TemplateInputs | None = None


def prepare_view(image, detector: str = "template", radius_range=(5.0, 7.0), roi: bool = True,
                 coarse: bool = True) -> PreparedView:
    """What :func:`detect_beads` computes over the whole photo before it looks at candidates:
    the bright region (``roi``) and, for the template detector, the grey image, its median and
    the half-resolution contrast map. These are OpenCV calls and large NumPy operations that
    release the GIL, so :func:`~stillcap.pipelines.puppet.analyse_puppet` makes them on its
    decoding thread while the previous photo is detected. Pass the result to
    :func:`detect_beads` as ``prepared`` with the same settings: the same result as without it."""
    img = np.asarray(image)
    region = roi_box(img, radius_range) if roi else None
    template = None
    if detector == "template":
        sub = img if region is None else img[region[1]:region[3], region[0]:region[2]]
        template = prepare_template(sub, radius_range, coarse)
    return PreparedView(region, template)


def detect_beads(image, palette: Palette, detector: str = "template", identify: str = "recommended",
                 radius_range=(5.0, 7.0), n_circles: int = 16, roi: bool = True, coarse: bool = True,
                 region=None, prepared: PreparedView | None = None) -> ViewResult:
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
    prepared : PreparedView, optional
        :func:`prepare_view` of this photo with the same ``detector``, ``radius_range``,
        ``roi`` and ``coarse`` (its region replaces ``region``).
    """
    if detector not in DETECTORS:
        raise ValueError(f"unknown detector {detector!r}; choose one of {', '.join(DETECTORS)}")
    if identify not in IDENTIFIERS:
        raise ValueError(f"unknown identification {identify!r}; choose one of {', '.join(IDENTIFIERS)}")
    t0 = time.perf_counter()
    circles = find_bead_candidates(image, detector, radius_range, n_circles, roi, coarse, region, prepared)
    ident = identify_markers(image, circles, palette, **IDENTIFIERS[identify])
    return ViewResult(circles, ident, time.perf_counter() - t0)


def find_bead_candidates(image, detector: str = "template", radius_range=(5.0, 7.0), n_circles: int = 16,
                         roi: bool = True, coarse: bool = True, region=None,
                         prepared: PreparedView | None = None, refine: bool = True) -> Circles:
    """The first half of :func:`detect_beads`: the bead candidates of one photo (whole-photo
    pixels), not yet named. Parameters as :func:`detect_beads`'s; ``refine=False`` leaves out
    the sub-pixel refinement of the centres (:func:`refine_bead_candidates` then refines
    several photos' candidates together)."""
    if detector not in DETECTORS:
        raise ValueError(f"unknown detector {detector!r}; choose one of {', '.join(DETECTORS)}")
    img = np.asarray(image)
    x0 = y0 = 0
    pre = None
    if prepared is not None:
        if roi != (prepared.region is not None) or (detector == "template") != (prepared.template is not None):
            raise ValueError(f"prepared view (region: {prepared.region is not None}, template inputs: "
                             f"{prepared.template is not None}) does not fit roi={roi}, detector={detector!r}")
        region, pre = prepared.region, prepared.template
    if roi:
        x0, y0, x1, y1 = roi_box(img, radius_range) if region is None else (int(v) for v in region)
        img = img[y0:y1, x0:x1]
    circles = find_circles(img, n=n_circles, radius_range=radius_range, method=detector, coarse=coarse,
                           prepared=pre, refine=None if refine else False)
    if x0 or y0:
        circles = Circles(circles.centers + [x0, y0], circles.radii, circles.scores, circles.method, circles.threshold)
    return circles


def refine_bead_candidates(candidates: Sequence[Circles], prepared: Sequence[PreparedView]) -> list:
    """Several photos' template candidates found with ``find_bead_candidates(..., refine=False)``
    and their :func:`prepare_view`, refined together: the centres
    ``find_bead_candidates(..., refine=True)`` gives on each photo
    (:func:`~stillcap.detect.circles.refine_bead_centers_views`, one set of array operations for
    all photos' beads).

    Parameters
    ----------
    candidates : sequence of Circles
        Each photo's unrefined candidates (whole-photo pixels; the template detector's centres
        are whole pixels, so moving them into the searched region and back is exact).
    prepared : sequence of PreparedView
        Each photo's :func:`prepare_view` with the template detector.

    Returns
    -------
    list of Circles
    """
    if len(candidates) != len(prepared):
        raise ValueError(f"need one prepared view per photo's candidates ({len(candidates)}), got {len(prepared)}")
    if any(p.template is None for p in prepared):
        raise ValueError("refine_bead_candidates needs the template detector's prepared views (prepare_view with "
                         "detector='template')")
    offsets = [np.zeros(2) if p.region is None else np.array(p.region[:2], float) for p in prepared]
    centers = refine_bead_centers_views([p.template.grey for p in prepared],
                                        [c.centers - o for c, o in zip(candidates, offsets)],
                                        [c.radii for c in candidates], backgrounds=[p.template.median for p in prepared])
    return [Circles(x + o if o.any() else x, c.radii, c.scores, c.method, c.threshold)
            for c, x, o in zip(candidates, centers, offsets)]


def identify_views(images, candidates: Sequence[Circles], palette: Palette, identify: str = "recommended") -> list:
    """The second half of :func:`detect_beads` for several photos at once: each photo's
    candidates named by colour (:func:`~stillcap.detect.identify.identify_markers_views`: the
    same identification per photo as :func:`detect_beads`'s, faster).

    Parameters
    ----------
    images : sequence of BGR photos
    candidates : sequence of Circles
        :func:`find_bead_candidates` of each photo.
    palette : Palette
    identify : str
        :data:`IDENTIFIERS` preset.

    Returns
    -------
    list of Identification
    """
    if identify not in IDENTIFIERS:
        raise ValueError(f"unknown identification {identify!r}; choose one of {', '.join(IDENTIFIERS)}")
    return identify_markers_views(images, candidates, palette, **IDENTIFIERS[identify])


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
    sub = g[::4, ::4]
    if sub.dtype == np.uint8 and sub.size:
        # np.median's value from a histogram (the mean of the two middle values), ~3x faster
        # than partitioning; and the mask with cv2.threshold (``g > t`` for uint8, ~10x faster
        # than the comparison and the cast, and it releases the GIL)
        n = sub.size
        cum = np.cumsum(np.bincount(sub.ravel(), minlength=256))
        lo, hi = np.searchsorted(cum, [(n - 1) // 2, n // 2], side="right")
        med = (float(lo) + float(hi)) / 2
        mask = cv2.threshold(g, med + contrast, 1, cv2.THRESH_BINARY)[1]
    else:
        med = float(np.median(sub))
        mask = (g > med + contrast).astype(np.uint8)
    mask = cv2.erode(mask, np.ones((3, 3), np.uint8))
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
    return _bead_levels(images, centers, radii_px)[0]


def bead_contrast_views(images, centers, radii_px) -> np.ndarray:
    """How far each bead stands out from its surroundings, grey levels, shape (n_views, N) (NaN
    where unknown): :func:`bead_fill`'s bead level (90th percentile within ``r / 2``) minus its
    background (median of the ring ``r + 1.5 .. r + 3.5`` px). A lit bead is several tens of
    grey levels brighter than the limb or backdrop around it; a dim patch of a limb that only
    happens to lie where a hidden bead would be is not. Arguments as :func:`bead_fill_views`."""
    return _bead_levels(images, centers, radii_px)[1]


def _bead_levels(images, centers, radii_px) -> tuple[np.ndarray, np.ndarray]:
    """:func:`bead_fill_views` and :func:`bead_contrast_views` from one pass over the windows."""
    images = [np.asarray(im) for im in images]
    for img in images:
        if img.ndim not in (2, 3):
            raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
    c_all = np.asarray(centers, float)
    if c_all.ndim != 3 or c_all.shape[0] != len(images) or c_all.shape[2] != 2:
        raise ValueError(f"centers must have shape ({len(images)}, N, 2), got {c_all.shape}")
    r_all = np.broadcast_to(np.asarray(radii_px, float), c_all.shape[:2])
    out = np.full(c_all.shape[:2], np.nan)
    contrast = np.full(c_all.shape[:2], np.nan)
    with np.errstate(invalid="ignore"):
        live = np.all(np.isfinite(c_all), axis=2) & np.isfinite(r_all) & (r_all > 0)
    if not live.any():
        return out, contrast
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
    # the window's columns and rows inside the photo and the bead's box, each on its own axis
    valid = (((ys >= 0) & (ys < h) & (np.abs(ys - ci[:, 1, None, None]) <= R))
             & ((xs >= 0) & (xs < w) & (np.abs(xs - ci[:, 0, None, None]) <= R)))
    patch = np.empty((len(c), S, S))
    # vi is sorted (np.nonzero in row order): each photo's beads are one slice
    starts = np.searchsorted(vi, np.arange(len(images) + 1))
    # the windows wholly inside their photo (their corners in every photo's range at once)
    wy_all, wx_all = ys[:, 0, 0], xs[:, 0, 0]  # window corners
    inner_all = (wy_all >= 0) & (wx_all >= 0) & (wy_all <= hw[:, 0] - S) & (wx_all <= hw[:, 1] - S)
    for v in np.flatnonzero(np.diff(starts)).tolist():  # gather each photo's windows
        sel = slice(starts[v], starts[v + 1])
        img = images[v]
        hh, ww = img.shape[:2]

        def pixels(ys_, xs_, hh=hh, ww=ww):  # flat indices of windows' pixels, clipped to the photo
            return (np.minimum(np.maximum(ys_, 0), hh - 1) * ww + np.minimum(np.maximum(xs_, 0), ww - 1)).ravel()

        if img.ndim == 2:
            idx = pixels(ys[sel], xs[sel])
            p = img.ravel()[idx].astype(float)
        elif img.dtype == np.uint8:
            # (R + G + B) / 3, as the thesis's grey image: the channels summed in integers (the
            # same values as a float mean over the channels). Windows inside the photo are
            # gathered whole from a zero-copy view of all its S x S windows (~3x faster than
            # indexing every pixel; made with np.ndarray, whose call costs less than
            # as_strided's); those crossing its border from clipped pixel indices.
            wy, wx, inner = wy_all[sel], wx_all[sel], inner_all[sel]
            if inner.any():  # (none in a photo smaller than the window)
                img_c = np.ascontiguousarray(img)
                win = np.ndarray((hh - S + 1, ww - S + 1, S, S, img.shape[2]), img.dtype, img_c, 0,
                                 img_c.strides[:2] * 2 + img_c.strides[2:])
                if inner.all():
                    np.divide(_channel_sum(win[wy, wx]), img.shape[2], out=patch[sel])
                    continue
            acc = np.empty((len(wy), S, S), np.int32)
            if inner.any():
                acc[inner] = _channel_sum(win[wy[inner], wx[inner]])
            ii = pixels(ys[sel][~inner], xs[sel][~inner])
            acc[~inner] = _channel_sum(img.reshape(-1, img.shape[2])[ii]).reshape(-1, S, S)
            p = acc / img.shape[2]
        else:
            p = img.reshape(-1, img.shape[2])[pixels(ys[sel], xs[sel])].astype(float).mean(axis=1)
        patch[sel] = p.reshape(-1, S, S)
    # squared distances against squared radii (np.hypot over every window cell cost ~1 ms)
    dx, dy = xs - c[:, 0, None, None], ys - c[:, 1, None, None]
    rr2 = dx * dx + dy * dy
    rb = r[:, None, None]
    ring = valid & (rr2 > (rb + 1.5) ** 2) & (rr2 < (rb + 3.5) ** 2)
    core = valid & (rr2 < (0.5 * rb) ** 2)
    disc = valid & (rr2 <= rb * rb)
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
    contrast[vi[ok], mi[ok]] = (peak - bg)[ok]
    return out, contrast


def expected_radius_px(rig: Rig, points: np.ndarray, bead_radius_m: float) -> np.ndarray:
    """Projected bead radius per view and marker, ``f * R / depth`` pixels, shape (n_views, n_markers)."""
    if not len(rig):
        return np.full((0, len(points)), np.nan)
    # every view's depths in one stacked product (NumPy's matmul makes the same BLAS call per
    # view as ``points @ cam.R.T`` does: the same numbers; a loop over the views cost ~0.2 ms
    # per call, three or four calls per puppet capture)
    w2c = np.stack([cam.world2cam for cam in rig])
    z = (np.asarray(points, float) @ w2c[:, :3, :3].transpose(0, 2, 1) + w2c[:, None, :3, 3])[..., 2]
    K = np.stack([cam.K for cam in rig])
    f = 0.5 * (K[:, 0, 0] + K[:, 1, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(z > 0, f[:, None] * bead_radius_m / z, np.nan)


#: :func:`reidentify`: a candidate whose colour is beyond the identification's own acceptance
#: is named after a 3D marker only if it stands out from its surroundings by at least this
#: share of the view's typical bead contrast (:func:`bead_contrast_views`, median over the beads
#: whose colour agrees). Measured on 72 rendered captures of other puppets (seeds 11-22, six
#: conditions incl. blur 1.5 px, a linear response, gamma 2.6 + tone curve): right names with
#: such colours stood out by >= 0.42 of their capture's median contrast, the one wrong name (a
#: dark patch of the torso where a hidden bead projects) by 0.14-0.24.
REID_CONTRAST_SHARE = 1.0 / 3.0


def reidentify(rig: Rig, points_3d, views: Sequence[ViewResult], bead_radius_m: float = 0.003,
               gate_radius: float = 0.6, color_factor: float = 2.0, images=None,
               contrast_share: float = REID_CONTRAST_SHARE) -> np.ndarray:
    """Name each view's bead candidates after the 3D markers: the identification consistent
    with the reconstruction.

    Colour alone names a few percent of the beads wrong (a bead partly hidden, its colour
    shifted by the light, a limb edge), and misses some. Once the markers are triangulated,
    every marker with a 3D point projects into every view: the candidate within
    ``gate_radius`` x its projected bead radius (at least 2 px) of that projection, and whose
    colour is within ``color_factor`` x the identification's acceptance distance of the
    marker's reference, is that marker (:func:`scipy.optimize.linear_sum_assignment` over
    pixel distance / gate + colour distance / colour gate, each candidate used once); a marker
    whose projection matches no candidate is left unidentified (hidden in that view). Markers
    without a 3D point keep their colour identification where its candidate is not taken and
    does not lie on another marker's projected bead (within its projected radius: that bead
    partly hidden, its visible sliver's centre outside the pixel gate).

    With ``images``, a candidate named only thanks to the wider colour gate (its colour distance
    beyond the identification's ``max_distance``) must also look like a lit bead: its contrast
    (:func:`bead_contrast_views`) at least ``contrast_share`` x the median contrast of the
    view's named beads whose colour agrees; otherwise the marker stays unidentified there (a
    bead hidden behind a limb projects onto the limb, whose shading can hold a faint candidate
    of a nearby colour).

    Parameters
    ----------
    rig : Rig, n_views cameras
    points_3d : array_like, shape (n_markers, 3)
        Triangulated markers, NaN where missing.
    views : sequence of ViewResult, length n_views
        Candidates and colour distances (:func:`detect_beads`).
    bead_radius_m : float
    gate_radius, color_factor : float
        Pixel gate as a share of the projected bead radius; colour gate as a multiple of the
        identification's ``max_distance``.
    images : sequence of n_views images, optional
        The photos (as detected), for the contrast test.
    contrast_share : float
        See above (:data:`REID_CONTRAST_SHARE`).

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
    beyond = np.zeros((len(rig), k), bool)  # named only thanks to the wider colour gate
    X_have = np.where(have[:, None], X, np.nan)
    proj = rig.project(X_have) if have.any() else None  # (n_views, k, 2)
    for v, vr in enumerate(views):
        ident = vr.identification
        cand = np.asarray(vr.circles.centers, float).reshape(-1, 2)
        if ident.points.shape[0] != k:
            raise ValueError(f"view {v}: identification has {ident.points.shape[0]} markers, points_3d {k}")
        taken = np.zeros(len(cand), bool)
        # every candidate's pixel distance to every marker's projection, (n_cand, k) (used twice below)
        d = np.linalg.norm(cand[:, None, :] - proj[v][None], axis=2) if len(cand) and have.any() else None
        if d is not None:
            gate = np.maximum(2.0, gate_radius * r_exp[v])[None]
            cgate = color_factor * float(ident.max_distance)
            col = np.asarray(ident.cost, float).reshape(len(cand), k)
            with np.errstate(invalid="ignore"):
                ok = (d <= gate) & (col <= cgate) & have[None]
            if ok.any():
                cost = np.where(ok, d / gate + col / cgate, 1e6)
                rows, cols = linear_sum_assignment(cost)
                good = ok[rows, cols]
                out[v, cols[good]] = cand[rows[good]]
                taken[rows[good]] = True
                beyond[v, cols[good]] = col[rows[good], cols[good]] > float(ident.max_distance)
        # markers without 3D: the colour's choice, unless a 3D-consistent marker took its candidate
        # or the candidate lies on another marker's projected bead (within its radius: that bead,
        # partly hidden, its centre pulled outside the pixel gate)
        on_bead = np.zeros(len(cand), bool)
        if d is not None:
            with np.errstate(invalid="ignore"):
                on_bead = np.any(d <= r_exp[v][None], axis=1)
        for m in np.flatnonzero(~have & (ident.candidate >= 0)):
            c = int(ident.candidate[m])
            if c < len(cand) and not taken[c] and not on_bead[c]:
                out[v, m] = ident.points[m]
    if images is not None and beyond.any():
        if len(images) != len(rig):
            raise ValueError(f"need one image per view ({len(rig)}), got {len(images)}")
        named = np.isfinite(out[..., 0])
        r_px = np.where(have[None], r_exp, np.nan)
        contrast = np.full(named.shape, np.nan)

        def measure(vs):  # the contrast of the named beads of views vs (each bead's on its own)
            contrast[vs] = bead_contrast_views([images[v] for v in vs], np.where(named[vs, :, None], out[vs], np.nan),
                                               r_px[vs])

        # only the views with such a candidate need their beads' contrast (1-3 of 12 views on
        # the benchmark's captures: ~2 ms less than all views'); every view's only when one of
        # them has no bead whose colour agrees, so the capture's median stands in
        some = beyond.any(axis=1)
        measure(np.flatnonzero(some))
        agree = named & ~beyond & np.isfinite(contrast)
        if not agree[some].any(axis=1).all():
            measure(np.flatnonzero(~some))
            agree = named & ~beyond & np.isfinite(contrast)
        whole_ref = float(np.median(contrast[agree])) if agree.any() else np.nan
        for v in np.flatnonzero(beyond.any(axis=1)):
            ref = float(np.median(contrast[v, agree[v]])) if agree[v].any() else whole_ref
            with np.errstate(invalid="ignore"):
                faint = beyond[v] & ~(contrast[v] >= contrast_share * ref)
            faint &= np.isfinite(ref)
            out[v, faint] = np.nan
    return out


def one_name_per_bead(rig: Rig, points_3d, views: Sequence[ViewResult], bead_radius_m: float = 0.003,
                      gate_radius: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Two markers triangulated onto one bead: keep the name whose colour the bead shows.

    Two beads cannot lie closer than one bead diameter (centre to centre), so two markers whose
    3D points do are one physical bead under two names: colour named it one way in some views
    and the other way in others (two references of nearby colours, e.g. ``head.2`` and
    ``leg.L3`` of the built-in puppet; the beads turned on another puppet change their shading),
    and each name's views agree because they see the same bead. :func:`reidentify` would then
    keep both. Here, for each such pair, the candidate at the point's projection in every view
    (within ``gate_radius`` x the projected radius, at least 2 px, as :func:`reidentify`) is
    scored against both references (colour distance over the view's acceptance distance,
    summed over the views); the name whose reference the bead is farther from loses its 3D
    point (NaN), so :func:`reidentify` gives the bead's views to the other name.

    ``rig``, ``points_3d`` (shape (n_markers, 3)), ``views`` (one per camera), ``bead_radius_m``
    and ``gate_radius`` are as :func:`reidentify`'s.

    Returns
    -------
    points : ndarray, shape (n_markers, 3)
        ``points_3d`` with the losing names' points NaN.
    dropped : ndarray of bool, shape (n_markers,)
    """
    X = np.array(points_3d, float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"points_3d must have shape (n_markers, 3), got {X.shape}")
    if len(views) != len(rig):
        raise ValueError(f"need one ViewResult per view ({len(rig)}), got {len(views)}")
    if not bead_radius_m > 0:
        raise ValueError(f"bead_radius_m must be > 0 metres, got {bead_radius_m}")
    if not gate_radius > 0:
        raise ValueError(f"gate_radius must be > 0 (a share of the projected bead radius), got {gate_radius}")
    dropped = np.zeros(len(X), bool)
    have = np.flatnonzero(np.all(np.isfinite(X), axis=1))
    if len(have) < 2:
        return X, dropped
    d = np.linalg.norm(X[have, None] - X[None, have], axis=2)
    pairs = [(have[a], have[b]) for a, b in zip(*np.nonzero(np.triu(d < 2.0 * bead_radius_m, 1)))]
    if not pairs:
        return X, dropped
    r_exp = expected_radius_px(rig, X[have], bead_radius_m)
    for i, j in sorted(pairs, key=lambda p: float(np.linalg.norm(X[p[0]] - X[p[1]]))):
        if dropped[i] or dropped[j]:
            continue
        mid = 0.5 * (X[i] + X[j])
        score = np.zeros(2)
        for v, (cam, vr) in enumerate(zip(rig, views)):
            cand = np.asarray(vr.circles.centers, float).reshape(-1, 2)
            if not len(cand):
                continue
            ident = vr.identification
            dist = np.linalg.norm(cand - cam.project(mid[None])[0], axis=1)
            c = int(np.argmin(dist))
            gate = max(2.0, gate_radius * float(r_exp[v, int(np.flatnonzero(have == i)[0])]))
            if not dist[c] <= gate:
                continue
            cost = np.asarray(ident.cost, float).reshape(len(cand), -1)
            score += cost[c, [i, j]] / float(ident.max_distance)
        loser = j if score[0] <= score[1] else i
        X[loser] = np.nan
        dropped[loser] = True
    return X, dropped
