"""The hand pipeline's entry point :func:`analyse_hand`: a hand capture's stereo pairs and photos,
then the stages of :mod:`~stillcap.pipelines.hand.stages` in order."""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from stillcap.body.hand_files import load_hand
from stillcap.io.capture import Capture
from stillcap.pipelines._response import apply_response, auto_report, auto_rig, camera_estimates, response_checks
from stillcap.pipelines.hand.options import HandOptions
from stillcap.pipelines.hand.result import HandResult
from stillcap.pipelines.hand.stages import (check_hand, hand_setup, read_hand_photos, find_ball, find_glove_markers, fit_poses, label_markers,
                                            label_markers_adapted, recover_markers, release_and_spin, triangulate_glove_markers)
from stillcap._progress import report_progress

__all__ = ["analyse_hand"]


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
    cap, response = apply_response(cap, None if options.response == "auto" else options.response)
    setup = hand_setup(cap, options.strobe_position_m)
    where, pairs, strobe_hz, light, messages = (setup.where, setup.pairs, setup.strobe_hz, setup.light,
                                                setup.messages)
    skeleton, markerset = _hand_of(cap, options)
    if light is None:
        messages.append("strobe position unknown (capture.json meta strobe_position_m): marker centroids keep "
                        "their half-lit bias (~1 px)")
    timings: dict = {}
    total = 7

    t = _time.perf_counter()
    report_progress(progress, 0, total, "reading photos")
    rig = cap.rig
    images = read_hand_photos(cap, pairs)
    timings["decode"] = _time.perf_counter() - t

    # -- ball ---------------------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 1, total, "ball")
    balls = find_ball(rig, images, strobe_hz, options, messages)
    if options.response == "auto" and balls is not None and len(balls):  # the ball's shading, found again if
        found = camera_estimates(rig.names, images, balls.centers_px, balls.radius_px)  # the class changes
        rig_auto = auto_rig(rig, found)
        if rig_auto is not None:
            cap, rig = replace(cap, rig=rig_auto), rig_auto
            balls = find_ball(rig, images, strobe_hz, options, messages)
        response = auto_report(rig, rig, found)
    timings["ball"] = _time.perf_counter() - t

    # -- markers ------------------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 2, total, "glove markers")
    blobs = find_glove_markers(images, balls, rig)
    timings["markers"] = _time.perf_counter() - t
    t = _time.perf_counter()
    report_progress(progress, 3, total, "3D markers")
    points = triangulate_glove_markers(rig, pairs, blobs, light, options, messages, where)
    timings["triangulation"] = _time.perf_counter() - t

    # -- labels and poses ---------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 4, total, "labelling")
    if options.adapt_model:  # experimental
        labels, adapted = label_markers_adapted(points, strobe_hz, options, messages, skeleton, markerset)
    else:
        labels, adapted = label_markers(points, strobe_hz, options, messages, skeleton, markerset), False
    blobs, points, labels = recover_markers(rig, blobs, points, labels, light, options, messages, images, balls,
                                            pairs)
    timings["labels"] = _time.perf_counter() - t
    t = _time.perf_counter()
    report_progress(progress, 5, total, "poses")
    labels, sequence, animation = fit_poses(labels, points, options, messages)
    timings["poses"] = _time.perf_counter() - t

    # -- release and spin ----------------------------------------------------------------------
    t = _time.perf_counter()
    report_progress(progress, 6, total, "release")
    balls, release, spin = release_and_spin(rig, balls, sequence, strobe_hz, pairs, images, options, messages)
    timings["release"] = _time.perf_counter() - t
    checks = check_hand(labels, sequence, points, adapted, messages)
    report_progress(progress, total, total, "done")
    timings["total"] = _time.perf_counter() - t_all
    checks += response_checks(rig, camera_estimates(rig.names, images, balls.centers_px, balls.radius_px)) \
        if balls is not None and len(balls) else []
    messages[:0] = response["messages"]
    return HandResult(cap, strobe_hz, list(pairs), blobs, points, labels, sequence, animation, balls, release, spin,
                      messages, timings, self_checks=checks, response=response)


def _hand_of(cap: Capture, options: HandOptions):
    """The hand model and marker set: the options' (any path), else capture.json's ``hand_model``
    / ``hand_markers`` (paths inside the capture folder), else the built-in ones."""
    refs, folders, whats = [], [], []
    for opt, key, flag in ((options.hand_model, "hand_model", "--hand-model"),
                           (options.hand_markers, "hand_markers", "--markers")):
        if opt is not None:
            refs.append(opt), folders.append(None), whats.append(flag)
        else:
            ref = cap.meta.get(key)
            if ref is not None and not isinstance(ref, str):
                raise ValueError(f"capture {cap.root}: capture.json \"{key}\" must be a file name or a built-in "
                                 f"name, got {ref!r}")
            refs.append(ref), folders.append(cap.root), whats.append(f"capture.json \"{key}\"")
    return load_hand(refs[0], refs[1], model_folder=folders[0], markers_folder=folders[1], model_what=whats[0],
                     markers_what=whats[1])
