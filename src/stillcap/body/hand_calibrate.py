"""The person's hand model from a calibration capture (issue 12, part 3: "the hand model adapts
to the person ... from the capture or a calibration pose"): ``stillcap hand-calibrate``.

Why a calibration pose: with one marker per finger segment, a throw cannot tell a marker's
height over the bone from the joint's angle (``stillcap.body.hand_adapt`` trades one for the
other: 3-11 deg). A flash of the hand held in a **known pose** fixes the angles of that flash, so
what its markers show is the model alone.

The calibration capture is a strobe sequence of the gloved hand (as a throw's capture: one
multi-exposure photo per camera):

- **``flat``** (:data:`CALIBRATION_POSES`) in the first flash(es): the hand flat, fingers
  extended and together, the thumb alongside: every joint angle 0 (the model's rest pose, by
  definition of the angles). It fixes every marker's place in the hand frame at rest: the
  phalanx-plus-marker sums along each finger, each marker's height and side, the knuckles'
  splay and the thumb's axis (its rest direction). It cannot fix where along a straight finger
  a joint centre lies (a knuckle 5 mm farther and a proximal phalanx 5 mm shorter look the same).
- **then the fingers curl** (any angles, not known, e.g. slowly into a loose fist, a few cm
  sideways per flash so the flashes do not overlap): every bending joint turns its distal
  markers about its centre, which fixes the joint centres (the phalanx lengths), with the flat
  flash holding the marker heights.

:func:`calibrate_hand` solves both at once: one regularised least-squares problem
(:func:`stillcap.body.hand_adapt.adapt_hand_model`, ``scipy.optimize.least_squares``) over
every joint offset (per-phalanx lengths, knuckle places, the thumb's base and axis) and every
marker's place on its bone, with per flash the hand's pose; the flat flash's angles are held at
0. :func:`calibrate_hand_from_points` labels the 3D markers first (the size-scaled labelling),
finds the flash in the stated pose and refuses a capture whose flash does not fit it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stillcap.body.hand import BACK_MARKERS, DIGITS, fit_hand, hand_markerset, hand_skeleton, scale_hand
from stillcap.body.hand_calibration_report import (UNFIXED_SIGMA_RATIO, CalibratedParameter, HandCalibration,
                                                   calibration_parameters, misfit_check, misfit_limit,
                                                   observability_check, phalanx_lengths)
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton

__all__ = ["BACK_SIGMA_M", "CALIBRATION_POSES", "REFUSE_RMS_M", "REFUSE_PRIOR_Z", "MAX_LENGTH_SIGMA_M", "UNFIXED_SIGMA_RATIO", "MAX_POSED_TRIES",
           "ALSO_POSED_P",
           "CalibratedParameter",
           "HandCalibration", "calibration_angles", "calibrate_hand",
           "calibrate_hand_from_points", "calibrate_hand_from_point_sets", "CalibrationPoints", "phalanx_lengths"]

#: The calibration poses: name -> description (their angles: :func:`calibration_angles`).
CALIBRATION_POSES = {"flat": "hand flat, fingers extended and together, thumb alongside (every joint angle 0)"}
#: A calibration flash whose markers the calibrated model cannot fit within this RMS (m) is not
#: in the stated pose (the measured noise is 0.2-0.4 mm; a wrong pose gives several mm).
REFUSE_RMS_M = 0.0015
#: Assumed noise of a labelled 3D marker (m): weighs the markers against the priors.
NOISE_M = 0.0004
#: A fit that moves a joint or marker farther than this many prior sigmas from the template
#: (scaled to the hand) is refused: the pose was not the one stated (measured: below 2 on the
#: studio's other hands, see docs/hand-calibration.md).
REFUSE_PRIOR_Z = 4.0
#: The pipeline's limit of a length's 1-sigma (m): beyond it the capture did not bend that joint.
MAX_LENGTH_SIGMA_M = 0.0015
#: Prior spread (m) of each component of a back-of-hand marker's place, as every digit marker's
#: (:func:`~stillcap.body.hand_adapt.adapt_hand_model`'s ``marker_sigma_m``). The hand frame is
#: the bones' (in the flat pose every phalanx lies along its x, every hinge turns about its y), not
#: the three markers': a glove's back markers sit a millimetre or two off the template's triangle,
#: and a triangle held to the template's shape tilts the frame by that much over its 5 cm (1-3 deg
#: on the studio's other hands), which the fingers' markers then absorb (docs/hand-calibration.md).
BACK_SIGMA_M = 0.004
#: Flashes tried as the posed one, nearest the pose first, before the capture is refused (each
#: refusal costs one fit; a flash is refused when its markers do not fit the pose stated).
MAX_POSED_TRIES = 3
#: False-alarm rate of the test that another shortlisted flash is in the pose too (held with the
#: first, :func:`_also_posed`): holding its angles at the pose's raises the fit's cost by no more
#: than a chi-square with one degree per angle allows.
ALSO_POSED_P = 0.01
#: The chance that :func:`_hidden_noise` scales the partly hidden labels' noise below what their
#: residuals show (the scale is the chi-square's upper bound at this level).
HIDDEN_NOISE_P = 0.05


def calibration_angles(pose: str, skeleton: Skeleton) -> np.ndarray:
    """The joint angles (degrees, ``(n_joints, 3)``) of a calibration pose."""
    if pose not in CALIBRATION_POSES:
        raise ValueError(f"unknown calibration pose {pose!r}; known: {', '.join(CALIBRATION_POSES)}")
    return np.zeros((skeleton.n_joints, 3))


def _size(markerset: MarkerSet, pts) -> float:
    b = [markerset.index(n) for n in BACK_MARKERS]
    d0 = np.linalg.norm(markerset.offsets[b][:, None] - markerset.offsets[b][None], axis=-1).sum()
    d1 = np.linalg.norm(pts[b][:, None] - pts[b][None], axis=-1).sum()
    return float(d1 / d0)


def calibrate_hand(posed, free=None, *, pose: str = "flat", skeleton: Skeleton | None = None,
                   markerset: MarkerSet | None = None, noise_m: float = NOISE_M, max_nfev: int = 200,
                   refuse_rms_m: float = REFUSE_RMS_M, refuse_prior_z: float = REFUSE_PRIOR_Z,
                   max_length_sigma_m: float | None = None, posed_sigma_m=None, free_sigma_m=None,
                   loss: str = "linear", back_sigma_m: float | None = BACK_SIGMA_M) -> HandCalibration:
    """The person's hand model from labelled markers in a calibration pose (module docstring).

    Parameters
    ----------
    posed : array_like, shape (n_posed, n_markers, 3)
        Labelled markers (m, NaN unseen) of flashes in the calibration pose ``pose``; the
        back-of-hand markers seen in each.
    free : array_like, shape (n_free, n_markers, 3), optional
        Labelled markers of flashes in other poses (angles not known): they fix the joint
        centres along the fingers (without them those stay at the template's, scaled).
    pose : str
        A name of :data:`CALIBRATION_POSES`.
    skeleton, markerset : optional
        The template (default the built-in hand); it is scaled to the hand's size first and is
        the prior of every offset.
    noise_m, max_nfev
        The markers' noise (m) and the solver's budget.
    refuse_rms_m : float
        ValueError when the calibration-pose flashes' residual RMS exceeds it.
    refuse_prior_z : float
        ValueError when the fit had to move a joint or marker farther than this many of its
        prior's sigmas from the template scaled to the hand (a pose other than the one stated,
        absorbed by the model: a hand is not that unlike the template).
    max_length_sigma_m : float, optional
        ValueError when a finger phalanx's or the thumb's length is known worse than this
        (1-sigma, m): the capture did not bend that joint enough (the protocol's steps were not
        done); None: not checked.
    posed_sigma_m, free_sigma_m : array_like, shape (n_posed, n_markers) and (n_free, n_markers), optional
        Each labelled marker's noise (m) in place of ``noise_m`` (a partly hidden marker's
        centroid shifts by millimetres: :func:`calibrate_hand_from_points` gives it less weight).
    loss : str
        SciPy's loss (:func:`~stillcap.body.hand_adapt.adapt_hand_model`): ``"linear"`` (every
        label at its noise; the model reported); ``"soft_l1"`` bounds a wrong label's pull, which
        :func:`calibrate_hand_from_point_sets` uses only to find the labels to leave out.
    back_sigma_m : float or None
        Prior spread (m) of each back-of-hand marker's place about the template's triangle scaled
        (:data:`BACK_SIGMA_M`); None: the triangle keeps the template's shape, only its size is
        free (as before 27 November 2026). The refusals (the posed flash's residual, the priors'
        z) are decided on the fit with the triangle held; the model returned is the fit with it
        free, started from the held fit's shape and poses (two fits).
    """
    from stillcap._selfcheck import SelfCheck
    from stillcap.body.hand_adapt import adapt_hand_model

    sk0 = skeleton or hand_skeleton()
    ms0 = markerset or hand_markerset()
    known = calibration_angles(pose, sk0)
    posed = np.asarray(posed, float).reshape(-1, len(ms0), 3)
    free = np.zeros((0, len(ms0), 3)) if free is None else np.asarray(free, float).reshape(-1, len(ms0), 3)
    if len(posed) == 0:
        raise ValueError(f"no flash in the calibration pose {pose!r}")
    size = float(np.median([_size(ms0, p) for p in posed]))
    sk, ms = scale_hand(sk0, ms0, size)
    pts = np.concatenate([posed, free])
    kd = [known] * len(posed) + [None] * len(free)
    # each free flash starts from its pose fitted with the scaled template (a fist is far from rest)
    init = [None] * len(posed) + [fit_hand(sk, ms, f).pose for f in free]
    sig = None
    if posed_sigma_m is not None or free_sigma_m is not None:
        sig = np.concatenate([np.full(posed.shape[:2], noise_m) if posed_sigma_m is None else
                              np.asarray(posed_sigma_m, float).reshape(posed.shape[:2]),
                              np.full(free.shape[:2], noise_m) if free_sigma_m is None else
                              np.asarray(free_sigma_m, float).reshape(free.shape[:2])])
    # the pose checks below are made on the fit with the back triangle's shape held (the
    # template's): with the triangle free, the frame could tilt toward a flash that is not flat
    # (with it free in every fit, another_hand(7)'s rendered capture took another flash as flat
    # and came out at 6.75 deg against 2.44, docs/hand-calibration.md)
    ad = adapt_hand_model(sk, ms, pts, known_deg=kd, initial=init, noise_m=noise_m, loss=loss, max_nfev=max_nfev,
                          point_sigma_m=sig)
    res = ad.residuals
    pose_rms = float(np.sqrt(np.nanmean(res[:len(posed)] ** 2)))
    checks = []
    what = f"the calibration flash is not in the {pose!r} pose ({CALIBRATION_POSES[pose]})"
    if not pose_rms <= refuse_rms_m:
        worst = ad.digit_rms()
        dig = max((d for d in worst if np.isfinite(worst[d])), key=lambda d: worst[d])
        raise ValueError(f"{what}: its markers miss the calibrated model by {pose_rms * 1e3:.1f} mm RMS (limit "
                         f"{refuse_rms_m * 1e3:.1f} mm; worst: {dig}, {worst[dig] * 1e3:.1f} mm)")
    checks.append(SelfCheck("calibration_pose_residual", True, pose_rms * 1e3, refuse_rms_m * 1e3,
                            f"the {pose} flash(es) fit the calibrated model", pose, "mm"))
    zj, zm = ad.joint_prior_z, ad.marker_prior_z
    if max(zj.max(), zm.max()) > refuse_prior_z:
        if zj.max() >= zm.max():
            i = int(np.argmax(zj))
            d = np.linalg.norm(ad.skeleton.offsets[i] - sk.offsets[i])
            who, z = f"joint {sk.names[i]!r} {d * 1e3:.0f} mm", zj[i]
        else:
            k = int(np.argmax(zm))
            d = np.linalg.norm(ad.markerset.offsets[k] - ms.offsets[k])
            who, z = f"marker {ms.names[k]!r} {d * 1e3:.0f} mm", zm[k]
        raise ValueError(f"{what}: fitting it moves {who} from the template's place ({z:.1f} prior sigmas, "
                         f"limit {refuse_prior_z:g}); hold the hand in the pose (docs/hand-calibration.md)")
    checks.append(SelfCheck("model_plausibility", True, float(max(zj.max(), zm.max())),
                            refuse_prior_z, "no joint or marker moved implausibly far from the template", pose,
                            "prior sigmas"))
    if back_sigma_m is not None:  # the model: the triangle's own shape, the frame the bones' (BACK_SIGMA_M)
        ad = adapt_hand_model(sk, ms, pts, known_deg=kd, start=ad, noise_m=noise_m, loss=loss,
                              max_nfev=max_nfev, point_sigma_m=sig, back_sigma_m=back_sigma_m)
        res = ad.residuals
        pose_rms = float(np.sqrt(np.nanmean(res[:len(posed)] ** 2)))
    sk1 = Skeleton(ad.skeleton.joints, name=f"{sk0.name}-calibrated", source=f"hand-calibrate ({pose})")
    ms1 = MarkerSet(ad.markerset.markers, ad.markerset.rules, ms0.name, sk1.name, f"hand-calibrate ({pose})")
    ad.skeleton, ad.markerset = sk1, ms1
    params = calibration_parameters(sk, ms, ad)
    if max_length_sigma_m is not None:
        lens = [p for p in params if p.kind == "length"]
        worst = max(lens, key=lambda p: p.sigma)
        if not worst.sigma <= max_length_sigma_m * 1e3:
            raise ValueError(f"the calibration capture does not fix the length {worst.name} (+-{worst.sigma:.1f} mm, "
                             f"limit {max_length_sigma_m * 1e3:.1f} mm): that joint did not bend enough; do every "
                             f"step of the protocol (docs/hand-calibration.md)")
        checks.append(SelfCheck("bone_lengths_fixed", True, worst.sigma, max_length_sigma_m * 1e3,
                                f"every length known to {max_length_sigma_m * 1e3:.1f} mm (worst {worst.name})",
                                pose, "mm"))
    checks.append(observability_check(params, pose))
    msgs = []
    if len(free) == 0:
        msgs.append("only the calibration pose was seen: the joint centres along the fingers stay at the "
                    "template's (scaled); flashes of the fingers curling fix them")
    s3 = np.full(res.shape, noise_m) if sig is None else np.where(np.isfinite(sig), sig, noise_m)
    misfit = (res / s3) ** 2
    checks.append(misfit_check(misfit, ms0.names, len(posed), pose))
    return HandCalibration(sk1, ms1, pose, size, ad.rms, pose_rms, len(posed), len(free), res, msgs, params, checks,
                           misfit, pts, ad.cost, ad.chi2_scale)


@dataclass(frozen=True)
class CalibrationPoints:
    """The unlabelled 3D markers of one calibration capture (:func:`calibrate_hand_from_point_sets`).

    ``points`` (n, 3) m and ``colors`` (n,) as the hand pipeline triangulates them, the
    capture's ``strobe_hz``; optionally ``reprojection_px`` (n,), ``point_sigma_m`` (n,: each
    point's noise, m) and ``unconfirmed`` (n,: partly hidden points no third view checked).
    """

    points: np.ndarray
    colors: np.ndarray
    strobe_hz: float
    reprojection_px: np.ndarray | None = None
    point_sigma_m: np.ndarray | None = None
    unconfirmed: np.ndarray | None = None


def calibrate_hand_from_points(points, colors, *, strobe_hz: float, pose: str = "flat",
                               skeleton: Skeleton | None = None, markerset: MarkerSet | None = None,
                               reprojection_px=None, max_free: int = 12, point_sigma_m=None, unconfirmed=None,
                               **kw) -> HandCalibration:
    """Label the unlabelled 3D markers of a calibration capture and calibrate the hand.

    The markers are labelled with the template scaled to the hand
    (:func:`~stillcap.body.hand_label.label_hand_markers`); the flash whose fitted angles are
    nearest the calibration pose is taken as posed; a first calibration on it alone labels the
    capture again (a model nearer the hand labels more), and the final calibration uses it with
    up to ``max_free`` other flashes. ``point_sigma_m`` (one per point, m): each point's noise in
    the calibration (default :data:`NOISE_M` for all); ``unconfirmed`` (a bool per point) goes to
    the labelling. Keyword arguments go to :func:`calibrate_hand`. One capture of
    :func:`calibrate_hand_from_point_sets`.
    """
    one = CalibrationPoints(points, colors, strobe_hz, reprojection_px, point_sigma_m, unconfirmed)
    return calibrate_hand_from_point_sets([one], pose=pose, skeleton=skeleton, markerset=markerset,
                                          max_free=max_free, **kw)


def calibrate_hand_from_point_sets(sets, *, pose: str = "flat", skeleton: Skeleton | None = None,
                                   markerset: MarkerSet | None = None, max_free: int = 12,
                                   max_posed_tries: int = MAX_POSED_TRIES, drop_misfits: bool = True,
                                   **kw) -> HandCalibration:
    """Calibrate the hand from one or more calibration captures of the same hand and glove
    (a list of :class:`CalibrationPoints`), as :func:`calibrate_hand_from_points` does for one.

    Each capture is labelled apart (its own strobe, its own flashes); of the ``max_posed_tries``
    flashes the template reads nearest the calibration pose over all of them, the posed one is the
    one whose fit of every flash, with it held in the pose, costs least (:func:`_pose_costs`), held
    with every other shortlisted flash the fit cannot tell from the pose (:func:`_also_posed`: a
    protocol's two flat flashes, so that one label a few mm off in one is outvoted), and
    up to ``max_free`` other flashes of
    *each* capture are fitted with it in one problem: the shape is shared, every flash has its
    own pose. More captures give the fit more poses (for instance the curl of one photo and the
    protocol's separate bends of another, docs/hand-calibration.md); they need not be in the
    same place or share the cameras' calibration beyond each capture's own rig.

    When the flash nearest the pose is refused (:func:`calibrate_hand`'s checks: its markers do not
    fit the pose, e.g. a wrong label, or the hand not yet flat), the next nearest flash, of any
    capture, is tried, up to ``max_posed_tries`` flashes in each of the two passes; the messages
    name the flashes refused. ValueError when every one tried is refused (the nearest's reason
    first).

    ``drop_misfits``: the labels of the other flashes that the self-check
    ``calibration_labels_fit`` finds missing the calibrated model by more than their noise allows
    (wrong labels, :func:`misfit_limit`) are left out and the model is fitted once more without
    them; the messages say how many.
    """
    from stillcap.body.hand_label import label_hand_markers

    sets = list(sets)
    if not sets:
        raise ValueError("no calibration capture given")
    sk0 = skeleton or hand_skeleton()
    ms0 = markerset or hand_markerset()
    target = calibration_angles(pose, sk0)
    multi = len(sets) > 1

    def label(s, sk, ms, **more):
        return label_hand_markers(s.points, s.colors, strobe_hz=s.strobe_hz, skeleton=sk, markerset=ms,
                                  reprojection_px=s.reprojection_px, fill=False, unconfirmed=s.unconfirmed, **more)

    def ranked(labs, skip=()):
        """(capture, flash) of the reconstructed flashes, nearest the pose first (``skip``: the
        ``(capture, time)`` of flashes already refused as posed)."""
        cand = []
        for c, lab in enumerate(labs):
            for k in np.flatnonzero(lab.reconstructed):
                if (c, float(lab.times[k])) in skip:
                    continue
                cand.append((float(np.sqrt(np.mean((lab.fits[k].angles_deg - target) ** 2))), c, int(k)))
        return [(c, k) for _, c, k in sorted(cand)]

    def sigma(c, lab, ks):
        ps = sets[c].point_sigma_m
        if ps is None:
            return None
        ps = np.asarray(ps, float)
        pi = lab.point_index[ks]
        return np.where(pi >= 0, ps[np.maximum(pi, 0)], np.nan)

    def free_flashes(labs, c1, k1, held=()):
        """The other flashes fitted with the posed flash ``(c1, k1)``: per capture up to
        ``max_free`` with 9 labelled markers or more, the most labelled first, less those also
        ``held`` in the pose; their markers, their noises (None when no capture has its own) and
        how many per capture."""
        free, free_sig, used = [], [], []
        for c, lab in enumerate(labs):
            rec = np.flatnonzero(lab.reconstructed)
            others = [int(k) for k in rec if (c, int(k)) != (c1, k1)
                      and np.isfinite(lab.positions[k]).all(axis=1).sum() >= 9]
            others = sorted(others, key=lambda k: -np.isfinite(lab.positions[k]).all(axis=1).sum())[:max_free]
            others = [k for k in others if (c, k) not in held]
            used.append(len(others))
            if others:
                free.append(lab.positions[others])
                free_sig.append(sigma(c, lab, others))
        if not free:
            return None, None, used
        if not any(s.point_sigma_m is not None for s in sets):
            return np.concatenate(free), None, used
        # a capture without its own noises: the common one
        free_sig = [np.full(f.shape[:2], kw.get("noise_m", NOISE_M)) if g is None else g for f, g in zip(free, free_sig)]
        return np.concatenate(free), np.concatenate(free_sig), used

    labs = [label(s, sk0, ms0) for s in sets]  # flashes with their back triplet
    order = ranked(labs)
    if not order:
        why = "; ".join(sorted({s for lab in labs for s in lab.skipped if s})) or "no back-of-hand markers found"
        raise ValueError(f"no flash of the calibration capture{'s' if multi else ''} has a hand pose ({why})")
    # the template's angles only shortlist the posed flash: on another person's hand they bend
    # every flash by several degrees, and a flash a few degrees from the pose can come first
    # (another_hand(5): the protocol's spread step, thumb out, 3 deg from flat, taken as flat; its
    # thumb's MCP then calibrated 20 mm off). The capture itself tells them apart: the same labels
    # of every flash fitted with each candidate held in the pose; a flash not in it must be absorbed
    # by the shared model, which the other flashes' bends then miss (:func:`_pose_costs`)
    def posed_of(labs, cks):
        """The markers of the flashes ``cks`` held in the pose and their noises (None: no own)."""
        sig = [sigma(c, labs[c], [k]) for c, k in cks]
        if not any(s is not None for s in sig):
            sig = None
        else:
            sig = np.concatenate([np.full((1, len(ms0)), kw.get("noise_m", NOISE_M)) if s is None else s
                                  for s in sig])
        return np.stack([labs[c].positions[k] for c, k in cks]), sig

    def by_fit(labs, order):
        if max_posed_tries < 2 or len(order) < 2:
            return order, []
        short = order[:max_posed_tries]
        fits = []  # the held fits, the best's reused by _also_posed
        cost = _pose_costs([(*posed_of(labs, [ck]), free_flashes(labs, *ck)[:2]) for ck in short], fits=fits,
                           pose=pose, skeleton=sk0, markerset=ms0, **kw)
        rank = np.argsort(cost, kind="stable")
        best = short[rank[0]]
        # a protocol has more than one flat flash (its first and its last): every one the data
        # cannot tell from the pose is held with the best, so that one label a few mm off in one
        # of them is outvoted (docs/hand-calibration.md, "Which flash is the flat one")
        rest = [short[i] for i in rank[1:] if np.isfinite(cost[i])]
        ok = _also_posed((*posed_of(labs, [best]), free_flashes(labs, *best)[:2]),
                         [(*posed_of(labs, [best, ck]), free_flashes(labs, *best, held={ck})[:2]) for ck in rest],
                         alone=fits[rank[0]] if len(fits) == len(short) else None,
                         pose=pose, skeleton=sk0, markerset=ms0, **kw) if rest else []
        also = [ck for ck, y in zip(rest, ok) if y]
        return [short[i] for i in rank] + order[max_posed_tries:], also

    order, also = by_fit(labs, order)
    # the flash nearest the pose may not be in it (a wrong label, a hand not yet flat): the next
    # nearest ones are tried, up to max_posed_tries, before the capture is refused
    # the first pass's model only labels the second pass: from the posed flash alone, which bends
    # no joint, the back triangle's shape cannot be told from the frame's tilt, so it is held
    refused, first = [], None
    for c0, k0 in order[:max_posed_tries]:
        try:
            first = calibrate_hand(labs[c0].positions[k0], pose=pose, skeleton=sk0, markerset=ms0,
                                   posed_sigma_m=sigma(c0, labs[c0], [k0]), **{**kw, "back_sigma_m": None})
            break
        except ValueError as e:
            refused.append(((c0, float(labs[c0].times[k0])), _flash_name(labs[c0], c0, k0, multi), e))
    if first is None:
        raise _refusal(refused)
    labs2 = [label(s, first.skeleton, first.markerset, hand_scale=1.0) for s in sets]
    # the first model reads its own posed flash as flat whether it is or not, and its labels can be
    # worse than the template's for the flash held (another_hand(7): a thumb nail 38 mm off): the
    # flash the first pass took (ranked by the fit) stays first
    order2 = ranked(labs2, skip={r[0] for r in refused})
    # (the same flash: the same back-of-hand points; a labelling's flash times are its own)
    back = [ms0.index(n) for n in BACK_MARKERS]

    def same(c, k):
        return [(c, int(j)) for j in np.flatnonzero(labs2[c].reconstructed)
                if np.array_equal(labs2[c].point_index[j][back], labs[c].point_index[k][back])]

    order2 = sorted(order2, key=lambda ck: ck not in same(c0, k0))
    if not order2:
        return first
    # the flashes the first pass found in the pose too, held with the first when it is
    held2 = [ck for c, k in (also if (c0, k0) == order[0] else []) for ck in same(c, k)[:1] if ck in order2]
    cal = None
    for i, (c1, k1) in enumerate(order2[:max_posed_tries]):
        held = held2 if i == 0 and (c1, k1) in same(c0, k0) else []
        free, free_sig, used = free_flashes(labs2, c1, k1, held=set(held))
        posed, posed_sig = posed_of(labs2, [(c1, k1)] + held)
        fit = dict(posed=posed, free=free, pose=pose, skeleton=sk0, markerset=ms0,
                   posed_sigma_m=posed_sig, free_sigma_m=free_sig, **kw)
        try:
            cal = calibrate_hand(**fit)
            cal, fit, scaled = _hidden_noise(cal, fit)
            cal = _without_misfits(cal, fit) if drop_misfits else cal
            cal.messages[:0] = [scaled] if scaled else []
            break
        except ValueError as e:
            # the posed flash calibrated alone in the first pass: a refusal of the fit with the
            # other flashes may be their wrong labels (a linear fit follows a label centimetres
            # off), so it is fitted again without the labels a robust fit names first
            try:
                cal = _without_misfits(None, fit, refused=e) if drop_misfits and fit["free"] is not None else None
            except ValueError:
                cal = None
            if cal is not None:
                break
            refused.append(((c1, float(labs2[c1].times[k1])), _flash_name(labs2[c1], c1, k1, multi), e))
    if cal is None:
        raise _refusal(refused)
    cal.messages += [f"{name} was not taken as the {pose} flash: {e}" for _, name, e in refused]
    if not multi:
        cal.messages.append(f"calibration pose in flash(es) {', '.join(str(int(labs2[c].order[k])) for c, k in [(c1, k1)] + held)}, {used[0]} other flash(es) "
                            f"used, {int(labs2[0].reconstructed.sum())} with a pose of {labs2[0].n_flashes}")
    else:
        cal.messages.append(f"calibration pose in flash {int(labs2[c1].order[k1])} of capture {c1 + 1}; other "
                            f"flashes used per capture: {', '.join(map(str, used))} (with a pose: "
                            f"{', '.join(str(int(lab.reconstructed.sum())) for lab in labs2)})")
    return cal


#: :func:`calibrate_hand`'s arguments for the fits robust to wrong labels (:func:`_held_fit`,
#: :func:`_robust_fit`): soft-L1, nothing refused, no length cap, the back triangle held
_ROBUST = {"loss": "soft_l1", "refuse_rms_m": np.inf, "refuse_prior_z": np.inf, "max_length_sigma_m": None,
           "back_sigma_m": None}


def _pose_costs(candidates, fits: list | None = None, **kw) -> np.ndarray:
    """Per candidate ``(posed markers, their noises, (free markers, their noises))`` (the same
    flashes each time, one of them held in the pose), the objective of the fit robust to wrong
    labels (soft-L1, 3 sigmas; no refusal, the back triangle held: :func:`calibrate_hand`'s
    arguments ``kw``); inf when the fit fails. The data are the same for every candidate, only
    which flash is held differs, so the costs compare: a flash held in a pose it is not in moves
    the shared model off the hand and the other flashes' bends miss it (measured on the studio's
    protocol captures of another_hand(5), 3 and 12: 1.2-2 times the cost of a flat flash;
    docs/hand-calibration.md). ``fits``: a list the fits (None when failed) are appended to."""
    cost = []
    for posed, posed_sig, (free, free_sig) in candidates:
        c = _held_fit(posed, posed_sig, free, free_sig, **kw)
        cost.append(np.inf if c is None else c.cost)
        if fits is not None:
            fits.append(c)
    return np.array(cost, float)


def _held_fit(posed, posed_sig, free, free_sig, **kw) -> HandCalibration | None:
    """:func:`_pose_costs`'s fit (None when it fails)."""
    try:
        return calibrate_hand(posed, free, posed_sigma_m=posed_sig, free_sigma_m=free_sig, **{**kw, **_ROBUST})
    except ValueError:
        return None


def _also_posed(best, pairs, alone: HandCalibration | None = None, **kw) -> list:
    """Per pair, whether its second flash is in the pose too. ``best`` is :func:`_pose_costs`'s
    candidate ``(posed, noises, (free, noises))`` of the best flash, each of ``pairs`` one with the
    best flash and a second held, the second taken out of the free ones (the same data).
    Holding the second's angles is a nested constraint: in the pose, the objective rises by a
    chi-square with one degree per angle (:func:`~stillcap.body.hand.hand_dofs`), scaled by the
    reduced chi-square of the best's fit when the noise was larger than stated (not of the fit with both
    held: a bent flash held inflates it, 98 against 1.4 on another_hand(5), and the test would
    pass it); a rise the test finds unlikely at :data:`ALSO_POSED_P` says the flash is bent.
    ``alone``: the best's fit when :func:`_pose_costs` made it (else it is fitted here)."""
    from scipy.stats import chi2

    from stillcap.body.hand import hand_dofs

    alone = alone if alone is not None else _held_fit(*best[:2], *best[2], **kw)
    limit = chi2.ppf(1.0 - ALSO_POSED_P, len(hand_dofs(kw.get("skeleton") or hand_skeleton())))
    out = []
    for posed, posed_sig, (free, free_sig) in pairs:
        both = None if alone is None else _held_fit(posed, posed_sig, free, free_sig, **kw)
        out.append(both is not None and bool((both.cost - alone.cost) / alone.chi2_scale <= limit))
    return out


def _hidden_noise(cal: HandCalibration, fit: dict) -> tuple[HandCalibration, dict, str]:
    """``(cal, fit, message)``: ``cal`` and its arguments ``fit`` fitted again with the stated
    noises of the labels noisier than a fully seen marker (the partly hidden ones,
    :func:`calibrate_hand`'s ``posed_sigma_m`` / ``free_sigma_m`` above ``noise_m``) scaled to what the fit's residuals show, when those show them smaller: their
    ``(r / sigma)^2`` sum to a chi-square with 3 degrees per label, and the scale is its upper
    bound at :data:`HIDDEN_NOISE_P` (never above 1, nor a label below ``noise_m``). A stated
    noise from the share of a marker's light (millimetres) can be ten times its error, and a
    marker partly hidden in every flat flash then has its place from the priors (the studio's hand
    11: its little finger's DIP marker 2.8 mm off, the throw's DIP 10 deg; docs/hand-calibration.md).
    Unchanged (message empty) when no label is noisier or the scale is not below 1; a refused
    refit keeps ``cal`` and says so."""
    from scipy.stats import chi2

    noise = fit.get("noise_m", NOISE_M)
    ps, fs = fit.get("posed_sigma_m"), fit.get("free_sigma_m")
    if ps is None and fs is None:
        return cal, fit, ""
    n_posed = cal.n_posed
    sig = np.concatenate([np.full((n_posed, cal.misfit.shape[1]), noise) if ps is None else
                          np.asarray(ps, float).reshape(n_posed, -1),
                          np.full((cal.n_free, cal.misfit.shape[1]), noise) if fs is None else
                          np.asarray(fs, float).reshape(cal.n_free, -1)])
    hid = np.isfinite(cal.misfit) & np.isfinite(sig) & (sig > noise)
    if not hid.any():
        return cal, fit, ""
    scale = np.sqrt(cal.misfit[hid].sum() / chi2.ppf(HIDDEN_NOISE_P, 3 * int(hid.sum())))
    if not scale < 1.0:
        return cal, fit, ""
    sig = np.where(hid, np.maximum(sig * scale, noise), sig)
    scaled = {**fit, "posed_sigma_m": sig[:n_posed], "free_sigma_m": sig[n_posed:] if cal.n_free else None}
    try:
        again = calibrate_hand(**scaled)
    except ValueError as e:
        return cal, fit, f"fitting again with the partly hidden markers' noise x{scale:.2f} was refused: {e}"
    return again, scaled, f"the partly hidden markers' noise scaled by {scale:.2f} (what the fit's residuals show)"


def _robust_fit(fit: dict) -> tuple[HandCalibration, np.ndarray]:
    """:func:`calibrate_hand` of ``fit`` (its arguments) with a robust loss (soft-L1, 3 sigmas), and
    the labels (bool, ``(n_posed + n_free, n_markers)``) that miss it by more than their noise allows
    (:func:`misfit_limit` over every label). A linear fit bends the shared model toward a wrong
    label (and can stop in another minimum: hand 12, docs/hand-calibration.md) and spreads its
    misfit over the right labels near it; the robust one bounds its pull, so the wrong label keeps
    its misfit. Nothing is refused here (soft-L1 softens the priors too: a wrong label 56 mm off
    still moves its marker's place 38 mm, though it keeps its misfit)."""
    rob = calibrate_hand(**{**fit, **_ROBUST})
    seen = np.isfinite(rob.misfit)
    bad = seen & (np.where(seen, rob.misfit, 0.0) > misfit_limit(int(seen.sum())))
    bad[:, [rob.markerset.index(n) for n in BACK_MARKERS]] = False  # every flash's pose needs them
    return rob, bad


def _without_misfits(cal: HandCalibration | None, fit: dict, refused: Exception | None = None) -> HandCalibration:
    """``cal`` fitted again without the labels a robust fit finds missing the model
    (:func:`_robust_fit`), when its self-check ``calibration_labels_fit`` failed; ``cal`` None: the
    linear fit of ``fit`` (:func:`calibrate_hand`'s arguments) was ``refused``, and when the robust
    fit names no label it is the calibration if it passes the checks (fitted again with them).
    Labels of the posed flash are left out one by one, a free flash's by digit; free flashes left
    with fewer than 9 labels are dropped. Returns ``cal`` when the robust fit names nothing or the
    new fit is refused (a message says so); ValueError when ``cal`` is None and the robust fit
    (with its checks) or the new fit is refused."""
    if cal is not None:
        check = next(c for c in cal.self_checks if c.name == "calibration_labels_fit")
        if check.passed or fit["free"] is None:
            return cal
    rob, bad = _robust_fit(fit)
    why = (f"the fit with every label at its noise was refused ({refused})" if cal is None else
           next(c for c in cal.self_checks if c.name == "calibration_labels_fit").message)
    if not bad.any():
        if cal is None:  # no wrong label: the linear fit stopped in another minimum
            rob = calibrate_hand(**{**fit, "loss": "soft_l1"})  # with the checks (ValueError)
            rob.messages.append(f"the model is the fit robust to wrong labels (soft-L1), which names none: {why}")
            return rob
        return cal
    free0 = np.asarray(fit["free"], float)
    posed0 = np.asarray(fit["posed"], float).reshape(-1, free0.shape[1], 3)
    n_posed = len(posed0)
    names = (fit.get("markerset") or hand_markerset()).names
    # in a free flash the digit's angles are free too, so they can follow a wrong label and leave
    # the misfit on a right one of the same digit (hand 7: a hook's ring nail 77 mm off kept, its
    # PIP marker named): the digit's labels of that flash go together
    digit = np.array([n.split(".")[0] for n in names])
    for f, m in np.argwhere(bad[n_posed:]):
        bad[n_posed + f] |= (digit == digit[m]) & np.isfinite(free0[f]).all(axis=1)
    posed = np.where(bad[:n_posed, :, None], np.nan, posed0)
    free = np.where(bad[n_posed:, :, None], np.nan, free0)
    keep = np.isfinite(free).all(axis=2).sum(axis=1) >= 9  # as the flashes chosen: 9 labelled markers
    fs = fit.get("free_sigma_m")
    try:
        again = calibrate_hand(**{**fit, "posed": posed, "free": free[keep] if keep.any() else None,
                                  "free_sigma_m": None if fs is None or not keep.any() else fs[keep]})
    except ValueError as e:  # kept as it was, the check failed
        if cal is None:
            raise
        cal.messages.append(f"fitting again without the {int(bad.sum())} label(s) that miss the model was refused: {e}")
        return cal
    which = ", ".join(f"{names[m]} of fitted flash {f}" for f, m in np.argwhere(bad)[:6])
    again.messages.append(f"{int(bad.sum())} label(s) that miss the model ({which}{' ...' if bad.sum() > 6 else ''}) "
                          f"left out and the model fitted again: {why}")
    return again


def _flash_name(lab, c: int, k: int, multi: bool) -> str:
    return f"flash {int(lab.order[k])}" + (f" of capture {c + 1}" if multi else "")


def _refusal(refused) -> ValueError:
    """The ValueError when every flash tried as the posed one was refused: the nearest's reason
    first, then the others'."""
    (_, name, e), rest = refused[0], refused[1:]
    more = "".join(f"; {n} was refused too: {x}" for _, n, x in rest)
    return ValueError(f"{e}{more}" if rest else str(e))


def digit_lengths_table(cal: HandCalibration, template: Skeleton | None = None) -> list:
    """Rows ``(digit, [lengths mm])`` for printing: metacarpal (wrist to knuckle) and phalanges."""
    L = cal.lengths()
    rows = []
    for d in DIGITS:
        names = [n for n in cal.skeleton.names if n.startswith(d + "-")]
        rows.append((d, [L[n] * 1e3 for n in names]))
    return rows
