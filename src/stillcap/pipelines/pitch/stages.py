"""The stages of the pitch pipeline (SPEC J1), one function each, in the order of the method.

:func:`stillcap.pipelines.pitch.analyse_pitch` runs them in this order (``docs/pitch.md`` tells
the whole story); each passes plain values and the small dataclasses below to the next, and
reports to one :class:`StageLog` (messages, timings, progress):

0. **Stereo pairs** (:func:`stillcap.io.capture.stereo_pairs`): the capture's photos grouped into
   strobed pairs (by ``images[].meta.pair``, the capture's ``pairs`` map, or the strobe rate),
   each with its rate.
1. **Find balls** per pair (:func:`find_balls`; :func:`stillcap.ball.stereo.ball_centers_stereo`,
   the seed's steps 1-5): colour background subtraction, contours, convex hull, ellipse,
   epipolar matching, approximate triangulation, projected radius, known-radius Hough refinement
   (half moons included), final triangulation. Matches whose refinement failed, whose size
   disagrees with the projected radius or which the image border cuts are dropped (a cut ball
   whose in-frame limb fixed its centre, ``EDGE``, is kept).
2. **Number flashes** (:func:`number_flashes`; :func:`stillcap.ball.flashes.number_flashes_from_spacing`): the
   3D positions of a pair are ordered along the flight (off-path detections dropped); the flash
   index ``k`` of each comes from the spacing (``round(spacing / base spacing)``, a missed flash
   leaves a gap); the pair's own clock is ``k / strobe_hz`` from its first ball image. The first
   pair along the flight (the front pair) is the reference clock (``t = 0`` at its first ball
   image); the other pairs' clock offsets are unknown (free-running strobes) and fitted with the
   flight (``time_groups`` of the reference fit).
3. **Fit flight** (:func:`fit_flight`): the seed's two-point release velocity, and the reference
   trajectory of the positions alone (:func:`stillcap.ball.fit.fit_reference_trajectory`): the
   clock offsets and the curvature for the alias check, with each position's error shape (from
   each view's own centre sigma: the pair's, or an arc fit's for ``EDGE`` views and faint
   crescents, :func:`image_sigma_px`) and the errors a pair's positions share (calibration, ball-centre
   bias: :mod:`stillcap.ball.uncertainty`).
4. **Markers and spin** (started by :func:`start_markers_and_spin` before the flight fit, on the
   workers; collected by :func:`markers_and_spin`). Markers
   (:func:`stillcap.ball.markers.pair_marker_observations`): coloured regions inside every ball
   image, matched across the pair by type and epipolar distance and triangulated (direction from
   the ball centre); markers seen by one camera only become pixel rays intersected with the ball
   sphere. Spin: ``"global"`` (default) fits one constant spin to all flashes of a pair
   (:func:`stillcap.ball.orientation.fit_spin`), ``"seed"`` is the seed's per-flash Powell method
   (:func:`~stillcap.ball.orientation.fit_spin_seed`). The alias above the strobe's Nyquist limit
   is chosen with both strobe rates and the Magnus curvature of the flight
   (:mod:`stillcap.ball.alias`); the global method then refits all pairs' markers together on the
   reference clock at that alias (:mod:`stillcap.pipelines.pitch.spin`).
5. **Refit with spin** (:func:`refit_with_spin`): the seed's objective (positions + measured
   initial parameters), least squares or Powell, seed or Nathan physics; clock offsets of the
   other pairs fitted jointly; each pair's position sigma and covariances from its residuals.
6. **Metrics and uncertainty** (:func:`metrics_and_uncertainty`): the release state, the metrics
   in the field frame (:mod:`stillcap.ball.metrics`) with 1-sigma uncertainties from the fits'
   covariances (:func:`stillcap.ball.uncertainty.metrics_sigma`: first order, or Monte Carlo
   through the flight model).

Everything is SI inside; the result's :meth:`~stillcap.pipelines.pitch.PitchResult.to_dict`
names units in its keys and shares its key names with the studio's ``truth.json``
(``metrics``, ``release``, ``spin``, ...).
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from stillcap.ball.fit import FitPriors, ReferenceFit, fit_reference_trajectory
from stillcap.ball.flashes import flight_axis, number_flashes_from_spacing, off_flight_path
from stillcap.ball.image_levels import level_dispersion, whitened_levels
from stillcap.ball.metrics import (FT, MPH, RPM_PER_RAD_S, PitchMetrics, clock_tilt, pitch_metrics_from_flight,
                                   spin_axis_deg, spin_efficiency)
from stillcap.ball.orientation import SpinResult
from stillcap.ball.physics import cross_plane, simulate
from stillcap.ball.stereo import StereoBalls, view_center_sigma_px
from stillcap.ball.uncertainty import (calibration_modes, center_bias_modes, metrics_sigma, pixel_sigma,
                                       position_covariances, remaining_bias_modes, speed_sigma, spin_decay_slope)
from stillcap.detect.ball import BallFlag
from stillcap.io.capture import Capture, StereoPairSpec, board_points_world
from stillcap.pipelines.pitch.options import PitchOptions
from stillcap.pipelines.pitch.result import PairResult
from stillcap.pipelines.pitch.spin import spin_stage
from stillcap._progress import report_progress

__all__ = ["BallImages", "MeasuredSpin", "MetricsWithSigma", "PositionsFit", "StageLog", "check_and_inflate", "find_balls",
           "fit_flight", "image_sigma_px", "markers_and_spin", "metrics_and_uncertainty", "number_flashes", "refit_with_spin",
           "start_markers_and_spin"]

#: Matched ball images not used: refinement failed, size disagrees with the projected radius, or
#: cut by the image border (its centre is off by millimetres: ``docs/pitch.md``) unless its
#: in-frame limb fixed its centre (``EDGE``, :func:`_dropped`).
_DROP_FLAGS = int(BallFlag.REFINE_FAILED | BallFlag.SIZE_MISMATCH | BallFlag.TOUCHES_BORDER)


def _dropped(flags) -> np.ndarray:
    """Which matches (their views' flags OR-ed) are not used: any of ``_DROP_FLAGS``, except
    ``TOUCHES_BORDER`` with an ``EDGE`` fit (issue 12). The flags are OR-ed over the two views:
    a match with one view fitted and the other cut but not fitted is caught per view by
    :func:`_cut_unfitted`."""
    f = np.asarray(flags, int)
    drop = (f & (_DROP_FLAGS & ~int(BallFlag.TOUCHES_BORDER))) != 0
    cut = (f & int(BallFlag.TOUCHES_BORDER)) != 0
    return drop | (cut & ((f & int(BallFlag.EDGE)) == 0))


def _cut_unfitted(st: StereoBalls) -> np.ndarray:
    """Matches with a view cut by the border that its in-frame limb did not fix, shape (K,)."""
    out = np.zeros(len(st), bool)
    for v, det in enumerate((st.detections_a, st.detections_b)):
        idx = st.pairs[:, v] if len(st) else np.zeros(0, int)
        out |= det.has(BallFlag.TOUCHES_BORDER)[idx] & ~det.has(BallFlag.EDGE)[idx]
    return out


def image_sigma_px(pair_sigma_px: float, arc_sigma_px) -> np.ndarray:
    """Each ball image's centre uncertainty per view (1 sigma, px), shape like ``arc_sigma_px``
    ((2, K): camera, image): the pair's own (``pair_sigma_px``, from its residuals:
    :func:`stillcap.ball.uncertainty.pixel_sigma`) where the centre rests on the whole limb, and
    the larger of it and the arc fit's ``center_sigma_px`` where it rests on an arc (``EDGE``
    views, faint crescents: :func:`stillcap.ball.stereo.view_center_sigma_px`; NaN in
    ``arc_sigma_px`` for the others): an arc's centre is no better than the pair's noise, and
    worse the shorter the arc."""
    a = np.asarray(arc_sigma_px, float)
    return np.where(np.isfinite(a), np.maximum(a, pair_sigma_px), pair_sigma_px)


def _weighted_shape(cams, centers_px, sigma_px, at_px: float | None = None) -> np.ndarray:
    """Each position's error covariance shape (K, 3, 3), m^2, from a pixel error of
    ``sigma_px`` ((2, K), per camera and image) on each centre, mapped to 3-D through the
    re-triangulation (:func:`stillcap.ball.uncertainty.center_bias_modes` at ``at_px``, default
    the median sigma, scaled per image and camera: the triangulation is linear over a pixel, and
    where every sigma is ``at_px`` the shape is exactly the unweighted one)."""
    s = np.asarray(sigma_px, float)
    at = float(np.median(s)) if at_px is None else float(at_px)
    d = center_bias_modes(cams, centers_px, at)  # (4, K, 3): camera 0 x, 0 y, 1 x, 1 y
    if at > 0:
        d = d * (s / at)[[0, 0, 1, 1]][:, :, None]
    return np.einsum("mki,mkj->kij", d, d)


# --------------------------------------------------------------------------------------------
# What the stages pass on
# --------------------------------------------------------------------------------------------
@dataclass
class StageLog:
    """Where the stages of one capture report: the user's messages (in order), the stages'
    timings (s) and the progress callback ``progress(done, total, label)``."""

    messages: list
    timings: dict
    progress: Callable[[int, int, str], None] | None
    total: int

    def step(self, done: int, label: str) -> None:
        report_progress(self.progress, done, self.total, label)


class BallImages(NamedTuple):
    """One stereo pair's ball images (:func:`find_balls`)."""

    spec: StereoPairSpec
    cameras: list
    photos: object  # the decoded photos, or the token of the worker process holding them
    stereo: StereoBalls
    ok: np.ndarray  # matched ball images kept (bool per row of ``stereo``)
    n_detected: tuple  # ball silhouettes found in each photo


@dataclass
class PositionsFit:
    """The flight from the positions alone (:func:`fit_flight`): the seed's two-point velocity,
    the positions-only reference fit and what the refit with the spin reuses."""

    p0: np.ndarray  # first position of the reference pair
    dk: int  # flashes between the reference pair's first two ball images
    v_two: np.ndarray  # the seed's two-point velocity
    times: np.ndarray  # every position's time on its pair's own clock
    positions: np.ndarray
    pair_index: np.ndarray
    n_groups: int  # clocks other than the reference
    fit_kw: dict  # the reference fit's arguments
    position_covariance: np.ndarray  # each position's error covariance shape
    fit: ReferenceFit  # positions only (clock offsets, curvature), calibration modes included
    cal_modes: np.ndarray | None  # shared (calibration, centre bias) modes over all positions
    shared_modes: dict  # pair index -> its shared modes


@dataclass
class MeasuredSpin:
    """The spin the markers gave (:func:`markers_and_spin`)."""

    spin: SpinResult | None
    alias: object
    obs_times: np.ndarray | None  # reference-clock time of each observation of ``spin``
    ok: bool
    w0: np.ndarray | None  # spin at t = 0 of the reference clock
    cov0: np.ndarray | None


@dataclass
class MetricsWithSigma:
    """The metrics and their uncertainties (:func:`metrics_and_uncertainty`)."""

    metrics: PitchMetrics
    sigma: dict
    release: dict
    table1: dict
    v_two_sigma: np.ndarray


# --------------------------------------------------------------------------------------------
# The stages, in the order of the method
# --------------------------------------------------------------------------------------------
def find_balls(specs: list, jobs, radius_m: float, where: str, log: StageLog) -> list:
    """1. The ball images of every stereo pair, matched across the pair and triangulated
    (:func:`stillcap.ball.stereo.ball_centers_stereo`, run by ``jobs``: the overlap of decoding
    and finding, threads or worker processes, is :mod:`stillcap.pipelines.pitch.workers`'s).

    Returns
    -------
    list of BallImages
        In the order of ``specs``; ``ok`` leaves out the matches whose refinement failed, whose
        size disagrees with the projected radius or which the image border cuts without an
        ``EDGE`` fit.

    Raises
    ------
    ValueError
        No ball found in any pair.
    """
    messages, timings = log.messages, log.timings
    t = _time.perf_counter()
    found = jobs.find_balls(specs, radius_m)
    raw = []
    for i, (sp, (cams, imgs, st)) in enumerate(zip(specs, found)):
        log.step(2 * i + 1, f"pair {sp.name}: ball images")
        ok = st.ok & ~_dropped(st.flags) & ~_cut_unfitted(st)
        nd = (len(st.detections_a), len(st.detections_b))
        if nd[0] == 0 or nd[1] == 0:
            none = [c for c, n in zip(sp.cameras, nd) if n == 0]
            messages.append(f"pair {sp.name!r}: no ball in the photo of {', '.join(none)}")
        elif not ok.any():
            messages.append(f"pair {sp.name!r}: {nd[0]} and {nd[1]} ball images, none matched across the pair")
        raw.append(BallImages(sp, cams, imgs, st, ok, nd))
        log.step(2 * i + 2, f"pair {sp.name}: {int(ok.sum())} ball positions")
    timings["positions"] = _time.perf_counter() - t
    if not any(r.ok.any() for r in raw):
        raise ValueError(f"{where}: no ball found in any stereo pair ({'; '.join(messages)})")
    return raw


def number_flashes(cap: Capture, raw: list, options: PitchOptions, where: str, log: StageLog) -> list:
    """2. The flight direction, each pair's positions in flight order with their flash indices
    (:func:`stillcap.ball.flashes.number_flashes_from_spacing`; off-path detections dropped), the pairs in
    flight order and the reference clock.

    Returns
    -------
    list of PairResult
        ``pairs[0]`` is the reference pair (the first along the flight with 2+ ball images).
        Each keeps its cameras and photos (``_cams``, ``_imgs``) for the marker step.

    Raises
    ------
    ValueError
        Fewer than 3 ball positions, or no pair with 2.
    """
    messages = log.messages
    pts_all = np.concatenate([st.points_3d[ok] for *_, st, ok, _ in raw]) if raw else np.zeros((0, 3))
    if len(pts_all) >= 2:
        axis = flight_axis(pts_all)
    else:
        axis = np.array([0.0, -1.0, 0.0])
    with_pts = [j for j, r in enumerate(raw) if r[4].any()]
    if cap.rig.world == "field":
        sign = -1.0 if axis[1] > 0 else 1.0  # the ball flies toward home plate (-y)
    elif len(with_pts) >= 2:
        a = raw[with_pts[0]][3].points_3d[raw[with_pts[0]][4]].mean(0)
        b = raw[with_pts[-1]][3].points_3d[raw[with_pts[-1]][4]].mean(0)
        sign = 1.0 if (b - a) @ axis > 0 else -1.0
        messages.append(f"rig world {cap.rig.world!r} is not the field frame: flight direction from pair "
                        f"{raw[with_pts[0]][0].name!r} toward {raw[with_pts[-1]][0].name!r}; metrics assume field axes")
    else:
        sign = 1.0
        messages.append(f"rig world {cap.rig.world!r} is not the field frame and only one pair saw the ball: "
                        "the flight direction is a guess; metrics assume field axes")
    direction = sign * axis
    pairs: list[PairResult] = []
    for sp, cams, imgs, st, ok, nd in raw:
        idx = np.flatnonzero(ok)
        n_drop = int(len(st) - len(idx))
        P = st.points_3d[idx]
        off = off_flight_path(P, direction)
        if off.any():
            messages.append(f"pair {sp.name!r}: {int(off.sum())} ball position(s) off the flight path dropped")
            idx, P = idx[~off], P[~off]
            n_drop += int(off.sum())
        exp_s = None if options.expected_speed_mph is None else options.expected_speed_mph * MPH / sp.strobe_hz
        order, k, spacing = number_flashes_from_spacing(P, direction, sp.strobe_hz, exp_s)
        n_drop += len(idx) - len(order)
        sel = idx[order]
        pr = PairResult(sp.name, sp.cameras, sp.strobe_hz, k, st.points_3d[sel],
                        np.stack([st.centers_a[sel], st.centers_b[sel]]), st.radius_px[sel].T.copy(),
                        st.reproj_error_px[sel], st.flags[sel], nd, n_drop, spacing, stereo=st)
        # each view's arc-fit centre sigma (NaN where the centre rests on the whole limb), (2, K)
        pr.arc_sigma_px = view_center_sigma_px(st)[sel].T.copy()
        pr._imgs = imgs  # kept for the marker step, dropped afterwards (processes: the worker's token)
        pr._cams = cams
        pairs.append(pr)
    # flight order of the pairs: by the position of their first ball image along the flight
    pairs.sort(key=lambda p: (len(p) == 0, p.positions[0] @ direction if len(p) else 0.0))
    # cross-check the base spacings (speeds) of the pairs: a pair that missed every other flash
    # looks twice as fast as the others (drag makes later pairs ~10 % slower, never 2x)
    speeds = [p.spacing_m * p.strobe_hz for p in pairs if len(p) >= 2 and np.isfinite(p.spacing_m)]
    if len(speeds) >= 2 and options.expected_speed_mph is None:
        v_ref = min(speeds)
        for p in pairs:
            if len(p) >= 2 and np.isfinite(p.spacing_m):
                ratio = p.spacing_m * p.strobe_hz / v_ref
                m = int(round(ratio))
                if m >= 2 and abs(ratio - m) < 0.25 * m:
                    p.flash_index = p.flash_index * m
                    p.spacing_m /= m
                    messages.append(f"pair {p.name!r}: spacing {m}x the other pairs' speed: every ball image "
                                    f"counted {m} flashes apart")
    usable = [p for p in pairs if len(p) >= 1]
    n_pos = sum(len(p) for p in usable)
    if n_pos < 3:
        raise ValueError(f"{where}: too few ball images for a flight: {n_pos} position(s) "
                         f"({', '.join(f'{p.name}: {len(p)}' for p in pairs)}); need at least 3"
                         + (f" ({'; '.join(messages)})" if messages else ""))
    ref = next((p for p in usable if len(p) >= 2), None)
    if ref is None:
        raise ValueError(f"{where}: too few flashes: no pair has 2 ball images (the release velocity needs two)")
    if ref is not usable[0]:
        messages.append(f"pair {usable[0].name!r} has one ball image only: pair {ref.name!r} is the reference clock")
    pairs = [ref] + [p for p in pairs if p is not ref]
    for p in pairs:
        if len(p) == 1:
            messages.append(f"pair {p.name!r}: one ball image only (its clock offset rests on it alone)")
    return pairs


def start_markers_and_spin(pairs: list, jobs, types, layout, options: PitchOptions) -> list:
    """4 (started). Each pair's markers and its own spin, on ``jobs`` (a Future per pair with
    ball images, else None): they need only the pair's ball images, markers and flash indices,
    not the flight fit, so they run while the calling thread fits the flight; collected by
    :func:`markers_and_spin`."""
    # the pair's own spin needs only its markers and flash indices, not the flight fit: it runs
    # in the same job, alongside the positions-only fit on the main thread
    args = (types, layout, options.radius_m, options.marker_epipolar_px, options.spin_method)
    return [jobs.markers_and_spin(p, p._cams, p._imgs, *args) if len(p) else None for p in pairs]


def fit_flight(cap: Capture, pairs: list, model, options: PitchOptions, log: StageLog) -> PositionsFit:
    """3. The flight from the positions alone: the seed's two-point release velocity, then the
    positions-only reference fit (least squares; the other pairs' clock offsets, the curvature
    for the alias check) with each position's error shape and the errors a pair's positions
    share (calibration, ball-centre bias: ``docs/pitch.md``, "Uncertainties"). Sets each pair's
    clock offset."""
    messages, timings = log.messages, log.timings
    ref = pairs[0]
    # the seed's two-point release velocity
    p0 = ref.positions[0]
    dk = int(ref.flash_index[1] - ref.flash_index[0])
    v_two = (ref.positions[1] - ref.positions[0]) * ref.strobe_hz / dk

    # the positions-only reference fit: clock offsets, curvature
    t = _time.perf_counter()
    groups, times_l, pos_l, pidx = [], [], [], []
    g = 0
    for i, p in enumerate(pairs):
        if len(p) == 0:
            continue
        if p is not ref:
            g += 1
        p.group = 0 if p is ref else g
        groups.append(np.full(len(p), p.group))
        times_l.append(p.local_times)
        pos_l.append(p.positions)
        pidx.append(np.full(len(p), i))
    groups_a, times_a, pos_a, pidx_a = (np.concatenate(x) for x in (groups, times_l, pos_l, pidx))
    off0 = []
    for p in pairs:
        if len(p) == 0 or p is ref:
            continue
        cr = cross_plane(p0, v_two, np.zeros(3), model, t0=0.0, plane_point=p.positions[0],
                         plane_normal=v_two, t_max=5.0)
        off0.append(cr.time if cr.success else float((p.positions[0] - p0) @ v_two / (v_two @ v_two)))
    # each position's error covariance shape from its pair's triangulation geometry: a pixel
    # error of sigma_px (the pair's sqrt(2) x RMS reprojection error) on each centre, mapped to
    # 3-D through the re-triangulation (the four center_bias_modes, one image at a time). A
    # stereo pair sees depth 3-6x worse than across its view; an isotropic fit pooled the
    # depth scatter of one pair with the small cross-view scatter of the rest and reported
    # direction sigmas ~1.7x too small (docs/pitch.md, "Uncertainties")
    pos_cov = np.zeros((len(pos_a), 3, 3))
    for i, p in enumerate(pairs):
        if len(p) == 0:
            continue
        # issue 12: each image weighed by its own centre sigma per view (an arc fit's, larger
        # the shorter the arc, for EDGE views and faint crescents: view_center_sigma_px)
        arc = getattr(p, "arc_sigma_px", None)
        s_pair = pixel_sigma(p.reproj_error_px)
        sig = image_sigma_px(s_pair, np.full((2, len(p)), np.nan) if arc is None else arc)
        pos_cov[pidx_a == i] = _weighted_shape(p._cams, p.centers_px, sig, s_pair)
    fit_kw = dict(model=model, t0=0.0, method=options.fit_method, position_sigma=options.position_sigma_m,
                  time_groups=groups_a if g else None, time_offsets=np.array(off0) if g else None,
                  position_covariance=pos_cov)
    # the positions-only fit (clock offsets, curvature for the alias check) always uses least
    # squares: it is a step of the pipeline, the selectable optimiser is the final fit's
    fit_pos = fit_reference_trajectory(times_a, pos_a, p0, v_two, None, **{**fit_kw, "method": "least_squares"})
    # calibration error: shared by all positions of a pair (docs/pitch.md, "Uncertainties")
    calib = cap.meta.get("calibration") if isinstance(cap.meta.get("calibration"), dict) else None
    cal_modes, shared_modes = [], {}
    for i, p in enumerate(pairs):
        if len(p) == 0:
            continue
        board = None if calib is None else [board_points_world(calib, p.name, c.name) for c in p._cams]
        m = calibration_modes(p._cams, p.centers_px, board, options.calibration_focal_sigma)
        sb = options.center_bias_px
        if sb is None and p.stereo is not None:
            # the bias the shading correction leaves (docs/pitch.md, "Coverage audit", 4th pass):
            # the share this capture's ball images measure (their misfit to the correction's
            # model, its phase's split-half sigma), at least the stated floor
            # (docs/pitch.md, "A share each capture measures")
            kappa = options.shading_model_error
            # how much of it the two cameras share: from the pair's epipolar residuals, which the
            # flight cannot absorb (docs/pitch.md, "Shared by the pair's cameras")
            # and how much larger than stated each camera's own part is, from the same residuals
            # (docs/pitch.md, "Each image's own level")
            mb = remaining_bias_modes(p._cams, p.stereo, p.centers_px, p.flags, p.radius_px, kappa,
                                      correlation="epipolar", epipolar_scale=True)
        else:
            if sb is None:
                sb = pixel_sigma(p.reproj_error_px, default_px=0.0)
            mb = center_bias_modes(p._cams, p.centers_px, sb, trend=True)
        m = mb if m is None else np.concatenate([m, mb])
        if not np.any(m):
            continue
        shared_modes[i] = m
        full = np.zeros((len(m), len(pos_a), 3))
        full[:, pidx_a == i] = m
        cal_modes.append(full)
        p.calibration_sigma_m = float(np.sqrt(np.mean(np.sum(m ** 2, axis=(0, 2))) / 3.0))
    cal_modes = np.concatenate(cal_modes) if cal_modes else None
    if calib is None and options.calibration_focal_sigma > 0 and cap.meta.get("rig_calibrated") is not False:
        messages.append("no calibration record (capture.json meta.calibration): the uncertainties leave out "
                        "the calibration error")
    if cal_modes is not None:
        fit_pos = fit_pos.with_extra_covariance(fit_pos.position_covariance_term(cal_modes))
    timings["fit_positions"] = _time.perf_counter() - t
    for p in pairs:
        if p.group > 0:
            p.time_offset_s = float(fit_pos.time_offsets[p.group - 1])
            p.time_offset_sigma_s = float(fit_pos.time_offset_sigma[p.group - 1])
    log.step(log.total - 2, "flight fitted; markers")
    return PositionsFit(p0, dk, v_two, times_a, pos_a, pidx_a, g, fit_kw, pos_cov, fit_pos, cal_modes, shared_modes)


def markers_and_spin(pairs: list, marker_jobs: list, flight: PositionsFit, model, layout, options: PitchOptions,
                     log: StageLog) -> MeasuredSpin:
    """4. Each pair's markers and own spin (collected from :func:`start_markers_and_spin`), the
    alias chosen with both strobe rates and the flight's curvature, and the spin of all pairs
    together (:func:`stillcap.pipelines.pitch.spin.spin_stage`); with the Nathan model, the
    mean spin over the flashes taken back to ``t = 0``. A spin that cannot be had leaves the
    flight: the result says why."""
    messages, timings = log.messages, log.timings
    fit_pos = flight.fit
    t = _time.perf_counter()
    t_jobs = t_spin_jobs = 0.0
    pair_spins, spin_error = [], None
    for p, job in zip(pairs, marker_jobs):
        pair_spins.append(None)
        if job is not None:
            (obs, mk, stats), sp, dt, dt_spin = job.result()
            t_jobs += dt
            t_spin_jobs += dt_spin
            if isinstance(sp, Exception):
                spin_error = spin_error or sp
            else:
                pair_spins[-1] = sp
            p.observations, p.markers = obs, mk
            p.n_markers_3d, p.n_markers_ray, p.marker_reproj_px = stats["n_3d"], stats["n_ray"], stats["epipolar_px"]
        del p._imgs, p._cams
    # "markers": the pairs' marker jobs summed (they run on the pool, alongside fit_positions);
    # "markers_wait": what the main thread still waited for them after its positions-only fit
    timings["markers"] = t_jobs
    timings["markers_wait"] = _time.perf_counter() - t
    t = _time.perf_counter()
    n_obs = sum(len(p.observations) for p in pairs if p.observations is not None)
    spin, alias, obs_times = None, None, None
    if n_obs == 0:
        messages.append("no markers found on the ball: spin unavailable (positions and velocity are reported)")
    else:
        try:
            if spin_error is not None:
                raise spin_error
            # the spin's shared ball-centre error: the positions' own modes (calibration, remaining
            # shading bias per camera along its lit direction)
            center_modes = [flight.shared_modes.get(i) for i in range(len(pairs))]
            spin, alias, obs_times = spin_stage(pairs, fit_pos, model, layout, options.spin_method, messages,
                                                pair_spins, center_modes, options.radius_m)
        except (ValueError, np.linalg.LinAlgError) as e:  # a spin that cannot be had must not cost the flight
            spin, alias, obs_times = None, None, None
            messages.append(f"spin fit failed ({e}): spin unavailable")
    # "spin": the main thread's spin stage; "spin_pairs": the pairs' own fits, in the marker jobs
    timings["spin"] = _time.perf_counter() - t
    timings["spin_pairs"] = t_spin_jobs
    spin_ok = spin is not None and spin.success
    w0 = cov0 = None  # measured spin at t = 0 of the reference clock
    if spin_ok:
        w0 = spin.spin.copy()
        cov0 = spin.spin_covariance if np.all(np.isfinite(spin.spin_covariance)) else np.eye(3) * 25.0
        if model.kind == "nathan" and obs_times is not None and len(obs_times) == len(spin.inliers):
            slope = spin_decay_slope(fit_pos, model, obs_times[spin.inliers], 0.0)
            w0, cov0 = w0 / slope, cov0 / slope ** 2
            messages.append(f"spin decay (Nathan model) taken into account: {spin.spin_rpm:.0f} rpm on average over "
                            f"the flashes, {np.linalg.norm(w0) * RPM_PER_RAD_S:.0f} rpm at the first ball image")
    return MeasuredSpin(spin, alias, obs_times, spin_ok, w0, cov0)


def refit_with_spin(pairs: list, flight: PositionsFit, spin: MeasuredSpin, options: PitchOptions,
                    log: StageLog) -> ReferenceFit:
    """5. The reference fit again with the measured spin as a prior (positions weighed by their
    measured scatter), or the positions-only fit without a spin; then each pair's clock offset,
    position sigma and per-image covariance from its residuals."""
    messages, timings = log.messages, log.timings
    fit_pos, fit_kw, g, p0, v_two = flight.fit, flight.fit_kw, flight.n_groups, flight.p0, flight.v_two
    times_a, pos_a, pidx_a = flight.times, flight.positions, flight.pair_index
    pos_cov, cal_modes, shared_modes = flight.position_covariance, flight.cal_modes, flight.shared_modes
    spin_ok, w0, cov0 = spin.ok, spin.w0, spin.cov0
    t = _time.perf_counter()
    # an ambiguous alias is not a measured spin: as a prior its wrong candidate would pull the
    # flight (1.3 mph, 1.1 deg on a gamma-2.6 robustness capture), so the flight keeps the positions'
    ambiguous = spin_ok and bool(getattr(spin.alias, "ambiguous", False))
    if ambiguous:
        messages.append("spin alias ambiguous: the flight is fitted from the ball positions alone, "
                        "without the markers' spin as a prior")
    if spin_ok and not ambiguous:
        # the spin priors' sigmas from the marker fit's covariance (at least 0.5 rad/s, ~5 rpm)
        e_v = v_two / np.linalg.norm(v_two)
        var_axial = max(float(e_v @ cov0 @ e_v), 0.0)
        var_transverse = max(float(np.trace(cov0)) - var_axial, 0.0) / 2.0
        priors = FitPriors(spin_axial_sigma=max(np.sqrt(var_axial), 0.5),
                           spin_transverse_sigma=max(np.sqrt(var_transverse), 0.5))
        fit_kw["time_offsets"] = fit_pos.time_offsets if g else None
        # positions weighed by their measured scatter (the positions-only fit's residual scale,
        # 0.16-0.25 of the nominal sigma): with the nominal 2 mm the spin prior pulled the fit
        # several times harder than its covariance said (docs/pitch.md, "Coverage audit")
        if np.isfinite(fit_pos.residual_scale) and fit_pos.residual_scale > 0:
            fit_kw["position_sigma"] = options.position_sigma_m * fit_pos.residual_scale
        fit = fit_reference_trajectory(times_a, pos_a, p0, v_two, w0, priors=priors, **fit_kw)
        # the priors weighed the spin with two sigmas; its error is correlated (ReferenceFit.spin_prior_covariance_term)
        fit = fit.with_extra_covariance(fit.spin_prior_covariance_term(cov0))
    elif options.fit_method != "least_squares":
        fit = fit_reference_trajectory(times_a, pos_a, p0, v_two, None, **fit_kw)
    else:
        fit = fit_pos
    if cal_modes is not None and fit is not fit_pos:
        fit = fit.with_extra_covariance(fit.position_covariance_term(cal_modes))
    timings["fit"] = _time.perf_counter() - t

    # residuals fall short of the errors by the fitted degrees of freedom (as in residual_scale)
    n_obs_coord = int(np.sum(np.isfinite(fit.residuals)))
    n_par = int(np.asarray(fit.covariance).shape[0])
    dof_ratio = n_obs_coord / (n_obs_coord - n_par) if n_obs_coord > n_par else 1.0
    # how much the images' error levels differ about their pair's, from their own residuals,
    # pooled over the pairs: each image's covariance then takes its own level (empirical Bayes;
    # docs/pitch.md, "Each image's own level")
    v_levels = level_dispersion([whitened_levels(fit.residuals[pidx_a == i], pos_cov[pidx_a == i])
                                 for i in range(len(pairs))])
    for i, p in enumerate(pairs):
        if p.group > 0:
            p.time_offset_s = float(fit.time_offsets[p.group - 1])
            p.time_offset_sigma_s = float(fit.time_offset_sigma[p.group - 1])
        sel = pidx_a == i
        r = fit.residuals[sel]
        r = r[np.all(np.isfinite(r), axis=1)]
        p.position_sigma_m = (float(np.sqrt(np.mean(r ** 2))) if len(r) >= 2
                              else float(fit.residual_scale * options.position_sigma_m))
        if np.isfinite(p.calibration_sigma_m):  # scatter and the pair's shared calibration shift
            p.position_sigma_m = float(np.hypot(p.position_sigma_m, p.calibration_sigma_m))
        # per image: the triangulation's error shape at the residuals' level, plus the shared
        # modes (an isotropic sigma mis-tests the thin depth ellipsoid; docs/pitch.md, sixth pass)
        cov_k, _ = position_covariances(fit.residuals[sel], pos_cov[sel], shared_modes.get(i),
                                        dof_ratio, v_levels)
        if cov_k is None and len(p) and np.isfinite(p.position_sigma_m):  # too few residuals for a shape
            cov_k = np.broadcast_to(np.eye(3) * p.position_sigma_m ** 2, (len(p), 3, 3)).copy()
        p.position_covariance_m2 = cov_k
    if not fit.success:
        messages.append(f"reference fit did not converge: {fit.message}")
    if fit.rms_error > 0.05:
        messages.append(f"reference trajectory misses the positions by {fit.rms_error * 1e3:.0f} mm RMS: "
                        "check the calibration and the flash order")
    return fit


def metrics_and_uncertainty(cap: Capture, pairs: list, flight: PositionsFit, measured: MeasuredSpin,
                            fit: ReferenceFit, model, options: PitchOptions, log: StageLog) -> MetricsWithSigma:
    """6. The release state (at the front pair's first ball image, or at ``release_y_ft``), the
    pitch metrics in the field frame (:mod:`stillcap.ball.metrics`), their 1-sigma uncertainties
    from the fits' covariances (:func:`stillcap.ball.uncertainty.metrics_sigma`) and the seed's
    Table 1 row."""
    messages, timings = log.messages, log.timings
    ref, dk = pairs[0], flight.dk
    spin, spin_ok, w0, cov0 = measured.spin, measured.ok, measured.w0, measured.cov0
    sig_pos = ref.position_sigma_m if np.isfinite(ref.position_sigma_m) else options.position_sigma_m
    v_two_sigma = np.full(3, np.sqrt(2.0) * sig_pos * ref.strobe_hz / dk)

    t = _time.perf_counter()
    if cap.rig.world != "field":
        messages.append(f"rig world is {cap.rig.world!r}, not the baseball field frame: metrics use its axes as if "
                        "they were field axes (y toward the pitcher, z up)")
    release_y_m = None if options.release_y_ft is None else options.release_y_ft * FT
    if release_y_m is None:
        t_rel, p_rel, v_rel = fit.t0, fit.p0, fit.v0
        if cap.rig.world == "field" and p_rel[1] < 50.0 * FT:
            messages.append(f"the first ball image is at y = {p_rel[1] / FT:.1f} ft, far from the pitcher: the release "
                            "metrics are evaluated there (give --release-y-ft / release_y_ft for the real release)")
    else:
        t_rel, p_rel, v_rel = _release_state(fit.p0, fit.v0, fit.spin, model, fit.t0, release_y_m)
    metrics = pitch_metrics_from_flight(p_rel, v_rel, fit.spin, model, t0=t_rel)
    w_meas = cov_rel = None
    if spin_ok:
        f_rel = 1.0
        if model.kind == "nathan":  # the spin at release (before the first ball image: a little faster)
            n = model.nathan
            f_rel = float(np.exp(-(t_rel - fit.t0) * np.linalg.norm(v_rel) / (n.tau0 * n.v_ref)))
        w_meas, cov_rel = w0 * f_rel, cov0 * f_rel ** 2
    _set_spin_metrics(metrics, w_meas, v_rel)
    if not spin_ok:
        metrics.message = "; ".join(filter(None, [metrics.message, "spin unavailable (no usable markers)"]))
    sigma = metrics_sigma(fit, w_meas, cov_rel, model, t_rel, release_y_m, metrics, int(options.n_samples),
                          options.rng, options.sigma_method)
    timings["metrics"] = _time.perf_counter() - t
    release = {"t0_s": float(t_rel), "p0": p_rel, "v0": v_rel, "spin": w_meas,
               "speed_mph": float(np.linalg.norm(v_rel) / MPH),
               "spin_rpm": float(np.linalg.norm(w_meas) * RPM_PER_RAD_S) if spin_ok else None,
               "p0_sigma": fit.p0_sigma, "v0_sigma": fit.v0_sigma,
               "spin_sigma": np.sqrt(np.clip(np.diag(cov_rel), 0, None)) if spin_ok else None,
               "where": "at the front pair's first ball image" if release_y_m is None
               else f"at y = {options.release_y_ft:.2f} ft (release_y_ft)"}
    table1 = {k: float(v) for k, v in fit.seed_table_row().items()}
    table1["spin_rpm"] = float(np.linalg.norm(w0) * RPM_PER_RAD_S) if spin_ok else float("nan")
    table1["speed_sigma_mph"] = speed_sigma(fit.v0, fit.covariance[3:6, 3:6]) / MPH
    table1["spin_sigma_rpm"] = float(spin.sigma_rpm) if spin_ok else float("nan")
    return MetricsWithSigma(metrics, sigma, release, table1, v_two_sigma)


def _photo_of(cap: Capture, camera: str):
    """The photo of ``camera`` decoded again for the missed-ball check (the pairs' photos are
    released after their marker step), or None if the capture has none or it cannot be read."""
    im = next((im for im in cap.images if im.camera == camera), None)
    if im is None:
        return None
    try:
        return cap.read_image(im)
    except (ValueError, OSError):
        return None


def check_and_inflate(cap: Capture, pairs: list, flight: PositionsFit, measured: MeasuredSpin,
                      fit: ReferenceFit, flight_spin, spin_cmp, model, options: PitchOptions,
                      log: StageLog) -> tuple[list, ReferenceFit]:
    """5b. The self-checks (:mod:`stillcap.pipelines.pitch.checks`) and the flight's
    uncertainties grown by the pairs' disagreement (``max(1, chi2 / 3)`` of the worst
    ``pair_agreement`` check, on the fit's covariance and every pair's position covariances).

    Returns ``(checks, fit)`` (failed checks are in the result's ``self_checks``, which the CLI
    prints, not in its messages)."""
    from stillcap.pipelines.pitch.checks import (ambiguous_alias_candidates, disagreement_factor, pitch_self_checks,
                                                 widen_spin_for_aliases)

    t = _time.perf_counter()
    for p in pairs:
        p._check_cams = [cap.rig[c] for c in p.cameras]
    try:
        checks = pitch_self_checks(pairs, flight, measured, fit, flight_spin, spin_cmp, model, options,
                                   photo=lambda name: _photo_of(cap, name))
    finally:
        for p in pairs:
            del p._check_cams
    # an ambiguous alias (alias_margin failed) is never one confident value: the spin's
    # intervals cover every alias the photos allow, and the result names them
    others = ambiguous_alias_candidates(checks, measured.alias) if measured.ok else []
    if others:
        spin0 = measured.spin
        measured.spin, extra = widen_spin_for_aliases(spin0, others)
        r = float(np.linalg.norm(measured.w0)) / max(float(np.linalg.norm(spin0.spin)), 1e-12)
        measured.cov0 = measured.cov0 + extra * r * r
        log.messages.append(
            f"spin ambiguous: {spin0.spin_rpm:.0f} rpm or "
            + " or ".join(f"{c.spin_rpm:.0f} rpm (axis {np.degrees(np.arccos(np.clip(c.axis @ spin0.axis, -1, 1))):.0f} deg "
                          "from the reported one)" for c in others)
            + f": the reported intervals cover them all (+-{1.96 * measured.spin.sigma_rpm:.0f} rpm, "
            f"axis +-{2.45 * measured.spin.sigma_axis_deg:.0f} deg); photograph with two strobe rates")
    # misidentified markers (ball_layout failed) and a flight that disagrees: the spin's
    # intervals cover the spin the flight shows as well (checks.identity_candidates)
    if measured.ok and measured.spin is not None:
        from stillcap.pipelines.pitch.checks import identity_candidates
        from stillcap.pipelines.pitch.spin import ball_layout_check

        r = float(np.linalg.norm(measured.w0)) / max(float(np.linalg.norm(measured.spin.spin)), 1e-12)
        cands = identity_candidates(measured.spin, ball_layout_check(measured.spin, options.marker_layout),
                                    flight_spin, spin_cmp, r)
        if cands:
            spin0 = measured.spin
            measured.spin, extra = widen_spin_for_aliases(spin0, cands)
            measured.cov0 = measured.cov0 + extra * r * r
            log.messages.append(
                f"spin unreliable: the markers do not fit the ball's layout (misidentified?) and the flight's "
                f"curvature points to {cands[0].spin_rpm:.0f} rpm against the markers' {spin0.spin_rpm:.0f} rpm: "
                f"the reported intervals cover both (+-{1.96 * measured.spin.sigma_rpm:.0f} rpm, "
                f"axis +-{2.45 * measured.spin.sigma_axis_deg:.1f} deg)")
    f = disagreement_factor(checks)
    if f > 1.0:
        fit = fit.with_extra_covariance((f - 1.0) * fit.covariance)
        for p in pairs:
            if p.position_covariance_m2 is not None:
                p.position_covariance_m2 = p.position_covariance_m2 * f
            p.position_sigma_m *= float(np.sqrt(f))
        log.messages.append(f"the pairs disagree about the flight: its uncertainties scaled by {np.sqrt(f):.2f}")
    log.timings["self_checks"] = _time.perf_counter() - t
    return checks, fit


# --------------------------------------------------------------------------------------------
# Helpers of the stages
# --------------------------------------------------------------------------------------------
def _release_state(p0, v0, spin, model, t0, release_y_m):
    """Position, velocity and time where the flight crosses ``y = release_y_m`` (Newton on the
    reference integrator, before or after ``t0``)."""
    t = t0
    p, v = np.asarray(p0, float), np.asarray(v0, float)
    for _ in range(6):
        if abs(v[1]) < 1e-6:
            raise ValueError("the flight does not move along y: cannot evaluate a release plane")
        dt = (release_y_m - p[1]) / v[1]
        if abs(dt) < 1e-9:
            break
        t = t + dt
        tr = simulate(p0, v0, spin, [t], model, t0=t0)
        p, v = tr.positions[0], tr.velocities[0]
    return t, p, v


def _set_spin_metrics(metrics: PitchMetrics, w, v_rel) -> None:
    nan = float("nan")
    if w is None:
        metrics.spin_rate_rpm = metrics.active_spin_rpm = metrics.spin_efficiency = nan
        metrics.gyro_angle_deg = metrics.spin_axis_deg = nan
        metrics.spin_tilt = metrics.spin_direction_clock = ""
        return
    w = np.asarray(w, float)
    metrics.spin_rate_rpm = float(np.linalg.norm(w) * RPM_PER_RAD_S)
    metrics.spin_efficiency = float(spin_efficiency(w, v_rel))
    metrics.active_spin_rpm = metrics.spin_rate_rpm * metrics.spin_efficiency
    metrics.gyro_angle_deg = float(np.degrees(np.arccos(np.clip(metrics.spin_efficiency, 0.0, 1.0))))
    metrics.spin_axis_deg = float(spin_axis_deg(w, v_rel))
    metrics.spin_tilt = clock_tilt(metrics.spin_axis_deg) if np.isfinite(metrics.spin_axis_deg) else ""
    metrics.spin_direction_clock = clock_tilt(metrics.spin_axis_deg, resolution_min=1) if np.isfinite(metrics.spin_axis_deg) else ""
