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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Literal, Protocol

import numpy as np
from scipy.integrate import solve_ivp

from stillcap._checks import as_array, as_points

#: Standard gravity, m/s^2.
G0 = 9.80665
#: Gravity in the baseball field frame (z up), m/s^2.
GRAVITY_FIELD = (0.0, 0.0, -G0)
#: The front edge of home plate in the field frame, metres (y = 17/12 ft).
PLATE_FRONT_Y = 17.0 / 12.0 * 0.3048

RPM_PER_RAD_S = 60.0 / (2.0 * np.pi)

#: Seed C_D(Re) polynomial coefficients, lowest order first (SPEC J1 "Flight physics").
SEED_CD_POLY = (2.23, -0.28342e-4, 0.13179e-9, -0.25083e-15, 0.17083e-21)


# --------------------------------------------------------------------------------------------
# Air and ball
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AirProperties:
    """Air as the flight model sees it.

    Attributes
    ----------
    density : float
        kg/m^3.
    kinematic_viscosity : float
        m^2/s, used for the Reynolds number of the seed model. The default 1.5e-5 reproduces the
        C_D values the seed's polynomial is documented with.
    """

    density: float = 1.2
    kinematic_viscosity: float = 1.5e-5

    def __post_init__(self):
        if not (self.density > 0 and self.kinematic_viscosity > 0):
            raise ValueError(f"air density and viscosity must be positive, got {self}")


def saturation_vapour_pressure(temperature_c):
    """Saturation vapour pressure of water over water, Pa (Buck 1996).

    ``e_s = 611.21 exp((18.678 - T/234.5) T / (257.14 + T))`` with T in deg C. Nathan's
    calculator uses the same form (in mmHg).
    """
    t = np.asarray(temperature_c, float)
    return 611.21 * np.exp((18.678 - t / 234.5) * t / (257.14 + t))


@dataclass(frozen=True)
class Atmosphere:
    """Weather at the ball park; :meth:`air` turns it into :class:`AirProperties`.

    Attributes
    ----------
    temperature_c : float
        Air temperature, deg C (Nathan's calculator default 70 F = 21.1 C).
    pressure_pa : float
        Barometric pressure *reduced to sea level*, Pa (what weather reports give; 29.92 inHg =
        101325 Pa). The pressure at the field is ``pressure_pa * exp(-altitude_m / 8217 m)``,
        the scale height Nathan's calculator uses (beta = 0.0001217 / m).
    relative_humidity : float
        0..1.
    altitude_m : float
        Field elevation above sea level, metres.
    """

    temperature_c: float = 21.1
    pressure_pa: float = 101325.0
    relative_humidity: float = 0.5
    altitude_m: float = 0.0

    def __post_init__(self):
        if not 0.0 <= self.relative_humidity <= 1.0:
            raise ValueError(f"relative_humidity must be in [0, 1], got {self.relative_humidity}")
        if self.temperature_c <= -273.15 or self.pressure_pa <= 0:
            raise ValueError(f"unphysical atmosphere {self}")

    @property
    def station_pressure_pa(self) -> float:
        """Pressure at the field's altitude, Pa."""
        return self.pressure_pa * float(np.exp(-1.217e-4 * self.altitude_m))

    @property
    def vapour_pressure_pa(self) -> float:
        """Partial pressure of water vapour, Pa."""
        return self.relative_humidity * float(saturation_vapour_pressure(self.temperature_c))

    @property
    def density(self) -> float:
        """Moist-air density, kg/m^3: ``(p - 0.3783 e) / (R_d T)`` (dry gas constant 287.058)."""
        t_k = self.temperature_c + 273.15
        return (self.station_pressure_pa - 0.3783 * self.vapour_pressure_pa) / (287.058 * t_k)

    @property
    def dynamic_viscosity(self) -> float:
        """Sutherland's law, Pa s: ``1.458e-6 T^1.5 / (T + 110.4)``."""
        t_k = self.temperature_c + 273.15
        return 1.458e-6 * t_k ** 1.5 / (t_k + 110.4)

    def air(self) -> AirProperties:
        """Density and kinematic viscosity for a :class:`FlightModel`."""
        rho = self.density
        return AirProperties(density=rho, kinematic_viscosity=self.dynamic_viscosity / rho)


@dataclass(frozen=True)
class BallProperties:
    """A ball's mass and size (default: the seed's baseball, 0.145 kg, 0.0737 m).

    Attributes
    ----------
    mass : float
        kg.
    diameter : float
        m (a regulation ball: 9.0-9.25 in circumference, i.e. 0.0729-0.0749 m).
    """

    mass: float = 0.145
    diameter: float = 0.0737

    def __post_init__(self):
        if not (self.mass > 0 and self.diameter > 0):
            raise ValueError(f"ball mass and diameter must be positive, got {self}")

    @property
    def radius(self) -> float:
        return 0.5 * self.diameter

    @property
    def area(self) -> float:
        """Cross-section ``pi r^2``, m^2."""
        return np.pi * self.radius ** 2


@dataclass(frozen=True)
class NathanCoefficients:
    """Aerodynamic constants of Nathan's trajectory calculator (see the module docstring).

    ``cdspin`` is per 1000 rpm of transverse spin; ``tau0`` (s) is the spin-decay time at
    ``v_ref`` (100 mph = 44.704 m/s), scaled as ``tau = tau0 * v_ref / |v|``.
    """

    cd0: float = 0.3008
    cdspin: float = 0.0292
    cl0: float = 0.583
    cl1: float = 2.333
    cl2: float = 1.120
    tau0: float = 30.0
    v_ref: float = 44.704


class AccelerationModel(Protocol):
    """What the integrators need: acceleration from velocity, spin and time since ``t0``."""

    def acceleration(self, velocity: np.ndarray, spin: np.ndarray, dt) -> np.ndarray: ...


@dataclass(frozen=True)
class FlightModel:
    """Gravity, drag and Magnus force on a spinning ball; ``kind`` is ``"seed"`` or ``"nathan"``.

    Attributes
    ----------
    kind : {"seed", "nathan"}
        Aerodynamic coefficients (module docstring).
    ball : BallProperties
    air : AirProperties
        Use ``Atmosphere(...).air()`` for weather-dependent density.
    gravity : tuple of 3 floats
        m/s^2 in the world frame (default: field frame, z up).
    wind : tuple of 3 floats
        Air velocity in the world frame, m/s; forces use the velocity relative to the air.
    nathan : NathanCoefficients
        Constants of the ``"nathan"`` model.
    re_range : tuple of 2 floats
        Reynolds numbers the seed polynomial is clamped to.
    """

    kind: Literal["seed", "nathan"] = "seed"
    ball: BallProperties = field(default_factory=BallProperties)
    air: AirProperties = field(default_factory=AirProperties)
    gravity: tuple = GRAVITY_FIELD
    wind: tuple = (0.0, 0.0, 0.0)
    nathan: NathanCoefficients = field(default_factory=NathanCoefficients)
    re_range: tuple = (0.8e5, 2.2e5)
    _c: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.kind not in ("seed", "nathan"):
            raise ValueError(f"kind must be 'seed' or 'nathan', got {self.kind!r}")
        object.__setattr__(self, "gravity", tuple(float(g) for g in as_array(self.gravity, (3,), "gravity")))
        object.__setattr__(self, "wind", tuple(float(g) for g in as_array(self.wind, (3,), "wind")))
        r = self.ball.radius
        k = self.air.density * self.ball.area / (2.0 * self.ball.mass)
        object.__setattr__(self, "_c", {
            "k": k, "r": r, "k15r": 1.5 * k * r, "g": self.gravity,
            "wind": np.asarray(self.wind), "windy": any(self.wind),
            "d_over_nu": self.ball.diameter / self.air.kinematic_viscosity,
            "re_lo": float(self.re_range[0]), "re_hi": float(self.re_range[1]),
            "inv_tau_vref": 1.0 / (self.nathan.tau0 * self.nathan.v_ref),
            "cdspin_rad": self.nathan.cdspin * RPM_PER_RAD_S / 1000.0,
        })

    @classmethod
    def seed_model(cls, **kwargs) -> "FlightModel":
        """The seed paper's model (``kind="seed"``)."""
        return cls(kind="seed", **kwargs)

    @classmethod
    def nathan_model(cls, atmosphere: Atmosphere | None = None, **kwargs) -> "FlightModel":
        """Nathan's model with air from ``atmosphere`` (default :class:`Atmosphere`)."""
        air = (atmosphere or Atmosphere()).air()
        return cls(kind="nathan", air=air, **kwargs)

    # -- coefficients -------------------------------------------------------------------------
    @property
    def k(self) -> float:
        """``rho A / (2 m)``, 1/m: acceleration = k C v^2."""
        return self.air.density * self.ball.area / (2.0 * self.ball.mass)

    def reynolds(self, speed):
        """``Re = |v| d / nu``."""
        return np.asarray(speed, float) * self.ball.diameter / self.air.kinematic_viscosity

    def drag_coefficient(self, speed, spin_perp=0.0, dt=0.0):
        """C_D for airspeed ``speed`` (m/s) and transverse spin ``spin_perp`` (rad/s).

        Seed: the clamped polynomial in Re (spin ignored). Nathan: ``cd0 + cdspin * rpm/1000``
        with the decayed transverse spin.
        """
        speed = np.asarray(speed, float)
        if self.kind == "seed":
            re = np.clip(self.reynolds(speed), *self.re_range)
            c = SEED_CD_POLY
            return c[0] + re * (c[1] + re * (c[2] + re * (c[3] + re * c[4])))
        n = self.nathan
        w = np.asarray(spin_perp, float) * self._decay(speed, dt)
        return n.cd0 + n.cdspin * w * RPM_PER_RAD_S / 1000.0

    def lift_coefficient(self, speed, spin, spin_perp=None, dt=0.0):
        """C_L for airspeed ``speed``, spin rate ``spin`` (|w|) and transverse spin (rad/s).

        Seed: ``1.5 r |w| / |v|``. Nathan: ``cl2 S / (cl0 + cl1 S)``, ``S = r w_perp / |v|``
        (decayed).
        """
        speed = np.asarray(speed, float)
        r = self.ball.radius
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.kind == "seed":
                return 1.5 * r * np.asarray(spin, float) / speed
            n = self.nathan
            wp = np.asarray(spin if spin_perp is None else spin_perp, float)
            s = r * wp * self._decay(speed, dt) / speed
            return n.cl2 * s / (n.cl0 + n.cl1 * s)

    def _decay(self, speed, dt):
        n = self.nathan
        return np.exp(-np.asarray(dt, float) * speed / (n.tau0 * n.v_ref))

    # -- forces --------------------------------------------------------------------------------
    def acceleration(self, velocity, spin, dt=0.0) -> np.ndarray:
        """Total acceleration ``g + (F_D + F_M) / m``, m/s^2.

        Parameters
        ----------
        velocity : ndarray, shape (..., 3)
            Ball velocity in the world frame, m/s.
        spin : ndarray, shape (..., 3)
            Spin vector (rad/s, right-hand rule), broadcast against ``velocity``.
        dt : float or ndarray, shape (...)
            Time since the spin was ``spin`` (Nathan's spin decay; ignored by the seed model).

        Returns
        -------
        ndarray, shape broadcast of (..., 3)
        """
        # The hot loop of every integrator: written component-wise with constants cached in
        # __post_init__ (np.cross and np.linalg.norm cost more than the arithmetic on 3-vectors).
        c = self._c
        v = np.asarray(velocity, float)
        w = np.asarray(spin, float)
        if c["windy"]:
            v = v - c["wind"]
        vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
        wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
        speed = np.maximum(np.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
        cx = wy * vz - wz * vy
        cy = wz * vx - wx * vz
        cz = wx * vy - wy * vx
        # |w x v|; where it is 0 the Magnus force is 0 (cx = cy = cz = 0), so any finite factor works
        n_wxv = np.maximum(np.sqrt(cx * cx + cy * cy + cz * cz), 1e-300)
        k = c["k"]
        if self.kind == "seed":
            re = np.clip(speed * c["d_over_nu"], c["re_lo"], c["re_hi"])
            p = SEED_CD_POLY
            cd = p[0] + re * (p[1] + re * (p[2] + re * (p[3] + re * p[4])))
            # k C_L v^2 (w x v)/|w x v| with C_L = 1.5 r |w| / v
            mag = c["k15r"] * np.sqrt(wx * wx + wy * wy + wz * wz) * speed / n_wxv
        else:
            nt = self.nathan
            wd = (n_wxv / speed) * np.exp(-np.asarray(dt, float) * speed * c["inv_tau_vref"])
            cd = nt.cd0 + c["cdspin_rad"] * wd
            s = c["r"] * wd / speed
            mag = k * (nt.cl2 * s / (nt.cl0 + nt.cl1 * s)) * speed * speed / n_wxv
        drag = k * cd * speed
        g = c["g"]
        out = np.empty(np.broadcast_shapes(v.shape, w.shape))
        out[..., 0] = g[0] - drag * vx + mag * cx
        out[..., 1] = g[1] - drag * vy + mag * cy
        out[..., 2] = g[2] - drag * vz + mag * cz
        return out

    def _fixed_spin(self, spin):
        """:meth:`acceleration` as a function ``acc(v, dt)`` of (M, 3) velocities for fixed spins.

        The (M, 3) face of :meth:`_fixed_spin_rows` (same numbers, transposed views).

        Parameters
        ----------
        spin : ndarray, shape (M, 3)

        Returns
        -------
        callable ``acc(velocity (M, 3), dt) -> ndarray (M, 3)``
        """
        rows = self._fixed_spin_rows(np.asarray(spin, float).T)

        def acc(velocity, dt):
            return rows(np.asarray(velocity, float).T, dt).T
        return acc

    def _fixed_spin_rows(self, spin):
        """:meth:`acceleration` as a function ``acc(v, dt, out=None)`` of (3, M) velocities.

        The integrators' hot loop, on component rows (x, y, z of M flights): the cost is NumPy's
        per-call overhead, so it is written to make few ufunc calls (squares and cross products
        on whole (3, M) blocks, the spin's rotated copies and ``|w|`` computed once per flight,
        arithmetic in place with ``out=``). The operations on every number and their order are
        those of :meth:`acceleration`, so the results are bit-identical (tests check it).

        Parameters
        ----------
        spin : ndarray, shape (3, M)

        Returns
        -------
        callable ``acc(velocity (3, M), dt, out=None) -> ndarray (3, M)``
            ``out`` (3, M), if given, must not overlap ``velocity``.
        """
        c = self._c
        w = np.array(spin, float)
        wx, wy, wz = w
        # cross product w x v = w1 * v[(2, 0, 1)] - w2 * v[(1, 2, 0)] row by row; the rotated
        # velocities are slices of the rows (vx, vy, vz, vx, vy) (two copies: cheaper than
        # fancy indexing)
        w1, w2 = w[[1, 2, 0]], w[[2, 0, 1]]
        shape = (5,) + w.shape[1:]
        seed = self.kind == "seed"
        k = c["k"]
        g = np.array(c["g"], float)[:, None]
        windy, wind = c["windy"], c["wind"][:, None]
        if seed:
            kw = c["k15r"] * np.sqrt(wx * wx + wy * wy + wz * wz)
            d_over_nu, re_lo, re_hi = c["d_over_nu"], c["re_lo"], c["re_hi"]
            p0, p1, p2, p3, p4 = SEED_CD_POLY
        else:
            nt = self.nathan
            r, inv_tau, cd0, cdspin = c["r"], c["inv_tau_vref"], nt.cd0, c["cdspin_rad"]
            cl0, cl1, cl2 = nt.cl0, nt.cl1, nt.cl2
        mul, add, sub, sqrt = np.multiply, np.add, np.subtract, np.sqrt

        def acc(velocity, dt, out=None):
            vb = np.empty(shape)
            v = vb[:3]
            if windy:
                sub(velocity, wind, out=v)
            else:
                v[...] = velocity
            vb[3:] = vb[:2]
            sq = v * v
            speed = add(sq[0], sq[1])
            add(speed, sq[2], out=speed)
            sqrt(speed, out=speed)
            np.maximum(speed, 1e-12, out=speed)
            cr = w1 * vb[2:]
            sub(cr, w2 * vb[1:4], out=cr)
            mul(cr, cr, out=sq)
            n_wxv = add(sq[0], sq[1])
            add(n_wxv, sq[2], out=n_wxv)
            sqrt(n_wxv, out=n_wxv)
            np.maximum(n_wxv, 1e-300, out=n_wxv)
            if seed:
                re = speed * d_over_nu
                np.maximum(re, re_lo, out=re)  # np.clip, without its wrapper's overhead
                np.minimum(re, re_hi, out=re)
                cd = re * p4
                add(cd, p3, out=cd)
                mul(cd, re, out=cd)
                add(cd, p2, out=cd)
                mul(cd, re, out=cd)
                add(cd, p1, out=cd)
                mul(cd, re, out=cd)
                add(cd, p0, out=cd)
                mag = kw * speed
                np.divide(mag, n_wxv, out=mag)
            else:
                wd = n_wxv / speed
                e = (-np.asarray(dt, float)) * speed
                mul(e, inv_tau, out=e)
                np.exp(e, out=e)
                mul(wd, e, out=wd)
                cd = cdspin * wd
                add(cd, cd0, out=cd)
                s = r * wd
                np.divide(s, speed, out=s)
                den = cl1 * s
                add(den, cl0, out=den)
                lift = cl2 * s
                np.divide(lift, den, out=lift)
                mag = k * lift
                mul(mag, speed, out=mag)
                mul(mag, speed, out=mag)
                np.divide(mag, n_wxv, out=mag)
            drag = k * cd
            mul(drag, speed, out=drag)
            # g - drag v + mag (w x v)
            out = mul(v, drag, out=out)
            sub(g, out, out=out)
            mul(cr, mag, out=cr)
            add(out, cr, out=out)
            return out
        return acc

    def _fixed_spin_scalar(self, spin):
        """:meth:`acceleration` of one ball with a fixed spin, in plain Python floats:
        ``acc(vx, vy, vz, dt) -> (ax, ay, az)``.

        The single-flight integrators' hot loop (:func:`simulate_batch` with one flight; for the
        seed model also :func:`simulate` and :func:`cross_plane`, see ``_rhs``): the constants
        and the spin terms are bound once, as Python floats (~10x faster than NumPy on length-3
        arrays). The same formulas in the same order as :meth:`acceleration`: bit-identical for
        the seed model; Nathan's ``math.exp`` can differ from ``np.exp`` in the last bit (tests
        check both).
        """
        c = self._c
        wx, wy, wz = (float(x) for x in spin)
        k = c["k"]
        g0, g1, g2 = c["g"]
        windy = c["windy"]
        ux, uy, uz = self.wind
        sqrt, exp = math.sqrt, math.exp
        if self.kind == "seed":
            d_over_nu, re_lo, re_hi = c["d_over_nu"], c["re_lo"], c["re_hi"]
            p0, p1, p2, p3, p4 = SEED_CD_POLY
            kw = c["k15r"] * sqrt(wx * wx + wy * wy + wz * wz)

            def acc(vx, vy, vz, dt):
                if windy:
                    vx, vy, vz = vx - ux, vy - uy, vz - uz
                speed = max(sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
                cx = wy * vz - wz * vy
                cy = wz * vx - wx * vz
                cz = wx * vy - wy * vx
                n_wxv = max(sqrt(cx * cx + cy * cy + cz * cz), 1e-300)
                re = min(max(speed * d_over_nu, re_lo), re_hi)
                cd = p0 + re * (p1 + re * (p2 + re * (p3 + re * p4)))
                mag = kw * speed / n_wxv
                drag = k * cd * speed
                return (g0 - drag * vx + mag * cx, g1 - drag * vy + mag * cy,
                        g2 - drag * vz + mag * cz)
            return acc
        nt = self.nathan
        r, inv_tau, cd0, cdspin = c["r"], c["inv_tau_vref"], nt.cd0, c["cdspin_rad"]
        cl0, cl1, cl2 = nt.cl0, nt.cl1, nt.cl2

        # the seed closure's first lines repeated on purpose: a shared helper would add a Python
        # call to every evaluation of this hot loop
        def acc(vx, vy, vz, dt):
            if windy:
                vx, vy, vz = vx - ux, vy - uy, vz - uz
            speed = max(sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
            cx = wy * vz - wz * vy
            cy = wz * vx - wx * vz
            cz = wx * vy - wy * vx
            n_wxv = max(sqrt(cx * cx + cy * cy + cz * cz), 1e-300)
            wd = (n_wxv / speed) * exp(-dt * speed * inv_tau)
            cd = cd0 + cdspin * wd
            s = r * wd / speed
            mag = k * (cl2 * s / (cl0 + cl1 * s)) * speed * speed / n_wxv
            drag = k * cd * speed
            return (g0 - drag * vx + mag * cx, g1 - drag * vy + mag * cy,
                    g2 - drag * vz + mag * cz)
        return acc


#: The flight models by name: the one registry that options, capture files, the CLI and the
#: studio choose from (``--physics NAME``).
FLIGHT_MODELS: dict[str, Callable[[], FlightModel]] = {
    "seed": FlightModel.seed_model,
    "nathan": FlightModel.nathan_model,
}


def flight_model(model: str | AccelerationModel | None = None) -> AccelerationModel:
    """A flight model from its name in :data:`FLIGHT_MODELS`; ``None`` is the seed's model and a
    model object (a :class:`FlightModel` or anything that implements
    :class:`AccelerationModel`) is returned as it is."""
    if model is None:
        return FlightModel()
    if isinstance(model, str):
        if model not in FLIGHT_MODELS:
            raise ValueError(f"unknown flight model {model!r}; choose one of {', '.join(FLIGHT_MODELS)}")
        return FLIGHT_MODELS[model]()
    return model


# --------------------------------------------------------------------------------------------
# Reference integrator
# --------------------------------------------------------------------------------------------
@dataclass
class Trajectory:
    """Positions and velocities of one ball at requested times.

    Attributes
    ----------
    times : ndarray, shape (N,)
    positions : ndarray, shape (N, 3)
        m.
    velocities : ndarray, shape (N, 3)
        m/s.
    success : bool
        The integrator reached every requested time.
    message : str
    nfev : int
        Acceleration evaluations.
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    success: bool = True
    message: str = ""
    nfev: int = 0


def _rhs(model, spin, t0):
    if isinstance(model, FlightModel) and model.kind == "seed":
        # solve_ivp integrates one ball: the plain-float twin of the acceleration is ~6x faster
        # than NumPy on 3-vectors and, for the seed model, bit-identical to it (tests check it;
        # Nathan's spin decay needs exp, where math.exp and np.exp may differ in the last bit)
        acc = model._fixed_spin_scalar(spin)

        def f(t, y):
            vx, vy, vz = y[3:].tolist()
            return np.array((vx, vy, vz, *acc(vx, vy, vz, t - t0)))
        return f

    def f(t, y):
        a = model.acceleration(y[3:], spin, t - t0)
        return np.concatenate([y[3:], a])
    return f


def _check_initial(p0, v0, spin):
    p0 = as_array(p0, (3,), "p0")
    v0 = as_array(v0, (3,), "v0")
    spin = as_array(spin, (3,), "spin")
    if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(v0)) and np.all(np.isfinite(spin))):
        raise ValueError("p0, v0 and spin must be finite")
    return p0, v0, spin


def simulate(p0, v0, spin, times, model=None, *, t0: float = 0.0, rtol: float = 1e-10,
             atol: float = 1e-10, method: str = "RK45") -> Trajectory:
    """Integrate one flight with ``solve_ivp`` (reference accuracy) and sample it at ``times``.

    Parameters
    ----------
    p0, v0 : array_like, shape (3,)
        Position (m) and velocity (m/s) at time ``t0``, world frame.
    spin : array_like, shape (3,)
        Spin vector at ``t0``, rad/s (right-hand rule; ``|spin| * 60 / 2 pi`` rpm).
    times : array_like, shape (N,)
        Times (s) to report; may lie before and after ``t0`` (integrated both ways).
    model : FlightModel, optional
        Default ``FlightModel()`` (seed model, field-frame gravity).
    t0 : float
        Time of the initial state, s.
    rtol, atol : float
        solve_ivp tolerances (defaults give ~1e-9 m over a pitch).
    method : str
        solve_ivp method; "RK45" is Dormand-Prince 5(4) (DOPRI5).

    Returns
    -------
    Trajectory
    """
    p0, v0, spin = _check_initial(p0, v0, spin)
    times = as_array(times, (None,), "times")
    if not np.all(np.isfinite(times)):
        raise ValueError("times must be finite")
    model = flight_model(model)
    n = len(times)
    pos = np.full((n, 3), np.nan)
    vel = np.full((n, 3), np.nan)
    y0 = np.concatenate([p0, v0])
    f = _rhs(model, spin, t0)
    ok, msgs, nfev = True, [], 0
    for sel in (times >= t0, times < t0):
        if not sel.any():
            continue
        ts = times[sel]
        t_end = ts.max() if ts.max() >= t0 else ts.min()
        if t_end == t0:
            pos[sel], vel[sel] = p0, v0
            continue
        sol = solve_ivp(f, (t0, t_end), y0, method=method, rtol=rtol, atol=atol, dense_output=True)
        nfev += sol.nfev
        ok &= bool(sol.success)
        msgs.append(sol.message)
        if sol.success:
            y = sol.sol(ts)
            pos[sel], vel[sel] = y[:3].T, y[3:].T
    return Trajectory(times, pos, vel, ok, "; ".join(msgs), nfev)


@dataclass
class PlaneCrossing:
    """Where and when a flight crosses a plane.

    Attributes
    ----------
    time : float
        s (NaN if not crossed before ``t_max``).
    position, velocity : ndarray, shape (3,)
    success : bool
    trajectory : scipy OdeSolution or None
        Dense output from ``t0`` to the crossing: ``trajectory(t)`` gives the (6,) state.
    """

    time: float
    position: np.ndarray
    velocity: np.ndarray
    success: bool
    message: str = ""
    trajectory: object = None


def cross_plane(p0, v0, spin, model=None, *, t0: float = 0.0,
                plane_point=(0.0, PLATE_FRONT_Y, 0.0), plane_normal=(0.0, 1.0, 0.0),
                t_max: float = 3.0, rtol: float = 1e-10, atol: float = 1e-10) -> PlaneCrossing:
    """Integrate (RK45, event) until the ball crosses a plane; default the front of home plate.

    Parameters
    ----------
    p0, v0, spin : array_like, shape (3,)
        Initial state at ``t0`` (m, m/s, rad/s).
    plane_point, plane_normal : array_like, shape (3,)
        The plane; default ``y = 17/12 ft`` in the field frame.
    t_max : float
        Give up after this long (s); ``success`` is then False.

    Returns
    -------
    PlaneCrossing
    """
    p0, v0, spin = _check_initial(p0, v0, spin)
    q = as_array(plane_point, (3,), "plane_point")
    nrm = as_array(plane_normal, (3,), "plane_normal")
    model = flight_model(model)

    def event(t, y):
        return float(np.dot(y[:3] - q, nrm))
    event.terminal = True

    sol = solve_ivp(_rhs(model, spin, t0), (t0, t0 + t_max), np.concatenate([p0, v0]),
                    method="RK45", rtol=rtol, atol=atol, events=event, dense_output=True)
    if sol.status == 1 and len(sol.t_events[0]):
        y = sol.y_events[0][0]
        return PlaneCrossing(float(sol.t_events[0][0]), y[:3].copy(), y[3:].copy(), True,
                             sol.message, sol.sol)
    nan = np.full(3, np.nan)
    return PlaneCrossing(np.nan, nan, nan.copy(), False,
                         sol.message if not sol.success else "plane not crossed before t_max",
                         sol.sol)


# --------------------------------------------------------------------------------------------
# Fast batch integrator
# --------------------------------------------------------------------------------------------
# Butcher tableaux (c, A, b). DOPRI5 uses its 5th-order weights at a fixed step.
_TABLEAUX = {
    "rk4": (
        np.array([0.0, 0.5, 0.5, 1.0]),
        [[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]],
        np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
    ),
    "dopri5": (
        np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0]),
        [[], [1 / 5], [3 / 40, 9 / 40], [44 / 45, -56 / 15, 32 / 9],
         [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729],
         [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]],
        np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]),
    ),
}


@dataclass
class BatchTrajectory:
    """Many flights sampled at shared times.

    Attributes
    ----------
    times : ndarray, shape (N,)
    positions, velocities : ndarray, shape (M, N, 3)
    nfev : int
        Vectorised acceleration evaluations (each over all M flights).
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    nfev: int = 0


def _rk_step(acc, plan, t, h, y, d1, ks, t0, out):
    # one explicit Runge-Kutta step of y = (p, v) (6, M), y' = (v, acc(v, t - t0)), written into
    # out (6, M). d1 = y'(t) is the first stage, known from the previous step; ks are (6, M)
    # buffers for the other stages (rows 0-2 the stage velocity, 3-5 its acceleration), so the
    # final combination of positions and velocities is one array operation per stage. plan is
    # _rk_plan(tableau). The arithmetic of every number is that of the textbook formula
    # vi = v + sum_j (h a_ij) ka_j, y + h sum_i b_i k_i, in the same order.
    stages, weights = plan
    ks[0] = d1
    v = y[3:]
    for i, (ci, row) in enumerate(stages, 1):
        vi = ks[i][:3]
        if row:
            (j, aij), *rest = row
            np.multiply(ks[j][3:], h * aij, out=vi)
            np.add(v, vi, out=vi)
            for j, aij in rest:
                np.add(vi, (h * aij) * ks[j][3:], out=vi)
        else:
            vi[...] = v
        acc(vi, t + ci * h - t0, out=ks[i][3:])
    (i, bi), *rest = weights
    dy = bi * ks[i]
    for i, bi in rest:
        np.add(dy, bi * ks[i], out=dy)
    np.multiply(dy, h, out=dy)
    return np.add(y, dy, out=out)


def _rk_plan(tab):
    # a Butcher tableau as (c_i, nonzero (j, a_ij)) per stage after the first and the nonzero
    # (i, b_i), Python floats: what _rk_step loops over
    c, a, b = _float_tableau(tab)
    stages = [(c[i], [(j, aij) for j, aij in enumerate(a[i]) if aij]) for i in range(1, len(c))]
    return stages, [(i, bi) for i, bi in enumerate(b) if bi]


def _rk_step_scalar(acc, tab, t, h, p, v, t0, a1):
    # pure-float twin of _rk_step for one flight (see FlightModel._fixed_spin_scalar): the same
    # operations on every number, in the same order; tab holds Python floats (_float_tableau)
    c, a, b = tab
    kv, ka = [v], [a1]
    for i in range(1, len(c)):
        x, y, z = v
        for j, aij in enumerate(a[i]):
            if aij:
                ha = h * aij
                kx, ky, kz = ka[j]
                x, y, z = x + ha * kx, y + ha * ky, z + ha * kz
        kv.append((x, y, z))
        ka.append(acc(x, y, z, t + c[i] * h - t0))
    px = py = pz = ax = ay = az = 0.0
    for bi, (ux, uy, uz), (gx, gy, gz) in zip(b, kv, ka):
        if bi:
            px += bi * ux
            py += bi * uy
            pz += bi * uz
            ax += bi * gx
            ay += bi * gy
            az += bi * gz
    return ((p[0] + h * px, p[1] + h * py, p[2] + h * pz),
            (v[0] + h * ax, v[1] + h * ay, v[2] + h * az))


def _float_tableau(tab):
    # a Butcher tableau as Python floats (NumPy scalars would slow the pure-float integrator)
    c, a, b = tab
    return [float(x) for x in c], [[float(x) for x in row] for row in a], [float(x) for x in b]


def _hermite5(s, h, p0, v0, a0, p1, v1, a1):
    """Quintic Hermite interpolation of position and velocity on one step.

    ``s`` (..., 1) in [0, 1] is the fraction of the step ``h`` (..., 1); end states (..., 3).
    Error ~ h^6 |p^(6)|: far below the RK error for smooth flights.
    """
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    s5 = s4 * s
    h0 = 1 - 10 * s3 + 15 * s4 - 6 * s5
    h1 = s - 6 * s3 + 8 * s4 - 3 * s5
    h2 = 0.5 * (s2 - 3 * s3 + 3 * s4 - s5)
    h3 = 0.5 * (s3 - 2 * s4 + s5)
    h4 = -4 * s3 + 7 * s4 - 3 * s5
    h5 = 10 * s3 - 15 * s4 + 6 * s5
    pos = h0 * p0 + h * h1 * v0 + h * h * h2 * a0 + h * h * h3 * a1 + h * h4 * v1 + h5 * p1
    d0 = -30 * s2 + 60 * s3 - 30 * s4
    d1 = 1 - 18 * s2 + 32 * s3 - 15 * s4
    d2 = 0.5 * (2 * s - 9 * s2 + 12 * s3 - 5 * s4)
    d3 = 0.5 * (3 * s2 - 8 * s3 + 5 * s4)
    d4 = -12 * s2 + 28 * s3 - 15 * s4
    vel = (d0 * (p0 - p1)) / h + d1 * v0 + h * d2 * a0 + h * d3 * a1 + d4 * v1
    return pos, vel


def _steps(t0, t_end, sign, max_step):
    """Number of steps and signed step from ``t0`` towards ``t_end`` (0 steps: nothing to do)."""
    span = sign * (t_end - t0)
    if span <= 0:
        return 0, 0.0
    k = int(np.ceil(span / max_step - 1e-9))
    return k, sign * span / k


def _nodes_scalar(model, tab, p, v, w, t0, max_step, ends):
    # simulate_batch's nodes for one flight with plain floats: node times (K,) and a (1, K, 9)
    # array of positions, velocities and accelerations
    # (Python floats throughout: arithmetic on NumPy scalars costs several times more)
    acc = model._fixed_spin_scalar(w[0])
    tab = _float_tableau(tab)
    p, v = tuple(p[0].tolist()), tuple(v[0].tolist())
    a_start = acc(*v, 0.0)
    branches = []
    for sign, t_end in ends:
        k, h = _steps(t0, t_end, sign, max_step)
        h = float(h)
        ts, ps, vs, as_ = [t0], [p], [v], [a_start]
        pc, vc = p, v
        for i in range(k):
            pc, vc = _rk_step_scalar(acc, tab, t0 + i * h, h, pc, vc, t0, as_[-1])
            ts.append(t0 + (i + 1) * h)
            ps.append(pc)
            vs.append(vc)
            as_.append(acc(*vc, (i + 1) * h))
        branches.append((ts, ps, vs, as_))
    (tf, pf, vf, af), (tb, pb, vb, ab) = branches
    # one ascending node list: backward branch reversed, then forward without the shared t0
    return (np.array(tb[::-1] + tf[1:]),
            np.concatenate([np.array(lb[::-1] + lf[1:]) for lb, lf in ((pb, pf), (vb, vf), (ab, af))],
                           axis=1)[None])


def _nodes_rows(model, tab, p, v, w, t0, max_step, ends):
    # simulate_batch's nodes for M flights, integrated on (6, M) states (rows: x, y, z of the
    # positions, then of the velocities); returns node times (K,) and an (M, K, 9) array of
    # positions, velocities and accelerations. A model without FlightModel's kernels is called
    # through its acceleration method.
    m = len(p)
    if hasattr(model, "_fixed_spin_rows"):
        acc = model._fixed_spin_rows(w.T)
    else:
        def acc(vel, dt, out=None):
            a = model.acceleration(vel.T, w, dt).T
            if out is None:
                return a
            out[...] = a
            return out
    y0 = np.concatenate([p.T, v.T])
    d0 = np.empty((6, m))
    d0[:3] = y0[3:]
    acc(y0[3:], 0.0, out=d0[3:])
    ks = [None] + [np.empty((6, m)) for _ in range(len(tab[0]) - 1)]
    plan = _rk_plan(tab)
    branches = []
    for sign, t_end in ends:
        k, h = _steps(t0, t_end, sign, max_step)
        ys = np.empty((k + 1, 6, m))  # states y and derivatives y' = (v, a) at the nodes
        ds = np.empty((k + 1, 6, m))
        ys[0], ds[0] = y0, d0
        for i in range(k):
            _rk_step(acc, plan, t0 + i * h, h, ys[i], ds[i], ks, t0, out=ys[i + 1])
            ds[i + 1, :3] = ys[i + 1, 3:]
            acc(ys[i + 1, 3:], (i + 1) * h, out=ds[i + 1, 3:])
        # (i + 1) * h and t0 + ... as in the scalar path: the same node times
        ts = [t0] + [t0 + (i + 1) * h for i in range(k)]
        branches.append((ts, ys, ds))
    (tf, yf, df), (tb, yb, db) = branches
    node_t = np.array(tb[::-1] + tf[1:])
    ys = np.concatenate([yb[::-1], yf[1:]]).transpose(2, 0, 1)  # (M, K, 6)
    ds = np.concatenate([db[::-1], df[1:]]).transpose(2, 0, 1)
    # C-contiguous (M, K, 9) like the scalar path: the layout of the interpolated outputs follows
    # it, and downstream reductions (einsum) may add in another order on other layouts
    return node_t, np.ascontiguousarray(np.concatenate([ys, ds[..., 3:]], axis=2))


def simulate_batch(p0, v0, spin, times, model=None, *, t0: float = 0.0, method: str = "rk4",
                   max_step: float = 0.02) -> BatchTrajectory:
    """Fixed-step RK4 / DOPRI5 over M flights at once (the fast integrator for fitting).

    The flights are stepped on a uniform grid from ``t0`` (steps of at most ``max_step``,
    forward and backward as the requested times need), and sampled at ``times`` by quintic
    Hermite interpolation of the node positions, velocities and accelerations, so the cost does
    not grow with the number of requested times.

    Parameters
    ----------
    p0, v0 : array_like, shape (3,) or (M, 3)
        Initial positions (m) and velocities (m/s) at ``t0``.
    spin : array_like, shape (3,) or (M, 3)
        Spin vectors, rad/s.
    times : array_like, shape (N,)
        Output times, s (before and/or after ``t0``).
    model : FlightModel, optional
    t0 : float
        Time of the initial states, s.
    method : {"rk4", "dopri5"}
        Fixed-step classical RK4 (4 evaluations per step) or the DOPRI5 5th-order formula
        (6 evaluations per step).
    max_step : float
        Largest step, s. Errors versus :func:`simulate` are in ``benchmarks/bench_physics.py``
        (RK4 with 20 ms steps: well below a micrometre over a pitch).

    Returns
    -------
    BatchTrajectory
        ``positions`` and ``velocities`` of shape (M, N, 3) (M = 1 for single inputs).
    """
    if method not in _TABLEAUX:
        raise ValueError(f"method must be one of {sorted(_TABLEAUX)}, got {method!r}")
    if not max_step > 0:
        raise ValueError(f"max_step must be positive, got {max_step}")
    p, _ = as_points(p0, 3, "p0")
    v, _ = as_points(v0, 3, "v0")
    w, _ = as_points(spin, 3, "spin")
    m = max(len(p), len(v), len(w))
    for name, arr in (("p0", p), ("v0", v), ("spin", w)):
        if len(arr) not in (1, m):
            raise ValueError(f"{name} must have shape (3,) or ({m}, 3), got {arr.shape}")
    # (read-only views: the integrators copy what they keep)
    p, v, w = (a if len(a) == m else np.broadcast_to(a, (m, 3)) for a in (p, v, w))
    times = as_array(times, (None,), "times")
    if not np.all(np.isfinite(times)):
        raise ValueError("times must be finite")
    t0 = float(t0)
    model = flight_model(model)
    tab = _TABLEAUX[method]
    n_stage = len(tab[0])
    scalar = m == 1 and hasattr(model, "_fixed_spin_scalar")
    ends = ((1.0, times.max(initial=t0)), (-1.0, times.min(initial=t0)))
    # node times (K,) and (M, K, 9) positions, velocities and accelerations at the nodes
    nodes_of = _nodes_scalar if scalar else _nodes_rows
    node_t, nodes = nodes_of(model, tab, p, v, w, t0, max_step, ends)
    nfev = 1 + (len(node_t) - 1) * n_stage  # stages 2..n plus each node's acceleration
    if len(node_t) == 1:
        pos = np.repeat(nodes[..., :3], len(times), axis=1)
        vel = np.repeat(nodes[..., 3:6], len(times), axis=1)
        return BatchTrajectory(times, pos, vel, nfev)
    j = np.clip(np.searchsorted(node_t, times, side="right") - 1, 0, len(node_t) - 2)
    hh = (node_t[j + 1] - node_t[j])[:, None]
    s = (times - node_t[j])[:, None] / hh
    n0, n1 = nodes[:, j], nodes[:, j + 1]  # the nodes before and after each time, (M, N, 9)
    pos, vel = _hermite5(s, hh, n0[..., :3], n0[..., 3:6], n0[..., 6:],
                         n1[..., :3], n1[..., 3:6], n1[..., 6:])
    return BatchTrajectory(times, pos, vel, nfev)
