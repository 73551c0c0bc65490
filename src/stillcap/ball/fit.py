"""Reference-trajectory fit (SPEC J1, seed section 4.5).

The flight is sensitive to its initial parameters, so the seed searches for the initial
position, velocity and spin whose physical trajectory (:mod:`stillcap.ball.physics`) is closest
to both the measured ball positions and the measured initial parameters. That reference
trajectory gives the accuracy table (mean / max position error, velocity angle, speed
difference, spin-axis angle, spin-rate difference).

The objective (both methods) is the sum of squares of

- position residuals ``(p_model(t_i) - p_i) / position_sigma`` for every observed coordinate
  (NaN = not observed), and
- prior residuals ``(theta - theta_measured) / prior_sigma`` pulling toward the measured initial
  position, velocity and spin (:class:`FitPriors`; an infinite sigma drops that prior).

``method="powell"`` minimises it with ``scipy.optimize.minimize(method="Powell")`` as the seed
did; ``method="least_squares"`` (default) with ``scipy.optimize.least_squares``, whose Jacobian
is computed by central differences on the vectorised fast integrator (all 2n+1 trajectories in
one batch). Either way the result carries the covariance ``(J_d^T J_d / s^2 + J_p^T J_p)^-1``
(``J_d``, ``J_p`` the Jacobians of the position and prior residuals, ``s^2`` the position
residual variance per degree of freedom) and 1-sigma uncertainties of every parameter.

Spin parameterisation: positions mainly see the spin component transverse to the flight (the
component along the velocity, gyro spin, produces no Magnus force in the Nathan model and only
enters the seed model's ``C_L`` through ``|w|``; it becomes weakly visible because gravity turns
the velocity during the flight). The spin is written in a fixed basis built from the measured
initial velocity, ``w = s_a e_v + s_1 e_1 + s_2 e_2`` (``e_v`` along the velocity, ``e_1`` the
horizontal and ``e_2`` the upward normal). With a measured spin the axial part ``s_a`` is held
near its measured value by its prior, which keeps the problem well posed (its reported
uncertainty is then essentially the prior's).

Without a measured spin all three are fitted. Positions see the axial spin only weakly, but they
do see it: the velocity turns during the flight (gravity, the break), so the axial spin at the
first flash becomes transverse later. Holding it at 0 (``fit_axial_spin=False``, tried for
issue 3) left the transverse part well determined but biased the flight of gyro-heavy pitches
(studio ``mlb-gyro-slider`` and curveballs: 1.5-2 mm RMS from the positions instead of 0.6 mm,
the velocity 12-17 of its sigmas off, and a 5x too small transverse sigma). What made the
free fit slow is the shape of that weak direction in the seed model, whose lift is ``|w|``
along ``w_perp``: at constant lift it is a curved valley (``|w|`` and the direction of
``w_perp`` fixed) that Levenberg-Marquardt crawled along (1000-2800 trajectories). So with the
seed model and no measured spin the fit runs in ``(phi, e_1, e_2)``, the gyro angle and the
effective transverse spin ``e = |w| w_perp / |w_perp|`` (:func:`_gyro_to_basis`), where that
valley is a coordinate axis: the same minimum and covariance in 120-420 trajectories. The
result is reported in ``(s_a, s_1, s_2)`` as always (covariance through the Jacobian of the
change of variables). Nathan's lift depends on ``w_perp`` alone, for which ``(s_a, s_1, s_2)``
is already that parameterisation.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize

from stillcap._checks import as_array
from stillcap.ball.physics import FlightModel, simulate, simulate_batch

PARAM_NAMES = ("px", "py", "pz", "vx", "vy", "vz", "spin_axial", "spin_t1", "spin_t2")
MPH = 0.44704
from stillcap._numeric import RPM_PER_RAD_S  # noqa: E402 (the one definition)


@dataclass(frozen=True)
class FitPriors:
    """1-sigma uncertainties of the measured initial parameters (weights of the priors).

    Attributes
    ----------
    position_sigma : float
        m, per coordinate.
    velocity_sigma : float
        m/s, per coordinate (the seed's speed differences were 0.7-1.9 mph).
    spin_axial_sigma : float
        rad/s, spin along the initial velocity (gyro part).
    spin_transverse_sigma : float
        rad/s, per transverse coordinate (the seed's rate differences were 7-32 rpm).
    """

    position_sigma: float = 0.02
    velocity_sigma: float = 0.5
    spin_axial_sigma: float = 5.0
    spin_transverse_sigma: float = 10.0

    def vector(self) -> np.ndarray:
        return np.array([self.position_sigma] * 3 + [self.velocity_sigma] * 3
                        + [self.spin_axial_sigma] + [self.spin_transverse_sigma] * 2, float)


def spin_basis(velocity, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Orthonormal columns ``(e_v, e_1, e_2)``: along ``velocity``, horizontal normal, upward normal.

    ``e_1 = e_v x up`` (normalised; any normal of ``e_v`` if the velocity is along ``up``),
    ``e_2 = e_1 x e_v``.

    Parameters
    ----------
    velocity : array_like, shape (3,)
    up : array_like, shape (3,)
        The world's up direction (default z; :func:`fit_reference_trajectory` uses the model's
        ``-gravity``).

    Returns
    -------
    ndarray, shape (3, 3)
    """
    v = as_array(velocity, (3,), "velocity")
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError(f"velocity must be non-zero to build the spin basis, got {v}")
    ev = v / n
    u = as_array(up, (3,), "up")
    if not np.linalg.norm(u) > 0:
        raise ValueError(f"up must be non-zero, got {u}")
    e1 = np.cross(ev, u / np.linalg.norm(u))
    if np.linalg.norm(e1) < 1e-9:
        # velocity along up: the world axis least aligned with it, made normal to it (x for z)
        e1 = np.eye(3)[int(np.argmin(np.abs(ev)))]
        e1 = e1 - ev * (e1 @ ev)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e1, ev)
    return np.stack([ev, e1, e2], axis=1)


@dataclass
class ReferenceFit:
    """A fitted reference trajectory and how well it matches the measurements.

    Attributes
    ----------
    p0, v0, spin : ndarray, shape (3,)
        Fitted initial position (m), velocity (m/s) and spin (rad/s) at ``t0``, world frame.
    p0_sigma, v0_sigma, spin_sigma : ndarray, shape (3,)
        1-sigma uncertainties of those, world frame.
    params, param_sigma : ndarray, shape (9,)
        The fit's parameters :data:`PARAM_NAMES` (spin in ``spin_basis``) and their 1-sigma.
    covariance : ndarray, shape (9 + G - 1, 9 + G - 1)
        Covariance of the flight parameters and then the time offsets.
    spin_basis : ndarray, shape (3, 3)
        Columns ``e_v, e_1, e_2`` of the spin parameterisation.
    spin_transverse, spin_transverse_sigma : ndarray, shape (2,)
        ``(s_1, s_2)`` in rad/s and their 1-sigma.
    time_offsets, time_offset_sigma : ndarray, shape (G - 1,)
        Fitted clock offsets of time groups 1.. (s) and their 1-sigma (empty without groups).
    t0 : float
        Time of the initial state, s.
    times : ndarray, shape (N,)
        Measurement times on the reference clock (offsets applied).
    positions : ndarray, shape (N, 3)
        The reference trajectory at ``times`` (reference integrator).
    residuals : ndarray, shape (N, 3)
        ``positions - measured`` (NaN where not observed).
    errors : ndarray, shape (N,)
        Euclidean error per point, m (NaN where not observed).
    mean_error, max_error, rms_error : float
        m, over observed points.
    velocity_angle_deg, speed_diff, spin_axis_angle_deg, spin_rate_diff : float
        Fitted versus measured initial parameters (seed Table 1): angle between velocities,
        ``|v_fit| - |v_meas|`` (m/s), angle between spin vectors, ``|w_fit| - |w_meas|``
        (rad/s); NaN where no measurement was given.
    residual_scale : float
        ``s = sqrt(sum r^2 / (m - n))`` of the whitened position residuals (about 1 when
        ``position_sigma`` is the true noise; the covariance is rescaled by it).
    success : bool
    message, method : str
    nfev : int
        Objective evaluations (trajectories).
    fit_time_s : float
    axial_spin_fitted : bool
        False when the axial spin ``s_a`` was held (at 0, or at the measured spin's axial
        component) rather than fitted: its row and column of ``covariance`` are then 0 and
        ``spin_sigma`` covers the transverse part only.
    position_gain : ndarray, shape (9 + G - 1, N, 3) or None
        Linear response of the parameters to the measured positions, ``d theta / d positions``
        (0 where not observed): a position error ``dP`` with covariance ``C`` (e.g. the
        calibration error shared by a pair's positions) adds ``G C G^T`` (see
        :meth:`position_covariance_term`).
    prior_gain : ndarray, shape (9 + G - 1, 9 + G - 1) or None
        Linear response of the parameters to the measured initial parameters (the priors'
        centres ``(p0, v0, spin in spin_basis)``), ``d theta / d theta_meas`` (0 in the columns
        without a prior). See :meth:`spin_prior_covariance_term`.
    prior_sigma : ndarray, shape (9 + G - 1,) or None
        The priors' 1-sigma the fit weighted them with (inf: no prior).
    """

    p0: np.ndarray
    v0: np.ndarray
    spin: np.ndarray
    p0_sigma: np.ndarray
    v0_sigma: np.ndarray
    spin_sigma: np.ndarray
    params: np.ndarray
    param_sigma: np.ndarray
    covariance: np.ndarray
    spin_basis: np.ndarray
    spin_transverse: np.ndarray
    spin_transverse_sigma: np.ndarray
    time_offsets: np.ndarray
    time_offset_sigma: np.ndarray
    t0: float
    times: np.ndarray
    positions: np.ndarray
    residuals: np.ndarray
    errors: np.ndarray
    mean_error: float
    max_error: float
    rms_error: float
    velocity_angle_deg: float
    speed_diff: float
    spin_axis_angle_deg: float
    spin_rate_diff: float
    residual_scale: float
    success: bool
    message: str
    method: str
    nfev: int
    fit_time_s: float
    position_gain: np.ndarray | None = None
    axial_spin_fitted: bool = True
    prior_gain: np.ndarray | None = None
    prior_sigma: np.ndarray | None = None

    def position_covariance_term(self, modes) -> np.ndarray:
        """Parameter covariance from correlated position errors given as modes.

        Parameters
        ----------
        modes : array_like, shape (n_modes, N, 3)
            Independent error modes of the measured positions, each at 1 sigma (the position
            error is ``sum_m z_m modes[m]`` with ``z_m`` standard normal).

        Returns
        -------
        ndarray, shape (9 + G - 1, 9 + G - 1)
            ``sum_m (G dP_m)(G dP_m)^T``.
        """
        if self.position_gain is None:
            raise ValueError("this fit has no position_gain")
        D = np.nan_to_num(np.asarray(modes, float))
        if D.ndim != 3 or D.shape[1:] != self.position_gain.shape[1:]:
            raise ValueError(f"modes must have shape (n_modes, {self.position_gain.shape[1]}, 3), got {D.shape}")
        dth = np.einsum("pnk,mnk->mp", self.position_gain, D)
        return dth.T @ dth

    def spin_prior_covariance_term(self, spin_covariance) -> np.ndarray:
        """Covariance correction for a measured spin whose error covariance is not the
        diagonal one the fit weighted its spin prior with.

        The fit weights the measured spin with independent sigmas along ``spin_basis``
        (:class:`FitPriors`: one axial, one for both transverse components). The spin fit's
        covariance is anisotropic and correlated (the axis direction is worse determined across
        the axis than the rate, e.g. 1.3x the averaged transverse sigma along its major axis on
        four-seamers), and the curvature of the flight passes the spin error into the velocity
        direction. As a linear estimator the parameters respond to the measured spin by
        ``G_s = d theta / d s_meas`` (:attr:`prior_gain`), so their covariance is the model one
        with ``G_s diag(sigma_used^2) G_s^T`` replaced by ``G_s (B^T C B) G_s^T``.

        Parameters
        ----------
        spin_covariance : array_like, shape (3, 3)
            Covariance of the measured spin given to the fit (world frame, (rad/s)^2).

        Returns
        -------
        ndarray, shape (9 + G - 1, 9 + G - 1)
            ``G_s (B^T C B - diag(sigma_used^2)) G_s^T``, to add with
            :meth:`with_extra_covariance` (0 when the fit had no spin prior).
        """
        C = np.asarray(spin_covariance, float)
        if C.shape != (3, 3):
            raise ValueError(f"spin_covariance must have shape (3, 3), got {C.shape}")
        n = len(self.covariance)
        if self.prior_gain is None or self.prior_sigma is None or not np.all(np.isfinite(C)):
            return np.zeros((n, n))
        has = np.isfinite(self.prior_sigma[6:9])
        if not has.any():
            return np.zeros((n, n))
        Cs = self.spin_basis.T @ (0.5 * (C + C.T)) @ self.spin_basis
        Cs = Cs[np.ix_(has, has)] - np.diag(self.prior_sigma[6:9][has] ** 2)
        Gs = self.prior_gain[:, 6:9][:, has]
        return Gs @ Cs @ Gs.T

    def with_extra_covariance(self, extra) -> "ReferenceFit":
        """A copy whose covariance (and every sigma) includes ``extra`` (same shape)."""
        from dataclasses import replace

        cov = self.covariance + np.asarray(extra, float)
        # a correction term (spin_prior_covariance_term) may be negative in some directions:
        # keep the sum symmetric positive semi-definite (it is one up to rounding)
        d, V = np.linalg.eigh(0.5 * (cov + cov.T))
        if d.size and d.min() < -1e-9 * max(d.max(), 0.0):
            cov = (V * np.clip(d, 0.0, None)) @ V.T
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        B = self.spin_basis
        cov_w = B @ cov[6:9, 6:9] @ B.T
        return replace(self, covariance=cov, p0_sigma=sig[:3], v0_sigma=sig[3:6],
                       spin_sigma=np.sqrt(np.clip(np.diag(cov_w), 0, None)), param_sigma=sig[:9],
                       spin_transverse_sigma=sig[7:9], time_offset_sigma=sig[9:])

    def seed_table_row(self) -> dict:
        """The seed's Table 1 columns in its units (mm, deg, mph, rpm)."""
        return {
            "mean_err_mm": self.mean_error * 1e3,
            "max_err_mm": self.max_error * 1e3,
            "velocity_angle_deg": self.velocity_angle_deg,
            "speed_diff_mph": self.speed_diff / MPH,
            "spin_axis_angle_deg": self.spin_axis_angle_deg,
            "spin_rate_diff_rpm": self.spin_rate_diff * RPM_PER_RAD_S,
            "speed_mph": float(np.linalg.norm(self.v0) / MPH),
            "spin_rpm": float(np.linalg.norm(self.spin) * RPM_PER_RAD_S),
        }


def _angle_deg(a, b) -> float:
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if not (na > 0 and nb > 0):
        return float("nan")
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))))


class _Problem:
    """Whitened residuals of the fit, vectorised over parameter sets.

    Parameters ``theta`` (P,) = 9 flight parameters, then one time offset per extra time group.
    """

    def __init__(self, times, positions, group_idx, theta_meas, sigmas, free, basis, model, t0,
                 position_sigma, integrator, max_step, weights=None):
        self.times = times
        self.group_idx = group_idx  # (N,) 0 = reference clock, g >= 1 -> offset g - 1
        self.mask = np.isfinite(positions)
        self.meas = positions[self.mask]
        # (N, 3, 3) whitening matrices of the position residuals (None: identity), only on rows
        # observed in all three coordinates (fit_reference_trajectory's position_covariance)
        self.weights = weights
        self.meas_full = np.nan_to_num(positions)
        self.entry_group = np.broadcast_to(group_idx[:, None], positions.shape)[self.mask]
        self.theta_meas = theta_meas
        self.free = free
        self.has_prior = free & np.isfinite(sigmas)
        self.prior_sigma = sigmas[self.has_prior]
        self.basis = basis
        self.gyro = False  # spin parameters (phi, e_1, e_2) instead of (s_a, s_1, s_2): _gyro_to_basis
        self.model = model
        self.t0 = t0
        self.position_sigma = position_sigma
        self.integrator = integrator
        self.max_step = max_step
        self.nfev = 0

    def full(self, x):
        """Free parameters (M, n_free) -> full parameter sets (M, P)."""
        x = np.atleast_2d(x)
        th = np.broadcast_to(self.theta_meas, (len(x), len(self.theta_meas))).copy()
        th[:, self.free] = x
        return th

    def effective_times(self, offsets):
        return self.times + np.concatenate([[0.0], offsets])[self.group_idx]

    def _simulate(self, th):
        """Trajectories of parameter sets sharing the same time offsets."""
        sp = _gyro_to_basis(th[:, 6:9]) if self.gyro else th[:, 6:9]
        spin = sp @ self.basis.T
        self.nfev += len(th)
        return simulate_batch(th[:, :3], th[:, 3:6], spin, self.effective_times(th[0, 9:]),
                              self.model, t0=self.t0, method=self.integrator,
                              max_step=self.max_step)

    def _apply_weights(self, d):
        """(M, N, 3) position differences -> whitened, observed entries (M, n_data)."""
        if self.weights is not None:
            if not np.isfinite(d).all():  # (checked first: nan_to_num costs more than the check)
                d = np.nan_to_num(d)
            d = np.einsum("nij,mnj->mni", self.weights, d)
        return d[:, self.mask] / self.position_sigma

    def _whiten(self, th, positions):
        if self.weights is None:
            data = (positions[:, self.mask] - self.meas) / self.position_sigma
        else:
            data = self._apply_weights(positions - self.meas_full[None])
        prior = (th[:, self.has_prior] - self.theta_meas[self.has_prior]) / self.prior_sigma
        return np.concatenate([data, prior], axis=1)

    def residuals(self, x) -> np.ndarray:
        th = self.full(x)
        if len(th) > 1 and th.shape[1] > 9 and np.ptp(th[:, 9:], axis=0).max() > 0:
            return np.concatenate([self.residuals(row) for row in x])
        return self._whiten(th, self._simulate(th).positions)

    def jacobian(self, x, steps) -> np.ndarray:
        """Central differences for the flight parameters (all 2n perturbed trajectories and the
        unperturbed one in one batch); time-offset columns analytically from the velocities."""
        x = np.asarray(x, float)
        n = len(x)
        phys = np.flatnonzero(self.free)[:n] < 9  # free parameters that are flight parameters
        k = np.flatnonzero(phys)
        xs = np.repeat(x[None], 2 * len(k) + 1, axis=0)
        xs[1 + 2 * np.arange(len(k)), k] += steps[k]
        xs[2 + 2 * np.arange(len(k)), k] -= steps[k]
        th = self.full(xs)
        tr = self._simulate(th)
        r = self._whiten(th, tr.positions)
        J = np.zeros((r.shape[1], n))
        J[:, k] = ((r[1::2] - r[2::2]) / (2.0 * steps[k][:, None])).T
        if not phys.all():
            vel = self._apply_weights(tr.velocities[:1])[0]
            free_idx = np.flatnonzero(self.free)
            n_data = len(self.meas)
            for col in np.flatnonzero(~phys):  # offsets have no priors: prior rows stay 0
                g = free_idx[col] - 9 + 1  # the time group this offset shifts
                J[:n_data, col] = np.where(self.entry_group == g, vel, 0.0)
        return J


def _gyro_to_basis(g) -> np.ndarray:
    """Spin parameters ``(phi, e_1, e_2)`` -> basis coordinates ``(s_a, s_1, s_2)``.

    ``w = |e| (sin(phi) e_v + cos(phi) e_hat)``: ``e`` is the effective transverse spin of the
    seed model (its lift is ``|w|`` along ``w_perp``, so ``|w| = |e|`` and ``w_perp`` along ``e``),
    ``phi`` the gyro angle. At the first flash the lift depends on ``e`` alone; ``phi`` only acts
    through the turning of the velocity during the flight. In ``(s_a, s_1, s_2)`` that weakly
    determined direction is a curved valley (constant ``|w|`` and ``w_perp`` direction) that
    Levenberg-Marquardt crawls along (1000-2800 trajectories on gyro-heavy pitches); in
    ``(phi, e)`` it is a coordinate axis.
    """
    g = np.asarray(g, float)
    phi, e = g[..., 0], g[..., 1:]
    ne = np.linalg.norm(e, axis=-1)
    out = np.empty(g.shape)
    out[..., 0] = ne * np.sin(phi)
    out[..., 1:] = e * np.cos(phi)[..., None]
    return out


def _gyro_jacobian(g) -> np.ndarray:
    """``d (s_a, s_1, s_2) / d (phi, e_1, e_2)`` at ``g``, shape (3, 3)."""
    phi, e = float(g[0]), np.asarray(g[1:], float)
    ne = float(np.linalg.norm(e))
    u = e / ne if ne > 0 else np.zeros(2)
    J = np.zeros((3, 3))
    J[0, 0] = ne * np.cos(phi)
    J[0, 1:] = np.sin(phi) * u
    J[1:, 0] = -np.sin(phi) * e
    J[1:, 1:] = np.cos(phi) * np.eye(2)
    return J


def _basis_to_gyro(s) -> np.ndarray:
    """Inverse of :func:`_gyro_to_basis` (``w_perp != 0``)."""
    s = np.asarray(s, float)
    nt = float(np.linalg.norm(s[1:]))
    nw = float(np.linalg.norm(s))
    if not nt > 0:
        return np.zeros(3)
    return np.concatenate([[np.arctan2(s[0], nt)], s[1:] * (nw / nt)])


def _spin_start(times, positions, model, max_rate: float = 600.0) -> np.ndarray:
    """A starting spin for a fit without a measured one: the transverse spin whose Magnus
    acceleration matches the curvature of a quadratic through the positions (the gravity and
    drag of the model taken out), rad/s; zeros when the positions show no curvature.

    Starting at zero spin stalls the least-squares fit: the seed model's lift grows as ``|w| w``,
    so the residuals' derivative with respect to the spin vanishes at ``w = 0`` and Gauss-Newton
    crawls (3000 residual evaluations instead of 500 for a 3000 rpm pitch).
    """
    ok = np.all(np.isfinite(positions), axis=1)
    if ok.sum() < 4 or np.ptp(times[ok]) <= 0:
        return np.zeros(3)
    tc = times[ok] - times[ok].mean()
    coef, *_ = np.linalg.lstsq(np.vander(tc, 3), positions[ok], rcond=None)
    a_meas, v_mid = 2.0 * coef[0], coef[1]
    speed = float(np.linalg.norm(v_mid))
    if not speed > 0:
        return np.zeros(3)
    e = v_mid / speed
    a_free = np.asarray(model.acceleration(v_mid, np.zeros(3)), float)
    a_t = a_meas - a_free
    a_t = a_t - e * (a_t @ e)
    target = float(np.linalg.norm(a_t))
    if not np.isfinite(target) or target < 1e-6:
        return np.zeros(3)
    w_dir = np.cross(v_mid, a_t)
    w_dir /= np.linalg.norm(w_dir)
    rates = np.linspace(0.0, max_rate, 121)
    acc = np.asarray(model.acceleration(np.broadcast_to(v_mid, (len(rates), 3)), rates[:, None] * w_dir), float)
    mag = acc - a_free
    mag = np.linalg.norm(mag - np.outer(mag @ e, e), axis=1)
    above = np.flatnonzero(mag >= target)
    if not len(above):
        return max_rate * w_dir
    i = int(above[0])
    if i == 0:
        return np.zeros(3)
    rate = rates[i - 1] + (target - mag[i - 1]) / (mag[i] - mag[i - 1]) * (rates[i] - rates[i - 1])
    return rate * w_dir


def _model_up(model) -> np.ndarray:
    """The up direction of a model: against its ``gravity`` (a FlightModel's, or any model's
    that has one); otherwise against the acceleration of a ball at rest without spin (gravity,
    for any model implementing only ``AccelerationModel``); z when neither gives one."""
    g = getattr(model, "gravity", None)
    if g is None:
        try:
            g = model.acceleration(np.zeros(3), np.zeros(3), 0.0)
        except (TypeError, ValueError, ArithmeticError):
            g = None
    g = np.asarray(g, float).reshape(-1) if g is not None else np.zeros(0)
    if g.shape != (3,) or not np.all(np.isfinite(g)) or not np.linalg.norm(g) > 0:
        return np.array([0.0, 0.0, 1.0])
    return -g / np.linalg.norm(g)


def _whitening(position_covariance, positions) -> np.ndarray:
    """Whitening matrices ``W_n`` (``W_n C_n W_n^T = I`` after the common normalisation of
    ``fit_reference_trajectory``'s ``position_covariance``), identity on unusable rows."""
    C = np.asarray(position_covariance, float)
    if C.shape != (len(positions), 3, 3):
        raise ValueError(f"position_covariance must have shape ({len(positions)}, 3, 3), got {C.shape}")
    W = np.broadcast_to(np.eye(3), C.shape).copy()
    ok = np.all(np.isfinite(positions), axis=1) & np.all(np.isfinite(C), axis=(1, 2))
    if ok.any():
        Cs = 0.5 * (C[ok] + np.swapaxes(C[ok], 1, 2))
        ev = np.linalg.eigvalsh(Cs)
        good = ev[:, 0] > 1e-12 * np.maximum(ev[:, -1], 1e-300)
        idx = np.flatnonzero(ok)[good]
        if len(idx):
            Cs = Cs[good] / np.mean(np.trace(Cs[good], axis1=1, axis2=2) / 3.0)
            # W = L^-1 with C = L L^T: residual W d has unit covariance
            W[idx] = np.linalg.inv(np.linalg.cholesky(Cs))
    return W


def fit_reference_trajectory(times, positions, p0, v0, spin=None, model: FlightModel | None = None,
                             *, t0: float | None = None, method: str = "least_squares",
                             position_sigma: float = 0.002, priors: FitPriors | None = None,
                             integrator: str = "rk4", max_step: float = 0.05,
                             time_groups=None, time_offsets=None,
                             max_nfev: int | None = None,
                             fit_axial_spin: bool = True,
                             position_covariance=None) -> ReferenceFit:
    """Fit the physical reference trajectory to measured ball positions (seed section 4.5).

    Parameters
    ----------
    times : array_like, shape (N,)
        Time of each measured position, s.
    positions : array_like, shape (N, 3)
        Measured ball centres, m, in the model's world frame; NaN marks "not observed" (gaps).
    p0, v0 : array_like, shape (3,)
        Measured initial position (m) and velocity (m/s) at ``t0``; also the starting guess.
    spin : array_like, shape (3,), optional
        Measured spin vector, rad/s. Without it the spin has no prior and starts at the spin
        whose Magnus force matches the curvature of the positions (with the seed model it is
        then fitted as a gyro angle and an effective transverse spin, module docstring).
    model : FlightModel, optional
        Default: the seed model in the field frame.
    t0 : float, optional
        Time of the initial parameters; default the first observed time.
    method : {"least_squares", "powell"}
    position_sigma : float
        Expected measurement noise per coordinate, m (relative weight of data and priors).
    priors : FitPriors, optional
    integrator : {"rk4", "dopri5"}
        Fast fixed-step integrator used inside the fit; the reported trajectory and errors use
        the reference integrator.
    max_step : float
        Step of the fast integrator, s. RK4 with 50 ms steps stays within 0.02 um of the
        reference integrator over a pitch (0.0006 um with 20 ms), far below any position
        error, at 2.5x fewer acceleration evaluations.
    time_groups : array_like of int, shape (N,), optional
        Clock of each measurement: 0 = the reference clock of ``times`` and ``t0``, 1, 2, ... =
        other clocks (e.g. the back stereo pair, whose strobe is not synchronised with the
        front pair, SPEC J1). One time offset per extra clock is fitted: the true time of a
        point of group g >= 1 is ``times + time_offsets[g - 1]``.
    time_offsets : array_like, shape (G - 1,), optional
        Starting guesses of those offsets, s (default 0).
    max_nfev : int, optional
        Limit on residual (least_squares) or objective (Powell) evaluations.
    fit_axial_spin : bool
        Fit the spin component along the initial velocity (``spin_axial``, default). When False
        it is held at the measured spin's axial component (0 without one) and only the two
        transverse components are fitted; without a measured spin that biases the fit of
        pitches with much gyro spin (module docstring).
    position_covariance : array_like, shape (N, 3, 3), optional
        The *shape* of each measured position's error covariance (e.g. from the triangulation
        geometry: a stereo pair sees depth worse than the directions across its view). The
        residuals are whitened with it (generalised least squares) after scaling all of them by
        one factor, so that the mean per-coordinate variance is ``position_sigma**2``: the
        overall noise level is still estimated from the residuals (``residual_scale``); only the
        relative weights (between points, and between the directions of one point) come from
        it. Rows not observed in all three coordinates, or whose matrix is not finite and
        positive definite, keep the isotropic ``position_sigma``. Default: isotropic.

    Returns
    -------
    ReferenceFit
    """
    t_start = _time.perf_counter()
    times = as_array(times, (None,), "times")
    positions = as_array(positions, (len(times), 3), "positions")
    if not np.all(np.isfinite(times)):
        raise ValueError("times must be finite (mark missing positions with NaN instead)")
    observed = np.any(np.isfinite(positions), axis=1)
    if np.count_nonzero(np.isfinite(positions)) < 9:
        raise ValueError(f"need at least 9 observed coordinates to fit 9 parameters, got "
                         f"{np.count_nonzero(np.isfinite(positions))}")
    p0 = as_array(p0, (3,), "p0")
    v0 = as_array(v0, (3,), "v0")
    if method not in ("least_squares", "powell"):
        raise ValueError(f"method must be 'least_squares' or 'powell', got {method!r}")
    if not (position_sigma > 0 and np.all(np.isfinite(np.r_[p0, v0]))):
        raise ValueError(f"need position_sigma > 0 and finite p0, v0; got {position_sigma}, {p0}, {v0}")
    model = FlightModel() if model is None else model
    priors = FitPriors() if priors is None else priors
    if time_groups is None:
        group_idx = np.zeros(len(times), int)
    else:
        group_idx = as_array(time_groups, (len(times),), "time_groups", dtype=int)
        if group_idx.min(initial=0) < 0:
            raise ValueError("time_groups must be non-negative integers (0 = reference clock)")
    n_off = int(group_idx.max(initial=0))
    off0 = np.zeros(n_off) if time_offsets is None else as_array(time_offsets, (n_off,), "time_offsets")
    t0 = float(times[observed & (group_idx == 0)].min(initial=np.inf)) if t0 is None else float(t0)
    if not np.isfinite(t0):
        t0 = float(times[observed].min())
    basis = spin_basis(v0, _model_up(model))
    sigmas = np.concatenate([priors.vector(), np.full(n_off, np.inf)])
    free = np.ones(9 + n_off, bool)
    if spin is None:
        # no measured spin: no spin priors; start from the spin the positions' curvature implies
        spin_meas = None
        s_meas = basis.T @ _spin_start(times + np.concatenate([[0.0], off0])[group_idx], positions, model)
        sigmas[6:9] = np.inf
        if not fit_axial_spin:
            s_meas[0] = 0.0
    else:
        spin_meas = as_array(spin, (3,), "spin")
        s_meas = basis.T @ spin_meas
    if not fit_axial_spin:
        free[6] = False  # held at s_meas[0]: 0, or the measured spin's axial component
    # the seed model without a measured spin: fitted in (gyro angle, effective transverse spin)
    gyro = spin is None and fit_axial_spin and getattr(model, "kind", None) == "seed" and np.linalg.norm(s_meas[1:]) > 0
    theta_meas = np.concatenate([p0, v0, _basis_to_gyro(s_meas) if gyro else s_meas, off0])
    weights = None if position_covariance is None else _whitening(position_covariance, positions)
    prob = _Problem(times, positions, group_idx, theta_meas, sigmas, free, basis, model, t0,
                    position_sigma, integrator, max_step, weights)
    prob.gyro = gyro
    # parameter scales (for conditioning and finite-difference steps)
    default_scale = np.array([0.01] * 3 + [0.5] * 3 + [0.1 if gyro else 10.0] + [10.0] * 2 + [1e-3] * n_off)
    scale = np.where(np.isfinite(sigmas), sigmas, default_scale)[free]
    steps = 1e-4 * scale
    x0 = theta_meas[free]

    last: dict = {}  # the last residuals and Jacobian evaluated: x -> value
    if method == "least_squares":
        # Levenberg-Marquardt (MINPACK) rather than "trf": in the weakly determined directions
        # (axial spin without a measured spin) "trf" took about twice as many trajectory
        # evaluations to the same minimum
        def fun(x):
            r = prob.residuals(x)[0]
            last["r"] = (np.array(x, float), r.copy())
            return r

        def jac(x):
            J = prob.jacobian(x, steps)
            last["J"] = (np.array(x, float), J.copy())
            return J

        res = least_squares(fun, x0, jac=jac, method="lm",
                            x_scale=scale, xtol=1e-10, ftol=1e-10, gtol=1e-10,
                            max_nfev=max_nfev)
        x_fit, success, message = res.x, bool(res.success), str(res.message)
    else:
        def objective(z):
            r = prob.residuals(x0 + scale * z)[0]
            return float(r @ r)
        opts = {"xtol": 1e-6, "ftol": 1e-12, "maxfev": max_nfev or 20000}
        res = minimize(objective, np.zeros(len(x0)), method="Powell", options=opts)
        x_fit, success, message = x0 + scale * res.x, bool(res.success), str(res.message)

    # Covariance from the Jacobian at the solution. The position rows are rescaled by the
    # residual variance of the data (s^2, so a wrong position_sigma does not matter), the prior
    # rows keep their stated sigmas (scaling them by s^2 too would shrink the uncertainty of
    # prior-dominated parameters such as the axial spin whenever the noise is overestimated).
    # (the optimiser's last evaluations are usually at the solution: the same numbers, reused)
    hit_r, hit_J = (k in last and np.array_equal(last[k][0], x_fit) for k in ("r", "J"))
    r = last["r"][1] if hit_r else prob.residuals(x_fit)[0]
    J = last["J"][1] if hit_J else prob.jacobian(x_fit, steps)
    n_data = len(prob.meas)
    rd = r[:n_data]
    s2 = float(rd @ rd) / max(n_data - len(x_fit), 1)
    Jd, Jp = J[:n_data], J[n_data:]
    # pseudo-inverses in the parameters' own scales (D = diag(scale)): unscaled, the cut-off of
    # pinv depended on the units and silently dropped a nearly undetermined axial spin (sigma
    # 0.1 rad/s reported for an axial spin undetermined to +-200 rad/s)

    def scaled_pinv(A):
        return scale[:, None] * np.linalg.pinv(scale[:, None] * A * scale[None, :]) * scale[None, :]
    cov_free = scaled_pinv(Jd.T @ Jd / max(s2, 1e-300) + Jp.T @ Jp)
    cov = np.zeros((len(free), len(free)))
    cov[np.ix_(free, free)] = cov_free
    # linear response of the parameters to a shift of the measured positions (the fit as a
    # linear estimator): d theta = G d positions, G = (J^T J)^-1 J_d^T / position_sigma
    # (with whitening W_n of position n: d theta = (J^T J)^-1 J_d^T W dP / position_sigma)
    gain_free = scaled_pinv(J.T @ J) @ Jd.T / position_sigma
    # ... and to the measured initial parameters: a shift d of theta_meas moves the prior rows
    # by -d / sigma, so d theta = (J^T J)^-1 J_p^T d / sigma (spin_prior_covariance_term)
    pgain = np.zeros((len(free), len(free)))
    pgain[np.ix_(free, prob.has_prior)] = scaled_pinv(J.T @ J) @ Jp.T / prob.prior_sigma
    gain = np.zeros((len(free), *positions.shape))
    g_view = np.zeros((len(free), n_data))
    g_view[free] = gain_free
    gain[:, prob.mask] = g_view
    if weights is not None:
        gain = np.einsum("pni,nij->pnj", gain, weights)
    theta = prob.full(x_fit)[0]
    if gyro:  # back to (s_a, s_1, s_2): parameters, covariance and gain
        T = np.eye(len(theta))
        T[6:9, 6:9] = _gyro_jacobian(theta[6:9])
        theta = theta.copy()
        theta[6:9] = _gyro_to_basis(theta[6:9])
        cov = T @ cov @ T.T
        gain = np.einsum("pq,qnk->pnk", T, gain)
        pgain = T @ pgain  # (no spin priors in the gyro parameterisation: no column to map)
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    p_fit, v_fit, s_fit = theta[:3], theta[3:6], theta[6:9]
    w_fit = basis @ s_fit
    cov_w = basis @ cov[6:9, 6:9] @ basis.T

    # the reference trajectory with the reference integrator, at the corrected times
    times_eff = prob.effective_times(theta[9:])
    ref = simulate(p_fit, v_fit, w_fit, times_eff, model, t0=t0)
    resid = ref.positions - positions
    errors = np.linalg.norm(resid, axis=1)
    full_rows = np.all(np.isfinite(resid), axis=1)
    e = errors[full_rows]
    nan = float("nan")
    return ReferenceFit(
        p0=p_fit, v0=v_fit, spin=w_fit,
        p0_sigma=sig[:3], v0_sigma=sig[3:6], spin_sigma=np.sqrt(np.clip(np.diag(cov_w), 0, None)),
        params=theta[:9], param_sigma=sig[:9], covariance=cov, spin_basis=basis,
        spin_transverse=s_fit[1:], spin_transverse_sigma=sig[7:9],
        time_offsets=theta[9:], time_offset_sigma=sig[9:],
        t0=t0, times=times_eff, positions=ref.positions, residuals=resid, errors=errors,
        mean_error=float(e.mean()) if len(e) else nan,
        max_error=float(e.max()) if len(e) else nan,
        rms_error=float(np.sqrt(np.mean(e ** 2))) if len(e) else nan,
        velocity_angle_deg=_angle_deg(v_fit, v0),
        speed_diff=float(np.linalg.norm(v_fit) - np.linalg.norm(v0)),
        spin_axis_angle_deg=_angle_deg(w_fit, spin_meas) if spin_meas is not None else nan,
        spin_rate_diff=(float(np.linalg.norm(w_fit) - np.linalg.norm(spin_meas))
                        if spin_meas is not None else nan),
        residual_scale=float(np.sqrt(s2)),
        success=success and ref.success, message=message, method=method,
        nfev=prob.nfev, fit_time_s=_time.perf_counter() - t_start, position_gain=gain,
        axial_spin_fitted=bool(fit_axial_spin), prior_gain=pgain,
        prior_sigma=np.where(prob.has_prior, sigmas, np.inf),
    )
