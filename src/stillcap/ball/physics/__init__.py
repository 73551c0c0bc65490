"""Ball-flight physics (SPEC J1 "Flight physics", seed section 4.5).

The flight of a spinning ball obeys ``m dv/dt = m g + F_D + F_M`` with

- drag ``F_D = -1/2 C_D rho A |v| v``
- Magnus force ``F_M = 1/2 C_L rho A |v|^2 (w x v) / |w x v|``

where ``v`` is the velocity relative to the air and ``w`` the spin (angular velocity, rad/s).
Everything is SI and lives in one right-handed world frame; gravity is a vector, by default the
baseball field frame's ``(0, 0, -9.80665)`` (z up, see :mod:`stillcap.ball.metrics`).

Two aerodynamic models are offered by :class:`FlightModel`:

``"seed"``
    The seed paper's model: ``C_D(Re)`` is the seed's 4th-order polynomial in the Reynolds number
    ``Re = |v| d / nu`` (a drag-crisis curve; ``Re`` clamped to the fitted range 0.8e5..2.2e5),
    ``C_L = 1.5 r |w| / |v|`` (Alaways) with the *total* spin rate, spin vector constant.
    With ``nu = 1.5e-5 m^2/s`` the polynomial gives C_D = 0.60 / 0.26 / 0.12 at 40 / 60 / 80 mph,
    the values the SPEC quotes, so that is the default air (:class:`AirProperties`).
``"nathan"``
    Alan Nathan's trajectory calculator (baseball.physics.illinois.edu, "TrajectoryCalculator";
    constants as in its spreadsheet and public ports): ``C_D = cd0 + cdspin * (w_perp / 1000 rpm)``
    with cd0 = 0.3008, cdspin = 0.0292; ``C_L = cl2 S / (cl0 + cl1 S)`` with cl0 = 0.583,
    cl1 = 2.333, cl2 = 1.120 and spin factor ``S = r w_perp / |v|`` (saturates at
    cl2/cl1 = 0.48); spin decays as ``exp(-t / tau)`` with ``tau = tau0 * (100 mph / |v|)`` and
    tau0 = 30 s (the calculator's "tau0 = 30", scaled by 146.7 ft/s / v). Only the spin
    component transverse to the velocity (``w_perp = |w x v| / |v|``) produces lift or the spin
    part of drag; gyro spin does nothing. Air density from temperature, pressure, humidity and
    altitude via :class:`Atmosphere`.

Integrators:

- :func:`simulate` is the reference: ``scipy.integrate.solve_ivp(method="RK45")`` (Dormand-Prince
  5(4), the seed's DOPRI5) with tight tolerances, forward and backward from ``t0``.
- :func:`cross_plane` integrates until the ball crosses a plane (default: the front of home
  plate, ``y = 17/12 ft``) using a terminal event.
- :func:`simulate_batch` is the fast integrator for fitting: fixed-step RK4 or DOPRI5 written in
  NumPy over many trajectories at once (hand-written because SciPy's ODE solvers integrate one
  system at a time; a fit needs 1 + 2 * n_params trajectories per Jacobian, which vectorise).
  ``benchmarks/bench_physics.py`` measures it against :func:`simulate`.

Where things are (private modules, the names below are the public face):

- ``_air``: :class:`AirProperties`, :class:`Atmosphere`, :func:`saturation_vapour_pressure`,
  :class:`BallProperties`, :class:`NathanCoefficients` and the constants;
- ``_model``: :class:`AccelerationModel`, :class:`FlightModel`, :data:`FLIGHT_MODELS`,
  :func:`flight_model`;
- ``_integrate``: :func:`simulate`, :class:`Trajectory`, :func:`cross_plane`,
  :class:`PlaneCrossing`;
- ``_balls``: :class:`BallModel`, :data:`BALLS`, :func:`ball_model` (softball, cricket, tennis,
  table tennis and baseball presets from published coefficients, sources there and in
  docs/flight.md);
- ``_batch``: :func:`simulate_batch`, :class:`BatchTrajectory` (Runge-Kutta tableaux and steps,
  Hermite interpolation).
"""

from stillcap.ball.physics._air import (G0, GRAVITY_FIELD, PLATE_FRONT_Y, RPM_PER_RAD_S, SEED_CD_POLY, AirProperties,
                                       Atmosphere, BallProperties, NathanCoefficients, saturation_vapour_pressure)
from stillcap.ball.physics._balls import BALLS, BallModel, ball_model
from stillcap.ball.physics._batch import BatchTrajectory, simulate_batch
from stillcap.ball.physics._integrate import PlaneCrossing, Trajectory, cross_plane, simulate
from stillcap.ball.physics._model import FLIGHT_MODELS, AccelerationModel, FlightModel, flight_model

__all__ = ["G0", "GRAVITY_FIELD", "PLATE_FRONT_Y", "RPM_PER_RAD_S", "SEED_CD_POLY", "AirProperties", "Atmosphere",
           "BallProperties", "NathanCoefficients", "saturation_vapour_pressure", "AccelerationModel", "FlightModel",
           "FLIGHT_MODELS", "flight_model", "Trajectory", "simulate", "PlaneCrossing", "cross_plane",
           "BatchTrajectory", "simulate_batch", "BALLS", "BallModel", "ball_model"]
