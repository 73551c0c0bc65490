"""What a hand calibration reports (:mod:`stillcap.body.hand_calibrate`'s results): its
parameters with their 1-sigma against the template and the self-checks read from them (moved out
of ``hand_calibrate`` on 27 November 2026 to keep that module near 800 lines)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap.body.hand import BACK_MARKERS
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton

__all__ = ["UNFIXED_SIGMA_RATIO", "CalibratedParameter", "HandCalibration", "calibration_parameters", "misfit_check",
           "misfit_limit", "observability_check", "phalanx_lengths"]

#: A parameter whose 1-sigma after the calibration is more than this share of its prior's was
#: not fixed by the capture (its variance shrank by less than half): the self-check
#: ``calibration_fixes_the_model`` names it (a warning; the value stays near the template's).
UNFIXED_SIGMA_RATIO = 0.7


def phalanx_lengths(skeleton: Skeleton) -> dict:
    """Length (m) of every bone but the root, by the joint at its end (``index-pip`` is the
    index's proximal phalanx; ``index-mcp`` its metacarpal, wrist to knuckle)."""
    L = np.linalg.norm(skeleton.offsets, axis=1)
    return {n: float(L[i]) for i, n in enumerate(skeleton.names) if i != skeleton.root}


@dataclass(frozen=True)
class CalibratedParameter:
    """One estimated parameter of the person's hand (:attr:`HandCalibration.parameters`).

    ``value``, ``sigma`` (1-sigma, from the fit's covariance), ``template`` (the built-in
    model scaled to the hand's size) and ``prior_sigma`` (the prior's spread about the template:
    what ``sigma`` would be had the capture shown nothing of the parameter) in ``unit``; ``kind`` is ``length`` (a bone), ``knuckle``
    (a joint's place: ``x`` along the fingers, ``y`` toward the thumb, ``z`` out of the back of
    the hand), ``height`` (a marker over its bone's axis) or ``axis`` (the thumb's bone
    directions, their angle from the template's).
    """

    name: str
    kind: str
    value: float
    sigma: float
    template: float
    unit: str
    prior_sigma: float = float("nan")

    @property
    def fixed(self) -> float:
        """``sigma / prior_sigma``: near 0 the capture fixed the parameter, near 1 it stayed at
        the prior (the template scaled to the hand: the capture did not show it)."""
        return self.sigma / self.prior_sigma if self.prior_sigma > 0 else float("nan")

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "value": self.value, "sigma": self.sigma,
                "template": self.template, "unit": self.unit, "prior_sigma": self.prior_sigma,
                "sigma_over_prior": self.fixed}


@dataclass(eq=False)
class HandCalibration:
    """Result of :func:`calibrate_hand`.

    Attributes
    ----------
    skeleton, markerset : Skeleton, MarkerSet
        The person's hand model and glove (write with ``save``; ``stillcap hand --hand-model
        --markers`` reads them).
    pose : str
        The calibration pose.
    size : float
        The hand's size relative to the template (back-of-hand triangle).
    rms, pose_rms : float
        Marker residual RMS (m) over all flashes used and over the calibration-pose flashes.
    n_posed, n_free : int
        Flashes in the stated pose and in other (unknown) poses used.
    residuals : ndarray, shape (n_flashes, n_markers)
        Fitted-to-measured marker distance (m), the posed flashes first; NaN unseen.
    misfit : ndarray, shape (n_flashes, n_markers)
        Each residual over its marker's stated noise, squared (``(r / sigma)^2``: chi-square with
        3 dof when the model and the label are right; NaN unseen).
    markers : ndarray, shape (n_flashes, n_markers, 3)
        The labelled markers fitted (m), in the order of ``residuals``; NaN unlabelled.
    cost : float
        The fit's objective (:attr:`~stillcap.body.hand_adapt.HandAdaptation.cost`).
    messages : list of str
    parameters : list of CalibratedParameter
        Every estimated length, knuckle place, marker height and thumb axis with its 1-sigma.
    self_checks : list of SelfCheck
        The calibration's checks: the pose's residual, the model's plausibility and (when asked)
        the lengths' sigmas refuse the capture with ValueError when they fail;
        ``calibration_fixes_the_model`` warns, naming the parameters the capture did not fix.
    """

    skeleton: Skeleton
    markerset: MarkerSet
    pose: str
    size: float
    rms: float
    pose_rms: float
    n_posed: int
    n_free: int
    residuals: np.ndarray
    messages: list = field(default_factory=list)
    parameters: list = field(default_factory=list)
    self_checks: list = field(default_factory=list)
    misfit: np.ndarray | None = None
    markers: np.ndarray | None = None
    cost: float = float("nan")
    chi2_scale: float = 1.0

    def lengths(self) -> dict:
        return phalanx_lengths(self.skeleton)

    def to_dict(self) -> dict:
        """The calibration report (JSON-ready, lengths in mm)."""
        from stillcap._selfcheck import checks_to_json

        return {"format": "stillcap-hand-calibration", "version": 1, "pose": self.pose, "size": self.size,
                "rms_mm": self.rms * 1e3, "pose_rms_mm": self.pose_rms * 1e3, "n_posed": self.n_posed,
                "n_free": self.n_free, "messages": list(self.messages),
                "parameters": [p.to_dict() for p in self.parameters],
                "self_checks": checks_to_json(self.self_checks)}


def _sd(v, cov) -> float:
    """1-sigma of ``|v|`` from the covariance of ``v`` (first order)."""
    n = np.linalg.norm(v)
    g = v / n if n > 0 else np.zeros(3)
    return float(np.sqrt(max(0.0, g @ cov @ g)))


def calibration_parameters(sk0: Skeleton, ms0: MarkerSet, ad) -> list:
    """The estimated parameters with their 1-sigma (mm, deg), against the template ``sk0``/``ms0``."""
    sk, ms = ad.skeleton, ad.markerset
    o, o0 = sk.offsets, sk0.offsets
    pj = ad.joint_prior_sigma if ad.joint_prior_sigma is not None else np.full(sk.n_joints, np.nan)
    pm = ad.marker_prior_sigma if ad.marker_prior_sigma is not None else np.nan
    out = []
    for i, n in enumerate(sk.names):
        if i == sk.root or n.endswith("-tip"):
            continue  # the tip's length: no marker beyond it
        C = ad.joint_cov[i]
        if sk.parents[i] == sk.root:  # a knuckle's (or the thumb base's) place on the palm
            for a, ax in enumerate("xyz"):
                out.append(CalibratedParameter(f"{n} {ax}", "knuckle", o[i, a] * 1e3, np.sqrt(C[a, a]) * 1e3,
                                               o0[i, a] * 1e3, "mm", pj[i] * 1e3))
        else:
            out.append(CalibratedParameter(f"{sk.names[sk.parents[i]]} to {n}", "length", np.linalg.norm(o[i]) * 1e3,
                                           _sd(o[i], C) * 1e3, np.linalg.norm(o0[i]) * 1e3, "mm", pj[i] * 1e3))
    for i, n in enumerate(sk.names):  # the thumb's bone directions
        if n.startswith("thumb-") and sk.parents[i] != sk.root and not n.endswith("-tip"):
            u, u0 = o[i] / np.linalg.norm(o[i]), o0[i] / np.linalg.norm(o0[i])
            P = (np.eye(3) - np.outer(u, u)) / np.linalg.norm(o[i])
            sd = np.sqrt(max(0.0, np.trace(P @ ad.joint_cov[i] @ P.T) / 2))
            out.append(CalibratedParameter(f"{n} axis", "axis", np.degrees(np.arccos(np.clip(u @ u0, -1, 1))),
                                           np.degrees(sd), 0.0, "deg", np.degrees(pj[i] / np.linalg.norm(o[i]))))
    frames = ms.bone_frames(sk)
    for k, m in enumerate(ms.markers):
        if m.name in BACK_MARKERS:
            continue
        b = frames[k]
        u = o[b] / np.linalg.norm(o[b]) if np.linalg.norm(o[b]) > 0 else np.array([1.0, 0, 0])
        # height: the part of the offset out of the bone's axis (the bone's end joint's direction)
        j = [c for c in range(sk.n_joints) if sk.parents[c] == b]
        u = o[j[0]] / np.linalg.norm(o[j[0]]) if j else u
        v = ms.offsets[k] - (ms.offsets[k] @ u) * u
        j0 = [c for c in range(sk0.n_joints) if sk0.parents[c] == b]
        u0 = o0[j0[0]] / np.linalg.norm(o0[j0[0]])
        v0 = ms0.offsets[k] - (ms0.offsets[k] @ u0) * u0
        out.append(CalibratedParameter(f"{m.name} height", "height", np.linalg.norm(v) * 1e3,
                                       _sd(v, ad.marker_cov[k]) * 1e3, np.linalg.norm(v0) * 1e3, "mm", pm * 1e3))
    return out


def observability_check(params, pose: str):
    """The self-check ``calibration_fixes_the_model``: every joint parameter (length, knuckle
    place, thumb axis) whose 1-sigma is more than :data:`UNFIXED_SIGMA_RATIO` of its prior's
    stayed near the template (scaled to the hand):
    the capture did not show it. It warns (the calibration is kept: the template's value is the
    best the capture allows) and names them, worst first."""
    from stillcap._selfcheck import SelfCheck

    # the joints' places (lengths, knuckles, the thumb's axes) set the angles; a marker's height
    # is fixed with them (the flat flash fixes each height plus its knuckle's height)
    rated = [q for q in params if q.kind != "height" and np.isfinite(q.fixed)]
    if not rated:
        return SelfCheck("calibration_fixes_the_model", True, None, UNFIXED_SIGMA_RATIO,
                         "no parameter's prior known: not checked", pose, "")
    unfixed = sorted((q for q in rated if q.fixed > UNFIXED_SIGMA_RATIO), key=lambda q: -q.fixed)
    worst = max(rated, key=lambda q: q.fixed)
    if not unfixed:
        return SelfCheck("calibration_fixes_the_model", True, worst.fixed, UNFIXED_SIGMA_RATIO,
                         f"the capture fixed every joint parameter (worst: {worst.name}, 1-sigma {worst.fixed:.2f} of "
                         f"its prior's)", worst.name, "")
    names = ", ".join(f"{q.name} (+-{q.sigma:.1f} {q.unit}, {q.fixed:.2f} of the prior's)" for q in unfixed[:6])
    more = f" and {len(unfixed) - 6} more" if len(unfixed) > 6 else ""
    return SelfCheck("calibration_fixes_the_model", False, worst.fixed, UNFIXED_SIGMA_RATIO,
                     f"the calibration capture did not fix {len(unfixed)} joint parameter(s), which stay near the "
                     f"template scaled to the hand: {names}{more}; bend those joints, and turn the hand, so that the "
                     f"cameras see the markers beyond them move (docs/hand-calibration.md)", worst.name, "")


def misfit_limit(n_labels: int, p: float | None = None) -> float:
    """The largest ``(r / sigma)^2`` of one label among ``n_labels`` that a right model and right
    labels give with probability ``1 - p`` over the whole capture (chi-square with 3 dof at
    ``p / n_labels``; default ``p``: the puppet's per-check false-alarm chance,
    :data:`stillcap.body.puppet_checks.FALSE_ALARM_P`). The fit absorbs part of a misfit, so the
    test is on the safe side."""
    from stillcap.body.puppet_checks import FALSE_ALARM_P, _limit

    return _limit((FALSE_ALARM_P if p is None else p) / max(1, n_labels), 3, float("inf"))


def misfit_check(misfit, names, n_posed: int, pose: str):
    """The self-check ``calibration_labels_fit``: no label of the other flashes misses the
    calibrated model by more than its stated noise allows (:func:`misfit_limit`). A label that
    does is a wrong label (a point of another finger or flash) or a model the capture pulled
    off; the fit bent the shared model toward it (the posed flash has its own check)."""
    from stillcap._selfcheck import SelfCheck

    z2 = np.asarray(misfit, float)[n_posed:]
    seen = np.isfinite(z2)
    if not seen.any():
        return SelfCheck("calibration_labels_fit", True, None, float("nan"), "no other flash: not checked", pose, "")
    lim = misfit_limit(int(seen.sum()))
    bad = np.argwhere(seen & (np.where(seen, z2, 0.0) > lim))
    worst = float(np.sqrt(np.nanmax(z2)))
    if len(bad) == 0:
        return SelfCheck("calibration_labels_fit", True, worst, float(np.sqrt(lim)),
                         f"every label of the other flashes fits the calibrated model within its noise "
                         f"(worst {worst:.1f} sigma)", pose, "sigma")
    bad = sorted(bad.tolist(), key=lambda fm: -z2[fm[0], fm[1]])
    names_ = ", ".join(f"{names[m]} of fitted flash {f + n_posed} ({np.sqrt(z2[f, m]):.1f} sigma)" for f, m in bad[:6])
    more = f" and {len(bad) - 6} more" if len(bad) > 6 else ""
    return SelfCheck("calibration_labels_fit", False, worst, float(np.sqrt(lim)),
                     f"{len(bad)} label(s) miss the calibrated model by more than their noise allows: {names_}{more}; "
                     f"wrong labels (markers of another finger or flash) bend the model: move the hand farther "
                     f"between flashes, keep the markers in view (docs/hand-calibration.md)", pose, "sigma")
