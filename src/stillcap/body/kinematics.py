"""From markers to poses: bone directions (the thesis's rules), rotations between directions,
rigid alignment (Kabsch) and posing a skeleton from measured bone directions.

All vectors are world vectors (metres or unit directions); rotations are
``scipy.spatial.transform.Rotation``. SciPy's ``Rotation.align_vectors`` does the work for both
the minimal rotation between two directions and the Kabsch / Wahba rigid alignment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Pose, Skeleton

__all__ = [
    "normalised",
    "bone_directions",
    "rotation_between",
    "align_matrix",
    "RigidAlignment",
    "rigid_alignment",
    "pose_from_bone_directions",
    "pose_from_markers",
    "pose_and_directions",
]


def normalised(v) -> np.ndarray:
    """Unit vectors along the last axis, shape as given; NaN for zero or NaN input."""
    v = np.asarray(v, float)
    if v.shape == (3,):
        # one vector (the pose's bone directions: ~90 calls per capture): its length in Python
        # floats, summed in np.linalg.norm's order, so the same numbers in ~1/5 of the time
        x, y, z = v.tolist()
        n1 = math.sqrt((x * x + y * y) + z * z)
        if 1e-12 < n1 < math.inf:  # a finite length: nothing to silence (np.errstate costs ~3 us)
            return v / n1
        with np.errstate(invalid="ignore"):
            return v / n1 if n1 > 1e-12 else np.full(3, np.nan)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 1e-12, v / n, np.nan)


def _marker_array(markerset: MarkerSet, marker_positions) -> np.ndarray:
    """Marker positions in markerset order, shape (n_markers, 3); NaN for missing names."""
    if isinstance(marker_positions, Mapping):
        out = np.full((len(markerset), 3), np.nan)
        for name, p in marker_positions.items():
            out[markerset.index(name)] = as_array(p, (3,), f"position of marker {name!r}")
        return out
    return as_array(marker_positions, (len(markerset), 3), "marker_positions")


def bone_directions(markerset: MarkerSet, marker_positions, root2world=None) -> dict[str, np.ndarray]:
    """Bone directions in the world from measured markers, by the marker set's rules.

    Parameters
    ----------
    markerset : MarkerSet
    marker_positions : array_like, shape (n_markers, 3), or mapping name -> (3,)
        World positions, metres; NaN (or a missing name) for unseen markers.
    root2world : array_like, shape (4, 4), optional
        Orientation of the root frame, in which the ``axis`` of ``cross`` rules is given
        (the puppet frame's x or z axis); identity by default.

    Returns
    -------
    dict
        Bone name -> unit direction, shape (3,); all NaN where the markers it needs are unseen.
    """
    pts = _marker_array(markerset, marker_positions)
    rot = np.eye(3) if root2world is None else as_array(root2world, (4, 4), "root2world")[:3, :3]
    out: dict[str, np.ndarray] = {}
    for r in markerset.rules:
        if r.kind == "markers":
            d = normalised(pts[markerset.index(r.end)] - pts[markerset.index(r.start)])
        elif r.kind == "copy":
            d = out[r.copy].copy()
        else:
            d = normalised(np.cross(out[r.cross], rot @ np.asarray(r.axis)))
        out[r.bone] = d
    return out


def rotation_between(rest_direction, direction) -> Rotation:
    """The smallest rotation taking ``rest_direction`` onto ``direction``.

    Parameters
    ----------
    rest_direction, direction : array_like, shape (3,)
        Non-zero vectors (need not be unit).

    Returns
    -------
    Rotation
        ``R`` with ``R.apply(rest_direction)`` parallel to ``direction``.
    """
    a = as_array(direction, (3,), "direction")
    b = as_array(rest_direction, (3,), "rest_direction")
    if not (np.linalg.norm(a) > 1e-12 and np.linalg.norm(b) > 1e-12) or not np.isfinite(a + b).all():
        raise ValueError(f"directions must be finite and non-zero, got {b.tolist()} and {a.tolist()}")
    rot, _ = Rotation.align_vectors(a[None], b[None])
    return rot


@dataclass(frozen=True)
class RigidAlignment:
    """Result of :func:`rigid_alignment`: ``measured ~ rotation.apply(model) + translation``.

    Attributes
    ----------
    rotation : Rotation
    translation : ndarray, shape (3,), metres
    rmsd : float
        Root-mean-square distance between aligned model and measured points, metres.
    n_points : int
        Number of (finite) point pairs used.
    """

    rotation: Rotation
    translation: np.ndarray
    rmsd: float
    n_points: int

    @property
    def model2world(self) -> np.ndarray:
        """The alignment as a 4x4 transform, shape (4, 4)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation.as_matrix()
        m[:3, 3] = self.translation
        return m


def rigid_alignment(model_points, measured_points, weights=None) -> RigidAlignment:
    """Least-squares rotation and translation from model points to measured points (Kabsch).

    Parameters
    ----------
    model_points : array_like, shape (N, 3)
        Points in the model (segment) frame, metres.
    measured_points : array_like, shape (N, 3)
        The same points measured in the world, metres; rows with NaN are ignored.
    weights : array_like, shape (N,), optional

    Returns
    -------
    RigidAlignment

    Raises
    ------
    ValueError
        With fewer than 3 finite pairs, or when the points are (nearly) collinear, so the
        rotation about their line (the twist) is undetermined.
    """
    model = as_array(model_points, (None, 3), "model_points")
    meas = as_array(measured_points, (model.shape[0], 3), "measured_points")
    w = np.ones(len(model)) if weights is None else as_array(weights, (len(model),), "weights")
    ok = np.isfinite(model).all(axis=1) & np.isfinite(meas).all(axis=1) & np.isfinite(w) & (w > 0)
    if ok.sum() < 3:
        raise ValueError(f"rigid alignment needs 3+ finite point pairs, got {int(ok.sum())}")
    model, meas, w = model[ok], meas[ok], w[ok]
    cm = np.average(model, axis=0, weights=w)
    cx = np.average(meas, axis=0, weights=w)
    s = np.linalg.svd(model - cm, compute_uv=False)
    if s[1] <= 1e-6 * max(s[0], 1e-12) or s[0] < 1e-12:
        raise ValueError("rigid alignment needs 3+ points that are not collinear (twist is undetermined)")
    rot, _ = Rotation.align_vectors(meas - cx, model - cm, weights=w)
    t = cx - rot.apply(cm)
    rmsd = float(np.sqrt(np.average(np.sum((rot.apply(model) + t - meas) ** 2, axis=1), weights=w)))
    return RigidAlignment(rot, t, rmsd, int(ok.sum()))


def align_matrix(a, b, weights=None) -> np.ndarray:
    """``Rotation.align_vectors(a, b, weights)[0].as_matrix()``: the rotation matrix ``R`` that best
    maps the rows of ``b`` onto those of ``a`` (weighted least squares; the minimal rotation for
    one pair), shape (3, 3).

    Hand-written for the two common cases, as SciPy's call costs ~55 us against ~15 us here and
    the puppet's start and thesis pose make ~24 of them per capture: two or more finite-weight
    pairs not in one line (Kabsch: the SVD of ``sum w a b^T``, its sign fixed), and one pair not
    opposed (Rodrigues). Every other case (an infinite weight, pairs in one line, opposed
    directions, non-finite input) goes to SciPy. The matrices agree with SciPy's to ~1e-15 (it
    goes through a quaternion), measured on 2000 random sets each.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    w = None if weights is None else np.asarray(weights, float)
    if a.shape == b.shape and a.ndim == 2 and a.shape[1] == 3 and np.isfinite(a).all() and np.isfinite(b).all():
        if len(a) == 1:
            na, nb = math.sqrt(float(a[0] @ a[0])), math.sqrt(float(b[0] @ b[0]))
            if na > 1e-12 and nb > 1e-12 and (w is None or (w.shape == (1,) and np.isfinite(w[0]) and w[0] > 0)):
                x, y = b[0] / nb, a[0] / na
                c = float(x @ y)
                if c > -0.9:  # opposed directions: the axis is ill-defined, SciPy's own handling
                    v0, v1, v2 = x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]
                    K = np.array([[0.0, -v2, v1], [v2, 0.0, -v0], [-v1, v0, 0.0]])
                    return np.eye(3) + K + (K @ K) / (1.0 + c)
        elif len(a) >= 2 and (w is None or (w.shape == (len(a),) and np.isfinite(w).all() and (w >= 0).all())):
            u, s, vt = np.linalg.svd((a if w is None else a * w[:, None]).T @ b)
            if s[1] > 1e-6 * s[0]:  # else the pairs lie in one line: the turn about it is free
                if np.linalg.det(u @ vt) < 0:
                    u[:, -1] = -u[:, -1]
                return u @ vt
    return Rotation.align_vectors(a, b, weights=w)[0].as_matrix()


def _solve_local(a_world: np.ndarray, parent_rot: np.ndarray, rest_vectors: list, weights: list) -> np.ndarray:
    """Local rotation R with parent_rot @ R @ rest_i ~ a_world_i (weighted; one weight may be inf)."""
    a_local = a_world @ parent_rot  # rows: parent_rot.T @ a_i
    b = normalised(np.array(rest_vectors))
    return align_matrix(a_local, b, np.array(weights, float))


def pose_from_bone_directions(
    skeleton: Skeleton,
    directions: Mapping[str, np.ndarray],
    root2world=None,
    weights: Mapping[str, float] | None = None,
    initial: Pose | None = None,
    world_rotations: Mapping[str, np.ndarray] | None = None,
) -> Pose:
    """Pose a skeleton so that its bones point along measured directions.

    Walks the hierarchy from the root. A joint's local rotation is chosen so that the bones
    starting at it (its children's bones) point along their measured directions: the minimal
    rotation for one bone, a weighted least-squares fit (``Rotation.align_vectors``) for several
    (a weight of ``math.inf`` on one bone matches it exactly and fits the rest about it). Bone
    lengths stay the skeleton's, as in the thesis (bone vector = length x direction).

    Parameters
    ----------
    skeleton : Skeleton
    directions : mapping bone name -> array_like, shape (3,)
        World directions; entries with NaN are ignored.
    root2world : array_like, shape (4, 4), optional
        The root's frame; default the skeleton's rest root frame.
    weights : mapping bone name -> float, optional
        Weight of each bone's direction (default 1).
    initial : Pose, optional
        Local rotations for joints with no measured child bone (default identity).
    world_rotations : mapping joint name -> array_like, shape (3, 3), optional
        Measured world orientations of joint frames (e.g. from :func:`rigid_alignment`);
        they override the directions for those joints.

    Returns
    -------
    Pose
    """
    r2w = skeleton.rest_root2world() if root2world is None else as_array(root2world, (4, 4), "root2world")
    n = skeleton.n_joints
    local = np.tile(np.eye(3), (n, 1, 1)) if initial is None else initial.local_rotations.copy()
    weights = weights or {}
    for name in directions:
        skeleton.index(name)  # ValueError for an unknown bone
    fixed = {skeleton.index(k): as_array(v, (3, 3), f"world rotation of {k!r}") for k, v in (world_rotations or {}).items()}
    world = np.zeros((n, 3, 3))
    parents = skeleton.parents
    for p in skeleton.depth_first:
        parent_rot = r2w[:3, :3] if parents[p] < 0 else world[parents[p]]
        if p in fixed:
            local[p] = parent_rot.T @ fixed[p]
            world[p] = fixed[p]
            continue
        a, b, w = [], [], []
        for c in skeleton.children(p):
            name = skeleton.names[c]
            d = directions.get(name)
            if d is None:
                continue
            d = as_array(d, (3,), f"direction of bone {name!r}")
            if not np.isfinite(d).all() or np.linalg.norm(skeleton.offsets[c]) < 1e-12:
                continue
            a.append(normalised(d))
            b.append(skeleton.offsets[c])
            w.append(float(weights.get(name, 1.0)))
        if a:
            if sum(math.isinf(x) for x in w) > 1:
                raise ValueError(f"at most one bone per joint may have an infinite weight (joint {skeleton.names[p]!r})")
            local[p] = _solve_local(np.array(a), parent_rot, b, w)
        world[p] = parent_rot @ local[p]
    return Pose(skeleton, r2w, local)


def pose_from_markers(
    skeleton: Skeleton,
    markerset: MarkerSet,
    marker_positions,
    root2world=None,
    initial: Pose | None = None,
) -> Pose:
    """Pose a skeleton from measured markers.

    Joints whose frame carries 3 or more seen, non-collinear markers get their world
    orientation by rigid alignment (full orientation, twist included); all other joints follow
    the marker set's bone-direction rules (:func:`bone_directions`, the thesis's method), with
    rules marked ``primary`` matched exactly.

    Parameters
    ----------
    skeleton : Skeleton
    markerset : MarkerSet
    marker_positions : array_like, shape (n_markers, 3), or mapping name -> (3,)
        World positions, metres; NaN for unseen.
    root2world : array_like, shape (4, 4), optional
        The root's frame (for the puppet: pelvis fixed on the turntable axis); default rest.
    initial : Pose, optional
        Local rotations for joints nothing constrains (default identity).

    Returns
    -------
    Pose
    """
    return pose_and_directions(skeleton, markerset, marker_positions, root2world, initial)[0]


def pose_and_directions(skeleton: Skeleton, markerset: MarkerSet, marker_positions, root2world=None,
                         initial: Pose | None = None) -> tuple[Pose, dict[str, np.ndarray]]:
    """:func:`pose_from_markers` and the :func:`bone_directions` it posed from, as a pair
    ``(pose, directions)`` (the puppet's pose fit keeps both: one computation of the directions)."""
    r2w = skeleton.rest_root2world() if root2world is None else as_array(root2world, (4, 4), "root2world")
    pts = _marker_array(markerset, marker_positions)
    dirs = bone_directions(markerset, pts, r2w)
    weights = {r.bone: (math.inf if r.primary else 1.0) for r in markerset.rules}
    frames = markerset.bone_frames(skeleton)
    rigid = {}
    for j in np.unique(frames):
        sel = np.flatnonzero(frames == j)
        if np.sum(np.isfinite(pts[sel]).all(axis=1)) >= 3:
            try:
                fit = rigid_alignment(markerset.offsets[sel], pts[sel])
            except ValueError:
                continue  # collinear markers: the direction rules pose this joint
            rigid[skeleton.names[j]] = fit.rotation.as_matrix()
    return pose_from_bone_directions(skeleton, dirs, r2w, weights, initial, world_rotations=rigid), dirs
