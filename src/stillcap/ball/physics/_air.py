"""Air and ball for the flight models: air properties (:class:`AirProperties`), the weather's
air density and viscosity (:class:`Atmosphere`), the ball (:class:`BallProperties`), the
constants of Nathan's model (:class:`NathanCoefficients`), and the physical constants (gravity,
the front of home plate, the seed's C_D polynomial)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: Standard gravity, m/s^2.
G0 = 9.80665
#: Gravity in the baseball field frame (z up), m/s^2.
GRAVITY_FIELD = (0.0, 0.0, -G0)
#: The front edge of home plate in the field frame, metres (y = 17/12 ft).
PLATE_FRONT_Y = 17.0 / 12.0 * 0.3048

from stillcap._numeric import RPM_PER_RAD_S  # noqa: E402,F401 (the one definition; re-exported)

#: Seed C_D(Re) polynomial coefficients, lowest order first (SPEC J1 "Flight physics").
SEED_CD_POLY = (2.23, -0.28342e-4, 0.13179e-9, -0.25083e-15, 0.17083e-21)


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
