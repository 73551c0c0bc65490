"""The hand model (SPEC J2, seed section 5): a right hand as data, its 18 glove markers in 4
colours, scaling to a person, and fitting the hand to measured markers.

Hand frame (``data/hand_skeleton.json``): **x distal** (along the fingers), **y radial**
(toward the thumb), **z dorsal** (out of the back of the hand), metres. The root joint
``wrist`` is the back of the hand (the carpus); its pose in the world is ``root2world``.
Digits: ``thumb-cmc, thumb-mcp, thumb-ip, thumb-tip`` and ``F-mcp, F-pip, F-dip, F-tip`` for
``F`` in index, middle, ring, little. A bone is named after the joint at its end (the bone
``index-pip`` is the proximal phalanx, moved by ``index-mcp``).

Degrees of freedom are the joint-limit axes that are not locked (intrinsic XYZ Euler angles:
X twist, Y flexion toward the palm, Z abduction toward the thumb): finger MCPs flex and
abduct, PIPs, DIPs, thumb MCP and IP are hinges (flexion only), the thumb CMC has all three;
21 in all (:func:`hand_dofs`).

Markers (``data/hand_markers.json``): 3 on the back of the hand (carried by the root), per
digit one over each of its two distal joints and one on the nail; 4 colours
(:data:`HAND_COLORS`), assigned so that same-colour markers are as far apart as possible
(:func:`same_color_min_distance`).

Fitting (:func:`fit_hand`) is a least-squares fit of the root pose and the 21 joint angles
(and, for :func:`personalise_hand`, six scale factors: palm and each digit) to measured
markers, started from a rigid alignment of the back-of-hand markers: the seed's procedure
(align the back of the hand, then choose each joint's rotation to bring the next marker to its
measurement) done for all joints at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Mapping

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.body.kinematics import _marker_array, rigid_alignment
from stillcap.body.markerset import Marker, MarkerSet
from stillcap.body.skeleton import Joint, Pose, Skeleton
from stillcap.files.jsonfile import read_package_json

__all__ = ["BACK_MARKERS", "DIGITS", "HAND_COLORS", "SCALE_GROUPS", "HandFit", "fit_hand", "fit_hand_poses", "hand_dofs",
           "hand_markerset", "hand_pose", "hand_skeleton", "marker_colors", "personalise_hand", "scale_groups",
           "scale_hand", "same_color_min_distance"]

#: Digits, thumb first.
DIGITS = ("thumb", "index", "middle", "ring", "little")
#: Scale groups of :func:`personalise_hand`: the palm (metacarpals of the fingers, the thumb's
#: CMC position, the back-of-hand markers) and each digit (its bones and markers).
SCALE_GROUPS = ("palm",) + DIGITS
#: The three back-of-hand markers (they fix the root's pose).
BACK_MARKERS = ("back.1", "back.2", "back.3")
#: The glove's marker colours: name -> HSB in [0, 1] (hue in turns); luminous, hues far apart.
HAND_COLORS = {"red": (0.0, 0.85, 1.0), "yellow": (0.15, 0.85, 1.0), "green": (0.38, 0.85, 1.0),
                "blue": (0.62, 0.85, 1.0)}


@lru_cache(maxsize=1)
def hand_skeleton() -> Skeleton:
    """The adult right hand (``data/hand_skeleton.json``), hand frame, metres, 21 joints."""
    data, source = read_package_json("hand_skeleton.json")
    return Skeleton.from_dict(data, source=source)


@lru_cache(maxsize=1)
def hand_markerset() -> MarkerSet:
    """The 18 glove markers (``data/hand_markers.json``) on :func:`hand_skeleton`."""
    data, source = read_package_json("hand_markers.json")
    return MarkerSet.from_dict(data, source=source)


def marker_colors(markerset: MarkerSet) -> list[str]:
    """The colour name (:data:`HAND_COLORS`) of each marker: the one with the nearest HSB
    (hue periodic)."""
    names = list(HAND_COLORS)
    ref = np.array([HAND_COLORS[n] for n in names])
    out = []
    for m in markerset.markers:
        d = np.abs(ref - np.array(m.hsb))
        d[:, 0] = np.minimum(d[:, 0], 1 - d[:, 0])
        out.append(names[int(np.argmin(np.linalg.norm(d, axis=1)))])
    return out


def same_color_min_distance(markerset: MarkerSet, pose: Pose | None = None, colors=None) -> float:
    """Smallest distance (m) between two markers of the same colour, in ``pose`` (default rest).

    ``colours`` (a colour name per marker) replaces the marker set's own colours, to compare
    assignments.
    """
    pose = pose or Pose.rest(hand_skeleton())
    pts = markerset.positions(pose)
    cols = np.asarray(marker_colors(markerset) if colors is None else list(colors))
    if len(cols) != len(pts):
        raise ValueError(f"colours must have {len(pts)} entries, got {len(cols)}")
    best = np.inf
    for c in np.unique(cols):
        idx = np.flatnonzero(cols == c)
        if len(idx) > 1:
            d = np.linalg.norm(pts[idx, None] - pts[None, idx], axis=-1)
            best = min(best, float(d[np.triu_indices(len(idx), 1)].min()))
    return best


def scale_groups(skeleton: Skeleton) -> list[str]:
    """Scale group of each joint's bone: ``palm`` for the root and the bones starting at it
    (metacarpals, the thumb's CMC position), else the digit named by the joint's prefix."""
    out = []
    for j in skeleton.joints:
        if j.parent is None or j.parent == skeleton.names[skeleton.root]:
            out.append("palm")
        else:
            digit = j.name.split("-")[0]
            if digit not in DIGITS:
                raise ValueError(f"joint {j.name!r} belongs to no digit (expected a prefix in {DIGITS})")
            out.append(digit)
    return out


def _scale_vector(scales) -> dict[str, float]:
    if np.isscalar(scales):
        s = float(scales)
        out = {g: s for g in SCALE_GROUPS}
    else:
        unknown = set(scales) - set(SCALE_GROUPS)
        if unknown:
            raise ValueError(f"unknown scale groups {sorted(unknown)}; groups: {list(SCALE_GROUPS)}")
        out = {g: float(scales.get(g, 1.0)) for g in SCALE_GROUPS}
    bad = {g: v for g, v in out.items() if not (np.isfinite(v) and v > 0)}
    if bad:
        raise ValueError(f"scale factors must be finite and > 0, got {bad}")
    return out


def scale_hand(skeleton: Skeleton, markerset: MarkerSet, scales) -> tuple[Skeleton, MarkerSet]:
    """A hand scaled to a person: bone lengths and marker offsets times a factor per group.

    Parameters
    ----------
    skeleton : Skeleton
        A hand skeleton (:func:`hand_skeleton`).
    markerset : MarkerSet
    scales : float or mapping group -> float
        One factor for everything or factors per :data:`SCALE_GROUPS` (missing groups: 1).
        A marker scales with its bone's group (so it stays on the scaled skin).

    Returns
    -------
    (Skeleton, MarkerSet)
    """
    s = _scale_vector(scales)
    groups = scale_groups(skeleton)
    joints = tuple(Joint(j.name, j.parent, j.offset * s[g], j.limits_deg) for j, g in zip(skeleton.joints, groups))
    sk = Skeleton(joints, name=skeleton.name, source=skeleton.source)
    mgroup = [groups[skeleton.index(m.bone)] for m in markerset.markers]
    markers = tuple(Marker(m.name, m.bone, m.offset * s[g], m.hsb, m.diameter) for m, g in zip(markerset.markers, mgroup))
    ms = MarkerSet(markers, markerset.rules, markerset.name, markerset.skeleton_name, markerset.source)
    return sk, ms


def hand_dofs(skeleton: Skeleton) -> list[tuple[int, int]]:
    """The hand's degrees of freedom: ``(joint index, axis)`` for every joint-limit axis that is
    not locked (axis 0, 1, 2 = the X, Y, Z intrinsic Euler angle)."""
    lim = skeleton.limits_deg
    out = []
    for i in range(skeleton.n_joints):
        for a in range(3):
            lo, hi = lim[i, a]
            if np.isnan(lo) or hi > lo:
                out.append((i, a))
    return out


def hand_pose(skeleton: Skeleton, root2world=None, angles_deg=None) -> Pose:
    """A hand pose from joint angles.

    Parameters
    ----------
    skeleton : Skeleton
    root2world : array_like, shape (4, 4), optional
        Default identity.
    angles_deg : mapping joint -> (3,) or array_like, shape (n_joints, 3), optional
        Intrinsic XYZ Euler angles (twist, flexion, abduction) in degrees; missing joints 0.

    Returns
    -------
    Pose
    """
    n = skeleton.n_joints
    ang = np.zeros((n, 3))
    if isinstance(angles_deg, Mapping):
        for k, v in angles_deg.items():
            ang[skeleton.index(k)] = as_array(v, (3,), f"angles of joint {k!r}")
    elif angles_deg is not None:
        ang = as_array(angles_deg, (n, 3), "angles_deg")
    r2w = np.eye(4) if root2world is None else root2world
    return Pose(skeleton, r2w, Rotation.from_euler("XYZ", ang, degrees=True).as_matrix())


# --------------------------------------------------------------------------------------------
# Fitting
# --------------------------------------------------------------------------------------------
@dataclass
class HandFit:
    """Result of :func:`fit_hand` / :func:`personalise_hand`.

    Attributes
    ----------
    pose : Pose
        The fitted pose (of :attr:`skeleton`).
    skeleton, markerset : Skeleton, MarkerSet
        The (scaled, for a personalisation) hand the pose belongs to.
    scales : dict
        Factor per :data:`SCALE_GROUPS` (all 1 unless scales were fitted).
    angles_deg : ndarray, shape (n_joints, 3)
        Fitted intrinsic XYZ Euler angles, degrees.
    residuals : ndarray, shape (n_markers,)
        Distance between fitted and measured markers, m; NaN for unseen markers.
    rms : float
        RMS of the residuals, m.
    n_markers : int
        Markers used.
    success : bool
        The optimiser converged and the RMS is below 5 mm.
    message : str
    """

    pose: Pose
    skeleton: Skeleton
    markerset: MarkerSet
    scales: dict
    angles_deg: np.ndarray
    residuals: np.ndarray
    rms: float
    n_markers: int
    success: bool
    message: str = ""


def _fk_markers(parents, order, offsets, moffsets, mframes, r2w, local):
    """Marker world positions for joint offsets (n, 3), marker offsets (m, 3), rotations (n, 3, 3)."""
    n = len(parents)
    R = np.empty((n, 3, 3))
    t = np.empty((n, 3))
    for i in order:
        p = parents[i]
        if p < 0:
            R[i] = r2w[:3, :3] @ local[i]
            t[i] = r2w[:3, 3]
        else:
            t[i] = R[p] @ offsets[i] + t[p]
            R[i] = R[p] @ local[i]
    return np.einsum("mij,mj->mi", R[mframes], moffsets) + t[mframes]


def _fit_setup(skeleton: Skeleton, markerset: MarkerSet):
    """What the hand fits need of the model: marker frames, DOFs, scale group per joint and per
    marker, offsets, hierarchy, limits (radians)."""
    gidx = np.array([SCALE_GROUPS.index(g) for g in scale_groups(skeleton)])
    mg = np.array([gidx[skeleton.index(m.bone)] for m in markerset.markers])
    return (markerset.bone_frames(skeleton), hand_dofs(skeleton), gidx, mg, skeleton.offsets, markerset.offsets,
            skeleton.parents, skeleton.depth_first, np.radians(skeleton.limits_deg))


def fit_hand(skeleton: Skeleton, markerset: MarkerSet, marker_positions, *, fit_scale: bool = False,
             initial: Pose | None = None, regularise: float = 1e-4, weights=None) -> HandFit:
    """Fit the hand's root pose and joint angles (and optionally its scale) to measured markers.

    Parameters
    ----------
    skeleton : Skeleton
        A hand (:func:`hand_skeleton`, possibly scaled).
    markerset : MarkerSet
    marker_positions : array_like, shape (n_markers, 3), or mapping name -> (3,)
        World positions, metres; NaN (or a missing name) for unseen markers. The back-of-hand
        markers (:data:`BACK_MARKERS`) must be seen (as in the seed), unless ``initial`` is
        given and 3+ markers are seen: the root then starts from ``initial``'s.
    fit_scale : bool
        Also fit a scale factor per :data:`SCALE_GROUPS` (see :func:`personalise_hand`).
    initial : Pose, optional
        Start for the joint angles (default: the rest pose); the root starts from the
        rigid alignment of the back-of-hand markers (from ``initial``'s root when one of them
        is unseen).
    regularise : float
        Weight (m per radian) pulling each angle toward its start, so that joints no seen
        marker constrains stay put.
    weights : array_like, shape (n_markers,), optional
        Relative weight of each marker's residual (default 1): e.g. the inverse of its position
        uncertainty relative to the others, so that a doubtful point bends the hand less.

    Returns
    -------
    HandFit
    """
    pts = _marker_array(markerset, marker_positions)
    seen = np.all(np.isfinite(pts), axis=1)
    w = np.ones(len(pts)) if weights is None else as_array(weights, (len(pts),), "weights")
    if not np.all(np.isfinite(w[seen]) & (w[seen] > 0)):
        raise ValueError("weights of the seen markers must be finite and > 0")
    back = [markerset.index(n) for n in BACK_MARKERS]
    if not seen[back].all() and (initial is None or seen.sum() < 3):
        raise ValueError(f"fitting a hand needs the back-of-hand markers {list(BACK_MARKERS)} seen (or an initial "
                         f"pose and 3+ markers), missing: {[BACK_MARKERS[k] for k in np.flatnonzero(~seen[back])]}")
    frames, dofs, gidx, mg, offsets, moffsets, parents, order, lim = _fit_setup(skeleton, markerset)

    ang0 = np.zeros((skeleton.n_joints, 3))
    if initial is not None:
        ang0 = np.radians(skeleton.limit_angles_deg(initial.local_rotations))
    a0 = np.array([ang0[i, a] for i, a in dofs])
    lo = np.array([lim[i, a, 0] if np.isfinite(lim[i, a, 0]) else -np.pi for i, a in dofs])
    hi = np.array([lim[i, a, 1] if np.isfinite(lim[i, a, 1]) else np.pi for i, a in dofs])
    a0 = np.clip(a0, lo, hi)

    # root from the back of the hand (scale-free start: the rotation is right, the translation nearly)
    if seen[back].all():
        fit0 = rigid_alignment(moffsets[back], pts[back])  # the back markers ride on the root frame
        rv0, t0 = fit0.rotation.as_rotvec(), fit0.translation
    else:  # a flash posed from its other markers (body.hand_label_fill): the root starts from the initial pose
        rv0, t0 = Rotation.from_matrix(initial.root2world[:3, :3]).as_rotvec(), initial.root2world[:3, 3]
    n_s = len(SCALE_GROUPS) if fit_scale else 0
    x0 = np.concatenate([rv0, t0, a0, np.zeros(n_s)])

    nd = len(dofs)
    dof_j = np.array([i for i, _ in dofs])
    dof_a = np.array([a for _, a in dofs])

    def unpack(x):
        r2w = np.eye(4)
        r2w[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
        r2w[:3, 3] = x[3:6]
        ang = np.zeros((skeleton.n_joints, 3))
        ang[dof_j, dof_a] = x[6:6 + nd]
        s = np.exp(x[6 + nd:]) if fit_scale else np.ones(len(SCALE_GROUPS))
        return r2w, ang, s

    def residuals(X):
        """Residuals of every row of ``X`` (P, n_params) at once: the forward kinematics loops
        over the joints once for all rows (a Jacobian by differences is one call, not 30)."""
        P = len(X)
        R0 = Rotation.from_rotvec(X[:, :3]).as_matrix()
        ang = np.zeros((P, skeleton.n_joints, 3))
        ang[:, dof_j, dof_a] = X[:, 6:6 + nd]
        local = Rotation.from_euler("XYZ", ang.reshape(-1, 3)).as_matrix().reshape(P, skeleton.n_joints, 3, 3)
        s = np.exp(X[:, 6 + nd:]) if fit_scale else np.ones((P, len(SCALE_GROUPS)))
        joff = offsets[None] * s[:, gidx, None]
        moff = moffsets[None] * s[:, mg, None]
        Rj = np.empty((P, skeleton.n_joints, 3, 3))
        tj = np.empty((P, skeleton.n_joints, 3))
        for i in order:
            q = parents[i]
            if q < 0:
                Rj[:, i] = np.einsum("pab,pbc->pac", R0, local[:, i])
                tj[:, i] = X[:, 3:6]
            else:
                tj[:, i] = np.einsum("pab,pb->pa", Rj[:, q], joff[:, i]) + tj[:, q]
                Rj[:, i] = np.einsum("pab,pbc->pac", Rj[:, q], local[:, i])
        m = np.einsum("pmab,pmb->pma", Rj[:, frames], moff) + tj[:, frames]
        res = ((m - pts[None]) * w[None, :, None])[:, seen].reshape(P, -1)
        return np.concatenate([res, regularise * (X[:, 6:6 + nd] - a0[None])], axis=1)

    def residual(x):
        return residuals(x[None])[0]

    def jacobian(x):
        # forward differences with SciPy's '2-point' step, stepping inward at a bound
        h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(x))
        h = np.where(x + h > ub, -h, h)
        F = residuals(np.vstack([x[None], x[None] + np.diag(h)]))
        return ((F[1:] - F[0]) / h[:, None]).T

    lb = np.concatenate([np.full(6, -np.inf), lo, np.full(n_s, np.log(0.5))])
    ub = np.concatenate([np.full(6, np.inf), hi, np.full(n_s, np.log(2.0))])
    x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
    sol = least_squares(residual, x0, jac=jacobian, bounds=(lb, ub), x_scale="jac", xtol=1e-12, ftol=1e-12,
                        gtol=1e-12, max_nfev=400)
    r2w, ang, s = unpack(sol.x)
    scales = dict(zip(SCALE_GROUPS, (float(v) for v in s)))
    sk, ms = scale_hand(skeleton, markerset, scales) if fit_scale else (skeleton, markerset)
    pose = Pose(sk, r2w, Rotation.from_euler("XYZ", ang).as_matrix())
    d = np.linalg.norm(ms.positions(pose) - pts, axis=1)
    d[~seen] = np.nan
    rms = float(np.sqrt(np.nanmean(d ** 2)))
    ok = bool(sol.success) and rms < 0.005
    return HandFit(pose, sk, ms, scales, np.degrees(ang), d, rms, int(seen.sum()), ok, str(sol.message))


def personalise_hand(skeleton: Skeleton, markerset: MarkerSet, marker_positions, **kw) -> HandFit:
    """Scale the hand model to a person from measured markers (any pose, all 18 seen best).

    Fits the pose together with a scale factor per :data:`SCALE_GROUPS` (palm and each digit):
    the marker distances fix the bone lengths. The result's ``skeleton`` and ``markerset`` are
    the personalised hand (:func:`scale_hand` with ``scales``); ``pose`` is the fitted pose of it.
    Keyword arguments go to :func:`fit_hand`.
    """
    return fit_hand(skeleton, markerset, marker_positions, fit_scale=True, **kw)


def fit_hand_poses(skeleton: Skeleton, markerset: MarkerSet, marker_positions, *, fit_scale: bool = True,
                   initial=None, regularise: float = 1e-4) -> tuple[dict, list[HandFit]]:
    """Fit several poses of one hand at once, sharing its scale factors (a joint personalisation).

    Every pose has its own root pose and joint angles (as :func:`fit_hand`); with ``fit_scale``
    one factor per :data:`SCALE_GROUPS` is shared by all poses, so markers seen in any flash
    fix the bone lengths. One least-squares problem over all poses, started from each pose's
    own :func:`fit_hand`.

    Parameters
    ----------
    skeleton, markerset
    marker_positions : array_like, shape (n_poses, n_markers, 3)
        NaN for unseen markers; every pose needs its back-of-hand markers.
    fit_scale : bool
    initial : sequence of Pose or None, optional
        Start per pose (default: each pose's own :func:`fit_hand` on the unscaled hand).
    regularise : float
        As :func:`fit_hand`.

    Returns
    -------
    scales : dict
    fits : list of HandFit
        One per pose, on the scaled hand.
    """
    pts_all = as_array(marker_positions, (None, len(markerset), 3), "marker_positions")
    n = len(pts_all)
    if n == 0:
        raise ValueError("fit_hand_poses needs at least one pose, got 0")
    initial = [None] * n if initial is None else list(initial)
    if len(initial) != n:
        raise ValueError(f"initial must have {n} entries (one per pose), got {len(initial)}")
    starts = [fit_hand(skeleton, markerset, p, initial=i, regularise=regularise) for p, i in zip(pts_all, initial)]
    if not fit_scale:
        return {g: 1.0 for g in SCALE_GROUPS}, starts
    frames, dofs, gidx, mg, offsets, moffsets, parents, order, lim = _fit_setup(skeleton, markerset)
    nd = len(dofs)
    lo = np.array([lim[i, a, 0] if np.isfinite(lim[i, a, 0]) else -np.pi for i, a in dofs])
    hi = np.array([lim[i, a, 1] if np.isfinite(lim[i, a, 1]) else np.pi for i, a in dofs])
    seen = np.all(np.isfinite(pts_all), axis=2)
    npp = 6 + nd
    ns = len(SCALE_GROUPS)
    x0, a0s = [], []
    for f in starts:
        ang = np.radians(skeleton.limit_angles_deg(f.pose.local_rotations))
        a = np.clip([ang[i, ax] for i, ax in dofs], lo, hi)
        a0s.append(a)
        x0.append(np.concatenate([Rotation.from_matrix(f.pose.root2world[:3, :3]).as_rotvec(),
                                  f.pose.root2world[:3, 3], a]))
    x0 = np.concatenate(x0 + [np.zeros(ns)])

    def unpack(xp):
        r2w = np.eye(4)
        r2w[:3, :3] = Rotation.from_rotvec(xp[:3]).as_matrix()
        r2w[:3, 3] = xp[3:6]
        ang = np.zeros((skeleton.n_joints, 3))
        for (i, a), v in zip(dofs, xp[6:]):
            ang[i, a] = v
        return r2w, ang

    def residual(x):
        s = np.exp(x[n * npp:])
        out = []
        for k in range(n):
            r2w, ang = unpack(x[k * npp:(k + 1) * npp])
            local = Rotation.from_euler("XYZ", ang).as_matrix()
            p = _fk_markers(parents, order, offsets * s[gidx][:, None], moffsets * s[mg][:, None], frames, r2w, local)
            out.append((p - pts_all[k])[seen[k]].ravel())
            out.append(regularise * (x[k * npp + 6:(k + 1) * npp] - a0s[k]))
        return np.concatenate(out)

    lb = np.concatenate([np.concatenate([np.full(6, -np.inf), lo]) for _ in range(n)] + [np.full(ns, np.log(0.5))])
    ub = np.concatenate([np.concatenate([np.full(6, np.inf), hi]) for _ in range(n)] + [np.full(ns, np.log(2.0))])
    x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
    # dense finite differences: ~30 parameters per pose plus 6 scales stay cheap, and the dense
    # trust-region solver converges in far fewer steps than the sparse (lsmr) one
    sol = least_squares(residual, x0, bounds=(lb, ub), x_scale="jac", xtol=1e-10, ftol=1e-10, gtol=1e-10,
                        max_nfev=200)
    s = np.exp(sol.x[n * npp:])
    scales = dict(zip(SCALE_GROUPS, (float(v) for v in s)))
    sk, ms = scale_hand(skeleton, markerset, scales)
    fits = []
    for k in range(n):
        r2w, ang = unpack(sol.x[k * npp:(k + 1) * npp])
        pose = Pose(sk, r2w, Rotation.from_euler("XYZ", ang).as_matrix())
        d = np.linalg.norm(ms.positions(pose) - pts_all[k], axis=1)
        d[~seen[k]] = np.nan
        rms = float(np.sqrt(np.nanmean(d ** 2)))
        fits.append(HandFit(pose, sk, ms, scales, np.degrees(ang), d, rms, int(seen[k].sum()),
                            bool(sol.success) and rms < 0.005, str(sol.message)))
    return scales, fits
