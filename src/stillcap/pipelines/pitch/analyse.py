"""The pitch pipeline's entry point: :func:`analyse_pitch` runs the stages of
:mod:`stillcap.pipelines.pitch.stages` in the order of the method, the per-pair work scheduled by
:mod:`stillcap.pipelines.pitch.workers`."""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from pathlib import Path

from dataclasses import replace

from stillcap.io.capture import Capture, capture_ball, stereo_pairs
from stillcap.pipelines._response import apply_response, pitch_auto_estimates, pitch_response_checks
from stillcap.pipelines.pitch.options import PitchOptions
from stillcap.pipelines.pitch.result import PitchResult
from stillcap.pipelines.pitch.spin import ball_layout_check, flight_spin_stage, spin_noise_check
from stillcap.pipelines.pitch.stages import (StageLog, check_and_inflate, find_balls, fit_flight, markers_and_spin,
                                             metrics_and_uncertainty, number_flashes, refit_with_spin,
                                             start_markers_and_spin)
from stillcap.pipelines.pitch.workers import pair_jobs

__all__ = ["analyse_pitch"]


def analyse_pitch(capture: Capture | str | Path, options: PitchOptions | None = None, *,
                  progress: Callable[[int, int, str], None] | None = None, **kwargs) -> PitchResult:
    """Analyse one pitch capture (SPEC J1): positions, timing, markers, spin, flight, metrics.

    Parameters
    ----------
    capture : Capture or path
        A capture folder (``kind: pitch``) with one photo per camera of 1+ strobed stereo pairs,
        each photo with its ``strobe_hz``; the rig's world should be the baseball field frame
        for the metrics.
    options : PitchOptions, optional
        Or pass its fields as keyword arguments (``spin_method="seed"``, ``physics="nathan"``).
    progress : callable(done, total, label), optional

    Returns
    -------
    PitchResult

    Raises
    ------
    ValueError
        A capture that cannot give a flight: not a pitch capture, no complete stereo pair, an
        unreadable photo, no ball found, fewer than 3 ball positions or fewer than 2 in the front
        pair. Missing markers (no spin) are not errors: the result says so in ``messages``.

    Examples
    --------
    A pitch rendered by the studio (1280x960 photos through the true rig), written as a capture
    folder and analysed; the spin rate against the truth:

    >>> import tempfile
    >>> from stillcap.studio.pitch import pitch_capture
    >>> rendered = pitch_capture("seed-4seam", rng=0, calibrate=False, image_size=(1280, 960))
    >>> capture, photos = rendered.to_capture()
    >>> folder = capture.save(tempfile.mkdtemp(), photos)
    >>> result = analyse_pitch(folder)
    >>> round(result.metrics.spin_rate_rpm), round(rendered.truth.release.spin_rpm)
    (1650, 1650)
    """
    t_all = _time.perf_counter()
    if options is None:
        options = PitchOptions(**kwargs)
    elif kwargs:
        raise ValueError("give either options or keyword arguments, not both")
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    if options.ball is None and options.layout is None:
        ball = capture_ball(cap)  # capture.json's "ball" (the CLI's --ball overrides it)
        if ball is not None:
            options = replace(options, ball=ball)
    # the cameras' responses: the rig's, the option's, or estimated from the photos ("auto")
    cap, response = apply_response(cap, options.response, lambda c: pitch_auto_estimates(c, options.radius_m))
    # the per-pair work on threads, or in worker processes (options.processes > 0)
    with pair_jobs(cap, options.workers, options.processes) as jobs:
        result = _analyse(cap, options, jobs, progress, t_all)
        # the response self-check's estimates, made by each pair's job on its photos after its
        # marker step (no second decode)
        estimates = jobs.response_estimates()
    # the response self-check: the ball's shading against the response used
    checks, found = pitch_response_checks(cap, result.pairs, estimates)
    result.self_checks.extend(checks)
    result.response = {**response, "shading": found}
    result.messages[:0] = response["messages"]
    return result


def _analyse(cap: Capture, options: PitchOptions, jobs, progress, t_all: float) -> PitchResult:
    """The method, stage by stage (:mod:`stillcap.pipelines.pitch.stages`)."""
    where = f"capture {cap.root}" if cap.root is not None else "capture"
    if cap.kind != "pitch":
        raise ValueError(f"{where} is a {cap.kind!r} capture, not a pitch capture (capture.json \"kind\")")
    layout = options.marker_layout
    types = None  # the layout's palette as each camera photographs it (its response)
    model = options.flight_model()
    timings: dict = {}
    specs, messages = stereo_pairs(cap)
    log = StageLog(messages, timings, progress, 2 * len(specs) + 3)

    balls = find_balls(specs, jobs, options.radius_m, where, log)
    pairs = number_flashes(cap, balls, options, where, log)
    # each pair's markers and own spin need only its ball images: on the workers, while this
    # thread fits the flight
    marker_jobs = start_markers_and_spin(pairs, jobs, types, layout, options)
    flight = fit_flight(cap, pairs, model, options, log)
    spin = markers_and_spin(pairs, marker_jobs, flight, model, layout, options, log)
    fit = refit_with_spin(pairs, flight, spin, options, log)
    spin_messages: list = []  # (reported after the metrics' messages, as before the checks)
    flight_spin, spin_cmp = flight_spin_stage(flight.fit, model, spin.ok, spin.w0, spin.cov0, spin_messages)
    checks, fit = check_and_inflate(cap, pairs, flight, spin, fit, flight_spin, spin_cmp, model, options, log)
    out = metrics_and_uncertainty(cap, pairs, flight, spin, fit, model, options, log)
    messages.extend(spin_messages)
    # a withheld spin's markers still show whether they fit the ball's layout at all (a wrong ball file)
    shown = spin.spin if spin.spin is not None else getattr(spin.alias, "withheld", None)
    checks += [c for c in (ball_layout_check(shown, layout), spin_noise_check(shown)) if c is not None]

    timings["total"] = _time.perf_counter() - t_all
    log.step(log.total, "done")
    return PitchResult(cap.rig.world, options, pairs, fit.times, flight.positions, flight.pair_index, flight.v_two,
                       out.v_two_sigma, fit, flight.fit, spin.spin, spin.alias, out.metrics, out.sigma, out.release,
                       out.table1, messages, timings, None if cap.root is None else str(cap.root),
                       spin_obs_times=spin.obs_times, flight_spin=flight_spin, spin_comparison=spin_cmp,
                       self_checks=checks)
