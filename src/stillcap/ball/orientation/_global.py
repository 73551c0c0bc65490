"""The global fit of one constant spin to all flashes' markers (:func:`fit_spin`): the residuals
and Jacobian of the model, robust least squares with re-assigned markers, the cluster-robust and
clock-offset covariance, and the starting points (per-flash alignments, or a grid over the
rotation per interval with its cache of the coarse grid's rotations)."""

from __future__ import annotations

import threading
import time as _time

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array
from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation._batched import (_observation_weights, _residual_ranks, _residuals_in_noise,
                                                _shifted_residuals)
from stillcap.ball.orientation._flash import _orient_flashes
from stillcap.ball.orientation._observations import _check_inputs, _default_layout, strobe_period
from stillcap.ball.orientation._photo_noise import apply_photo_noise
from stillcap.ball.orientation._result import SpinResult, _failed, _spin_summary
from stillcap.ball.orientation._so3 import (_consensus_rotations, _dphi_over_sin, _expmap, _left_jacobian,
                                           _mean_rotation, _phi_over_sin, _rot_angles, _sq_norms, _tangent_bases)


_NEXT, _NEXT2 = np.array([1, 2, 0]), np.array([2, 0, 1])  # cyclic component order of a cross product


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
        # per-observation weights: each residual pair (r1, r2) multiplied by W = L^T, L L^T the
        # observation's information in the (t1, t2) basis, scaled so that the median observation's
        # is about 1 (residuals stay in radians there; info_scale, px^2/rad^2, turns the fitted
        # residual scale into the centroid noise in pixels)
        self.W, self.info_scale = None, float("nan")
        if obs.information is not None and len(obs):
            W, scale = _observation_weights(self.t1[None], self.t2[None], obs.information)
            if W is not None:
                self.W, self.info_scale = W[0], float(scale[0])
        self.W_base = self.W
        self.noise_class = obs.noise_class
        self.class_scale = {}

    def estimate_class_noise(self, x, R0_ref, j, sel, min_obs: int = 4):
        """Each noise class's residual scale relative to class 0 (or to all observations when
        class 0 has fewer than ``min_obs``): the weights of class ``c`` are divided by its
        ``scale_c`` so that every class's weighted residuals have the same variance. A class with
        fewer than ``min_obs`` observations keeps scale 1. Returns ``{class: scale}``."""
        if self.W_base is None:
            return {}
        self.W = self.W_base
        cls = self.noise_class[sel]
        kinds = np.unique(cls)
        if len(kinds) < 2:
            self.class_scale = {}
            return {}
        e2 = self.observation_norms(x, R0_ref, j, sel) ** 2
        pooled = float(np.mean(e2))
        ref = float(np.mean(e2[cls == 0])) if np.count_nonzero(cls == 0) >= min_obs else pooled
        if not ref > 0:
            return {}
        scales = {}
        for c in kinds:
            n_c = int(np.count_nonzero(cls == c))
            scales[int(c)] = float(np.sqrt(np.mean(e2[cls == c]) / ref)) if n_c >= min_obs else 1.0
        f = np.array([1.0 / max(scales.get(int(c), 1.0), 1e-6) for c in self.noise_class])
        self.W = self.W_base * f[:, None, None]
        self.class_scale = scales
        return scales

    def _whiten(self, a1, a2, sel):
        """``W (a1, a2)`` per observation ``sel`` (rows of residuals or of the Jacobian); the entries
        of ``W[sel]`` are kept for the last ``W`` and ``sel`` (as :meth:`_subset`: the same numbers)."""
        if self.W is None:
            return a1, a2
        key, last = np.asarray(sel).tobytes(), getattr(self, "_last_weights", None)
        if last is None or last[0] is not self.W or last[1] != key:
            W = self.W[sel]
            self._last_weights = last = (self.W, key, W[:, 0, 0], W[:, 0, 1], W[:, 1, 1])
        w00, w01, w11 = last[2:] if a1.ndim == 1 else (w[:, None] for w in last[2:])
        return w00 * a1 + w01 * a2, w11 * a2

    def observation_norms(self, x, R0_ref, j, sel):
        """Length of each observation's (weighted) residual pair, shape (m,)."""
        r = self.residuals(x, R0_ref, j, sel)
        m = len(r) // 2
        return np.hypot(r[:m], r[m:])

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
        # exp(delta) and the K flash rotations in one call (elementwise: the same numbers); V, th2 kept (jacobian)
        V = np.vstack([x[:3], np.outer(self.dt, x[3:])])
        th2 = _sq_norms(V)
        E = _expmap(V, th2)
        if getattr(self, "_last_markers", (None,))[0] != key[2:4]:  # the assigned markers, kept per (j, sel)
            self._last_markers = (key[2:4], self.layout.directions[j[sel]].T)
        v = (E[0] @ R0_ref) @ self._last_markers[1]  # exp(delta) R0_ref m, (3, m)
        A = E[1:][fl]  # (m, 3, 3)
        p = np.einsum("mab,bm->ma", A, v)
        c = np.minimum(np.maximum(np.einsum("ma,ma->m", u, p), -1.0), 1.0)  # np.clip, less overhead
        out = (p, v.T, A, c, _phi_over_sin(c))
        for a in out + (V, th2):
            a.flags.writeable = False
        self._last = (key, out, (V, th2))
        return out

    def residuals(self, x, R0_ref, j, sel):
        """Log-map residuals (2 per observation, rad) at parameters x = (delta (3), w (3)):
        the angle between observation u and prediction p as a vector in u's tangent plane."""
        p, _, _, _, g = self._predict(x, R0_ref, j, sel)
        _, t1, t2, _ = self._subset(sel)
        r1 = g * np.einsum("ma,ma->m", t1, p)
        r2 = g * np.einsum("ma,ma->m", t2, p)
        return np.concatenate(self._whiten(r1, r2, sel))

    def jacobian(self, x, R0_ref, j, sel):
        """Analytic Jacobian of :meth:`residuals`, shape (2 m, 6)."""
        p, _, A, c, g = self._predict(x, R0_ref, j, sel)
        u, t1, t2, fl = self._subset(sel)
        # J_l of delta and per flash (then per observation: the same numbers, K instead of m
        # evaluations), in one call, of the rotation vectors _predict made (kept) for this x
        Jl = _left_jacobian(*self._last[2])
        # dp/d(delta) = -A [v]x J_l(delta) = -[p]x A J_l(delta) (A [v]x = [A v]x A);
        # dp/dw = -[p]x J_l(w dt) dt. Residual i of an observation is g (t_i . p), so its row
        # is q_i^T dp with q_i = g t_i + g'(c) (t_i . p) u, and q^T [p]x = (q x p)^T: both rows of
        # every observation from one (2 m, 3) cross product, no (m, 3, 6) products
        dg = _dphi_over_sin(c)
        q = np.concatenate([g[:, None] * t1 + (dg * np.einsum("ma,ma->m", t1, p))[:, None] * u,
                            g[:, None] * t2 + (dg * np.einsum("ma,ma->m", t2, p))[:, None] * u])
        p2 = np.concatenate([p, p])
        y = q[:, _NEXT] * p2[:, _NEXT2] - q[:, _NEXT2] * p2[:, _NEXT]  # q x p (np.cross: 3x the overhead)
        fl2 = np.concatenate([fl, fl])
        J = np.empty((len(q), 6))
        J[:, :3] = -np.einsum("ma,mab->mb", y, np.concatenate([A, A])) @ Jl[0]
        J[:, 3:] = -np.einsum("ma,mab->mb", y, Jl[1:][fl2]) * self.dt[fl2][:, None]
        if self.W is not None:
            m = len(J) // 2
            J = np.concatenate(self._whiten(J[:m], J[m:], sel))
        return J


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


def _pose_clusters(rotations, tol_rad: float, groups=None) -> np.ndarray:
    """A cluster label per flash: flashes of one clock group (``groups``, default all one) whose
    ball orientations (``ball2world``, (K, 3, 3)) lie within ``tol_rad`` of the cluster's first
    flash (in time order) share it.

    When the rotation per strobe interval is close to ``360 deg / n`` (1,600 rpm at 80 Hz: a
    third of a turn) every n-th flash shows the ball in nearly the same pose to the same
    cameras and light, and the markers' centroid errors that come with the pose (a marker cut
    by the shading's terminator or the limb, seen only on its lit side) repeat: those flashes'
    errors are one error, not n independent ones (issue 12, "everything varied" #18: a red
    marker at the terminator 2.1-2.9 px off in all five of its views, at flashes 1, 4 and 7 of
    the front pair)."""
    R = np.asarray(rotations, float)
    K = len(R)
    g = np.zeros(K, int) if groups is None else np.asarray(groups, int)
    ang = _rot_angles(R)
    lab = np.full(K, -1)
    for a in range(K):
        if lab[a] < 0:
            lab[(lab < 0) & (g == g[a]) & (ang[a] < tol_rad)] = a
    return lab


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


def _center_shift_cov(prob, x, R0, j, sel, bread, J, modes):
    """Covariance of (delta, w) from ball-centre errors shared by all flashes: for each
    ``(mask, C)`` in ``modes`` (``C`` the 3x3 covariance of a centre offset common to the masked
    observations, in ball radii, world frame) and each eigen-direction ``e`` of ``C``, the
    directions from the moved centre (``u - h (e - (e.u) u)``, central differences) give
    ``dx = -(J^T J)^-1 J^T dr/dh`` and ``cov += lambda dx dx^T``. A mode may also be an array
    (M, 3): a 1-sigma centre shift per observation (ball radii; e.g. the shift of each flash's
    triangulated centre when one camera's ball centres move along their lit direction), taken
    with variance 1. The cluster-robust sandwich sees
    a centre error that changes from flash to flash; one common to the flashes (a bias of the
    centre refinement) it cannot.

    Directions from pixel rays (``obs.views`` given) move differently: the ray meets the moved
    sphere, so ``du = -(e - v (e.u) / (v.u))`` with ``v`` the direction to the camera (a centre
    error along the line of sight leaves them unchanged); ``v.u`` is kept above 0.1, as
    :func:`direction_information` keeps ``cos theta``."""
    from stillcap.ball.orientation._observations import MarkerObservations

    out = np.zeros((J.shape[1], J.shape[1]))
    obs, u = prob.obs, prob.u
    f = None if prob.W is None else prob.W[:, 0, 0] / prob.W_base[:, 0, 0]  # the noise classes' weights
    h = 1e-4

    def shifts():
        """Every mode as ``(variance, per-observation centre shift (M, 3))``."""
        for mode in modes:
            if isinstance(mode, np.ndarray):  # a 1-sigma shift per observation (M, 3)
                e = np.asarray(mode, float)
                if e.shape != u.shape:
                    raise ValueError(f"a centre-shift mode must have shape {u.shape}, got {e.shape}")
                if np.any(e):
                    yield 1.0, e
                continue
            mask, C = mode
            m = np.ones(len(u), bool) if mask is None else np.asarray(mask, bool)
            lam, V = np.linalg.eigh(0.5 * (np.asarray(C, float) + np.asarray(C, float).T))
            for lk, e in zip(lam, V.T):
                if lk > 0:
                    yield lk, np.where(m[:, None], e[None, :], 0.0)

    modes_l, moved = [], []
    for lk, e in shifts():
        if obs.views is None:
            du = e - np.einsum("ij,ij->i", u, e)[:, None] * u
        else:
            vu = np.maximum(np.einsum("ij,ij->i", obs.views, u), 0.1)
            du = e - obs.views * (np.einsum("ij,ij->i", u, e) / vu)[:, None]
        modes_l.append(lk)
        moved += [u - sgn * h * du for sgn in (1.0, -1.0)]
    if not moved:
        return out
    # every moved copy's residuals in one batch (speed, issue 16: one problem per copy cost ~0.4 ms
    # each, ~30 of them a pitch); each copy's numbers are those of its own problem
    rs = _shifted_residuals(prob, x, R0, j, sel, np.stack(moved), f)
    if rs is None:  # (a copy without weights: each copy as its own problem, as before)
        rs = []
        for d in moved:
            p2 = _GlobalProblem(prob.dt, MarkerObservations(obs.flash, obs.types, d, obs.from_ray, obs.information,
                                                            obs.noise_class, obs.views), prob.layout, 0.0)
            if f is not None and p2.W is not None:
                p2.W = p2.W_base * f[:, None, None]
            rs.append(p2.residuals(x, R0, j, sel))
    for i, lk in enumerate(modes_l):
        dx = -bread @ (J.T @ ((rs[2 * i] - rs[2 * i + 1]) / (2.0 * h)))
        out += lk * np.outer(dx, dx)
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
             stop_fraction: float | None = None, center_shift_cov=None, flash_alignments=None) -> SpinResult:
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
    center_shift_cov : sequence of (mask, ndarray (3, 3)) or ndarray (M, 3), optional
        Ball-centre errors common to all flashes: per entry, the covariance (ball radii^2, world
        frame) of an offset shared by the observations ``mask`` (bool (M,), or None for all), or
        a 1-sigma error mode given as each observation's centre shift (ball radii, world frame),
        propagated into the spin's covariance (:func:`_center_shift_cov`).
    stop_fraction : float, optional
        Skip the other starts when the first one, after fitting, has this fraction of the
        observations within ``cap_deg`` of their markers (the pitch pipeline uses 0.9: on the
        27 benchmark pitches of issue 3 the first per-flash start was then always the best or
        reached the same minimum as the best). Default: try every start.
    flash_alignments : dict, optional
        Kept by the caller over fits of the same observations (e.g. from other starts): each
        flash's type alignment (:func:`orient_flash`) is made once and found there again.

    Returns
    -------
    SpinResult
        ``method="global"``; ``success`` False with a message when there are too few markers.

    Examples
    --------
    Eight flashes at 80 Hz of the seed's ball spinning at 1,543 rpm, seen from two directions,
    marker directions with 0.5 deg of noise:

    >>> import numpy as np
    >>> from stillcap.ball.orientation import fit_spin, simulate_observations
    >>> times = np.arange(8) / 80.0
    >>> obs = simulate_observations(times, np.eye(3), [0.0, -150.0, 60.0], [[1, 0, 0], [0, 1, 0]],
    ...                             noise_deg=0.5, rng=1)
    >>> res = fit_spin(times, obs)
    >>> bool(res.success), round(res.spin_rpm), np.round(res.axis, 2).tolist()
    (True, 1542, [-0.0, -0.93, 0.37])
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
                                  max_outer, x_scale, time_groups, time_group_sigma, t_start, center_shift_cov)

    flash_fit = _orient_flashes(obs, np.flatnonzero(counts >= 2), layout, cap_deg, flash_alignments)
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
                          x_scale, time_groups, time_group_sigma, t_start, center_shift_cov)


def _finish_global(prob, obs, times, best, spin_init, period, t0, f, cap, outlier_deg, max_outer, x_scale,
                   time_groups, time_group_sigma, t_start, center_shift_cov=None) -> SpinResult:
    """:func:`fit_spin` after the robust stage: outliers, least-squares polish, covariance."""
    _, R0, w, j, d = best
    assigned = (j, d)  # at (R0, w)
    if spin_init is None and np.linalg.norm(w) * period > np.pi:
        # the same rotation per interval the short way round: report the principal alias
        w = Rotation.from_rotvec(w * period).as_rotvec() / period
        assigned = None

    # outliers, then a plain least-squares polish on the inliers for the covariance
    every = np.ones(len(obs), bool)
    r = prob.residuals(np.concatenate([np.zeros(3), w]), R0, j, every)
    sigma_robust = float(np.median(np.abs(r)) / 0.6745)
    thr = np.radians(outlier_deg) if outlier_deg is not None else max(4.0 * sigma_robust, np.radians(1.0))
    # weighted observations: the outlier test on the weighted residual (a marker near the limb
    # may lie further off in angle than one face-on, as its weight says)
    inl = (d if prob.W is None else prob.observation_norms(np.concatenate([np.zeros(3), w]), R0, j, every)) < thr
    message = "ok"
    if inl.sum() < 4:
        inl = d <= np.sort(d)[min(3, len(d) - 1)]
        message = "few inliers"
    R0, w, j, d, res = _solve_global(prob, R0, w, loss="linear", f_scale=1.0, x_scale=x_scale,
                                     max_outer=max_outer, sel=inl, assigned=assigned)
    # each noise class's own scale (markers cut by the limb are noisier than whole ones), then
    # the polish again with those weights
    if prob.estimate_class_noise(np.concatenate([np.zeros(3), w]), R0, j, inl):
        R0, w, j, d, res2 = _solve_global(prob, R0, w, loss="linear", f_scale=1.0, x_scale=x_scale,
                                          max_outer=max_outer, sel=inl)
        res = res if res2 is None else res2
    # the redundancy counts only the informative components: a limb-cut marker's second
    # (weighted ~0) component is no degree of freedom (counted, the noise and the spin's
    # sigmas came out low where most markers are cut)
    ranks = _residual_ranks(prob)
    x = np.concatenate([np.zeros(3), w])
    r = prob.residuals(x, R0, j, inl)
    J = prob.jacobian(x, R0, j, inl)
    # each photo's own centroid noise, as far as these residuals show it (_photo_noise): if it
    # reweighs, polished again and the residuals taken anew
    if apply_photo_noise(prob, r, J, inl, ranks) > 0:
        R0, w, j, d, res2 = _solve_global(prob, R0, w, loss="linear", f_scale=1.0, x_scale=x_scale,
                                          max_outer=max_outer, sel=inl)
        res = res if res2 is None else res2
        x = np.concatenate([np.zeros(3), w])
        r = prob.residuals(x, R0, j, inl)
        J = prob.jacobian(x, R0, j, inl)
    n_dof = int(np.sum(ranks[inl])) - 6
    dof = max(n_dof, 1)
    s2 = float(r @ r) / dof
    bread = np.linalg.pinv(J.T @ J)
    cov = s2 * bread
    cov = _cluster_robust(cov, bread, J, r, prob.flash[inl])
    # flashes that show the ball in the same pose (orientations within a marker's angular size:
    # every marker where it was) share their markers' pose-bound errors: the sandwich again with
    # each such set of flashes as one cluster (it only widens; no change without repeated poses)
    poses = _pose_clusters(prob.rotations(R0, w), float(np.max(prob.layout.sizes)), time_groups)
    if len(np.unique(poses)) < len(poses):
        cov = _cluster_robust(cov, bread, J, r, poses[prob.flash[inl]])
    if time_groups is not None and time_group_sigma is not None:
        cov = cov + _time_offset_cov(prob, x, R0, j, inl, bread, J, time_groups, time_group_sigma)
    if center_shift_cov:
        cov = cov + _center_shift_cov(prob, x, R0, j, inl, bread, J, center_shift_cov)
    cov_w = cov[3:, 3:]
    rate, axis, sig_r, sig_a = _spin_summary(w, cov_w)
    if prob.W is None:
        rms_deg = float(np.degrees(np.sqrt(np.mean(d[inl] ** 2))))
    else:
        # weighted: the RMS of the weighted residuals (before the noise classes' scales) in the
        # angle of the median observation's weight: a marker near the limb, whose direction its
        # centroid fixes poorly toward the line of sight, counts as the precision it has there
        prob.W = prob.W_base
        rms_deg = float(np.degrees(np.sqrt(np.mean(prob.observation_norms(x, R0, j, inl) ** 2))))
    noise_res = _residuals_in_noise(prob, x, R0, j, d)
    success = bool(res is None or res.status > 0) and int(inl.sum()) >= 4 and np.all(np.isfinite(w))
    if n_dof < 2:
        message = "as many parameters as residuals: no uncertainty"
        sig_r = sig_a = np.nan
    return SpinResult(
        spin=w, spin_rpm=rate, axis=axis, sigma_rpm=sig_r, sigma_axis_deg=sig_a,
        spin_covariance=cov_w, ball2world_t0=R0, t0=t0, times=times, strobe_hz=f,
        orientations=prob.rotations(R0, w), residuals_deg=np.degrees(d), assigned=j, inliers=inl,
        rms_deg=rms_deg, n_observations=len(obs),
        n_inliers=int(inl.sum()), success=success, message=message, method="global",
        fit_time_s=_time.perf_counter() - t_start,
        noise_px=float(np.sqrt(s2 * prob.info_scale)) if prob.W is not None else float("nan"),
        dof=n_dof, residuals_noise=noise_res, residual_ranks=ranks)
