"""Uncertainty of a pitch's metrics: 1-sigma of every metric from the reference fit's and the
marker spin's covariances (:func:`metrics_sigma`, first order or Monte Carlo through the flight
model), of the speed (:func:`speed_sigma`), and the Nathan model's spin decay over the flashes
(:func:`spin_decay_slope`).

Split from :mod:`stillcap.ball.uncertainty` (which re-exports these names) to keep both modules
under the project's 800-line limit; the error modes of the ball positions stay there.
"""

from __future__ import annotations

import numpy as np

from stillcap._checks import as_rng
from stillcap.ball.fit import ReferenceFit
from stillcap.ball.metrics import PitchMetrics, pitch_metrics_batch
from stillcap.ball.physics import FlightModel, simulate, simulate_batch

__all__ = ["ANGLE_KEYS", "metrics_sigma", "speed_sigma", "spin_decay_slope"]

#: Metric keys that are angles (their spread is taken on the circle).
ANGLE_KEYS = ("spin_axis_deg", "spin_axis_from_movement_deg", "pitchfx_spin_dir_deg")


# --------------------------------------------------------------------------------------------
# Uncertainty of the metrics
# --------------------------------------------------------------------------------------------
def speed_sigma(v, cov) -> float:
    """1-sigma of the speed ``|v|`` from the velocity's covariance ``cov`` (3, 3): first order,
    along the velocity's direction (NaN for a zero velocity)."""
    v = np.asarray(v, float)
    n = np.linalg.norm(v)
    if not n > 0:
        return float("nan")
    u = v / n
    return float(np.sqrt(max(u @ np.asarray(cov) @ u, 0.0)))


def spin_decay_slope(fit: ReferenceFit, model: FlightModel, t_obs, t_ref: float) -> float:
    """How much slower a constant-spin fit over ``t_obs`` turns than the spin at ``t_ref`` under
    the Nathan model's decay ``exp(-(t - t_ref) |v(t)| / (tau0 v_ref))``: the least-squares slope
    of the turned angle (unit rate at ``t_ref``) against time over the observation times."""
    t_obs = np.asarray(t_obs, float)
    if len(t_obs) < 2 or np.ptp(t_obs) <= 0:
        return 1.0
    grid = np.linspace(min(t_ref, t_obs.min()), t_obs.max(), 400)
    tr = simulate(fit.p0, fit.v0, fit.spin, grid, model, t0=fit.t0)
    n = model.nathan
    rate = np.exp(-(grid - t_ref) * np.linalg.norm(tr.velocities, axis=1) / (n.tau0 * n.v_ref))
    phi = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(grid))])
    slope = float(np.polyfit(t_obs, np.interp(t_obs, grid, phi), 1)[0])
    return slope if slope > 0.5 else 1.0


def _metric_keys(nominal: PitchMetrics):
    nom = nominal.to_dict()
    keys = [k for k in nom if k not in ("nine_parameter", "success", "message", "spin_tilt", "spin_direction_clock")]
    nine_keys = [k for k in (nom.get("nine_parameter") or {}) if k not in ("success", "n_points")]
    return nom, keys, nine_keys


def _metrics_of_states(fit: ReferenceFit, th, spins, model, t_rel, release_y_m, nominal: PitchMetrics, keys,
                       nine_keys):
    """Metrics of many flights at once: initial states ``th`` (n, 9: p0, v0, spin-basis
    coordinates of the reference fit) flown with the fast integrator (``simulate_batch``),
    ``spins`` (n, 3) or None the measured spin of each. Returns ``{key: (n,)}`` and the same for
    the nine-parameter fit (NaN where a flight gave no metrics)."""
    n = len(th)
    w_traj = th[:, 6:9] @ fit.spin_basis.T
    t_end = t_rel + max(nominal.plate_time_s if np.isfinite(nominal.plate_time_s) else 0.6, 0.1) * 1.1 + 0.02
    t_lo = min(t_rel, fit.t0) - 0.03
    ts = np.arange(t_lo, t_end, 0.002)
    # 50 ms RK4 steps (the flight fit's): against 10 ms steps every metric sigma of 7 studio
    # pitches moved by at most 2e-5 of itself (central differences of flights flown alike), 9 ms
    # less per capture
    tr = simulate_batch(th[:, :3], th[:, 3:6], w_traj, ts, model, t0=fit.t0, method="rk4", max_step=0.05)
    pos, vel = tr.positions, tr.velocities
    # each flight from the release: the samples after its crossing of the release plane, led by
    # the crossing (linear interpolation); NaN marks the samples a flight does not use
    keep = np.broadcast_to(np.arange(len(ts)) >= np.searchsorted(ts, t_rel), (n, len(ts)))
    first_t, first_p, first_v = np.full(n, np.nan), np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    if release_y_m is not None:
        y = pos[:, :, 1] - release_y_m
        sign_change = np.sign(y[:, :-1]) != np.sign(y[:, 1:])
        crossed = sign_change.any(axis=1)  # a flight that never crosses gives no metrics
        i = np.argmax(sign_change, axis=1)
        rows = np.arange(n)
        with np.errstate(invalid="ignore", divide="ignore"):  # (flights that do not cross)
            a = (y[rows, i] / (y[rows, i] - y[rows, i + 1]))[:, None]
        first_t = np.where(crossed, ts[i] + a[:, 0] * (ts[i + 1] - ts[i]), np.nan)
        first_p = np.where(crossed[:, None], pos[rows, i] + a * (pos[rows, i + 1] - pos[rows, i]), np.nan)
        first_v = np.where(crossed[:, None], vel[rows, i] + a * (vel[rows, i + 1] - vel[rows, i]), np.nan)
        keep = crossed[:, None] & (np.arange(len(ts))[None] > i[:, None])
    t_m = np.concatenate([first_t[:, None], np.where(keep, ts, np.nan)], axis=1)
    p_m = np.concatenate([first_p[:, None], np.where(keep[..., None], pos, np.nan)], axis=1)
    v_m = np.concatenate([first_v[:, None], np.where(keep[..., None], vel, np.nan)], axis=1)
    vals, nine = pitch_metrics_batch(t_m, p_m, spins, velocities=v_m)
    return {k: vals[k] for k in keys}, {k: nine[k] for k in nine_keys}


def _principal_steps(cov):
    """1-sigma steps along the principal axes of a covariance: rows ``sqrt(lambda_i) v_i`` for
    the positive eigenvalues (a zero-variance direction needs no evaluation)."""
    c = np.asarray(cov, float)
    c = 0.5 * (c + c.T)
    lam, V = np.linalg.eigh(c)
    keep = lam > lam.max(initial=0.0) * 1e-14
    return (V[:, keep] * np.sqrt(lam[keep])).T


def metrics_sigma(fit: ReferenceFit, spin_meas, spin_cov, model, t_rel, release_y_m, nominal: PitchMetrics,
                  n_samples: int, rng, method: str = "linear") -> dict:
    """1-sigma of every numeric metric from the reference fit's covariance (release state and the
    spin of the trajectory) and the marker spin's covariance (spin metrics).

    ``method="linear"`` (default): first-order propagation with central differences along the
    principal axes of both covariances, one sigma each way (at most 2 x (9 + 3) = 24 flights):
    ``sigma_k^2 = sum_i ((f_k(x + s_i) - f_k(x - s_i)) / 2)^2``. ``"monte_carlo"``:
    ``n_samples`` states drawn from the covariances, sigma = sample standard deviation. Angles
    are differenced on the circle. ``n_samples < 2`` gives no sigmas (either method)."""
    nom, keys, nine_keys = _metric_keys(nominal)
    empty = {k: None for k in keys} | {"nine_parameter": None}
    if n_samples < 2 or not np.all(np.isfinite(fit.covariance[:9, :9])):
        return empty
    cov = fit.covariance[:9, :9]
    cov = 0.5 * (cov + cov.T)
    c_spin = None
    if spin_meas is not None:
        c_spin = np.asarray(spin_cov, float)
        c_spin = 0.5 * (c_spin + c_spin.T) if np.all(np.isfinite(c_spin)) else np.zeros((3, 3))
    nn = nom.get("nine_parameter") or {}

    def wrap(k, d):
        return (d + 180.0) % 360.0 - 180.0 if k in ANGLE_KEYS else d

    if method == "linear":
        try:
            s_th = _principal_steps(cov)
            s_w = _principal_steps(c_spin) if c_spin is not None else np.zeros((0, 3))
        except np.linalg.LinAlgError:
            return empty
        n_th, n_w = len(s_th), len(s_w)
        th = np.tile(fit.params[:9], (1 + 2 * (n_th + n_w), 1))
        th[1:1 + n_th] += s_th
        th[1 + n_th:1 + 2 * n_th] -= s_th
        spins = None
        if spin_meas is not None:
            spins = np.tile(np.asarray(spin_meas, float), (len(th), 1))
            o = 1 + 2 * n_th
            spins[o:o + n_w] += s_w
            spins[o + n_w:o + 2 * n_w] -= s_w
        vals, nine_vals = _metrics_of_states(fit, th, spins, model, t_rel, release_y_m, nominal, keys, nine_keys)
        i_plus = np.r_[1:1 + n_th, 1 + 2 * n_th:1 + 2 * n_th + n_w]
        i_minus = np.r_[1 + n_th:1 + 2 * n_th, 1 + 2 * n_th + n_w:1 + 2 * (n_th + n_w)]

        def spread(k, a, center):
            if center is None or not np.isfinite(a[0]):
                return None
            fp, fm = a[i_plus], a[i_minus]
            ok_p, ok_m = np.isfinite(fp), np.isfinite(fm)
            if not np.all(ok_p | ok_m):
                return None
            # one side failed: one-sided difference
            d = np.where(ok_p & ok_m, 0.5 * wrap(k, fp - fm), wrap(k, np.where(ok_p, fp, fm) - a[0]))
            # (accumulate: summed in order, as a loop would)
            return float(np.sqrt(np.add.accumulate(d * d)[-1])) if len(d) else 0.0
    else:
        rng = as_rng(rng)
        try:
            th = rng.multivariate_normal(fit.params[:9], cov, size=n_samples, method="eigh")
        except (np.linalg.LinAlgError, ValueError):
            return empty
        spins = None
        if spin_meas is not None:
            spins = rng.multivariate_normal(spin_meas, c_spin, size=n_samples, method="eigh")
        vals, nine_vals = _metrics_of_states(fit, th, spins, model, t_rel, release_y_m, nominal, keys, nine_keys)

        def spread(k, a, center):
            a = a[np.isfinite(a)]
            if len(a) < 2 or center is None:
                return None
            if k in ANGLE_KEYS:
                a = wrap(k, a - center)
            return float(np.std(a, ddof=1))

    out = {k: spread(k, vals[k], nom.get(k)) for k in keys}
    out["nine_parameter"] = {k: spread(k, nine_vals[k], nn.get(k)) for k in nine_keys} if nine_keys else None
    if spin_meas is None:
        for k in ("spin_rate_rpm", "active_spin_rpm", "spin_efficiency", "gyro_angle_deg", "spin_axis_deg"):
            if k in out:
                out[k] = None
    return out
