"""Synthetic marker observations of a ball spinning at a constant rate (tests, benchmarks,
demos): :func:`simulate_observations`."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_array, as_rng
from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation._observations import MarkerObservations, _default_layout, _unit_rows
from stillcap.ball.orientation._so3 import _tangent_bases


def simulate_observations(times, ball2world_t0, spin, view_dirs, layout: BallLayout | None = None,
                          *, t0: float | None = None, noise_deg: float = 1.0,
                          margin_deg: float = 10.0, miss_rate: float = 0.0,
                          mistype_rate: float = 0.0, max_per_flash=None,
                          rng=None) -> MarkerObservations:
    """Marker observations of a ball spinning at constant ``spin`` seen from ``view_dirs``.

    Parameters
    ----------
    times : array_like, shape (K,)
        Flash times, s.
    ball2world_t0 : array_like, shape (3, 3)
        Orientation at ``t0``.
    spin : array_like, shape (3,)
        rad/s, world frame.
    view_dirs : array_like, shape (3,) or (C, 3)
        Directions from the ball toward each camera (or stereo pair), world frame: a marker
        is seen when it is within ``90 - margin_deg`` deg of one of them.
    layout : BallLayout, optional
    t0 : float, optional
        Default ``times[0]``.
    noise_deg : float
        1-sigma of each of the two tangent components of the direction error, deg (the RMS
        angular error is ``sqrt(2)`` times this).
    margin_deg : float
    miss_rate : float
        Probability that a visible marker is not detected.
    mistype_rate : float
        Probability that a detected marker gets a wrong (random other) type: an outlier.
    max_per_flash : array_like of int, shape (K,), optional
        At most this many markers on each flash (randomly kept), e.g. 0 or 1 for some flashes.
    rng : np.random.Generator or int, optional

    Returns
    -------
    MarkerObservations
    """
    rng = as_rng(rng)
    layout = _default_layout(layout)
    times = as_array(times, (None,), "times")
    R0 = as_array(ball2world_t0, (3, 3), "ball2world_t0")
    w = as_array(spin, (3,), "spin")
    v = np.atleast_2d(np.asarray(view_dirs, float))
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"view_dirs must have shape (3,) or (C, 3), got {np.shape(view_dirs)}")
    v = _unit_rows(v, "view_dirs")
    t0 = float(times[0]) if t0 is None else float(t0)
    caps = (None if max_per_flash is None
            else as_array(max_per_flash, (len(times),), "max_per_flash", dtype=int))
    Rk = (Rotation.from_rotvec(np.outer(times - t0, w)) * Rotation.from_matrix(R0)).as_matrix()
    sig = np.radians(noise_deg)
    fl, ty, di = [], [], []
    for k in range(len(times)):
        world = layout.directions @ Rk[k].T
        vis = np.any(world @ v.T > np.cos(np.radians(90.0 - margin_deg)), axis=1)
        vis &= rng.random(len(world)) >= miss_rate
        idx = np.flatnonzero(vis)
        if caps is not None and len(idx) > caps[k]:
            idx = np.sort(rng.choice(idx, size=max(int(caps[k]), 0), replace=False))
        u = world[idx]
        if len(u):
            t1, t2 = _tangent_bases(u)
            e = rng.normal(size=(len(u), 2)) * sig
            u = u * np.cos(np.linalg.norm(e, axis=1))[:, None] + (
                np.sinc(np.linalg.norm(e, axis=1) / np.pi)[:, None] * (e[:, :1] * t1 + e[:, 1:] * t2))
        t = layout.types[idx].copy()
        bad = rng.random(len(t)) < mistype_rate
        for i in np.flatnonzero(bad):
            t[i] = rng.choice([x for x in range(layout.n_types) if x != t[i]])
        fl.append(np.full(len(idx), k))
        ty.append(t)
        di.append(u.reshape(-1, 3))
    return MarkerObservations(np.concatenate(fl), np.concatenate(ty), np.concatenate(di))
