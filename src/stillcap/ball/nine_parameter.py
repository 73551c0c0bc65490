"""The 9-parameter pitch model and the movement definitions of PITCHf/x and Statcast (vectorised).

Field frame of :mod:`stillcap.ball.metrics` (catcher's view, y toward the pitcher, z up), feet
and seconds. Every function takes arrays of shape ``(..., 9)`` (``x0, y0, z0, vx0, vy0, vz0,
ax, ay, az``) and returns arrays of shape ``(...)``, so a whole table of pitches goes at once.

- PITCHf/x movement (:func:`movement_in`): the spin-and-drag deviation from a gravity-only
  path over the last 40 ft (``y = 40 ft`` to the front of the plate).
- Statcast movement (:func:`statcast_movement_in`): the movement caused by spin alone from
  release to the front of the plate: the 9-parameter acceleration without gravity, with its
  component along the release velocity (drag) removed, over the release-to-plate time.
- Spin axis from movement (:func:`spin_axis_from_movement_deg`, Statcast ``spin_axis``, PITCHf/x
  ``spin_dir`` when given PITCHf/x movement): ``atan2(pfx_z, pfx_x) + 90``; 180 = backspin.

``docs/pitch-metrics.md`` gives each definition's source and the agreement with real files.
"""

from __future__ import annotations

import numpy as np

FT = 0.3048  #: metres per foot
INCH = 0.0254  #: metres per inch
MPH = 0.44704  #: m/s per mph
FPS_PER_MPH = 5280.0 / 3600.0  #: ft/s per mph
G_FT = 32.174  #: standard gravity, ft/s^2 (PITCHf/x)
Y0_FT = 50.0  #: reference plane of the 9-parameter fit, ft
Y_MOVEMENT_START_FT = 40.0  #: where PITCHf/x movement starts, ft
PLATE_FRONT_Y_FT = 17.0 / 12.0  #: front edge of home plate, ft
RUBBER_Y_FT = 60.5  #: front edge of the pitching rubber, ft
from stillcap._numeric import RPM_PER_RAD_S  # noqa: E402,F401 (the one definition; re-exported)

NINE_NAMES = ("x0", "y0", "z0", "vx0", "vy0", "vz0", "ax", "ay", "az")


# --------------------------------------------------------------------------------------------
# 9-parameter model (vectorised over pitches: arrays of shape (..., 9), feet and seconds)
# --------------------------------------------------------------------------------------------
def _nine(nine) -> np.ndarray:
    a = np.asarray(nine, float)
    if a.ndim < 1 or a.shape[-1] != 9:
        raise ValueError(f"nine-parameter array must have shape (..., 9), got {a.shape}")
    return a


def time_at_y(nine, y_ft):
    """Time (s, from the 9-parameter reference ``t = 0``) at which the pitch reaches ``y_ft``.

    Parameters
    ----------
    nine : array_like, shape (..., 9)
        ``x0, y0, z0, vx0, vy0, vz0, ax, ay, az`` (ft, ft/s, ft/s^2).
    y_ft : float or array_like, shape (...)

    Returns
    -------
    ndarray, shape (...)
        The root of ``y0 + vy0 t + ay t^2 / 2 = y`` continuous with ``(y - y0) / vy0`` (NaN if
        the pitch never gets there).
    """
    n = _nine(nine)
    a = 0.5 * n[..., 7]
    b = n[..., 4]
    c = n[..., 1] - np.asarray(y_ft, float)
    disc = b * b - 4.0 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        q = -0.5 * (b + np.copysign(np.sqrt(disc), b))  # numerically stable quadratic root
        return np.where(disc >= 0, c / q, np.nan)


def nine_position_ft(nine, t):
    """Position (ft), shape (..., 3), of the 9-parameter model at time ``t`` (s, shape (...))."""
    n = _nine(nine)
    t = np.asarray(t, float)[..., None]
    return n[..., 0:3] + n[..., 3:6] * t + 0.5 * n[..., 6:9] * t * t


def nine_velocity_fps(nine, t):
    """Velocity (ft/s), shape (..., 3), of the 9-parameter model at time ``t`` (s)."""
    n = _nine(nine)
    return n[..., 3:6] + n[..., 6:9] * np.asarray(t, float)[..., None]


def plate_location_ft(nine):
    """PITCHf/x ``px, pz`` (ft): x and z at the front of the plate (``y = 17/12 ft``).

    Parameters
    ----------
    nine : array_like, shape (..., 9)

    Returns
    -------
    px, pz : ndarray, shape (...)
    """
    p = nine_position_ft(nine, time_at_y(nine, PLATE_FRONT_Y_FT))
    return p[..., 0], p[..., 2]


def movement_in(nine, y_start_ft: float = Y_MOVEMENT_START_FT):
    """PITCHf/x movement ``pfx_x, pfx_z`` (inches) from ``y_start_ft`` to the front of the plate.

    ``pfx_x = a_x T^2 / 2`` and ``pfx_z = (a_z + 32.174) T^2 / 2`` (gravity removed), ``T`` the
    flight time from ``y_start_ft`` to ``y = 17/12 ft``.

    Parameters
    ----------
    nine : array_like, shape (..., 9)

    Returns
    -------
    pfx_x_in, pfx_z_in : ndarray, shape (...)
    """
    n = _nine(nine)
    t = time_at_y(n, PLATE_FRONT_Y_FT) - time_at_y(n, y_start_ft)
    half_t2_in = 0.5 * t * t * 12.0
    return n[..., 6] * half_t2_in, (n[..., 8] + G_FT) * half_t2_in


def movement_axis_deg(pfx_x, pfx_z):
    """Movement-based spin axis (PITCHf/x ``spin_dir``): ``atan2(pfx_z, pfx_x) + 90``, 0..360."""
    return np.mod(np.degrees(np.arctan2(pfx_z, pfx_x)) + 90.0, 360.0)


pitchfx_movement_in = movement_in  #: PITCHf/x movement (the last 40 ft), the name says whose


def release_time(nine, release_y_ft):
    """Model time (s, negative before ``y0``) at which the pitch is at ``y = release_y_ft``."""
    return time_at_y(nine, release_y_ft)


def nine_from_release(release_pos_ft, v0_fps, a_fps2, y0_ft: float = Y0_FT) -> np.ndarray:
    """The 9-parameter model whose path passes through the release point (Statcast rebuild).

    Statcast exports give ``vx0, vy0, vz0, ax, ay, az`` at ``y = 50 ft`` and
    ``release_pos_x/y/z`` but no ``x0, z0``: carrying the release point along the fit from
    ``y = release_pos_y`` to ``y = y0_ft`` gives them.

    Parameters
    ----------
    release_pos_ft : array_like, shape (..., 3)
    v0_fps, a_fps2 : array_like, shape (..., 3)
        Velocity at ``y0_ft`` and the constant acceleration.

    Returns
    -------
    ndarray, shape (..., 9)
    """
    r = np.asarray(release_pos_ft, float)
    v = np.asarray(v0_fps, float)
    a = np.asarray(a_fps2, float)
    r, v, a = np.broadcast_arrays(r, v, a)
    if r.shape[-1:] != (3,):
        raise ValueError(f"release, velocity and acceleration need shape (..., 3), got {r.shape}")
    nine = np.concatenate([np.zeros_like(r), v, a], axis=-1)
    nine[..., 1] = y0_ft
    t = time_at_y(nine, r[..., 1])
    nine[..., 0] = r[..., 0] - v[..., 0] * t - 0.5 * a[..., 0] * t * t
    nine[..., 2] = r[..., 2] - v[..., 2] * t - 0.5 * a[..., 2] * t * t
    return nine


def spin_acceleration_fps2(nine, release_y_ft):
    """The spin-induced (Magnus) acceleration, ft/s^2, shape (..., 3): the 9-parameter
    acceleration without gravity, less its component along the velocity at ``y = release_y_ft``
    (the drag, as Statcast takes it)."""
    n = _nine(nine)
    a = n[..., 6:9].copy()
    a[..., 2] += G_FT
    v = nine_velocity_fps(n, release_time(n, release_y_ft))
    with np.errstate(invalid="ignore", divide="ignore"):
        vh = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return a - np.sum(a * vh, axis=-1, keepdims=True) * vh


def statcast_movement_in(nine, release_y_ft):
    """Statcast movement ``pfx_x, pfx_z`` (inches): the movement caused by spin alone from
    release (``y = release_y_ft``) to the front of the plate.

    ``pfx = a_M T^2 / 2`` with ``a_M`` from :func:`spin_acceleration_fps2` and ``T`` the
    9-parameter time from release to ``y = 17/12 ft``. On 540 real Statcast pitches this gives
    the file's ``pfx_x, pfx_z`` to 0.08 / 0.03 in (median; ``docs/pitch-metrics.md``).

    Returns
    -------
    pfx_x_in, pfx_z_in : ndarray, shape (...)
    """
    n = _nine(nine)
    t = time_at_y(n, PLATE_FRONT_Y_FT) - release_time(n, release_y_ft)
    am = spin_acceleration_fps2(n, release_y_ft)
    half_t2_in = 0.5 * t * t * 12.0
    return am[..., 0] * half_t2_in, am[..., 2] * half_t2_in


def spin_axis_from_movement_deg(pfx_x, pfx_z):
    """Spin axis inferred from movement (Statcast ``spin_axis`` from Statcast ``pfx``; PITCHf/x
    ``spin_dir`` from PITCHf/x ``pfx``): ``atan2(pfx_z, pfx_x) + 90`` in 0..360, 180 = backspin."""
    return movement_axis_deg(pfx_x, pfx_z)


def approach_angles_deg(nine, y_ft: float = PLATE_FRONT_Y_FT):
    """Vertical and horizontal approach angles (deg) at ``y = y_ft`` (the front of the plate).

    ``VAA = -atan(vz / vy)`` and ``HAA = -atan(vx / vy)`` with the 9-parameter velocity there
    (``vy < 0``): VAA is negative for a descending pitch, HAA positive when the pitch travels
    toward +x (first-base side, catcher's view).
    """
    n = _nine(nine)
    v = nine_velocity_fps(n, time_at_y(n, y_ft))
    return (np.degrees(np.arctan(v[..., 2] / -v[..., 1])), np.degrees(np.arctan(v[..., 0] / -v[..., 1])))


def parse_clock_deg(text: str) -> float:
    """A spin direction on a clock (``"1:08"``, ``"1:8"``, ``"0:52"``, ``"12:52"``) as a Statcast
    axis in degrees (``180 + 30 * hours``, 0..360). ``ValueError`` naming the text otherwise."""
    parts = str(text).strip().split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        h, m = int(parts[0]), int(parts[1])
        if not (0 <= h <= 12 and 0 <= m < 60):
            raise ValueError
    except ValueError:
        raise ValueError(f"not a clock time h:mm: {text!r}") from None
    return float(np.mod(180.0 + 30.0 * (h % 12) + 0.5 * m, 360.0))
