"""Rallies of any ball: reading a tracked trajectory (:func:`read_trajectory_csv`), cutting it into
free flights at bounces and hits (:func:`cut_flights`), and fitting each flight with gravity, drag
and Magnus force, the spin and optionally the drag and lift coefficients fitted
(:func:`fit_flight`). ``stillcap flight`` is the command line face; docs/flight.md the numbers.

Cutting: between contacts a ball moves under gravity plus small aerodynamic forces, so after
taking gravity out (``q = p - g t^2 / 2``) the positions are nearly straight. At every sample the
velocity of a straight line through the ``window`` samples before it and through the ``window``
after it are compared; a jump larger than ``jump`` (m/s) marks a contact, at the sample where the
jump peaks (that sample is dropped: it may belong to either side). A contact where the up
component of the velocity turns from down to up near the lowest plane (or near ``plane`` if
given) is a bounce, any other a hit. Gaps in time longer than ``max_gap`` times the median sample
interval cut too.

Fitting (:func:`fit_flight`): parameters are the position and velocity at the first sample, the
spin transverse to the first velocity (two components in :func:`stillcap.ball.fit.spin_basis`
with the model's up; spin along the velocity makes no force in these models and is not fitted),
and with ``fit_coefficients`` the drag scale (and the lift scale when the spin is given: with the
spin unknown only their product is seen, so the fitted spin carries the lift and the lift
coefficient is reported from it). Levenberg-Marquardt on the position residuals, with the
Jacobian by central differences over all perturbed flights at once (a fixed-step RK4 that
steps through the sample times). Uncertainties are ``s^2 (J^T J)^-1`` with ``s^2`` the residual
variance per degree of freedom.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from stillcap.files.table import number_cell
from stillcap._checks import as_array
from stillcap.ball.fit import spin_basis

from stillcap._numeric import RPM_PER_RAD_S  # noqa: E402 (the one definition)

_TIME_NAMES = ("t", "time", "timestamp", "times", "t_s", "time_s", "seconds")


# -- reading -------------------------------------------------------------------------------------
def read_trajectory_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) and positions (N, 3) from a CSV with a header naming ``t`` (or ``time``,
    ``timestamp``) and ``x, y, z`` columns, any case and order (tt3d's ``Timestamp,X,Y,Z``).

    Rows are sorted by time; an empty cell or ``nan`` is an unobserved coordinate (the row
    is dropped). Raises ``ValueError`` naming the file, row and column of anything else.
    """
    path = Path(path)
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    if not rows or not any(c.strip() for c in rows[0]):
        raise ValueError(f"{path}: empty file, expected a header with t, x, y, z columns")
    header = [c.strip().lower() for c in rows[0]]
    cols = {}
    for want, names in (("t", _TIME_NAMES), ("x", ("x", "x_m")), ("y", ("y", "y_m")), ("z", ("z", "z_m"))):
        hit = [i for i, h in enumerate(header) if h in names]
        if not hit:
            raise ValueError(f"{path}: row 1: no {want!r} column (header {','.join(rows[0])}; "
                             f"expected t or time or timestamp, x, y, z)")
        cols[want] = hit[0]
    out = []
    for r, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        vals = []
        for want in ("t", "x", "y", "z"):
            i = cols[want]
            name = rows[0][i].strip()
            if i >= len(row):
                raise ValueError(f"{path}: row {r}, column {name!r}: missing (the row has {len(row)} cells)")
            cell = row[i].strip()
            if cell == "" or cell.lower() == "nan":
                if want == "t":
                    raise ValueError(f"{path}: row {r}, column {name!r}: empty time")
                vals.append(math.nan)
                continue
            vals.append(number_cell(cell, f"{path}: row {r}, column {name!r}"))
        out.append(vals)
    a = np.array(out, float).reshape(-1, 4)
    a = a[np.all(np.isfinite(a), axis=1)]
    if len(a) < 2:
        raise ValueError(f"{path}: {len(a)} complete rows of t, x, y, z; a flight needs more")
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    dup = np.flatnonzero(np.diff(a[:, 0]) <= 0)
    if len(dup):
        raise ValueError(f"{path}: row {int(order[dup[0] + 1]) + 2}, column {rows[0][cols['t']].strip()!r}: "
                         f"time {a[dup[0] + 1, 0]!r} repeats an earlier row's")
    return a[:, 0].copy(), a[:, 1:].copy()


# -- cutting -------------------------------------------------------------------------------------
@dataclass
class Contact:
    """A bounce, hit or gap between two flights."""

    index: int
    time: float
    kind: str  # "bounce", "hit" or "gap"
    position: np.ndarray
    velocity_jump: float  # m/s (NaN for a gap)


@dataclass
class Rally:
    """A trajectory cut into free flights: ``flights`` are (start, stop) index ranges."""

    flights: list
    contacts: list
    jumps: np.ndarray = field(repr=False, default=None)


def _up(gravity) -> np.ndarray:
    g = as_array(gravity, (3,), "gravity")
    n = np.linalg.norm(g)
    if not n > 0:
        raise ValueError(f"gravity must be non-zero to know which way is up, got {g}")
    return -g / n


def _line_slopes(t, q, idx, lo, hi):
    # slope of the least-squares line through samples idx+lo .. idx+hi (inclusive) per idx
    off = np.arange(lo, hi + 1)
    tt = t[idx[:, None] + off]
    qq = q[idx[:, None] + off]
    tc = tt - tt.mean(axis=1, keepdims=True)
    qc = qq - qq.mean(axis=1, keepdims=True)
    return np.einsum("nk,nkd->nd", tc, qc) / np.sum(tc * tc, axis=1)[:, None]


def cut_flights(times, positions, gravity=(0.0, 0.0, -9.80665), *, jump: float = 2.0, window: int = 3,
                max_gap: float = 4.0, min_points: int = 10, plane=None, plane_tolerance: float = 0.05) -> Rally:
    """Cut a rally into free flights at bounces, hits and gaps (module docstring).

    Parameters
    ----------
    times : array_like, shape (N,)
        Increasing times, s.
    positions : array_like, shape (N, 3)
        m, in the frame of ``gravity``.
    gravity : array_like, shape (3,)
        m/s^2; also says which way is up.
    jump : float
        Velocity change (m/s) that marks a contact.
    window : int
        Samples on each side of the straight-line velocity estimates.
    max_gap : float
        A time gap longer than this many median sample intervals cuts too.
    min_points : int
        Shorter flights are dropped.
    plane : (point, normal), optional
        The surface balls bounce on (a table); default: the horizontal plane through the lowest
        contact.
    plane_tolerance : float
        m: a contact this close to the plane (or to the lowest contact) is a bounce candidate.

    Returns
    -------
    Rally
    """
    t = as_array(times, (None,), "times")
    p = as_array(positions, (len(t), 3), "positions")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
        raise ValueError("times and positions must be finite (drop unobserved rows first)")
    if len(t) > 1 and np.any(np.diff(t) <= 0):
        raise ValueError("times must increase")
    if window < 2 or jump <= 0:
        raise ValueError(f"need window >= 2 and jump > 0, got {window}, {jump}")
    g = as_array(gravity, (3,), "gravity")
    up = _up(g)
    n = len(t)
    jumps = np.zeros(n)
    contacts: list[Contact] = []
    cut = np.zeros(n, bool)  # samples dropped (contacts)
    starts = [0]  # segment starts (gap cuts)
    if n > 1:
        dts = np.diff(t)
        med = float(np.median(dts))
        for i in np.flatnonzero(dts > max_gap * med):
            starts.append(int(i) + 1)
            contacts.append(Contact(int(i) + 1, float(t[i + 1]), "gap", p[i + 1].copy(), float("nan")))
    bounds = list(zip(starts, starts[1:] + [n]))
    q = p - 0.5 * g[None, :] * ((t - t[0]) ** 2)[:, None]
    vel_lr = {}
    for a, b in bounds:
        if b - a < 2 * window + 1:
            continue
        idx = np.arange(a + window, b - window)
        vl = _line_slopes(t, q, idx, -window, 0)
        vr = _line_slopes(t, q, idx, 0, window)
        jumps[idx] = np.linalg.norm(vr - vl, axis=1)
        for k, i in enumerate(idx):  # back to velocities (q's slopes lack g (t - t[0]))
            back = g * (t[i] - t[0])
            vel_lr[int(i)] = (vl[k] + back, vr[k] + back)
    above = jumps > jump
    i = 0
    found = []
    while i < n:
        if above[i]:
            j = i
            while j + 1 < n and above[j + 1]:
                j += 1
            c = i + int(np.argmax(jumps[i:j + 1]))
            found.append(c)
            i = j + 1
        else:
            i += 1
    if plane is not None:
        q0 = as_array(plane[0], (3,), "plane point")
        nrm = as_array(plane[1], (3,), "plane normal")
        nrm = nrm / np.linalg.norm(nrm)
    else:
        # the lowest contact whose velocity turns upward: the surface balls bounce on
        ups = [c for c in found if vel_lr[c][0] @ up < 0 < vel_lr[c][1] @ up]
        q0 = p[min(ups, key=lambda c: p[c] @ up)] if ups else None
        nrm = up
    for c in found:
        vl, vr = vel_lr[c]
        near = q0 is not None and abs((p[c] - q0) @ nrm) <= plane_tolerance
        kind = "bounce" if (near and vl @ up < 0 < vr @ up) else "hit"
        contacts.append(Contact(c, float(t[c]), kind, p[c].copy(), float(jumps[c])))
        cut[c] = True
    contacts.sort(key=lambda c: c.index)
    flights = []
    for a, b in bounds:
        edges = [a] + [c + 1 for c in found if a <= c < b] + [b]
        ends = [c for c in found if a <= c < b] + [b]
        for s, e in zip(edges, ends):
            if e - s >= min_points:
                flights.append((s, e))
    return Rally(flights, contacts, jumps)


# -- fitting -------------------------------------------------------------------------------------
@dataclass
class FlightFit:
    """A fitted free flight (SI units, world frame)."""

    times: np.ndarray
    positions: np.ndarray  # the measured positions
    model_positions: np.ndarray
    residuals: np.ndarray  # model - measured, (N, 3)
    p0: np.ndarray
    v0: np.ndarray
    spin: np.ndarray  # rad/s, transverse to v0
    spin_sigma: float  # rad/s, 1-sigma of the spin rate
    cd_scale: float
    cd_scale_sigma: float
    cl_scale: float
    cl_scale_sigma: float
    cd: float  # effective drag coefficient (mean over the flight)
    cd_sigma: float
    cl: float  # lift coefficient at the first sample
    cl_sigma: float
    rms: float  # m, 3D
    cross_rms: float  # m, across the flight direction
    along_rms: float  # m, along it
    speed: float  # m/s at the first sample
    covariance: np.ndarray
    param_names: tuple
    success: bool
    message: str
    nfev: int
    cd_in_range: bool
    cl_in_range: bool

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    @property
    def spin_rpm(self) -> float:
        return float(np.linalg.norm(self.spin) * RPM_PER_RAD_S)

    def summary(self) -> dict:
        """JSON-ready numbers (mm, rpm, m/s)."""
        return {
            "t_start": float(self.times[0]), "duration_s": self.duration, "points": int(len(self.times)),
            "speed_m_s": self.speed, "spin_rpm": self.spin_rpm, "spin_rpm_sigma": self.spin_sigma * RPM_PER_RAD_S,
            "spin_axis": [float(x) for x in (self.spin / max(np.linalg.norm(self.spin), 1e-300))],
            "rms_mm": self.rms * 1e3, "cross_track_rms_mm": self.cross_rms * 1e3,
            "along_track_rms_mm": self.along_rms * 1e3,
            "cd": self.cd, "cd_sigma": self.cd_sigma, "cl": self.cl, "cl_sigma": self.cl_sigma,
            "cd_scale": self.cd_scale, "cd_scale_sigma": self.cd_scale_sigma,
            "cl_scale": self.cl_scale, "cl_scale_sigma": self.cl_scale_sigma,
            "cd_in_published_range": self.cd_in_range, "cl_in_published_range": self.cl_in_range,
            "success": self.success,
        }


def _integrate(model, t, p0, v0, w, cd, cl, max_step):
    """Fixed-step RK4 of M flights (p0, v0, w: (M, 3); cd, cl: (M,)) from t[0] through the
    sample times t (N,): positions and velocities (M, N, 3)."""
    m, n = len(p0), len(t)
    pos = np.empty((m, n, 3))
    vel = np.empty((m, n, 3))
    p, v = p0.copy(), v0.copy()
    pos[:, 0], vel[:, 0] = p, v

    def acc(vv):
        return model.acceleration_scaled(vv, w, cd, cl)
    for i in range(1, n):
        span = t[i] - t[i - 1]
        k = max(1, int(math.ceil(span / max_step - 1e-9)))
        h = span / k
        for _ in range(k):
            a1 = acc(v)
            v2 = v + 0.5 * h * a1
            a2 = acc(v2)
            v3 = v + 0.5 * h * a2
            a3 = acc(v3)
            v4 = v + h * a3
            a4 = acc(v4)
            p = p + h * (v + h / 6.0 * (a1 + a2 + a3))
            v = v + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        pos[:, i], vel[:, i] = p, v
    return pos, vel


def _start(t, p, model):
    # position and velocity at t[0] from a quadratic; a transverse spin whose Magnus force
    # matches the curvature left after gravity and drag (small-spin slope of the lift model)
    tc = t - t[0]
    coef, *_ = np.linalg.lstsq(np.vander(tc, 3), p, rcond=None)
    p0, v0, a = coef[2], coef[1], 2.0 * coef[0]
    speed = float(np.linalg.norm(v0))
    e = v0 / max(speed, 1e-12)
    a_free = model.acceleration_scaled(v0, np.zeros(3), model.cd_scale, model.cl_scale)
    a_t = a - a_free
    a_t = a_t - e * (a_t @ e)
    slope = model.k * model.cl_scale * model.cl2 / model.cl0 * model.radius * speed  # |a_M| per rad/s
    w = np.cross(v0, a_t)
    nw = np.linalg.norm(w)
    w = w / nw * min(np.linalg.norm(a_t) / max(slope, 1e-12), 2000.0) if nw > 0 else np.zeros(3)
    return p0, v0, w


def fit_flight(times, positions, model, *, fit_coefficients: bool = False, spin=None,
               max_step: float = 0.006, max_nfev: int = 200) -> FlightFit:
    """Fit one free flight (module docstring).

    Parameters
    ----------
    times : array_like, shape (N,)
        Increasing, s.
    positions : array_like, shape (N, 3)
        m, in the frame of ``model.gravity``.
    model : BallModel
        :func:`stillcap.ball.physics.ball_model` preset (its ``cd_scale``, ``cl_scale`` start the
        fit and stay fixed without ``fit_coefficients``).
    fit_coefficients : bool
        Fit the drag scale; with ``spin`` given, the lift scale too.
    spin : array_like, shape (3,), optional
        Known spin, rad/s: held fixed instead of fitted.
    max_step : float
        Largest RK4 step, s.

    Returns
    -------
    FlightFit
    """
    t = as_array(times, (None,), "times")
    p = as_array(positions, (len(t), 3), "positions")
    if len(t) < 6:
        raise ValueError(f"a flight needs at least 6 positions to fit, got {len(t)}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))) or np.any(np.diff(t) <= 0):
        raise ValueError("flight times must increase and positions be finite")
    if not hasattr(model, "acceleration_scaled"):
        raise ValueError(f"fit_flight needs a BallModel (ball_model(name)), got {type(model).__name__}")
    p0, v0, w0 = _start(t, p, model)
    basis = spin_basis(v0, model.up)
    names = ["px", "py", "pz", "vx", "vy", "vz"]
    x0 = list(p0) + list(v0)
    scale = [0.01] * 3 + [0.1] * 3
    spin_fixed = spin is not None
    if spin_fixed:
        w_fixed = as_array(spin, (3,), "spin")
    else:
        names += ["spin_t1", "spin_t2"]
        x0 += list(basis[:, 1:].T @ w0)
        scale += [20.0, 20.0]
    fit_cd = bool(fit_coefficients)
    fit_cl = bool(fit_coefficients) and spin_fixed
    if fit_cd:
        names.append("cd_scale")
        x0.append(model.cd_scale)
        scale.append(0.05)
    if fit_cl:
        names.append("cl_scale")
        x0.append(model.cl_scale)
        scale.append(0.05)
    x0 = np.array(x0, float)
    scale = np.array(scale, float)
    col = {nm: i for i, nm in enumerate(names)}
    nfev = [0]

    def unpack(X):
        X = np.atleast_2d(X)
        w = (np.broadcast_to(w_fixed, (len(X), 3)) if spin_fixed
             else X[:, [col["spin_t1"], col["spin_t2"]]] @ basis[:, 1:].T)
        cd = X[:, col["cd_scale"]] if fit_cd else np.full(len(X), model.cd_scale)
        cl = X[:, col["cl_scale"]] if fit_cl else np.full(len(X), model.cl_scale)
        return X[:, :3], X[:, 3:6], np.ascontiguousarray(w), cd, cl

    def sim(X):
        nfev[0] += len(np.atleast_2d(X))
        return _integrate(model, t, *unpack(X), max_step)

    def fun(x):
        return (sim(x)[0][0] - p).ravel()

    steps = 1e-4 * scale

    def jac(x):
        k = len(x)
        X = np.repeat(x[None], 2 * k, axis=0)
        X[2 * np.arange(k), np.arange(k)] += steps
        X[2 * np.arange(k) + 1, np.arange(k)] -= steps
        pos = sim(X)[0].reshape(2 * k, -1)
        return ((pos[0::2] - pos[1::2]) / (2.0 * steps[:, None])).T

    res = least_squares(fun, x0, jac=jac, method="lm", x_scale=scale, xtol=1e-10, ftol=1e-10,
                        max_nfev=max_nfev)
    x = res.x
    pos, vel = sim(x)
    pos, vel = pos[0], vel[0]
    r = pos - p
    J = jac(x)
    dof = max(r.size - len(x), 1)
    s2 = float(np.sum(r * r)) / dof
    JTJ = J.T @ J
    Ds = scale[:, None] * scale[None, :]
    cov = np.linalg.pinv(JTJ * Ds) * Ds * s2
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    pf, vf, w, cdv, clv = (a[0] for a in unpack(x))
    u = vel / np.linalg.norm(vel, axis=1, keepdims=True)
    along = np.sum(r * u, axis=1)
    cross = r - along[:, None] * u
    speeds = np.linalg.norm(vel, axis=1)
    fitted = model.with_scales(float(cdv), float(clv))
    w_perp = np.linalg.norm(np.cross(w, vf)) / np.linalg.norm(vf)
    cd_eff = float(np.mean(fitted.drag_coefficient(speeds, np.linalg.norm(np.cross(w, vel), axis=1) / speeds)))
    cd_sigma = cd_eff / cdv * sig[col["cd_scale"]] if fit_cd else 0.0
    cl_eff = float(fitted.lift_coefficient(speeds[0], w_perp))
    # sigma of C_L: through the spin rate (fitted spin) or the lift scale (fixed spin)
    if spin_fixed:
        spin_sigma = 0.0
        cl_sigma = cl_eff / clv * sig[col["cl_scale"]] if fit_cl else 0.0
    else:
        ic = [col["spin_t1"], col["spin_t2"]]
        s12 = x[ic]
        ns = float(np.linalg.norm(s12))
        grad = s12 / ns if ns > 0 else np.zeros(2)
        spin_sigma = float(np.sqrt(max(grad @ cov[np.ix_(ic, ic)] @ grad, 0.0)))
        h = max(1e-3 * w_perp, 1e-6)
        dcl = (fitted.lift_coefficient(speeds[0], w_perp + h) - fitted.lift_coefficient(speeds[0], max(w_perp - h, 0.0))) \
            / (w_perp + h - max(w_perp - h, 0.0))
        cl_sigma = float(abs(dcl) * spin_sigma)
    lo, hi = model.cd_range
    clo, chi = model.cl_range
    return FlightFit(
        times=t, positions=p, model_positions=pos, residuals=r, p0=pf, v0=vf, spin=w, spin_sigma=spin_sigma,
        cd_scale=float(cdv), cd_scale_sigma=float(sig[col["cd_scale"]]) if fit_cd else 0.0,
        cl_scale=float(clv), cl_scale_sigma=float(sig[col["cl_scale"]]) if fit_cl else 0.0,
        cd=cd_eff, cd_sigma=float(cd_sigma), cl=cl_eff, cl_sigma=float(cl_sigma),
        rms=float(np.sqrt(np.mean(np.sum(r * r, axis=1)))),
        cross_rms=float(np.sqrt(np.mean(np.sum(cross * cross, axis=1)))),
        along_rms=float(np.sqrt(np.mean(along ** 2))), speed=float(np.linalg.norm(vf)),
        covariance=cov, param_names=tuple(names), success=bool(res.success), message=str(res.message),
        nfev=nfev[0], cd_in_range=bool(lo <= cd_eff <= hi), cl_in_range=bool(clo <= cl_eff <= chi))


def fit_rally(times, positions, model, *, fit_coefficients: bool = False, **cut_options):
    """:func:`cut_flights` then :func:`fit_flight` on each flight: (Rally, [FlightFit])."""
    rally = cut_flights(times, positions, model.gravity, **cut_options)
    t = np.asarray(times, float)
    p = np.asarray(positions, float)
    fits = [fit_flight(t[a:b], p[a:b], model, fit_coefficients=fit_coefficients) for a, b in rally.flights]
    return rally, fits
