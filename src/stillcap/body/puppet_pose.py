"""Puppet pose from 3D markers (SPEC J3): what the markers measure of each joint, and the joint
rotations that put the marker set's beads on them. A stage of :mod:`stillcap.pipelines.puppet`.

:func:`fit_pose` fits every free joint's intrinsic XYZ Euler angles (the limits' own
parameters, so the limits are hard bounds) to the 3D markers by least squares with an analytic
Jacobian. A joint frame that carries two beads not in line with the joint has three points
(its markers and the joint itself): its full orientation, twist included, is measured
(:func:`frame_status`). Where the markers leave a rotation open (with the thesis's 16 beads,
``puppet-16``, forearms and shins carry one bead each: the rotation about the elbow-to-bead
line; ``puppet-20`` adds a second bead there, so they are fully measured; hands and feet carry
none) a weak prior
pulls each Euler angle toward 0 (clipped into its limits) with a standard deviation of half its
range, so near-hinge joints stay near their hinge. The thesis's bone-direction pose
(:func:`stillcap.body.kinematics.pose_from_markers`) is kept beside it. A marker seen in one
view only (no 3D point) still counts: its ray (:class:`MarkerRays`) keeps the model bead near
it, which settles a forearm's twist when its other bead is triangulated.

Metres and degrees; see ``docs/puppet.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from stillcap._blas import single_blas_thread
from stillcap.body.kinematics import align_matrix, normalised, pose_and_directions
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import EULER_LIMIT_SEQUENCE, Pose, Skeleton, euler_within_limits, forward_kinematics

__all__ = ["MarkerRays", "PoseFit", "fit_pose", "frame_status", "root_freedom"]


def frame_status(skeleton: Skeleton, markerset: MarkerSet, recovered=None) -> dict[str, str]:
    """What the markers measure of each joint's frame (its local rotation); with ``recovered``
    (bool, shape (n_markers,)) what those markers alone measure (a capture's beads seen in two
    views or more).

    ``"full"``: the frame carries 2+ markers not in one line with the joint (or 3+ markers), so
    its whole orientation, twist included, follows from them; ``"partial"``: one marker (or
    markers in line with the joint): a rotation about that line stays open; ``"none"``: no
    marker; ``"locked"``: the joint cannot rotate (all limits ``[0, 0]``).
    """
    frames = markerset.bone_frames(skeleton)
    if recovered is not None:
        recovered = np.asarray(recovered, bool)
        if recovered.shape != frames.shape:
            raise ValueError(f"recovered must have shape {frames.shape}, got {recovered.shape}")
        frames = np.where(recovered, frames, -1)
    lim = skeleton.limits_deg
    n = skeleton.n_joints
    locked = np.all(lim[:, :, 0] == lim[:, :, 1], axis=1)
    on = frames >= 0
    f, offs = frames[on], markerset.offsets.reshape(-1, 3)[on]  # (0, 3) for a marker set without beads
    counts = np.bincount(f, minlength=n)
    # every frame's cloud (its markers' offsets and the joint, the origin) centred on its own
    # mean, as the rows of one zero-padded (n_joints, rows, 3) array: zero rows leave a matrix's
    # singular values as they are, so one batched SVD gives every frame's (a loop of one SVD
    # per joint cost ~0.22 ms per call, three calls per capture; this ~0.06 ms)
    mean = np.stack([np.bincount(f, offs[:, i], minlength=n) for i in range(3)], axis=1) / (counts + 1)[:, None]
    order = np.argsort(f, kind="stable")
    fo = f[order]
    cloud = np.zeros((n, max(int(counts.max(initial=0)), 1) + 1, 3))  # two rows at least: s[:, 1] exists
    cloud[fo, np.arange(len(fo)) - np.searchsorted(fo, fo)] = offs[order] - mean[fo]
    cloud[np.arange(n), counts] = -mean
    s = np.linalg.svd(cloud, compute_uv=False)
    full = (counts >= 2) & (s[:, 1] > 1e-3 * np.maximum(s[:, 0], 1e-12))
    return {name: "locked" if locked[j] else "none" if counts[j] == 0 else "full" if full[j] else "partial"
            for j, name in enumerate(skeleton.names)}


@dataclass(eq=False)
class MarkerRays:
    """Single-view observations of markers: each a ray from a camera centre through the
    bead's pixel, in world coordinates, for :func:`fit_pose`.

    A bead seen in one view only has no 3D point, but it lies on its ray: the ray fixes two of
    its three coordinates (to a pixel's accuracy times its depth), which is enough to settle a
    forearm's twist when its other bead is triangulated.

    Attributes
    ----------
    marker : ndarray of int, shape (n_rays,)
        Marker-set index of each ray's bead.
    origin : ndarray, shape (n_rays, 3)
        Camera centres, metres, world.
    direction : ndarray, shape (n_rays, 3)
        Unit directions through the pixels, world.
    focal_px : ndarray, shape (n_rays,)
        Focal length of each ray's camera, pixels (mean of fx and fy): a pixel at depth ``z`` is
        ``z / focal_px`` metres.
    view : ndarray of int, shape (n_rays,)
        The view each ray comes from (-1 if unknown).
    sigma_px : ndarray, shape (n_rays,)
        Expected error of each ray's pixel, pixels; NaN: :func:`fit_pose`'s ``ray_sigma_px``.
    """

    marker: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    focal_px: np.ndarray
    view: np.ndarray | None = None
    sigma_px: np.ndarray | None = None

    def __post_init__(self):
        self.marker = np.asarray(self.marker, int).reshape(-1)
        k = len(self.marker)
        self.origin = np.asarray(self.origin, float).reshape(-1, 3) if k else np.zeros((0, 3))
        self.direction = np.asarray(self.direction, float).reshape(-1, 3) if k else np.zeros((0, 3))
        self.focal_px = np.broadcast_to(np.asarray(self.focal_px, float), (k,)).copy()
        self.view = np.full(k, -1) if self.view is None else np.asarray(self.view, int).reshape(-1)
        self.sigma_px = (np.full(k, np.nan) if self.sigma_px is None
                         else np.broadcast_to(np.asarray(self.sigma_px, float), (k,)).copy())
        for name, a, shape in (("origin", self.origin, (k, 3)), ("direction", self.direction, (k, 3)),
                               ("view", self.view, (k,))):
            if a.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
        n = np.linalg.norm(self.direction, axis=1)
        if k and not np.all(np.isfinite(n) & (n > 0)):
            raise ValueError("every ray direction must be finite and non-zero")
        self.direction = self.direction / n[:, None] if k else self.direction

    def __len__(self) -> int:
        return len(self.marker)

    @classmethod
    def from_views(cls, rig, observations, markers=None, fill=None, sigma_px: float = 1.0,
                   fill_slope_px: float = 6.5) -> MarkerRays:
        """The rays of identified pixels.

        A partly hidden bead's detected centre lies off its true centre, toward its visible part,
        by more the less of it shows. With ``fill`` (:func:`stillcap.detect.beads.bead_fill`, as in
        :attr:`MarkerSolve.fill <stillcap.pipelines.puppet.MarkerSolve>`) each ray's
        ``sigma_px = max(sigma_px, fill_slope_px * (0.8 - fill))``: on the 52 ``puppet-20``
        benchmark poses (beads ~6.3 px in radius) the centre error was 3.5 px RMS at fill < 0.3,
        2.6 px at 0.3-0.5, 1.3 px at 0.5-0.7 and 0.2-0.3 px above 0.7.

        Parameters
        ----------
        rig : Rig or sequence of Camera, n_views cameras
        observations : array_like, shape (n_views, n_markers, 2)
            Distorted pixels, NaN where a view did not identify a marker.
        markers : array_like of bool, shape (n_markers,), or of int, optional
            The markers to make rays of (e.g. those without a 3D point); default all.
        fill : array_like, shape (n_views, n_markers), optional
            Fill of every observation (NaN: unknown, ``sigma_px``).
        sigma_px : float
            Error of a whole bead's centre, pixels (the floor).
        fill_slope_px : float
            Growth of the error as the fill drops, pixels per unit fill.
        """
        cams = list(rig)
        x = np.asarray(observations, float)
        if x.ndim != 3 or x.shape[0] != len(cams) or x.shape[2] != 2:
            raise ValueError(f"observations must have shape ({len(cams)}, n_markers, 2), got {x.shape}")
        pick = np.ones(x.shape[1], bool)
        if markers is not None:
            m = np.asarray(markers)
            pick = np.zeros(x.shape[1], bool)
            if m.dtype == bool:
                if m.shape != (x.shape[1],):
                    raise ValueError(f"markers mask must have shape ({x.shape[1]},), got {m.shape}")
                pick = m.copy()
            else:
                pick[m.astype(int)] = True
        fl = np.full(x.shape[:2], np.nan) if fill is None else np.asarray(fill, float)
        if fl.shape != x.shape[:2]:
            raise ValueError(f"fill must have shape {x.shape[:2]}, got {fl.shape}")
        with np.errstate(invalid="ignore"):
            sig = np.where(np.isfinite(fl), np.maximum(sigma_px, fill_slope_px * (0.8 - fl)), sigma_px)
        mk, org, dirs, foc, vw, sg = [], [], [], [], [], []
        for v, cam in enumerate(cams):
            sel = np.flatnonzero(pick & np.isfinite(x[v, :, 0]) & np.isfinite(x[v, :, 1]))
            if not len(sel):
                continue
            xn = cam.pixels_to_normalized(x[v, sel])
            ok = np.isfinite(xn).all(axis=1)
            sel, xn = sel[ok], xn[ok]
            d_cam = np.column_stack([xn, np.ones(len(sel))])
            mk.append(sel)
            dirs.append(d_cam @ cam.R)  # rows: R.T @ d, camera -> world
            org.append(np.broadcast_to(cam.center, (len(sel), 3)))
            foc.append(np.full(len(sel), 0.5 * (cam.K[0, 0] + cam.K[1, 1])))
            vw.append(np.full(len(sel), v))
            sg.append(sig[v, sel])
        if not mk:
            return cls(np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))
        return cls(np.concatenate(mk), np.vstack(org), np.vstack(dirs), np.concatenate(foc), np.concatenate(vw),
                   np.concatenate(sg))

    def subset(self, keep) -> MarkerRays:
        keep = np.asarray(keep)
        return MarkerRays(self.marker[keep], self.origin[keep], self.direction[keep], self.focal_px[keep],
                          self.view[keep], self.sigma_px[keep])

    def distances(self, points) -> np.ndarray:
        """Distance of each ray's marker (``points[marker]``, (n_markers, 3)) from the ray, metres."""
        d = np.asarray(points, float)[self.marker] - self.origin
        return np.linalg.norm(d - np.sum(d * self.direction, axis=1)[:, None] * self.direction, axis=1)

    def depths(self, points) -> np.ndarray:
        """Depth of each ray's marker along the ray, metres."""
        return np.sum((np.asarray(points, float)[self.marker] - self.origin) * self.direction, axis=1)

    def bases(self) -> np.ndarray:
        """Two unit vectors perpendicular to each ray (and to each other), shape (n_rays, 2, 3)."""
        d = self.direction
        # any vector not along d: the world axis d is least along
        a = np.eye(3)[np.argmin(np.abs(d), axis=1)]
        b1 = np.cross(d, a)
        b1 /= np.linalg.norm(b1, axis=1)[:, None]
        return np.stack([b1, np.cross(d, b1)], axis=1)


@dataclass(eq=False)
class PoseFit:
    """Result of :func:`fit_pose`.

    Attributes
    ----------
    pose : Pose
        The fitted pose (every local rotation within the joint limits).
    thesis_pose : Pose
        The thesis's pose from bone directions (:func:`~stillcap.body.kinematics.pose_from_markers`).
    directions : dict
        The thesis's bone directions from the markers (bone -> unit vector, NaN if unmeasured).
    residuals_m : ndarray, shape (n_markers,)
        Distance of each fitted model marker from its measurement, metres (NaN if unseen).
    thesis_residuals_m : ndarray, shape (n_markers,)
        The same for the thesis's pose.
    success : bool
        The optimiser converged.
    n_markers : int
        Markers used.
    time_s : float
    rays : MarkerRays or None
        The single-view rays given to :func:`fit_pose` (None without).
    ray_used : ndarray of bool, shape (n_rays,)
        Rays the final fit used: not of a triangulated marker, not rejected.
    ray_residuals_px : ndarray, shape (n_rays,)
        Distance of each ray's fitted model bead from the ray, in pixels at the bead's depth
        (NaN for rays of triangulated markers).
    root : str
        What was fitted of the root's frame (``fit_pose``'s ``root``).
    """

    pose: Pose
    thesis_pose: Pose
    directions: dict
    residuals_m: np.ndarray
    thesis_residuals_m: np.ndarray
    success: bool
    n_markers: int
    time_s: float = 0.0
    rays: MarkerRays | None = None
    ray_used: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    ray_residuals_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    root: str = "pinned"

    @property
    def ray_markers(self) -> np.ndarray:
        """Marker-set indices of the markers the fit placed on single-view rays (sorted, unique)."""
        if self.rays is None:
            return np.zeros(0, int)
        return np.unique(self.rays.marker[self.ray_used])

    @property
    def rms_m(self) -> float:
        r = self.residuals_m[np.isfinite(self.residuals_m)]
        return float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan")


def _euler_matrices(angles_deg: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rx(a), Ry(b), Rz(c) for rows (a, b, c) in degrees, each (n, 3, 3).

    Written from cos and sin (the elementary rotations) rather than with
    ``Rotation.from_euler``: the fit builds them at every residual and Jacobian evaluation, and
    the quaternion round trip cost ~12 ms of the ~30 ms fit; the same matrices to ~1e-16."""
    a = np.radians(np.asarray(angles_deg, float))
    c, s = np.cos(a), np.sin(a)
    n = len(a)
    # zero matrices with their five non-zero entries set (the same arrays as stacking the nine
    # entries, in ~1/3 of the time: ~15 calls per pose)
    R = np.zeros((3, n, 3, 3))
    for k, (i, j) in enumerate(((1, 2), (0, 2), (0, 1))):  # the plane each axis turns
        R[k, :, 3 - i - j, 3 - i - j] = 1.0
        R[k, :, i, i] = R[k, :, j, j] = c[:, k]
        R[k, :, i, j] = s[:, k] if k == 1 else -s[:, k]
        R[k, :, j, i] = -s[:, k] if k == 1 else s[:, k]
    return R[0], R[1], R[2]


def _rotations_about(axis: np.ndarray, angles_rad: np.ndarray) -> np.ndarray:
    """Rotations about one unit axis by each angle, shape (n, 3, 3)."""
    return Rotation.from_rotvec(np.outer(angles_rad, axis)).as_matrix()


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of 3-vectors along the last axis, broadcast: the same products and
    differences (the same values, bit for bit), without ``np.cross``'s axis handling (~10 us of
    its ~26 us per call in the fit's Jacobian)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _levels(skeleton: Skeleton) -> tuple[np.ndarray, ...]:
    """The joints by depth that :func:`_start_angles` solves together
    (:attr:`~stillcap.body.skeleton.Skeleton.depth_levels`)."""
    return skeleton.depth_levels


def _start_angles(skeleton: Skeleton, markerset: MarkerSet, pts: np.ndarray, r2w: np.ndarray, lo, hi, center,
                  sd, rays: MarkerRays | None = None, ray_sigma_px: float = 1.0) -> np.ndarray:
    """A start for :func:`fit_pose`, joint by joint from the root (degrees, (n_joints, 3)).

    Each joint's parent frame is known by then, so the joint's world position is too. A frame
    with 2+ seen markers not in line with the joint: the rotation about the joint that best
    maps the markers' offsets onto the measured markers (Wahba / Kabsch). One seen marker: the
    rotations that put it exactly on its measurement form a one-parameter family (turning about
    the joint-to-marker line); the one whose Euler angles the prior likes best, within the
    limits, is taken, or, when ``rays`` hold single-view rays of the frame's other markers, the
    one that puts them nearest their rays (in sigma: ``ray_sigma_px`` at the bead's depth). No
    marker: the prior's centre.

    The joints of one depth from the root depend only on their parents, so they are solved
    together: one Euler conversion (:func:`euler_within_limits`) of every candidate rotation of
    the level and one ``Rotation.from_euler`` for its frames. The angles are the same as one
    joint at a time (the conversions work rotation by rotation); a level's conversion costs about
    what one joint's did (its fixed cost is most of it: ~0.12 ms CPU for one rotation, ~0.21 ms
    for 120), which took the start of the 20-joint puppet (7 levels) from 5.0 to 3.6 ms CPU.
    """
    n = skeleton.n_joints
    lim = np.stack([lo, hi], axis=-1)
    lim_nan = np.where(np.isfinite(lim), lim, np.nan)
    frames = markerset.bone_frames(skeleton)
    seen = np.isfinite(pts).all(axis=1)
    offs = markerset.offsets
    ang = np.zeros((n, 3))
    world = np.zeros((n, 3, 3))
    origin = np.zeros((n, 3))
    parents = skeleton.parents
    phis = np.radians(np.arange(0.0, 360.0, 3.0))
    for level in _levels(skeleton):
        todo, cand_list, parent_w = [], [], {}
        for j in level:
            p = parents[j]
            Wp = r2w[:3, :3] if p < 0 else world[p]
            parent_w[j] = Wp
            origin[j] = r2w[:3, 3] if p < 0 else origin[p] + world[p] @ skeleton.offsets[j]
            locked = (hi[j] <= lo[j]).all()
            sel = np.flatnonzero((frames == j) & seen)
            cands = None
            if not locked and len(sel):
                meas = (pts[sel] - origin[j]) @ Wp  # measured offsets in the parent's frame (rows: Wp.T @ v)
                model = offs[sel]
                cloud = np.vstack([model, np.zeros((1, 3))])
                sv = np.linalg.svd(cloud - cloud.mean(axis=0), compute_uv=False)
                if len(sel) >= 2 and sv[1] > 1e-3 * sv[0]:
                    cands = align_matrix(meas, model)[None]
                else:
                    a, b = normalised(meas.mean(axis=0)), normalised(model.mean(axis=0))
                    if np.isfinite(a).all() and np.isfinite(b).all():
                        R0 = align_matrix(a[None], b[None])
                        cands = _rotations_about(a, phis) @ R0
            if cands is None:
                ang[j] = np.where(locked, lo[j], center[j])
            else:
                todo.append(j)
                cand_list.append(cands)
        if todo:  # every candidate of the level converted at once
            counts = [len(c) for c in cand_list]
            e_all, viol_all = euler_within_limits(np.concatenate(cand_list), np.repeat(lim_nan[todo], counts, axis=0))
            ends = np.cumsum(counts)
            for j, cands, stop, k in zip(todo, cand_list, ends, counts):
                e, viol = e_all[stop - k:stop], viol_all[stop - k:stop]
                cost = 100.0 * viol + np.sum(((e - center[j]) / sd[j]) ** 2, axis=1)
                if rays is not None and len(cands) > 1:
                    Wp = parent_w[j]
                    for r in np.flatnonzero(frames[rays.marker] == j):
                        bead = origin[j] + np.einsum("ij,cjk,k->ci", Wp, cands, offs[rays.marker[r]])  # (n_cands, 3)
                        v = bead - rays.origin[r]
                        z = v @ rays.direction[r]
                        dist = np.linalg.norm(v - z[:, None] * rays.direction[r], axis=1)
                        spx = rays.sigma_px[r] if np.isfinite(rays.sigma_px[r]) else ray_sigma_px
                        sig = spx * np.maximum(np.abs(z), 1e-3) / rays.focal_px[r]
                        cost = cost + np.minimum((dist / sig) ** 2, 1e4)  # a wrong ray: bounded say
                ang[j] = np.clip(e[int(np.argmin(cost))], lo[j], hi[j])
        local = Rotation.from_euler(EULER_LIMIT_SEQUENCE, ang[level], degrees=True).as_matrix()
        for j, L in zip(level, local):
            world[j] = parent_w[j] @ L
    return ang


def _robust_cost(f: np.ndarray, f_scale: float | None) -> float:
    """``least_squares``' cost of residuals ``f``: half their sum of squares, or with the soft-L1
    loss of scale ``f_scale`` ``0.5 C^2 sum 2 (sqrt(1 + (f / C)^2) - 1)``."""
    if f_scale is None:
        return 0.5 * float(f @ f)
    return f_scale ** 2 * float(np.sum(np.sqrt(1.0 + (f / f_scale) ** 2) - 1.0))


def _newton_start(fun, jac, x: np.ndarray, bounds, f_scale: float | None, steps: int = 6,
                  rtol: float = 1e-4) -> tuple[np.ndarray, np.ndarray, bool]:
    """A few Gauss-Newton steps from ``x`` on the loss ``least_squares`` then minimises (its
    soft-L1 of scale ``f_scale`` as reweighted least squares: each residual row scaled by the
    square root of the loss's slope ``1 / sqrt(1 + (f / C)^2)``; plain squares for ``None``).
    Parameters on a bound whose gradient (or step) points out of it are held there (projected
    Newton), each step is shortened to the first bound it meets and halved until the loss
    decreases. Stops after ``steps`` steps or at the first that lowers the loss by less than
    ``rtol`` of itself, or whose model predicts less (converged).

    Why not ``least_squares`` alone: its trust region (``x_scale``-limited steps, reflected at
    the bounds) took 8 iterations at ~1.5 ms each on the benchmark's pose, most of them to walk
    the weakly measured angles (a forearm's twist) the ~10 deg to their optimum that a full
    Gauss-Newton step goes at once; from this start it needs ~2 to confirm the optimum.
    ``least_squares`` still ends the fit, with its own tolerances, so the optimum is its.

    Returns the parameters, their residuals, and whether the steps converged."""
    lo, hi = bounds
    f = fun(x)
    cost = _robust_cost(f, f_scale)
    for _ in range(steps):
        J = jac(x)
        w = np.ones(len(f)) if f_scale is None else 1.0 / np.sqrt(np.sqrt(1.0 + (f / f_scale) ** 2))
        Jw, fw = J * w[:, None], f * w
        A, g = Jw.T @ Jw, Jw.T @ fw
        move = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))  # not held on a bound
        dx = np.zeros_like(x)
        try:
            for _ in range(3):  # held too: parameters on a bound the step would leave it by
                dx[:] = 0.0
                dx[move] = np.linalg.solve(A[np.ix_(move, move)], -g[move])
                out = move & (((x <= lo) & (dx < 0)) | ((x >= hi) & (dx > 0)))
                if not out.any():
                    break
                move &= ~out
        except np.linalg.LinAlgError:
            break
        if not np.isfinite(dx).all() or out.any():
            break
        if -0.5 * float(g @ dx) <= rtol * cost:  # the model's own decrease: at the optimum already
            return x, f, True
        # the step shortened to the first bound it meets (the direction kept: a descent one)
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(dx < 0, (lo - x) / dx, np.where(dx > 0, (hi - x) / dx, np.inf))
        t = min(1.0, float(np.min(room, initial=np.inf)))
        if t <= 0.0:
            break
        bound = np.broadcast_to(np.where(dx < 0, lo, hi), x.shape)
        for _ in range(6):  # halved until the loss decreases
            x_new = np.clip(x + t * dx, lo, hi)
            hit = room <= t  # the parameters the step takes to their bound: put exactly on it
            x_new[hit] = bound[hit]  # (x + t dx lands an ulp short of it, which depends on the BLAS's kernel)
            f_new = fun(x_new)
            c_new = _robust_cost(f_new, f_scale)
            if c_new < cost:
                break
            t = 0.5 * t
        else:
            break
        done = cost - c_new < rtol * cost
        x, f, cost = x_new, f_new, c_new
        if done:
            return x, f, True
    return x, f, False


def fit_pose(skeleton: Skeleton, markerset: MarkerSet, marker_positions, root2world=None,
             initial: Pose | None = None, marker_sigma_m: float = 0.2e-3, robust: bool = True,
             rays: MarkerRays | None = None, ray_sigma_px: float = 1.0, ray_reject: float = 5.0,
             root: str = "pinned") -> PoseFit:
    """Joint rotations that put the marker set's beads on the measured markers.

    The free joints' intrinsic XYZ Euler angles (:data:`~stillcap.body.skeleton.EULER_LIMIT_SEQUENCE`,
    the angles ``limits_deg`` bounds) are fitted by least squares (``scipy.optimize.least_squares``,
    trust region with the limits as bounds, analytic Jacobian: turning joint ``j`` about the
    world axis ``u`` moves every point beyond it by ``u x (p - o_j)``) to

    - every seen marker: ``(model - measured) / marker_sigma_m``;
    - every single-view ray (``rays``) of a marker without a 3D point: the model bead's offset
      from the ray along two unit vectors perpendicular to it, divided by
      ``sigma = sigma_px * depth / focal_px`` (the ray's pixel error, ``rays.sigma_px`` or
      ``ray_sigma_px``, at the bead's depth along the ray, the depth taken at the start pose and
      again at the fitted pose before a refit);
      rays of markers that have a 3D point are ignored (never counted twice);
    - a weak prior per angle: ``(angle - clip(0, limits)) / (half the range, >= 5 deg)``, which
      only matters for what the markers leave open (see the module docstring).

    The start is built joint by joint from the root (:func:`_start_angles`: Kabsch where a
    frame has 2+ markers, otherwise the exact one-marker solution that puts the frame's rays'
    beads nearest their rays, or the prior's favourite without rays);
    if some marker or ray then still misses by more than 5 sigma, ``initial`` and the thesis's pose
    are tried as starts too and the best fit is kept. With ``robust`` a soft-L1 loss (scale
    5 sigma) keeps one wrong marker or ray from bending the whole skeleton. A ray still more
    than ``ray_reject`` sigma from its fitted bead (a wrongly identified single-view bead) is
    dropped and the fit run again from there, until none is.

    Parameters
    ----------
    skeleton : Skeleton
    markerset : MarkerSet
    marker_positions : array_like, shape (n_markers, 3)
        Measured markers, metres, marker-set order; NaN for missing ones.
    root2world : array_like, shape (4, 4), optional
        The root's frame (puppet: the pelvis, fixed on the turntable axis); default rest.
    initial : Pose, optional
        Start instead of the thesis's pose.
    marker_sigma_m : float or array_like, shape (n_markers,)
        Expected marker error, metres (per marker: e.g. larger for partly hidden beads).
    robust : bool
        Soft-L1 loss (scale 5 sigma) instead of squares.
    rays : MarkerRays, optional
        Single-view observations (:meth:`MarkerRays.from_views`), world frame.
    ray_sigma_px : float
        Expected error of a single-view bead centre, pixels, for rays without their own
        ``sigma_px`` (default 1 px: a bead seen once is often partly hidden, so its centre is
        less sure than a triangulated one's ~0.2 px).
    ray_reject : float
        Rays whose fitted residual exceeds this many sigma are rejected.
    root : {"pinned", "translate", "free"}
        ``"pinned"``: the root stays at ``root2world`` (the thesis's pelvis on the turntable
        axis); ``"translate"``: its position is fitted too (a weak prior, 20 mm, toward
        ``root2world``'s); ``"free"``: its position and rotation (the root joint's Euler angles,
        whatever its limits, with the prior's 180 deg) are fitted. :func:`root_freedom` says
        what the markers fix.

    Returns
    -------
    PoseFit
    """
    t0 = time.perf_counter()
    pts = np.asarray(marker_positions, float)
    if pts.shape != (len(markerset), 3):
        raise ValueError(f"marker_positions must have shape ({len(markerset)}, 3), got {pts.shape}")
    r2w = skeleton.rest_root2world() if root2world is None else np.asarray(root2world, float)
    if root not in ("pinned", "translate", "free"):
        raise ValueError(f"root must be pinned, translate or free, got {root!r}")
    seen = np.isfinite(pts).all(axis=1)
    msig = np.broadcast_to(np.asarray(marker_sigma_m, float), (len(markerset),))
    if not np.all(np.isfinite(msig) & (msig > 0)):
        raise ValueError(f"marker_sigma_m must be > 0 metres, got {marker_sigma_m}")
    sig_seen = msig[seen]
    if rays is not None:
        if not isinstance(rays, MarkerRays):
            raise ValueError(f"rays must be a MarkerRays, got {type(rays).__name__}")
        if len(rays) and (rays.marker.min() < 0 or rays.marker.max() >= len(markerset)):
            raise ValueError(f"ray markers must index the {len(markerset)} markers, got {rays.marker.tolist()}")
        if ray_sigma_px <= 0 or ray_reject <= 0:
            raise ValueError(f"ray_sigma_px and ray_reject must be > 0, got {ray_sigma_px}, {ray_reject}")
    use = np.zeros(0, bool) if rays is None else ~seen[rays.marker]  # never a triangulated marker twice
    active = rays.subset(use) if rays is not None and use.any() else None
    thesis, dirs = pose_and_directions(skeleton, markerset, pts, r2w)
    n = skeleton.n_joints
    lim = skeleton.limits_deg
    lo = np.where(np.isnan(lim[..., 0]), -np.inf, lim[..., 0])
    hi = np.where(np.isnan(lim[..., 1]), np.inf, lim[..., 1])
    if root == "free":  # the root's rotation fitted whatever its limits (the puppet's pelvis: locked)
        lo[skeleton.root], hi[skeleton.root] = -np.inf, np.inf
    free = hi > lo  # (n, 3)
    n_t = 3 if root != "pinned" else 0  # root translation parameters, after the angles
    t_sd = 0.02  # metres: the translation's weak prior toward root2world's
    center = np.clip(0.0, lo, hi)
    width = np.where(np.isfinite(hi - lo), 0.5 * (hi - lo), 180.0)
    sd = np.maximum(width, 5.0)
    starts = [_start_angles(skeleton, markerset, pts, r2w, lo, hi, center, sd, active, ray_sigma_px)]
    for other in ((initial,) if initial is not None else ()) + (thesis,):
        a0 = np.clip(skeleton.limit_angles_deg(other.local_rotations), lo, hi)
        starts.append(np.where(np.isfinite(lo) & ~free, lo, a0))
    ang = starts[0]
    frames = markerset.bone_frames(skeleton)
    offs = markerset.offsets
    parents = skeleton.parents
    # chain[j]: joints whose rotation moves points of frame j (j and its ancestors)
    chain = np.zeros((n, n), bool)
    for j in range(n):
        k = j
        while k >= 0:
            chain[j, k] = True
            k = parents[k]
    pidx = np.argwhere(free)  # (n_params, 2): joint, axis
    pj, pax = pidx[:, 0], pidx[:, 1]
    mf = frames[seen]
    meas = pts[seen]
    n_res = 3 * len(mf)
    k_deg = math.pi / 180.0

    def unpack(x):
        a = ang.copy()
        a[free] = x[:len(pidx)]
        return a

    def root_of(x):
        if not n_t:
            return r2w
        m = r2w.copy()
        m[:3, 3] = x[len(pidx):]
        return m

    def pack(a):
        return np.concatenate([a[free], r2w[:3, 3]]) if n_t else a[free]

    last = [None, None]  # the parameters of the latest model() and its value

    def model(x):
        # least_squares asks for the Jacobian at the parameters it has just evaluated the
        # residuals at: the same frames are not built twice (the same values, ~10 % of the fit)
        if last[0] is not None and np.array_equal(last[0], x):
            return last[1]
        a = unpack(x)
        Rx, Ry, Rz = _euler_matrices(a)
        local = Rx @ Ry @ Rz  # intrinsic XYZ
        j2w = forward_kinematics(skeleton, root_of(x), local)
        last[0], last[1] = np.array(x, copy=True), (a, Rx, Ry, j2w)
        return last[1]

    def beads(j2w, idx):
        return np.einsum("nij,nj->ni", j2w[frames[idx], :3, :3], offs[idx]) + j2w[frames[idx], :3, 3]

    def problem(ray_set: MarkerRays | None, ray_sig: np.ndarray):
        """Residual and Jacobian functions for the markers and the rays ``ray_set`` (sigmas in metres)."""
        nr = 0 if ray_set is None else len(ray_set)
        rf = frames[ray_set.marker] if nr else np.zeros(0, int)
        B = ray_set.bases() / ray_sig[:, None, None] if nr else np.zeros((0, 2, 3))  # (nr, 2, 3), per metre
        idx = np.concatenate([np.flatnonzero(seen), ray_set.marker if nr else np.zeros(0, int)])
        n_rows = n_res + 2 * nr
        prior_rows = n_rows + np.arange(len(pidx))
        moves = chain[np.concatenate([mf, rf])][:, pj].T  # (n_params, n_points): parameter moves the point
        scale = np.concatenate([1.0 / sig_seen, np.ones(nr)])

        def residuals(x):
            a, _, _, j2w = model(x)
            m = beads(j2w, idx)
            parts = [((m[:len(mf)] - meas) / sig_seen[:, None]).ravel()]
            if nr:
                parts.append(np.einsum("rki,ri->rk", B, m[len(mf):] - ray_set.origin).ravel())
            parts.append(((a - center) / sd)[free])
            if n_t:
                parts.append((x[len(pidx):] - r2w[:3, 3]) / t_sd)
            return np.concatenate(parts)

        def jacobian(x):
            _, Rx, Ry, j2w = model(x)
            m = beads(j2w, idx)
            r2w_x = root_of(x)
            W = np.concatenate([r2w_x[None, :3, :3], j2w[:, :3, :3]])[parents[pj] + 1]  # parent world rotations
            # world axis of each Euler angle: x, then Rx y, then Rx Ry z (intrinsic XYZ)
            axes = np.where((pax == 0)[:, None], [1.0, 0.0, 0.0],
                            np.where((pax == 1)[:, None], Rx[pj][:, :, 1], (Rx[pj] @ Ry[pj])[:, :, 2]))
            u = np.einsum("pij,pj->pi", W, axes)
            d = _cross(u[:, None, :], m[None] - j2w[pj, None, :3, 3]) * k_deg  # (n_params, n_points, 3)
            d = d * (moves * scale[None])[..., None]
            npar = len(pidx) + n_t
            J = np.zeros((n_rows + npar, npar))
            J[:n_res, :len(pidx)] = d[:, :len(mf)].reshape(len(pidx), n_res).T
            if nr:
                J[n_res:n_rows, :len(pidx)] = np.einsum("rki,pri->rkp", B, d[:, len(mf):]).reshape(2 * nr, len(pidx))
            J[prior_rows, np.arange(len(pidx))] = 1.0 / sd[pj, pax]
            if n_t:  # moving the root moves every point by the same vector
                J[:n_res, len(pidx):] = np.tile(np.eye(3), (len(mf), 1)) / np.repeat(sig_seen, 3)[:, None]
                if nr:
                    J[n_res:n_rows, len(pidx):] = B.reshape(2 * nr, 3)
                J[n_rows + len(pidx) + np.arange(3), len(pidx) + np.arange(3)] = 1.0 / t_sd
            return J

        return residuals, jacobian

    def ray_sigmas(ray_set: MarkerRays, x) -> np.ndarray:
        z = ray_set.depths(beads(model(x)[3], np.arange(len(markerset))))
        # a bead behind its camera at this pose: its distance from the camera instead
        far = np.linalg.norm(r2w[:3, 3] - ray_set.origin, axis=1)
        spx = np.where(np.isfinite(ray_set.sigma_px), ray_set.sigma_px, ray_sigma_px)
        return spx * np.where(z > 1e-3, z, far) / ray_set.focal_px

    lb = np.concatenate([lo[free], np.full(n_t, -np.inf)])
    ub = np.concatenate([hi[free], np.full(n_t, np.inf)])
    inner = (np.where(np.isfinite(lb), lb + 1e-9, lb), np.where(np.isfinite(ub), ub - 1e-9, ub))
    kw = dict(loss="soft_l1", f_scale=5.0) if robust else {}
    # tr_solver="exact": the dense trust-region solve (an SVD of the small Jacobian per step) is
    # 15 ms per fit against 22 ms with LSMR (~40 pure-Python iterations per step), and ends nearer
    # the optimum: on the 52 benchmark poses its joints are within 5.5 um of a fit run to 1e-12
    # tolerances, LSMR's within 36 um. It needs BLAS on one thread: on a busy machine OpenBLAS's
    # threads spin on these small matrices (225-240 ms per fit measured on 2 shared cores), hence
    # the threadpoolctl limit, which holds for this call only.
    # Tolerances 1e-6 instead of SciPy's 1e-8: the steps after them move the joints by at most
    # 5.5 um (see above; the fit's joint error is ~110 um) and cost ~40 % of the time.
    opts = dict(bounds=(lb, ub), x_scale=10.0, method="trf", tr_solver="exact",
                ftol=1e-6, xtol=1e-6, gtol=1e-6, **kw)
    keep = np.ones(0 if active is None else len(active), bool)
    best = None

    def newton(fun, jac, x0, n_data):
        # Gauss-Newton steps first (_newton_start) where they converge to a good fit (every
        # marker and ray within 5 sigma, as the starts' test below): then least_squares only
        # confirms the optimum. A poor fit (a skeleton unlike the puppet) has several minima,
        # and the full steps may reach another than the trust region's path from x0 (measured:
        # 0.2-2 deg of bone direction either way): there x0 is kept
        x, f, converged = _newton_start(fun, jac, x0, inner, kw.get("f_scale"))
        return x if converged and np.max(np.abs(f[:n_data]), initial=0.0) < 5.0 else x0

    with single_blas_thread():
        cur = active
        sig = ray_sigmas(active, np.clip(pack(starts[0]), *inner)) if active is not None else np.zeros(0)
        fun, jac = problem(cur, sig)
        n_data = n_res + 2 * (0 if cur is None else len(cur))
        for a0 in starts:  # the joint-by-joint start; the others only when it ends in a poor fit
            r = least_squares(fun, newton(fun, jac, np.clip(pack(a0), *inner), n_data), jac=jac, **opts)
            if best is None or r.cost < best.cost:
                best = r
            if np.max(np.abs(best.fun[:n_data]), initial=0.0) < 5.0:  # every marker and ray within 5 sigma
                break
        # rays whose bead the fit leaves > ray_reject sigma away: wrongly identified; drop, refit
        while active is not None and keep.any():
            sig = ray_sigmas(active, best.x)
            off = active.distances(beads(model(best.x)[3], np.arange(len(markerset)))) / sig
            bad = keep & (off > ray_reject)
            if not bad.any():
                break
            # the worst first: one wrong ray can pull its neighbours' beads off their own rays
            keep[np.flatnonzero(bad)[np.argmax(off[bad])]] = False
            cur = active.subset(keep) if keep.any() else None
            fun, jac = problem(cur, sig[keep])
            cands = [best.x, np.clip(pack(starts[0]), *inner)]
            if cur is not None:
                cands[1] = np.clip(pack(_start_angles(skeleton, markerset, pts, r2w, lo, hi, center, sd, cur,
                                                      ray_sigma_px)), *inner)
            n_data = n_res + 2 * (0 if cur is None else len(cur))
            best = min((least_squares(fun, newton(fun, jac, c, n_data), jac=jac, **opts) for c in cands),
                       key=lambda r: r.cost)
    a = unpack(best.x)
    local = Rotation.from_euler(EULER_LIMIT_SEQUENCE, a, degrees=True).as_matrix()
    r2w = root_of(best.x)
    pose = Pose(skeleton, r2w, local)
    model_pts = markerset.positions(pose)
    res = np.full(len(markerset), np.nan)
    res[seen] = np.linalg.norm(model_pts[seen] - meas, axis=1)
    tres = np.full(len(markerset), np.nan)
    tres[seen] = np.linalg.norm(markerset.positions(thesis)[seen] - meas, axis=1)
    ray_used = np.zeros(0 if rays is None else len(rays), bool)
    ray_px = np.full(len(ray_used), np.nan)
    if active is not None:
        ray_used[np.flatnonzero(use)[keep]] = True
        z = active.depths(model_pts)
        far = np.linalg.norm(r2w[:3, 3] - active.origin, axis=1)
        ray_px[use] = active.distances(model_pts) * active.focal_px / np.where(z > 1e-3, z, far)
    return PoseFit(pose, thesis, dirs, res, tres, bool(best.success), int(seen.sum()), time.perf_counter() - t0,
                   rays, ray_used, ray_px, root)


def root_freedom(skeleton: Skeleton, markerset: MarkerSet) -> str:
    """What the markers fix of the root's frame, as :func:`fit_pose`'s ``root``.

    A joint frame with two or more beads not in line with its joint (``"full"``,
    :func:`frame_status`) is a rigid body whose joint the beads place (up to a turn about the
    beads' line, which the rest of the chain settles). ``"free"`` (position and rotation) when
    the root frame is full itself, or when three or more of the root's child branches hold a
    full frame (three joints round the root, not in one line, fix its frame); ``"translate"`` when
    one or two do; ``"pinned"`` otherwise (nothing measures the root: it stays where the
    caller puts it).
    """
    status = frame_status(skeleton, markerset)
    r = skeleton.root
    if status[skeleton.names[r]] == "full":
        return "free"
    branches = 0
    for c in skeleton.children(r):
        stack = [c]
        while stack:
            j = stack.pop()
            if status[skeleton.names[j]] == "full":
                branches += 1
                break
            stack.extend(skeleton.children(j))
    return "free" if branches >= 3 else "translate" if branches >= 1 else "pinned"
