"""The ball's release from the hand: which flashes hold it, when and where it leaves, how fast.

Inputs are what the hand capture gives (``docs/hand-ball.md``): ball centres per flash (the ball
pipeline), and the hand's pose per reconstructed flash (``root2world``, the hand pipeline), all
on one relative clock (flash ``k`` at ``k / strobe_hz``; the zero is the caller's, usually the
first flash of the window).

1. **Held flashes.** At a flash with a hand pose the ball's centre in the hand frame is
   ``q_k = R_k^T (p_k - t_k)``. While held, ``q_k`` is the same point (the hold point); the
   ball leaves once, so the held flashes are the longest leading run whose ``q_k`` agree within
   ``hold_tol_m``. The hold point ``c`` is their mean (learnt, not assumed).
2. **Hold-point path.** ``h(t) = R(t) c + t(t)``: a cubic spline through ``c`` carried by every
   hand pose (``scipy.interpolate.CubicSpline``, linear with 2 poses), and its derivative.
3. **Release time.** The ball leaves the hold-point path tangentially: its free flight is
   ``p(t) = h(t_r) + v (t - t_r) + a (t - t_r)^2 / 2`` with ``a`` gravity plus drag
   (:class:`stillcap.ball.physics.FlightModel`, constant over the ~20 ms after release: drag moves
   the ball ~1 mm, gravity ~2 mm there). Least squares (``scipy.optimize.least_squares``) over the
   free flashes for ``t_r`` and ``v`` (two or more free flashes), or for ``t_r`` alone with
   ``v = h'(t_r)`` (one free flash). ``t_r`` is bounded by the last held and the first free flash.
4. **Uncertainty**: ``s^2 (J^T J)^-1`` with ``s`` the larger of the position sigma given and the
   residual RMS; propagated to the point ``h(t_r)``, the speed and the direction.

Flags: ``held_seen`` (some flash holds the ball), ``released_seen`` (some flash shows it free);
without both there is no release time (NaN) and ``message`` says why. Nothing here imports the
studio. The ball's flashes are numbered from the hand poses by
:func:`stillcap.ball.flashes.number_flashes_from_hand` (on the hold-point path of :func:`hold_point_path`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from stillcap._checks import as_array
from stillcap.ball.metrics import MPH

__all__ = ["Release", "estimate_release", "ball_in_hand", "hold_point_path", "release_angles_deg"]


@dataclass
class Release:
    """The ball's release from the hand (frame of the inputs, SI; times on the input clock).

    Attributes
    ----------
    success : bool
        A release time was estimated.
    held_seen, released_seen : bool
        Some flash shows the ball in the hand / in free flight.
    held : ndarray of bool, shape (m,)
        Per ball flash: held (True) or free (False); False where the flash has no hand pose and
        lies after release, NaN-position flashes are False.
    hold_point : ndarray, shape (3,)
        Ball centre in the hand (root) frame learnt from the held flashes, m (NaN if none).
    hold_point_sigma : ndarray, shape (3,)
        1-sigma of its mean per axis, m.
    hold_spread_m : float
        Largest distance of a held flash's ball from the hold point, m.
    t_release : float
        Release time, s, and ``t_release_sigma`` its 1-sigma.
    position : ndarray, shape (3,)
        Release point ``h(t_release)``, m, with ``position_sigma`` (3,) per axis.
    velocity : ndarray, shape (3,)
        Release velocity, m/s, with ``velocity_cov`` (3, 3).
    speed_mph, speed_sigma_mph : float
    horizontal_deg, vertical_deg : float
        Direction (:func:`release_angles_deg`), with ``direction_sigma_deg`` (cone 1-sigma).
    velocity_source : str
        ``"free flashes"`` (2+ free flashes) or ``"hand"`` (``h'(t_release)``, 1 free flash).
    residuals_m : ndarray, shape (m,)
        Distance of each free flash from the fitted free path (NaN for the others), m.
    n_held, n_free : int
    chi2 : float
        Sum of squared normalised residuals (free flashes to the free path, held flashes to the
        hold point).
    message : str
    """

    success: bool
    held_seen: bool
    released_seen: bool
    held: np.ndarray
    hold_point: np.ndarray
    hold_point_sigma: np.ndarray
    hold_spread_m: float
    t_release: float = float("nan")
    t_release_sigma: float = float("nan")
    position: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    position_sigma: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    velocity: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    velocity_cov: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    speed_mph: float = float("nan")
    speed_sigma_mph: float = float("nan")
    horizontal_deg: float = float("nan")
    vertical_deg: float = float("nan")
    direction_sigma_deg: float = float("nan")
    velocity_source: str = ""
    residuals_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_held: int = 0
    n_free: int = 0
    chi2: float = float("nan")
    message: str = ""

    def to_dict(self) -> dict:
        """JSON-ready dict; keys shared with the studio truth's ``release`` (``t0_s``, ``p0``,
        ``v0``, ``speed_mph``) plus sigmas and flags."""
        return {"success": self.success, "held_seen": self.held_seen, "released_seen": self.released_seen,
                "t0_s": self.t_release, "t0_sigma_s": self.t_release_sigma, "p0": self.position.tolist(),
                "p0_sigma": self.position_sigma.tolist(), "v0": self.velocity.tolist(),
                "v0_sigma": np.sqrt(np.clip(np.diag(self.velocity_cov), 0, None)).tolist(),
                "speed_mph": self.speed_mph, "speed_sigma_mph": self.speed_sigma_mph,
                "horizontal_deg": self.horizontal_deg, "vertical_deg": self.vertical_deg,
                "direction_sigma_deg": self.direction_sigma_deg, "velocity_source": self.velocity_source,
                "hold_point": self.hold_point.tolist(), "hold_spread_mm": self.hold_spread_m * 1e3,
                "held": self.held.tolist(), "n_held": self.n_held, "n_free": self.n_free, "message": self.message}


def release_angles_deg(velocity) -> tuple[float, float]:
    """Direction of a velocity in the field frame: ``(horizontal, vertical)`` degrees.

    Horizontal: toward +x (the catcher's right) from straight at the plate (-y); vertical: above
    the horizontal plane.
    """
    v = as_array(velocity, (3,), "velocity")
    return (float(np.degrees(np.arctan2(v[0], -v[1]))),
            float(np.degrees(np.arctan2(v[2], np.hypot(v[0], v[1])))))


def ball_in_hand(ball_positions, root2world) -> np.ndarray:
    """Ball centres in the hand (root) frame, ``R^T (p - t)`` per flash, shape (m, 3)."""
    P = as_array(ball_positions, (None, 3), "ball_positions")
    T = as_array(root2world, (len(P), 4, 4), "root2world")
    return np.einsum("kba,kb->ka", T[:, :3, :3], P - T[:, :3, 3])


def _circle_3d(points: np.ndarray):
    """Plane and circle through 3+ points (least squares): centre (3,), e1, e2, normal, radius.
    A Kasa fit in the best-fit plane (``np.linalg.lstsq``)."""
    mu = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - mu)
    e1, e2, n = vt
    xy = np.stack([(points - mu) @ e1, (points - mu) @ e2], axis=1)
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    sol, *_ = np.linalg.lstsq(A, (xy ** 2).sum(axis=1), rcond=None)
    c2 = sol[:2]
    r = float(np.sqrt(max(sol[2] + c2 @ c2, 0.0)))
    return mu + c2[0] * e1 + c2[1] * e2, e1, e2, n, r


def hold_point_path(times: np.ndarray, points: np.ndarray):
    """Path of the hold point through its positions at the hand flashes: ``(h(t), h'(t))``.

    The hand swings about the shoulder, so the path is close to a circular arc sampled ~30
    degrees apart: splines of the polar coordinates (angle, radius, offset from the plane)
    about a fitted circle follow it far better than a Cartesian spline of the same samples (whose
    derivative is off by ~5 % there). Cartesian spline when the points are nearly on a line;
    straight line with 2 points.
    """
    if len(times) >= 3:
        # imported here: a pitch never needs it, and stillcap pitch starts faster without it
        from scipy.interpolate import CubicSpline

        c, e1, e2, n, r = _circle_3d(points)
        span = float(np.linalg.norm(points[-1] - points[0]))
        if np.isfinite(r) and 0 < r < 20 * max(span, 1e-9):
            d = points - c
            phi = np.unwrap(np.arctan2(d @ e2, d @ e1))
            rad = np.hypot(d @ e1, d @ e2)
            off = d @ n
            cs = CubicSpline(times, np.column_stack([phi, rad, off]), axis=0, extrapolate=True)
            dcs = cs.derivative()

            def h(t):
                f = cs(t)
                return c + (f[..., 1] * np.cos(f[..., 0]))[..., None] * e1 + \
                    (f[..., 1] * np.sin(f[..., 0]))[..., None] * e2 + f[..., 2:3] * n

            def dh(t):
                f, g = cs(t), dcs(t)
                u = np.cos(f[..., 0])[..., None] * e1 + np.sin(f[..., 0])[..., None] * e2
                w = -np.sin(f[..., 0])[..., None] * e1 + np.cos(f[..., 0])[..., None] * e2
                return g[..., 1:2] * u + (f[..., 1] * g[..., 0])[..., None] * w + g[..., 2:3] * n
            return h, dh
        cs = CubicSpline(times, points, axis=0, extrapolate=True)
        return cs, cs.derivative()
    v = (points[1] - points[0]) / (times[1] - times[0])
    return (lambda t: points[0] + np.multiply.outer(np.asarray(t) - times[0], v)), \
        (lambda t: np.broadcast_to(v, np.shape(t) + (3,)))


def _constant_acceleration(model, velocity) -> np.ndarray:
    if model is None:
        return np.zeros(3)
    if model == "gravity":
        return np.array([0.0, 0.0, -9.80665])
    return np.asarray(model.acceleration(np.asarray(velocity, float), np.zeros(3)), float)


def estimate_release(ball_times, ball_positions, hold_times, root2world, *, strobe_hz: float,
                     position_sigma_m=0.002, hold_tol_m: float = 0.012, model="seed", model_sigma_m: float = 0.003,
                     hand_sigma_m: float = 0.0, hand_speed_rel_sigma: float = 0.05,
                     min_held: int = 2) -> Release:
    """Estimate when and where the ball leaves the hand, and its velocity (module docstring).

    Parameters
    ----------
    ball_times : array_like, shape (m,)
        Flash time of each ball position, s (relative clock shared with ``hold_times``).
    ball_positions : array_like, shape (m, 3)
        Ball centres, m (NaN rows: not seen).
    hold_times : array_like, shape (n,)
        Times of the flashes with a hand pose, s, increasing.
    root2world : array_like, shape (n, 4, 4)
        The hand's root pose at those flashes.
    strobe_hz : float
        The strobe (used to match ball flashes to hand flashes: within a tenth of a period).
    position_sigma_m : float or array_like, shape (m,)
        Expected 1-sigma of each ball position per axis (e.g. ``HandBalls.sigma_m``).
    model_sigma_m : float
        1-sigma per axis of the free-flight model at the free flashes (hold-path spline between
        hand poses, constant acceleration), added to theirs; with one or two free flashes the
        fit has no redundancy to show this error, so it is assumed (measured: ~3 mm).
    hold_tol_m : float
        Largest distance of a held flash's ball from the hold point.
    model : FlightModel, "seed", "nathan", "gravity" or None
        Constant acceleration of the free flight (gravity + drag at the release speed; None: none).
    hand_sigma_m : float
        1-sigma of the hold-point path (hand pose errors), added to the free flashes' sigma.
    hand_speed_rel_sigma : float
        With one free flash only: relative 1-sigma of the hold path's speed ``|h'(t_r)|`` used
        as a soft prior on the release speed (the direction is the path's tangent).

    min_held : int
        Fewest leading flashes at one point of the hand that count as held (a single flash
        agrees with itself, so it cannot show that the ball is held).

    Returns
    -------
    Release
    """
    t_b = as_array(ball_times, (None,), "ball_times")
    P = as_array(ball_positions, (len(t_b), 3), "ball_positions")
    t_h = as_array(hold_times, (None,), "hold_times")
    T = as_array(root2world, (len(t_h), 4, 4), "root2world")
    if not (np.isfinite(strobe_hz) and strobe_hz > 0):
        raise ValueError(f"strobe_hz must be positive, got {strobe_hz}")
    if len(t_h) and np.any(np.diff(t_h) <= 0):
        raise ValueError("hold_times must be strictly increasing")
    if isinstance(model, str):
        from stillcap.ball.physics import flight_model
        model = flight_model(model)
    psig = np.broadcast_to(np.asarray(position_sigma_m, float), (len(t_b),)).astype(float)
    if not np.all(psig > 0):
        raise ValueError("position_sigma_m must be positive")
    order = np.argsort(t_b, kind="stable")
    m = len(t_b)
    seen = np.all(np.isfinite(P), axis=1)
    held = np.zeros(m, bool)
    empty = Release(False, False, False, held, np.full(3, np.nan), np.full(3, np.nan), float("nan"),
                    residuals_m=np.full(m, np.nan))
    hand_ok = np.all(np.isfinite(T.reshape(len(t_h), -1)), axis=1)
    t_h, T = t_h[hand_ok], T[hand_ok]
    if len(t_h) < 2:
        empty.message = f"{len(t_h)} hand pose(s): the hold-point path needs at least 2"
        return empty
    # ball flashes with a hand pose at the same flash
    tol_t = 0.1 / strobe_hz
    j_of = np.full(m, -1)
    for i in range(m):
        d = np.abs(t_h - t_b[i])
        if len(d) and d.min() < tol_t:
            j_of[i] = int(d.argmin())
    # 1. held flashes: the longest leading run (in time, seen flashes) whose hand-frame
    #    positions agree within hold_tol_m
    seq = [i for i in order if seen[i]]
    q = np.full((m, 3), np.nan)
    for i in seq:
        if j_of[i] >= 0:
            q[i] = ball_in_hand(P[i:i + 1], T[j_of[i]:j_of[i] + 1])[0]
    run: list[int] = []
    lead: list[int] = []  # before the first hand pose: held, unchecked (its back of the hand was not seen)
    for i in seq:
        if j_of[i] < 0:
            if not run and t_b[i] < t_h.min():
                lead.append(i)
                continue
            break
        trial = run + [i]
        c = q[trial].mean(axis=0)
        if np.max(np.linalg.norm(q[trial] - c, axis=1)) > hold_tol_m:
            break
        run = trial
    if len(run) < min_held:  # one flash agrees with itself: it cannot show that the ball is held
        run = []

    def attempt(run):
        held = np.zeros(m, bool)
        held[run] = True
        free = [i for i in seq if not held[i] and (not run or t_b[i] > t_b[run[-1]])]
        if run:
            held[lead] = True
        res = Release(False, bool(run), bool(free), held, np.full(3, np.nan), np.full(3, np.nan), float("nan"),
                      residuals_m=np.full(m, np.nan), n_held=len(run), n_free=len(free))
        if not run:
            res.message = ("the ball is never held in the window (no flash shows it at a fixed point of the hand): "
                           "no release time")
            return res
        c = q[run].mean(axis=0)
        res.hold_point = c
        res.hold_spread_m = float(np.max(np.linalg.norm(q[run] - c, axis=1)))
        spread = np.std(q[run], axis=0, ddof=1) if len(run) >= 2 else np.full(3, psig[run[0]])
        res.hold_point_sigma = np.maximum(spread, np.median(psig[run])) / np.sqrt(len(run))
        if not free:
            res.message = (f"the ball is held in all {len(run)} flashes that show it: never released in the window, "
                           "no release time")
            return res
        # 2. hold-point path through every hand pose
        hp = np.einsum("kab,b->ka", T[:, :3, :3], c) + T[:, :3, 3]
        h, dh = hold_point_path(t_h, hp)
        t_lo, t_hi = float(t_b[run[-1]]), float(t_b[free[0]])
        tf = t_b[free]
        Pf = P[free]
        # per free flash: its position sigma, the hand path's, and the model floor (the polar
        # spline of the hold path between poses ~33 degrees apart, the constant acceleration)
        sig = np.sqrt(psig[free] ** 2 + hand_sigma_m ** 2 + model_sigma_m ** 2)[:, None]
        sig_held = float(np.sqrt(np.median(psig[run]) ** 2 + hand_sigma_m ** 2 + model_sigma_m ** 2))
        v_hand = np.asarray(dh(0.5 * (t_lo + t_hi)), float)
        a = _constant_acceleration(model, v_hand)

        # 3. release time (and velocity) by least squares over the free flashes
        if len(free) >= 2:
            def fun(x):
                tr, v = x[0], x[1:]
                dt = tf - tr
                d = np.asarray(dh(tr), float)
                prior = (v - d) / (hand_speed_rel_sigma * np.linalg.norm(d))  # the ball leaves ~ with the hand
                return np.concatenate([((h(tr) + np.outer(dt, v) + 0.5 * np.outer(dt ** 2, a) - Pf) / sig).ravel(), prior])
            v_init = (Pf[-1] - Pf[0]) / (tf[-1] - tf[0])
            x0 = np.concatenate([[0.5 * (t_lo + t_hi)], v_init])
            lb = np.concatenate([[t_lo], np.full(3, -np.inf)])
            ub = np.concatenate([[t_hi], np.full(3, np.inf)])
            source = "free flashes"
        else:
            # one free flash: the ball leaves along the hold path's tangent u(t_r) at an unknown
            # speed; the path's curvature (the hand swings on an arc) separates it from the tangent
            # line, which fixes t_r; the speed is pulled softly toward |h'(t_r)| (the spline's
            # derivative is a few % off where the arm's acceleration changes at release)
            def fun(x):
                tr, sp = x
                dt = tf - tr
                d = np.asarray(dh(tr), float)
                nd = np.linalg.norm(d)
                pos = (h(tr) + np.outer(dt, d / nd * sp) + 0.5 * np.outer(dt ** 2, a) - Pf) / sig
                return np.concatenate([pos.ravel(), [(sp - nd) / (hand_speed_rel_sigma * nd)]])
            x0 = np.array([0.5 * (t_lo + t_hi), float(np.linalg.norm(v_hand))])
            lb, ub = np.array([t_lo, 0.0]), np.array([t_hi, np.inf])
            source = "hand"
        # a few starts across the bracket: the hold path is curved, the cost need not be convex
        best = None
        for s in np.linspace(0.1, 0.9, 5):
            x0[0] = t_lo + s * (t_hi - t_lo)
            r = least_squares(fun, x0, bounds=(lb, ub), x_scale="jac")
            if best is None or r.cost < best.cost:
                best = r
        x = best.x
        t_r = float(x[0])
        if len(free) >= 2:
            v = x[1:].copy()
        else:
            d = np.asarray(dh(t_r), float)
            v = d / np.linalg.norm(d) * x[1]
        J = best.jac
        r_m = best.fun[:3 * len(free)].reshape(-1, 3) * sig
        dof = max(J.shape[0] - J.shape[1], 1)
        scale = max(float(np.sum(best.fun ** 2)) / dof, 1.0)  # residuals larger than the sigmas say: widen
        try:
            cov = np.linalg.inv(J.T @ J) * scale
        except np.linalg.LinAlgError:
            cov = np.full((len(x), len(x)), np.nan)
        var_t = float(cov[0, 0])
        hdot = np.asarray(dh(t_r), float)
        # the point h(t_r): its spread from t_r along the path plus the hold-path's own sigma
        p_cov = np.outer(hdot, hdot) * var_t + np.eye(3) * (res.hold_point_sigma ** 2 + hand_sigma_m ** 2)
        if len(free) >= 2:
            v_cov = cov[1:, 1:]
        else:
            u0 = v / np.linalg.norm(v)
            d2 = (np.asarray(dh(t_r + 1e-4)) / np.linalg.norm(dh(t_r + 1e-4))
                  - np.asarray(dh(t_r - 1e-4)) / np.linalg.norm(dh(t_r - 1e-4))) / 2e-4  # turn of the tangent
            g = np.column_stack([x[1] * d2, u0])  # dv / d(t_r, speed)
            v_cov = g @ cov @ g.T
        speed = float(np.linalg.norm(v))
        u = v / speed
        hz, vt = release_angles_deg(v)
        P_perp = np.eye(3) - np.outer(u, u)
        ang_var = float(np.trace(P_perp @ v_cov @ P_perp)) / 2 / speed ** 2
        res.success = bool(np.isfinite(t_r))
        res.t_release, res.t_release_sigma = t_r, float(np.sqrt(max(var_t, 0.0)))
        res.position = np.asarray(h(t_r), float)
        res.position_sigma = np.sqrt(np.clip(np.diag(p_cov), 0, None))
        res.velocity, res.velocity_cov = v, v_cov
        res.speed_mph = speed / MPH
        res.speed_sigma_mph = float(np.sqrt(max(u @ v_cov @ u, 0.0))) / MPH
        res.horizontal_deg, res.vertical_deg = hz, vt
        res.direction_sigma_deg = float(np.degrees(np.sqrt(max(ang_var, 0.0))))
        res.velocity_source = source
        res.residuals_m[free] = np.linalg.norm(r_m, axis=1)
        at_bound = min(t_r - t_lo, t_hi - t_r) < 1e-6
        held_r = q[run] - c
        res.chi2 = float(np.sum(best.fun[:3 * len(free)] ** 2) + np.sum(held_r ** 2) / sig_held ** 2)
        res.message = (f"{len(run)} held and {len(free)} free flash(es); velocity from the {source}"
                       + ("; the release time sits on its bracket (last held / first free flash)" if at_bound else ""))
        return res

    res = attempt(run)
    if len(run) >= max(min_held, 2) + 1 and res.n_free >= 1:
        # the last "held" flash may be just after release (within hold_tol_m of the hold point):
        # keep it free instead when that fits clearly better (chi-square drop > 9)
        alt = attempt(run[:-1])
        if alt.success and (not res.success or alt.chi2 < res.chi2 - 9.0):
            alt.message += "; the last flash near the hold point fits the free flight better"
            res = alt
    return res
