"""The seed's spin estimate (section 4.4, :func:`fit_spin_seed`): per flash, Powell's method over
Euler angles minimises the marker energy plus a prediction term; the spin is the mean of the
relative rotations of consecutive flashes."""

from __future__ import annotations

import time as _time

import numpy as np
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation._flash import _nearest_same_type, orient_flash
from stillcap.ball.orientation._observations import _check_inputs, _default_layout, strobe_period
from stillcap.ball.orientation._result import RPM_PER_RAD_S, SpinResult, _failed
from stillcap.ball.orientation._so3 import _expmap, _rot_angle


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
