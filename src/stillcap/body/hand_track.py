"""The hand over a capture: a pose per flash, the person's hand, and a smooth animation.

From labelled markers (:class:`~stillcap.body.hand_label.HandLabels`) to

- :func:`fit_hand_sequence`: the pose of every flash whose back-of-hand markers were found
  (rigid alignment of the back of the hand, then every joint within its limits:
  :func:`~stillcap.body.hand.fit_hand`, each flash started from the previous one), optionally
  on a hand personalised to the markers (one scale factor per palm and digit);
- :func:`interpolate_animation`: keyframe interpolation to an :class:`Animation` at a frame
  rate (joint local rotations and the root's rotation by ``Slerp`` or ``RotationSpline``, the
  root's position by a cubic spline; the keyframes are reproduced exactly);
- :func:`joint_angle_series`: the joint angles (degrees, per degree of freedom) over time, for
  plots and comparisons.

See ``docs/hand-labelling.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline, Slerp

from stillcap._checks import as_array
from stillcap.body.hand import BACK_MARKERS, fit_hand, fit_hand_poses, hand_dofs, personalise_hand
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Animation, Pose, Skeleton

__all__ = ["HandSequence", "JointAngleSeries", "fit_hand_sequence", "interpolate_animation", "joint_angle_series",
           "observed_dofs", "dofs_fixed_by", "dofs_on_partly_hidden"]

_PERSONALISE = (None, "best", "joint")
_AXES = ("twist", "flexion", "abduction")


@dataclass(eq=False)
class HandSequence:
    """Fitted hand poses of the reconstructed flashes of one capture, in time order.

    Attributes
    ----------
    skeleton, markerset : Skeleton, MarkerSet
        The hand the poses belong to (personalised when asked).
    flashes : ndarray of int, shape (n,)
        Index of each pose's flash in the labels.
    times : ndarray, shape (n,)
        Seconds (default: after the first reconstructed flash).
    poses : list of Pose
    angles_deg : ndarray, shape (n, n_joints, 3)
        Joint angles (twist, flexion, abduction), as :meth:`Skeleton.limit_angles_deg` reads them.
    residuals : ndarray, shape (n, n_markers)
        Fitted-to-measured marker distances (m), NaN for unseen markers.
    rms : ndarray, shape (n,)
        Per-flash RMS of the residuals (m).
    n_markers : ndarray of int, shape (n,)
    success : ndarray of bool, shape (n,)
    scales : dict
        Scale factor per group (all 1 without personalisation).
    personalise : str or None
    """

    skeleton: Skeleton
    markerset: MarkerSet
    flashes: np.ndarray
    times: np.ndarray
    poses: list
    angles_deg: np.ndarray
    residuals: np.ndarray
    rms: np.ndarray
    n_markers: np.ndarray
    success: np.ndarray
    scales: dict
    personalise: str | None = None

    @property
    def n(self) -> int:
        return len(self.times)

    @property
    def root2world(self) -> np.ndarray:
        """Shape (n, 4, 4)."""
        return np.stack([p.root2world for p in self.poses])

    @property
    def local_rotations(self) -> np.ndarray:
        """Shape (n, n_joints, 3, 3)."""
        return np.stack([p.local_rotations for p in self.poses])

    def markers(self) -> np.ndarray:
        """The model's marker positions per pose, shape (n, n_markers, 3)."""
        return np.stack([self.markerset.positions(p) for p in self.poses])

    def to_dict(self) -> dict:
        """JSON-ready dict, keys shared with the hand truth (``times_s``, ``root2world``,
        ``angles_deg``, ``joints``)."""
        from stillcap.files.jsonable import to_jsonable

        return to_jsonable({"joint_names": list(self.skeleton.names), "scales": self.scales,
                            "personalise": self.personalise,
                            "flashes": {"flash": self.flashes, "times_s": self.times, "root2world": self.root2world,
                                        "angles_deg": self.angles_deg,
                                        "joints": np.stack([p.positions for p in self.poses]),
                                        "rms_mm": self.rms * 1000, "n_markers": self.n_markers,
                                        "success": self.success}})


def fit_hand_sequence(labels, skeleton: Skeleton | None = None, markerset: MarkerSet | None = None, *,
                      personalise: str | None = None, times=None, point_sigma_m=None) -> HandSequence:
    """Fit the hand pose of every reconstructed flash.

    Parameters
    ----------
    labels : HandLabels
        From :func:`~stillcap.body.hand_label.label_hand_markers`.
    skeleton, markerset : optional
        The hand (default: the labels' own).
    personalise : {None, "best", "joint"}
        Scale the hand to the person first: ``"best"`` from the flash with the most markers
        (:func:`~stillcap.body.hand.personalise_hand`), ``"joint"`` from all reconstructed
        flashes at once (:func:`~stillcap.body.hand.fit_hand_poses`, one scale per group
        shared by all poses). Off by default: see ``docs/hand-labelling.md`` for what it costs
        on a hand of the model's size.
    times : array_like, shape (labels.n_flashes,), optional
        Time of every flash of the labels (s); default ``labels.times`` minus the first
        reconstructed flash's time.

    point_sigma_m : array_like, shape (len(labels.points),), optional
        Position uncertainty of every point (m): each marker's residual is weighted by
        ``min(sigma) / sigma`` (e.g. partly hidden markers, whose centroids shift, count less).

    Returns
    -------
    HandSequence
    """
    if personalise not in _PERSONALISE:
        raise ValueError(f"personalise must be one of {_PERSONALISE}, got {personalise!r}")
    sk = skeleton or labels.skeleton
    ms = markerset or labels.markerset
    if list(ms.names) != list(labels.marker_names):
        raise ValueError(f"markerset {ms.name!r} has markers {list(ms.names)}, the labels {list(labels.marker_names)}")
    flashes = np.flatnonzero(labels.reconstructed)
    if not len(flashes):
        why = "; ".join(f"flash {k}: {s}" for k, s in enumerate(labels.skipped)) or "no flash was found"
        raise ValueError(f"no flash has its back-of-hand markers, nothing to fit ({why})")
    if times is None:
        t = labels.times[flashes] - labels.times[flashes[0]]
    else:
        t = as_array(times, (labels.n_flashes,), "times")[flashes]
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("times of the reconstructed flashes must be finite and increasing")
    pos = labels.positions[flashes]
    scales = {g: 1.0 for g in ("palm", "thumb", "index", "middle", "ring", "little")}
    if personalise == "best":
        best = int(np.argmax(np.isfinite(pos[..., 0]).sum(axis=1)))
        init = labels.fits[flashes[best]].pose if labels.fits[flashes[best]] is not None else None
        p = personalise_hand(sk, ms, pos[best], initial=init)
        sk, ms, scales = p.skeleton, p.markerset, p.scales
    elif personalise == "joint":
        scales, fits = fit_hand_poses(sk, ms, pos, fit_scale=True,
                                      initial=[labels.fits[k].pose if labels.fits[k] is not None else None
                                               for k in flashes])
        sk, ms = fits[0].skeleton, fits[0].markerset
    wts = np.ones((len(flashes), len(ms.names)))
    if point_sigma_m is not None:
        sig = as_array(point_sigma_m, (len(labels.points),), "point_sigma_m")
        if not np.all(np.isfinite(sig) & (sig > 0)):
            raise ValueError("point_sigma_m must be finite and > 0")
        idx = labels.point_index[flashes]
        wts = np.where(idx >= 0, sig.min() / sig[np.maximum(idx, 0)], 1.0)
    fits, prev = [], None
    back = [ms.index(b) for b in BACK_MARKERS]
    for k in range(len(flashes)):
        own = labels.fits[flashes[k]]
        init = prev if prev is not None else own.pose if own is not None else None
        from_triplet = np.isfinite(pos[k, back]).all()
        if own is not None and not from_triplet:  # posed from its other markers
            init = own.pose  # (stillcap.body.hand_label_fill): its root starts from its own pose
        if init is not None and init.skeleton is not sk:
            init = Pose(sk, init.root2world, init.local_rotations)
        f = fit_hand(sk, ms, pos[k], initial=init, weights=wts[k])
        fits.append(f)
        if from_triplet:  # a flash posed from a neighbour's prior is no start for the next one: its
            prev = f.pose  # digits with one marker or none keep angles the photos do not fix
    return HandSequence(sk, ms, flashes, t, [f.pose for f in fits],
                        np.stack([sk.limit_angles_deg(f.pose.local_rotations) for f in fits]),
                        np.stack([f.residuals for f in fits]), np.array([f.rms for f in fits]),
                        np.array([f.n_markers for f in fits]), np.array([f.success for f in fits]), dict(scales),
                        personalise)


def interpolate_animation(sequence: HandSequence, frame_rate: float = 1000.0, *, times=None,
                          method: str = "slerp") -> Animation:
    """Keyframe interpolation of a hand sequence into an animation.

    Joint local rotations and the root's rotation are interpolated by ``Slerp`` (``"slerp"``:
    constant angular speed between keyframes, C0 at them) or ``RotationSpline`` (``"spline"``:
    continuous angular velocity and acceleration); the root's position by a cubic spline
    (``scipy.interpolate.CubicSpline``, not-a-knot). Both pass through the keyframes exactly.

    Parameters
    ----------
    sequence : HandSequence
        Two or more keyframes.
    frame_rate : float
        Frames per second, from the first keyframe to the last (default 1000).
    times : array_like, shape (n_frames,), optional
        Explicit frame times (s) within the keyframes' span, increasing; replaces ``frame_rate``.
    method : {"slerp", "spline"}

    Returns
    -------
    Animation
    """
    if method not in ("slerp", "spline"):
        raise ValueError(f"method must be 'slerp' or 'spline', got {method!r}")
    kt = np.asarray(sequence.times, float)
    if len(kt) < 2:
        raise ValueError(f"interpolation needs 2+ keyframes, got {len(kt)}")
    if times is None:
        rate = float(frame_rate)
        if not (np.isfinite(rate) and rate > 0):
            raise ValueError(f"frame_rate must be finite and > 0, got {frame_rate}")
        n = int(np.floor((kt[-1] - kt[0]) * rate + 1e-9)) + 1
        t = kt[0] + np.arange(n) / rate
    else:
        t = as_array(times, (None,), "times")
        span = 1e-9 * max(1.0, abs(kt[-1]))
        if len(t) == 0 or t.min() < kt[0] - span or t.max() > kt[-1] + span:
            raise ValueError(f"times must lie within the keyframes' span [{kt[0]:g}, {kt[-1]:g}] s")
        t = np.clip(t, kt[0], kt[-1])

    def interp(mats):  # (n_keys, 3, 3) -> (n_frames, 3, 3)
        r = Rotation.from_matrix(mats)
        f = Slerp(kt, r) if method == "slerp" else RotationSpline(kt, r)
        out = f(t).as_matrix()
        # the interpolants hit the keyframes to rounding: put the keyframes back exactly
        hit = np.isclose(t[:, None], kt[None], rtol=0, atol=1e-12)
        for i, j in zip(*np.nonzero(hit)):
            out[i] = mats[j]
        return out

    r2w = sequence.root2world
    local = sequence.local_rotations
    nj = local.shape[1]
    out_local = np.empty((len(t), nj, 3, 3))
    for j in range(nj):
        if np.allclose(local[:, j], np.eye(3), atol=0):
            out_local[:, j] = np.eye(3)  # locked joints stay exactly identity
        else:
            out_local[:, j] = interp(local[:, j])
    root = np.tile(np.eye(4), (len(t), 1, 1))
    root[:, :3, :3] = interp(r2w[:, :3, :3])
    root[:, :3, 3] = CubicSpline(kt, r2w[:, :3, 3], axis=0)(t)
    return Animation(sequence.skeleton, t, root, out_local)


@dataclass(eq=False)
class JointAngleSeries:
    """Joint angles over time.

    Attributes
    ----------
    times : ndarray, shape (n,)
    angles_deg : ndarray, shape (n, n_joints, 3)
        Twist, flexion, abduction per joint (intrinsic XYZ Euler, as the limits read them).
    dofs : list of (int, int)
        ``(joint, axis)`` of the free axes (:func:`~stillcap.body.hand.hand_dofs`).
    names : list of str
        ``"index-mcp.flexion"`` style name per DOF.
    """

    times: np.ndarray
    angles_deg: np.ndarray
    dofs: list
    names: list

    @property
    def values(self) -> np.ndarray:
        """Angle per DOF over time, shape (n, n_dofs), degrees."""
        return np.stack([self.angles_deg[:, j, a] for j, a in self.dofs], axis=1)

    def __getitem__(self, name: str) -> np.ndarray:
        """One DOF's angles over time by name (e.g. ``"index-pip.flexion"``)."""
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise ValueError(f"unknown degree of freedom {name!r}; known: {', '.join(self.names)}") from None


def joint_angle_series(animation, skeleton: Skeleton | None = None) -> JointAngleSeries:
    """The joint angles (degrees) of every degree of freedom over time.

    Parameters
    ----------
    animation : Animation or HandSequence
    skeleton : Skeleton, optional
        Default the animation's own.

    Returns
    -------
    JointAngleSeries
    """
    if not hasattr(animation, "local_rotations") or not hasattr(animation, "times"):
        raise ValueError(f"joint_angle_series needs an Animation or a HandSequence, got {type(animation).__name__}")
    sk = skeleton or animation.skeleton
    local = np.asarray(animation.local_rotations, float)
    if local.ndim != 4 or local.shape[1:] != (sk.n_joints, 3, 3):
        raise ValueError(f"local_rotations must have shape (n, {sk.n_joints}, 3, 3), got {local.shape}")
    ang = np.stack([sk.limit_angles_deg(r) for r in local]) if len(local) else np.zeros((0, sk.n_joints, 3))
    dofs = hand_dofs(sk)
    names = [f"{sk.names[j]}.{_AXES[a]}" for j, a in dofs]
    return JointAngleSeries(np.asarray(animation.times, float), ang, dofs, names)


def observed_dofs(sequence: HandSequence, k: int) -> list[tuple[int, int]]:
    """The degrees of freedom (``(joint, axis)`` of :func:`~stillcap.body.hand.hand_dofs`) that the
    markers seen at pose ``k`` fix: every marker on the joint's chain, from the back of the hand
    down to the joint itself, was seen (the thumb CMC also needs the thumb MCP's marker). The
    others rest on the fit's pull toward its start and say nothing about the hand."""
    seen = np.isfinite(sequence.residuals[k])
    return [(j, a) for j, a, _ in dofs_fixed_by(sequence.skeleton, sequence.markerset, seen)]


def dofs_fixed_by(skeleton, markerset, seen: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """:func:`observed_dofs`'s rule for any set of seen markers (a bool per marker):
    ``(joint, axis, the markers it needs)`` for each degree of freedom they fix."""
    sk, frames = skeleton, markerset.bone_frames(skeleton)
    out = []
    for j, a in hand_dofs(sk):
        chain, c = [], j
        while c != sk.root:
            chain.append(c)
            c = sk.parents[c]
        need = np.isin(frames, chain)
        if sk.names[j] == "thumb-cmc":
            need |= frames == sk.index("thumb-mcp")
        if seen[need].all():
            out.append((j, a, need))
    return out


def dofs_on_partly_hidden(sequence: HandSequence, point_index, partly_hidden) -> np.ndarray:
    """Which fitted joint angles rest only on partly hidden markers (issue 12): bool, shape
    ``(n, n_joints, 3)`` like ``sequence.angles_deg``, True for a degree of freedom the markers
    seen at that pose fix (:func:`observed_dofs`) but the fully seen ones alone do not
    (:func:`dofs_fixed_by`). A partly hidden marker's centroid shifts by up to a few mm
    (docs/hand-markers.md), so such an angle is less sure than the others (on the studio's other
    hands 3-15 deg off against about 1 deg; ``joint_angle_rms_partly_hidden_deg``).

    Parameters
    ----------
    sequence : HandSequence
    point_index : array_like of int, shape (n_flashes, n_markers)
        The labels' point per (flash, marker), -1 for none (``HandLabels.point_index``).
    partly_hidden : array_like of bool, shape (n_points,)
        Per point (``MarkerPoints.partly_hidden``).
    """
    pi = np.asarray(point_index)
    hidden = np.asarray(partly_hidden, bool)
    if pi.ndim != 2 or pi.shape[1] != sequence.residuals.shape[1]:
        raise ValueError(f"point_index must have shape (n_flashes, {sequence.residuals.shape[1]}), got {pi.shape}")
    if hidden.ndim != 1 or (pi.size and pi.max() >= len(hidden)):
        raise ValueError(f"partly_hidden must have one flag per point (at least {int(pi.max()) + 1}), "
                         f"got shape {hidden.shape}")
    out = np.zeros(np.shape(sequence.angles_deg), bool)
    for i, k in enumerate(sequence.flashes):
        p = pi[k]
        whole = np.isfinite(sequence.residuals[i]) & (p >= 0)
        whole[whole] = ~hidden[p[whole]]
        by_whole = {(q, ax) for q, ax, _ in dofs_fixed_by(sequence.skeleton, sequence.markerset, whole)}
        for q, ax in observed_dofs(sequence, i):
            out[i, q, ax] = (q, ax) not in by_whole
    return out
