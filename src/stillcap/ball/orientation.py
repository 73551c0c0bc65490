"""Ball orientation per flash and the spin of a pitched ball (SPEC J1, seed section 4.4).

Input: for every strobe flash ``k`` (time ``times[k]``), the painted markers found on that ball
image, each as a **direction from the ball centre** in the world frame with its marker type
(:class:`MarkerObservations`). A marker triangulated by a stereo pair gives the direction
``(X - c) / |X - c|`` directly; a marker seen by one camera only gives a pixel ray, which meets
the ball sphere (known centre and radius) on the visible hemisphere:
:meth:`MarkerObservations.from_rays` turns it into a direction.

Rotations are ``ball2world``: ``u_world = R u_ball``; a marker ``j`` of the layout
(:class:`stillcap.ball.layout.BallLayout`) appears at ``R_k m_j`` at flash ``k``.

Two estimators return the same :class:`SpinResult`:

- :func:`fit_spin_seed`, the seed's method: per flash, ``R_k`` minimises
  ``E = a1 sum_i D_M(i)^2 + a2 sum_{j in x,y,z} D_A(j)^2`` (``D_M`` the angle from observed
  marker ``i`` to the nearest model marker of its type, ``D_A`` the angle between the ball
  axes of ``R_k`` and of the prediction ``R_{k-1}`` turned once more by the last relative
  rotation; ``a2 = 0`` for the first two orientations) with Powell's method over Euler angles;
  the relative rotations ``R_k R_{k-1}^T`` give axis-angle pairs, the spin axis is their mean
  and the rate their angle times the strobe frequency.
- :func:`fit_spin`, one constant spin over all flashes: ``R(t) = exp([w] (t - t0)) R0`` with
  ``R0`` and ``w`` (rad/s, world frame) fitted by robust least squares
  (``scipy.optimize.least_squares``) to the angles between every observed marker and the
  rotated model marker of its type it is assigned to (nearest, re-assigned until stable);
  then a plain least-squares polish on the inliers gives the covariance and the 1-sigma of
  the spin rate and axis.

Aliasing: with flashes every ``1/f`` s the rotation between flashes is only known modulo a full
turn, so both methods return the *principal* spin, whose rotation per interval is at most half
a turn (at most ``f / 2`` revolutions per second: 2400 rpm at 80 Hz). :mod:`stillcap.ball.alias`
enumerates the other candidates and picks one with a second strobe rate or the flight's
curvature; ``fit_spin(..., spin_init=candidate)`` then refits at that alias.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array, as_rng
from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout

RPM_PER_RAD_S = 60.0 / (2.0 * np.pi)


def _default_layout(layout):
    return BallLayout.seed() if layout is None else layout


def _unit_rows(a, name):
    n = np.linalg.norm(a, axis=1)
    if np.any(~(n > 0)):
        bad = np.flatnonzero(~(n > 0))
        raise ValueError(f"{name} must be non-zero and finite, rows {bad.tolist()} are not")
    return a / n[:, None]


# ----------------------------------------------------------------------------------------------
# Observations
# ----------------------------------------------------------------------------------------------
def rays_to_directions(ray_origins, ray_directions, ball_centers, radius: float = BASEBALL_RADIUS):
    """Where pixel rays meet the ball sphere, as directions from the ball centre.

    Each ray ``o + s d`` (``s > 0``) is intersected with the sphere ``|X - c| = radius``; the
    nearer intersection is the marker on the visible hemisphere. A ray that misses the sphere
    (noise near the silhouette) gives the direction of its closest approach (a point on the
    limb).

    Parameters
    ----------
    ray_origins : array_like, shape (M, 3)
        Camera centres, world frame, m.
    ray_directions : array_like, shape (M, 3)
        Ray directions through the marker pixels (any length), world frame.
    ball_centers : array_like, shape (M, 3)
        Ball centre at each observation's flash, m.
    radius : float
        Ball radius, m.

    Returns
    -------
    directions : ndarray, shape (M, 3)
        Unit vectors from the ball centre to the marker, world frame.
    hit : ndarray of bool, shape (M,)
        False where the ray missed the sphere (direction on the limb).
    """
    o = as_array(ray_origins, (None, 3), "ray_origins")
    d = _unit_rows(as_array(ray_directions, (len(o), 3), "ray_directions"), "ray_directions")
    c = as_array(ball_centers, (len(o), 3), "ball_centers")
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    disc = b * b - (np.einsum("ij,ij->i", oc, oc) - radius * radius)
    hit = disc >= 0
    s = np.where(hit, -b - np.sqrt(np.where(hit, disc, 0.0)), -b)
    p = oc + s[:, None] * d
    return _unit_rows(p, "ray-sphere points (ray through the ball centre?)"), hit


@dataclass
class MarkerObservations:
    """Marker observations of one ball over several flashes (flat arrays).

    Attributes
    ----------
    flash : ndarray of int, shape (M,)
        Flash index of each observation (into the ``times`` given to the fits).
    types : ndarray of int, shape (M,)
        Marker type index (into ``BallLayout.type_names``).
    directions : ndarray, shape (M, 3)
        Unit vectors from the ball centre to the marker, world frame.
    from_ray : ndarray of bool, shape (M,)
        True for observations converted from a single camera's pixel ray.
    """

    flash: np.ndarray
    types: np.ndarray
    directions: np.ndarray
    from_ray: np.ndarray = None

    def __post_init__(self):
        self.flash = np.asarray(self.flash)
        if self.flash.ndim != 1:
            raise ValueError(f"flash must have shape (M,), got {self.flash.shape}")
        m = len(self.flash)
        if m and not np.all(np.equal(np.mod(self.flash, 1), 0)):
            raise ValueError("flash indices must be integers")
        self.flash = self.flash.astype(int)
        if m and self.flash.min() < 0:
            raise ValueError(f"flash indices must be >= 0, got {self.flash.min()}")
        self.types = np.asarray(self.types)
        if self.types.shape != (m,):
            raise ValueError(f"types must have shape ({m},), got {self.types.shape}")
        self.types = self.types.astype(int)
        d = as_array(self.directions, (m, 3), "directions")
        self.directions = _unit_rows(d, "directions") if m else d.reshape(0, 3)
        self.from_ray = (np.zeros(m, bool) if self.from_ray is None
                         else as_array(self.from_ray, (m,), "from_ray", dtype=bool))

    def __len__(self) -> int:
        return len(self.flash)

    @classmethod
    def from_directions(cls, flash, types, directions, layout: BallLayout | None = None):
        """From directions (stereo-triangulated markers minus the ball centre).

        Parameters
        ----------
        flash : array_like of int, shape (M,)
        types : array_like, shape (M,)
            Type names (``"red"``) or indices.
        directions : array_like, shape (M, 3)
            From the ball centre to the marker, world frame (normalised here).
        layout : BallLayout, optional
            To translate type names (default the seed layout).
        """
        layout = _default_layout(layout)
        flash = np.asarray(flash)
        return cls(flash, layout.type_index(types).reshape(flash.shape), directions)

    @classmethod
    def from_rays(cls, flash, types, ray_origins, ray_directions, ball_centers,
                  radius: float | None = None, layout: BallLayout | None = None):
        """From single-camera pixel rays (see :func:`rays_to_directions`).

        Parameters
        ----------
        flash : array_like of int, shape (M,)
        types : array_like, shape (M,)
        ray_origins, ray_directions : array_like, shape (M, 3)
            Camera centre and ray direction through the marker pixel, world frame.
        ball_centers : array_like, shape (M, 3) or (K, 3)
            Ball centre per observation, or per flash (indexed by ``flash``), m.
        radius : float, optional
            Ball radius (default ``layout.radius``).
        """
        layout = _default_layout(layout)
        flash = np.asarray(flash)
        m = len(flash)
        c = np.asarray(ball_centers, float)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"ball_centers must have shape (M, 3) or (K, 3), got {c.shape}")
        if c.shape[0] != m:
            if m and flash.max() >= len(c):
                raise ValueError(f"ball_centers has {len(c)} rows but flash indices reach {flash.max()}")
            c = c[flash.astype(int)]
        d, _ = rays_to_directions(ray_origins, ray_directions, c, layout.radius if radius is None else radius)
        return cls(flash, layout.type_index(types).reshape(flash.shape), d, np.ones(m, bool))

    @classmethod
    def from_per_flash(cls, per_flash, layout: BallLayout | None = None):
        """From a list with one ``(directions (n_k, 3), types (n_k,))`` pair per flash."""
        layout = _default_layout(layout)
        fl, ty, di = [], [], []
        for k, item in enumerate(per_flash):
            if len(item) != 2:
                raise ValueError(f"per_flash[{k}] must be a (directions, types) pair")
            d = np.asarray(item[0], float).reshape(-1, 3) if np.size(item[0]) else np.zeros((0, 3))
            t = layout.type_index(np.asarray(item[1], dtype=object).reshape(-1))
            if len(t) != len(d):
                raise ValueError(f"per_flash[{k}]: {len(d)} directions but {len(t)} types")
            fl.append(np.full(len(d), k))
            ty.append(t)
            di.append(d)
        if not fl:
            return cls(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        return cls(np.concatenate(fl), np.concatenate(ty), np.concatenate(di))

    @classmethod
    def concatenate(cls, parts):
        """Join several observation sets (e.g. stereo directions and single-camera rays)."""
        parts = list(parts)
        if not parts:
            return cls(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        return cls(np.concatenate([p.flash for p in parts]), np.concatenate([p.types for p in parts]),
                   np.concatenate([p.directions for p in parts]),
                   np.concatenate([p.from_ray for p in parts]))

    def of_flash(self, k: int):
        """``(directions (n, 3), types (n,))`` of flash ``k``."""
        sel = self.flash == k
        return self.directions[sel], self.types[sel]

    def counts(self, n_flashes: int) -> np.ndarray:
        """Observations per flash, shape (n_flashes,)."""
        return np.bincount(self.flash, minlength=n_flashes)[:n_flashes]


def _check_inputs(times, observations, layout):
    times = as_array(times, (None,), "times")
    if len(times) < 2:
        raise ValueError(f"need at least 2 flash times, got {len(times)}")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError("times must be finite and strictly increasing")
    if not isinstance(observations, MarkerObservations):
        observations = MarkerObservations.from_per_flash(observations, layout)
    if len(observations) and observations.flash.max() >= len(times):
        raise ValueError(f"observations refer to flash {observations.flash.max()} but times has "
                         f"shape {times.shape}")
    if len(observations) and observations.types.max() >= layout.n_types:
        raise ValueError(f"observation types must be < {layout.n_types}, got {observations.types.max()}")
    return times, observations


def strobe_period(times) -> float:
    """The flash interval: the smallest time step (a missed flash leaves a 2x step), s."""
    times = as_array(times, (None,), "times")
    if len(times) < 2:
        raise ValueError(f"need at least 2 times, got shape {times.shape}")
    return float(np.min(np.diff(times)))


# ----------------------------------------------------------------------------------------------
# Per-flash orientation from marker types (no temporal information)
# ----------------------------------------------------------------------------------------------
def _triads(p, q):
    """Orthonormal frames (H, 3, 3), columns, from unit vectors p, q (H, 3), symmetric in p, q."""
    e1 = p + q
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = p - q
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def _nearest_same_type(R, u, t, layout):
    """For rotations R (H,3,3): angle (rad) from each observation u (n,3) of type t (n,) to the
    nearest rotated model marker of its type, and that marker's index: (H, n), (H, n)."""
    model = np.einsum("hab,jb->hja", R, layout.directions)  # (H, 12, 3)
    cos = np.einsum("na,hja->hnj", u, model)  # (H, n, 12)
    same = layout.types[None, :] == t[:, None]  # (n, 12)
    cos = np.where(same[None], cos, -2.0)
    j = cos.argmax(-1)
    c = np.take_along_axis(cos, j[..., None], -1)[..., 0]
    return np.arccos(np.clip(c, -1.0, 1.0)), j


def _kabsch(a, b, w=None):
    """Rotation R minimising sum w |R a_i - b_i|^2 (a, b: (n, 3))."""
    w = np.ones(len(a)) if w is None else w
    h = (a * w[:, None]).T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


@dataclass
class FlashOrientation:
    """Orientation of the ball at one flash from its markers alone (:func:`orient_flash`).

    Attributes
    ----------
    ball2world : ndarray, shape (3, 3)
        NaN when undetermined (fewer than 2 usable markers).
    cost : float
        Robust cost ``sum min(D_M, cap)^2`` (rad^2) of the best hypothesis.
    n_inliers : int
        Markers within ``cap`` of a model marker of their type.
    rms_deg : float
        RMS angle of the inliers to their model markers.
    assigned : ndarray of int, shape (n,)
        Model marker of each observation.
    runner_up_cost : float
        Cost of the best hypothesis more than ``distinct_deg`` away (inf if none): close to
        ``cost`` means the flash alone is ambiguous.
    candidates : list of ndarray, shape (3, 3)
        The best distinct hypotheses, best first (starting points for the seed method).
    determined : bool
    """

    ball2world: np.ndarray
    cost: float
    n_inliers: int
    rms_deg: float
    assigned: np.ndarray
    runner_up_cost: float
    candidates: list = field(default_factory=list)
    determined: bool = True


def orient_flash(directions, types, layout: BallLayout | None = None, *, cap_deg: float = 8.0,
                 pair_tol_deg: float = 8.0, n_candidates: int = 4,
                 distinct_deg: float = 10.0) -> FlashOrientation:
    """Ball orientation from one flash's markers, by aligning marker types (no prior).

    Every pair of observed markers and every pair of model markers with the same two types and
    nearly the same angle between them (within ``pair_tol_deg``) give a hypothesis; each is
    scored with the capped cost ``sum_i min(D_M(i), cap)^2`` and the best few are refined by
    re-assigning nearest same-type markers and a weighted Kabsch alignment of the inliers.

    Parameters
    ----------
    directions : array_like, shape (n, 3)
        Observed marker directions from the ball centre, world frame.
    types : array_like, shape (n,)
        Type names or indices.
    layout : BallLayout, optional
    cap_deg : float
        Inlier threshold / cost cap (about 4-5 times the direction noise).
    pair_tol_deg : float
        Tolerance on the angle between two markers when pairing.
    n_candidates : int
        Distinct hypotheses kept in ``candidates``.
    distinct_deg : float
        Hypotheses closer than this (rotation angle) count as the same.

    Returns
    -------
    FlashOrientation
    """
    layout = _default_layout(layout)
    u = as_array(directions, (None, 3), "directions")
    t = layout.type_index(np.asarray(types, dtype=object).reshape(-1)) if len(u) else np.zeros(0, int)
    if len(t) != len(u):
        raise ValueError(f"types must have shape ({len(u)},), got {np.shape(types)}")
    nan3 = np.full((3, 3), np.nan)
    if len(u) < 2:
        return FlashOrientation(nan3, np.inf, 0, np.nan, np.full(len(u), -1), np.inf, [], False)
    u = _unit_rows(u, "directions")
    cap = np.radians(cap_deg)
    m = layout.directions
    # hypotheses: observed pair (a, b) -> model pair (i, j) of the same types and angle
    a_idx, b_idx = np.triu_indices(len(u), 1)
    cos_ab = np.einsum("ij,ij->i", u[a_idx], u[b_idx])
    ok = np.abs(cos_ab) < np.cos(np.radians(5.0))  # a pair must not be (anti)parallel
    a_idx, b_idx, cos_ab = a_idx[ok], b_idx[ok], cos_ab[ok]
    ang_model = np.arccos(np.clip(m @ m.T, -1, 1))
    hyp_a, hyp_b, hyp_i, hyp_j = [], [], [], []
    for a, b, c in zip(a_idx, b_idx, cos_ab):
        ii = np.flatnonzero(layout.types == t[a])
        jj = np.flatnonzero(layout.types == t[b])
        I, J = np.meshgrid(ii, jj, indexing="ij")
        I, J = I.ravel(), J.ravel()
        keep = (I != J) & (np.abs(ang_model[I, J] - np.arccos(np.clip(c, -1, 1))) < np.radians(pair_tol_deg))
        hyp_a += [a] * int(keep.sum())
        hyp_b += [b] * int(keep.sum())
        hyp_i += I[keep].tolist()
        hyp_j += J[keep].tolist()
    if not hyp_a:
        return FlashOrientation(nan3, np.inf, 0, np.nan, np.full(len(u), -1), np.inf, [], False)
    ha, hb, hi, hj = (np.array(x) for x in (hyp_a, hyp_b, hyp_i, hyp_j))
    R = _triads(u[ha], u[hb]) @ np.transpose(_triads(m[hi], m[hj]), (0, 2, 1))
    d, _ = _nearest_same_type(R, u, t, layout)
    cost = np.sum(np.minimum(d, cap) ** 2, axis=1)
    order = np.argsort(cost)
    # refine the best distinct hypotheses
    refined = []
    for h in order:
        Rh = R[h]
        if any(_rot_angle(Rh, r) < np.radians(distinct_deg) for r, _ in refined):
            continue
        Rh, c = _refine(Rh, u, t, layout, cap)
        refined.append((Rh, c))
        if len(refined) >= max(n_candidates, 2) + 2:
            break
    refined.sort(key=lambda rc: rc[1])
    distinct = []
    for r, c in refined:
        if not any(_rot_angle(r, q) < np.radians(distinct_deg) for q, _ in distinct):
            distinct.append((r, c))
    best, best_cost = distinct[0]
    d, j = _nearest_same_type(best[None], u, t, layout)
    d, j = d[0], j[0]
    inl = d < cap
    rms = float(np.degrees(np.sqrt(np.mean(d[inl] ** 2)))) if inl.any() else np.nan
    runner = distinct[1][1] if len(distinct) > 1 else np.inf
    determined = int(inl.sum()) >= 2
    return FlashOrientation(best if determined else nan3, float(best_cost), int(inl.sum()), rms, j,
                            float(runner), [r for r, _ in distinct[:n_candidates]], determined)


def _rot_angle(Ra, Rb) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _refine(R, u, t, layout, cap, iters: int = 5):
    """Re-assign nearest same-type markers and realign the inliers (Kabsch)."""
    cost = np.inf
    for _ in range(iters):
        d, j = _nearest_same_type(R[None], u, t, layout)
        d, j = d[0], j[0]
        cost_new = float(np.sum(np.minimum(d, cap) ** 2))
        inl = d < cap
        if inl.sum() < 2 or cost_new >= cost - 1e-12:
            cost = min(cost, cost_new)
            break
        cost = cost_new
        R = _kabsch(layout.directions[j[inl]], u[inl])
    d, _ = _nearest_same_type(R[None], u, t, layout)
    return R, float(np.sum(np.minimum(d[0], cap) ** 2))
