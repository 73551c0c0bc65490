"""The pitch pipeline (SPEC J1): strobe photos of a pitched, marked baseball -> flight, spin, metrics.

Wiring only; every step is a stage of its own module (``docs/pitch.md`` tells the whole story):

1. **Stereo pairs** (:func:`stereo_pairs`): the capture's photos grouped into strobed pairs (by
   ``images[].meta.pair``, the capture's ``pairs`` map, or the strobe rate), each with its rate.
2. **Ball positions** per pair (:func:`stillcap.ball.stereo.ball_centers_stereo`, the seed's steps
   1-5): colour background subtraction, contours, convex hull, ellipse, epipolar matching,
   approximate triangulation, projected radius, known-radius Hough refinement (half moons
   included), final triangulation. Off-path detections are dropped.
3. **Order and timing** (:func:`order_flashes`): the 3D positions of a pair are ordered along the
   flight; the flash index ``k`` of each comes from the spacing (``round(spacing / base
   spacing)``, a missed flash leaves a gap); the pair's own clock is ``k / strobe_hz`` from its
   first ball image. The first pair along the flight (the front pair) is the reference clock
   (``t = 0`` at its first ball image); the other pairs' clock offsets are unknown (free-running
   strobes) and fitted with the flight (``time_groups`` of the reference fit).
4. **Markers** (:func:`pair_marker_observations`): coloured regions inside every ball image
   (:func:`stillcap.detect.ball_markers.detect_ball_markers`), matched across the pair by type and
   epipolar distance and triangulated (direction from the ball centre); markers seen by one
   camera only become pixel rays intersected with the ball sphere.
5. **Spin**: ``"global"`` (default) fits one constant spin to all flashes of a pair
   (:func:`stillcap.ball.orientation.fit_spin`), ``"seed"`` is the seed's per-flash Powell method
   (:func:`~stillcap.ball.orientation.fit_spin_seed`). The alias above the strobe's Nyquist limit
   is chosen with both strobe rates and the Magnus curvature of the flight
   (:mod:`stillcap.ball.alias`); the global method then refits all pairs' markers together on the
   reference clock at that alias.
6. **Release velocity**: the seed's two-point estimate and the fitted one.
7. **Reference trajectory** (:func:`stillcap.ball.fit.fit_reference_trajectory`): the seed's
   objective (positions + measured initial parameters), least squares or Powell, seed or Nathan
   physics; clock offsets of the other pairs fitted jointly.
8. **Metrics** in the field frame (:mod:`stillcap.ball.metrics`) with 1-sigma uncertainties from the
   fits' covariances (Monte Carlo through the flight model).

Everything is SI inside; the result's :meth:`PitchResult.to_dict` names units in its keys and
shares its key names with the studio's ``truth.json`` (``metrics``, ``release``, ``spin``, ...).
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_rng
from stillcap.ball.fit import FitPriors, ReferenceFit, fit_reference_trajectory
from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout
from stillcap.ball.metrics import (FT, MPH, RPM_PER_RAD_S, PitchMetrics, clock_tilt, pitch_metrics_batch,
                                   spin_axis_deg, spin_efficiency)
from stillcap.ball.orientation import MarkerObservations, SpinResult, fit_spin, fit_spin_seed, rays_to_directions
from stillcap.ball.physics import FLIGHT_MODELS, FlightModel, cross_plane, flight_model, simulate, simulate_batch
from stillcap.camera import Camera
from stillcap.detect.ball import BallFlag
from stillcap.ball.stereo import StereoBalls, ball_centers_stereo
from stillcap.detect.ball_markers import BallMarkers, MarkerType, detect_ball_markers
from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import triangulate
from stillcap.io.capture import Capture, CaptureImage

__all__ = ["PitchOptions", "StereoPairSpec", "PairResult", "PitchResult", "SPIN_METHODS", "PHYSICS", "FIT_METHODS",
           "SIGMA_METHODS",
           "analyse_pitch", "stereo_pairs", "order_flashes", "pair_marker_observations",
           "marker_types", "compare_with_truth", "TABLE1_COLUMNS"]

SPIN_METHODS = ("global", "seed")
PHYSICS = tuple(FLIGHT_MODELS)
FIT_METHODS = ("least_squares", "powell")
SIGMA_METHODS = ("linear", "monte_carlo")
#: The seed's Table 1 columns (in order) and their units.
TABLE1_COLUMNS = (("mean_err_mm", "mm"), ("max_err_mm", "mm"), ("velocity_angle_deg", "deg"),
                  ("speed_diff_mph", "mph"), ("spin_axis_angle_deg", "deg"), ("spin_rate_diff_rpm", "rpm"),
                  ("speed_mph", "mph"), ("spin_rpm", "rpm"))
#: Metric keys that are angles (their spread is taken on the circle).
_ANGLE_KEYS = ("spin_axis_deg", "movement_axis_deg")
#: Matched ball images not used: refinement failed, size disagrees with the projected radius, or
#: cut by the image border (its centre is off by millimetres: ``docs/pitch.md``).
_DROP_FLAGS = int(BallFlag.REFINE_FAILED | BallFlag.SIZE_MISMATCH | BallFlag.TOUCHES_BORDER)


# --------------------------------------------------------------------------------------------
# Options and results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PitchOptions:
    """How :func:`analyse_pitch` runs.

    Attributes
    ----------
    spin_method : {"global", "seed"}
        One constant spin fitted to all flashes (default), or the seed's per-flash method.
    physics : {"seed", "nathan"}
        Flight model of the reference fit and the metrics.
    fit_method : {"least_squares", "powell"}
        Optimiser of the reference fit (Powell is the seed's).
    ball_radius_m : float
    layout : BallLayout or None
        The painted markers (default: the seed's 12-marker ball).
    release_y_ft : float or None
        Where "release" is evaluated: None = at the first ball image of the front pair (the
        photos do not show the hand); a value evaluates the fitted flight at that plane
        (field frame ``y``, feet), e.g. the pitcher's known release extension.
    expected_speed_mph : float or None
        Anchors the flash spacing (``speed / strobe_hz``) when a pair may have missed flashes
        between every pair of ball images; default: from the smallest spacing.
    position_sigma_m : float
        Expected position noise (relative weight of positions and measured initial parameters in
        the reference fit; the reported covariance is rescaled by the actual residuals).
    marker_epipolar_px : float
        Largest epipolar distance of a marker matched across a pair.
    sigma_method : {"linear", "monte_carlo"}
        How the metrics' uncertainties are propagated from the fits' covariances: first order
        (central differences along the covariances' principal axes, about 24 flights; default)
        or Monte Carlo with ``n_samples`` draws (``docs/pitch.md``, "Uncertainties").
    n_samples : int
        Monte Carlo samples for the metrics' uncertainties (0 or 1: no metric uncertainties,
        with either method).
    rng : int or Generator
        For the Monte Carlo samples.
    calibration_focal_sigma : float
        Relative 1-sigma of each camera's calibrated focal length, the calibration error that
        dominates the positions (``docs/pitch.md``, "Uncertainties"): every camera's focal
        length is perturbed by it, its pose re-solved on the calibration's own board corners
        (from ``capture.json`` ``meta.calibration``) and the ball images re-triangulated; the
        shift, shared by all positions of the pair, goes into every reported uncertainty.
        Default 2.5e-4: the RMS focal error of ``calibrate_pitch_rig`` against the true rig
        (0.015-0.025 %). 0 leaves calibration error out.
    centre_bias_px : float or None
        1-sigma per image coordinate of a systematic error of the refined ball centres shared by
        all ball images of one camera (the strobe lights the ball from one side). None (default):
        the bias the detector's shading correction leaves, per ball image from its lit phase and
        radius (:func:`stillcap.ball.uncertainty.shading_residual_lookup`; ``docs/pitch.md``,
        "Coverage audit", fourth pass); a number: that many px per image axis and camera, a
        constant and a trend along the flight; 0 leaves it out. ``docs/pitch.md``,
        "Uncertainties".
    workers : int
        Threads for the per-pair work: decoding the photos (while the calling thread finds the
        ball images of the pairs already decoded), markers and the pairs' own spin fits. The
        results do not depend on it.
    processes : int
        Worker processes for the per-pair work (0, default: the ``workers`` threads). Each pair's
        photos are decoded, its ball images and markers found and its own spin fitted in a
        process of a pool that lives across calls (:mod:`stillcap.pipelines.pitch_workers`;
        started on the first call with ``processes > 0``, about 1 s, reused afterwards): worth it
        for many captures in one process (benchmarks, batches), not for one (``docs/pitch.md``,
        "Timing"). The results are identical to the threads'. Needs a capture loaded from or
        saved to a folder; scripts that use it need an ``if __name__ == "__main__":`` guard.
    """

    spin_method: str = "global"
    physics: str = "seed"
    fit_method: str = "least_squares"
    ball_radius_m: float = BASEBALL_RADIUS
    layout: BallLayout | None = None
    release_y_ft: float | None = None
    expected_speed_mph: float | None = None
    position_sigma_m: float = 0.002
    marker_epipolar_px: float = 2.0
    n_samples: int = 200
    rng: object = 0
    sigma_method: str = "linear"
    calibration_focal_sigma: float = 2.5e-4
    centre_bias_px: float | None = None
    workers: int = 2
    processes: int = 0

    def __post_init__(self):
        fm = self.fit_method.replace("-", "_") if isinstance(self.fit_method, str) else self.fit_method
        object.__setattr__(self, "fit_method", fm)
        for name, allowed in (("spin_method", SPIN_METHODS), ("physics", PHYSICS), ("fit_method", FIT_METHODS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        if not (np.isfinite(self.ball_radius_m) and self.ball_radius_m > 0):
            raise ValueError(f"ball_radius_m must be a positive number of metres, got {self.ball_radius_m}")
        if self.expected_speed_mph is not None and not self.expected_speed_mph > 0:
            raise ValueError(f"expected_speed_mph must be positive, got {self.expected_speed_mph}")
        if self.release_y_ft is not None and not np.isfinite(self.release_y_ft):
            raise ValueError(f"release_y_ft must be a finite number of feet, got {self.release_y_ft}")
        if not self.position_sigma_m > 0:
            raise ValueError(f"position_sigma_m must be positive, got {self.position_sigma_m}")
        if self.sigma_method not in SIGMA_METHODS:
            raise ValueError(f"sigma_method must be one of {', '.join(SIGMA_METHODS)}, got {self.sigma_method!r}")
        if int(self.n_samples) < 0:
            raise ValueError(f"n_samples must be >= 0, got {self.n_samples}")
        if int(self.workers) < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if int(self.processes) < 0:
            raise ValueError(f"processes must be >= 0, got {self.processes}")
        if not (np.isfinite(self.calibration_focal_sigma) and self.calibration_focal_sigma >= 0):
            raise ValueError(f"calibration_focal_sigma must be >= 0, got {self.calibration_focal_sigma}")

    def to_dict(self) -> dict:
        return {"spin_method": self.spin_method, "physics": self.physics, "fit_method": self.fit_method,
                "ball_radius_m": self.ball_radius_m, "release_y_ft": self.release_y_ft,
                "expected_speed_mph": self.expected_speed_mph, "position_sigma_m": self.position_sigma_m,
                "marker_epipolar_px": self.marker_epipolar_px, "n_samples": int(self.n_samples),
                "calibration_focal_sigma": self.calibration_focal_sigma, "centre_bias_px": self.centre_bias_px}


@dataclass
class StereoPairSpec:
    """Two photos of one strobed stereo pair."""

    name: str
    images: tuple  # (CaptureImage, CaptureImage)
    strobe_hz: float

    @property
    def cameras(self) -> tuple:
        return tuple(im.camera for im in self.images)


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
        error gives all positions of the pair (:func:`calibration_modes`); NaN without a
        calibration record.
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
        }


@dataclass
class PitchResult:
    """Everything :func:`analyse_pitch` measured (SI, world frame of the rig).

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
        :func:`compare_with_truth` for synthetic captures.
    spin_obs_times : ndarray, shape (M,) or None
        Reference-clock time of each marker observation of ``spin`` (plots).
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
            "capture": self.capture_root, "options": self.options.to_dict(), "model": self.options.physics,
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
                "two_point_speed_sigma_mph": _speed_sigma(self.velocity_two_point,
                                                          np.diag(self.velocity_two_point_sigma ** 2)) / MPH,
                "fitted": fit.v0, "fitted_sigma": fit.v0_sigma,
                "fitted_speed_mph": float(np.linalg.norm(fit.v0) / MPH),
                "fitted_speed_sigma_mph": _speed_sigma(fit.v0, fit.covariance[3:6, 3:6]) / MPH,
            },
            "reference_fit": _fit_dict(fit),
            "reference_fit_positions_only": _fit_dict(self.fit_positions_only),
            "table1": self.table1,
            "pairs": [p.to_dict() for p in self.pairs],
            "messages": list(self.messages),
            "timings_s": self.timings_s,
        }
        if self.truth is not None:
            d["truth_comparison"] = self.truth
        return to_jsonable(d)


def _speed_sigma(v, cov) -> float:
    v = np.asarray(v, float)
    n = np.linalg.norm(v)
    if not n > 0:
        return float("nan")
    u = v / n
    return float(np.sqrt(max(u @ np.asarray(cov) @ u, 0.0)))


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
              "chi2_curvature": c.chi2_curvature, "chi2": c.chi2, "probability": c.probability}
             for c in alias.candidates[:6]]
    return {"best_rpm": alias.best.spin_rpm, "ambiguous": bool(alias.ambiguous),
            "likelihood_ratio": alias.likelihood_ratio, "evidence": list(alias.evidence),
            "consistent": bool(alias.consistent), "dof": int(alias.dof),
            "best_chi2": float(alias.best.chi2),
            "message": alias.message, "candidates": cands}


# --------------------------------------------------------------------------------------------
# Stages
# --------------------------------------------------------------------------------------------
def marker_types(layout: BallLayout | None = None) -> tuple:
    """The detector's palette for a ball layout: each type's linear-RGB colour through a 2.2 gamma
    (as a fully lit marker looks in a photo), BGR 0-255, with the type's shape."""
    layout = BallLayout.seed() if layout is None else layout
    out = []
    for name, shape in zip(layout.type_names, layout.type_shapes):
        rgb = np.clip(np.asarray(layout.palette[name], float), 0.0, 1.0)
        bgr = 255.0 * rgb[::-1] ** (1.0 / 2.2)
        out.append(MarkerType(name, tuple(np.round(bgr, 1)), shape))
    return tuple(out)


def stereo_pairs(capture: Capture) -> tuple[list[StereoPairSpec], list[str]]:
    """Group a capture's photos into strobed stereo pairs.

    A photo's pair is ``images[].meta.pair``, else the pair of the capture's ``pairs`` map
    (``{"front": ["front_top", "front_bottom"], ...}``) holding its camera, else photos are
    grouped by strobe rate and paired in the order given. A group that is not exactly two photos
    of two cameras at one strobe rate is skipped with a message.

    Returns
    -------
    pairs : list of StereoPairSpec
        In the capture's order.
    messages : list of str

    Raises
    ------
    ValueError
        When no complete pair is left.
    """
    messages: list[str] = []
    cmap = capture.meta.get("pairs") if isinstance(capture.meta.get("pairs"), dict) else {}
    cam_pair = {str(c): str(name) for name, cams in cmap.items() for c in (cams or [])}
    groups: dict[str, list[CaptureImage]] = {}
    unnamed: list[CaptureImage] = []
    for im in capture.images:
        name = im.meta.get("pair") if isinstance(im.meta, dict) else None
        name = name if name is not None else cam_pair.get(im.camera)
        if name is None:
            unnamed.append(im)
        else:
            groups.setdefault(str(name), []).append(im)
    # photos without a pair name: by strobe rate, two by two in the order given
    by_rate: dict = {}
    for im in unnamed:
        by_rate.setdefault(None if im.strobe_hz is None else round(im.strobe_hz, 6), []).append(im)
    for rate, ims in by_rate.items():
        for i in range(0, len(ims), 2):
            groups.setdefault(f"pair{len(groups)}", []).extend(ims[i:i + 2])
    for name, cams in cmap.items():
        if name not in groups:
            messages.append(f"pair {name!r}: no photo in the capture (cameras {list(cams or [])}): skipped")
    out = []
    for name, ims in groups.items():
        files = ", ".join(im.file for im in ims)
        if len(ims) != 2:
            want = cmap.get(name)
            have = {im.camera for im in ims}
            missing = [c for c in (want or []) if c not in have]
            why = f"camera {', '.join(missing)} has no photo" if missing else f"{len(ims)} photo(s) ({files})"
            messages.append(f"pair {name!r}: {why}; a stereo pair needs one photo from each of two cameras: skipped")
            continue
        if ims[0].camera == ims[1].camera:
            messages.append(f"pair {name!r}: both photos are from camera {ims[0].camera!r}: skipped")
            continue
        rates = [im.strobe_hz for im in ims]
        if any(r is None for r in rates):
            messages.append(f"pair {name!r}: no strobe_hz for {files} (flash times unknown): skipped")
            continue
        if abs(rates[0] - rates[1]) > 1e-6 * max(rates):
            messages.append(f"pair {name!r}: the two photos have different strobe rates {rates} Hz: skipped")
            continue
        out.append(StereoPairSpec(name, (ims[0], ims[1]), float(rates[0])))
    if not out:
        detail = "; ".join(messages) if messages else "no photos"
        raise ValueError(f"capture {capture.root or ''}: no complete stereo pair ({detail})")
    return out, messages


def _flight_axis(points: np.ndarray) -> np.ndarray:
    c = points - points.mean(axis=0)
    return np.linalg.svd(c, full_matrices=False)[2][0]


def _off_path(points: np.ndarray, direction: np.ndarray, tol_m: float = 0.03) -> np.ndarray:
    """Points further than ``tol_m`` (or 6 robust sigmas) from a quadratic fitted to the lateral
    coordinates along ``direction``: stray detections, wrong matches (bool mask)."""
    n = len(points)
    bad = np.zeros(n, bool)
    if n < 5:
        return bad
    s = points @ direction
    lat = points - np.outer(s, direction)
    A = np.stack([np.ones(n), s - s.mean(), (s - s.mean()) ** 2], axis=1)
    for _ in range(2):
        keep = ~bad
        if keep.sum() < 4:
            break
        coef, *_ = np.linalg.lstsq(A[keep], lat[keep], rcond=None)
        r = np.linalg.norm(lat - A @ coef, axis=1)
        mad = 1.4826 * np.median(r[keep])
        bad = r > max(tol_m, 6.0 * mad)
    return bad


def order_flashes(points, direction, strobe_hz: float, expected_spacing_m: float | None = None):
    """Order a pair's 3D ball positions along the flight and give each its flash index.

    Parameters
    ----------
    points : array_like, shape (K, 3)
    direction : array_like, shape (3,)
        Flight direction (any length).
    strobe_hz : float
    expected_spacing_m : float, optional
        Distance between consecutive flashes (``speed / strobe_hz``); default: the smallest
        spacing refined by the spacing ratios (each rounded to a whole number of flashes).

    Returns
    -------
    order : ndarray of int, shape (K',)
        Indices into ``points`` in flight order (duplicates, spacing ~0, dropped).
    flash_index : ndarray of int, shape (K',)
        Flash counted from the first, gaps for missed flashes.
    spacing_m : float
        Base spacing, m.
    """
    P = np.asarray(points, float)
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    order = np.argsort(P @ d)
    if len(order) < 2:
        return order, np.zeros(len(order), int), float("nan")
    # drop duplicates (two detections of one ball image)
    keep = [order[0]]
    for i in order[1:]:
        if np.linalg.norm(P[i] - P[keep[-1]]) > 0.3 * (expected_spacing_m or 0.0) + 0.02:
            keep.append(i)
    order = np.array(keep)
    gaps = np.linalg.norm(np.diff(P[order], axis=0), axis=1)
    if len(gaps) == 0:
        return order, np.zeros(1, int), float("nan")
    s = float(expected_spacing_m) if expected_spacing_m else float(gaps.min())
    for _ in range(3):
        k = np.maximum(np.rint(gaps / s), 1)
        s = float(gaps.sum() / k.sum())
    k = np.maximum(np.rint(gaps / s), 1).astype(int)
    return order, np.concatenate([[0], np.cumsum(k)]).astype(int), s


def _triangulated_direction(cam_a, cam_b, xa, xb, center, radius):
    X = triangulate([cam_a, cam_b], np.stack([xa, xb])).points
    v = X - center
    r = np.linalg.norm(v, axis=1)
    ok = np.isfinite(r) & (r > 0.8 * radius) & (r < 1.15 * radius)
    return v / np.where(r > 0, r, 1.0)[:, None], ok


def pair_marker_observations(cam_a: Camera, img_a, cam_b: Camera, img_b, centers_a, centers_b, radius_a, radius_b,
                             positions, types=None, layout: BallLayout | None = None, radius_m: float = BASEBALL_RADIUS,
                             max_px: float = 2.0):
    """Painted markers of a pair's ball images as directions from the ball centres.

    Per photo the markers are found inside each ball image (colour and shape); per ball the two
    photos' markers are matched (same type, epipolar distance below ``max_px``, optimal
    assignment) and triangulated, and the direction from the ball centre is kept when the
    marker lies on the sphere (0.8-1.15 radii: a wrong match does not). Markers seen by one
    camera (or badly triangulated) become pixel rays meeting the sphere their image centroids
    lie on (:attr:`BallLayout.centroid_depth <stillcap.ball.layout.BallLayout.centroid_depth>`,
    just inside the ball).

    Returns
    -------
    obs : MarkerObservations
        ``flash`` = index of the ball position.
    markers : list of 2 BallMarkers
    stats : dict
        ``n_3d``, ``n_ray``, ``epipolar_px`` (median of the matches).
    """
    layout = BallLayout.seed() if layout is None else layout
    types = marker_types(layout) if types is None else types
    P = np.asarray(positions, float)
    K = len(P)
    if K == 0:
        empty = MarkerObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        return empty, [BallMarkers.empty(), BallMarkers.empty()], {"n_3d": 0, "n_ray": 0, "epipolar_px": np.nan}
    ma = detect_ball_markers(img_a, centers_a, radius_a, types)
    mb = detect_ball_markers(img_b, centers_b, radius_b, types)
    # The K balls' markers (sorted by ball), matched in one call (a call per ball cost more than
    # the matching): labelled by ball and type, a marker pairs only with one of the same ball
    # and type, and an optimal assignment of such independent blocks is each block's own.
    A, B = ma.select(ma.ball_index < K), mb.select(mb.ball_index < K)
    m = match_epipolar(cam_a, cam_b, A.centers, B.centers, max_px=max_px,
                       labels_a=[f"{k} {t}" for k, t in zip(A.ball_index, A.types)],
                       labels_b=[f"{k} {t}" for k, t in zip(B.ball_index, B.types)])
    ia, ib = m.pairs[:, 0], m.pairs[:, 1]
    ball = A.ball_index[ia]  # of each match
    if len(ia):
        u, ok = _triangulated_direction(cam_a, cam_b, A.centers[ia], B.centers[ib], P[ball], radius_m)
    else:
        u, ok = np.zeros((0, 3)), np.zeros(0, bool)
    # Single-camera rays, every ball's at once: the unmatched markers, then the matches off the
    # sphere; a stable sort by ball keeps that order within each ball.
    rays = []
    for M, cam, idx in ((A, cam_a, np.concatenate([m.unmatched_a, ia[~ok]])),
                        (B, cam_b, np.concatenate([m.unmatched_b, ib[~ok]]))):
        idx = idx[np.argsort(M.ball_index[idx], kind="stable")].astype(int)
        k_ray = M.ball_index[idx]
        ti = layout.type_index(list(M.types[idx]))
        if len(idx):
            o, dirs = cam.rays(M.centers[idx])
            # a centroid is the image of a point inside the ball (BallLayout.centroid_depth): the
            # ray meets that smaller sphere where the marker's axis does, the ball's surface
            # closer to the line of sight (a fixed-sign spin error otherwise, "Coverage audit")
            v, hit = rays_to_directions(o, dirs, P[k_ray], radius_m * (1.0 - layout.centroid_depth[ti]))
        else:
            v, hit = np.zeros((0, 3)), np.zeros(0, bool)
        rays.append((ti, k_ray, v, hit))
    parts, n3, nray, epi = [], 0, 0, []
    for k in range(K):
        sel = ok & (ball == k)
        if sel.any():
            parts.append(MarkerObservations.from_directions(np.full(int(sel.sum()), k), list(A.types[ia[sel]]),
                                                            u[sel], layout))
            n3 += int(sel.sum())
            epi += list(m.distance_px[sel])
        for ti, k_ray, v, hit in rays:
            sel = hit & (k_ray == k)
            if sel.any():
                parts.append(MarkerObservations(np.full(int(sel.sum()), k), ti[sel], v[sel],
                                                np.ones(int(sel.sum()), bool)))
                nray += int(sel.sum())
    obs = (MarkerObservations.concatenate(parts) if parts
           else MarkerObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3))))
    return obs, [ma, mb], {"n_3d": n3, "n_ray": nray, "epipolar_px": float(np.median(epi)) if epi else np.nan}


def _board_points_world(calib: dict, pair_name: str, camera: str):
    """World coordinates of the calibration board corners a camera's pose was solved on (from
    the capture's ``meta.calibration`` record), or None when the record does not say."""
    from stillcap.io.capture import target_from_dict

    try:
        target = target_from_dict(calib["extrinsics_target"])
        T = np.asarray(calib["board2world"][pair_name], float).reshape(-1, 4, 4)
        spots = calib["cameras"][camera].get("spots_used", range(len(T)))
        obj = target.object_points
        obj = np.asarray(obj() if callable(obj) else obj, float).reshape(-1, 3)
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    pts = [obj @ T[k][:3, :3].T + T[k][:3, 3] for k in spots if 0 <= int(k) < len(T)]
    return np.concatenate(pts) if pts else None


def calibration_modes(cams, centers_px, calib: dict | None, pair_name: str, focal_sigma: float):
    """How a pair's triangulated positions move with each camera's focal-length error.

    For each camera the focal length is scaled by ``1 + focal_sigma``, the pose re-solved by PnP
    on the board corners it was calibrated with (their pixels as the calibrated camera sees
    them: the error the board cannot reveal), and the ball images re-triangulated.

    Parameters
    ----------
    cams : sequence of 2 Camera
    centers_px : array_like, shape (2, K, 2)
    calib : dict or None
        The capture's ``meta.calibration`` record (``extrinsics_target``, ``board2world``,
        ``cameras[name].spots_used``).
    pair_name : str
    focal_sigma : float

    Returns
    -------
    ndarray, shape (2, K, 3) or None
        Position shift per camera at 1 sigma (m); None without a usable calibration record.
    """
    import cv2

    x = np.asarray(centers_px, float)
    if calib is None or not focal_sigma > 0 or x.shape[1] == 0:
        return None
    X0 = triangulate(list(cams), x).points
    out = np.zeros((2, x.shape[1], 3))
    for i, cam in enumerate(cams):
        W = _board_points_world(calib, pair_name, cam.name)
        if W is None or len(W) < 6:
            return None
        img = cam.project(W)
        K = cam.K.copy()
        K[0, 0] *= 1.0 + focal_sigma
        K[1, 1] *= 1.0 + focal_sigma
        rvec, _ = cv2.Rodrigues(cam.R)
        ok, rvec, tvec = cv2.solvePnP(W, img, K, cam.dist, rvec.copy(), cam.t.reshape(3, 1).copy(),
                                      useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            return None
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        c2 = Camera(cam.name, K, cam.dist, T, cam.image_size)
        pair = [c2, cams[1]] if i == 0 else [cams[0], c2]
        out[i] = triangulate(pair, x).points - X0
    return out


def _pixel_sigma(reproj_error_px, default_px: float = 0.1) -> float:
    """Random ball-centre error per image axis, px: ``sqrt(2) x`` the RMS reprojection error of
    a pair's triangulated centres (a two-view reprojection error sees one of the two pixel
    errors' four components' worth of noise per camera), ``default_px`` with fewer than two."""
    e = np.asarray(reproj_error_px, float)
    e = e[np.isfinite(e)]
    s = float(np.sqrt(2.0 * np.mean(e ** 2))) if len(e) >= 2 else 0.0
    return s if s > 0 else default_px


def centre_bias_modes(cams, centers_px, sigma_px: float, trend: bool = False):
    """How a pair's triangulated positions move with a systematic shift of one camera's ball
    centres: one mode per camera and image axis, the same shift for all its ball images; with
    ``trend`` also one mode per camera and axis whose shift changes linearly along the pair's
    images (in flight order), from ``-sigma_px`` at the first to ``+sigma_px`` at the last.

    Returns
    -------
    ndarray, shape (4, K, 3), or (8, K, 3) with ``trend``
        Position shift (m) of camera 0 x, 0 y, 1 x, 1 y (then the same four for the trend).
    """
    x = np.asarray(centers_px, float)
    K = x.shape[1]
    profiles = [np.ones(K)]
    if trend:
        profiles.append(np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K))
    out = np.zeros((4 * len(profiles), K, 3))
    if not sigma_px > 0 or K == 0:
        return out
    shifted = []
    for prof in profiles:
        for c in range(2):
            for j in range(2):
                xs = x.copy()
                xs[c, :, j] += sigma_px * prof
                shifted.append(xs)
    return _retriangulated_shifts(cams, x, shifted)


def _retriangulated_shifts(cams, x, shifted) -> np.ndarray:
    """Position shifts (m), shape (len(shifted), K, 3), of a pair's centres ``x`` (2, K, 2)
    re-triangulated as each of the ``shifted`` copies: one triangulation of the centres and all
    copies (a call per copy cost ~8x more)."""
    K = x.shape[1]
    P = triangulate(list(cams), np.concatenate([x, *shifted], axis=1)).points.reshape(1 + len(shifted), K, 3)
    return P[1:] - P[0]


def lit_geometry(stereo, centers_px, flags, radius_px):
    """Per ball image of a pair: the lit direction, the phase angle and whether the shading
    correction ran, from the stereo step's detections.

    Parameters
    ----------
    stereo : StereoBalls
        The pair's :func:`ball_centers_stereo` result (its detections).
    centers_px : array_like, shape (2, K, 2)
        The pair's refined centres (rows of ``stereo.centers_a`` / ``centers_b``).
    flags : array_like of int, shape (K,)
        ``BallFlag`` bits of both views (``PARTIAL``: the correction ran in both views).
    radius_px : array_like, shape (2, K)

    Returns
    -------
    u : ndarray, shape (2, K, 2)
        Unit vector from the refined centre toward the silhouette's ellipse centre (the lit
        side: a lit silhouette's middle lies toward the light); 0 where they coincide.
    phase : ndarray, shape (2, K)
        Phase angle (rad) from the silhouette's area (:func:`lit_phase_from_area`).
    corrected : ndarray of bool, shape (K,)
    """
    from stillcap.ball.uncertainty import lit_phase_from_area

    x = np.asarray(centers_px, float)
    if x.ndim != 3 or x.shape[0] != 2 or x.shape[2] != 2:
        raise ValueError(f"centers_px must have shape (2, K, 2), got {x.shape}")
    K = x.shape[1]
    u = np.zeros((2, K, 2))
    phase = np.zeros((2, K))
    for c, (cen, det, col) in enumerate(((stereo.centers_a, stereo.detections_a, 0),
                                         (stereo.centers_b, stereo.detections_b, 1))):
        if K == 0 or len(cen) == 0:
            break
        row = np.argmin(np.linalg.norm(np.asarray(cen)[None] - x[c][:, None], axis=2), axis=1)
        j = stereo.pairs[row, col]
        d = det.ellipse_centers[j] - x[c]
        n = np.linalg.norm(d, axis=1)
        u[c] = np.where(n[:, None] > 1e-9, d / np.maximum(n, 1e-9)[:, None], 0.0)
        phase[c] = lit_phase_from_area(det.areas[j], np.asarray(radius_px, float)[c])
    corrected = (np.asarray(flags, int) & int(BallFlag.PARTIAL)) > 0
    return u, phase, corrected


def lit_bias_modes(cams, centers_px, u, sigma_px, corrected):
    """How a pair's triangulated positions move with the ball-centre bias that remains after
    the shading correction (:func:`stillcap.ball.uncertainty.shading_residual_lookup`).

    Per camera: for corrected images a shift of ``sigma_px`` along their lit direction ``u``
    (the correction's model error has that direction), the same for all (constant) and growing
    linearly from ``-sigma_px`` at the pair's first image to ``+sigma_px`` at its last (trend:
    the phase angle changes along the flight); for the others (full discs, no lit direction)
    the same two profiles along each image axis.

    Parameters
    ----------
    cams : sequence of 2 Camera
    centers_px : array_like, shape (2, K, 2)
    u : array_like, shape (2, K, 2)
    sigma_px : array_like, shape (2, K)
    corrected : array_like of bool, shape (K,)

    Returns
    -------
    ndarray, shape (12, K, 3)
        Position shift (m) per camera (6 each: along ``u`` constant, trend; x, y constant;
        x, y trend).
    """
    x = np.asarray(centers_px, float)
    K = x.shape[1] if x.ndim == 3 else 0
    u, s = np.asarray(u, float), np.asarray(sigma_px, float)
    if x.shape != (2, K, 2) or u.shape != (2, K, 2) or s.shape != (2, K):
        raise ValueError(f"centers_px and u must have shape (2, K, 2) and sigma_px (2, K), got "
                         f"{x.shape}, {u.shape}, {s.shape}")
    corr = np.broadcast_to(np.asarray(corrected, bool), (K,))
    out = np.zeros((12, K, 3))
    if K == 0:
        return out
    profiles = [np.ones(K), np.linspace(-1.0, 1.0, K) if K > 1 else np.zeros(K)]
    e = np.eye(2)
    modes, shifted = [], []
    for c in range(2):
        shifts = [np.where(corr[:, None], u[c], 0.0) * (s[c] * prof)[:, None] for prof in profiles]
        shifts += [np.where(corr[:, None], 0.0, e[j]) * (s[c] * prof)[:, None] for prof in profiles for j in range(2)]
        for m, dx in enumerate(shifts):
            if np.any(dx):
                xs = x.copy()
                xs[c] += dx
                modes.append(6 * c + m)
                shifted.append(xs)
    if shifted:
        out[modes] = _retriangulated_shifts(cams, x, shifted)
    return out


def _remaining_bias_modes(p: PairResult) -> np.ndarray:
    """:func:`lit_bias_modes` of a pair, sized by the shading model's remaining error."""
    from stillcap.ball.uncertainty import shading_residual_lookup

    u, phase, corr = lit_geometry(p.stereo, p.centers_px, p.flags, p.radius_px)
    # full discs (not PARTIAL, phase below ~55 deg) as lit from the camera: there the model's
    # offset swings by ~0.1 px within 10 deg of phase, finer than the silhouette's area resolves
    # (a thresholded full disc loses its dim limb: 0.96-1.11 of pi r^2 from 0 to 30 deg), and
    # against the truth the front pair's (phase ~10 deg) per-camera bias was 0.016-0.020 px
    phase = np.where(corr[None, :], phase, 0.0)
    s = np.stack([shading_residual_lookup(phase[c], p.radius_px[c], corr) for c in range(2)])
    return lit_bias_modes(p._cams, p.centers_px, u, s, corr)


def _release_state(p0, v0, spin, model, t0, release_y_m):
    """Position, velocity and time where the flight crosses ``y = release_y_m`` (Newton on the
    reference integrator, before or after ``t0``)."""
    t = t0
    p, v = np.asarray(p0, float), np.asarray(v0, float)
    for _ in range(6):
        if abs(v[1]) < 1e-6:
            raise ValueError("the flight does not move along y: cannot evaluate a release plane")
        dt = (release_y_m - p[1]) / v[1]
        if abs(dt) < 1e-9:
            break
        t = t + dt
        tr = simulate(p0, v0, spin, [t], model, t0=t0)
        p, v = tr.positions[0], tr.velocities[0]
    return t, p, v


# --------------------------------------------------------------------------------------------
# Spin and aliases
# --------------------------------------------------------------------------------------------
def _fit_pair_spin(pair: PairResult, method: str, layout, spin_init=None, observations=None) -> SpinResult | None:
    """The spin of one pair's markers on its own clock (``observations`` instead of the pair's:
    the marker job on the worker pool runs it before they are stored on the pair)."""
    obs = pair.observations if observations is None else observations
    if obs is None or len(obs) == 0 or len(pair) < 2:
        return None
    t = pair.local_times
    if method == "seed":
        return fit_spin_seed(t, obs, layout, strobe_hz=pair.strobe_hz)
    # stop after the first start that explains 90 % of the markers (fit_spin: the same result on
    # the benchmark pitches, one fit instead of three)
    return fit_spin(t, obs, layout, strobe_hz=pair.strobe_hz, spin_init=spin_init, stop_fraction=0.9)


def _resolve_alias(pairs: list, fit_curv: ReferenceFit, model: FlightModel, messages: list):
    """Choose the spin alias with both strobe rates and the flight's Magnus curvature
    (:func:`stillcap.ball.alias.resolve_aliases`).

    Returns ``(spin vector (3,) or None, AliasResolution or None)``."""
    from stillcap.ball.alias import CurvatureMeasurement, StrobeMeasurement, resolve_aliases

    meas = []
    for p in pairs:
        s = p.spin
        if s is None or not s.success or not np.all(np.isfinite(s.spin)):
            continue
        cov = s.spin_covariance
        if not np.all(np.isfinite(cov)):  # e.g. the seed method with one interval: no spread
            cov = np.eye(3) * (20.0 / RPM_PER_RAD_S) ** 2
        meas.append(StrobeMeasurement(s.spin, p.strobe_hz, cov, f"pair {p.name} ({p.strobe_hz:g} Hz)"))
    if not meas:
        return None, None
    curv = None
    if fit_curv is not None and np.all(np.isfinite(fit_curv.covariance[6:9, 6:9])):
        try:
            curv = CurvatureMeasurement.from_reference_fit(fit_curv, model)
        except ValueError:
            curv = None
    res = resolve_aliases(meas, curv)
    if res.ambiguous:
        messages.append(f"spin rate ambiguous (aliasing above the strobe's Nyquist limit): {res.message}")
    elif len(meas) == 1 and curv is None:
        messages.append("spin alias checked with one strobe rate only")
    return res.best.spin.copy(), res


def _combined_spin(pairs: list, spin_init, layout, messages) -> SpinResult | None:
    """One constant spin over all pairs' markers on the reference clock, started at ``spin_init``.

    Returns ``(SpinResult or None, reference-clock time of each observation)``."""
    parts, times, groups = [], [], []
    for p in pairs:
        if p.observations is None or len(p.observations) == 0:
            continue
        parts.append(p)
        times.append(p.times)
        groups.append(np.full(len(p), p.group))
    if not parts:
        return None, None
    # start at the orientation a pair's own fit found at its first flash, turned back to t = 0 at
    # the chosen alias (alias candidates agree at flash times): one start instead of four
    fitted = [p for p in parts
              if p.spin is not None and p.spin.success and np.all(np.isfinite(p.spin.ball2world_t0))]
    src = next((p for p in fitted if p.group == 0), max(fitted, key=lambda p: p.spin.n_inliers, default=None))
    if len(parts) == 1:
        p = parts[0]
        R_init = p.spin.ball2world_t0 if p is src else None
        return (fit_spin(p.local_times, p.observations, layout, strobe_hz=p.strobe_hz, spin_init=spin_init,
                         ball2world_init=R_init), p.times[p.observations.flash])
    R_init = None
    if src is not None:
        R_init = Rotation.from_rotvec(-np.asarray(spin_init, float) * src.times[0]).as_matrix() @ src.spin.ball2world_t0
    t_all = np.concatenate(times)
    order = np.argsort(t_all, kind="stable")
    if np.any(np.diff(t_all[order]) <= 0):
        messages.append("flashes of different pairs coincide in time: spin from the pairs separately")
        return None, None
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    obs_parts, start = [], 0
    for p in parts:
        o = p.observations
        obs_parts.append(MarkerObservations(rank[start + o.flash], o.types, o.directions, o.from_ray))
        start += len(p)
    obs = MarkerObservations.concatenate(obs_parts)
    ref = parts[0]
    t_sorted = t_all[order]
    # the other pairs' flashes sit on the reference clock through fitted offsets: their
    # uncertainty goes into the spin's covariance
    g_sorted = np.concatenate(groups)[order]
    n_g = int(g_sorted.max(initial=0))
    g_sig = np.zeros(n_g)
    for p in parts:
        if p.group > 0:
            g_sig[p.group - 1] = p.time_offset_sigma_s
    return (fit_spin(t_sorted, obs, layout, t0=0.0, strobe_hz=ref.strobe_hz, spin_init=spin_init,
                     ball2world_init=R_init, time_groups=g_sorted, time_group_sigma=g_sig),
            t_sorted[obs.flash])


def _spin_stage(pairs, fit_pos, model, layout, method, messages, pair_spins=None):
    """Per-pair spin fits, the alias choice and the final spin: ``(SpinResult or None, alias
    resolution or None, reference-clock time of each observation of the final fit)``.
    ``pair_spins``: the per-pair fits already made (one per pair, in order), e.g. on the pool."""
    from stillcap.ball.alias import alias_candidates

    for i, p in enumerate(pairs):
        p.spin = _fit_pair_spin(p, method, layout) if pair_spins is None else pair_spins[i]
        if p.spin is not None and not p.spin.success:
            messages.append(f"pair {p.name!r}: spin not determined ({p.spin.message})")
    w_alias, alias = _resolve_alias(pairs, fit_pos, model, messages)
    if w_alias is None:
        messages.append("too few markers for a spin (need markers on 2+ flashes with 2+ types): spin unavailable")
        return None, alias, None
    best = max((p for p in pairs if p.spin is not None and p.spin.success), key=lambda p: p.spin.n_inliers)
    if method == "global":
        spin, obs_times = _combined_spin(pairs, w_alias, layout, messages)
        if spin is None or not spin.success:
            spin = _fit_pair_spin(best, "global", layout, spin_init=w_alias)
            obs_times = best.times[best.observations.flash]
    else:
        spin = best.spin
        obs_times = best.times[best.observations.flash]
        # the seed method's rate is the principal alias of its strobe: move it to the chosen alias
        cands = alias_candidates(spin.spin, best.strobe_hz, max_rpm=max(4000.0, 1.5 * np.linalg.norm(w_alias)
                                                                        * RPM_PER_RAD_S))
        w = min((c.spin for c in cands), key=lambda c: float(np.linalg.norm(c - w_alias)))
        if np.linalg.norm(w - spin.spin) > 1e-9:
            spin = _with_spin(spin, w)
    if spin is not None and not spin.success:
        messages.append(f"spin fit failed: {spin.message}")
    return spin, alias, obs_times


def _decay_slope(fit: ReferenceFit, model: FlightModel, t_obs, t_ref: float) -> float:
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


# --------------------------------------------------------------------------------------------
# Uncertainty of the metrics
# --------------------------------------------------------------------------------------------
def _metric_keys(nominal: PitchMetrics):
    nom = nominal.to_dict()
    keys = [k for k in nom if k not in ("nine_parameter", "success", "message", "spin_tilt")]
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


def _metrics_sigma(fit: ReferenceFit, spin_meas, spin_cov, model, t_rel, release_y_m, nominal: PitchMetrics,
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
        return (d + 180.0) % 360.0 - 180.0 if k in _ANGLE_KEYS else d

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

        def spread(k, a, centre):
            if centre is None or not np.isfinite(a[0]):
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

        def spread(k, a, centre):
            a = a[np.isfinite(a)]
            if len(a) < 2 or centre is None:
                return None
            if k in _ANGLE_KEYS:
                a = wrap(k, a - centre)
            return float(np.std(a, ddof=1))

    out = {k: spread(k, vals[k], nom.get(k)) for k in keys}
    out["nine_parameter"] = {k: spread(k, nine_vals[k], nn.get(k)) for k in nine_keys} if nine_keys else None
    if spin_meas is None:
        for k in ("spin_rate_rpm", "active_spin_rpm", "spin_efficiency", "gyro_angle_deg", "spin_axis_deg"):
            if k in out:
                out[k] = None
    return out


# --------------------------------------------------------------------------------------------
# The pipeline
# --------------------------------------------------------------------------------------------
def _progress(cb, done, total, label):
    if cb is not None:
        cb(done, total, label)


def analyse_pitch(capture: Capture | str | Path, options: PitchOptions | None = None, *,
                  progress: Callable[[int, int, str], None] | None = None, **kwargs) -> PitchResult:
    """Analyse one pitch capture (SPEC J1): positions, timing, markers, spin, flight, metrics.

    Parameters
    ----------
    capture : Capture or path
        A capture folder (``kind: pitch``) with one photo per camera of 1+ strobed stereo pairs,
        each photo with its ``strobe_hz``; the rig's world should be the baseball field frame
        for the metrics.
    options : PitchOptions, optional
        Or pass its fields as keyword arguments (``spin_method="seed"``, ``physics="nathan"``).
    progress : callable(done, total, label), optional

    Returns
    -------
    PitchResult

    Raises
    ------
    ValueError
        A capture that cannot give a flight: not a pitch capture, no complete stereo pair, an
        unreadable photo, no ball found, fewer than 3 ball positions or fewer than 2 in the front
        pair. Missing markers (no spin) are not errors: the result says so in ``messages``.
    """
    t_all = _time.perf_counter()
    if options is None:
        options = PitchOptions(**kwargs)
    elif kwargs:
        raise ValueError("give either options or keyword arguments, not both")
    cap = capture if isinstance(capture, Capture) else Capture.load(capture)
    if int(options.processes) == 0:
        with ThreadPoolExecutor(max(1, int(options.workers))) as pool:
            return _analyse_pitch(cap, options, progress, pool, t_all)
    from stillcap.pipelines import pitch_workers

    if cap.root is None:
        raise ValueError("processes > 0 needs a capture loaded from or saved to a folder (the worker processes "
                         "read its photos): use processes=0")
    procs = pitch_workers.worker_pools(int(options.processes))
    cached: dict = {}  # token -> executor: a pair's photos held by a worker until its marker step
    try:
        return _analyse_pitch(cap, options, progress, None, t_all, procs, cached)
    finally:
        for token, ex in cached.items():  # the capture stopped before these pairs' marker step
            ex.submit(pitch_workers.drop_job, token)


def pair_markers_and_spin(cams, imgs, pair: PairResult, types, layout, radius_m: float, max_px: float,
                          spin_method: str):
    """The marker step of one pair: :func:`pair_marker_observations` on its photos, then the
    pair's own spin (it needs only the pair's markers and flash indices, not the flight fit).

    Returns
    -------
    ((obs, markers, stats), spin, t_markers_s, t_spin_s)
        ``spin``: SpinResult, None, or the ValueError / LinAlgError of the fit (reported where
        the spin stage would report it).
    """
    t_job = _time.perf_counter()
    out = pair_marker_observations(
        cams[0], imgs[0], cams[1], imgs[1], pair.centers_px[0], pair.centers_px[1], pair.radius_px[0],
        pair.radius_px[1], pair.positions, types, layout, radius_m, max_px)
    t_mk = _time.perf_counter() - t_job
    try:
        spin = _fit_pair_spin(pair, spin_method, layout, observations=out[0])
    except (ValueError, np.linalg.LinAlgError) as e:
        spin = e
    return out, spin, t_mk, _time.perf_counter() - t_job - t_mk


def _analyse_pitch(cap: Capture, options: PitchOptions, progress, pool: ThreadPoolExecutor | None,
                   t_all: float, procs: list | None = None, cached: dict | None = None) -> PitchResult:
    """The stages of :func:`analyse_pitch`, with `pool` (threads) or `procs` (single-process
    executors, :mod:`stillcap.pipelines.pitch_workers`) for the per-pair work; `cached` collects
    the tokens of the photos the workers hold until the pair's marker step."""
    where = f"capture {cap.root}" if cap.root is not None else "capture"
    if cap.kind != "pitch":
        raise ValueError(f"{where} is a {cap.kind!r} capture, not a pitch capture (capture.json \"kind\")")
    layout = options.layout or BallLayout.seed(radius=options.ball_radius_m)
    types = marker_types(layout)
    model = flight_model(options.physics)
    R = options.ball_radius_m
    timings: dict = {}
    specs, messages = stereo_pairs(cap)
    total = 2 * len(specs) + 3

    # -- 1-2. ball positions per pair -----------------------------------------------------------
    t = _time.perf_counter()
    if procs is None:
        # the photos decode on the pool in pair order (imread releases the GIL); each pair's ball
        # images are found on this thread as soon as its two photos are in, while the next pair's
        # photos decode (detection mostly holds the GIL: two pairs on threads overlapped less)
        decoding = [[pool.submit(cap.read_image, im) for im in sp.images] for sp in specs]
        found = []
        for sp, futs in zip(specs, decoding):
            cams = [cap.rig[c] for c in sp.cameras]
            imgs = [f.result() for f in futs]
            found.append((cams, imgs, ball_centers_stereo(cams[0], imgs[0], cams[1], imgs[1], R)))
    else:  # pair i on worker i % n, which keeps its photos (under a token) for the marker step
        from stillcap.pipelines import pitch_workers

        light = Capture(cap.kind, cap.rig, cap.images, None, {}, cap.root)  # paths only, no truth
        futs = []
        for i, sp in enumerate(specs):
            token, ex = pitch_workers.new_token(), procs[i % len(procs)]
            cached[token] = ex
            futs.append((token, ex.submit(pitch_workers.pair_positions_job, light, sp.images, sp.cameras, R, token)))
        found = [([cap.rig[c] for c in sp.cameras], token, f.result()) for sp, (token, f) in zip(specs, futs)]
    raw = []
    for i, (sp, (cams, imgs, st)) in enumerate(zip(specs, found)):
        _progress(progress, 2 * i + 1, total, f"pair {sp.name}: ball images")
        ok = st.ok & ((st.flags & _DROP_FLAGS) == 0)
        nd = (len(st.detections_a), len(st.detections_b))
        if nd[0] == 0 or nd[1] == 0:
            none = [c for c, n in zip(sp.cameras, nd) if n == 0]
            messages.append(f"pair {sp.name!r}: no ball in the photo of {', '.join(none)}")
        elif not ok.any():
            messages.append(f"pair {sp.name!r}: {nd[0]} and {nd[1]} ball images, none matched across the pair")
        raw.append((sp, cams, imgs, st, ok, nd))
        _progress(progress, 2 * i + 2, total, f"pair {sp.name}: {int(ok.sum())} ball positions")
    timings["positions"] = _time.perf_counter() - t
    pts_all = np.concatenate([st.points_3d[ok] for *_, st, ok, _ in raw]) if raw else np.zeros((0, 3))
    if len(pts_all) == 0:
        raise ValueError(f"{where}: no ball found in any stereo pair ({'; '.join(messages)})")

    # -- 3. flight direction, order, flash indices -------------------------------------------------
    if len(pts_all) >= 2:
        axis = _flight_axis(pts_all)
    else:
        axis = np.array([0.0, -1.0, 0.0])
    with_pts = [j for j, r in enumerate(raw) if r[4].any()]
    if cap.rig.world == "field":
        sign = -1.0 if axis[1] > 0 else 1.0  # the ball flies toward home plate (-y)
    elif len(with_pts) >= 2:
        a = raw[with_pts[0]][3].points_3d[raw[with_pts[0]][4]].mean(0)
        b = raw[with_pts[-1]][3].points_3d[raw[with_pts[-1]][4]].mean(0)
        sign = 1.0 if (b - a) @ axis > 0 else -1.0
        messages.append(f"rig world {cap.rig.world!r} is not the field frame: flight direction from pair "
                        f"{raw[with_pts[0]][0].name!r} toward {raw[with_pts[-1]][0].name!r}; metrics assume field axes")
    else:
        sign = 1.0
        messages.append(f"rig world {cap.rig.world!r} is not the field frame and only one pair saw the ball: "
                        "the flight direction is a guess; metrics assume field axes")
    direction = sign * axis
    pairs: list[PairResult] = []
    for sp, cams, imgs, st, ok, nd in raw:
        idx = np.flatnonzero(ok)
        n_drop = int(len(st) - len(idx))
        P = st.points_3d[idx]
        off = _off_path(P, direction)
        if off.any():
            messages.append(f"pair {sp.name!r}: {int(off.sum())} ball position(s) off the flight path dropped")
            idx, P = idx[~off], P[~off]
            n_drop += int(off.sum())
        exp_s = None if options.expected_speed_mph is None else options.expected_speed_mph * MPH / sp.strobe_hz
        order, k, spacing = order_flashes(P, direction, sp.strobe_hz, exp_s)
        n_drop += len(idx) - len(order)
        sel = idx[order]
        pr = PairResult(sp.name, sp.cameras, sp.strobe_hz, k, st.points_3d[sel],
                        np.stack([st.centers_a[sel], st.centers_b[sel]]), st.radius_px[sel].T.copy(),
                        st.reproj_error_px[sel], st.flags[sel], nd, n_drop, spacing, stereo=st)
        pr._imgs = imgs  # kept for the marker step, dropped afterwards (processes: the worker's token)
        pr._cams = cams
        pairs.append(pr)
    # flight order of the pairs: by the position of their first ball image along the flight
    pairs.sort(key=lambda p: (len(p) == 0, p.positions[0] @ direction if len(p) else 0.0))
    # cross-check the base spacings (speeds) of the pairs: a pair that missed every other flash
    # looks twice as fast as the others (drag makes later pairs ~10 % slower, never 2x)
    speeds = [p.spacing_m * p.strobe_hz for p in pairs if len(p) >= 2 and np.isfinite(p.spacing_m)]
    if len(speeds) >= 2 and options.expected_speed_mph is None:
        v_ref = min(speeds)
        for p in pairs:
            if len(p) >= 2 and np.isfinite(p.spacing_m):
                ratio = p.spacing_m * p.strobe_hz / v_ref
                m = int(round(ratio))
                if m >= 2 and abs(ratio - m) < 0.25 * m:
                    p.flash_index = p.flash_index * m
                    p.spacing_m /= m
                    messages.append(f"pair {p.name!r}: spacing {m}x the other pairs' speed: every ball image "
                                    f"counted {m} flashes apart")
    usable = [p for p in pairs if len(p) >= 1]
    n_pos = sum(len(p) for p in usable)
    if n_pos < 3:
        raise ValueError(f"{where}: too few ball images for a flight: {n_pos} position(s) "
                         f"({', '.join(f'{p.name}: {len(p)}' for p in pairs)}); need at least 3"
                         + (f" ({'; '.join(messages)})" if messages else ""))
    ref = next((p for p in usable if len(p) >= 2), None)
    if ref is None:
        raise ValueError(f"{where}: too few flashes: no pair has 2 ball images (the release velocity needs two)")
    if ref is not usable[0]:
        messages.append(f"pair {usable[0].name!r} has one ball image only: pair {ref.name!r} is the reference clock")
    pairs = [ref] + [p for p in pairs if p is not ref]
    for p in pairs:
        if len(p) == 1:
            messages.append(f"pair {p.name!r}: one ball image only (its clock offset rests on it alone)")

    # -- 4. markers, per pair on the pool while the main thread fits the positions (they need only
    # the pair's ball images, not the fit; collected in step 4-5 below) ------------------------------
    # the pair's own spin needs only its markers and flash indices, not the flight fit: it runs
    # in the same job, alongside the positions-only fit on the main thread
    def markers_of(p):
        args = (types, layout, R, options.marker_epipolar_px, options.spin_method)
        if procs is None:
            return pool.submit(pair_markers_and_spin, p._cams, p._imgs, p, *args)
        # the worker holding the photos; the pair goes without them and its StereoBalls
        return cached.pop(p._imgs).submit(pitch_workers.pair_markers_job, p._imgs, replace(p, stereo=None), *args)

    marker_jobs = [markers_of(p) if len(p) else None for p in pairs]

    # -- 6. release velocity (seed's two points) -----------------------------------------------------
    p0 = ref.positions[0]
    dk = int(ref.flash_index[1] - ref.flash_index[0])
    v_two = (ref.positions[1] - ref.positions[0]) * ref.strobe_hz / dk

    # -- 7a. positions-only reference fit: clock offsets, curvature -----------------------------------
    t = _time.perf_counter()
    groups, times_l, pos_l, pidx = [], [], [], []
    g = 0
    for i, p in enumerate(pairs):
        if len(p) == 0:
            continue
        if p is not ref:
            g += 1
        p.group = 0 if p is ref else g
        groups.append(np.full(len(p), p.group))
        times_l.append(p.local_times)
        pos_l.append(p.positions)
        pidx.append(np.full(len(p), i))
    groups_a, times_a, pos_a, pidx_a = (np.concatenate(x) for x in (groups, times_l, pos_l, pidx))
    off0 = []
    for p in pairs:
        if len(p) == 0 or p is ref:
            continue
        cr = cross_plane(p0, v_two, np.zeros(3), model, t0=0.0, plane_point=p.positions[0],
                         plane_normal=v_two, t_max=5.0)
        off0.append(cr.time if cr.success else float((p.positions[0] - p0) @ v_two / (v_two @ v_two)))
    # each position's error covariance shape from its pair's triangulation geometry: a pixel
    # error of sigma_px (the pair's sqrt(2) x RMS reprojection error) on each centre, mapped to
    # 3-D through the re-triangulation (the four centre_bias_modes, one image at a time). A
    # stereo pair sees depth 3-6x worse than across its view; an isotropic fit pooled the
    # depth scatter of one pair with the small cross-view scatter of the rest and reported
    # direction sigmas ~1.7x too small (docs/pitch.md, "Uncertainties")
    pos_cov = np.zeros((len(pos_a), 3, 3))
    for i, p in enumerate(pairs):
        if len(p) == 0:
            continue
        d = centre_bias_modes(p._cams, p.centers_px, _pixel_sigma(p.reproj_error_px))  # (4, K, 3)
        pos_cov[pidx_a == i] = np.einsum("mki,mkj->kij", d, d)
    fit_kw = dict(model=model, t0=0.0, method=options.fit_method, position_sigma=options.position_sigma_m,
                  time_groups=groups_a if g else None, time_offsets=np.array(off0) if g else None,
                  position_covariance=pos_cov)
    # the positions-only fit (clock offsets, curvature for the alias check) always uses least
    # squares: it is a step of the pipeline, the selectable optimiser is the final fit's
    fit_pos = fit_reference_trajectory(times_a, pos_a, p0, v_two, None, **{**fit_kw, "method": "least_squares"})
    # calibration error: shared by all positions of a pair (docs/pitch.md, "Uncertainties")
    calib = cap.meta.get("calibration") if isinstance(cap.meta.get("calibration"), dict) else None
    cal_modes, shared_modes = [], {}
    for i, p in enumerate(pairs):
        if len(p) == 0:
            continue
        m = calibration_modes(p._cams, p.centers_px, calib, p.name, options.calibration_focal_sigma)
        sb = options.centre_bias_px
        if sb is None and p.stereo is not None:
            # the bias the shading correction leaves (docs/pitch.md, "Coverage audit", 4th pass)
            mb = _remaining_bias_modes(p)
        else:
            if sb is None:
                sb = _pixel_sigma(p.reproj_error_px, default_px=0.0)
            mb = centre_bias_modes(p._cams, p.centers_px, sb, trend=True)
        m = mb if m is None else np.concatenate([m, mb])
        if not np.any(m):
            continue
        shared_modes[i] = m
        full = np.zeros((len(m), len(pos_a), 3))
        full[:, pidx_a == i] = m
        cal_modes.append(full)
        p.calibration_sigma_m = float(np.sqrt(np.mean(np.sum(m ** 2, axis=(0, 2))) / 3.0))
    cal_modes = np.concatenate(cal_modes) if cal_modes else None
    if calib is None and options.calibration_focal_sigma > 0 and cap.meta.get("rig_calibrated") is not False:
        messages.append("no calibration record (capture.json meta.calibration): the uncertainties leave out "
                        "the calibration error")
    if cal_modes is not None:
        fit_pos = fit_pos.with_extra_covariance(fit_pos.position_covariance_term(cal_modes))
    timings["fit_positions"] = _time.perf_counter() - t
    for p in pairs:
        if p.group > 0:
            p.time_offset_s = float(fit_pos.time_offsets[p.group - 1])
            p.time_offset_sigma_s = float(fit_pos.time_offset_sigma[p.group - 1])
    _progress(progress, total - 2, total, "flight fitted; markers")

    # -- 4-5. markers and spin ----------------------------------------------------------------------
    t = _time.perf_counter()
    t_jobs = t_spin_jobs = 0.0
    pair_spins, spin_error = [], None
    for p, job in zip(pairs, marker_jobs):
        pair_spins.append(None)
        if job is not None:
            (obs, mk, stats), sp, dt, dt_spin = job.result()
            t_jobs += dt
            t_spin_jobs += dt_spin
            if isinstance(sp, Exception):
                spin_error = spin_error or sp
            else:
                pair_spins[-1] = sp
            p.observations, p.markers = obs, mk
            p.n_markers_3d, p.n_markers_ray, p.marker_reproj_px = stats["n_3d"], stats["n_ray"], stats["epipolar_px"]
        del p._imgs, p._cams
    # "markers": the pairs' marker jobs summed (they run on the pool, alongside fit_positions);
    # "markers_wait": what the main thread still waited for them after its positions-only fit
    timings["markers"] = t_jobs
    timings["markers_wait"] = _time.perf_counter() - t
    t = _time.perf_counter()
    n_obs = sum(len(p.observations) for p in pairs if p.observations is not None)
    spin, alias, obs_times = None, None, None
    if n_obs == 0:
        messages.append("no markers found on the ball: spin unavailable (positions and velocity are reported)")
    else:
        try:
            if spin_error is not None:
                raise spin_error
            spin, alias, obs_times = _spin_stage(pairs, fit_pos, model, layout, options.spin_method, messages,
                                                 pair_spins)
        except (ValueError, np.linalg.LinAlgError) as e:  # a spin that cannot be had must not cost the flight
            spin, alias, obs_times = None, None, None
            messages.append(f"spin fit failed ({e}): spin unavailable")
    # "spin": the main thread's spin stage; "spin_pairs": the pairs' own fits, in the marker jobs
    timings["spin"] = _time.perf_counter() - t
    timings["spin_pairs"] = t_spin_jobs
    spin_ok = spin is not None and spin.success
    w0 = cov0 = None  # measured spin at t = 0 of the reference clock
    if spin_ok:
        w0 = spin.spin.copy()
        cov0 = spin.spin_covariance if np.all(np.isfinite(spin.spin_covariance)) else np.eye(3) * 25.0
        if model.kind == "nathan" and obs_times is not None and len(obs_times) == len(spin.inliers):
            slope = _decay_slope(fit_pos, model, obs_times[spin.inliers], 0.0)
            w0, cov0 = w0 / slope, cov0 / slope ** 2
            messages.append(f"spin decay (Nathan model) taken into account: {spin.spin_rpm:.0f} rpm on average over "
                            f"the flashes, {np.linalg.norm(w0) * RPM_PER_RAD_S:.0f} rpm at the first ball image")

    # -- 7b. reference fit with the measured spin ---------------------------------------------------
    t = _time.perf_counter()
    if spin_ok:
        # the spin priors' sigmas from the marker fit's covariance (at least 0.5 rad/s, ~5 rpm)
        e_v = v_two / np.linalg.norm(v_two)
        var_axial = max(float(e_v @ cov0 @ e_v), 0.0)
        var_transverse = max(float(np.trace(cov0)) - var_axial, 0.0) / 2.0
        priors = FitPriors(spin_axial_sigma=max(np.sqrt(var_axial), 0.5),
                           spin_transverse_sigma=max(np.sqrt(var_transverse), 0.5))
        fit_kw["time_offsets"] = fit_pos.time_offsets if g else None
        # positions weighed by their measured scatter (the positions-only fit's residual scale,
        # 0.16-0.25 of the nominal sigma): with the nominal 2 mm the spin prior pulled the fit
        # several times harder than its covariance said (docs/pitch.md, "Coverage audit")
        if np.isfinite(fit_pos.residual_scale) and fit_pos.residual_scale > 0:
            fit_kw["position_sigma"] = options.position_sigma_m * fit_pos.residual_scale
        fit = fit_reference_trajectory(times_a, pos_a, p0, v_two, w0, priors=priors, **fit_kw)
        # the priors weighed the spin with two sigmas; its error is correlated (ReferenceFit.spin_prior_covariance_term)
        fit = fit.with_extra_covariance(fit.spin_prior_covariance_term(cov0))
    elif options.fit_method != "least_squares":
        fit = fit_reference_trajectory(times_a, pos_a, p0, v_two, None, **fit_kw)
    else:
        fit = fit_pos
    if cal_modes is not None and fit is not fit_pos:
        fit = fit.with_extra_covariance(fit.position_covariance_term(cal_modes))
    timings["fit"] = _time.perf_counter() - t
    from stillcap.ball.uncertainty import position_covariances

    # residuals fall short of the errors by the fitted degrees of freedom (as in residual_scale)
    n_obs_coord = int(np.sum(np.isfinite(fit.residuals)))
    n_par = int(np.asarray(fit.covariance).shape[0])
    dof_ratio = n_obs_coord / (n_obs_coord - n_par) if n_obs_coord > n_par else 1.0
    for i, p in enumerate(pairs):
        if p.group > 0:
            p.time_offset_s = float(fit.time_offsets[p.group - 1])
            p.time_offset_sigma_s = float(fit.time_offset_sigma[p.group - 1])
        sel = pidx_a == i
        r = fit.residuals[sel]
        r = r[np.all(np.isfinite(r), axis=1)]
        p.position_sigma_m = (float(np.sqrt(np.mean(r ** 2))) if len(r) >= 2
                              else float(fit.residual_scale * options.position_sigma_m))
        if np.isfinite(p.calibration_sigma_m):  # scatter and the pair's shared calibration shift
            p.position_sigma_m = float(np.hypot(p.position_sigma_m, p.calibration_sigma_m))
        # per image: the triangulation's error shape at the residuals' level, plus the shared
        # modes (an isotropic sigma mis-tests the thin depth ellipsoid; docs/pitch.md, sixth pass)
        cov_k, _ = position_covariances(fit.residuals[sel], pos_cov[sel], shared_modes.get(i),
                                        dof_ratio)
        if cov_k is None and len(p) and np.isfinite(p.position_sigma_m):  # too few residuals for a shape
            cov_k = np.broadcast_to(np.eye(3) * p.position_sigma_m ** 2, (len(p), 3, 3)).copy()
        p.position_covariance_m2 = cov_k
    if not fit.success:
        messages.append(f"reference fit did not converge: {fit.message}")
    if fit.rms_error > 0.05:
        messages.append(f"reference trajectory misses the positions by {fit.rms_error * 1e3:.0f} mm RMS: "
                        "check the calibration and the flash order")
    sig_pos = ref.position_sigma_m if np.isfinite(ref.position_sigma_m) else options.position_sigma_m
    v_two_sigma = np.full(3, np.sqrt(2.0) * sig_pos * ref.strobe_hz / dk)

    # -- 8. metrics ------------------------------------------------------------------------------------
    t = _time.perf_counter()
    if cap.rig.world != "field":
        messages.append(f"rig world is {cap.rig.world!r}, not the baseball field frame: metrics use its axes as if "
                        "they were field axes (y toward the pitcher, z up)")
    release_y_m = None if options.release_y_ft is None else options.release_y_ft * FT
    if release_y_m is None:
        t_rel, p_rel, v_rel = fit.t0, fit.p0, fit.v0
        if cap.rig.world == "field" and p_rel[1] < 50.0 * FT:
            messages.append(f"the first ball image is at y = {p_rel[1] / FT:.1f} ft, far from the pitcher: the release "
                            "metrics are evaluated there (give --release-y-ft / release_y_ft for the real release)")
    else:
        t_rel, p_rel, v_rel = _release_state(fit.p0, fit.v0, fit.spin, model, fit.t0, release_y_m)
    from stillcap.ball.metrics import pitch_metrics_from_flight

    metrics = pitch_metrics_from_flight(p_rel, v_rel, fit.spin, model, t0=t_rel)
    w_meas = cov_rel = None
    if spin_ok:
        f_rel = 1.0
        if model.kind == "nathan":  # the spin at release (before the first ball image: a little faster)
            n = model.nathan
            f_rel = float(np.exp(-(t_rel - fit.t0) * np.linalg.norm(v_rel) / (n.tau0 * n.v_ref)))
        w_meas, cov_rel = w0 * f_rel, cov0 * f_rel ** 2
    _set_spin_metrics(metrics, w_meas, v_rel)
    if not spin_ok:
        metrics.message = "; ".join(filter(None, [metrics.message, "spin unavailable (no usable markers)"]))
    sigma = _metrics_sigma(fit, w_meas, cov_rel, model, t_rel, release_y_m, metrics, int(options.n_samples),
                           options.rng, options.sigma_method)
    timings["metrics"] = _time.perf_counter() - t
    release = {"t0_s": float(t_rel), "p0": p_rel, "v0": v_rel, "spin": w_meas,
               "speed_mph": float(np.linalg.norm(v_rel) / MPH),
               "spin_rpm": float(np.linalg.norm(w_meas) * RPM_PER_RAD_S) if spin_ok else None,
               "p0_sigma": fit.p0_sigma, "v0_sigma": fit.v0_sigma,
               "spin_sigma": np.sqrt(np.clip(np.diag(cov_rel), 0, None)) if spin_ok else None,
               "where": "at the front pair's first ball image" if release_y_m is None
               else f"at y = {options.release_y_ft:.2f} ft (release_y_ft)"}
    table1 = {k: float(v) for k, v in fit.seed_table_row().items()}
    table1["spin_rpm"] = float(np.linalg.norm(w0) * RPM_PER_RAD_S) if spin_ok else float("nan")
    table1["speed_sigma_mph"] = _speed_sigma(fit.v0, fit.covariance[3:6, 3:6]) / MPH
    table1["spin_sigma_rpm"] = float(spin.sigma_rpm) if spin_ok else float("nan")
    timings["total"] = _time.perf_counter() - t_all
    _progress(progress, total, total, "done")
    res = PitchResult(cap.rig.world, options, pairs, fit.times, pos_a, pidx_a, v_two, v_two_sigma, fit, fit_pos,
                      spin, alias, metrics, sigma, release, table1, messages, timings,
                      None if cap.root is None else str(cap.root), spin_obs_times=obs_times)
    if isinstance(cap.truth, dict) and cap.truth.get("kind") == "pitch":
        try:
            res.truth = compare_with_truth(res, cap.truth)
        except (KeyError, ValueError, TypeError, IndexError) as e:  # a truth file of another version
            messages.append(f"truth.json could not be compared: {e}")
    return res


def _set_spin_metrics(metrics: PitchMetrics, w, v_rel) -> None:
    nan = float("nan")
    if w is None:
        metrics.spin_rate_rpm = metrics.active_spin_rpm = metrics.spin_efficiency = nan
        metrics.gyro_angle_deg = metrics.spin_axis_deg = nan
        metrics.spin_tilt = ""
        return
    w = np.asarray(w, float)
    metrics.spin_rate_rpm = float(np.linalg.norm(w) * RPM_PER_RAD_S)
    metrics.spin_efficiency = float(spin_efficiency(w, v_rel))
    metrics.active_spin_rpm = metrics.spin_rate_rpm * metrics.spin_efficiency
    metrics.gyro_angle_deg = float(np.degrees(np.arccos(np.clip(metrics.spin_efficiency, 0.0, 1.0))))
    metrics.spin_axis_deg = float(spin_axis_deg(w, v_rel))
    metrics.spin_tilt = clock_tilt(metrics.spin_axis_deg) if np.isfinite(metrics.spin_axis_deg) else ""


def _with_spin(res: SpinResult, w) -> SpinResult:
    """A copy of a spin result moved to another alias ``w`` (same axis line, rate from the alias)."""
    from dataclasses import replace as _replace

    w = np.asarray(w, float)
    n = float(np.linalg.norm(w))
    return _replace(res, spin=w.copy(), spin_rpm=n * RPM_PER_RAD_S, axis=w / n if n > 0 else np.full(3, np.nan),
                    message=f"{res.message}; alias chosen with both strobe rates and the flight curvature")


# --------------------------------------------------------------------------------------------
# Comparison with the truth (synthetic captures)
# --------------------------------------------------------------------------------------------
def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if not (np.linalg.norm(a) > 0 and np.linalg.norm(b) > 0):
        return float("nan")
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))


def compare_with_truth(result: PitchResult, truth: dict) -> dict:
    """Errors of a result against a studio ``truth.json`` (dict), in the seed's Table 1 units.

    Positions are compared with the true ball centre at the nearest true flash of the same pair;
    the release velocity with the true velocity at the instant of the front pair's first ball
    image; spin with the true spin vector; metrics key by key (``ours - truth``).
    """
    from stillcap.files.jsonable import from_jsonable

    tmodel = flight_model(truth.get("model", "seed"))
    rel = truth["release"]
    tp0, tv0, tw = (np.asarray(rel[k], float) for k in ("p0", "v0", "spin"))
    t_rel = float(rel["t0_s"])
    tpairs = {p["name"]: p for p in truth["pairs"]}
    errs, per_pair, true_t = [], {}, {}
    for p in result.pairs:
        tp = tpairs.get(p.name)
        if tp is None or len(p) == 0:
            continue
        P = from_jsonable(tp["positions"]).reshape(-1, 3)
        T = np.asarray(tp["times_s"], float)
        d = np.linalg.norm(P[None] - p.positions[:, None], axis=2)
        j = np.nanargmin(d, axis=1)
        e = d[np.arange(len(p)), j]
        errs.append(e)
        true_t[p.name] = T[j]
        k_true = np.asarray(tp["flash_index"], int)[j]
        per_pair[p.name] = {"mean_err_mm": float(e.mean() * 1e3), "max_err_mm": float(e.max() * 1e3),
                            "n": len(p), "n_true": int(np.sum(tp.get("rendered", [True] * len(T)))),
                            "flash_index_ok": bool(np.all(np.diff(k_true) == np.diff(p.flash_index)))}
    e = np.concatenate(errs) if errs else np.zeros(0)
    ref = result.pairs[0]
    T0 = float(true_t[ref.name][0]) if ref.name in true_t else float("nan")
    out = {"positions": per_pair, "mean_err_mm": float(e.mean() * 1e3) if len(e) else None,
           "max_err_mm": float(e.max() * 1e3) if len(e) else None}
    if np.isfinite(T0):
        st = simulate(tp0, tv0, tw, [T0], tmodel, t0=t_rel)
        v_true = st.velocities[0]
        for name, v in (("fitted", result.fit.v0), ("two_point", result.velocity_two_point)):
            out[f"velocity_angle_deg_{name}"] = _angle(v, v_true)
            out[f"speed_diff_mph_{name}"] = float((np.linalg.norm(v) - np.linalg.norm(v_true)) / MPH)
        out["true_speed_mph_at_t0"] = float(np.linalg.norm(v_true) / MPH)
        out["true_time_of_t0_s"] = T0
        offs = {}
        for p in result.pairs[1:]:
            if p.name in true_t and len(p):
                # true time of this pair's flash 0 on the reference clock
                true_off = float(true_t[p.name][0] - p.flash_index[0] / p.strobe_hz - T0)
                offs[p.name] = {"fitted_s": p.time_offset_s, "true_s": true_off,
                                "error_ms": (p.time_offset_s - true_off) * 1e3,
                                "sigma_ms": p.time_offset_sigma_s * 1e3}
        out["time_offsets"] = offs
    if result.spin_available:
        w = np.asarray(result.release["spin"], float)
        out["spin_axis_angle_deg"] = _angle(w, tw)
        out["spin_rate_diff_rpm"] = float((np.linalg.norm(w) - np.linalg.norm(tw)) * RPM_PER_RAD_S)
        out["spin_axis_sigma_deg"] = float(result.spin.sigma_axis_deg)
        out["spin_rate_sigma_rpm"] = float(result.spin.sigma_rpm)
    else:
        out["spin_axis_angle_deg"] = out["spin_rate_diff_rpm"] = None
    out["fit_spin_axis_angle_deg"] = _angle(result.fit.spin, tw)
    out["fit_spin_rate_diff_rpm"] = float((np.linalg.norm(result.fit.spin) - np.linalg.norm(tw)) * RPM_PER_RAD_S)
    out["true_speed_mph"] = float(np.linalg.norm(tv0) / MPH)
    out["true_spin_rpm"] = float(np.linalg.norm(tw) * RPM_PER_RAD_S)
    tm = truth.get("metrics") or {}
    ours = result.metrics.to_dict()
    diffs = {}
    for k, tv in tm.items():
        ov = ours.get(k)
        if isinstance(tv, (int, float)) and not isinstance(tv, bool) and isinstance(ov, (int, float)) \
                and not isinstance(ov, bool):
            dv = float(ov) - float(tv)
            if k in _ANGLE_KEYS:
                dv = (dv + 180.0) % 360.0 - 180.0
            diffs[k] = {"ours": float(ov), "truth": float(tv), "diff": dv,
                        "sigma": result.metrics_sigma.get(k)}
    out["metrics"] = diffs
    out["table1"] = {
        "mean_err_mm": out["mean_err_mm"], "max_err_mm": out["max_err_mm"],
        "velocity_angle_deg": out.get("velocity_angle_deg_fitted"), "speed_diff_mph": out.get("speed_diff_mph_fitted"),
        "spin_axis_angle_deg": out["spin_axis_angle_deg"], "spin_rate_diff_rpm": out["spin_rate_diff_rpm"],
        "speed_mph": float(np.linalg.norm(result.fit.v0) / MPH),
        "spin_rpm": float(np.linalg.norm(w) * RPM_PER_RAD_S) if result.spin_available else None,
    }
    return out

