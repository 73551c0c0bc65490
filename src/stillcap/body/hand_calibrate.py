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

from dataclasses import dataclass, field

import numpy as np

from stillcap.body.hand import BACK_MARKERS, DIGITS, hand_markerset, hand_skeleton, scale_hand
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton

__all__ = ["CALIBRATION_POSES", "REFUSE_RMS_M", "HandCalibration", "calibration_angles", "calibrate_hand",
           "calibrate_hand_from_points", "phalanx_lengths"]

#: The calibration poses: name -> description (their angles: :func:`calibration_angles`).
CALIBRATION_POSES = {"flat": "hand flat, fingers extended and together, thumb alongside (every joint angle 0)"}
#: A calibration flash whose markers the calibrated model cannot fit within this RMS (m) is not
#: in the stated pose (the measured noise is 0.2-0.4 mm; a wrong pose gives several mm).
REFUSE_RMS_M = 0.0015
#: Assumed noise of a labelled 3D marker (m): weighs the markers against the priors.
NOISE_M = 0.0004


def calibration_angles(pose: str, skeleton: Skeleton) -> np.ndarray:
    """The joint angles (degrees, ``(n_joints, 3)``) of a calibration pose."""
    if pose not in CALIBRATION_POSES:
        raise ValueError(f"unknown calibration pose {pose!r}; known: {', '.join(CALIBRATION_POSES)}")
    return np.zeros((skeleton.n_joints, 3))


def phalanx_lengths(skeleton: Skeleton) -> dict:
    """Length (m) of every bone but the root, by the joint at its end (``index-pip`` is the
    index's proximal phalanx; ``index-mcp`` its metacarpal, wrist to knuckle)."""
    L = np.linalg.norm(skeleton.offsets, axis=1)
    return {n: float(L[i]) for i, n in enumerate(skeleton.names) if i != skeleton.root}


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
    messages : list of str
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

    def lengths(self) -> dict:
        return phalanx_lengths(self.skeleton)


def _size(markerset: MarkerSet, pts) -> float:
    b = [markerset.index(n) for n in BACK_MARKERS]
    d0 = np.linalg.norm(markerset.offsets[b][:, None] - markerset.offsets[b][None], axis=-1).sum()
    d1 = np.linalg.norm(pts[b][:, None] - pts[b][None], axis=-1).sum()
    return float(d1 / d0)


def calibrate_hand(posed, free=None, *, pose: str = "flat", skeleton: Skeleton | None = None,
                   markerset: MarkerSet | None = None, noise_m: float = NOISE_M, max_nfev: int = 100,
                   refuse_rms_m: float = REFUSE_RMS_M) -> HandCalibration:
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
    """
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
    ad = adapt_hand_model(sk, ms, pts, known_deg=kd, noise_m=noise_m, loss="linear", max_nfev=max_nfev)
    res = ad.residuals
    pose_rms = float(np.sqrt(np.nanmean(res[:len(posed)] ** 2)))
    if not pose_rms <= refuse_rms_m:
        worst = ad.digit_rms()
        dig = max((d for d in worst if np.isfinite(worst[d])), key=lambda d: worst[d])
        raise ValueError(f"the calibration flash is not in the {pose!r} pose ({CALIBRATION_POSES[pose]}): its "
                         f"markers miss the calibrated model by {pose_rms * 1e3:.1f} mm RMS (limit "
                         f"{refuse_rms_m * 1e3:.1f} mm; worst: {dig}, {worst[dig] * 1e3:.1f} mm)")
    sk1 = Skeleton(ad.skeleton.joints, name=f"{sk0.name}-calibrated", source=f"hand-calibrate ({pose})")
    ms1 = MarkerSet(ad.markerset.markers, ad.markerset.rules, ms0.name, sk1.name, f"hand-calibrate ({pose})")
    msgs = []
    if len(free) == 0:
        msgs.append("only the calibration pose was seen: the joint centres along the fingers stay at the "
                    "template's (scaled); flashes of the fingers curling fix them")
    return HandCalibration(sk1, ms1, pose, size, ad.rms, pose_rms, len(posed), len(free), res, msgs)


def calibrate_hand_from_points(points, colors, *, strobe_hz: float, pose: str = "flat",
                               skeleton: Skeleton | None = None, markerset: MarkerSet | None = None,
                               reprojection_px=None, max_free: int = 4, **kw) -> HandCalibration:
    """Label the unlabelled 3D markers of a calibration capture and calibrate the hand.

    The markers are labelled with the template scaled to the hand
    (:func:`~stillcap.body.hand_label.label_hand_markers`); the flash whose fitted angles are
    nearest the calibration pose is taken as posed; a first calibration on it alone labels the
    capture again (a model nearer the hand labels more), and the final calibration uses it with
    up to ``max_free`` other flashes. Keyword arguments go to :func:`calibrate_hand`.
    """
    from stillcap.body.hand_label import label_hand_markers

    sk0 = skeleton or hand_skeleton()
    ms0 = markerset or hand_markerset()
    target = calibration_angles(pose, sk0)
    lab = label_hand_markers(points, colors, strobe_hz=strobe_hz, skeleton=sk0, markerset=ms0,
                             reprojection_px=reprojection_px, fill=False)  # flashes with their back triplet
    rec = np.flatnonzero(lab.reconstructed)
    if len(rec) == 0:
        why = "; ".join(sorted({s for s in lab.skipped if s})) or "no back-of-hand markers found"
        raise ValueError(f"no flash of the calibration capture has a hand pose ({why})")
    dist = [float(np.sqrt(np.mean((lab.fits[k].angles_deg - target) ** 2))) for k in rec]
    k0 = int(rec[int(np.argmin(dist))])
    first = calibrate_hand(lab.positions[k0], pose=pose, skeleton=sk0, markerset=ms0, **kw)
    lab2 = label_hand_markers(points, colors, strobe_hz=strobe_hz, skeleton=first.skeleton,
                              markerset=first.markerset, reprojection_px=reprojection_px, hand_scale=1.0,
                              fill=False)
    rec2 = np.flatnonzero(lab2.reconstructed)
    if len(rec2) == 0:
        return first
    d2 = [float(np.sqrt(np.mean((lab2.fits[k].angles_deg - target) ** 2))) for k in rec2]
    k1 = int(rec2[int(np.argmin(d2))])
    others = [int(k) for k in rec2 if k != k1 and np.isfinite(lab2.positions[k]).all(axis=1).sum() >= 9]
    others = sorted(others, key=lambda k: -np.isfinite(lab2.positions[k]).all(axis=1).sum())[:max_free]
    cal = calibrate_hand(lab2.positions[k1], lab2.positions[others] if others else None, pose=pose,
                         skeleton=sk0, markerset=ms0, **kw)
    cal.messages.append(f"calibration pose in flash {int(lab2.order[k1])}, {len(others)} other flash(es) "
                        f"used, {int(lab2.reconstructed.sum())} with a pose of {lab2.n_flashes}")
    return cal


def digit_lengths_table(cal: HandCalibration, template: Skeleton | None = None) -> list:
    """Rows ``(digit, [lengths mm])`` for printing: metacarpal (wrist to knuckle) and phalanges."""
    L = cal.lengths()
    rows = []
    for d in DIGITS:
        names = [n for n in cal.skeleton.names if n.startswith(d + "-")]
        rows.append((d, [L[n] * 1e3 for n in names]))
    return rows
