"""Where the hand studio's held ball sits in the hand (issue 12, hand): seated by the hand's own
geometry, so that no glove marker and no part of the glove is inside the ball.

The ball used to sit at one fixed point of the hand frame (:data:`stillcap.studio.hand.BALL_IN_HAND`)
whatever the hand's size and finger angles. On 11 of 12 benchmark hands and on the seed's hand,
marker centres then lay inside the held ball (as deep as 14 mm from its centre, radius 36.85 mm)
and glove capsules up to 37 mm deep: such markers rendered as slivers or not at all, an artefact
of the studio rather than a hidden marker a real photo would show.

:func:`seat_ball` places the ball once per hand (a held ball does not slide in the grip, and the
release estimator, :func:`stillcap.ball.release.estimate_release`, rightly assumes so): the point
nearest to the nominal place scaled by the hand's size (:func:`nominal_ball_in_hand`) where, at
every held instant of the delivery, every marker centre stays at least ball radius + marker radius
plus :data:`GRIP_MARGIN_M` from the ball centre and every glove capsule (bones, palm, wrist) at
least ball radius + capsule radius. Where the nominal place already clears everything the ball stays
there; otherwise the ball ends up resting against the glove where it was pushed out. A small
constrained least-squares problem (three unknowns, one clearance per marker, capsule and instant),
solved with SciPy's SLSQP.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from stillcap.body.hand import hand_pose, hand_skeleton
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton

__all__ = ["BALL_IN_HAND", "GRIP_MARGIN_M", "GRIP_T", "grip_clearance", "held_ball_center", "nominal_ball_in_hand", "seat_ball"]

#: Nominal ball centre in the hand frame while held (m), seed's hand: in front of the palm, under the
#: fingers; each hand seats its ball from there (:func:`held_ball_center`).
BALL_IN_HAND = (0.118, 0.004, -0.052)
#: Extra clearance the seating keeps (m), so that poses between the sampled instants stay clear.
GRIP_MARGIN_M = 0.0005
#: Times relative to release (s) at which the seated ball must clear the glove: the held part of
#: the delivery (:class:`~stillcap.studio.hand.HandMotion`'s finger angles are constant before -60 ms).
GRIP_T = np.linspace(-0.060, 0.0, 61)
#: Caps on the smallest gap (mm) of :func:`seat_ball`'s searches for a clear place, one search each.
SEAT_CAPS_MM = (0.0, 1.0, 5.0)


#: Capsule radius of the bone ending at each joint (m); the palm and wrist are extra capsules.
_BONE_RADIUS = {"thumb-cmc": 0.014, "thumb-mcp": 0.011, "thumb-ip": 0.009, "thumb-tip": 0.0085,
                "mcp": 0.011, "pip": {"little": 0.0075, "ring": 0.008}, "dip": {"little": 0.0065, "ring": 0.007},
                "tip": {"little": 0.006, "ring": 0.0062}}
_FINGER_DEFAULT = {"pip": 0.0085, "dip": 0.0075, "tip": 0.0065}


def _bone_radius(name: str) -> float:
    if name in _BONE_RADIUS:
        return _BONE_RADIUS[name]
    digit, part = name.split("-")
    r = _BONE_RADIUS[part]
    return r if isinstance(r, float) else r.get(digit, _FINGER_DEFAULT[part])


def _hand_parts(skeleton: Skeleton) -> list[tuple]:
    """``(name, frame joint index, start (3,), end (3,), radius)`` of every hand capsule."""
    parts = []
    root = skeleton.root
    for i, j in enumerate(skeleton.joints):
        if j.parent is None:
            continue
        parts.append((j.name, int(skeleton.parents[i]), np.zeros(3), j.offset.copy(), _bone_radius(j.name)))
    off = {n: skeleton.offsets[skeleton.index(n)] for n in ("index-mcp", "little-mcp")}
    parts.append(("palm", root, off["index-mcp"] * [0.92, 1, 1], off["little-mcp"] * [0.92, 1, 1], 0.012))
    parts.append(("wrist", root, np.array([-0.01, 0.018, 0.0]), np.array([-0.01, -0.022, 0.0]), 0.012))
    return parts


def nominal_ball_in_hand(skeleton: Skeleton, nominal) -> np.ndarray:
    """``nominal`` (the seed hand's ball place, hand frame, m) scaled by the hand's size: the sum
    of its bone lengths over the seed hand's."""
    size = np.linalg.norm(skeleton.offsets, axis=1).sum() / np.linalg.norm(hand_skeleton().offsets, axis=1).sum()
    return float(size) * np.asarray(nominal, float)


def _glove(skeleton: Skeleton, markerset: MarkerSet, angles_deg) -> tuple:
    """Marker centres and radii, capsule ends and radii of one pose, in the hand frame."""
    pose = hand_pose(skeleton, np.eye(4), angles_deg)
    centers = markerset.positions(pose)
    radii = np.array([m.diameter / 2 for m in markerset.markers])
    j2w = pose.joint2world
    parts = _hand_parts(skeleton)
    a = np.array([j2w[f, :3, :3] @ s + j2w[f, :3, 3] for _, f, s, _, _ in parts])
    b = np.array([j2w[f, :3, :3] @ e + j2w[f, :3, 3] for _, f, _, e, _ in parts])
    r = np.array([p[4] for p in parts])
    return centers, radii, a, b, r


def _clearances(c: np.ndarray, glove: tuple, radius: float) -> tuple[np.ndarray, np.ndarray]:
    centers, radii, a, b, r = glove
    dm = np.linalg.norm(centers - c, axis=1) - radius - radii
    ab = b - a
    u = np.clip(np.einsum("ij,ij->i", c - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    dc = np.linalg.norm(c - (a + u[:, None] * ab), axis=1) - radius - r
    return dm, dc


def grip_clearance(skeleton: Skeleton, markerset: MarkerSet, angles_deg, center, radius: float) -> tuple:
    """Gaps between a ball (``center`` in the hand frame, ``radius``, m) and the glove in the pose
    ``angles_deg``: ``(markers (n_markers,), capsules (n_parts,))``, m, negative where inside."""
    return _clearances(np.asarray(center, float), _glove(skeleton, markerset, angles_deg), float(radius))


def seat_ball(skeleton: Skeleton, markerset: MarkerSet, angles_seq, radius: float, start) -> np.ndarray:
    """The ball's centre in the hand frame (m, (3,)) nearest to ``start`` that clears the glove in
    every pose of ``angles_seq`` (each ``(n_joints, 3)`` degrees) by :data:`GRIP_MARGIN_M` (module
    docstring). Raises ``ValueError`` when no such place is found."""
    gloves = [_glove(skeleton, markerset, a) for a in angles_seq]
    glove = tuple(np.concatenate([g[k] for g in gloves]) for k in range(5))  # every instant at once
    start = np.asarray(start, float)
    radius = float(radius)
    mm = 1e3  # solve in millimetres: SLSQP's tolerances are absolute

    def gaps(x):
        return np.concatenate(_clearances(x / mm, glove, radius)) * mm - GRIP_MARGIN_M * mm

    x0 = start * mm
    if gaps(x0).min() >= 0:
        return start.copy()
    # From inside the glove the nearest-point problem's linearisation is inconsistent (SLSQP stalls
    # at the start), so first find clear places (maximise the smallest gap, capped), then the
    # nearest clear place from each; keep the nearest. When no search from the start finds one,
    # the searches start again 20 mm away along each axis.
    opts = {"ftol": 1e-10, "maxiter": 300}
    for s0 in [x0] + [x0 + d * e for e in np.eye(3) for d in (20.0, -20.0)]:
        best = None
        for cap in SEAT_CAPS_MM:
            z0 = np.append(s0, gaps(s0).min())
            clear = minimize(lambda z: -z[3], z0, jac=lambda z: np.array([0.0, 0.0, 0.0, -1.0]), method="SLSQP",
                             constraints=[{"type": "ineq", "fun": lambda z: gaps(z[:3]) - z[3]},
                                          {"type": "ineq", "fun": lambda z, c=cap: c - z[3]}], options=opts).x[:3]
            res = minimize(lambda x: float(np.sum((x - x0) ** 2)), clear, jac=lambda x: 2 * (x - x0),
                           method="SLSQP", constraints=[{"type": "ineq", "fun": gaps}], options=opts)
            for x in (res.x, clear):
                if gaps(x).min() >= -1e-6 and (best is None or np.linalg.norm(x - x0) < np.linalg.norm(best - x0)):
                    best = x
        if best is not None:
            return best / mm
    raise ValueError(f"the held ball (radius {radius * 1e3:.2f} mm) cannot be seated clear of the glove "
                     f"near {np.round(start * 1e3, 1).tolist()} mm in the hand frame")


_SEATS: dict = {}  # seats already found (a few seconds each)


def held_ball_center(motion) -> np.ndarray:
    """:attr:`stillcap.studio.hand.HandMotion.ball_in_hand`: the ball seated (:func:`seat_ball`)
    for the motion's hand, glove markers and finger angles over :data:`GRIP_T`, from
    :data:`~stillcap.studio.hand.BALL_IN_HAND` scaled by the hand's size; cached on the motion
    until its angle offsets, markers or ball radius change."""
    from stillcap.ball.layout import BallLayout
    from stillcap.body.hand import hand_markerset
    ms = motion.markerset if motion.markerset is not None else hand_markerset()
    radius = float(BallLayout.seed().radius if motion.ball_radius is None else motion.ball_radius)
    offsets = None if motion.angle_offsets_deg is None else np.asarray(motion.angle_offsets_deg, float).tobytes()
    # the seat depends on the hand, its markers, its angle offsets and the ball, not on the release
    key = (motion.skeleton.offsets.tobytes(), ms.offsets.tobytes(), offsets, radius)
    if motion._seat is None or motion._seat[0] != key:
        if key not in _SEATS:
            angles = [motion.angles_deg(motion.release.t0 + s) for s in GRIP_T]
            _SEATS[key] = seat_ball(motion.skeleton, ms, angles, radius,
                                    nominal_ball_in_hand(motion.skeleton, BALL_IN_HAND))
            while len(_SEATS) > 64:
                _SEATS.pop(next(iter(_SEATS)))
        motion._seat = (key, _SEATS[key])
    return motion._seat[1].copy()
