"""The puppet pipeline's stages, in order (each a plain function over arrays and dataclasses):

1. :func:`find_beads`        bead candidates in every photo (``detect.beads``: template or thesis)
2. :func:`identify_beads`    the candidates named by colour, all photos together
   (:func:`detect_view` does 1 and 2 for one photo)
3. :func:`triangulate_beads` the candidates named after first 3D markers (2 px view-pair
                             consensus; :func:`~stillcap.detect.beads.reidentify`), then the
                             3D markers of the final names (:func:`solve_markers`: fill test,
                             view-pair consensus)
4. :func:`pose_skeleton`     joint rotations within the limits, the markers seen once as rays
                             (:func:`~stillcap.body.puppet_pose.fit_pose`)

:func:`~stillcap.pipelines.puppet.analyse_puppet_views` runs them in this order.
"""
from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np

from stillcap.body.markerset import MarkerSet
from stillcap.body.puppet_pose import PoseFit, fit_pose
from stillcap.body.skeleton import Skeleton
from stillcap.camera import Rig
from stillcap.detect.beads import (PreparedView, ViewResult, bead_fill_views, detect_beads, expected_radius_px,
                                   find_bead_candidates, identify_views, one_name_per_bead, prepare_view,
                                   reidentify)
from stillcap.detect.palette import Palette
from stillcap.geometry.triangulate import StackedViews, triangulate_markers, view_pair_errors
from stillcap.pipelines.puppet.options import DEFAULT, PuppetOptions
from stillcap.pipelines.puppet.result import MarkerSolve

__all__ = ["find_beads", "identify_beads", "triangulate_beads", "pose_skeleton", "detect_view", "solve_markers"]


# --- stages 1 and 2: detection and identification per photo ---------------------------------
def detect_view(image, palette: Palette, options: PuppetOptions = DEFAULT, region=None,
                prepared: PreparedView | None = None) -> ViewResult:
    """:func:`stillcap.detect.beads.detect_beads` with the options' ``detector``, ``identify``,
    ``radius_range``, ``n_circles`` and ``roi``: the bead candidates of one photo, named by colour.
    ``region``: the photo's :func:`~stillcap.detect.beads.roi_box` if already computed;
    ``prepared``: its :func:`~stillcap.detect.beads.prepare_view` with these options (:func:`_prepare`)."""
    return detect_beads(image, palette, options.detector, options.identify, options.radius_range,
                        options.n_circles, options.roi, options.coarse, region, prepared)


def _prepare(image, options: PuppetOptions = DEFAULT) -> PreparedView:
    """:func:`~stillcap.detect.beads.prepare_view` with the options' detector, radii, roi and coarse."""
    return prepare_view(image, options.detector, options.radius_range, options.roi, options.coarse)



def find_beads(images, options: PuppetOptions = DEFAULT,
               progress: Callable[[int, int], None] | None = None) -> tuple[list, list]:
    """Stage 1: the bead candidates of every photo (:func:`~stillcap.detect.beads.find_bead_candidates`
    with the options' detector, radii, count, roi and coarse), and the seconds each took.
    ``progress(done, total)`` is called after each photo."""
    cands, t_det = [], []
    n = len(images)
    for k, img in enumerate(images):
        t1 = time.perf_counter()
        cands.append(find_bead_candidates(img, options.detector, options.radius_range, options.n_circles,
                                          options.roi, options.coarse))
        t_det.append(time.perf_counter() - t1)
        if progress is not None:
            progress(k + 1, n)
    return cands, t_det


def identify_beads(images, candidates, seconds, palette: Palette, options: PuppetOptions = DEFAULT) -> list:
    """Stage 2: every photo's candidates named by colour (:func:`~stillcap.detect.beads.identify_views`:
    :func:`detect_view`'s identification, its small matrices computed for all photos at once); one
    :class:`~stillcap.detect.beads.ViewResult` per photo, its time the photo's ``seconds`` plus its
    share of the identification."""
    n = len(images)
    t1 = time.perf_counter()
    idents = identify_views(images, candidates, palette, options.identify)
    share = (time.perf_counter() - t1) / max(n, 1)
    return [ViewResult(c, i, t + share) for c, i, t in zip(candidates, idents, seconds)]


def _arc_refit(images, x, x_used, good, hidden, r_exp):
    """Partly hidden beads' views refitted to their visible arc (:mod:`stillcap.detect.bead_arc`):
    the contour radius a whole bead would have there is its expected radius times the median
    contour/expected ratio of the capture's whole views. Views the arc does not fix are left
    out while two whole or refitted views remain. Returns the centres to triangulate and the
    views left out."""
    from stillcap.detect.bead_arc import arc_centers, contour_radii

    with np.errstate(invalid="ignore", divide="ignore"):
        q = (contour_radii(images, np.where(good[..., None], x, np.nan), r_exp) / r_exp).ravel()
    q = q[np.isfinite(q)]
    ratio = float(np.median(q)) if len(q) else np.nan
    if not np.isfinite(ratio):
        return x_used, np.zeros_like(hidden)
    arc = arc_centers(images, np.where(hidden[..., None], x, np.nan), ratio * r_exp)
    fixed = hidden & np.isfinite(arc[..., 0])
    x_used = np.where(fixed[..., None], arc, x_used)
    drop = hidden & ~fixed & ((good | fixed).sum(axis=0) >= 2)[None]
    return np.where(drop[..., None], np.nan, x_used), drop


# --- stage 3: triangulation --------------------------------------------------------------------
def _checked_points(rig: Rig, points_2d, names: Sequence[str]) -> np.ndarray:
    """``points_2d`` as a float array of shape (n_views, n_markers, 2), else ValueError."""
    x = np.asarray(points_2d, float)
    if x.ndim != 3 or x.shape[0] != len(rig) or x.shape[2] != 2 or x.shape[1] != len(names):
        raise ValueError(f"points_2d must have shape ({len(rig)}, {len(names)}, 2), got {x.shape}")
    return x


def _first_pass(rig: Rig, x: np.ndarray, options: PuppetOptions) -> tuple:
    """:func:`solve_markers`' first triangulation of the observations ``x``: ``(views, pair_errors,
    triangulation)``, the stacked views (``"dlt"``; else None), the view pairs' errors (None
    with fewer than 3 views) and the points of the 2 px consensus. They serve as the beads'
    depths (their expected radii) and as the 3D markers :func:`triangulate_beads` names the
    candidates after, so linear points: the Gauss-Newton refinement moves them by ~0.05 mm at
    ~0.4 m (1e-4 of a bead's radius, ~0.1 px), and a marker that falls back on its first point
    gets it refined."""
    method = options.triangulation
    views = StackedViews(rig, x) if method == "dlt" else None
    pair_err = ((views.pair_errors() if views is not None else view_pair_errors(rig, x, method))
                if len(rig) >= 3 and x.shape[1] else None)
    return views, pair_err, triangulate_markers(rig, x, method, False, 2.0, pair_errors=pair_err, views=views)


def solve_markers(rig: Rig, points_2d, names: Sequence[str], images=None, options: PuppetOptions = DEFAULT,
                  bead_radius_m: float = 0.003, radii_px=None, noise_px: float | None = None, *,
                  first_pass: tuple | None = None) -> MarkerSolve:
    """Triangulate identified markers, leaving out partly hidden beads and disagreeing views.

    1. A first triangulation (``outlier_px`` = 2 px consensus, linear points) gives each
       marker's depth, so its expected radius in every photo.
    2. With ``images`` and ``options.use_fill``: :func:`~stillcap.detect.beads.bead_fill` of every observation;
       where a marker has two or more whole views (see :class:`~stillcap.pipelines.puppet.PuppetOptions`), only those are
       used.
    3. The final triangulation (``options.triangulation``, ``options.outlier_px``); markers
       with fewer than two agreeing views are NaN. A marker the final step loses but the first
       had (its whole views disagree) keeps the first estimate.
    4. With the fill test: views that look whole but lie more than :data:`OFF_CENTER_SIGMA` x
       the capture's pixel noise (``noise_px``; default :func:`_pixel_noise` of this
       triangulation) off the consensus are left out (partial), one of each marker at a time
       (the least whole-looking: lowest fill), triangulating again after each, while two other
       whole views remain;
       those still off then no longer count as whole (the marker may then be partly hidden).

    Parameters
    ----------
    rig : Rig, n_views cameras
        The camera of every view (a turntable's virtual cameras).
    points_2d : array_like, shape (n_views, n_markers, 2)
        Identified pixels, NaN where a view did not identify a marker.
    names : sequence of str, length n_markers
    images : sequence of n_views images, optional
        The photos, for the fill test.
    options : PuppetOptions
    bead_radius_m : float
        Bead radius, metres (the thesis's beads: 3 mm).
    radii_px : array_like, shape (n_views, n_markers), optional
        Detected radii, used where a marker has no first 3D point.
    noise_px : float, optional
        The capture's pixel noise for step 4 (default: measured on this solve's whole views).
    first_pass : tuple, optional
        :func:`_first_pass` of these observations and options, if already made (step 1).
    """
    x = _checked_points(rig, points_2d, names)
    method = options.triangulation
    refine = method == "dlt"
    seen = np.isfinite(x[..., 0]) & np.isfinite(x[..., 1])
    fill = np.full(seen.shape, np.nan)
    partial = np.zeros(seen.shape, bool)
    good = seen.copy()
    x_used = x
    first = pair_err = views = None
    if images is not None and options.use_fill:
        images = list(images)
        if len(images) != len(rig):
            raise ValueError(f"need one image per view ({len(rig)}), got {len(images)}")
        views, pair_err, first = first_pass if first_pass is not None else _first_pass(rig, x, options)
        first_pair_err, first_views = pair_err, views  # kept: the arc refit below may replace both
        r_exp = expected_radius_px(rig, first.points, bead_radius_m)
        if radii_px is not None:
            r_exp = np.where(np.isfinite(r_exp), r_exp, np.asarray(radii_px, float) + 0.7)
        r_exp = np.where(np.isfinite(r_exp), r_exp, 0.5 * sum(options.radius_range) + 0.7)
        fill = bead_fill_views(images, np.where(seen[..., None], x, np.nan), r_exp)
        with np.errstate(invalid="ignore"):
            best = np.nanmax(np.where(seen, fill, -np.inf), axis=0)
            # whole: fill above min_fill, or (when the marker has a whole view at all) close to
            # its best view's fill (beads that look smaller or dimmer in every view)
            good = seen & ((fill >= options.min_fill)
                           | ((fill >= options.fill_ratio * best[None]) & (best[None] >= options.min_fill)))
        enough = good.sum(axis=0) >= 2
        partial = seen & ~good & enough[None]
        x_used = np.where(partial[..., None], np.nan, x)
        hidden = seen & ~good & ~enough[None]  # views of beads that fewer than two views show whole
        if options.arc_fit and hidden.any():
            x_used, dropped = _arc_refit(images, x, x_used, good, hidden, r_exp)
            partial |= dropped
            if np.any(np.isfinite(x_used) & (x_used != x)):
                # refitted centres: the stacked views and the view pairs' errors were made from
                # the detected ones, which the triangulations below would otherwise use
                views = StackedViews(rig, x_used) if method == "dlt" else None
                pair_err = ((views.pair_errors() if views is not None else view_pair_errors(rig, x_used, method))
                            if len(rig) >= 3 and x.shape[1] else None)
    tri = triangulate_markers(rig, x_used, method, refine, options.outlier_px, pair_errors=pair_err, views=views)
    if first is not None:
        # views that look whole but sit off the other views' consensus by more than the
        # capture's own pixel noise allows (partly hidden beads the fill test passed: at 80-90 %
        # of the bead visible the fill overlaps a whole bead's, the centre is 0.6 px off where
        # whole beads are 0.05 px): left out where two whole views remain, else not counted whole
        if noise_px is None:
            noise_px = _pixel_noise(tri.errors_px, tri.used & good)
        # one view per marker at a time (one off view pulls the point and so the others' errors
        # too), the off view that looks least whole first (lowest fill; two partly hidden views
        # of one bead can agree with each other and leave the whole ones farther off), while
        # two other whole views remain
        off = np.zeros_like(good)
        for _ in range(len(rig)):
            if not np.isfinite(noise_px):
                break
            with np.errstate(invalid="ignore"):
                off = tri.used & good & (tri.errors_px > OFF_CENTER_SIGMA * noise_px)
            worst = np.argmin(np.where(off, np.nan_to_num(fill, nan=np.inf), np.inf)
                              - 1e-9 * np.where(off, tri.errors_px, 0.0), axis=0)
            cols = np.flatnonzero(off.any(axis=0) & ((tri.used & good).sum(axis=0) >= 3))
            if not len(cols):
                break
            demote = np.zeros_like(good)
            demote[worst[cols], cols] = True
            x_used = np.where(demote[..., None], np.nan, x_used)
            partial |= demote
            good = good & ~demote
            tri = triangulate_markers(rig, x_used, method, refine, options.outlier_px, pair_errors=pair_err,
                                      views=views)
        if np.isfinite(noise_px):
            with np.errstate(invalid="ignore"):
                off = tri.used & good & (tri.errors_px > OFF_CENTER_SIGMA * noise_px)
        good = good & ~off
    points, used = tri.points.copy(), tri.used.copy()
    lost = ~np.isfinite(points).all(axis=1)
    if first is not None and lost.any() and refine:  # the first triangulation as a final one: refined
        first = triangulate_markers(rig, x, method, refine, 2.0, pair_errors=first_pair_err, views=first_views)
    if first is not None and lost.any():
        back = lost & np.isfinite(first.points).all(axis=1)
        points[back] = first.points[back]
        used[:, back] = first.used[:, back]
        partial[:, back] = False
    err = np.where(used, tri.errors_px, np.nan)
    if first is not None:
        err = np.where(used & ~np.isfinite(err), first.errors_px, err)
    sq = np.where(used, err, 0.0) ** 2
    k = used.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(k >= 2, np.sqrt(np.nansum(sq, axis=0) / k), np.nan)
    outlier = seen & ~used & ~partial
    return MarkerSolve(tuple(names), points, x, used, fill, partial, outlier, rms, tri, good,
                       float("nan") if noise_px is None else float(noise_px))


#: :func:`solve_markers`: a view that looks whole is off centre beyond this many times the
#: capture's pixel noise (:func:`_pixel_noise`). Were the whole beads' reprojection errors
#: Rayleigh with that sigma, 4 sigma would leave ~0.03 % of them out by chance (rendered beads
#: scatter more than that: a whole view left out costs little while two whole views remain); on 72
#: rendered captures of other puppets (seeds 11-22 of six conditions) the views at 80-90 %
#: visible were 0.6-0.7 px off (median) against 0.05-0.07 px for whole ones.
OFF_CENTER_SIGMA = 4.0


def _pixel_noise(errors_px, whole_used) -> float:
    """The capture's 1-sigma pixel noise per axis from its whole beads' reprojection errors:
    their median over 1.1774 (the Rayleigh median), robust to the partly hidden views among
    them; NaN with fewer than 10 errors."""
    e = np.asarray(errors_px, float)[np.asarray(whole_used, bool)]
    e = e[np.isfinite(e)]
    return float(np.median(e) / 1.1774) if len(e) >= 10 else float("nan")


def triangulate_beads(rig: Rig, observations: np.ndarray, markerset: MarkerSet, images=None,
                      options: PuppetOptions = DEFAULT, radii_px=None,
                      views: Sequence[ViewResult] | None = None) -> tuple[MarkerSolve, np.ndarray | None]:
    """Stage 3: the 3D markers (:func:`solve_markers`); with ``views`` (the detections) and
    ``options.reidentify``, first the candidates named after the 3D markers of
    :func:`solve_markers`' first step (its 2 px view-pair consensus of the colour names; linear
    points) by :func:`~stillcap.detect.beads.one_name_per_bead` and
    :func:`~stillcap.detect.beads.reidentify`, then the markers solved on the final names.

    Returns
    -------
    solve : MarkerSolve
    raw_observations : ndarray, shape (n_views, n_markers, 2), or None
        The colour-only identification when the re-identification ran.
    """
    bead_r = 0.5 * float(np.mean([m.diameter for m in markerset.markers]))
    if views is None or not options.reidentify:
        return solve_markers(rig, observations, markerset.names, images, options, bead_radius_m=bead_r,
                             radii_px=radii_px), None
    obs = _checked_points(rig, observations, markerset.names)
    # the candidates named after the first pass's 3D markers (solve_markers' own first step, so it
    # costs nothing more where no name changes), then one solve of the final names: a second
    # solve of the renamed markers after a full one (as before) cost ~5-10 ms of fixed costs
    # for 1-5 markers. One bead under two names (their 3D points closer than a bead's
    # diameter): the name its colour fits worse loses its point first, so the bead's views go
    # to the other name
    first = _first_pass(rig, obs, options)
    points, _ = one_name_per_bead(rig, first[2].points, views, bead_r, options.reid_gate)
    final = reidentify(rig, points, views, bead_r, options.reid_gate, options.reid_color, images)
    same = np.all((np.isnan(final) & np.isnan(obs)) | (final == obs), axis=(0, 2))
    if same.all():
        fill = images is not None and options.use_fill
        return solve_markers(rig, obs, markerset.names, images, options, bead_radius_m=bead_r, radii_px=radii_px,
                             first_pass=first if fill else None), obs
    # the renamed markers without detected radii (those were measured on the other beads)
    radii = None if radii_px is None else np.where(same[None], np.asarray(radii_px, float), np.nan)
    return solve_markers(rig, final, markerset.names, images, options, bead_radius_m=bead_r, radii_px=radii), obs


# --- stage 4: the pose -------------------------------------------------------------------------
#: Expected 3D error of a partly hidden bead's point (measured 1-2 mm in the issue's test), metres.
PARTLY_HIDDEN_SIGMA_M = 1.0e-3


def pose_skeleton(rig: Rig, skeleton: Skeleton, markerset: MarkerSet, solve: MarkerSolve, root2world=None,
                  options: PuppetOptions = DEFAULT, sigma_m=None) -> PoseFit:
    """Stage 4: the skeleton posed on the 3D markers (:func:`~stillcap.body.puppet_pose.fit_pose`).

    Each marker counts with its expected 3D error ``sigma_m`` (metres, shape (n_markers,); default
    ``options.marker_sigma_m``); markers that fewer than two views show whole (partly hidden
    beads: 1-2 mm off) with at least :data:`PARTLY_HIDDEN_SIGMA_M`."""
    # markers without a 3D point (seen in one view, or their views disagree) still constrain the
    # pose: their final identification's rays, less sure the less of the bead shows (fill);
    # fit_pose rejects those its fit leaves > 5 sigma off
    from stillcap.body.puppet_pose import MarkerRays, root_freedom

    rays = MarkerRays.from_views(rig, solve.observations, ~solve.ok, fill=solve.fill)
    root = root_freedom(skeleton, markerset) if options.root == "auto" else options.root
    sigma = np.broadcast_to(np.asarray(options.marker_sigma_m if sigma_m is None else sigma_m, float),
                            solve.partly_hidden.shape)
    sigma = np.where(solve.partly_hidden, np.maximum(sigma, PARTLY_HIDDEN_SIGMA_M), sigma)
    return fit_pose(skeleton, markerset, solve.points, root2world, marker_sigma_m=sigma,
                    rays=rays if len(rays) else None, root=root)
