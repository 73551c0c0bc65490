"""Options of the pitch pipeline (:class:`PitchOptions`) and the names its options take."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout
from stillcap.ball.physics import FLIGHT_MODELS, flight_model
from stillcap.response import check_response_option

if TYPE_CHECKING:
    from stillcap.ball.ballfile import Ball

__all__ = ["FIT_METHODS", "PHYSICS", "PitchOptions", "SIGMA_METHODS", "SPIN_METHODS"]

SPIN_METHODS = ("global", "seed")
PHYSICS = tuple(FLIGHT_MODELS)
FIT_METHODS = ("least_squares", "powell")
SIGMA_METHODS = ("linear", "monte_carlo")


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
    ball : Ball or None
        The ball (:class:`stillcap.ball.ballfile.Ball`, a ``stillcap-ball`` file or a built-in
        ball): its radius, mass, flight coefficients and painted markers. Default: the capture's
        ``ball`` key, else the seed's 12-marker baseball. ``layout`` and ``ball_radius_m``, when
        given, override its markers and radius.
    ball_radius_m : float or None
        Ball radius, m; default the ball's (``layout``'s when only a layout is given).
    layout : BallLayout or None
        The painted markers (default: the ball's; the seed's 12-marker ball without one).
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
    center_bias_px : float or None
        1-sigma per image coordinate of a systematic error of the refined ball centres shared by
        all ball images of one camera (the strobe lights the ball from one side). None (default):
        the bias the detector's shading correction leaves, per ball image from its lit phase and
        radius (:func:`stillcap.ball.uncertainty.shading_residual_lookup`; ``docs/pitch.md``,
        "Coverage audit", fourth pass); a number: that many px per image axis and camera, a
        constant and a trend along the flight; 0 leaves it out. ``docs/pitch.md``,
        "Uncertainties".
    shading_model_error : float
        The floor of the share of each ball image's shading correction (``StereoBalls.shading_px``)
        the model may have wrong: the share the photos cannot show. Each capture measures its own
        share on top of it, in quadrature (``remaining_bias_modes(measured=True)``): the share
        its ball images' misfit to the correction's model states (a least-squares fit of the
        same model to each ball's pixels against the correction's Hough centre,
        :func:`stillcap.ball.uncertainty.misfit_share`) and the phase angle's split-half
        uncertainty carried through the model (:func:`stillcap.ball.uncertainty.phase_error_px`);
        ``docs/pitch.md``, "A share each capture measures". The share is taken as a bias shared
        by a camera's ball images, a constant and a linear trend along the pair's images each of
        this size (with the default ``center_bias_px``): the light's direction, the lens blur
        and the clipping are read from the photo and the leather is taken for lambertian; what a
        misfit cannot show (a wrong blur or response moves both estimates alike) is this floor.
        How much of it a pair's two cameras share is read from the pair's epipolar residuals
        (``remaining_bias_modes(correlation="epipolar")``); the same modes size the spin's
        shared ball-centre error (``docs/pitch.md``, "The spin's centre error and the pair's
        shared bias").
        Default 0.1, a stated assumption (it was a fixed 0.5 before the share was measured per
        capture); 0 trusts what the capture measures alone.
    center_sigma_px : float
        Expected random error of a refined ball centre per image axis, px: the noise the
        self-checks (:mod:`stillcap.pipelines.pitch.checks`) test the epipolar residuals and the
        flight's chi-square against. Default 0.2 (the studio's photos give 0.05-0.1; real
        lenses, motion blur and JPEG give more).
    workers : int
        Threads for the per-pair work: decoding the photos (while the calling thread finds the
        ball images of the pairs already decoded), markers and the pairs' own spin fits; 1: all
        on the calling thread (one core: a batch worker's setting). The results do not depend on
        it.
    processes : int
        Worker processes for the per-pair work (0, default: the ``workers`` threads). Each pair's
        photos are decoded, its ball images and markers found and its own spin fitted in a
        process of a pool that lives across calls (:mod:`stillcap.pipelines.pitch.workers`;
        started on the first call with ``processes > 0``, about 1 s, reused afterwards): worth it
        for many captures in one process (benchmarks, batches), not for one (``docs/pitch.md``,
        "Timing"). The results are identical to the threads'. Needs a capture loaded from or
        saved to a folder; scripts that use it need an ``if __name__ == "__main__":`` guard.
    response : None, "auto", Response or str
        The cameras' response (``docs/camera-response.md``): None (default) each camera's own
        from the rig; a :class:`~stillcap.response.Response` (or ``"srgb"``, ``"linear"``,
        ``"gamma:2.2"``) for every camera; ``"auto"`` estimated from the ball's shading.
    """

    spin_method: str = "global"
    physics: str = "seed"
    fit_method: str = "least_squares"
    ball_radius_m: float | None = None
    layout: BallLayout | None = None
    ball: Ball | None = None
    release_y_ft: float | None = None
    expected_speed_mph: float | None = None
    position_sigma_m: float = 0.002
    marker_epipolar_px: float = 2.0
    n_samples: int = 200
    rng: object = 0
    sigma_method: str = "linear"
    calibration_focal_sigma: float = 2.5e-4
    center_bias_px: float | None = None
    shading_model_error: float = 0.1
    center_sigma_px: float = 0.2
    workers: int = 2
    processes: int = 0
    response: object = None

    def __post_init__(self):
        object.__setattr__(self, "response", check_response_option(self.response))
        fm = self.fit_method.replace("-", "_") if isinstance(self.fit_method, str) else self.fit_method
        object.__setattr__(self, "fit_method", fm)
        for name, allowed in (("spin_method", SPIN_METHODS), ("physics", PHYSICS), ("fit_method", FIT_METHODS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        if self.ball is not None:
            # imported here: only a given ball needs it, and stillcap pitch starts faster without it
            from stillcap.ball.ballfile import Ball

            if not isinstance(self.ball, Ball):
                raise ValueError(f"ball must be a stillcap.ball.ballfile.Ball, got {type(self.ball).__name__}")
        if self.ball_radius_m is not None and not (np.isfinite(self.ball_radius_m) and self.ball_radius_m > 0):
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
        if not (np.isfinite(self.center_sigma_px) and self.center_sigma_px > 0):
            raise ValueError(f"center_sigma_px must be a positive number of pixels, got {self.center_sigma_px}")
        if not (np.isfinite(self.shading_model_error) and self.shading_model_error >= 0):
            raise ValueError(f"shading_model_error must be >= 0, got {self.shading_model_error}")
        if not (np.isfinite(self.calibration_focal_sigma) and self.calibration_focal_sigma >= 0):
            raise ValueError(f"calibration_focal_sigma must be >= 0, got {self.calibration_focal_sigma}")

    @property
    def radius_m(self) -> float:
        """The ball radius used, m: ``ball_radius_m``, else the layout's or the ball's, else the
        seed's baseball."""
        if self.ball_radius_m is not None:
            return float(self.ball_radius_m)
        if self.layout is not None:
            return float(self.layout.radius)
        return float(self.ball.radius) if self.ball is not None else BASEBALL_RADIUS

    @property
    def marker_layout(self) -> BallLayout:
        """The painted markers used: ``layout``, else the ball's, else the seed's (with the
        radius :attr:`radius_m`)."""
        if self.layout is not None:
            return self.layout
        if self.ball is not None:
            lay = self.ball.layout
            return lay if lay.radius == self.radius_m else replace(lay, radius=self.radius_m)
        return BallLayout.seed(radius=self.radius_m)

    def flight_model(self):
        """The flight model: the ball's (:meth:`Ball.flight_model`, ``physics`` choosing between
        the baseball models), or ``physics``'s baseball model without a ball."""
        if self.ball is not None:
            return self.ball.flight_model(self.physics)
        return flight_model(self.physics)

    @property
    def flight_name(self) -> str:
        """The flight model's name: ``physics`` for a ball flying as a baseball, else the
        ball's flight preset (or ``"own coefficients"``)."""
        if self.ball is None or self.ball.flight_preset == "baseball":
            return self.physics
        return self.ball.flight_name

    def to_dict(self) -> dict:
        d = self._to_dict()
        if self.ball is not None:  # (only then: results without a ball keep their keys)
            d["ball"] = {"name": self.ball.name, "radius_m": self.ball.radius, "mass_kg": self.ball.mass,
                         "flight": self.ball.flight_name, "markers": len(self.marker_layout),
                         "source": self.ball.source}
        return d

    def _to_dict(self) -> dict:
        return {"spin_method": self.spin_method, "physics": self.physics, "fit_method": self.fit_method,
                "ball_radius_m": self.radius_m, "release_y_ft": self.release_y_ft,
                "expected_speed_mph": self.expected_speed_mph, "position_sigma_m": self.position_sigma_m,
                "marker_epipolar_px": self.marker_epipolar_px, "n_samples": int(self.n_samples),
                "calibration_focal_sigma": self.calibration_focal_sigma, "centre_bias_px": self.center_bias_px,
                "center_sigma_px": self.center_sigma_px, "shading_model_error": self.shading_model_error,
                "response": self.response if self.response in (None, "auto") else self.response.to_json()}
