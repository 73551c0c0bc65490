"""The flight models: what the integrators need (:class:`AccelerationModel`), gravity, drag and
Magnus force on a spinning ball (:class:`FlightModel`, with its fast fixed-spin kernels), and the
one registry of models by name (:data:`FLIGHT_MODELS`, :func:`flight_model`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Literal, Protocol

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.physics._air import (GRAVITY_FIELD, RPM_PER_RAD_S, SEED_CD_POLY, AirProperties, Atmosphere,
                                       BallProperties, NathanCoefficients)


class AccelerationModel(Protocol):
    """What the integrators need: acceleration from velocity, spin and time since ``t0``."""

    def acceleration(self, velocity: np.ndarray, spin: np.ndarray, dt) -> np.ndarray: ...


@dataclass(frozen=True)
class FlightModel:
    """Gravity, drag and Magnus force on a spinning ball; ``kind`` is ``"seed"`` or ``"nathan"``.

    Attributes
    ----------
    kind : {"seed", "nathan"}
        Aerodynamic coefficients (:mod:`stillcap.ball.physics`).
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
