"""Baseball pitch metrics in the field frame (SPEC J1 "Baseball conventions").

Field frame (PITCHf/x, Statcast): origin at the back tip of home plate, **y toward the pitcher**,
**z up**, **x to the catcher's right** (right-handed). The front edge of the plate is at
``y = 17/12 ft``, the front of the pitching rubber at ``y = 60.5 ft``. Arrays going in are SI
(metres, seconds, rad/s) in that frame; results name their unit (``_ft``, ``_in``, ``_mph``,
``_rpm``, ``_deg``) and follow PITCHf/x / Statcast definitions:

- 9-parameter fit: constant-acceleration model ``r(t) = r0 + v0 t + a t^2 / 2`` with ``t = 0`` at
  ``y = 50 ft`` (feet, seconds), :class:`NineParameterFit`.
- plate location ``plate_x_ft, plate_z_ft`` (PITCHf/x ``px, pz``, Statcast ``plate_x, plate_z``):
  the 9-parameter model at ``y = 17/12 ft``.
- Statcast movement ``pfx_x_in, pfx_z_in``: the movement caused by spin alone from release to
  the front of the plate (9-parameter acceleration without gravity and without its component
  along the release velocity, over the release-to-plate time), in inches; induced vertical break
  and horizontal break (Statcast, TrackMan) are these numbers.
- PITCHf/x movement ``pitchfx_pfx_x_in, pitchfx_pfx_z_in``: ``a_x T^2 / 2``,
  ``(a_z + 32.174) T^2 / 2`` with ``T`` the time from ``y = 40 ft`` to 17/12 ft, and its axis
  ``pitchfx_spin_dir_deg``.
- spin axis (Statcast convention, degrees): ``spin_axis_deg`` observed from the spin vector (the
  Magnus direction ``w x v`` seen from the catcher, counter-clockwise from +x, plus 90 deg),
  ``spin_axis_from_movement_deg`` inferred from the Statcast movement (Statcast's
  ``spin_axis``); 180 = pure backspin, 0 = pure topspin; as a clock tilt 180 deg = "12:00" and
  every 30 deg is one hour (210 deg = "1:00"). ``spin_direction_clock`` is the observed axis
  to the minute, as Rapsodo shows its spin direction.
- spin efficiency: ``|w_perp| / |w|``, the share of the spin transverse to the release velocity
  (only it moves the ball); ``active_spin_rpm = efficiency * spin_rate_rpm``,
  ``gyro_angle_deg = acos(efficiency)``.
- Rapsodo VB/HB (spin): ``rapsodo_vb_in = pfx_z_in``, ``rapsodo_hb_in = -pfx_x_in`` (Rapsodo
  gives the horizontal break from the pitcher's view).
- approach angles at the front of the plate, release extension, time to plate.

``docs/pitch-metrics.md`` documents every field and JSON key.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.nine_parameter import (
    FPS_PER_MPH,
    FT,
    MPH,
    NINE_NAMES,
    PLATE_FRONT_Y_FT,
    RPM_PER_RAD_S,
    RUBBER_Y_FT,
    Y0_FT,
    Y_MOVEMENT_START_FT,
    _nine,
    approach_angles_deg,
    movement_axis_deg,
    movement_in,
    nine_position_ft,
    nine_velocity_fps,
    parse_clock_deg,
    plate_location_ft,
    spin_axis_from_movement_deg,
    statcast_movement_in,
    time_at_y,
)


@dataclass(frozen=True)
class NineParameterFit:
    """PITCHf/x 9-parameter constant-acceleration model of one pitch (feet, seconds).

    ``r(t) = (x0, y0, z0) + (vx0, vy0, vz0) t + (ax, ay, az) t^2 / 2`` with ``t = 0`` where
    ``y = y0`` (50 ft by convention).

    Attributes
    ----------
    x0, y0, z0 : float
        ft.
    vx0, vy0, vz0 : float
        ft/s.
    ax, ay, az : float
        ft/s^2.
    t_ref : float
        The caller's time (s) at which ``t = 0`` (for fits to timed data; 0 otherwise).
    rms_residual_ft : float
        RMS distance of the fitted points from the model, ft (NaN if not from a fit).
    n_points : int
        Points used by the fit.
    success : bool
    """

    x0: float
    y0: float
    z0: float
    vx0: float
    vy0: float
    vz0: float
    ax: float
    ay: float
    az: float
    t_ref: float = 0.0
    rms_residual_ft: float = float("nan")
    n_points: int = 0
    success: bool = True

    @classmethod
    def from_array(cls, a, **kwargs) -> "NineParameterFit":
        """From ``(x0, y0, z0, vx0, vy0, vz0, ax, ay, az)``, shape (9,)."""
        a = as_array(a, (9,), "nine")
        return cls(*map(float, a), **kwargs)

    @classmethod
    def from_record(cls, rec) -> "NineParameterFit":
        """From a mapping with PITCHf/x keys ``x0 ... az`` (e.g. a ``csv.DictReader`` row)."""
        return cls(*(float(rec[k]) for k in NINE_NAMES))

    def as_array(self) -> np.ndarray:
        """``(x0, y0, z0, vx0, vy0, vz0, ax, ay, az)``, shape (9,)."""
        return np.array([getattr(self, k) for k in NINE_NAMES])

    def to_dict(self) -> dict:
        return _jsonable(asdict(self))

    def position_ft(self, t):
        """Position (ft) at model time ``t`` (s): shape (3,) or (N, 3)."""
        return nine_position_ft(self.as_array(), t)

    def velocity_fps(self, t):
        """Velocity (ft/s) at model time ``t`` (s)."""
        return nine_velocity_fps(self.as_array(), t)

    def time_at_y(self, y_ft):
        """Model time (s) at which ``y = y_ft``."""
        return time_at_y(self.as_array(), y_ft)

    def plate_location_ft(self) -> tuple[float, float]:
        """``(px, pz)`` at the front of the plate, ft."""
        px, pz = plate_location_ft(self.as_array())
        return float(px), float(pz)

    def movement_in(self, y_start_ft: float = Y_MOVEMENT_START_FT) -> tuple[float, float]:
        """``(pfx_x, pfx_z)``, inches."""
        mx, mz = movement_in(self.as_array(), y_start_ft)
        return float(mx), float(mz)

    @property
    def start_speed_mph(self) -> float:
        """Speed at ``y = y0`` (PITCHf/x ``start_speed``), mph."""
        return float(np.linalg.norm([self.vx0, self.vy0, self.vz0]) / FPS_PER_MPH)


def fit_nine_parameter(times, positions, *, y0_ft: float = Y0_FT) -> NineParameterFit:
    """Least-squares 9-parameter (constant-acceleration) fit to a measured or simulated pitch.

    Parameters
    ----------
    times : array_like, shape (N,)
        s.
    positions : array_like, shape (N, 3)
        Field frame, metres; rows with NaN are skipped (per coordinate).
    y0_ft : float
        Reference plane: the result is expressed at the time the fit reaches ``y = y0_ft``
        (extrapolated when the points do not reach it).

    Returns
    -------
    NineParameterFit
        ``success`` is False (parameters NaN) with fewer than 3 usable points per coordinate or
        when the fitted ``y(t)`` never reaches ``y0_ft``.
    """
    times = as_array(times, (None,), "times")
    pos = as_array(positions, (len(times), 3), "positions") / FT
    coef = np.full((3, 3), np.nan)  # per axis: c0 + c1 t + c2 t^2
    tc = np.nanmean(times) if len(times) else 0.0  # centre times for conditioning
    res2, n_used = 0.0, 0
    for axis in range(3):
        ok = np.isfinite(pos[:, axis]) & np.isfinite(times)
        if ok.sum() < 3 or np.ptp(times[ok]) <= 0:
            continue
        dt = times[ok] - tc
        A = np.stack([np.ones_like(dt), dt, dt * dt], axis=1)
        c, *_ = np.linalg.lstsq(A, pos[ok, axis], rcond=None)
        coef[axis] = c
        res2 += float(np.sum((A @ c - pos[ok, axis]) ** 2))
        n_used = max(n_used, int(ok.sum()))
    nan9 = dict(zip(NINE_NAMES, [float("nan")] * 9))
    if not np.all(np.isfinite(coef)):
        return NineParameterFit(**nan9, t_ref=float("nan"), n_points=n_used, success=False)
    # time (relative to tc) where y = y0_ft, the root nearest the data
    c0, c1, c2 = coef[1]
    roots = np.roots([c2, c1, c0 - y0_ft]) if c2 != 0 else np.array([(y0_ft - c0) / c1])
    roots = roots[np.isreal(roots)].real
    if not len(roots):
        return NineParameterFit(**nan9, t_ref=float("nan"), n_points=n_used, success=False)
    ts = roots[np.argmin(np.abs(roots))]
    p = coef[:, 0] + coef[:, 1] * ts + coef[:, 2] * ts * ts
    v = coef[:, 1] + 2.0 * coef[:, 2] * ts
    a = 2.0 * coef[:, 2]
    n_pts = int(np.sum(np.all(np.isfinite(pos), axis=1)))
    rms = math.sqrt(res2 / max(n_pts, 1))
    return NineParameterFit(*map(float, np.concatenate([p, v, a])), t_ref=float(tc + ts),
                            rms_residual_ft=rms, n_points=n_pts, success=True)


# --------------------------------------------------------------------------------------------
# Spin
# --------------------------------------------------------------------------------------------
def spin_rate_rpm(spin) -> float:
    """``|w| * 60 / (2 pi)`` for a spin vector in rad/s, shape (3,)."""
    return float(np.linalg.norm(as_array(spin, (3,), "spin")) * RPM_PER_RAD_S)


def _unit(v, name):
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError(f"{name} must be non-zero, got {v}")
    return v / n


def spin_efficiency(spin, velocity) -> float:
    """Share of the spin transverse to ``velocity``: ``|w x v_hat| / |w|`` (0..1; NaN if no spin).

    Parameters
    ----------
    spin : array_like, shape (3,)
        rad/s.
    velocity : array_like, shape (3,)
        m/s (any unit; only its direction is used).
    """
    w = as_array(spin, (3,), "spin")
    vh = _unit(as_array(velocity, (3,), "velocity"), "velocity")
    nw = np.linalg.norm(w)
    if nw == 0:
        return float("nan")
    return float(min(np.linalg.norm(np.cross(w, vh)) / nw, 1.0))


def spin_axis_deg(spin, velocity) -> float:
    """Statcast spin axis (deg, 0..360) from the spin vector and the velocity (field frame).

    The Magnus direction ``w x v`` seen from the catcher (its x and z components), measured
    counter-clockwise from +x, plus 90 deg: 180 = backspin, 0 = topspin, 90 = movement toward
    +x (first-base side), 270 = toward -x. NaN for pure gyro spin or no spin.

    Parameters
    ----------
    spin : array_like, shape (3,)
        rad/s.
    velocity : array_like, shape (3,)
    """
    w = as_array(spin, (3,), "spin")
    vh = _unit(as_array(velocity, (3,), "velocity"), "velocity")
    m = np.cross(w, vh)
    if math.hypot(m[0], m[2]) <= 1e-12 * max(np.linalg.norm(w), 1e-300):
        return float("nan")
    return float(np.mod(np.degrees(np.arctan2(m[2], m[0])) + 90.0, 360.0))


def clock_tilt(axis_deg: float, resolution_min: int = 15) -> str:
    """Spin axis as a clock tilt: 180 deg -> "12:00", 210 -> "1:00", 0 -> "6:00".

    ``hours = (axis - 180) / 30`` on a 12-hour face, rounded to ``resolution_min`` minutes
    (Statcast shows 15-minute steps). Empty string for NaN.
    """
    if not np.isfinite(axis_deg):
        return ""
    if resolution_min <= 0:
        raise ValueError(f"resolution_min must be positive, got {resolution_min}")
    minutes = ((float(axis_deg) - 180.0) / 30.0) * 60.0
    minutes = int(round(minutes / resolution_min) * resolution_min) % 720
    h, mm = divmod(minutes, 60)
    return f"{12 if h == 0 else h}:{mm:02d}"


def spin_vector(spin_rpm: float, axis_deg: float, velocity, efficiency: float = 1.0,
                gyro_sign: float = 1.0) -> np.ndarray:
    """The spin vector (rad/s) with a given rate, Statcast axis and efficiency at ``velocity``.

    Inverse of :func:`spin_rate_rpm`, :func:`spin_axis_deg` and :func:`spin_efficiency`: the
    transverse part moves the ball in direction ``axis_deg - 90`` (catcher's view), the rest is
    gyro spin along ``gyro_sign * velocity``.

    Parameters
    ----------
    spin_rpm : float
    axis_deg : float
        Statcast spin axis (180 = backspin).
    velocity : array_like, shape (3,)
        Field frame; must have a y component (a pitch).
    efficiency : float
        0..1.
    gyro_sign : float
        +1: gyro spin along the velocity (right-hand rule), -1: against it.

    Returns
    -------
    ndarray, shape (3,)
    """
    vh = _unit(as_array(velocity, (3,), "velocity"), "velocity")
    if not 0.0 <= efficiency <= 1.0:
        raise ValueError(f"efficiency must be in [0, 1], got {efficiency}")
    if abs(vh[1]) < 1e-9:
        raise ValueError(f"velocity needs a y component (toward the plate), got {velocity}")
    phi = math.radians(axis_deg - 90.0)
    # movement direction perpendicular to v whose catcher-view (x, z) part points along phi
    mx, mz = math.cos(phi), math.sin(phi)
    m = np.array([mx, -(mx * vh[0] + mz * vh[2]) / vh[1], mz])
    w_perp = _unit(np.cross(vh, m), "movement")  # (v x m) x v = m for m perpendicular to v
    rate = spin_rpm / RPM_PER_RAD_S
    gyro = math.sqrt(max(0.0, 1.0 - efficiency ** 2))
    return rate * (efficiency * w_perp + math.copysign(gyro, gyro_sign) * vh)


# --------------------------------------------------------------------------------------------
# All metrics of one pitch
# --------------------------------------------------------------------------------------------
def _jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out[k] = _jsonable(v)
        elif isinstance(v, (bool, np.bool_)):
            out[k] = bool(v)
        elif isinstance(v, (int, np.integer)):
            out[k] = int(v)
        elif isinstance(v, (float, np.floating)):
            out[k] = float(v) if np.isfinite(v) else None  # JSON has no NaN
        else:
            out[k] = v
    return out


_NAN = float("nan")


@dataclass
class PitchMetrics:
    """Standard metrics of one pitch; field names are the JSON keys (:meth:`to_dict`).

    Each field names its unit and, where definitions differ between systems, whose definition
    it follows (``docs/pitch-metrics.md`` gives the source of each).

    Attributes
    ----------
    release_speed_mph : float
        Speed at release.
    release_pos_x_ft, release_pos_y_ft, release_pos_z_ft : float
        Release point, field frame.
    release_extension_ft : float
        ``60.5 ft - release_pos_y_ft`` (distance in front of the rubber; Statcast
        ``release_extension``).
    start_speed_mph : float
        Speed at ``y = 50 ft`` (PITCHf/x ``start_speed``, 9-parameter model).
    spin_rate_rpm, active_spin_rpm : float
        Total spin rate and its transverse part.
    spin_efficiency : float
        0..1.
    gyro_angle_deg : float
        Angle between the spin axis and the velocity's normal plane, ``acos(efficiency)``.
    spin_axis_deg : float
        Statcast-convention spin axis observed from the spin vector (180 = backspin).
    spin_tilt : str
        ``spin_axis_deg`` as a clock to 15 minutes ("12:00" = backspin).
    spin_direction_clock : str
        ``spin_axis_deg`` as a clock to the minute (Rapsodo's "spin direction").
    spin_axis_from_movement_deg : float
        Spin axis inferred from the Statcast movement (Statcast ``spin_axis``).
    pfx_x_in, pfx_z_in : float
        Statcast movement: spin alone, release to the front of the plate, inches (catcher's view).
    induced_vertical_break_in, horizontal_break_in : float
        Statcast / TrackMan induced vertical break and horizontal break: ``pfx_z_in``, ``pfx_x_in``.
    rapsodo_vb_in, rapsodo_hb_in : float
        Rapsodo VB and HB (spin): ``pfx_z_in`` and ``-pfx_x_in`` (pitcher's view).
    pitchfx_pfx_x_in, pitchfx_pfx_z_in : float
        PITCHf/x movement over the last 40 ft, inches.
    pitchfx_spin_dir_deg : float
        Axis from the PITCHf/x movement (PITCHf/x ``spin_dir``).
    vertical_approach_angle_deg, horizontal_approach_angle_deg : float
        At the front of the plate (negative VAA = descending; positive HAA = toward +x).
    plate_x_ft, plate_z_ft : float
        PITCHf/x ``px, pz`` (Statcast ``plate_x, plate_z``) at the front of the plate.
    plate_time_s : float
        Flight time from release to the front of the plate.
    nine_parameter : NineParameterFit or None
    success : bool
    message : str
    """

    release_speed_mph: float = _NAN
    release_pos_x_ft: float = _NAN
    release_pos_y_ft: float = _NAN
    release_pos_z_ft: float = _NAN
    release_extension_ft: float = _NAN
    start_speed_mph: float = _NAN
    spin_rate_rpm: float = _NAN
    active_spin_rpm: float = _NAN
    spin_efficiency: float = _NAN
    gyro_angle_deg: float = _NAN
    spin_axis_deg: float = _NAN
    spin_tilt: str = ""
    spin_direction_clock: str = ""
    spin_axis_from_movement_deg: float = _NAN
    pfx_x_in: float = _NAN
    pfx_z_in: float = _NAN
    induced_vertical_break_in: float = _NAN
    horizontal_break_in: float = _NAN
    rapsodo_vb_in: float = _NAN
    rapsodo_hb_in: float = _NAN
    pitchfx_pfx_x_in: float = _NAN
    pitchfx_pfx_z_in: float = _NAN
    pitchfx_spin_dir_deg: float = _NAN
    vertical_approach_angle_deg: float = _NAN
    horizontal_approach_angle_deg: float = _NAN
    plate_x_ft: float = _NAN
    plate_z_ft: float = _NAN
    plate_time_s: float = _NAN
    nine_parameter: NineParameterFit | None = field(default=None, repr=False)
    success: bool = True
    message: str = ""

    def to_dict(self) -> dict:
        """Plain dict for JSON: field names as keys, NaN as None, ``nine_parameter`` nested."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "nine_parameter"}
        d = _jsonable(d)
        d["nine_parameter"] = self.nine_parameter.to_dict() if self.nine_parameter else None
        return d

    @classmethod
    def from_nine_parameter(cls, nine: NineParameterFit, release_y_ft: float | None = None) -> "PitchMetrics":
        """The metrics a 9-parameter model alone gives (plate location, movements, approach
        angles, start speed; with ``release_y_ft`` the release-based ones as well: Statcast
        movement and its axis, release speed and point, extension, time to plate)."""
        vals = nine_parameter_metrics(nine.as_array(), release_y_ft)
        out = cls(nine_parameter=nine, success=nine.success,
                  **{k: float(v) for k, v in vals.items()})
        return out


def nine_parameter_metrics(nine, release_y_ft=None) -> dict:
    """The metrics that follow from 9-parameter models alone, vectorised.

    Parameters
    ----------
    nine : array_like, shape (..., 9)
    release_y_ft : float or array_like, shape (...), optional
        Where the pitch was released; without it the release-based metrics are NaN.

    Returns
    -------
    dict
        ``{field name of PitchMetrics: ndarray (...)}``.
    """
    n = _nine(nine)
    px, pz = plate_location_ft(n)
    mx, mz = movement_in(n)
    vaa, haa = approach_angles_deg(n)
    out = {"start_speed_mph": np.linalg.norm(n[..., 3:6], axis=-1) / FPS_PER_MPH,
           "pitchfx_pfx_x_in": mx, "pitchfx_pfx_z_in": mz, "pitchfx_spin_dir_deg": movement_axis_deg(mx, mz),
           "vertical_approach_angle_deg": vaa, "horizontal_approach_angle_deg": haa,
           "plate_x_ft": px, "plate_z_ft": pz}
    if release_y_ft is not None:
        ry = np.broadcast_to(np.asarray(release_y_ft, float), px.shape)
        sx, sz = statcast_movement_in(n, ry)
        t_rel = time_at_y(n, ry)
        p_rel = nine_position_ft(n, t_rel)
        out.update(release_speed_mph=np.linalg.norm(nine_velocity_fps(n, t_rel), axis=-1) / FPS_PER_MPH,
                   release_pos_x_ft=p_rel[..., 0], release_pos_y_ft=ry + 0.0, release_pos_z_ft=p_rel[..., 2],
                   release_extension_ft=RUBBER_Y_FT - ry,
                   plate_time_s=time_at_y(n, PLATE_FRONT_Y_FT) - t_rel)
        out.update(_statcast_movement_fields(sx, sz))
    else:
        nan = np.full(px.shape, np.nan)
        for k in ("release_speed_mph", "release_pos_x_ft", "release_pos_y_ft", "release_pos_z_ft",
                  "release_extension_ft", "plate_time_s"):
            out[k] = nan
        out.update(_statcast_movement_fields(nan, nan))
    return out


def _statcast_movement_fields(sx, sz) -> dict:
    return {"spin_axis_from_movement_deg": spin_axis_from_movement_deg(sx, sz), "pfx_x_in": sx, "pfx_z_in": sz,
            "induced_vertical_break_in": sz, "horizontal_break_in": sx, "rapsodo_vb_in": sz, "rapsodo_hb_in": -sx}


def pitch_metrics(times, positions, spin=None, *, velocities=None, release_time=None,
                  y0_ft: float = Y0_FT) -> PitchMetrics:
    """All pitch metrics from a measured or simulated flight in the field frame.

    Parameters
    ----------
    times : array_like, shape (N,)
        s.
    positions : array_like, shape (N, 3)
        Field frame, metres (NaN rows = not observed).
    spin : array_like, shape (3,), optional
        Spin vector at release, rad/s, field frame. Without it the spin fields are NaN.
    velocities : array_like, shape (N, 3), optional
        m/s; gives the release velocity exactly (otherwise it comes from the 9-parameter fit).
    release_time : float, optional
        Release instant (s). Default: the first observed sample, whose position is the release
        point; a given time evaluates the 9-parameter model there.
    y0_ft : float
        Reference plane of the 9-parameter fit.

    Returns
    -------
    PitchMetrics
    """
    times = as_array(times, (None,), "times")
    positions = as_array(positions, (len(times), 3), "positions")
    if velocities is not None:
        velocities = as_array(velocities, (len(times), 3), "velocities")
    nine = fit_nine_parameter(times, positions, y0_ft=y0_ft)
    out = PitchMetrics.from_nine_parameter(nine)
    if not nine.success:
        out.success, out.message = False, "9-parameter fit failed (too few points?)"
        return out
    n9 = nine.as_array()
    seen = np.flatnonzero(np.all(np.isfinite(positions), axis=1))
    if release_time is None:
        i = seen[np.argmin(times[seen])]
        t_rel = float(times[i])
        p_rel = positions[i]
        v_rel = velocities[i] if velocities is not None else nine_velocity_fps(n9, t_rel - nine.t_ref) * FT
    else:
        t_rel = float(release_time)
        p_rel = nine_position_ft(n9, t_rel - nine.t_ref) * FT
        v_rel = nine_velocity_fps(n9, t_rel - nine.t_ref) * FT
    out.release_speed_mph = float(np.linalg.norm(v_rel) / MPH)
    out.release_pos_x_ft, out.release_pos_y_ft, out.release_pos_z_ft = map(float, p_rel / FT)
    out.release_extension_ft = RUBBER_Y_FT - out.release_pos_y_ft
    out.plate_time_s = float(nine.t_ref + time_at_y(n9, PLATE_FRONT_Y_FT) - t_rel)
    sx, sz = statcast_movement_in(n9, out.release_pos_y_ft)
    for k, v in _statcast_movement_fields(sx, sz).items():
        setattr(out, k, float(v))
    if spin is not None:
        w = as_array(spin, (3,), "spin")
        out.spin_rate_rpm = spin_rate_rpm(w)
        out.spin_efficiency = spin_efficiency(w, v_rel)
        out.active_spin_rpm = out.spin_rate_rpm * out.spin_efficiency
        out.gyro_angle_deg = float(np.degrees(np.arccos(np.clip(out.spin_efficiency, 0.0, 1.0))))
        out.spin_axis_deg = spin_axis_deg(w, v_rel)
        out.spin_tilt = clock_tilt(out.spin_axis_deg)
        out.spin_direction_clock = clock_tilt(out.spin_axis_deg, resolution_min=1)
    return out


def pitch_metrics_from_flight(p0, v0, spin, model=None, *, t0: float = 0.0,
                              sample_rate_hz: float = 500.0) -> PitchMetrics:
    """Metrics of a simulated pitch released at ``p0`` with ``v0`` and ``spin`` (field frame, SI).

    The flight is integrated (reference integrator) from release to the front of the plate and
    sampled at ``sample_rate_hz`` (the dense output of that integration: the same steps as a
    second integration to the crossing, but for the last one, without its cost); the
    9-parameter fit uses the whole flight.

    Parameters
    ----------
    p0, v0, spin : array_like, shape (3,)
        Release position (m), velocity (m/s) and spin (rad/s).
    model : stillcap.ball.physics.FlightModel, optional
    """
    from stillcap.ball.physics import cross_plane

    cross = cross_plane(p0, v0, spin, model, t0=t0)
    if not cross.success:
        return PitchMetrics(success=False, message=f"flight did not reach the plate: {cross.message}")
    n = max(int(np.ceil((cross.time - t0) * sample_rate_hz)) + 1, 4)
    ts = np.linspace(t0, cross.time, n)
    y = cross.trajectory(ts)  # (6, n): positions and velocities
    return pitch_metrics(ts, y[:3].T, spin, velocities=y[3:].T)


# --------------------------------------------------------------------------------------------
# Many flights at once (the metric sigmas: ~25 flights per pitch)
# --------------------------------------------------------------------------------------------
def fit_nine_parameter_batch(times, positions, *, y0_ft: float = Y0_FT) -> dict:
    """:func:`fit_nine_parameter` of many flights at once.

    The flights share one sample grid; a sample a flight does not have is NaN (its time and
    its coordinates). Each flight's fit is the one :func:`fit_nine_parameter` gives for its
    own samples, solved per axis with a batched QR decomposition (NumPy has no batched
    ``lstsq``) instead of one ``lstsq`` (SVD) per flight and axis: the same least-squares
    solution up to rounding (~1e-12 relative). Only a rank-deficient design (fewer than three
    distinct times), where ``lstsq`` would return a minimum-norm solution, counts as a failure.

    Parameters
    ----------
    times : array_like, shape (M, N)
        s, NaN where a flight has no sample.
    positions : array_like, shape (M, N, 3)
        Field frame, metres; NaN = not observed (per coordinate).
    y0_ft : float

    Returns
    -------
    dict
        ``"nine"`` (M, 9) in :data:`NINE_NAMES` order, ``"t_ref"`` and ``"rms_residual_ft"``
        (M,) (all NaN where the fit failed), ``"n_points"`` (M,) int and ``"success"`` (M,)
        bool, as in :class:`NineParameterFit`.
    """
    t = np.asarray(times, float)
    pos = np.asarray(positions, float) / FT
    if t.ndim != 2 or pos.shape != (*t.shape, 3):
        raise ValueError(f"need times (M, N) and positions (M, N, 3), got {t.shape} and {pos.shape}")
    has_t = np.isfinite(t)
    tc = np.sum(np.where(has_t, t, 0.0), axis=1) / np.maximum(has_t.sum(axis=1), 1)  # nanmean
    ok = (np.isfinite(pos) & has_t[..., None]).transpose(0, 2, 1)  # (M, 3 axes, N)
    # design (M, 3 axes, N, 3): rows of unused samples are zero and do not count
    d = np.where(ok, (t - tc[:, None])[:, None, :], 0.0)
    A = np.stack([ok.astype(float), d, d * d], axis=-1)
    b = np.where(ok, pos.transpose(0, 2, 1), 0.0)
    fit_ok = np.count_nonzero(ok, axis=2) >= 3
    if A.shape[2] >= 3:
        # one decomposition per flight when its three axes use the same samples (the usual case)
        q, r = np.linalg.qr(A[:, :1] if np.all(ok == ok[:, :1]) else A)
        diag = np.abs(np.diagonal(r, axis1=-2, axis2=-1))
        fit_ok &= np.all(diag > 1e-12 * np.maximum(diag.max(axis=-1, keepdims=True), 1e-300), axis=-1)
        r = np.where(fit_ok[..., None, None], r, np.eye(3))  # failed fits: any solvable system
        coef = np.linalg.solve(r, (b[..., None, :] @ q)[..., 0, :, None])[..., 0]  # R c = Q^T b
    else:
        fit_ok[:] = False
        coef = np.zeros(A.shape[:2] + (3,))
    coef[~fit_ok] = np.nan
    res = (A @ coef[..., None])[..., 0] - b
    res2 = np.sum(np.where(ok, res, 0.0) ** 2, axis=(1, 2))
    # time (relative to tc) where y = y0_ft, the root nearest the data (np.roots in the scalar fit)
    c1, c2 = coef[:, 1, 1], coef[:, 1, 2]
    c = coef[:, 1, 0] - y0_ft
    with np.errstate(invalid="ignore", divide="ignore"):
        qq = -0.5 * (c1 + np.copysign(np.sqrt(c1 * c1 - 4.0 * c2 * c), c1))  # stable quadratic roots
        r1, r2 = qq / c2, c / qq
        ts = np.where(c2 != 0, np.where(np.abs(r1) < np.abs(r2), r1, r2), -c / c1)
    success = np.all(fit_ok, axis=1) & np.isfinite(ts)
    p = coef[..., 0] + coef[..., 1] * ts[:, None] + coef[..., 2] * (ts * ts)[:, None]
    v = coef[..., 1] + 2.0 * coef[..., 2] * ts[:, None]
    nine = np.where(success[:, None], np.concatenate([p, v, 2.0 * coef[..., 2]], axis=1), np.nan)
    n_pts = np.sum(np.all(np.isfinite(pos), axis=2), axis=1)
    return {"nine": nine, "t_ref": np.where(success, tc + ts, np.nan),
            "rms_residual_ft": np.where(success, np.sqrt(res2 / np.maximum(n_pts, 1)), np.nan),
            "n_points": np.where(success, n_pts, np.where(fit_ok, ok.sum(axis=2), 0).max(axis=1)),
            "success": success}


def pitch_metrics_batch(times, positions, spins=None, *, velocities, y0_ft: float = Y0_FT) -> dict:
    """:func:`pitch_metrics` of many flights at once (release at each flight's first sample).

    Parameters
    ----------
    times : array_like, shape (M, N)
        s, NaN where a flight has no sample (as in :func:`fit_nine_parameter_batch`).
    positions, velocities : array_like, shape (M, N, 3)
        Field frame, metres and m/s (NaN where not observed).
    spins : array_like, shape (M, 3), optional
        Spin vector of each flight at release, rad/s. Without it the spin fields are NaN.
    y0_ft : float

    Returns
    -------
    metrics, nine : dict
        ``{name: (M,)}`` for the numeric fields of :class:`PitchMetrics` and for those of
        :class:`NineParameterFit` (``spin_tilt``, ``spin_direction_clock``, ``message`` and ``nine_parameter`` left out),
        NaN where :func:`pitch_metrics` gives NaN (or ``None`` in ``to_dict``); ``success``
        as there. The same numbers as :func:`pitch_metrics` flight by flight, up to rounding.
    """
    t = np.asarray(times, float)
    pos = np.asarray(positions, float)
    vel = np.asarray(velocities, float)
    if vel.shape != pos.shape:
        raise ValueError(f"velocities must have the shape of positions {pos.shape}, got {vel.shape}")
    fit = fit_nine_parameter_batch(t, pos, y0_ft=y0_ft)
    n9, ok = fit["nine"], fit["success"]
    nine = {k: n9[:, i] for i, k in enumerate(NINE_NAMES)}
    nine.update(t_ref=fit["t_ref"], rms_residual_ft=fit["rms_residual_ft"])
    # release: each flight's first sample observed in all coordinates
    seen = np.all(np.isfinite(pos), axis=2) & np.isfinite(t)
    i = np.argmin(np.where(seen, t, np.inf), axis=1)
    rows = np.arange(len(t))
    ok = ok & seen[rows, i]
    t_rel = np.where(ok, t[rows, i], np.nan)
    p_rel, v_rel = pos[rows, i] / FT, vel[rows, i]
    speed = np.linalg.norm(v_rel, axis=1)
    out = {
        "release_speed_mph": speed / MPH,
        "release_pos_x_ft": p_rel[:, 0], "release_pos_y_ft": p_rel[:, 1], "release_pos_z_ft": p_rel[:, 2],
        "release_extension_ft": RUBBER_Y_FT - p_rel[:, 1],
        "plate_time_s": fit["t_ref"] + time_at_y(n9, PLATE_FRONT_Y_FT) - t_rel,
    }
    out.update({k: v for k, v in nine_parameter_metrics(n9).items() if k not in out})
    out.update(_statcast_movement_fields(*statcast_movement_in(n9, p_rel[:, 1])))
    nan = np.full(len(t), np.nan)
    spin_keys = ("spin_rate_rpm", "active_spin_rpm", "spin_efficiency", "gyro_angle_deg", "spin_axis_deg")
    if spins is None:
        out.update({k: nan for k in spin_keys})
    else:
        w = np.asarray(spins, float)
        if w.shape != (len(t), 3):
            raise ValueError(f"spins must have shape ({len(t)}, 3), got {w.shape}")
        with np.errstate(invalid="ignore", divide="ignore"):
            m = np.cross(w, v_rel / speed[:, None])
            nw = np.linalg.norm(w, axis=1)
            eff = np.where(nw == 0, np.nan, np.minimum(np.linalg.norm(m, axis=1) / nw, 1.0))
            flat = np.hypot(m[:, 0], m[:, 2]) <= 1e-12 * np.maximum(nw, 1e-300)  # pure gyro / no spin
            out.update(spin_rate_rpm=nw * RPM_PER_RAD_S, spin_efficiency=eff, active_spin_rpm=nw * RPM_PER_RAD_S * eff,
                       gyro_angle_deg=np.degrees(np.arccos(np.clip(eff, 0.0, 1.0))),
                       spin_axis_deg=np.where(flat, np.nan, np.mod(np.degrees(np.arctan2(m[:, 2], m[:, 0])) + 90.0, 360.0)))
    # pitch_metrics: a failed 9-parameter fit leaves the release and spin fields NaN as well
    out = {k: np.where(ok, v, np.nan) for k, v in out.items()}
    out["success"] = ok
    return out, nine


def rapsodo_spin_break_in(speed_mph, release_angle_deg, horizontal_angle_deg, release_height_ft, release_side_ft,
                          spin_rpm, spin_direction, gyro_deg, model=None, *, extension_ft: float = 6.0):
    """Rapsodo's VB and HB (spin), inches, predicted from what Rapsodo measures at release.

    The pitch is flown (``model``, default Nathan's) from ``y = 60.5 ft - extension_ft`` (Rapsodo
    measures no extension: 6 ft assumed) with the speed, the release angles (vertical, positive
    up; horizontal, positive toward +x), the release height and side (side positive toward -x,
    the pitcher's right) and the spin vector (total rate, direction on the clock as Rapsodo
    shows it, gyro degree: efficiency ``cos(gyro)``); VB/HB are its Statcast movement
    (``rapsodo_vb_in``, ``rapsodo_hb_in``). No fitted constant: on the shared Rapsodo file this
    gives VB within 1.44 in and HB within 0.33 in (median, ``docs/pitch-metrics.md``).

    Returns
    -------
    vb_in, hb_in : float
    """
    from stillcap.ball.physics import FlightModel

    model = FlightModel.nathan_model() if model is None else model
    axis = parse_clock_deg(spin_direction) if isinstance(spin_direction, str) else float(spin_direction)
    va, ha = math.radians(release_angle_deg), math.radians(horizontal_angle_deg)
    v = speed_mph * MPH * np.array([math.cos(va) * math.sin(ha), -math.cos(va) * math.cos(ha), math.sin(va)])
    p0 = np.array([-release_side_ft, RUBBER_Y_FT - extension_ft, release_height_ft]) * FT
    w = spin_vector(spin_rpm, axis, v, efficiency=math.cos(math.radians(gyro_deg)))
    m = pitch_metrics_from_flight(p0, v, w, model)
    return m.rapsodo_vb_in, m.rapsodo_hb_in
