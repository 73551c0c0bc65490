"""The result of both spin fits (:class:`SpinResult`), the rate and axis with their 1-sigma from a
spin vector and its covariance, and the result of a fit that could not run."""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array

from stillcap._numeric import RPM_PER_RAD_S  # noqa: E402 (the one definition)


@dataclass
class SpinResult:
    """Spin of a ball from its markers over several flashes.

    Attributes
    ----------
    spin : ndarray, shape (3,)
        Spin vector, rad/s, world frame (right-hand rule). The principal alias unless the fit
        was started at another one ("Aliasing" in :mod:`stillcap.ball.orientation`).
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
        RMS residual angle of the inliers; with weighted observations
        (``MarkerObservations.information``) the RMS of the weighted residuals in the angle of
        the median observation's weight (a marker near the limb counts with the precision its
        centroid has there).
    n_observations, n_inliers : int
    success : bool
    message : str
    method : str
        ``"global"`` or ``"seed"``.
    fit_time_s : float
    noise_px : float
        The marker-centroid noise the global fit's residuals show, px (1-sigma per image
        coordinate), when the observations carry ``information``; NaN otherwise. The spin's
        covariance is scaled by it.
    dof : int
        The final fit's informative residual components minus its 6 parameters:
        ``sum(residual_ranks[inliers]) - 6`` (one component for a marker cut by the limb; 0 when unknown).
        ``noise_px`` and the spin's covariance are scaled by the residuals' sum of squares over it.
    residuals_noise : ndarray, shape (M,) or None
        Each observation's residual length in the units of the fit's noise (global fit): with
        weighted observations the weighted residual in centroid pixels (what ``noise_px``
        measures), otherwise the angle in rad; the nearest marker of its type at the solution,
        every observation (outliers too). None when not computed (the seed method).
    residual_ranks : ndarray of int, shape (M,) or None
        How many of each observation's two residual components carry information: 1 for a
        marker cut by the limb, whose centroid fixes only its direction around the line of
        sight (:func:`direction_information`), else 2. The redundancy of the fit is
        ``sum(ranks[inliers]) - 6`` (:func:`stillcap.ball.alias.marker_misfit_test`).
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
    noise_px: float = float("nan")
    dof: int = 0
    residuals_noise: np.ndarray | None = None
    residual_ranks: np.ndarray | None = None

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
                "marker_noise_px": f(self.noise_px),
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
