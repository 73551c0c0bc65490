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

import threading
import time as _time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array, as_rng
from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout, _triad

RPM_PER_RAD_S = 60.0 / (2.0 * np.pi)


def _default_layout(layout):
    return BallLayout.seed() if layout is None else layout


def _unit_rows(a, name):
    n = np.linalg.norm(a, axis=1)
    if np.any(~(n > 0)):
        bad = np.flatnonzero(~(n > 0))
        raise ValueError(f"{name} must be non-zero and finite, rows {bad.tolist()} are not")
    return a / n[:, None]


def _expmap(rotvecs) -> np.ndarray:
    """Rotation matrices of rotation vectors, shape (..., 3) -> (..., 3, 3) (Rodrigues).

    Hand-written because it runs inside the least-squares residuals, where building scipy
    ``Rotation`` objects costs more than the rest of the residual.
    """
    v = np.asarray(rotvecs, float)
    th2 = np.einsum("...i,...i->...", v, v)
    th = np.sqrt(th2)
    small = th < 1e-6
    if small.any():
        ths = np.where(small, 1.0, th)
        a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
        b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    else:  # the same numbers without the series branch (most calls: small arrays, no zero angle)
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / (th * th)
    c = (1.0 - b * th2).reshape(-1)  # cos(theta)
    # assembled entry-major, (3, 3, N): every entry's products and sums run over one contiguous
    # row (the (N, 3, 3) layout's 3-long inner loops cost most of the time of the grid scan's
    # large calls); the same products and sums, so the same numbers
    vT = np.ascontiguousarray(v.reshape(-1, 3).T)
    bv = b.reshape(-1) * vT
    R = bv[:, None, :] * vT[None, :, :]  # (b v_i) v_j
    av = a.reshape(-1) * vT
    R[0, 0] += c
    R[1, 1] += c
    R[2, 2] += c
    R[0, 1] -= av[2]
    R[1, 0] += av[2]
    R[0, 2] += av[1]
    R[2, 0] -= av[1]
    R[1, 2] -= av[0]
    R[2, 1] += av[0]
    return np.ascontiguousarray(R.transpose(2, 0, 1)).reshape(v.shape + (3,))


def _skew(v) -> np.ndarray:
    """Cross-product matrices ``[v]x``, shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def _left_jacobian(rotvecs) -> np.ndarray:
    """Left Jacobian of SO(3), ``d exp(phi + e) = exp(J_l(phi) e) exp(phi)``: (..., 3) -> (..., 3, 3)."""
    v = np.asarray(rotvecs, float)
    th2 = np.einsum("...i,...i->...", v, v)
    th = np.sqrt(th2)
    small = th < 1e-4
    if small.any():
        ths = np.where(small, 1.0, th)
        a = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
        b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ths - np.sin(ths)) / (ths ** 3))
    else:
        a = (1.0 - np.cos(th)) / (th * th)
        b = (th - np.sin(th)) / (np.asarray(th) ** 3)  # ndarray power as above (a numpy scalar's differs)
    K = _skew(v)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def _phi_over_sin(c):
    """``arccos(c) / sqrt(1 - c^2)`` (1 at c = 1), for the log-map residual."""
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    small = s < 1e-6
    if not small.any():  # the same numbers without the series branch
        return np.arctan2(s, c) / s
    return np.where(small, 1.0 + (1.0 - c) / 3.0, np.arctan2(s, c) / np.where(small, 1.0, s))


def _dphi_over_sin(c):
    """Derivative of :func:`_phi_over_sin` with respect to c (-1/3 at c = 1)."""
    s2 = np.maximum(1.0 - c * c, 0.0)
    s = np.sqrt(s2)
    small = s < 1e-4
    if not small.any():  # the same numbers without the series branch
        return (-1.0 + np.arctan2(s, c) * c / s) / s2
    ss = np.where(small, 1.0, s)
    return np.where(small, -1.0 / 3.0, (-1.0 + np.arctan2(s, c) * c / ss) / np.where(small, 1.0, s2))


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
    radius : float or array_like, shape (M,)
        Sphere radius, m (per ray: e.g. the depth of each marker's image centroid,
        :attr:`stillcap.ball.layout.BallLayout.centroid_depth`).

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
    radius = np.asarray(radius, float)
    if radius.shape not in ((), (len(o),)) or not np.all(radius > 0):
        raise ValueError(f"radius must be positive, one value or one per ray, got {radius}")
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
            Ball centre per observation, or per flash (indexed by ``flash``), m; with as many
            rows as observations it is taken per observation.
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
def _nearest_same_type(R, u, t, layout):
    """For rotations R (H,3,3): angle (rad) from each observation u (n,3) of type t (n,) to the
    nearest rotated model marker of its type, and that marker's index: (H, n), (H, n)."""
    model = np.einsum("hab,jb->hja", R, layout.directions)  # (H, 12, 3)
    cos = np.einsum("na,hja->hnj", u, model)  # (H, n, 12)
    same = layout.types[None, :] == t[:, None]  # (n, 12)
    cos = np.where(same[None], cos, -2.0)
    # the largest cosine is the one at argmax; np.minimum/np.maximum clip with less overhead
    # than take_along_axis and np.clip (this runs ~10 times per flash in orient_flash)
    return np.arccos(np.minimum(np.maximum(cos.max(-1), -1.0), 1.0)), cos.argmax(-1)


def _kabsch(a, b, w=None):
    """Rotation R minimising sum w |R a_i - b_i|^2 (a, b: (n, 3))."""
    h = (a if w is None else a * w[:, None]).T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    # vt^T diag(1, 1, d) u^T with the diagonal applied as a column sign (exact, no product)
    v = vt.T.copy()
    v[:, 2] *= d
    return v @ u.T


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


_MODEL_TRIADS = {}


def _model_triads_t(m):
    """``_triad(m_i, m_j)^T`` of every ordered pair of layout markers, (n, n, 3, 3), kept per
    layout (orient_flash needs the same ones on every flash; row-wise the same numbers)."""
    key = m.tobytes()
    T = _MODEL_TRIADS.get(key)
    if T is None:
        n = len(m)
        i, j = np.divmod(np.arange(n * n), n)
        with np.errstate(invalid="ignore", divide="ignore"):  # i = j (never used) or antipodal
            T = np.transpose(_triad(m[i], m[j]), (0, 2, 1)).reshape(n, n, 3, 3)
        T.flags.writeable = False
        if len(_MODEL_TRIADS) >= 8:
            _MODEL_TRIADS.clear()
        _MODEL_TRIADS[key] = T
    return T


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
    tt = np.asarray(types)
    if (len(u) and tt.dtype.kind in "iu" and tt.ndim == 1 and tt.size
            and 0 <= tt.min() and tt.max() < layout.n_types):
        t = tt.astype(int)  # indices already (fit_spin's observations): no per-element lookup
    else:
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
    # all (observed pair, model marker i, model marker j) at once: i of a's type, j of b's, i != j,
    # model angle within pair_tol_deg of the observed one; np.nonzero keeps the order of the
    # loop over observed pairs, then i, then j
    n_m = len(m)
    keep = ((layout.types[None, :, None] == t[a_idx][:, None, None])
            & (layout.types[None, None, :] == t[b_idx][:, None, None])
            & ~np.eye(n_m, dtype=bool)[None]
            & (np.abs(ang_model[None] - np.arccos(np.clip(cos_ab, -1, 1))[:, None, None])
               < np.radians(pair_tol_deg)))
    hp, hi, hj = np.nonzero(keep)
    if not len(hp):
        return FlashOrientation(nan3, np.inf, 0, np.nan, np.full(len(u), -1), np.inf, [], False)
    ha, hb = a_idx[hp], b_idx[hp]
    R = _triad(u[ha], u[hb]) @ _model_triads_t(m)[hi, hj]
    d, jh = _nearest_same_type(R, u, t, layout)
    cost = np.sum(np.minimum(d, cap) ** 2, axis=1)
    order = np.argsort(cost)
    # refine the best distinct hypotheses
    refined = []  # (R, cost, angles, assigned markers)
    # hypotheses within distinct_deg of a refined one are skipped: the mask is updated once per
    # refined rotation for all hypotheses (instead of testing each hypothesis against the list)
    near = np.zeros(len(R), bool)
    for h in order:
        if near[h]:
            continue
        refined.append(_refine(R[h], u, t, layout, cap, nearest=(d[h:h + 1], jh[h:h + 1])))
        if len(refined) >= max(n_candidates, 2) + 2:
            break
        near |= _angles_to(refined[-1][0], R) < np.radians(distinct_deg)
    refined.sort(key=lambda rc: rc[1])
    close = _rot_angles([rc[0] for rc in refined]) < np.radians(distinct_deg)  # all pairs at once
    kept = []
    for i in range(len(refined)):
        if not close[i, kept].any():
            kept.append(i)
    distinct = [refined[i] for i in kept]
    best, best_cost, d, j = distinct[0]
    inl = d < cap
    rms = float(np.degrees(np.sqrt(np.mean(d[inl] ** 2)))) if inl.any() else np.nan
    runner = distinct[1][1] if len(distinct) > 1 else np.inf
    determined = int(inl.sum()) >= 2
    return FlashOrientation(best if determined else nan3, float(best_cost), int(inl.sum()), rms, j,
                            float(runner), [rc[0] for rc in distinct[:n_candidates]], determined)


def _rot_angle(Ra, Rb) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def _angles_to(R, Rs) -> np.ndarray:
    """:func:`_rot_angle` of ``R`` to each of the rotations ``Rs``: (k, 3, 3) -> (k,)."""
    c = (np.einsum("ab,kab->k", R, Rs) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def _rot_angles(Rs) -> np.ndarray:
    """Pairwise :func:`_rot_angle` of rotations (n, 3, 3) -> (n, n), in one pass
    (``trace(Ra^T Rb)`` is the sum of the elementwise product)."""
    Rs = np.asarray(Rs, float).reshape(-1, 3, 3)
    c = (np.einsum("iab,kab->ik", Rs, Rs) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def _refine(R, u, t, layout, cap, iters: int = 5, nearest=None):
    """Re-assign nearest same-type markers and realign the inliers (Kabsch); keep the best.

    ``nearest``: ``_nearest_same_type(R[None], u, t, layout)`` when known (orient_flash has it
    for every hypothesis). Returns ``(R, cost, angles (n,), assigned markers (n,))`` of the best."""
    d, j = _nearest_same_type(R[None], u, t, layout) if nearest is None else nearest
    best = (R, float(np.sum(np.minimum(d[0], cap) ** 2)), d[0], j[0])
    for _ in range(iters):
        inl = d[0] < cap
        if inl.sum() < 2:
            break
        R = _kabsch(layout.directions[j[0][inl]], u[inl])
        d, j = _nearest_same_type(R[None], u, t, layout)
        cost = float(np.sum(np.minimum(d[0], cap) ** 2))
        if cost >= best[1] - 1e-12:
            break
        best = (R, cost, d[0], j[0])
    return best


# ----------------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------------
@dataclass
class SpinResult:
    """Spin of a ball from its markers over several flashes.

    Attributes
    ----------
    spin : ndarray, shape (3,)
        Spin vector, rad/s, world frame (right-hand rule). The principal alias unless the fit
        was started at another one (module docstring).
    spin_rpm : float
        ``|spin|`` in revolutions per minute.
    axis : ndarray, shape (3,)
        ``spin / |spin|`` (NaN without spin).
    sigma_rpm : float
        1-sigma of the spin rate, rpm.
    sigma_axis_deg : float
        1-sigma of the axis direction per component (RMS over the two directions
        perpendicular to the axis), deg. The 95 % cone half-angle is about 2.45 times this.
    spin_covariance : ndarray, shape (3, 3)
        Covariance of ``spin``, (rad/s)^2.
    ball2world_t0 : ndarray, shape (3, 3)
        Orientation at ``t0`` (global fit; for the seed method the first determined flash
        rotated back with the spin).
    t0 : float
        Reference time, s.
    times : ndarray, shape (K,)
        Flash times, s.
    strobe_hz : float
        Flash frequency used for rates and aliasing.
    orientations : ndarray, shape (K, 3, 3)
        ``ball2world`` at each flash (NaN where the seed method could not determine it).
    residuals_deg : ndarray, shape (M,)
        Angle from each observation to the rotated model marker it was assigned to (NaN if
        its flash has no orientation).
    assigned : ndarray of int, shape (M,)
        Model marker of each observation (-1 if none).
    inliers : ndarray of bool, shape (M,)
        Observations used by the final fit.
    rms_deg : float
        RMS residual angle of the inliers.
    n_observations, n_inliers : int
    success : bool
    message : str
    method : str
        ``"global"`` or ``"seed"``.
    fit_time_s : float
    """

    spin: np.ndarray
    spin_rpm: float
    axis: np.ndarray
    sigma_rpm: float
    sigma_axis_deg: float
    spin_covariance: np.ndarray
    ball2world_t0: np.ndarray
    t0: float
    times: np.ndarray
    strobe_hz: float
    orientations: np.ndarray
    residuals_deg: np.ndarray
    assigned: np.ndarray
    inliers: np.ndarray
    rms_deg: float
    n_observations: int
    n_inliers: int
    success: bool
    message: str
    method: str
    fit_time_s: float = 0.0

    @property
    def rotation_per_interval_deg(self) -> float:
        """Rotation between consecutive flashes, deg (above 180: not the principal alias)."""
        return float(np.degrees(np.linalg.norm(self.spin) / self.strobe_hz))

    def orientation_at(self, t) -> Rotation:
        """``ball2world`` at time(s) ``t`` under constant spin: ``exp([w](t - t0)) R0``."""
        t = np.asarray(t, float)
        rv = np.multiply.outer(t - self.t0, self.spin)
        return Rotation.from_rotvec(rv) * Rotation.from_matrix(self.ball2world_t0)

    def angle_errors_deg(self, spin_true) -> tuple[float, float]:
        """``(rate error rpm, axis angle deg)`` against a known spin vector (tests, benchmarks)."""
        w = as_array(spin_true, (3,), "spin_true")
        rate = (np.linalg.norm(self.spin) - np.linalg.norm(w)) * RPM_PER_RAD_S
        ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(self.spin, w)), self.spin @ w))
        return float(rate), float(ang)

    def to_dict(self) -> dict:
        """Summary for JSON (units in the keys; NaN as None)."""
        def f(x):
            return float(x) if np.isfinite(x) else None
        return {"spin_rad_s": [f(x) for x in self.spin], "spin_rpm": f(self.spin_rpm),
                "axis": [f(x) for x in self.axis], "sigma_rpm": f(self.sigma_rpm),
                "sigma_axis_deg": f(self.sigma_axis_deg), "strobe_hz": f(self.strobe_hz),
                "rms_deg": f(self.rms_deg), "n_observations": int(self.n_observations),
                "n_inliers": int(self.n_inliers), "success": bool(self.success),
                "message": self.message, "method": self.method}


def _spin_summary(w, cov):
    """rate (rpm), axis, sigma_rpm, sigma_axis_deg from a spin vector and its covariance."""
    n = float(np.linalg.norm(w))
    if not n > 0:
        return 0.0, np.full(3, np.nan), float(np.sqrt(np.trace(cov) / 3) * RPM_PER_RAD_S), np.nan
    a = w / n
    var_rate = float(a @ cov @ a)
    P = np.eye(3) - np.outer(a, a)
    var_perp = float(np.trace(P @ cov @ P)) / 2.0
    return (n * RPM_PER_RAD_S, a, float(np.sqrt(max(var_rate, 0.0)) * RPM_PER_RAD_S),
            float(np.degrees(np.sqrt(max(var_perp, 0.0)) / n)))


def _failed(method, times, obs, message, t_start, strobe_hz):
    k = len(times)
    nan = np.nan
    m = len(obs)
    return SpinResult(np.full(3, nan), nan, np.full(3, nan), nan, nan, np.full((3, 3), nan),
                      np.full((3, 3), nan), float(times[0]), times, strobe_hz,
                      np.full((k, 3, 3), nan), np.full(m, nan), np.full(m, -1), np.zeros(m, bool),
                      nan, m, 0, False, message, method, _time.perf_counter() - t_start)


# ----------------------------------------------------------------------------------------------
# Global fit of one constant spin
# ----------------------------------------------------------------------------------------------
def _tangent_bases(u):
    """Two unit vectors (M, 3) each, perpendicular to the unit rows of u and to each other."""
    ref = np.where(np.abs(u[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(u, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(u, t1)


class _GlobalProblem:
    """Residuals of the constant-spin model for fixed marker assignments."""

    def __init__(self, times, obs, layout, t0):
        self.dt = times - t0
        self.obs = obs
        self.u = obs.directions
        self.t1, self.t2 = _tangent_bases(self.u)
        self.layout = layout
        self.flash = obs.flash
        self._same = layout.types[None, :] == obs.types[:, None]  # (M, 12): markers of each one's type

    def rotations(self, R0, w):
        """ball2world per flash, (K, 3, 3)."""
        return _expmap(np.outer(self.dt, w)) @ R0

    def assign(self, R0, w):
        """Nearest same-type model marker and its angle for every observation."""
        Rk = self.rotations(R0, w)[self.flash]  # (M, 3, 3)
        model = np.einsum("mab,jb->mja", Rk, self.layout.directions)  # (M, 12, 3)
        cos = np.where(self._same, np.einsum("ma,mja->mj", self.u, model), -2.0)
        j = cos.argmax(1)
        return j, np.arccos(np.minimum(np.maximum(cos.max(1), -1.0), 1.0))  # the cosine at j, clipped

    def _subset(self, sel):
        """``u``, ``t1``, ``t2`` and ``flash`` of the observations ``sel``: kept, since a fit asks
        for the same subset at every evaluation."""
        key = np.asarray(sel).tobytes()
        last = getattr(self, "_last_subset", None)
        if last is None or last[0] != key:
            last = (key, (self.u[sel], self.t1[sel], self.t2[sel], self.flash[sel]))
            self._last_subset = last
        return last[1]

    def _predict(self, x, R0_ref, j, sel):
        """Predicted marker directions p (m, 3), and the pieces the residuals and the Jacobian
        need: v (m, 3), A (m, 3, 3), the clipped cosine c (m,) between u and p, and
        ``_phi_over_sin(c)``.

        The last result is kept: least squares asks for the residuals and then the Jacobian
        at the same parameters (the key holds every input, also ``dt``, which
        :func:`_time_offset_cov` shifts)."""
        key = (np.asarray(x, float).tobytes(), np.asarray(R0_ref, float).tobytes(), np.asarray(j).tobytes(),
               np.asarray(sel).tobytes(), self.dt.tobytes())
        last = getattr(self, "_last", None)
        if last is not None and last[0] == key:
            return last[1]
        u, _, _, fl = self._subset(sel)
        # exp(delta) and the K flash rotations in one call (elementwise: the same numbers)
        E = _expmap(np.vstack([x[:3], np.outer(self.dt, x[3:])]))
        v = (E[0] @ R0_ref) @ self.layout.directions[j[sel]].T  # exp(delta) R0_ref m, (3, m)
        A = E[1:][fl]  # (m, 3, 3)
        p = np.einsum("mab,bm->ma", A, v)
        c = np.minimum(np.maximum(np.einsum("ma,ma->m", u, p), -1.0), 1.0)  # np.clip, less overhead
        out = (p, v.T, A, c, _phi_over_sin(c))
        for a in out:
            a.flags.writeable = False
        self._last = (key, out)
        return out

    def residuals(self, x, R0_ref, j, sel):
        """Log-map residuals (2 per observation, rad) at parameters x = (delta (3), w (3)):
        the angle between observation u and prediction p as a vector in u's tangent plane."""
        p, _, _, _, g = self._predict(x, R0_ref, j, sel)
        _, t1, t2, _ = self._subset(sel)
        r1 = g * np.einsum("ma,ma->m", t1, p)
        r2 = g * np.einsum("ma,ma->m", t2, p)
        return np.concatenate([r1, r2])

    def jacobian(self, x, R0_ref, j, sel):
        """Analytic Jacobian of :meth:`residuals`, shape (2 m, 6)."""
        p, v, A, c, g = self._predict(x, R0_ref, j, sel)
        u, t1, t2, fl = self._subset(sel)
        dt = self.dt[fl]
        # J_l of delta and per flash (then per observation: the same numbers, K instead of m
        # evaluations), in one call
        Jl = _left_jacobian(np.vstack([x[:3], np.outer(self.dt, x[3:])]))
        # dp/d(delta) = -A [v]x J_l(delta);  dp/dw = -[p]x J_l(w dt) dt
        dp_dd = -np.einsum("mab,mbc->mac", A, _skew(v)) @ Jl[0]
        dp_dw = -_skew(p) @ Jl[1:][fl] * dt[:, None, None]
        dp = np.concatenate([dp_dd, dp_dw], axis=2)  # (m, 3, 6)
        dg = _dphi_over_sin(c)
        dc = np.einsum("ma,mak->mk", u, dp)
        J1 = g[:, None] * np.einsum("ma,mak->mk", t1, dp) + (dg * (t1 * p).sum(1))[:, None] * dc
        J2 = g[:, None] * np.einsum("ma,mak->mk", t2, dp) + (dg * (t2 * p).sum(1))[:, None] * dc
        return np.concatenate([J1, J2], axis=0)


def _cluster_robust(cov, bread, J, r, flash):
    """``cov`` (independent residuals) widened by the cluster-robust sandwich covariance with
    the residuals grouped by flash (rows: first components of all observations, then second).

    Every direction gets the larger of the two variances: ``cov + V max(D, 0) V^T`` with
    ``V D V^T`` the eigen-decomposition of ``sandwich - cov`` (a sandwich from few flashes is
    noisy, so it only ever widens the model-based covariance).

    The sandwich is Bell and McCaffrey's CR2: each flash's residuals are divided by
    ``(I - H_gg)^(1/2)`` (``H_gg`` its block of the hat matrix ``J (J^T J)^-1 J^T``) before the
    meat is summed. The least-squares residuals of a flash are smaller than its errors by about
    its leverage (``p / G`` on average: 6 parameters over 15-25 flashes, 0.25-0.4), which the
    plain CR1 factor ``G / (G - 1) * (n - 1) / (n - p)`` (~1.1) did not make up for: the spin
    axis errors were ~1.15x their sigma (issue 3; ``docs/pitch.md``, "Spin").
    """
    fl = np.concatenate([flash, flash])
    groups, idx = np.unique(fl, return_inverse=True)
    G, n, p = len(groups), len(r), J.shape[1]
    if G < 3 or n <= p:
        return cov
    order = np.argsort(idx, kind="stable")
    size = np.bincount(idx, minlength=G)
    bounds = np.concatenate([[0], np.cumsum(size)])
    S = np.empty((G, p))  # J_g^T (I - H_gg)^(-1/2) r_g of every flash g
    # one small (rows of a flash)^2 eigen-problem per flash, batched over the flashes with the
    # same number of rows (fewer calls; each matrix's numbers are the same as one at a time)
    for n_g in np.unique(size):
        gs = np.flatnonzero(size == n_g)
        rows = order[bounds[gs][:, None] + np.arange(n_g)]  # (flashes, n_g)
        Jg = J[rows]
        w, U = np.linalg.eigh(np.eye(n_g) - Jg @ bread @ np.swapaxes(Jg, 1, 2))
        # (I - H_gg)^(-1/2) r_g; a flash that alone determines a direction (leverage ~1) is
        # capped at 100x instead of dividing by ~0
        ut_r = np.swapaxes(U, 1, 2) @ r[rows][:, :, None]
        rt = U @ (ut_r / np.sqrt(np.clip(w, 1e-4, None))[:, :, None])
        S[gs] = (np.swapaxes(Jg, 1, 2) @ rt)[:, :, 0]
    meat = (S[:, :, None] * S[:, None, :]).sum(axis=0)  # sum of outer(s_g, s_g), in flash order
    sand = bread @ meat @ bread
    d, V = np.linalg.eigh(0.5 * ((sand - cov) + (sand - cov).T))
    return cov + (V * np.clip(d, 0.0, None)) @ V.T


def _time_offset_cov(prob, x, R0, j, sel, bread, J, time_groups, time_group_sigma):
    """Covariance of (delta, w) from uncertain clock offsets of flash groups: linearised,
    ``dx = -(J^T J)^-1 J^T dr/d(offset)`` with ``dr/d(offset)`` by central differences."""
    groups = np.asarray(time_groups, int)
    sig = np.atleast_1d(np.asarray(time_group_sigma, float))
    if len(groups) != len(prob.dt):
        raise ValueError(f"time_groups must have one entry per flash ({len(prob.dt)}), got shape {groups.shape}")
    out = np.zeros((J.shape[1], J.shape[1]))
    dt0 = prob.dt.copy()
    try:
        for gi, sg in enumerate(sig, start=1):
            on = groups == gi
            if not (on.any() and np.isfinite(sg) and sg > 0):
                continue
            h = max(float(sg), 1e-6)
            prob.dt = dt0 + h * on
            rp = prob.residuals(x, R0, j, sel)
            prob.dt = dt0 - h * on
            rm = prob.residuals(x, R0, j, sel)
            dx = -bread @ (J.T @ ((rp - rm) / (2.0 * h)))
            out += sg ** 2 * np.outer(dx, dx)
    finally:
        prob.dt = dt0
    return out


def _solve_global(prob, R0, w, *, loss, f_scale, x_scale, max_outer, sel=None, assigned=None):
    """Outer loop: assign nearest same-type markers, robust least squares, repeat.

    ``assigned``: ``prob.assign(R0, w)`` when the caller has it already."""
    m = len(prob.u)
    sel = np.ones(m, bool) if sel is None else sel
    j_prev = None
    res = None
    jd = assigned
    for _ in range(max_outer):
        j, d = prob.assign(R0, w) if jd is None else jd
        jd = (j, d)
        if j_prev is not None and np.array_equal(j[sel], j_prev[sel]):
            break  # (j, d) is the assignment at the solution
        j_prev = j
        res = least_squares(prob.residuals, np.concatenate([np.zeros(3), w]), jac=prob.jacobian,
                            args=(R0, j, sel), loss=loss, f_scale=f_scale, x_scale=x_scale,
                            xtol=1e-9, ftol=1e-9, gtol=1e-9, max_nfev=100)
        R0 = _expmap(res.x[:3]) @ R0
        w = res.x[3:].copy()
        jd = None
    j, d = prob.assign(R0, w) if jd is None else jd
    return R0, w, j, d, res


def _consensus_rotations(Rs, tol):
    """Index set of the largest group of rotations within ``tol`` (rad) of one of them."""
    n = len(Rs)
    if n == 0:
        return np.zeros(0, int)
    ang = _rot_angles(Rs)
    support = (ang < tol).sum(1)
    best = int(np.argmax(support))
    return np.flatnonzero(ang[best] < tol)


def _mean_rotation(Rs):
    return Rotation.from_matrix(np.asarray(Rs)).mean().as_matrix()


def _per_flash_inits(times, flash_fit, period, t0, n_hyp: int = 3):
    """Constant-spin starting points from per-flash type alignments (principal alias).

    The relative rotations of flashes one interval apart, over the two best hypotheses of
    each flash (a flash showing few markers can be ambiguous), are grouped; the best-supported
    groups give spins, and the flash orientations rotated back to ``t0`` give ``R0``.
    """
    keys = sorted(flash_fit)
    rel, who = [], []
    for a, b in zip(keys[:-1], keys[1:]):
        if times[b] - times[a] < 1.5 * period:  # one interval: the principal rotation is meaningful
            for Rb in flash_fit[b].candidates[:2]:
                for Ra in flash_fit[a].candidates[:2]:
                    rel.append(Rb @ Ra.T)
                    who.append(a)
    if not rel:
        return []
    tol = np.radians(15.0)
    ang = _rot_angles(rel)
    who = np.array(who)
    support = np.array([len(set(who[ang[i] < tol])) for i in range(len(rel))])
    out, used = [], np.zeros(len(rel), bool)
    for i in np.argsort(-support, kind="stable"):
        if used[i]:
            continue
        grp = ang[i] < tol
        used |= grp
        w0 = Rotation.from_matrix(_mean_rotation([rel[g] for g in np.flatnonzero(grp)])).as_rotvec() / period
        back = _expmap((-w0)[None, :] * (times[keys] - t0)[:, None])  # all flashes in one call
        R0s = [back[i] @ R for i, k in enumerate(keys) for R in flash_fit[k].candidates[:2]]
        idx = _consensus_rotations(R0s, np.radians(20.0))
        out.append((_mean_rotation([R0s[g] for g in idx]), w0))
        if len(out) >= n_hyp:
            break
    return out


def _coarse_grid(step_deg):
    """The coarse grid of rotations per interval of :func:`_grid_inits`: a cubic grid of spacing
    ``step_deg`` inside the ball ``|rho| <= pi`` (plus half a step), (G, 3)."""
    h = np.radians(step_deg)
    n = int(np.ceil(np.pi / h))
    g = np.arange(-n, n + 1) * h
    coarse = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return coarse[np.linalg.norm(coarse, axis=1) <= np.pi + 0.5 * h]


_COARSE_ROTATIONS = {}
_COARSE_LOCK = threading.Lock()
# ~0.6 MB per entry at 15 deg; a pitch's steps take 10-20 entries (times with rounding noise
# give several keys per integer step): 64 entries (~38 MB) keep the last few pitches' steps
_COARSE_CACHE_SIZE = 64


def _coarse_grid_rotations(step_deg, step):
    """``exp(rho step)`` of every coarse grid point ``rho``, (G, 9) row-major: cached, since the
    grid is fixed and the steps (flash time minus anchor time over the period) are small integers
    that recur from pitch to pitch; the same numbers as computing them anew (elementwise)."""
    key = (float(step_deg), float(step))
    with _COARSE_LOCK:  # the pipeline may fit several balls on threads
        E = _COARSE_ROTATIONS.pop(key, None)
        if E is not None:
            _COARSE_ROTATIONS[key] = E  # reinserted last: dicts keep insertion order
            return E
    E = _expmap(_coarse_grid(step_deg) * step).reshape(-1, 9)
    E.flags.writeable = False
    with _COARSE_LOCK:
        while len(_COARSE_ROTATIONS) >= _COARSE_CACHE_SIZE:  # least recently used out
            del _COARSE_ROTATIONS[next(iter(_COARSE_ROTATIONS))]
        _COARSE_ROTATIONS[key] = E
    return E


def _capped_sq_angles(c, cap):
    """``min(arccos(clip(c, -1, 1)), cap) ** 2`` elementwise: the arccos only where it can be
    below the cap (most cosines of a grid scan are far from every marker: cap^2 then)."""
    out = np.full(c.shape, cap * cap)
    near = c > np.cos(cap) - 1e-9  # arccos(c) > cap elsewhere, with margin for rounding
    out[near] = np.minimum(np.arccos(np.clip(c[near], -1, 1)), cap) ** 2
    return out


def _grid_inits(prob, times, period, anchors, t0, cap, step_deg, n_keep):
    """Best constant spins from a grid over the rotation per interval ``rho`` (|rho| <= pi).

    For each anchor (a flash k_a and an orientation R_a of it) the orientation at flash k is
    ``exp(rho (t_k - t_a) / T) R_a``; the capped cost over all observations is scanned on a
    coarse grid, the best cells are refined on a finer local grid.
    """
    lay = prob.layout
    same = [np.flatnonzero(lay.types == t) for t in range(lay.n_types)]
    width = max(len(s) for s in same)
    cand = np.full((lay.n_types, width), -1)
    for t, s in enumerate(same):
        cand[t, :len(s)] = s
    cand = cand[prob.obs.types]  # (M, c): model markers of each observation's type, -1 = padding
    pad = cand < 0
    mdl = lay.directions[np.maximum(cand, 0)]  # (M, c, 3)
    u, fl = prob.u, prob.flash

    flashes = [(k, np.flatnonzero(fl == k)) for k in np.unique(fl)]
    n_c = cand.shape[1]
    # a padded candidate gets cos = 0 (a zero column) instead of -1: with cap <= 90 deg both are
    # capped, the same cost; the scan then needs no masking pass
    zero_pad = cap <= 0.5 * np.pi

    def costs(rho, k_a, R_as, coarse_step=None):
        """Capped costs (len(R_as), G) of the grid points rho for anchors (k_a, R_a) of one flash:
        the rotations exp(rho (t_k - t_a) / T), the scan's main cost, are shared by the anchors
        (and with ``coarse_step``, when rho is ``_coarse_grid(coarse_step)``, by every call: cached
        per step)."""
        steps = (times - times[k_a]) / period
        Wks = []
        for R_a in R_as:
            body = np.swapaxes(mdl @ R_a.T, 1, 2)  # (M, 3, c): R_a m_j as columns
            # cos(observation m, candidate marker c) = (E^T u_m) . (R_a m_c) = sum_ab E_ab u_m,a (R_a m_c)_b
            # with E = exp(rho (t_k - t_a) / T) of the observation's flash k: per flash one matrix
            # product (G, 9) @ (9, c M_k) over all grid points, instead of gathering a 3x3 matrix per
            # grid point and observation (the cost of this scan is in the gathering, not the sums)
            Wuv = (u[:, :, None, None] * body[:, None, :, :]).reshape(len(u), 9, n_c)
            if zero_pad:
                Wuv = np.where(pad[:, None, :], 0.0, Wuv)
            # columns candidate-major per flash: each candidate's cosines are a contiguous block
            Wks.append([(k, idx, np.ascontiguousarray(Wuv[idx].transpose(1, 2, 0)).reshape(9, -1))
                        for k, idx in flashes])
        out = np.empty((len(R_as), len(rho)))
        chunk = 1024  # grid points at a time (the scan's arrays stay in the CPU cache)
        for s in range(0, len(rho), chunk):
            if coarse_step is not None:
                Ek = {k: _coarse_grid_rotations(coarse_step, steps[k])[s:s + chunk] for k, _ in flashes}
            else:  # only the flashes with markers
                ks = [k for k, _ in flashes]
                E = _expmap(steps[ks][:, None, None] * rho[None, s:s + chunk, :])  # (K', G, 3, 3)
                Ek = {k: E[i].reshape(-1, 9) for i, k in enumerate(ks)}
            G = min(chunk, len(rho) - s)
            for ia, Wk in enumerate(Wks):
                best = np.empty((G, len(u)))
                for k, idx, W in Wk:
                    cos = (Ek[k] @ W).reshape(G, n_c, len(idx))
                    if not zero_pad:
                        cos = np.where(pad[idx].T[None], -1.0, cos)
                    m = cos[:, 0].copy()
                    for j in range(1, n_c):  # elementwise over contiguous blocks: faster than .max(1)
                        np.maximum(m, cos[:, j], out=m)
                    best[:, idx] = m
                out[ia, s:s + chunk] = _capped_sq_angles(best, cap).sum(axis=1)
        return out

    h = np.radians(step_deg)
    coarse = _coarse_grid(step_deg)
    f = np.arange(-2, 3) * (h / 4)
    local = np.stack(np.meshgrid(f, f, f, indexing="ij"), -1).reshape(-1, 3)
    found = []
    # the coarse scan of anchors of the same flash at once (they share its rotations)
    by_flash = {}
    for k_a, R_a in anchors:
        by_flash.setdefault(k_a, []).append(R_a)
    coarse_costs = {k_a: costs(coarse, k_a, R_as, step_deg) for k_a, R_as in by_flash.items()}
    seen = {k_a: 0 for k_a in by_flash}
    for k_a, R_a in anchors:
        c = coarse_costs[k_a][seen[k_a]]
        seen[k_a] += 1
        best = coarse[np.argsort(c)[:20]]
        fine = (best[:, None, :] + local[None]).reshape(-1, 3)
        cf = costs(fine, k_a, [R_a])[0]
        for i in np.argsort(cf)[:40]:
            found.append((cf[i], fine[i], (k_a, R_a)))
    found.sort(key=lambda x: x[0])
    out, kept = [], []
    for c, rho, (k_a, R_a) in found:
        if any(np.linalg.norm(rho - r) < h for r in kept):
            continue
        kept.append(rho)
        w = rho / period
        out.append((_expmap(-w * (times[k_a] - t0)) @ R_a, w))
        if len(out) >= n_keep:
            break
    return out


def fit_spin(times, observations, layout: BallLayout | None = None, *, t0: float | None = None,
             strobe_hz: float | None = None, spin_init=None, ball2world_init=None,
             init: str = "auto", loss: str = "soft_l1", f_scale_deg: float = 3.0,
             outlier_deg: float | None = None, cap_deg: float = 8.0, max_outer: int = 10,
             grid_step_deg: float = 15.0, time_groups=None, time_group_sigma=None,
             stop_fraction: float | None = None) -> SpinResult:
    """Fit one constant spin to all flashes' markers (robust least squares, SPEC "beyond").

    Model: ``R(t) = exp([w] (t - t0)) R0`` (``ball2world``); residuals: the angle (as a 2-D
    log-map vector in the tangent plane of the observation) between each observed marker
    direction and the rotated model marker of its type it is assigned to (the nearest;
    assignments are renewed until they stop changing). ``scipy.optimize.least_squares`` with a
    robust ``loss`` downweights mis-typed or misplaced markers; observations further than
    ``outlier_deg`` from their marker are then dropped and a plain least-squares polish gives
    the covariance: in every direction the larger of
    ``s^2 (J^T J)^-1`` (``s^2`` the residual variance per degree of freedom) and the
    cluster-robust "sandwich" ``(J^T J)^-1 (sum_k J_k^T r_k r_k^T J_k) (J^T J)^-1`` with the
    residuals grouped by flash: the markers of one flash share the error of that flash's ball
    centre (a 0.5 mm centre error turns every marker direction by up to 0.8 deg), which the
    independent-residual formula ignores. With ``time_groups`` / ``time_group_sigma`` the
    uncertainty of clock offsets (flashes of another stereo pair placed on the reference clock
    by a fitted offset) is propagated too: ``dw/d(offset)`` by central differences of the
    residuals, ``cov += sigma^2 g g^T`` per group.

    Starting points (``init``): ``"per_flash"`` aligns each flash's markers by type
    (:func:`orient_flash`) and groups the relative rotations of consecutive flashes (over the
    two best alignments of each flash) into up to three spin hypotheses, each with the consensus
    of the implied initial orientations; ``"grid"`` anchors on the flash with the most markers
    and scans the rotation per interval over a grid (``grid_step_deg``, refined locally) for the
    lowest capped cost; ``"auto"`` uses ``per_flash`` and adds the grid when that fails, leaves
    more than 10 % outliers or fewer than 3 flashes identify the ball unambiguously on their
    own. The start with the lowest capped cost after fitting wins. ``spin_init`` (e.g. an alias
    candidate) overrides both.

    Parameters
    ----------
    times : array_like, shape (K,)
        Flash times, s, strictly increasing (a missed flash leaves a gap).
    observations : MarkerObservations or sequence of (directions (n_k, 3), types (n_k,))
        Marker directions from the ball centre, world frame, with their types.
    layout : BallLayout, optional
        Default the seed's 12-marker ball.
    t0 : float, optional
        Reference time of ``ball2world_t0`` (default ``times[0]``).
    strobe_hz : float, optional
        Default ``1 / min(diff(times))``.
    spin_init : array_like, shape (3,), optional
        Start at this spin vector (rad/s): the fit stays at its alias.
    ball2world_init : array_like, shape (3, 3), optional
        Start at this orientation at ``t0`` (with ``spin_init``).
    init : {"auto", "per_flash", "grid"}
    loss : str
        ``least_squares`` loss of the robust stage (``"soft_l1"``, ``"cauchy"``, ``"huber"``,
        ``"linear"``).
    f_scale_deg : float
        Residual size where the robust loss starts to flatten, deg.
    outlier_deg : float, optional
        Observations further than this from their marker are outliers; default
        ``max(4 sigma, 1 deg)`` with ``sigma`` the robust (MAD) residual scale.
    cap_deg : float
        Cost cap of the per-flash alignment and of the grid scan, deg.
    max_outer : int
        Assignment / fit rounds.
    grid_step_deg : float
        Grid spacing of the rotation per interval, deg.
    time_groups : array_like of int, shape (K,), optional
        Clock of each flash (0 = exact times, g >= 1: times shifted by a common, uncertain
        offset ``g``).
    time_group_sigma : array_like, shape (G,), optional
        1-sigma of the offset of groups 1..G, s (added to the spin covariance).
    stop_fraction : float, optional
        Skip the other starts when the first one, after fitting, has this fraction of the
        observations within ``cap_deg`` of their markers (the pitch pipeline uses 0.9: on the
        27 benchmark pitches of issue 3 the first per-flash start was then always the best or
        reached the same minimum as the best). Default: try every start.

    Returns
    -------
    SpinResult
        ``method="global"``; ``success`` False with a message when there are too few markers.
    """
    t_start = _time.perf_counter()
    layout = _default_layout(layout)
    times, obs = _check_inputs(times, observations, layout)
    if init not in ("auto", "per_flash", "grid"):
        raise ValueError(f"init must be 'auto', 'per_flash' or 'grid', got {init!r}")
    period = strobe_period(times) if strobe_hz is None else 1.0 / float(strobe_hz)
    if not period > 0:
        raise ValueError(f"strobe_hz must be positive, got {strobe_hz}")
    f = 1.0 / period
    t0 = float(times[0]) if t0 is None else float(t0)
    counts = obs.counts(len(times))
    if len(obs) < 4 or np.count_nonzero(counts) < 2:
        return _failed("global", times, obs, f"too few markers: {len(obs)} observations on "
                       f"{np.count_nonzero(counts)} flashes (need >= 4 on >= 2)", t_start, f)
    cap = np.radians(cap_deg)
    prob = _GlobalProblem(times, obs, layout, t0)
    span = max(float(np.max(np.abs(times - t0))), period)
    x_scale = np.array([1.0, 1.0, 1.0] + [1.0 / span] * 3)
    f_scale = np.radians(f_scale_deg)

    def run(start_list, stop=None):
        best = None
        for R0, w in start_list:
            R0f, wf, j, d, res = _solve_global(prob, R0, w, loss=loss, f_scale=f_scale,
                                               x_scale=x_scale, max_outer=max_outer)
            c = float(np.sum(np.minimum(d, cap) ** 2))
            if best is None and stop is not None and np.mean(d < cap) >= stop:
                return (c, R0f, wf, j, d)  # the first start explains nearly every marker
            if best is None or c < best[0]:
                best = (c, R0f, wf, j, d)
        return best

    first = None
    if spin_init is not None and ball2world_init is not None:
        # a full start (e.g. the orientation of an earlier fit of the same ball): when it explains
        # 90 % of the markers the per-flash alignments and the other starts are not needed
        first = run([(as_array(ball2world_init, (3, 3), "ball2world_init"),
                      as_array(spin_init, (3,), "spin_init"))])
        if np.mean(first[4] < cap) >= 0.9:
            return _finish_global(prob, obs, times, first, spin_init, period, t0, f, cap, outlier_deg,
                                  max_outer, x_scale, time_groups, time_group_sigma, t_start)

    flash_fit = {}
    for k in np.flatnonzero(counts >= 2):
        fo = orient_flash(*obs.of_flash(k), layout, cap_deg=cap_deg)
        if fo.determined:
            flash_fit[int(k)] = fo
    anchors_order = sorted(flash_fit, key=lambda k: (-flash_fit[k].n_inliers, flash_fit[k].cost))

    starts = []
    if spin_init is not None:
        w_init = as_array(spin_init, (3,), "spin_init")
        for k in anchors_order[:2]:
            for Rk in flash_fit[k].candidates[:2]:
                starts.append((Rotation.from_rotvec(-w_init * (times[k] - t0)).as_matrix() @ Rk, w_init))
        if not starts and first is None:
            return _failed("global", times, obs, "no flash with 2 identifiable markers to anchor "
                           "spin_init", t_start, f)
    elif init in ("auto", "per_flash"):
        starts += _per_flash_inits(times, flash_fit, period, t0)

    best = run(starts, stop_fraction) if starts else None
    if first is not None and (best is None or first[0] <= best[0]):
        best = first
    # a flash is unambiguous when its runner-up alignment is clearly worse
    n_clear = sum(int(fo.runner_up_cost - fo.cost > 0.25 * cap ** 2) for fo in flash_fit.values())
    need_grid = spin_init is None and (init == "grid" or (init == "auto" and (
        best is None or np.mean(best[4] < cap) < 0.9 or n_clear < 3)))
    if need_grid and anchors_order:
        anchors = [(anchors_order[0], Rk) for Rk in flash_fit[anchors_order[0]].candidates[:2]]
        grid = _grid_inits(prob, times, period, anchors, t0, cap, grid_step_deg, n_keep=3)
        gbest = run(grid)
        if gbest is not None and (best is None or gbest[0] < best[0]):
            best = gbest
    if best is None:
        return _failed("global", times, obs, "no flash with 2 identifiable markers: cannot start "
                       "the fit (pass spin_init and ball2world_init)", t_start, f)
    return _finish_global(prob, obs, times, best, spin_init, period, t0, f, cap, outlier_deg, max_outer,
                          x_scale, time_groups, time_group_sigma, t_start)


def _finish_global(prob, obs, times, best, spin_init, period, t0, f, cap, outlier_deg, max_outer, x_scale,
                   time_groups, time_group_sigma, t_start) -> SpinResult:
    """:func:`fit_spin` after the robust stage: outliers, least-squares polish, covariance."""
    _, R0, w, j, d = best
    assigned = (j, d)  # at (R0, w)
    if spin_init is None and np.linalg.norm(w) * period > np.pi:
        # the same rotation per interval the short way round: report the principal alias
        w = Rotation.from_rotvec(w * period).as_rotvec() / period
        assigned = None

    # outliers, then a plain least-squares polish on the inliers for the covariance
    r = prob.residuals(np.concatenate([np.zeros(3), w]), R0, j, np.ones(len(obs), bool))
    sigma_robust = float(np.median(np.abs(r)) / 0.6745)
    thr = np.radians(outlier_deg) if outlier_deg is not None else max(4.0 * sigma_robust, np.radians(1.0))
    inl = d < thr
    message = "ok"
    if inl.sum() < 4:
        inl = d <= np.sort(d)[min(3, len(d) - 1)]
        message = "few inliers"
    R0, w, j, d, res = _solve_global(prob, R0, w, loss="linear", f_scale=1.0, x_scale=x_scale,
                                     max_outer=max_outer, sel=inl, assigned=assigned)
    x = np.concatenate([np.zeros(3), w])
    r = prob.residuals(x, R0, j, inl)
    J = prob.jacobian(x, R0, j, inl)
    dof = max(len(r) - 6, 1)
    s2 = float(r @ r) / dof
    bread = np.linalg.pinv(J.T @ J)
    cov = s2 * bread
    cov = _cluster_robust(cov, bread, J, r, prob.flash[inl])
    if time_groups is not None and time_group_sigma is not None:
        cov = cov + _time_offset_cov(prob, x, R0, j, inl, bread, J, time_groups, time_group_sigma)
    cov_w = cov[3:, 3:]
    rate, axis, sig_r, sig_a = _spin_summary(w, cov_w)
    success = bool(res is None or res.status > 0) and int(inl.sum()) >= 4 and np.all(np.isfinite(w))
    if len(r) - 6 < 2:
        message = "as many parameters as residuals: no uncertainty"
        sig_r = sig_a = np.nan
    return SpinResult(
        spin=w, spin_rpm=rate, axis=axis, sigma_rpm=sig_r, sigma_axis_deg=sig_a,
        spin_covariance=cov_w, ball2world_t0=R0, t0=t0, times=times, strobe_hz=f,
        orientations=prob.rotations(R0, w), residuals_deg=np.degrees(d), assigned=j, inliers=inl,
        rms_deg=float(np.degrees(np.sqrt(np.mean(d[inl] ** 2)))), n_observations=len(obs),
        n_inliers=int(inl.sum()), success=success, message=message, method="global",
        fit_time_s=_time.perf_counter() - t_start)


# ----------------------------------------------------------------------------------------------
# The seed's per-flash method
# ----------------------------------------------------------------------------------------------
def _euler_xyz(x):
    """Rotation matrix of extrinsic 'xyz' Euler angles, as ``Rotation.from_euler("xyz", x)``."""
    cx, cy, cz = np.cos(x)
    sx, sy, sz = np.sin(x)
    # R = Rz @ Ry @ Rx  (extrinsic x, then y, then z)
    return np.array([
        [cy * cz, sx * sy * cz - cx * sz, cx * sy * cz + sx * sz],
        [cy * sz, sx * sy * sz + cx * cz, cx * sy * sz - sx * cz],
        [-sy, sx * cy, cx * cy],
    ])


def _seed_energy(R, u, t, layout, a1, a2, R_pred, cap):
    """a1 sum D_M^2 + a2 sum D_A^2 (angles in rad)."""
    e = 0.0
    if len(u):
        model = layout.directions @ R.T
        cos = np.where(layout.types[None, :] == t[:, None], u @ model.T, -2.0).max(1)
        d = np.arccos(np.clip(cos, -1.0, 1.0))
        if cap is not None:
            d = np.minimum(d, cap)
        e += a1 * float(d @ d)
    if a2 > 0 and R_pred is not None:
        ca = np.clip(np.einsum("ij,ij->j", R, R_pred), -1.0, 1.0)
        da = np.arccos(ca)
        e += a2 * float(da @ da)
    return e


def _powell_orientation(R_start, u, t, layout, a1, a2, R_pred, cap, xtol):
    """Powell over Euler angles (relative to the start, away from gimbal lock)."""
    def fun(x):
        return _seed_energy(_euler_xyz(x) @ R_start, u, t, layout, a1, a2, R_pred, cap)
    res = minimize(fun, np.zeros(3), method="Powell",
                   options={"xtol": xtol, "ftol": 1e-10, "maxfev": 4000})
    return _euler_xyz(res.x) @ R_start, float(res.fun)


def fit_spin_seed(times, observations, layout: BallLayout | None = None, *, a1: float = 1.0,
                  a2: float = 1.0, strobe_hz: float | None = None, cap_deg: float | None = None,
                  n_starts: int = 2, xtol: float = 1e-4) -> SpinResult:
    """The seed's spin estimate (section 4.4): per-flash orientations, then averaged rotations.

    Flashes are processed in time order. For flash ``k`` the orientation minimises
    ``E = a1 sum_i D_M(i)^2 + a2 sum_{j in x,y,z} D_A(j)^2`` (angles in rad): ``D_M(i)`` the
    angle from observed marker ``i`` to the nearest model marker of its type, ``D_A(j)`` the
    angle between ball axis ``j`` of ``R_k`` and of the prediction (the last determined
    orientation turned once more by the last relative rotation of two determined flashes one
    interval apart, scaled to the time step). ``a2 = 0`` until two orientations one interval
    apart are known (the seed's "first two"; over a gap the relative rotation could exceed half
    a turn and mislead). Those first two are the first consecutive flashes whose markers each
    identify the ball unambiguously (at least 3 inliers, no second alignment nearly as good),
    else with one such flash, else the first consecutive pair with an alignment: a wrong
    orientation there would mislead
    every later prediction. The flashes before them are then processed backwards.
    ``scipy.optimize.minimize(method="Powell")``
    runs over Euler angles (``xyz``, relative to each start, so away from gimbal lock) from the
    prediction and from the best type alignments of the flash's own markers
    (:func:`orient_flash`); the lowest ``E`` wins. A flash without markers takes the prediction;
    one whose orientation cannot be determined (fewer than 2 markers before a prediction
    exists) is left out (NaN).

    The relative rotations ``R_k R_{k-1}^T`` of consecutive determined flashes one strobe
    interval apart (each with at least one marker) give axis-angle pairs; axes are aligned to
    their principal direction (an axis flipped near half a turn becomes ``2 pi - angle`` about
    the opposite axis), the spin axis is their mean and the rate their mean angle times the
    strobe frequency. The 1-sigma values are the standard errors of those means.

    Parameters
    ----------
    times : array_like, shape (K,)
    observations : MarkerObservations or sequence of (directions, types)
    layout : BallLayout, optional
    a1, a2 : float
        Weights of the marker and prediction terms.
    strobe_hz : float, optional
        Default ``1 / min(diff(times))``.
    cap_deg : float, optional
        Cap ``D_M`` at this angle (a robust variant; the seed does not cap: ``None``).
    n_starts : int
        Type-alignment starts per flash besides the prediction.
    xtol : float
        Powell's tolerance on the Euler angles, rad.

    Returns
    -------
    SpinResult
        ``method="seed"``; ``orientations`` NaN where undetermined.
    """
    t_start = _time.perf_counter()
    layout = _default_layout(layout)
    times, obs = _check_inputs(times, observations, layout)
    if a1 <= 0 or a2 < 0:
        raise ValueError(f"need a1 > 0 and a2 >= 0, got a1={a1}, a2={a2}")
    period = strobe_period(times) if strobe_hz is None else 1.0 / float(strobe_hz)
    if not period > 0:
        raise ValueError(f"strobe_hz must be positive, got {strobe_hz}")
    f = 1.0 / period
    cap = None if cap_deg is None else np.radians(cap_deg)
    K = len(times)
    Rs = np.full((K, 3, 3), np.nan)
    measured = np.zeros(K, bool)
    align_cap = np.radians(8.0 if cap_deg is None else cap_deg)
    aligned = {}
    for k in np.flatnonzero(obs.counts(K) >= 2):
        aligned[int(k)] = orient_flash(*obs.of_flash(k), layout, cap_deg=np.degrees(align_cap))

    def clear(k):
        fo = aligned.get(k)
        return int(fo is not None and fo.determined and fo.n_inliers >= 3
                   and fo.runner_up_cost - fo.cost > 0.25 * align_cap ** 2)

    def solve(k, R_pred):
        """R_k minimising E from the prediction and the flash's own type alignments."""
        u, t = obs.of_flash(k)
        starts = [] if R_pred is None else [R_pred]
        if k in aligned:
            for R_c in aligned[k].candidates[:n_starts]:  # skip starts the prediction covers
                if all(_rot_angle(R_c, R_s) > np.radians(5.0) for R_s in starts):
                    starts.append(R_c)
        if R_pred is None and (len(u) < 2 or not starts):
            return None  # a2 = 0 and too few markers: undetermined
        if len(u) == 0:
            return R_pred  # no markers: the prediction
        a2k = a2 if R_pred is not None else 0.0
        best = None
        for R_s in starts:
            R_k, e = _powell_orientation(R_s, u, t, layout, a1, a2k, R_pred, cap, xtol)
            if best is None or e < best[1]:
                best = (R_k, e)
        return best[0]

    def run(seq, omega, last):
        """Process flashes in order ``seq``; ``omega`` the last relative rotation (rad/s) of
        two determined flashes one interval apart, ``last`` the last determined flash."""
        for k in seq:
            R_pred = None
            if omega is not None and last is not None:
                R_pred = _expmap(omega * (times[k] - times[last])) @ Rs[last]
            R_k = solve(k, R_pred)
            if R_k is None:
                continue
            Rs[k] = R_k
            measured[k] = len(obs.of_flash(k)[1]) >= 1
            if last is not None and abs(times[k] - times[last]) < 1.5 * period:
                omega = Rotation.from_matrix(R_k @ Rs[last].T).as_rotvec() / (times[k] - times[last])
            last = k

    # The seed starts with the first two flashes (a2 = 0). A wrong orientation there (a flash
    # whose few markers fit two frames) misleads every prediction after it, so start at the
    # first two consecutive flashes that each identify the ball on their own, go forward, then
    # back to the flashes before them.
    one = [k for k in range(K - 1) if times[k + 1] - times[k] < 1.5 * period
           and k in aligned and k + 1 in aligned]
    k0 = max(one, key=lambda k: (clear(k) + clear(k + 1), -k)) if one else 0
    run(range(k0, K), None, None)
    if k0 > 0 and np.isfinite(Rs[k0, 0, 0]):
        omega0 = None
        if k0 + 1 < K and np.isfinite(Rs[k0 + 1, 0, 0]) and times[k0 + 1] - times[k0] < 1.5 * period:
            omega0 = Rotation.from_matrix(Rs[k0 + 1] @ Rs[k0].T).as_rotvec() / (times[k0 + 1] - times[k0])
        run(range(k0 - 1, -1, -1), omega0, k0)
    det = [k for k in range(K) if np.isfinite(Rs[k, 0, 0])]

    # relative rotations of consecutive determined flashes one interval apart (a flash without
    # markers only repeats the prediction and adds nothing)
    pairs = [(a, b) for a, b in zip(det[:-1], det[1:])
             if times[b] - times[a] < 1.5 * period and measured[a] and measured[b]]
    if not pairs:
        pairs = [(a, b) for a, b in zip(det[:-1], det[1:]) if times[b] - times[a] < 1.5 * period]
    # residuals per observation at the per-flash orientations
    res_deg = np.full(len(obs), np.nan)
    assigned = np.full(len(obs), -1)
    for k in det:
        sel = obs.flash == k
        if sel.any():
            d, j = _nearest_same_type(Rs[k][None], obs.directions[sel], obs.types[sel], layout)
            res_deg[sel] = np.degrees(d[0])
            assigned[sel] = j[0]
    if not pairs:
        out = _failed("seed", times, obs, f"fewer than 2 consecutive flashes with an orientation "
                      f"({len(det)} determined)", t_start, f)
        out.orientations, out.residuals_deg, out.assigned = Rs, res_deg, assigned
        return out
    axes, angles, dts = [], [], []
    for a, b in pairs:
        rv = Rotation.from_matrix(Rs[b] @ Rs[a].T).as_rotvec()
        th = float(np.linalg.norm(rv))
        axes.append(rv / th if th > 0 else np.array([0.0, 0.0, 1.0]))
        angles.append(th)
        dts.append(times[b] - times[a])
    axes, angles, dts = np.array(axes), np.array(angles), np.array(dts)
    # principal direction of the axes (sign-free), then flip to agree with it
    _, _, vt = np.linalg.svd(axes * np.maximum(angles, 1e-9)[:, None])
    ref = vt[0]
    if np.sum(np.sign(axes @ ref) * angles) < 0:
        ref = -ref
    flip = axes @ ref < 0
    axes[flip] *= -1
    angles[flip] = 2 * np.pi - angles[flip]
    rates = angles / dts
    axis = axes.mean(0)
    axis /= np.linalg.norm(axis)
    rate = float(rates.mean())
    w = rate * axis
    n = len(rates)
    if n >= 2:
        sig_rate = float(rates.std(ddof=1) / np.sqrt(n))
        ang = np.arccos(np.clip(axes @ axis, -1, 1))
        sig_axis = float(np.sqrt(np.sum(ang ** 2) / (2 * (n - 1)) / n))
    else:
        sig_rate = sig_axis = np.nan
    cov = sig_rate ** 2 * np.outer(axis, axis) + (rate * sig_axis) ** 2 * (np.eye(3) - np.outer(axis, axis))
    k_first = det[0]
    R0 = Rotation.from_rotvec(-w * (times[k_first] - times[0])).as_matrix() @ Rs[k_first]
    inl = np.isfinite(res_deg) & (res_deg < (10.0 if cap_deg is None else cap_deg))
    return SpinResult(
        spin=w, spin_rpm=rate * RPM_PER_RAD_S, axis=axis, sigma_rpm=sig_rate * RPM_PER_RAD_S,
        sigma_axis_deg=float(np.degrees(sig_axis)), spin_covariance=cov, ball2world_t0=R0,
        t0=float(times[0]), times=times, strobe_hz=f, orientations=Rs, residuals_deg=res_deg,
        assigned=assigned, inliers=inl,
        rms_deg=float(np.sqrt(np.mean(res_deg[inl] ** 2))) if inl.any() else np.nan,
        n_observations=len(obs), n_inliers=int(inl.sum()), success=True,
        message="ok" if n >= 2 else "one interval only: no uncertainty", method="seed",
        fit_time_s=_time.perf_counter() - t_start)


# ----------------------------------------------------------------------------------------------
# Synthetic observations (tests, benchmarks, demos)
# ----------------------------------------------------------------------------------------------
def simulate_observations(times, ball2world_t0, spin, view_dirs, layout: BallLayout | None = None,
                          *, t0: float | None = None, noise_deg: float = 1.0,
                          margin_deg: float = 10.0, miss_rate: float = 0.0,
                          mistype_rate: float = 0.0, max_per_flash=None,
                          rng=None) -> MarkerObservations:
    """Marker observations of a ball spinning at constant ``spin`` seen from ``view_dirs``.

    Parameters
    ----------
    times : array_like, shape (K,)
        Flash times, s.
    ball2world_t0 : array_like, shape (3, 3)
        Orientation at ``t0``.
    spin : array_like, shape (3,)
        rad/s, world frame.
    view_dirs : array_like, shape (3,) or (C, 3)
        Directions from the ball toward each camera (or stereo pair), world frame: a marker
        is seen when it is within ``90 - margin_deg`` deg of one of them.
    layout : BallLayout, optional
    t0 : float, optional
        Default ``times[0]``.
    noise_deg : float
        1-sigma of each of the two tangent components of the direction error, deg (the RMS
        angular error is ``sqrt(2)`` times this).
    margin_deg : float
    miss_rate : float
        Probability that a visible marker is not detected.
    mistype_rate : float
        Probability that a detected marker gets a wrong (random other) type: an outlier.
    max_per_flash : array_like of int, shape (K,), optional
        At most this many markers on each flash (randomly kept), e.g. 0 or 1 for some flashes.
    rng : np.random.Generator or int, optional

    Returns
    -------
    MarkerObservations
    """
    rng = as_rng(rng)
    layout = _default_layout(layout)
    times = as_array(times, (None,), "times")
    R0 = as_array(ball2world_t0, (3, 3), "ball2world_t0")
    w = as_array(spin, (3,), "spin")
    v = np.atleast_2d(np.asarray(view_dirs, float))
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"view_dirs must have shape (3,) or (C, 3), got {np.shape(view_dirs)}")
    v = _unit_rows(v, "view_dirs")
    t0 = float(times[0]) if t0 is None else float(t0)
    caps = (None if max_per_flash is None
            else as_array(max_per_flash, (len(times),), "max_per_flash", dtype=int))
    Rk = (Rotation.from_rotvec(np.outer(times - t0, w)) * Rotation.from_matrix(R0)).as_matrix()
    sig = np.radians(noise_deg)
    fl, ty, di = [], [], []
    for k in range(len(times)):
        world = layout.directions @ Rk[k].T
        vis = np.any(world @ v.T > np.cos(np.radians(90.0 - margin_deg)), axis=1)
        vis &= rng.random(len(world)) >= miss_rate
        idx = np.flatnonzero(vis)
        if caps is not None and len(idx) > caps[k]:
            idx = np.sort(rng.choice(idx, size=max(int(caps[k]), 0), replace=False))
        u = world[idx]
        if len(u):
            t1, t2 = _tangent_bases(u)
            e = rng.normal(size=(len(u), 2)) * sig
            u = u * np.cos(np.linalg.norm(e, axis=1))[:, None] + (
                np.sinc(np.linalg.norm(e, axis=1) / np.pi)[:, None] * (e[:, :1] * t1 + e[:, 1:] * t2))
        t = layout.types[idx].copy()
        bad = rng.random(len(t)) < mistype_rate
        for i in np.flatnonzero(bad):
            t[i] = rng.choice([x for x in range(layout.n_types) if x != t[i]])
        fl.append(np.full(len(idx), k))
        ty.append(t)
        di.append(u.reshape(-1, 3))
    return MarkerObservations(np.concatenate(fl), np.concatenate(ty), np.concatenate(di))
