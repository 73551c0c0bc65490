"""Balls of other sports: a generic aerodynamic model (:class:`BallModel`, an
:class:`~stillcap.ball.physics.AccelerationModel`) and presets from published coefficients
(:data:`BALLS`, :func:`ball_model`).

The model is the one of :mod:`stillcap.ball.physics` with coefficients of any ball:

- drag ``C_D = cd_scale * (C_D0(Re) + cd_spin * w_perp / 1000 rpm)``, where ``C_D0(Re)`` is the
  preset's table of (Re, C_D) points interpolated linearly in ``log Re`` and held constant
  outside the table (the table's own range: nothing is clamped to a baseball's Reynolds numbers);
- lift ``C_L = cl_scale * cl2 S / (cl0 + cl1 S)`` with the spin factor ``S = r w_perp / |v|``
  (``cl1 = 0``: linear in S), along ``w x v``; only the spin transverse to the velocity
  (``w_perp = |w x v| / |v|``) acts, as in Nathan's model.

``cd_scale`` and ``cl_scale`` (1 for a preset) are what :func:`stillcap.ball.rally.fit_flight`
fits with ``fit_coefficients``. ``cd_range`` and ``cl_range`` are the published ranges of the
coefficients for the ball, against which fitted values are compared.

Sources (also in docs/flight.md):

baseball
    0.145 kg, 73.7 mm (Official Baseball Rules 3.01: 5-5.25 oz, 9-9.25 in). Nathan's
    TrajectoryCalculator constants (the ``"nathan"`` :class:`FlightModel` without its spin decay):
    C_D = 0.3008 + 0.0292 per 1000 rpm, C_L = 1.120 S / (0.583 + 2.333 S). C_D range 0.30-0.50
    (A. M. Nathan, "The effect of spin on the flight of a baseball", Am. J. Phys. 76, 119 (2008)).
softball
    Fastpitch 12 in: 0.184 kg (6.25-7 oz), 97.0 mm (12 in circumference), USA Softball rules.
    C_D ~ 0.40 with the baseball's C_L shape (Nathan's softball notes; A. M. Nathan et al.
    measured C_D 0.33-0.50 for softballs in free flight); range 0.30-0.55.
cricket
    0.160 kg (5.5-5.75 oz), 71.9 mm (8.81-9 in circumference), MCC Laws of Cricket, law 4.
    R. D. Mehta, "Aerodynamics of sports balls", Annu. Rev. Fluid Mech. 17, 151 (1985) and
    Mehta & Pallis (2001): C_D ~ 0.5 below Re 1.5e5, falling to ~0.3 above the seam-tripped
    transition near 2-4e5; range 0.25-0.60. C_L linear, 1.0 S (a smooth-sphere Magnus slope).
tennis
    57.7 g (56.0-59.4 g), 67.0 mm (65.4-68.6 mm), ITF Rules of Tennis, appendix I.
    C_D = 0.508, C_L = 1 / (2.022 + 0.981 / S) (J. Štěpánek, "The aerodynamics of tennis balls:
    the topspin lob", Am. J. Phys. 56, 138 (1988)); free flight C_D 0.507 +- 0.024
    (R. Cross & C. Lindsey, "Measurements of drag and lift on tennis balls in flight",
    Sports Eng. 17 (2014)); range 0.48-0.70 (wind tunnels give 0.55-0.65, Mehta & Pallis).
table-tennis
    2.7 g, 40 mm (ITTF Handbook, 2.3). C_D ~ 0.50 at 3e4 < Re < 9e4, C_L rising with S to
    ~0.3 (flight experiments with Nittaku 3-Star Premium balls, "Lift crisis of a spinning table
    tennis ball", Eur. J. Phys. (2020); C_D 0.4-0.6 over those Re, with a lift crisis near
    S = 0.5 not modelled here); range C_D 0.40-0.60, C_L 0-0.40. C_L = 1.3 S / (1 + 1.9 S),
    saturating near 0.4 as those measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.physics._air import GRAVITY_FIELD, RPM_PER_RAD_S, AirProperties


@dataclass(frozen=True)
class BallModel:
    """Gravity, drag and Magnus force on any ball (module docstring); an AccelerationModel.

    Attributes
    ----------
    name : str
    mass : float
        kg.
    diameter : float
        m.
    cd_table : tuple of (Re, C_D) pairs
        Drag coefficient of the non-spinning ball, interpolated linearly in ``log Re``.
    cd_spin : float
        Extra C_D per 1000 rpm of transverse spin.
    cl0, cl1, cl2 : float
        ``C_L = cl2 S / (cl0 + cl1 S)``.
    cd_scale, cl_scale : float
        Multipliers of C_D and C_L (fitted by :func:`stillcap.ball.rally.fit_flight`).
    cd_range, cl_range : tuple of 2 floats
        Published ranges of C_D and C_L for this ball.
    air : AirProperties
    gravity : tuple of 3 floats
        m/s^2 in the world frame: it also says which way is up.
    source : str
        Where the coefficients come from.
    """

    name: str
    mass: float
    diameter: float
    cd_table: tuple = ((1e4, 0.5),)
    cd_spin: float = 0.0
    cl0: float = 1.0
    cl1: float = 0.0
    cl2: float = 1.0
    cd_scale: float = 1.0
    cl_scale: float = 1.0
    cd_range: tuple = (0.0, math.inf)
    cl_range: tuple = (0.0, math.inf)
    air: AirProperties = field(default_factory=AirProperties)
    gravity: tuple = GRAVITY_FIELD
    source: str = ""

    def __post_init__(self):
        if not (self.mass > 0 and self.diameter > 0):
            raise ValueError(f"ball {self.name!r}: mass and diameter must be positive, got {self.mass}, {self.diameter}")
        table = np.asarray(self.cd_table, float).reshape(-1, 2)
        if not (len(table) and np.all(table[:, 0] > 0) and np.all(np.diff(table[:, 0]) > 0)):
            raise ValueError(f"ball {self.name!r}: cd_table must be (Re, C_D) pairs with increasing Re > 0")
        if not (self.cl0 > 0 and self.cl1 >= 0):
            raise ValueError(f"ball {self.name!r}: need cl0 > 0 and cl1 >= 0, got {self.cl0}, {self.cl1}")
        object.__setattr__(self, "gravity", tuple(float(g) for g in as_array(self.gravity, (3,), "gravity")))
        object.__setattr__(self, "_log_re", np.log(table[:, 0]))
        object.__setattr__(self, "_cd", table[:, 1].copy())

    # -- coefficients -------------------------------------------------------------------------
    @property
    def kind(self) -> str:
        """``"ball"``: lift from the transverse spin (as Nathan's model), no spin decay (what the
        fits and the alias check ask of a model's ``kind``, beside FlightModel's "seed" and "nathan")."""
        return "ball"

    @property
    def radius(self) -> float:
        return 0.5 * self.diameter

    @property
    def k(self) -> float:
        """``rho A / (2 m)``, 1/m: acceleration = k C v^2."""
        return self.air.density * math.pi * self.radius ** 2 / (2.0 * self.mass)

    @property
    def up(self) -> np.ndarray:
        """Unit vector against gravity."""
        g = np.asarray(self.gravity, float)
        n = np.linalg.norm(g)
        return -g / n if n > 0 else np.array([0.0, 0.0, 1.0])

    def reynolds(self, speed):
        """``Re = |v| d / nu``."""
        return np.asarray(speed, float) * self.diameter / self.air.kinematic_viscosity

    def drag_coefficient(self, speed, spin_perp=0.0):
        """C_D at airspeed ``speed`` (m/s) and transverse spin ``spin_perp`` (rad/s)."""
        lr = np.log(np.maximum(self.reynolds(speed), 1e-300))
        cd0 = np.interp(lr, self._log_re, self._cd)
        return self.cd_scale * (cd0 + self.cd_spin * np.asarray(spin_perp, float) * RPM_PER_RAD_S / 1000.0)

    def lift_coefficient(self, speed, spin_perp):
        """C_L at airspeed ``speed`` (m/s) and transverse spin ``spin_perp`` (rad/s)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            s = self.radius * np.asarray(spin_perp, float) / np.asarray(speed, float)
            return self.cl_scale * self.cl2 * s / (self.cl0 + self.cl1 * s)

    def with_scales(self, cd_scale: float | None = None, cl_scale: float | None = None, **kwargs) -> "BallModel":
        """A copy with other coefficient scales (and any other field in ``kwargs``)."""
        return replace(self, cd_scale=self.cd_scale if cd_scale is None else float(cd_scale),
                       cl_scale=self.cl_scale if cl_scale is None else float(cl_scale), **kwargs)

    # -- forces --------------------------------------------------------------------------------
    def acceleration(self, velocity, spin, dt=0.0) -> np.ndarray:
        """Total acceleration ``g + (F_D + F_M) / m``, m/s^2 (shapes as FlightModel's)."""
        return self.acceleration_scaled(velocity, spin, self.cd_scale, self.cl_scale)

    def acceleration_scaled(self, velocity, spin, cd_scale, cl_scale) -> np.ndarray:
        """:meth:`acceleration` with C_D and C_L scales broadcast against ``velocity[..., 0]``
        (many parameter sets at once, for the fits)."""
        v = np.asarray(velocity, float)
        w = np.asarray(spin, float)
        speed = np.maximum(np.linalg.norm(v, axis=-1), 1e-12)
        wxv = np.cross(w, v)
        n_wxv = np.linalg.norm(wxv, axis=-1)
        w_perp = n_wxv / speed
        lr = np.log(speed * (self.diameter / self.air.kinematic_viscosity))
        cd = np.interp(lr, self._log_re, self._cd) + self.cd_spin * w_perp * (RPM_PER_RAD_S / 1000.0)
        s = self.radius * w_perp / speed
        cl = self.cl2 * s / (self.cl0 + self.cl1 * s)
        k = self.k
        drag = (k * speed) * cd * np.asarray(cd_scale, float)
        mag = k * np.asarray(cl_scale, float) * cl * speed * speed / np.maximum(n_wxv, 1e-300)
        return np.asarray(self.gravity) - drag[..., None] * v + mag[..., None] * wxv


def _baseball():
    return BallModel("baseball", 0.145, 0.0737, ((1e4, 0.3008),), cd_spin=0.0292, cl0=0.583, cl1=2.333,
                     cl2=1.120, cd_range=(0.30, 0.50), cl_range=(0.0, 0.48),
                     source="Nathan, TrajectoryCalculator; Am. J. Phys. 76, 119 (2008)")


def _softball():
    return BallModel("softball", 0.184, 0.0970, ((1e4, 0.40),), cl0=0.583, cl1=2.333, cl2=1.120,
                     cd_range=(0.30, 0.55), cl_range=(0.0, 0.48),
                     source="USA Softball rules; Nathan's baseball C_L shape, C_D ~ 0.40")


def _cricket():
    return BallModel("cricket", 0.160, 0.0719, ((1.0e5, 0.50), (1.5e5, 0.50), (3.0e5, 0.30)),
                     cd_range=(0.25, 0.60), cl_range=(0.0, 0.40),
                     source="MCC Laws of Cricket 4; Mehta, Annu. Rev. Fluid Mech. 17, 151 (1985)")


def _tennis():
    return BallModel("tennis", 0.0577, 0.067, ((1e4, 0.508),), cl0=0.981, cl1=2.022, cl2=1.0,
                     cd_range=(0.48, 0.70), cl_range=(0.0, 0.50),
                     source="ITF Rules appendix I; Stepanek, Am. J. Phys. 56, 138 (1988); Cross & Lindsey (2014)")


def _table_tennis():
    return BallModel("table-tennis", 0.0027, 0.040, ((3e4, 0.50), (9e4, 0.50)), cl0=1.0, cl1=1.9, cl2=1.3,
                     cd_range=(0.40, 0.60), cl_range=(0.0, 0.40),
                     source="ITTF Handbook 2.3; 'Lift crisis of a spinning table tennis ball' (flight experiments)")


#: Ball presets by name (module docstring for the sources): ``--ball NAME``.
BALLS = {
    "baseball": _baseball,
    "softball": _softball,
    "cricket": _cricket,
    "tennis": _tennis,
    "table-tennis": _table_tennis,
}


def ball_model(name: str, gravity=None, air: AirProperties | None = None) -> BallModel:
    """The preset :data:`BALLS` ``[name]`` (``table_tennis`` and ``table-tennis`` both work),
    with ``gravity`` (m/s^2, world frame; default z up) and ``air`` if given."""
    key = str(name).strip().lower().replace("_", "-")
    if key not in BALLS:
        raise ValueError(f"unknown ball {name!r}; choose one of {', '.join(BALLS)}")
    model = BALLS[key]()
    kw = {}
    if gravity is not None:
        kw["gravity"] = tuple(as_array(gravity, (3,), "gravity"))
    if air is not None:
        kw["air"] = air
    return replace(model, **kw) if kw else model
