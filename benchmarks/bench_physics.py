"""Ball-flight integrators and the reference-trajectory fit: accuracy and speed.

    python benchmarks/bench_physics.py [--fits 5]

Table 1: every integrator against a very tight reference (solve_ivp RK45, rtol = atol = 1e-12)
over five pitches (both aerodynamic models), 40 output times from release to the front of the
plate: max position / velocity difference, time per trajectory and speed ratio to the default
reference ``simulate`` (RK45, rtol = atol = 1e-10). The fast integrator is also timed on a batch
of 19 trajectories (what one central-difference Jacobian of the fit needs).
Table 2: the reference-trajectory fit on a seed-like capture (front pair 80 Hz after release,
back pair 50 Hz before the plate, one lost flash, 2 mm noise): time, trajectories integrated,
recovery errors, for least_squares and the seed's Powell.
"""

from __future__ import annotations

import argparse

import numpy as np
from rich.console import Console
from rich.table import Table

from stillcap.ball.fit import FitPriors, fit_reference_trajectory, spin_basis
from stillcap.ball.metrics import FT, MPH, spin_vector
from stillcap.ball.physics import FlightModel, cross_plane, simulate, simulate_batch

from _timing import best_time

RELEASE = np.array([-0.6, 54.5 * FT, 1.8])


def pitches():
    """(name, v0, spin) of typical pitches (field frame, right-hander)."""
    out = []
    for name, mph, down_deg, rpm, axis, eff in (
        ("4-seam 94 mph", 94, 4.0, 2300, 210, 0.95),
        ("curve 78 mph", 78, -1.0, 2600, 30, 0.7),
        ("slider 85 mph", 85, 2.5, 2450, 260, 0.35),
        ("change 84 mph", 84, 3.0, 1750, 235, 0.9),
        ("seed 63 mph", 63, 1.0, 1600, 180, 1.0),
    ):
        d = np.radians(down_deg)
        v0 = mph * MPH * np.array([0.03, -np.cos(d), -np.sin(d)])
        out.append((name, v0, spin_vector(rpm, axis, v0, eff)))
    return out


def integrator_table(con: Console):
    tab = Table(title="Integrators vs tight reference (RK45 rtol=atol=1e-12); worst over 5 pitches")
    for col in ("model", "integrator", "max |dp| m", "max |dv| m/s", "ms / traj", "speed ratio",
                "ms / traj in batch of 19", "batch speed ratio"):
        tab.add_column(col, justify="right")
    for kind in ("seed", "nathan"):
        model = FlightModel(kind=kind)
        cases = [("RK45 tol 1e-10 (reference)",
                  lambda p, v, w, t: simulate(p, v, w, t, model), False),
                 ("RK45 tol 1e-6",
                  lambda p, v, w, t: simulate(p, v, w, t, model, rtol=1e-6, atol=1e-6), False)]
        for method in ("rk4", "dopri5"):
            for step in (0.01, 0.02, 0.04, 0.08):
                def fast(p, v, w, t, m=method, s=step):
                    return simulate_batch(p, v, w, t, model, method=m, max_step=s)
                cases.append((f"fixed {method} h={step * 1e3:.0f} ms", fast, True))
        ref_ms = None
        for name, fn, batch in cases:
            dp = dv = 0.0
            ms = ms19 = 0.0
            for _, v0, w in pitches():
                t_end = cross_plane(RELEASE, v0, w, model).time
                ts = np.linspace(0.0, t_end, 40)
                tight = simulate(RELEASE, v0, w, ts, model, rtol=1e-12, atol=1e-12)
                out = fn(RELEASE, v0, w, ts)
                pos = out.positions[0] if batch else out.positions
                vel = out.velocities[0] if batch else out.velocities
                dp = max(dp, float(np.abs(pos - tight.positions).max()))
                dv = max(dv, float(np.abs(vel - tight.velocities).max()))
                ms += best_time(lambda: fn(RELEASE, v0, w, ts), repeat=5) * 1e3 / 5
                if batch:
                    P = np.tile(RELEASE, (19, 1))
                    ms19 += best_time(lambda: fn(P, v0, w, ts), repeat=3) * 1e3 / 5 / 19
            if ref_ms is None:
                ref_ms = ms
            tab.add_row(kind, name, f"{dp:.1e}", f"{dv:.1e}", f"{ms:.2f}", f"{ref_ms / ms:.1f}",
                        f"{ms19:.2f}" if batch else "-", f"{ref_ms / ms19:.1f}" if batch else "-")
    con.print(tab)


def fit_table(con: Console, n_fits: int):
    tab = Table(title=f"Reference-trajectory fit, seed-like capture, 2 mm noise ({n_fits} captures)")
    for col in ("model", "method", "time s (mean)", "trajectories (mean)", "max |v0 err| m/s",
                "mean 1-sigma v0 m/s", "max |s_perp err| rad/s", "max |err| / 1-sigma (9 params)",
                "mean err mm", "max err mm"):
        tab.add_column(col, justify="right")
    for kind in ("seed", "nathan"):
        model = FlightModel(kind=kind)
        name, v0, w = pitches()[-1]
        t_plate = cross_plane(RELEASE, v0, w, model).time
        tf = np.arange(0.0, 0.12, 1 / 80)
        tb = np.arange(t_plate - 0.22, t_plate, 1 / 50)
        times = np.concatenate([tf, [0.3], tb])
        truth = simulate(RELEASE, v0, w, times, model).positions
        pri = FitPriors()
        for method in ("least_squares", "powell"):
            rows = []
            for seed in range(n_fits if method == "least_squares" else min(n_fits, 3)):
                rng = np.random.default_rng(seed)
                meas = truth + rng.normal(0, 0.002, truth.shape)
                meas[len(tf)] = np.nan
                p0m = RELEASE + rng.normal(0, pri.position_sigma, 3)
                v0m = v0 + rng.normal(0, pri.velocity_sigma, 3)
                b = spin_basis(v0m)
                wm = w + b @ (rng.normal(0, 1, 3) * [pri.spin_axial_sigma, pri.spin_transverse_sigma,
                                                     pri.spin_transverse_sigma])
                f = fit_reference_trajectory(times, meas, p0m, v0m, wm, model, method=method)
                err = np.concatenate([f.p0 - RELEASE, f.v0 - v0, f.params[6:] - b.T @ w])
                rows.append((f.fit_time_s, f.nfev, np.abs(f.v0 - v0).max(), f.v0_sigma.mean(),
                             np.abs(f.params[7:] - (b.T @ w)[1:]).max(), np.abs(err / f.param_sigma).max(),
                             f.mean_error * 1e3, f.max_error * 1e3))
            r = np.array(rows)
            tab.add_row(kind, method, f"{r[:, 0].mean():.3f}", f"{r[:, 1].mean():.0f}",
                        f"{r[:, 2].max():.4f}", f"{r[:, 3].mean():.4f}", f"{r[:, 4].max():.2f}",
                        f"{r[:, 5].max():.2f}", f"{r[:, 6].mean():.2f}", f"{r[:, 7].max():.2f}")
    con.print(tab)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=int, default=5, help="captures per fit row (Powell: at most 3)")
    args = ap.parse_args(argv)
    con = Console(width=180)
    integrator_table(con)
    fit_table(con, args.fits)


if __name__ == "__main__":
    main()
