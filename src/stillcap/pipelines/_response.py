"""The camera response of a capture's cameras, as the pipelines use it (``docs/camera-response.md``).

A pipeline's ``response`` option: None uses each camera's own (the rig file's ``response``,
sRGB when the rig does not say); a :class:`~stillcap.response.Response` (or its rig-file form)
overrides every camera's; ``"auto"`` estimates each camera's from the photos (the shading of the
lit ball, :mod:`stillcap.detect.response`) and uses what it found where the photos can tell.

:func:`apply_response` gives the capture with the responses to use and a report (recorded in
the result JSON under ``response``); :func:`pitch_response_checks` is the ``response`` self-check
of every camera of a pitch: the ball's shading against the response the pipeline used.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from stillcap.ball.stereo import ball_centers_stereo
from stillcap.detect.response import ResponseEstimate, estimate_responses, response_check
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.response import Response, check_response_option

__all__ = ["apply_response", "camera_estimates", "auto_rig", "auto_report", "response_checks",
           "pitch_response_checks", "pitch_auto_estimates"]


def _with_rig(cap: Capture, rig) -> Capture:
    return replace(cap, rig=rig)


def apply_response(cap: Capture, response, estimate=None) -> tuple[Capture, dict]:
    """The capture with the camera responses to use, and the report of where they came from.

    Parameters
    ----------
    cap : Capture
    response : None, "auto" or Response
        The pipeline's option (:func:`check_response_option`).
    estimate : callable(Capture) -> dict camera name -> ResponseEstimate, optional
        How ``"auto"`` estimates (e.g. :func:`pitch_auto_estimates`); without it ``"auto"``
        raises ``ValueError`` (the pipeline cannot estimate).

    Returns
    -------
    (Capture, dict)
        The report: ``source`` ("rig", "option", "auto"), ``cameras`` (name -> the response used,
        rig-file form) and for "auto" ``estimates`` (name -> class, gamma, evidence) and
        ``messages`` (one line per camera, also for the terminal).
    """
    response = check_response_option(response)
    if response is None:
        return cap, {"source": "rig", "cameras": {c.name: c.response.to_json() for c in cap.rig}, "messages": []}
    if isinstance(response, Response):
        rig = cap.rig.with_responses(response)
        return _with_rig(cap, rig), {"source": "option", "cameras": {c.name: c.response.to_json() for c in rig},
                                     "messages": []}
    if estimate is None:
        raise ValueError("--response auto: this pipeline cannot estimate the camera response from its photos; "
                         "give srgb, linear or gamma:G")
    found = estimate(cap)
    chosen, msgs = {}, []
    for c in cap.rig:
        e = found.get(c.name)
        if e is None:
            continue
        r = e.response()
        if r is None:
            msgs.append(f"response of {c.name}: the photos cannot tell ({e.evidence}); kept the rig's ({c.response})")
        else:
            chosen[c.name] = r
            msgs.append(f"response of {c.name}: {e.response_class} (effective gamma {e.gamma:.2f}), using {r}; "
                        f"{e.evidence}")
    rig = cap.rig.with_responses(chosen)
    return _with_rig(cap, rig), {"source": "auto", "cameras": {c.name: c.response.to_json() for c in rig},
                                 "estimates": {k: v.to_json() for k, v in found.items()}, "messages": msgs}


def _pair_estimates(cams, imgs, radius_m: float) -> tuple:
    """Each camera's estimate from the pair's ball images: matched, refined with the cameras'
    responses, radii projected from the triangulated balls (the geometry the shading fit needs)."""
    st = ball_centers_stereo(cams[0], imgs[0], cams[1], imgs[1], radius_m)
    ok = st.ok
    return tuple(estimate_responses([(imgs[k], (st.centers_a, st.centers_b)[k][ok], st.radius_px[ok, k],
                                      _blur_of(st, k)) for k in range(2)]))


def _blur_of(stereo, k: int) -> float | None:
    """Camera ``k``'s lens blur (px) the ball step read from the limbs (None: not known)."""
    psf = None if stereo is None else getattr(stereo, "psf_px", None)
    return None if psf is None else float(np.asarray(psf, float)[k])


def pitch_auto_estimates(cap: Capture, radius_m: float, rounds: int = 3) -> dict:
    """``"auto"`` for a pitch: each camera's :class:`ResponseEstimate` from its stereo pair's ball
    images. The shading fit needs the ball's centre and radius, which a wrong response biases
    (and the bias pulls the estimate toward the response the balls were found with), so it
    iterates: the balls refined with the rig's responses give a first estimate, the balls
    refined with the estimated ones a second, and a third where a camera's class changed
    between the two."""
    specs, _ = stereo_pairs(cap)
    out: dict = {}
    for sp in specs:
        cams = [cap.rig[c] for c in sp.cameras]
        imgs = [cap.read_image(im) for im in sp.images]
        est = _pair_estimates(cams, imgs, radius_m)
        for k in range(1, int(rounds)):
            if not all(e.ok for e in est):
                break
            again = [c.with_response(e.response()) for c, e in zip(cams, est)]
            before = [e.response_class for e in est]
            est = _pair_estimates(again, imgs, radius_m)
            if [e.response_class for e in est] == before:
                break
        out.update(dict(zip(sp.cameras, est)))
    return out


def pitch_response_checks(cap: Capture, pairs: list, estimates: dict | None = None) -> tuple[list, dict]:
    """The ``response`` self-check of every camera of a pitch's pairs: the shading of its ball
    images (at the refined centres and projected radii the result used) against the response the
    pipeline used. Returns the checks and each camera's estimate (JSON form). ``estimates``:
    ``{(camera, photo file): ResponseEstimate}`` already made from those centres and radii (by
    the pipeline's pair jobs, on the photos they decoded); the others are made here."""
    checks, found = [], {}
    estimates = estimates or {}
    for p in pairs:
        if len(p) == 0:
            continue
        for k, name in enumerate(p.cameras):
            ims = cap.images_of(name)
            if not ims:
                continue
            e: ResponseEstimate | None = estimates.get((name, ims[0].file))
            if e is None:
                img = cap.read_image(ims[0])
                e = estimate_responses([(img, np.asarray(p.centers_px[k]), np.asarray(p.radius_px[k]),
                                         _blur_of(getattr(p, "stereo", None), k))])[0]
            found[name] = e.to_json()
            checks.append(response_check(e, cap.rig[name].response, subject=name))
    return checks, found


def camera_estimates(names, images, centers_px, radius_px) -> dict:
    """Each camera's :class:`ResponseEstimate` from its photo's ball images at known centres
    ``(n_cams, K, 2)`` and radii ``(n_cams, K)`` (e.g. the hand capture's triangulated ball,
    projected); cameras without a photo are left out."""
    names_in, args = [], []
    for k, (name, img) in enumerate(zip(names, images)):
        if img is None:
            continue
        c, r = np.asarray(centers_px[k], float), np.asarray(radius_px[k], float)
        ok = np.all(np.isfinite(c), axis=1) & np.isfinite(r)
        names_in.append(name)
        args.append((img, c[ok], r[ok]))
    return dict(zip(names_in, estimate_responses(args)))  # all cameras in one batch


def auto_rig(rig, estimates: dict):
    """The rig with each camera's estimated response where the photos tell another class than the
    camera's (None when no camera changes)."""
    chosen = {n: e.response() for n, e in estimates.items()
              if e.ok and e.response_class != rig[n].response.response_class}
    return rig.with_responses(chosen) if chosen else None


def auto_report(rig_before, rig_after, estimates: dict) -> dict:
    """The ``response`` report of an "auto" run from its estimates (as :func:`apply_response`'s)."""
    msgs = []
    for c in rig_after:
        e = estimates.get(c.name)
        if e is None:
            continue
        if e.ok:
            msgs.append(f"response of {c.name}: {e.response_class} (effective gamma {e.gamma:.2f}), using "
                        f"{c.response}; {e.evidence}")
        else:
            msgs.append(f"response of {c.name}: the photos cannot tell ({e.evidence}); kept the rig's ({c.response})")
    return {"source": "auto", "cameras": {c.name: c.response.to_json() for c in rig_after},
            "estimates": {k: v.to_json() for k, v in estimates.items()}, "messages": msgs}


def response_checks(rig, estimates: dict) -> list:
    """The ``response`` self-check of every camera with an estimate, against its response in ``rig``."""
    return [response_check(e, rig[name].response, subject=name) for name, e in estimates.items()]
