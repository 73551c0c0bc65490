"""What the pitch pipeline gives: :class:`PairResult` per stereo pair, :class:`PitchResult` per capture,
and their strict-JSON dictionaries (key names shared with the studio's ``truth.json``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap._selfcheck import checks_to_json
from stillcap.ball.fit import ReferenceFit
from stillcap.ball.metrics import MPH, RPM_PER_RAD_S, PitchMetrics
from stillcap.ball.orientation import MarkerObservations, SpinResult
from stillcap.ball.spin_from_flight import FlightSpin, SpinComparison
from stillcap.ball.stereo import StereoBalls
from stillcap.ball.uncertainty import speed_sigma
from stillcap.pipelines.pitch.options import PitchOptions

__all__ = ["PairResult", "PitchResult", "TABLE1_COLUMNS"]

#: The seed's Table 1 columns (in order) and their units.
TABLE1_COLUMNS = (("mean_err_mm", "mm"), ("max_err_mm", "mm"), ("velocity_angle_deg", "deg"),
                  ("speed_diff_mph", "mph"), ("spin_axis_angle_deg", "deg"), ("spin_rate_diff_rpm", "rpm"),
                  ("speed_mph", "mph"), ("spin_rpm", "rpm"))


@dataclass
class PairResult:
    """What one stereo pair gave (positions in flight order).

    Attributes
    ----------
    name : str
    cameras : tuple of 2 str
    strobe_hz : float
    flash_index : ndarray of int, shape (K,)
        Flash of each ball image counted from the pair's first ball image (gaps = missed flashes).
    positions : ndarray, shape (K, 3)
        Triangulated ball centres, world frame, m.
    centers_px : ndarray, shape (2, K, 2)
        Refined ball centres in the raw photos of both cameras.
    radius_px : ndarray, shape (2, K)
        Projected ball radius in each camera.
    reproj_error_px : ndarray, shape (K,)
    flags : ndarray of int, shape (K,)
        :class:`stillcap.detect.ball.BallFlag` bits of both views.
    n_detected : tuple of 2 int
        Ball silhouettes found in each photo.
    n_dropped : int
        Matched ball images dropped (refinement failed, size mismatch, off the flight path, duplicate).
    spacing_m : float
        Distance between consecutive flashes (base spacing), m.
    group : int
        Clock of the reference fit (0 = reference pair).
    time_offset_s, time_offset_sigma_s : float
        Clock offset: flash ``k`` happened at ``time_offset_s + k / strobe_hz`` on the reference
        clock (0 for the reference pair).
    markers : list of BallMarkers
        Markers found in each camera's photo (``ball_index`` = position index).
    observations : MarkerObservations
        Marker directions (``flash`` = position index).
    n_markers_3d, n_markers_ray : int
        Markers triangulated across the pair / seen by one camera only.
    marker_reproj_px : float
        Median epipolar distance of the matched markers.
    spin : SpinResult or None
        The pair's own spin fit (principal alias, on its own clock).
    position_sigma_m : float
        1-sigma per coordinate of the positions: RMS residual to the reference trajectory and
        the calibration term (``calibration_sigma_m``) in quadrature.
    calibration_sigma_m : float
        1-sigma per coordinate (RMS over the pair's positions) of the shift the calibration
        error gives all positions of the pair (:func:`stillcap.ball.uncertainty.calibration_modes`);
        NaN without a calibration record.
    position_covariance_m2 : ndarray, shape (K, 3, 3) or None
        Error covariance of each position (m^2): the triangulation geometry's shape (depth along
        the lines of sight) at the level of the pair's residuals, plus the shared calibration
        and centre-bias modes (:func:`stillcap.ball.uncertainty.position_covariances`). Test a
        position with ``e^T C^-1 e`` against chi-square(3); ``position_sigma_m`` is its
        isotropic summary.
    """

    name: str
    cameras: tuple
    strobe_hz: float
    flash_index: np.ndarray
    positions: np.ndarray
    centers_px: np.ndarray
    radius_px: np.ndarray
    reproj_error_px: np.ndarray
    flags: np.ndarray
    n_detected: tuple
    n_dropped: int
    spacing_m: float
    group: int = 0
    time_offset_s: float = 0.0
    time_offset_sigma_s: float = 0.0
    markers: list = field(default_factory=list, repr=False)
    observations: MarkerObservations | None = field(default=None, repr=False)
    n_markers_3d: int = 0
    n_markers_ray: int = 0
    marker_reproj_px: float = float("nan")
    spin: SpinResult | None = field(default=None, repr=False)
    position_sigma_m: float = float("nan")
    stereo: StereoBalls | None = field(default=None, repr=False)
    calibration_sigma_m: float = float("nan")
    position_covariance_m2: np.ndarray | None = field(default=None, repr=False)

    @property
    def local_times(self) -> np.ndarray:
        """``flash_index / strobe_hz``, s (the pair's own clock)."""
        return self.flash_index / self.strobe_hz

    @property
    def times(self) -> np.ndarray:
        """Times on the reference clock, s."""
        return self.time_offset_s + self.local_times

    def __len__(self) -> int:
        return len(self.positions)

    def to_dict(self) -> dict:
        n_mk = (self.observations.counts(len(self)) if self.observations is not None and len(self)
                else np.zeros(len(self), int))
        return {
            "name": self.name, "cameras": list(self.cameras), "strobe_hz": self.strobe_hz,
            "flash_index": self.flash_index, "times_s": self.times, "positions": self.positions,
            "position_sigma_mm": self.position_sigma_m * 1e3, "calibration_sigma_mm": self.calibration_sigma_m * 1e3,
            "position_covariance_mm2": (None if self.position_covariance_m2 is None
                                        else self.position_covariance_m2 * 1e6),
            "centers_px": self.centers_px,
            "radius_px": self.radius_px, "reproj_error_px": self.reproj_error_px, "flags": self.flags,
            "n_detected": list(self.n_detected), "n_dropped": self.n_dropped, "spacing_m": self.spacing_m,
            "time_offset_s": self.time_offset_s, "time_offset_sigma_s": self.time_offset_sigma_s,
            "markers_per_flash": n_mk, "n_markers_3d": self.n_markers_3d, "n_markers_ray": self.n_markers_ray,
            "spin": None if self.spin is None else self.spin.to_dict(),
            # the lens blur each camera's shading correction used (read from the balls' limbs)
            "blur_px": None if self.stereo is None else [float(v) for v in self.stereo.psf_px],
        }


@dataclass
class PitchResult:
    """Everything :func:`~stillcap.pipelines.pitch.analyse_pitch` measured (SI, world frame of the rig).

    Attributes
    ----------
    frame : str
        The rig's world frame (``"field"`` for metrics in baseball conventions).
    options : PitchOptions
    pairs : list of PairResult
        In flight order; ``pairs[0]`` is the reference clock.
    times : ndarray, shape (N,)
        All ball images on the reference clock (0 = first ball image of the front pair), s.
    positions : ndarray, shape (N, 3)
    pair_index : ndarray of int, shape (N,)
        Pair of each position.
    velocity_two_point, velocity_two_point_sigma : ndarray, shape (3,)
        The seed's estimate at ``t = 0`` (line through the first two positions, m/s) and its 1-sigma.
    fit : ReferenceFit
        The reference trajectory (positions + measured initial parameters).
    fit_positions_only : ReferenceFit
        The fit without a measured spin (curvature only: the spin transverse to the flight).
    spin : SpinResult or None
        The spin measured from the markers (chosen alias), None when unavailable.
    alias : object or None
        The alias ranking (:mod:`stillcap.ball.alias`) when the rate was checked.
    metrics : PitchMetrics
    metrics_sigma : dict
        1-sigma of every numeric metric (same keys).
    release : dict
        Release state where the metrics are evaluated: ``t0_s``, ``p0``, ``v0``, ``spin`` (+ ``_sigma``).
    table1 : dict
        The seed's Table 1 columns (reference fit against the measured initial parameters).
    messages : list of str
        Everything the user should know (skipped pairs, missing markers, ambiguous aliases, ...).
    timings_s : dict
    truth : dict or None
        The comparison with a studio truth (:func:`stillcap.studio.compare.pitch.compare_with_truth`),
        set by the caller that holds one (the pipeline never reads a truth).
    spin_obs_times : ndarray, shape (M,) or None
        Reference-clock time of each marker observation of ``spin`` (plots).
    flight_spin : FlightSpin or None
        The spin the flight alone shows (positions-only fit; transverse, at ``t = 0``):
        :mod:`stillcap.ball.spin_from_flight`.
    spin_comparison : SpinComparison or None
        With markers: the marker spin against ``flight_spin`` (chi-square, agreement, spin
        efficiency from the two).
    self_checks : list of SelfCheck
        What the photos show against what the model expects
        (:mod:`stillcap.pipelines.pitch.checks`); ``self_checks`` in JSON.
    response : dict or None
        The cameras' responses used and where they came from (rig, option, auto with its
        estimates and evidence), and each camera's shading estimate.
    """

    frame: str
    options: PitchOptions
    pairs: list
    times: np.ndarray
    positions: np.ndarray
    pair_index: np.ndarray
    velocity_two_point: np.ndarray
    velocity_two_point_sigma: np.ndarray
    fit: ReferenceFit
    fit_positions_only: ReferenceFit
    spin: SpinResult | None
    alias: object
    metrics: PitchMetrics
    metrics_sigma: dict
    release: dict
    table1: dict
    messages: list
    timings_s: dict = field(default_factory=dict)
    capture_root: str | None = None
    truth: dict | None = None
    spin_obs_times: np.ndarray | None = field(default=None, repr=False)
    flight_spin: FlightSpin | None = field(default=None, repr=False)
    spin_comparison: SpinComparison | None = field(default=None, repr=False)
    self_checks: list = field(default_factory=list)
    response: dict | None = None

    @property
    def spin_source(self) -> str | None:
        """Where the reported spin comes from: ``"markers"``, ``"flight"`` (no markers: the
        flight's transverse spin) or None."""
        if self.spin_available:
            return "markers"
        return "flight" if self.flight_spin is not None else None

    def spin_reported(self) -> dict | None:
        """The spin the result reports, flagged with its source (``spin_reported`` in JSON)."""
        if self.spin_available:
            return {"source": "markers", "transverse_only": False, "spin": self.release.get("spin"),
                    "spin_rpm": self.release.get("spin_rpm"), "spin_sigma_rpm": self.spin.sigma_rpm,
                    "axis_sigma_deg": self.spin.sigma_axis_deg}
        f = self.flight_spin
        if f is None:
            return None
        return {"source": "flight", "transverse_only": True, "lift_from": f.lift_from, "spin": f.spin,
                "spin_rpm": f.rate_rpm, "spin_sigma_rpm": f.rate_sigma_rpm, "axis_sigma_deg": f.axis_sigma_deg}

    @property
    def spin_available(self) -> bool:
        return self.spin is not None and bool(self.spin.success)

    @property
    def release_speed_mph(self) -> float:
        return float(self.metrics.release_speed_mph)

    def to_dict(self) -> dict:
        """Strict-JSON-ready summary; key names shared with the studio's ``truth.json``."""
        from stillcap.files.jsonable import to_jsonable

        fit = self.fit
        w = self.release.get("spin") if self.spin_available else None
        d = {
            "format": "stillcap-pitch", "version": 1, "kind": "pitch", "frame": self.frame,
            "units": {"length": "m", "time": "s (0 = first ball image of the front pair)", "spin": "rad/s",
                      "pixels": "px (x, y), origin top-left pixel centre"},
            "capture": self.capture_root, "options": self.options.to_dict(), "model": self.options.flight_name,
            "cameras": [c for p in self.pairs for c in p.cameras],
            "strobe_hz": {p.name: p.strobe_hz for p in self.pairs},
            "metrics": self.metrics.to_dict(),
            "metrics_sigma": self.metrics_sigma,
            "release": self.release,
            "spin": w, "spin_rpm": self.release.get("spin_rpm") if self.spin_available else None,
            "spin_sigma_rpm": self.spin.sigma_rpm if self.spin_available else None,
            "spin_axis_sigma_deg": self.spin.sigma_axis_deg if self.spin_available else None,
            "spin_fit": None if self.spin is None else self.spin.to_dict(),
            "alias": _alias_dict(self.alias),
            "plate_time_s": self.metrics.plate_time_s,
            "time_offsets_s": {p.name: p.time_offset_s for p in self.pairs},
            "time_offsets_sigma_s": {p.name: p.time_offset_sigma_s for p in self.pairs},
            "velocity": {
                "two_point": self.velocity_two_point, "two_point_sigma": self.velocity_two_point_sigma,
                "two_point_speed_mph": float(np.linalg.norm(self.velocity_two_point) / MPH),
                "two_point_speed_sigma_mph": speed_sigma(self.velocity_two_point,
                                                         np.diag(self.velocity_two_point_sigma ** 2)) / MPH,
                "fitted": fit.v0, "fitted_sigma": fit.v0_sigma,
                "fitted_speed_mph": float(np.linalg.norm(fit.v0) / MPH),
                "fitted_speed_sigma_mph": speed_sigma(fit.v0, fit.covariance[3:6, 3:6]) / MPH,
            },
            "reference_fit": _fit_dict(fit),
            "reference_fit_positions_only": _fit_dict(self.fit_positions_only),
            "table1": self.table1,
            "pairs": [p.to_dict() for p in self.pairs],
            "messages": list(self.messages),
            "timings_s": self.timings_s,
        }
        # added keys (spin from flight): the existing ones above keep their meaning
        d["spin_source"] = self.spin_source
        d["spin_reported"] = self.spin_reported()
        d["spin_from_flight"] = None if self.flight_spin is None else self.flight_spin.to_dict()
        d["spin_comparison"] = None if self.spin_comparison is None else self.spin_comparison.to_dict()
        d["response"] = self.response
        # an ambiguous spin alias (the alias_margin check failed): every alias the photos allow,
        # the reported one first; the reported intervals cover them all
        from stillcap.pipelines.pitch.checks import ambiguous_alias_candidates

        others = ambiguous_alias_candidates(self.self_checks, self.alias) if self.spin_available else []
        d["spin_ambiguous"] = bool(others)
        d["spin_candidates"] = ([{"spin": self.spin.spin, "spin_rpm": self.spin.spin_rpm, "axis": self.spin.axis,
                                  "reported": True}]
                                + [{"spin": c.spin, "spin_rpm": c.spin_rpm, "axis": c.axis, "reported": False,
                                    "chi2_above_best": float(c.chi2 - self.alias.best.chi2)} for c in others]
                                if others else None)
        d["self_checks"] = checks_to_json(self.self_checks)
        if self.truth is not None:
            d["truth_comparison"] = self.truth
        return to_jsonable(d)


def _fit_dict(fit: ReferenceFit) -> dict:
    return {
        "method": fit.method, "success": fit.success, "message": fit.message, "t0_s": fit.t0,
        "p0": fit.p0, "p0_sigma": fit.p0_sigma, "v0": fit.v0, "v0_sigma": fit.v0_sigma,
        "spin": fit.spin, "spin_sigma": fit.spin_sigma, "spin_rpm": float(np.linalg.norm(fit.spin) * RPM_PER_RAD_S),
        "spin_transverse": fit.spin_transverse, "spin_transverse_sigma": fit.spin_transverse_sigma,
        "spin_transverse_rpm": float(np.linalg.norm(fit.spin_transverse) * RPM_PER_RAD_S),
        "time_offsets_s": fit.time_offsets, "time_offset_sigma_s": fit.time_offset_sigma,
        "mean_error_mm": fit.mean_error * 1e3, "max_error_mm": fit.max_error * 1e3,
        "rms_error_mm": fit.rms_error * 1e3, "residual_scale": fit.residual_scale,
        "times_s": fit.times, "positions": fit.positions, "errors_mm": fit.errors * 1e3,
        "nfev": fit.nfev, "fit_time_s": fit.fit_time_s,
    }


def _alias_dict(alias) -> dict | None:
    if alias is None:
        return None
    cands = [{"spin": c.spin, "spin_rpm": c.spin_rpm, "axis": c.axis, "n": int(c.n), "source": int(c.source),
              "axis_determined": bool(c.axis_determined), "chi2_strobes": c.chi2_strobes,
              "chi2_curvature": c.chi2_curvature, "chi2_markers": float(c.chi2_markers), "chi2": c.chi2,
              "probability": c.probability}
             for c in alias.candidates[:6]]
    return {"best_rpm": alias.best.spin_rpm, "ambiguous": bool(alias.ambiguous),
            "likelihood_ratio": alias.likelihood_ratio, "evidence": list(alias.evidence),
            "consistent": bool(alias.consistent), "dof": int(alias.dof),
            "best_chi2": float(alias.best.chi2), "left_out": list(getattr(alias, "left_out", [])),
            "undecided_rpm": [float(c.spin_rpm) for c in getattr(alias, "undecided", [])],
            "message": alias.message, "candidates": cands}
