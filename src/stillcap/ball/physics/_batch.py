"""The fast batch integrator for fitting (:func:`simulate_batch`): fixed-step RK4 or DOPRI5 in
NumPy over many flights at once (with a plain-float path for one flight), sampled by quintic
Hermite interpolation of the nodes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stillcap._checks import as_array, as_points
from stillcap.ball.physics._model import flight_model


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
