"""The hand pipeline (SPEC J2): multi-exposure photos of a gloved hand -> labelled 3D markers,
hand poses per flash, a smooth animation, and the ball's release.

Wiring only; every step is a stage of its own module (``docs/hand-pipeline.md`` tells the story):

1. **Stereo pairs** (:func:`stillcap.io.capture.stereo_pairs`): the capture's photos grouped
   into strobed stereo pairs; all pairs share one strobe.
2. **Ball** (:func:`stillcap.pipelines.hand_ball.hand_ball_positions`): the white ball's centre
   per flash from all views; its discs are masked out of the marker search so that its painted
   markers are not taken for glove markers.
3. **Markers** (:func:`stillcap.detect.colour_markers.find_colour_markers`): colour intervals,
   connected regions above a minimum size, centroids.
4. **3D markers** (:func:`stillcap.geometry.marker_points.triangulate_colour_markers`): epipolar
   matching per stereo pair, triangulation, a marker seen by both pairs merged; with the strobe's
   position known (``capture.json`` meta ``strobe_position_m`` or the option), the half-lit
   centroid bias is removed.
5. **Labels** (:func:`stillcap.body.hand_label.label_hand_markers`): 3D markers clustered into
   hand poses per flash, ordered in time, labelled by colour and fit to the hand model with
   optimal assignment; manual overrides from a file.
6. **Poses** (:func:`stillcap.body.hand_track.fit_hand_sequence`): rigid alignment of the back of
   the hand, then the fingers down their hierarchy, within the joint limits, for every flash
   whose three back-of-hand markers were found.
7. **Animation** (:func:`stillcap.body.hand_track.interpolate_animation`): keyframe interpolation
   of the joint rotations.
8. **Release** (:func:`stillcap.ball.release.estimate_release`) and the free ball's spin
   (:func:`stillcap.pipelines.hand_ball.hand_ball_spin`, only when two free flashes show markers).

Times are seconds after the first flash in which the hand was found (the strobe runs free, so
the photos do not tell the time since the shutter opened). SI inside; :meth:`HandResult.to_dict`
names units in its keys and shares key names with the studio's ``truth.json``.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.layout import BASEBALL_RADIUS
from stillcap.ball.flashes import number_flashes
from stillcap.ball.release import Release, estimate_release
from stillcap.body.hand import HAND_COLOURS
from stillcap.body.hand_label import HandLabels, label_hand_markers
from stillcap.body.markerset import MarkerTrajectories
from stillcap.body.hand_track import HandSequence, fit_hand_sequence, interpolate_animation, observed_dofs
from stillcap.body.skeleton import Animation
from stillcap.detect.colour_markers import ColourBlobs, find_colour_markers
from stillcap.geometry.marker_points import MarkerPoints, triangulate_colour_markers
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.files.jsonable import from_jsonable, to_jsonable
from stillcap.pipelines.hand_ball import HandBalls, HandBallSpin, hand_ball_positions, hand_ball_spin
from stillcap.pipelines.progress import report_progress

__all__ = ["HandOptions", "HandResult", "analyse_hand", "compare_with_truth", "truth_arrays"]

#: Position uncertainty of fully seen and of partly hidden glove markers (m), as measured by
#: ``benchmarks/bench_hand_markers.py`` (0.16 mm RMS and a few mm): the pose fit's weights.
SEEN_SIGMA_M, HIDDEN_SIGMA_M = 0.0003, 0.003
#: A label is right when the true marker nearest its point is the one it names and within this
#: distance (m); farther, the point is spurious.
LABEL_TOLERANCE_M = 0.010


@dataclass
class HandOptions:
    """How :func:`analyse_hand` runs.

    Attributes
    ----------
    strobe_position_m : (3,) or None
        The strobe's position in the rig world (m); default from ``capture.json`` meta
        ``strobe_position_m``. Without it the half-lit marker bias stays in the positions.
    overrides : path or None
        Manual label corrections (``docs/hand-labelling.md``).
    personalise : {None, "best", "joint"}
        Scale the hand model to the person from the markers first.
    frame_rate : float
        Frames per second of the interpolated animation.
    interpolation : {"spline", "slerp"}
    marker_radius_m, ball_radius_m : float
    spin : bool
        Try the free ball's spin (needs two free-flight flashes with markers).
    """

    strobe_position_m: tuple | None = None
    overrides: str | Path | None = None
    personalise: str | None = None
    frame_rate: float = 1000.0
    interpolation: str = "spline"
    marker_radius_m: float = 0.005
    ball_radius_m: float = BASEBALL_RADIUS
    spin: bool = True

    def __post_init__(self):
        if self.interpolation not in ("spline", "slerp"):
            raise ValueError(f"interpolation must be 'spline' or 'slerp', got {self.interpolation!r}")
        if self.personalise not in (None, "best", "joint"):
            raise ValueError(f"personalise must be None, 'best' or 'joint', got {self.personalise!r}")
        if not (np.isfinite(self.frame_rate) and self.frame_rate > 0):
            raise ValueError(f"frame_rate must be a positive number of frames per second, got {self.frame_rate}")


@dataclass
class HandResult:
    """What :func:`analyse_hand` found (rig world frame, SI, times after the first hand flash).

    Attributes
    ----------
    capture : Capture
    strobe_hz : float
    pairs : list of str
    blobs : list of ColourBlobs
        Coloured blobs per camera (rig order).
    points : MarkerPoints
        Unlabelled 3D markers of all flashes.
    labels : HandLabels
    sequence : HandSequence or None
        Poses of the reconstructed flashes (None when no flash could be reconstructed).
    animation : Animation or None
        Keyframe-interpolated motion (None with fewer than two poses).
    balls : HandBalls or None
    release : Release or None
    spin : HandBallSpin or None
    messages : list of str
    timings_s : dict
    truth : dict or None
        :func:`compare_with_truth` when the capture has a truth file.
    """

    capture: Capture
    strobe_hz: float
    pairs: list
    blobs: list
    points: MarkerPoints
    labels: HandLabels
    sequence: HandSequence | None
    animation: Animation | None
    balls: HandBalls | None
    release: Release | None
    spin: HandBallSpin | None
    messages: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)
    truth: dict | None = None

    @property
    def skeleton(self):
        return self.sequence.skeleton if self.sequence is not None else self.labels.skeleton

    @property
    def markers(self) -> MarkerTrajectories:
        """The labelled markers per flash (for the C3D/CSV exporters)."""
        lab = self.labels
        n_frames = int(lab.order.max()) + 1 if lab.n_flashes else 0
        pts = np.full((n_frames, len(lab.marker_names), 3), np.nan)
        pts[lab.order] = lab.positions  # one frame per strobe period: missed flashes stay NaN
        return MarkerTrajectories(list(lab.marker_names), pts, self.strobe_hz)

    def ball_held(self) -> dict:
        """``{flash number (labels.order): True if the ball is in the hand, False if free}`` for
        the flashes that show the ball (empty without a release estimate)."""
        if self.release is None or self.balls is None:
            return {}
        return {int(k): bool(h) for k, h in zip(self.balls.flash_index, self.release.held)}

    def to_dict(self) -> dict:
        """JSON-ready; keys shared with the hand truth (``flashes.times_s``, ``markers``,
        ``angles_deg``, ``root2world``, ``joints``, ``release``)."""
        lab = self.labels
        flashes = {"times_s": lab.times.tolist(), "order": lab.order.tolist(),
                   "reconstructed": lab.reconstructed.tolist(), "skipped": list(lab.skipped),
                   "markers": lab.positions, "fit_rms_mm": lab.rms * 1e3}
        seq = self.sequence
        if seq is not None:
            nf, nj = lab.n_flashes, seq.skeleton.n_joints
            ang, r2w, joints = (np.full((nf, nj, 3), np.nan), np.full((nf, 4, 4), np.nan),
                                np.full((nf, nj, 3), np.nan))
            for k, p, a in zip(seq.flashes, seq.poses, seq.angles_deg):
                ang[k], r2w[k], joints[k] = a, p.root2world, p.positions
            flashes.update(angles_deg=ang, root2world=r2w, joints=joints)
        d = {"kind": "hand", "frame": self.capture.rig.world,
             "units": {"length": "m", "time": "s (after the first flash with the hand)", "angle": "deg"},
             "strobe_hz": self.strobe_hz, "pairs": self.pairs, "marker_names": list(lab.marker_names),
             "marker_colours": list(lab.marker_colours), "joint_names": list(self.skeleton.names),
             "flashes": flashes, "points": self.points.to_dict(),
             "scales": None if seq is None else seq.scales,
             "ball": None if self.balls is None else self.balls.to_dict(),
             "release": None if self.release is None else self.release.to_dict(),
             "spin": None if self.spin is None else _spin_dict(self.spin),
             "messages": list(self.messages), "timings_s": dict(self.timings_s)}
        if self.truth is not None:
            d["truth_comparison"] = self.truth
        return to_jsonable(d)


def _spin_dict(s: HandBallSpin) -> dict:
    rpm = float(np.linalg.norm(s.spin) * 60 / (2 * np.pi)) if s.available else None
    return {"available": s.available, "spin": s.spin.tolist(), "spin_rpm": rpm,
            "candidates_rpm": list(s.candidates_rpm), "ambiguous": s.ambiguous, "message": s.message}


def analyse_hand(capture: Capture | str | Path, options: HandOptions | None = None, *,
                 progress: Callable[[int, int, str], None] | None = None, **kwargs) -> HandResult:
    """Analyse one hand capture (SPEC J2): markers, labels, poses, animation, ball release.

    Parameters
    ----------
    capture : Capture or path
        A capture folder (``kind: hand``) with one multi-exposure photo per camera of two or
        more stereo pairs (``images[].meta.pair`` or the capture's ``pairs`` map), all lit by
        one strobe (``strobe_hz``).
    options : HandOptions, optional
        Or its fields as keyword arguments.
    progress : callable(done, total, label), optional

    Returns
    -------
    HandResult

    Raises
    ------
    ValueError
        Not a hand capture, no complete stereo pair, pairs with different strobes, an
        unreadable photo, or no glove marker in 3D. A capture where no flash shows the three
        back-of-hand markers still gives its 3D markers; the result says why in ``messages``.
    """
    t_all = _time.perf_counter()
    if options is None:
        options = HandOptions(**kwargs)
    elif kwargs:
        raise ValueError("give either options or keyword arguments, not both")
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    where = f"capture {cap.root}" if cap.root is not None else "capture"
    if cap.kind != "hand":
        raise ValueError(f"{where} is a {cap.kind!r} capture, not a hand capture (capture.json \"kind\")")
    specs, messages = stereo_pairs(cap)
    rates = {sp.strobe_hz for sp in specs}
    if len(rates) != 1:
        raise ValueError(f"{where}: the stereo pairs have different strobe rates {sorted(rates)} Hz; "
                         "a hand capture is lit by one strobe")
    strobe_hz = rates.pop()
    pairs = {sp.name: sp.cameras for sp in specs}
    light = options.strobe_position_m if options.strobe_position_m is not None else cap.meta.get("strobe_position_m")
    if light is not None:
        light = as_array(light, (3,), "strobe_position_m")
    else:
        messages.append("strobe position unknown (capture.json meta strobe_position_m): marker centroids keep "
                        "their half-lit bias (~1 px)")
    timings: dict = {}
    total = 7

    t = _time.perf_counter()
    report_progress(progress, 0, total, "reading photos")
    rig = cap.rig
    used = [c for sp in specs for c in sp.cameras]
    images = []
    for name in rig.names:
        ims = cap.images_of(name)
        images.append(cap.read_image(ims[0]) if (name in used and ims) else None)
    timings["decode"] = _time.perf_counter() - t

    # -- ball ---------------------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 1, total, "ball")
    balls = None
    try:
        # every two cameras, not only the stereo pairs: fingers often hide the first free ball
        # from one camera of each pair (docs/hand-ball.md)
        balls = hand_ball_positions(rig, "all", images=images, ball_radius_m=options.ball_radius_m,
                                    strobe_hz=strobe_hz)
        messages.extend(balls.messages)
    except ValueError as e:
        messages.append(f"ball: {e}")
    timings["ball"] = _time.perf_counter() - t

    # -- markers ------------------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 2, total, "glove markers")
    blobs = []
    for i, img in enumerate(images):
        if img is None:
            blobs.append(ColourBlobs.empty())
            continue
        exclude = balls.ball_discs_px(i) if balls is not None and len(balls) else None
        blobs.append(find_colour_markers(img, HAND_COLOURS, exclude=exclude))
    timings["markers"] = _time.perf_counter() - t
    t = _time.perf_counter()
    report_progress(progress, 3, total, "3D markers")
    points = triangulate_colour_markers(rig, pairs, blobs, light_position=light, radius_m=options.marker_radius_m)
    doubtful = points.partly_hidden & points.ambiguous
    if doubtful.any():
        # a partly hidden blob whose match no third view confirmed: on the benchmark these are
        # the points that get wrong labels; one view less is cheaper than a wrong label
        messages.append(f"{int(doubtful.sum())} partly hidden, unconfirmed 3D marker(s) left out")
        points = points.select(~doubtful)
    if len(points) == 0:
        raise ValueError(f"{where}: no glove marker seen by both cameras of a pair "
                         f"(blobs per camera: {dict(zip(rig.names, (len(b) for b in blobs)))})")
    timings["triangulation"] = _time.perf_counter() - t

    # -- labels and poses ---------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 4, total, "labelling")
    labels = label_hand_markers(points.points, points.colours, strobe_hz=strobe_hz,
                                reprojection_px=points.reprojection_px, overrides=options.overrides)
    for k, why in enumerate(labels.skipped):
        if why:
            messages.append(f"flash {int(labels.order[k])}: no pose ({why})")
    timings["labels"] = _time.perf_counter() - t
    t = _time.perf_counter()
    report_progress(progress, 5, total, "poses")
    sequence = animation = None
    if labels.reconstructed.any():
        # partly hidden markers' centroids shift by up to a few mm (docs/hand-markers.md): they
        # count 10x less in the pose fit than fully seen ones, and less still the less of their
        # light a view got (flux ratio: 1 unhidden, 0.01 a sliver)
        flux = np.where(np.isfinite(points.flux_ratio), points.flux_ratio, np.inf).min(axis=0)
        flux = np.clip(np.where(np.isfinite(flux), flux, 1.0), 0.02, 1.0)
        sigma = np.where(points.partly_hidden, HIDDEN_SIGMA_M / flux, SEEN_SIGMA_M)
        sequence = fit_hand_sequence(labels, personalise=options.personalise, times=labels.times,
                                     point_sigma_m=sigma)
        if sequence.n >= 2:
            animation = interpolate_animation(sequence, options.frame_rate, method=options.interpolation)
        else:
            messages.append("one pose only: no animation")
    else:
        messages.append("no flash shows the three back-of-hand markers: no hand pose")
    timings["poses"] = _time.perf_counter() - t

    # -- release and spin ----------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 6, total, "release")
    release = spin = None
    if balls is not None and len(balls) and sequence is not None:
        hold_times = sequence.times
        r2w = sequence.root2world
        balls = _on_hand_clock(balls, hold_times, r2w, strobe_hz, messages)
        release = estimate_release(balls.times, balls.positions, hold_times, r2w, strobe_hz=strobe_hz,
                                   position_sigma_m=balls.sigma_m)
        if release.message:
            messages.append(f"release: {release.message}")
        if options.spin and release.success:
            spin = hand_ball_spin(rig, balls, ~release.held, pairs=pairs, images=images)
            if spin.message:
                messages.append(f"spin: {spin.message}")
    timings["release"] = _time.perf_counter() - t
    report_progress(progress, total, total, "done")
    timings["total"] = _time.perf_counter() - t_all
    res = HandResult(cap, strobe_hz, list(pairs), blobs, points, labels, sequence, animation, balls, release, spin,
                     messages, timings)
    if cap.truth is not None and cap.truth.get("kind") == "hand":
        res.truth = compare_with_truth(res, cap.truth)
    return res


def _on_hand_clock(balls: HandBalls, hold_times, root2world, strobe_hz: float, messages: list) -> HandBalls:
    """Renumber the ball's flashes from the hand poses (:func:`stillcap.ball.flashes.number_flashes`):
    the ball was found before the hand (its discs mask the glove-marker search), numbered from
    its spacing, which a missed flash of an accelerating arm gets wrong."""
    fn = number_flashes(balls.positions, hold_times, root2world, strobe_hz=strobe_hz)
    if not fn.success:
        messages.append(f"ball: {fn.message}; flashes numbered from the ball's spacing")
        return balls
    return replace(balls, flash_index=np.asarray(fn.flash, int), times=np.asarray(fn.times, float))


# --------------------------------------------------------------------------------------------
# Comparison with the studio's truth
# --------------------------------------------------------------------------------------------
def truth_arrays(truth: dict) -> dict:
    """The arrays of a hand ``truth.json`` (dict) by name: ``times``, ``markers``, ``angles_deg``,
    ``root2world``, ``joints``, ``visible`` (per camera), ``ball`` (centres); NaN for null."""
    f = truth["flashes"]
    n, nm, nj = len(f["times_s"]), len(truth["marker_names"]), len(truth["joint_names"])
    nc = len(truth["cameras"])
    return {"times": from_jsonable(f["times_s"]).reshape(n),
            "markers": from_jsonable(f["markers"]).reshape(n, nm, 3),
            "angles_deg": from_jsonable(f["angles_deg"]).reshape(n, nj, 3),
            "root2world": from_jsonable(f["root2world"]).reshape(n, 4, 4),
            "joints": from_jsonable(f["joints"]).reshape(n, nj, 3),
            "visible": from_jsonable(f["markers_visible"]).reshape(nc, n, nm).astype(bool),
            "ball": from_jsonable(f["ball2world"]).reshape(n, 4, 4)[:, :3, 3]}


def compare_with_truth(result: HandResult, truth: dict) -> dict:
    """Errors of a hand result against the studio's ``truth.json`` (dict).

    Flashes are matched by time: the result's clock starts at its first hand flash, so the
    offset to the truth's clock is the one that puts the result's flashes on truth flashes
    (the nearest back-of-hand position decides the first). Returns counts and errors in mm,
    deg, ms and mph (keys named with their units).
    """
    from stillcap.body.hand import hand_dofs

    tr = truth_arrays(truth)
    lab = result.labels
    names = list(lab.marker_names)
    if names != list(truth["marker_names"]):
        raise ValueError("the result's markers are not the truth's (different marker sets)")
    # match flashes: the result's first flash is the truth flash whose back of the hand is nearest
    back = [names.index(n) for n in ("back.1", "back.2", "back.3")]
    period = 1.0 / result.strobe_hz
    match = np.full(lab.n_flashes, -1)
    best = None
    for k in range(lab.n_flashes):
        b = lab.positions[k, back]
        if np.all(np.isfinite(b)):
            d = np.nanmean(np.linalg.norm(tr["markers"][:, back] - b[None], axis=2), axis=1)
            j = int(np.argmin(d))
            best = (k, j)
            break
    if best is not None:
        k0, j0 = best
        t_off = tr["times"][j0] - lab.times[k0]
        for k in range(lab.n_flashes):
            j = int(np.argmin(np.abs(tr["times"] - (lab.times[k] + t_off))))
            if abs(tr["times"][j] - (lab.times[k] + t_off)) < 0.25 * period:
                match[k] = j
    else:
        t_off = np.nan
    # labels and marker errors: a label is right when the true marker nearest its point (same
    # flash) is the one it names, within LABEL_TOLERANCE_M (farther: a spurious point)
    n_lab = n_right = 0
    errs = []
    for k in range(lab.n_flashes):
        if match[k] < 0:
            n_lab += int(np.sum(lab.point_index[k] >= 0))
            continue
        T = tr["markers"][match[k]]
        for j in range(len(names)):
            if lab.point_index[k, j] < 0:
                continue
            n_lab += 1
            d = np.linalg.norm(T - lab.positions[k, j], axis=1)
            if int(np.nanargmin(d)) == j and d[j] <= LABEL_TOLERANCE_M:
                n_right += 1
                errs.append(d[j])
    errs = np.asarray(errs)
    # markers the truth shows in 2+ cameras, per matched flash
    seen2 = tr["visible"].sum(axis=0) >= 2
    n_seen2 = int(sum(seen2[j].sum() for j in match if j >= 0))
    # joint angles: on the degrees of freedom the seen markers fix, and on all of them
    ang_err, ang_all, joint_err = [], [], []
    seq = result.sequence
    if seq is not None:
        dofs = hand_dofs(seq.skeleton)
        for i, (k, a, p) in enumerate(zip(seq.flashes, seq.angles_deg, seq.poses)):
            j = match[k]
            if j < 0:
                continue
            ang_all.extend(a[q, ax] - tr["angles_deg"][j, q, ax] for q, ax in dofs)
            ang_err.extend(a[q, ax] - tr["angles_deg"][j, q, ax] for q, ax in observed_dofs(seq, i))
            joint_err.extend(np.linalg.norm(p.positions - tr["joints"][j], axis=1))
    ang_all = np.asarray(ang_all)
    ang_err, joint_err = np.asarray(ang_err), np.asarray(joint_err)
    back_seen = (tr["visible"][:, :, back].sum(axis=0) >= 2).all(axis=1)
    out = {"flashes_true": len(tr["times"]), "flashes_back_seen_2plus": int(back_seen.sum()),
           "flashes_found": int(lab.n_flashes), "flashes_matched": int(np.sum(match >= 0)),
           "flashes_reconstructed": int(lab.reconstructed.sum()),
           "flash_match": match.tolist(), "clock_offset_s": float(t_off),
           "labels": n_lab, "labels_right": n_right,
           "labels_right_pct": 100.0 * n_right / n_lab if n_lab else None,
           "markers_seen_2plus": n_seen2, "markers_recovered_pct": 100.0 * n_right / n_seen2 if n_seen2 else None,
           "marker_rms_mm": float(np.sqrt(np.mean(errs ** 2)) * 1e3) if len(errs) else None,
           "marker_max_mm": float(errs.max() * 1e3) if len(errs) else None,
           "joint_angle_rms_deg": float(np.sqrt(np.mean(ang_err ** 2))) if len(ang_err) else None,
           "joint_angle_max_deg": float(np.abs(ang_err).max()) if len(ang_err) else None,
           "joint_angles_compared": len(ang_err),
           "joint_angle_rms_all_deg": float(np.sqrt(np.mean(ang_all ** 2))) if len(ang_all) else None,
           "joint_rms_mm": float(np.sqrt(np.mean(joint_err ** 2)) * 1e3) if len(joint_err) else None}
    if result.balls is not None and len(result.balls) and np.isfinite(t_off):
        be = []
        for tb, pb in zip(result.balls.times, result.balls.positions):
            j = int(np.argmin(np.abs(tr["times"] - (tb + t_off))))
            if abs(tr["times"][j] - (tb + t_off)) < 0.25 * period:
                be.append(np.linalg.norm(pb - tr["ball"][j]))
        out["ball_positions"] = len(be)
        out["ball_mean_mm"] = float(np.mean(be) * 1e3) if be else None
        out["ball_max_mm"] = float(np.max(be) * 1e3) if be else None
    rel = result.release
    if rel is not None and rel.success and np.isfinite(t_off):
        tr_rel = truth["release"]
        v_true = np.asarray(tr_rel["v0"], float)
        out["release_time_ms"] = float((rel.t_release + t_off - tr_rel["t0_s"]) * 1e3)
        out["release_point_mm"] = float(np.linalg.norm(rel.position - np.asarray(tr_rel["p0"], float)) * 1e3)
        out["release_speed_mph"] = float(rel.speed_mph - np.linalg.norm(v_true) / 0.44704)
        cosang = rel.velocity @ v_true / (np.linalg.norm(rel.velocity) * np.linalg.norm(v_true))
        out["release_direction_deg"] = float(np.degrees(np.arccos(np.clip(cosang, -1, 1))))
        out["release_time_sigma_ms"] = float(rel.t_release_sigma * 1e3)
        out["release_speed_sigma_mph"] = float(rel.speed_sigma_mph)
    return out
