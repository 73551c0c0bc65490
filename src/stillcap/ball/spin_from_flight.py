"""Spin from the flight alone: the transverse spin of a ball fitted to its 3-D trajectory.

A spinning ball's Magnus force is ``(w x v)``: only the spin component transverse to the
velocity, ``w_perp = w - (w . v_hat) v_hat``, bends the flight. The component along the velocity
(gyro spin) produces no Magnus force and cannot be seen from positions (it becomes weakly visible
only as gravity turns the velocity). So the flight gives ``w_perp``: its rate and its axis, which
lies in the plane perpendicular to the velocity.

:func:`spin_from_flight` fits it with the drag + lift model (:mod:`stillcap.ball.physics`)
through the reference-trajectory fit (:func:`stillcap.ball.fit.fit_reference_trajectory`, no
measured spin), and :func:`transverse_spin_from_fit` reads it from any such fit (the pitch
pipeline's positions-only fit). The uncertainty is the fit's covariance (Jacobian, scaled by the
residual variance per degree of freedom) projected on the transverse plane; 1-sigma of the rate
and of the axis direction within that plane are reported.

:func:`compare_spins` tests a spin measured another way (a marked ball) against it: the marker
spin's transverse part minus the flight spin, chi-square with 2 degrees of freedom in the
transverse plane with both covariances, and the spin efficiency ``|w_perp| / |w|`` from the two
(transverse from the flight, total from the markers).

The "up" direction is the opposite of the model's gravity (any direction), or given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
# chi2.sf(x, k) is scipy.special.chdtrc(k, x) (what scipy.stats computes): importing scipy.stats costs
# 0.4-1 s per CLI call
from scipy.special import chdtrc as _chdtrc

from stillcap._checks import as_array
from stillcap.ball.fit import ReferenceFit, fit_reference_trajectory
from stillcap.ball.physics import RPM_PER_RAD_S, flight_model

__all__ = ["FlightSpin", "SpinComparison", "spin_from_flight", "transverse_spin_from_fit", "compare_spins",
           "MIN_POSITIONS"]

#: Fewest observed positions :func:`spin_from_flight` accepts: 9 parameters (position, velocity,
#: spin) need more than 3 positions (3 coordinates each) to leave residuals for the uncertainty.
MIN_POSITIONS = 4


@dataclass
class FlightSpin:
    """The transverse spin a flight shows, at the fit's ``t0``.

    Attributes
    ----------
    spin : ndarray, shape (3,)
        Transverse spin vector, rad/s, world frame (perpendicular to ``velocity``).
    covariance : ndarray, shape (3, 3)
        Its covariance, (rad/s)^2 (rank 2: within the transverse plane).
    rate_rpm, rate_sigma_rpm : float
        ``|spin|`` and its 1-sigma, rpm.
    axis : ndarray, shape (3,)
        Unit spin axis (NaN when the rate is 0).
    axis_sigma_deg : float
        1-sigma of the axis direction within the transverse plane, deg (NaN when the rate is 0).
    axis_tilt_deg : float
        The axis's angle in the transverse plane, deg: 0 when it points along the horizontal
        ``v_hat x up`` (backspin for a ball moving horizontally), 90 along ``up x`` that
        horizontal (side spin turning about the up-ish direction); NaN when the rate is 0.
    velocity : ndarray, shape (3,)
        Fitted velocity at ``t0``, m/s.
    up : ndarray, shape (3,)
        Unit up direction the tilt is measured with.
    t0 : float
    rms_error_m, cross_track_rms_m : float
        RMS of the 3-D residuals, and of their part across the flight direction, m.
    residual_scale : float
        The fit's ``s`` (whitened residual RMS; 1 when ``position_sigma`` was the noise).
    n_positions : int
    fit : ReferenceFit
        The underlying fit (positions, residuals, full covariance).
    lift_from : {"transverse", "total"}
        What the model's lift depends on. ``"transverse"`` (Nathan's model, any model whose lift
        is ``w_perp``'s): ``spin`` is the transverse spin. ``"total"`` (the seed model, whose
        ``C_L`` grows with the total rate ``|w|``): the flight sees the *effective* transverse
        spin ``|w| w_perp / |w_perp|``, the total rate along the transverse axis, so ``spin`` is
        that, and the spin efficiency cannot come from the flight.
    """

    spin: np.ndarray
    covariance: np.ndarray
    rate_rpm: float
    rate_sigma_rpm: float
    axis: np.ndarray
    axis_sigma_deg: float
    axis_tilt_deg: float
    velocity: np.ndarray
    up: np.ndarray
    t0: float
    rms_error_m: float
    cross_track_rms_m: float
    residual_scale: float
    n_positions: int
    fit: ReferenceFit = field(repr=False)
    lift_from: str = "transverse"

    def interval95(self) -> tuple[float, float]:
        """Half-widths of the 95 % intervals of (rate rpm, axis deg): 1.96 sigma."""
        return 1.96 * self.rate_sigma_rpm, 1.96 * self.axis_sigma_deg

    def to_dict(self) -> dict:
        return {
            "source": "flight", "transverse_only": True, "t0_s": self.t0,
            "spin": self.spin, "spin_rpm": self.rate_rpm, "spin_sigma_rpm": self.rate_sigma_rpm,
            "axis": self.axis, "axis_sigma_deg": self.axis_sigma_deg, "axis_tilt_deg": self.axis_tilt_deg,
            "spin_covariance": self.covariance, "velocity": self.velocity, "up": self.up,
            "lift_from": self.lift_from, "rms_error_mm": self.rms_error_m * 1e3, "cross_track_rms_mm": self.cross_track_rms_m * 1e3,
            "residual_scale": self.residual_scale, "n_positions": self.n_positions,
        }


@dataclass
class SpinComparison:
    """A measured spin (markers) against the flight's transverse spin (:func:`compare_spins`).

    Attributes
    ----------
    marker_transverse : ndarray, shape (3,)
        Transverse part of the measured spin (perpendicular to the flight's velocity), rad/s.
    marker_transverse_rpm, flight_rpm, marker_rpm : float
    difference_rpm : float
        ``|marker_transverse - flight spin|``, rpm.
    rate_diff_rpm : float
        ``|flight| - |marker_transverse|``, rpm.
    axis_angle_deg : float
        Angle between the two transverse axes, deg.
    chi2, p_value : float
        ``d^T (C_m + C_f)^-1 d`` over the 2 transverse dimensions and its chi-square(2) tail.
    dof : int
    agree : bool
        ``p_value >= alpha`` (default 1 %).
    spin_efficiency, spin_efficiency_sigma : float
        ``|flight spin| / |marker spin|`` (transverse / total) and its 1-sigma; NaN when the
        flight's lift follows the total rate (seed model: the flight does not see the gyro part).
    marker_transverse : the marker spin's counterpart of the flight spin: its transverse part,
        or with ``lift_from == "total"`` its total rate along the transverse axis.
    """

    marker_transverse: np.ndarray
    marker_transverse_rpm: float
    marker_rpm: float
    flight_rpm: float
    difference_rpm: float
    rate_diff_rpm: float
    axis_angle_deg: float
    chi2: float
    dof: int
    p_value: float
    agree: bool
    alpha: float
    spin_efficiency: float
    spin_efficiency_sigma: float

    def to_dict(self) -> dict:
        return {
            "marker_transverse": self.marker_transverse, "marker_transverse_rpm": self.marker_transverse_rpm,
            "marker_rpm": self.marker_rpm, "flight_rpm": self.flight_rpm, "difference_rpm": self.difference_rpm,
            "rate_diff_rpm": self.rate_diff_rpm, "axis_angle_deg": self.axis_angle_deg,
            "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value, "agree": self.agree, "alpha": self.alpha,
            "spin_efficiency": self.spin_efficiency, "spin_efficiency_sigma": self.spin_efficiency_sigma,
        }


def _up_from(model, up) -> np.ndarray:
    if up is None:
        g = getattr(model, "gravity", None)
        g = np.array([0.0, 0.0, -1.0]) if g is None else np.asarray(g, float)
        if g.shape != (3,) or not np.all(np.isfinite(g)) or not np.linalg.norm(g) > 0:
            raise ValueError(f"the model's gravity gives no up direction (gravity {g}); pass up=")
        return -g / np.linalg.norm(g)
    u = as_array(up, (3,), "up")
    n = np.linalg.norm(u)
    if not (np.all(np.isfinite(u)) and n > 0):
        raise ValueError(f"up must be a finite non-zero vector, got {u}")
    return u / n


def _transverse_frame(velocity, up) -> np.ndarray:
    """Columns ``(v_hat, h, n)``: ``h = v_hat x up`` (horizontal), ``n = h x v_hat`` (up-ish)."""
    vh = velocity / np.linalg.norm(velocity)
    h = np.cross(vh, up)
    if np.linalg.norm(h) < 1e-9:  # vertical flight: any horizontal
        h = np.cross(vh, np.eye(3)[int(np.argmin(np.abs(vh)))])
    h /= np.linalg.norm(h)
    return np.stack([vh, h, np.cross(h, vh)], axis=1)


def transverse_spin_from_fit(fit: ReferenceFit, up=None, *, model=None) -> FlightSpin:
    """The transverse spin of a fitted flight (a :class:`ReferenceFit` fitted without a measured
    spin, e.g. the pitch pipeline's positions-only fit), with its uncertainty.

    Parameters
    ----------
    fit : ReferenceFit
    up : array_like, shape (3,), optional
        Up direction (for the axis tilt); default the opposite of ``model``'s gravity, or z.
    model : flight model, optional
        For its gravity and its lift (the seed model's lift grows with the total rate:
        :attr:`FlightSpin.lift_from`).

    Returns
    -------
    FlightSpin
    """
    up = _up_from(model, up)
    v = np.asarray(fit.v0, float)
    if not (np.all(np.isfinite(v)) and np.linalg.norm(v) > 0):
        raise ValueError(f"the fit's velocity must be finite and non-zero, got {v}")
    F = _transverse_frame(v, up)
    vh, T = F[:, 0], F[:, 1:]
    P = T @ T.T  # projector on the transverse plane
    B = np.asarray(fit.spin_basis, float)
    w = np.asarray(fit.spin, float)
    w_perp = P @ w
    M = P @ B
    lift = "total" if getattr(model, "kind", None) == "seed" else "transverse"
    if lift == "total" and np.linalg.norm(w_perp) > 0:
        # the seed model's lift is |w| along w_perp: the flight sees e = |w| w_perp / |w_perp|
        nw, nt = float(np.linalg.norm(w)), float(np.linalg.norm(w_perp))
        u = w_perp / nt
        M = (np.outer(u, w) / nw + nw / nt * (P - np.outer(u, u) @ P)) @ B
        w_perp = nw * u
    cov = M @ np.asarray(fit.covariance, float)[6:9, 6:9] @ M.T
    cov = 0.5 * (cov + cov.T)
    c2 = T.T @ cov @ T  # 2x2 in (h, n)
    s2 = T.T @ w_perp
    rate = float(np.linalg.norm(s2))
    nan = float("nan")
    if rate > 0:
        u = s2 / rate
        perp = np.array([-u[1], u[0]])
        rate_sig = float(np.sqrt(max(u @ c2 @ u, 0.0)))
        axis_sig = float(np.degrees(np.sqrt(max(perp @ c2 @ perp, 0.0)) / rate))
        axis = w_perp / rate
        tilt = float(np.degrees(np.arctan2(s2[1], s2[0])))
    else:
        rate_sig = float(np.sqrt(max(np.trace(c2) / 2.0, 0.0)))
        axis_sig, axis, tilt = nan, np.full(3, nan), nan
    res = np.asarray(fit.residuals, float)
    ok = np.all(np.isfinite(res), axis=1)
    r = res[ok]
    vfit = np.asarray(fit.positions, float)[ok]
    # cross-track: the residual minus its part along the local flight direction (differences of
    # the fitted trajectory; timestamps' jitter moves points along it)
    if len(vfit) >= 2:
        d = np.gradient(vfit, axis=0)
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        rc = r - np.sum(r * d, axis=1, keepdims=True) * d
    else:
        rc = r
    rms = float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) if len(r) else nan
    cross = float(np.sqrt(np.mean(np.sum(rc ** 2, axis=1)))) if len(r) else nan
    return FlightSpin(spin=w_perp, covariance=cov, rate_rpm=rate * RPM_PER_RAD_S,
                      rate_sigma_rpm=rate_sig * RPM_PER_RAD_S, axis=axis, axis_sigma_deg=axis_sig,
                      axis_tilt_deg=tilt, velocity=v.copy(), up=up, t0=float(fit.t0), rms_error_m=rms,
                      cross_track_rms_m=cross, residual_scale=float(fit.residual_scale),
                      n_positions=int(ok.sum()), fit=fit, lift_from=lift)


def spin_from_flight(times, positions, model=None, *, position_sigma: float = 0.002, up=None,
                     t0: float | None = None, p0=None, v0=None, position_covariance=None,
                     max_nfev: int | None = None, where: str = "") -> FlightSpin:
    """Fit the transverse spin (rate and axis) of a ball from its 3-D positions alone.

    Parameters
    ----------
    times : array_like, shape (N,)
        s, distinct.
    positions : array_like, shape (N, 3)
        m, in the model's world frame; rows with NaN are left out.
    model : flight model or name, optional
        Drag + lift model (:func:`stillcap.ball.physics.flight_model`; default the seed model).
    position_sigma : float
        Expected noise per coordinate, m (the uncertainty is rescaled by the residuals anyway).
    up : array_like, shape (3,), optional
        Default: the opposite of the model's gravity.
    t0 : float, optional
        Time of the reported spin and velocity (default the first time).
    p0, v0 : array_like, shape (3,), optional
        Starting guesses (default: a quadratic through the positions, at ``t0``).
    position_covariance : array_like, shape (N, 3, 3), optional
        Shape of each position's error covariance (:func:`fit_reference_trajectory`).
    where : str
        Names the source in error messages (e.g. a file name).

    Returns
    -------
    FlightSpin

    Raises
    ------
    ValueError
        Fewer than :data:`MIN_POSITIONS` complete positions, repeated or non-finite times, or a
        flight with no velocity.
    """
    src = f"{where}: " if where else ""
    model = flight_model(model)
    times = as_array(times, (None,), "times")
    positions = as_array(positions, (len(times), 3), "positions")
    if not np.all(np.isfinite(times)):
        raise ValueError(f"{src}times must be finite")
    ok = np.all(np.isfinite(positions), axis=1)
    n = int(ok.sum())
    if n < MIN_POSITIONS:
        raise ValueError(f"{src}spin from flight needs at least {MIN_POSITIONS} positions (position, velocity and "
                         f"spin: 9 parameters), got {n}")
    if len(np.unique(times[ok])) != n:
        raise ValueError(f"{src}times of the positions must be distinct")
    up = _up_from(model, up)
    t_ok, p_ok = times[ok], positions[ok]
    t0 = float(t_ok.min()) if t0 is None else float(t0)
    if p0 is None or v0 is None:
        coef, *_ = np.linalg.lstsq(np.vander(t_ok - t0, 3), p_ok, rcond=None)
        p0 = coef[2] if p0 is None else p0
        v0 = coef[1] if v0 is None else v0
    v0 = as_array(v0, (3,), "v0")
    if not np.linalg.norm(v0) > 0:
        raise ValueError(f"{src}the positions show no motion: no velocity to fit a spin to")
    fit = fit_reference_trajectory(times, positions, p0, v0, None, model, t0=t0, position_sigma=position_sigma,
                                   position_covariance=position_covariance, max_nfev=max_nfev)
    return transverse_spin_from_fit(fit, up, model=model)


def compare_spins(flight: FlightSpin, spin, spin_covariance, *, alpha: float = 0.01) -> SpinComparison:
    """A spin measured another way (markers, at the flight's ``t0``) against the flight's.

    Parameters
    ----------
    flight : FlightSpin
    spin : array_like, shape (3,)
        Measured (total) spin, rad/s, world frame, at ``flight.t0``.
    spin_covariance : array_like, shape (3, 3)
        Its covariance, (rad/s)^2 (NaN entries: treated as 0, only the flight's uncertainty).
    alpha : float
        Significance of the agreement test (``agree`` when the chi-square(2) tail is at least it).

    Returns
    -------
    SpinComparison
    """
    w = as_array(spin, (3,), "spin")
    C = np.nan_to_num(as_array(spin_covariance, (3, 3), "spin_covariance"))
    F = _transverse_frame(flight.velocity, flight.up)
    T = F[:, 1:]
    wm2 = T.T @ w
    effective = flight.lift_from == "total"
    if effective and np.linalg.norm(wm2) > 0:  # the seed model's flight sees |w| along w_perp
        nw, nt = float(np.linalg.norm(w)), float(np.linalg.norm(wm2))
        u = wm2 / nt
        J2 = np.outer(u, w) / nw + nw / nt * (T.T - np.outer(u, u) @ T.T)
        wm2 = nw * u
    else:
        J2 = T.T
    wf2 = T.T @ flight.spin
    d = wm2 - wf2
    c2 = J2 @ (0.5 * (C + C.T)) @ J2.T + T.T @ flight.covariance @ T
    chi2 = float(d @ np.linalg.pinv(c2) @ d)
    p = float(_chdtrc(2, chi2))
    rm, rf, rt = float(np.linalg.norm(wm2)), float(np.linalg.norm(wf2)), float(np.linalg.norm(w))
    ang = float(np.degrees(np.arctan2(abs(wm2[0] * wf2[1] - wm2[1] * wf2[0]), wm2 @ wf2))) if rm > 0 and rf > 0 \
        else float("nan")
    if rt > 0 and not effective:
        eff = rf / rt
        sf = flight.rate_sigma_rpm / RPM_PER_RAD_S
        st = float(np.sqrt(max(w @ C @ w, 0.0))) / rt
        eff_sig = float(np.sqrt((sf / rt) ** 2 + (eff * st / rt) ** 2))
    else:
        eff = eff_sig = float("nan")
    return SpinComparison(marker_transverse=T @ wm2, marker_transverse_rpm=rm * RPM_PER_RAD_S,
                          marker_rpm=rt * RPM_PER_RAD_S, flight_rpm=rf * RPM_PER_RAD_S,
                          difference_rpm=float(np.linalg.norm(d)) * RPM_PER_RAD_S,
                          rate_diff_rpm=(rf - rm) * RPM_PER_RAD_S, axis_angle_deg=ang, chi2=chi2, dof=2,
                          p_value=p, agree=bool(p >= alpha), alpha=float(alpha), spin_efficiency=float(eff),
                          spin_efficiency_sigma=eff_sig)
