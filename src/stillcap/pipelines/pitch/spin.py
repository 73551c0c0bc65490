"""The spin step of the pitch pipeline: a pair's markers and own spin (the per-pair job, on a
thread or in a worker process), the alias choice, and one spin over all pairs.

- :func:`pair_markers_and_spin`: the markers of one pair
  (:func:`stillcap.ball.markers.pair_marker_observations`) and the pair's own spin on its clock;
  it needs neither the flight fit nor the other pairs, so it runs alongside the positions-only fit.
- :func:`spin_stage`: the alias above the strobe's Nyquist limit chosen with both strobe rates
  and the flight's Magnus curvature (:mod:`stillcap.ball.alias`; a pair whose markers fix the
  ball's orientation at fewer than 2 flashes is no evidence while another pair's do), then (``"global"``) all pairs'
  markers refitted together on the reference clock at that alias, or (``"seed"``) the best
  pair's per-flash fit moved to it; with ``"global"`` the fit of all markers is started again
  from the flight's transverse spin (and, when the choice is in doubt, from the other aliases),
  and the solutions are ranked on all the markers and the curvature (:func:`_joint_decision`).
- :func:`flight_spin_stage`: the transverse spin the flight alone shows (the positions-only fit,
  :mod:`stillcap.ball.spin_from_flight`), and with a marker spin the test of the two against
  each other and the spin efficiency they give.
"""

from __future__ import annotations

import time as _time

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._selfcheck import SelfCheck
from stillcap.ball.fit import ReferenceFit
from stillcap.ball.markers import pair_marker_observations
from stillcap.ball.metrics import RPM_PER_RAD_S
from stillcap.ball.orientation import MarkerObservations, SpinResult, fit_spin, fit_spin_seed
from stillcap.ball.physics import FlightModel
from stillcap.ball.spin_from_flight import FlightSpin, SpinComparison, compare_spins, transverse_spin_from_fit
from stillcap.pipelines.pitch.result import PairResult

__all__ = ["pair_markers_and_spin", "spin_stage", "flight_spin_stage", "ball_layout_check", "spin_noise_check",
           "MARKER_NOISE_PX", "MIN_ORIENTATION_FLASHES"]


def pair_markers_and_spin(cams, imgs, pair: PairResult, types, layout, radius_m: float, max_px: float,
                          spin_method: str):
    """The marker step of one pair: :func:`~stillcap.ball.markers.pair_marker_observations` on
    its photos, then the pair's own spin (it needs only the pair's markers and flash indices, not
    the flight fit).

    Returns
    -------
    ((obs, markers, stats), spin, t_markers_s, t_spin_s)
        ``spin``: SpinResult, None, or the ValueError / LinAlgError of the fit (reported where
        the spin stage would report it).
    """
    t_job = _time.perf_counter()
    out = pair_marker_observations(
        cams[0], imgs[0], cams[1], imgs[1], pair.centers_px[0], pair.centers_px[1], pair.radius_px[0],
        pair.radius_px[1], pair.positions, types, layout, radius_m, max_px,
        blur_px=None if pair.stereo is None else pair.stereo.psf_px)
    t_mk = _time.perf_counter() - t_job
    try:
        spin = _fit_pair_spin(pair, spin_method, layout, observations=out[0])
    except (ValueError, np.linalg.LinAlgError) as e:
        spin = e
    return out, spin, t_mk, _time.perf_counter() - t_job - t_mk


def _fit_pair_spin(pair: PairResult, method: str, layout, spin_init=None, observations=None) -> SpinResult | None:
    """The spin of one pair's markers on its own clock (``observations`` instead of the pair's:
    the marker job on the worker pool runs it before they are stored on the pair)."""
    obs = pair.observations if observations is None else observations
    if obs is None or len(obs) == 0 or len(pair) < 2:
        return None
    t = pair.local_times
    if method == "seed":
        return fit_spin_seed(t, obs, layout, strobe_hz=pair.strobe_hz)
    # stop after the first start that explains 90 % of the markers (fit_spin: the same result on
    # the benchmark pitches, one fit instead of three)
    return fit_spin(t, obs, layout, strobe_hz=pair.strobe_hz, spin_init=spin_init, stop_fraction=0.9)


def _resolve_alias(pairs: list, fit_curv: ReferenceFit, model: FlightModel, messages: list):
    """Choose the spin alias with both strobe rates and the flight's Magnus curvature
    (:func:`stillcap.ball.alias.resolve_aliases`).

    Returns ``(spin vector (3,) or None, AliasResolution or None)``."""
    from stillcap.ball.alias import resolve_aliases

    meas, fixed = _strobe_measurements(pairs)
    if not meas:
        return None, None
    # A pair whose markers fix the ball's orientation at fewer than 2 flashes measures no
    # rotation per interval of its own: with about one marker per flash its constant-spin fit
    # chains the flashes through the model and can settle on a wrong minimum (rotations 40-180
    # deg per interval off, measured on the robustness benchmark's back pairs at 8-16 px ball
    # radius) whose covariance, a local one, is a few rpm or even zero. Such a pair's spin
    # chooses no alias while another pair's markers do fix two orientations (it still joins the
    # combined fit at the chosen alias, which keeps only the markers that agree).
    weak = [f is not None and f < MIN_ORIENTATION_FLASHES for f in fixed]
    if any(weak) and not all(weak):
        for m, f, w in zip(meas, fixed, weak):
            if w:
                messages.append(f"{m.name}: its own spin was not used to choose the alias (its markers fix the ball's "
                                f"orientation at {f} flash{'es' if f != 1 else ''}, fewer than "
                                f"{MIN_ORIENTATION_FLASHES})")
        meas = [m for m, w in zip(meas, weak) if not w]
    curv = _curvature(fit_curv, model)
    res = resolve_aliases(meas, curv)
    if res.left_out:
        messages.append(f"spin alias chosen without {', '.join(res.left_out)}: it contradicts the rest of the evidence, "
                        f"which agrees without it ({res.message})")
    if res.ambiguous:
        messages.append(f"spin rate ambiguous (aliasing above the strobe's Nyquist limit): {res.message}")
    elif len(meas) == 1 and curv is None:
        messages.append("spin alias checked with one strobe rate only")
    return res.best.spin.copy(), res


def _strobe_measurements(pairs: list):
    """Each pair's own spin as a :class:`~stillcap.ball.alias.StrobeMeasurement`, and how many
    flashes its inlier markers fix the ball's orientation at (:func:`_orientation_flashes`)."""
    from stillcap.ball.alias import StrobeMeasurement

    meas, fixed = [], []
    for p in pairs:
        s = p.spin
        if s is None or not s.success or not np.all(np.isfinite(s.spin)):
            continue
        cov = s.spin_covariance
        if not np.all(np.isfinite(cov)):  # e.g. the seed method with one interval: no spread
            cov = np.eye(3) * (20.0 / RPM_PER_RAD_S) ** 2
        meas.append(StrobeMeasurement(s.spin, p.strobe_hz, cov, f"pair {p.name} ({p.strobe_hz:g} Hz)"))
        fixed.append(_orientation_flashes(s, p.observations))
    return meas, fixed


def _curvature(fit_curv: ReferenceFit | None, model: FlightModel):
    """What the positions-only fit's curvature shows of the spin
    (:class:`~stillcap.ball.alias.CurvatureMeasurement`), or None without a usable fit."""
    from stillcap.ball.alias import CurvatureMeasurement

    if fit_curv is None or not np.all(np.isfinite(fit_curv.covariance[6:9, 6:9])):
        return None
    try:
        return CurvatureMeasurement.from_reference_fit(fit_curv, model)
    except ValueError:
        return None


#: Flashes at which a pair's own spin fit must have 2 or more inlier markers (the ball's
#: orientation fixed there) for its spin to count as alias evidence (:func:`_resolve_alias`):
#: two orientations give a rotation per interval of their own.
MIN_ORIENTATION_FLASHES = 2


def _orientation_flashes(spin: SpinResult, obs) -> int | None:
    """How many flashes have 2+ of the fit's inlier markers (two directions fix the ball's
    orientation); None when the fit does not say which observations it kept."""
    inl = getattr(spin, "inliers", None)
    if obs is None or inl is None or len(inl) != len(obs) or not len(obs):
        return None
    fl = np.asarray(obs.flash)[np.asarray(inl, bool)]
    return int(np.sum(np.bincount(fl) >= 2)) if len(fl) else 0


def _center_shift_modes(parts: list, center_modes: list, radius_m: float | None):
    """Each pair's ball-centre errors shared by its flashes, as ``fit_spin``'s
    ``center_shift_cov``: one array (M, 3) per error mode, the shift (ball radii) of the centre
    every observation's direction is measured from (the pairs' observations joined in order).

    The modes are the pair's shared position modes (``center_modes``, one (n_modes, K, 3) array
    in metres per part, or None; :func:`stillcap.ball.uncertainty.remaining_bias_modes` and the
    calibration modes): each camera's remaining shading bias moved along its own lit direction,
    constant and trending along the flight, re-triangulated. The same modes size the positions'
    intervals, so the spin and the flight state one error of the ball centres, with the light's
    direction in each image (an isotropic offset across the line of sight, the former model,
    overstated it: a shift along one camera's epipolar line moves the point along the other
    camera's ray, which turns none of that camera's marker directions). The marker directions
    all turn with a shared centre error, which the spin fit's own residuals cannot show. Parts
    without modes or without ray views add nothing.

    One more mode: the marker centroids' blur corrections' own error (``observations.blur_mode``,
    :func:`stillcap.detect._blur_shift.shading_blur_correction`), the same overcorrection in every
    photo, so again invisible in the residuals; a direction moved by a tangent ``d`` is the
    direction from a centre moved by ``-d``."""
    blur = [np.zeros((len(p.observations), 3)) if p.observations.blur_mode is None else p.observations.blur_mode
            for p in parts]
    out = [-np.concatenate(blur)] if any(np.any(b) for b in blur) else []
    if not radius_m or not radius_m > 0:
        return out
    n_all = sum(len(p.observations) for p in parts)
    start = 0
    for p, D in zip(parts, center_modes):
        o = p.observations
        n = len(o)
        if D is not None and o.views is not None and len(D) and D.shape[1] == len(p):
            for d in np.asarray(D, float):
                if not np.any(d):
                    continue
                e = np.zeros((n_all, 3))
                e[start:start + n] = d[o.flash] / radius_m
                out.append(e)
        start += n
    return out


def _combined_spin(pairs: list, spin_init, layout, messages, center_modes=None, radius_m: float | None = None,
                   aligned: dict | None = None):
    """One constant spin over all pairs' markers on the reference clock, started at ``spin_init``
    (None: the fit's own starts, per-flash alignments and the grid); ``center_modes`` (one per
    pair, or None) as :func:`_center_shift_modes`'s; ``aligned``: the flashes' type alignments kept
    over fits of the same markers (``fit_spin``'s ``flash_alignments``).

    Returns ``(SpinResult or None, reference-clock time of each observation)``."""
    parts, times, groups, modes = [], [], [], []
    center_modes = [None] * len(pairs) if center_modes is None else list(center_modes)
    for p, D in zip(pairs, center_modes):
        if p.observations is None or len(p.observations) == 0:
            continue
        parts.append(p)
        modes.append(D)
        times.append(p.times)
        groups.append(np.full(len(p), p.group))
    if not parts:
        return None, None
    # start at the orientation a pair's own fit found at its first flash, turned back to t = 0 at
    # the chosen alias (alias candidates agree at flash times): one start instead of four
    fitted = [p for p in parts
              if p.spin is not None and p.spin.success and np.all(np.isfinite(p.spin.ball2world_t0))]
    src = next((p for p in fitted if p.group == 0), max(fitted, key=lambda p: p.spin.n_inliers, default=None))
    if len(parts) == 1:
        p = parts[0]
        R_init = p.spin.ball2world_t0 if p is src else None
        return (fit_spin(p.local_times, p.observations, layout, strobe_hz=p.strobe_hz, spin_init=spin_init,
                         ball2world_init=R_init, center_shift_cov=_center_shift_modes(parts, modes, radius_m),
                         flash_alignments=aligned),
                p.times[p.observations.flash])
    R_init = None
    if src is not None and spin_init is not None:
        R_init = Rotation.from_rotvec(-np.asarray(spin_init, float) * src.times[0]).as_matrix() @ src.spin.ball2world_t0
    t_all = np.concatenate(times)
    order = np.argsort(t_all, kind="stable")
    if np.any(np.diff(t_all[order]) <= 0):
        messages.append("flashes of different pairs coincide in time: spin from the pairs separately")
        return None, None
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    obs_parts, start = [], 0
    for p in parts:
        o = p.observations
        obs_parts.append(o.with_flash(rank[start + o.flash]))
        start += len(p)
    obs = MarkerObservations.concatenate(obs_parts)
    ref = parts[0]
    t_sorted = t_all[order]
    # the other pairs' flashes sit on the reference clock through fitted offsets: their
    # uncertainty goes into the spin's covariance
    g_sorted = np.concatenate(groups)[order]
    n_g = int(g_sorted.max(initial=0))
    g_sig = np.zeros(n_g)
    for p in parts:
        if p.group > 0:
            g_sig[p.group - 1] = p.time_offset_sigma_s
    return (fit_spin(t_sorted, obs, layout, t0=0.0, strobe_hz=ref.strobe_hz, spin_init=spin_init,
                     ball2world_init=R_init, time_groups=g_sorted, time_group_sigma=g_sig,
                     center_shift_cov=_center_shift_modes(parts, modes, radius_m), flash_alignments=aligned),
            t_sorted[obs.flash])


def spin_stage(pairs, fit_pos, model, layout, method, messages, pair_spins=None, center_modes=None,
               radius_m: float | None = None):
    """Per-pair spin fits, the alias choice and the final spin: ``(SpinResult or None, alias
    resolution or None, reference-clock time of each observation of the final fit)``.
    ``pair_spins``: the per-pair fits already made (one per pair, in order), e.g. on the pool.
    ``center_modes``: each pair's shared ball-centre error modes (n_modes, K, 3), metres, or
    None (one per pair, in order), propagated into the final spin's covariance with the ball's
    ``radius_m`` (:func:`_center_shift_modes`)."""
    from stillcap.ball.alias import alias_candidates

    for i, p in enumerate(pairs):
        p.spin = _fit_pair_spin(p, method, layout) if pair_spins is None else pair_spins[i]
        if p.spin is not None and not p.spin.success:
            messages.append(f"pair {p.name!r}: spin not determined ({p.spin.message})")
    w_alias, alias = _resolve_alias(pairs, fit_pos, model, messages)
    if w_alias is None:
        messages.append("too few markers for a spin (need markers on 2+ flashes with 2+ types): spin unavailable")
        return None, alias, None
    best = max((p for p in pairs if p.spin is not None and p.spin.success), key=lambda p: p.spin.n_inliers)
    if method == "global":
        spin, obs_times = _combined_spin(pairs, w_alias, layout, messages, center_modes, radius_m)
        if spin is None or not spin.success:
            spin = _fit_pair_spin(best, "global", layout, spin_init=w_alias)
            obs_times = best.times[best.observations.flash]
        else:
            spin, obs_times, alias = _joint_decision(pairs, spin, obs_times, alias, _curvature(fit_pos, model), layout,
                                                     messages, center_modes, radius_m)
    else:
        spin = best.spin
        obs_times = best.times[best.observations.flash]
        # the seed method's rate is the principal alias of its strobe: move it to the chosen alias
        cands = alias_candidates(spin.spin, best.strobe_hz, max_rpm=max(4000.0, 1.5 * np.linalg.norm(w_alias)
                                                                        * RPM_PER_RAD_S))
        w = min((c.spin for c in cands), key=lambda c: float(np.linalg.norm(c - w_alias)))
        if np.linalg.norm(w - spin.spin) > 1e-9:
            spin = _with_spin(spin, w)
    if spin is not None and not spin.success:
        messages.append(f"spin fit failed: {spin.message}")
    return spin, alias, obs_times


#: Share of the marker observations the spin fit at the chosen alias must explain (inliers)
#: for the alias choice to stand without the other aliases' and the fit's own starts
#: (:func:`_joint_decision`); ``fit_spin``'s ``stop_fraction`` of the pairs' own fits.
JOINT_INLIER_SHARE = 0.9
#: Alias candidates of the strobe measurements refitted on all pairs' markers when the choice
#: is in doubt (:func:`_joint_decision`; the candidates are ranked, the rest are unlikely).
JOINT_MAX_CANDIDATES = 4


def _joint_decision(pairs: list, first: SpinResult, first_times, alias, curv, layout, messages: list,
                    center_modes=None, radius_m: float | None = None):
    """The alias and the minimum of the markers' fit decided on the full evidence: all pairs'
    markers together and the flight's curvature (:func:`stillcap.ball.alias.resolve_joint_fits`).

    The strobe measurements that chose the alias are the pairs' own fits; a pair whose few
    markers fix the ball's orientation at one flash can settle on a wrong minimum (issue 12,
    "light to the side" #0: the front pair's own fit found the right rate about an axis 91 deg
    off; the fit of all pairs' markers started there kept 10 of 14 markers, started from the
    flight's transverse spin it kept all 14, 1.0 deg RMS, and agreed with the curvature). So
    the fit of all markers is started again from the flight's transverse spin
    (:func:`~stillcap.ball.alias.flight_informed_spin`), and, when the choice is in doubt (the
    strobe evidence ambiguous or contradicting itself, the first fit explaining fewer than
    ``JOINT_INLIER_SHARE`` of the markers or disagreeing with the curvature), from the other
    alias candidates, their flight-informed versions and the fit's own starts. The solutions
    are ranked on the markers and the curvature. The first fit and the strobes' ranking stand
    unless another solution scores better or comes within the ambiguity margin; otherwise the
    joint ranking replaces them (its ``ambiguous`` widens the intervals through the
    ``alias_margin`` check as before).

    Returns ``(spin, reference-clock time of each observation, alias resolution)``."""
    from scipy.special import chdtri

    from stillcap.ball.alias import curvature_chi2, flight_informed_spin, resolve_joint_fits, same_solution

    if alias is None or first is None or not np.all(np.isfinite(first.spin)):
        return first, first_times, alias
    doubt = (bool(alias.ambiguous) or not bool(alias.consistent)
             or first.n_inliers < JOINT_INLIER_SHARE * first.n_observations
             or (curv is not None and curvature_chi2(curv, first.spin) > float(chdtri(2, 1e-3))))
    starts = [] if curv is None else [flight_informed_spin(curv, first.spin)]
    if doubt:
        for c in alias.candidates[1:JOINT_MAX_CANDIDATES + 1]:
            starts.append(np.asarray(c.spin, float))
            if curv is not None:
                starts.append(flight_informed_spin(curv, c.spin))
        starts.append(None)
    if not starts:
        return first, first_times, alias
    sols, sol_times = [first], [first_times]
    scratch: list = []
    aligned: dict = {}  # the flashes' type alignments, made once for all these fits of the same markers
    for w in starts:
        try:
            s, t = _combined_spin(pairs, w, layout, scratch, center_modes, radius_m, aligned)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if (s is not None and s.success and np.all(np.isfinite(s.spin)) and np.all(np.isfinite(s.spin_covariance))
                and len(s.residuals_deg) == len(first.residuals_deg)):
            sols.append(s)
            sol_times.append(t)
    meas, _ = _strobe_measurements(pairs)
    strobes = sorted({float(p.strobe_hz) for p in pairs if p.observations is not None and len(p.observations)})
    joint = resolve_joint_fits(sols, curv, meas, strobes_hz=strobes)
    if joint.undecided:
        # the markers fit another rotation per interval as well as the best: they do not decide
        # the spin, and the minima found are only a sample of those they allow (issue 12,
        # "everything varied" #0: 5 observations, two cut by the limb, 1 degree of freedom; three
        # minima 1093-1467 rpm with axes up to 131 deg apart, the truth none of them). The spin is
        # withheld rather than one minimum reported with its local covariance (docs/spin.md).
        messages.append(
            f"spin undetermined (spin alias undecided): {joint.undecided_text()} ({first.n_observations} "
            f"observations, {joint.marker_dof} degrees of freedom left for their noise): the marker spin is withheld")
        joint.withheld = sols[joint.best.source]
        return None, None, joint
    if not doubt and not joint.ambiguous and (
            joint.best.source == 0 or same_solution(first, sols[joint.best.source])):
        # the strobes' choice stands, unchanged (also when a refit lands on the same solution, within
        # the two fits' covariances, and scores a hair better: the same spin, not a new decision)
        return first, first_times, alias
    chosen = sols[joint.best.source]
    if joint.best.source != 0:
        ang = float(np.degrees(np.arccos(np.clip(chosen.axis @ first.axis, -1, 1))))
        messages.append(f"spin decided on all pairs' markers and the flight: {chosen.spin_rpm:.0f} rpm (explains "
                        f"{chosen.n_inliers} of {chosen.n_observations} markers) in place of the strobes' choice "
                        f"{first.spin_rpm:.0f} rpm (axis {ang:.0f} deg away, explains {first.n_inliers}): "
                        f"{joint.message}")
    return chosen, sol_times[joint.best.source], joint


def _with_spin(res: SpinResult, w) -> SpinResult:
    """A copy of a spin result moved to another alias ``w`` (same axis line, rate from the alias)."""
    from dataclasses import replace as _replace

    w = np.asarray(w, float)
    n = float(np.linalg.norm(w))
    return _replace(res, spin=w.copy(), spin_rpm=n * RPM_PER_RAD_S, axis=w / n if n > 0 else np.full(3, np.nan),
                    message=f"{res.message}; alias chosen with both strobe rates and the flight curvature")


def flight_spin_stage(fit_positions: ReferenceFit, model, spin_ok: bool, w0, cov0,
                      messages: list) -> tuple[FlightSpin | None, SpinComparison | None]:
    """The spin from the flight alone (the positions-only fit, no refit) and, with a marker spin
    ``w0`` (covariance ``cov0``, both at ``t = 0`` of the reference clock like the fit's ``t0``),
    their comparison. Without markers the flight spin is what the result reports as its spin
    (flagged ``"source": "flight"``, transverse only): a message says so. A flight spin that
    cannot be had (a failed fit) gives None and a message, never an error."""
    try:
        fs = transverse_spin_from_fit(fit_positions, model=model)
    except (ValueError, np.linalg.LinAlgError) as e:
        messages.append(f"spin from flight unavailable ({e})")
        return None, None
    if not spin_ok:
        what = "total rate along the transverse axis" if fs.lift_from == "total" else "transverse spin only"
        messages.append(f"spin from flight alone ({what}): {fs.rate_rpm:.0f} +- {fs.rate_sigma_rpm:.0f} rpm, axis "
                        f"+- {fs.axis_sigma_deg:.1f} deg")
        return fs, None
    return fs, compare_spins(fs, w0, cov0)


#: Largest RMS angle, deg, between the observed marker directions and the fitted markers of the
#: ball's layout (the spin fit's inliers) before the ``ball_layout`` self-check fails. Measured
#: (docs/ball-format.md, "Checking the layout"): 0.9-2.7 deg with the ball's own layout on the
#: studio's captures (1280-2560 px photos), 5-13 deg with another ball's layout.
LAYOUT_RMS_LIMIT_DEG = 4.0


def ball_layout_check(spin: SpinResult | None, layout) -> SelfCheck | None:
    """Self-check ``ball_layout``: do the markers seen fit the ball's layout?

    The spin fit rotates the layout onto the observed marker directions; with the wrong layout
    (another ball, markers painted elsewhere, colours assigned differently) the best rotation
    leaves large residuals. None when no spin was fitted."""
    if spin is None or not spin.success or not spin.n_inliers:
        return None
    rms = float(spin.rms_deg)
    share = 1.0 - spin.n_inliers / max(spin.n_observations, 1)
    ok = bool(rms <= LAYOUT_RMS_LIMIT_DEG)
    msg = (f"the {spin.n_inliers} markers the spin fit uses lie {rms:.1f} deg RMS from the {layout.name} layout's "
           f"markers ({100 * share:.0f} % of the {spin.n_observations} observations left out)")
    if not ok:
        msg += (f"; more than {LAYOUT_RMS_LIMIT_DEG:g} deg: the painted markers do not match the ball's layout - "
                "give the ball file of the ball photographed (--ball, capture.json ball); the spin is unreliable")
    return SelfCheck("ball_layout", ok, rms, LAYOUT_RMS_LIMIT_DEG, msg, layout.name, "deg")


#: The centroid noise, px (1-sigma per image coordinate), of markers seen whole that the
#: ``spin_noise`` self-check states. Measured (``benchmarks/bench_spin_conditions.py``, the
#: robustness benchmark's photos at 1280x960, 15 px ball radius): 0.08-0.13 px on clean photos,
#: 0.28-0.45 px with 1.5 px of lens blur, up to 0.56 px with every condition varied at once, and
#: 3.5 px where the markers matched no rotation of the layout (a wrong alias with a wrong ball
#: file). A user whose photos are blurrier or whose markers are smaller states their own.
MARKER_NOISE_PX = 0.7


def spin_noise_check(spin: SpinResult | None, stated_px: float = MARKER_NOISE_PX,
                     p_false: float = 1e-3) -> SelfCheck | None:
    """Self-check ``spin_noise``: do the spin fit's residuals exceed the stated marker noise?

    The global fit weighs every marker observation by how precisely its centroid fixes its
    direction (:func:`stillcap.ball.orientation.direction_information`) and estimates the
    centroid noise in pixels from its residuals (``SpinResult.noise_px``: markers seen whole;
    the spin's intervals are scaled by it, so they grow with the misfit). The check fails when
    that noise is larger than ``stated_px`` beyond chance: ``dof s^2 / stated^2`` above the
    chi-square quantile ``1 - p_false`` with the fit's degrees of freedom. A failure means the
    markers do not follow one constant spin as well as markers are found: misidentified markers,
    wrong ball centres, a wrong layout or a ball that is not a rigid constant spinner; or photos
    whose markers are blurrier than stated. None when the fit has no pixel noise (no weights)."""
    if spin is None or not spin.success or not np.isfinite(getattr(spin, "noise_px", np.nan)):
        return None
    # chi2.ppf(q, k) is 2 gammaincinv(k / 2, q), as in pipelines/pitch/checks.py: importing
    # scipy.stats would cost 0.1-1 s of every CLI call
    from scipy.special import gammaincinv

    dof = max(int(spin.dof), 1)
    stat = dof * (spin.noise_px / stated_px) ** 2
    limit = float(2.0 * gammaincinv(dof / 2.0, 1.0 - p_false))
    ok = bool(stat <= limit)
    msg = (f"the markers lie {spin.noise_px:.2f} px (1-sigma) from the fitted constant spin, against "
           f"{stated_px:g} px stated (chi-square {stat:.0f} for {dof} degrees of freedom, limit {limit:.0f})")
    if not ok:
        msg += (": the markers do not follow one spin - misidentified markers, wrong ball centres or a wrong "
                "ball layout; the spin's intervals have been widened by the misfit, but the spin may be wrong")
    return SelfCheck("spin_noise", ok, float(spin.noise_px), float(stated_px), msg, "", "px")
