"""Spin from ball markers: the seed's per-flash method against the global constant-spin fit.

    python benchmarks/bench_spin.py [--seeds 20] [--rates 1200 1600 2400 3000] [--noise 1.0]

Each capture: a random pitch-like spin (Statcast axis uniform, efficiency 0.5-1) at the given
rate, a random ball orientation, the front stereo pair at 80 Hz (6-10 flashes right after
release, markers within 80 deg of the pair's direction, direction noise ``--noise`` deg per
component, 10 % of markers missed, 3 % mis-typed, two flashes with 0-1 markers) and the back
pair at 50 Hz (7 flashes 0.33 s later, half-moon lighting: markers within 70 deg, 1.5x noise).
The flight (seed model, 2 mm position noise on both pairs) gives the curvature through a
reference fit without a spin prior.

Methods, each fitted to both pairs: ``seed`` (the seed's energy, no outlier cap), ``seed+cap``
(``cap_deg=8``), ``global`` (robust constant-spin fit). Aliases are resolved with the two
strobe rates and the curvature (:func:`stillcap.ball.alias.resolve_aliases`). Columns: rate
error |rpm| and axis error deg (median / mean / max) of the front pair's alias nearest the
truth (the estimation accuracy), coverage of the 95 % intervals (rate: 1.96 sigma; axis: 2.45
sigma per component), gross failures (rate error > 30 rpm or axis error > 3 deg), alias
resolution with 80+50 Hz, with 80 Hz + curvature and with all three, as % right / flagged
ambiguous / confidently wrong, captures where the front fit failed, fit time per pair (ms).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial.transform import Rotation

from stillcap.ball.alias import (CurvatureMeasurement, StrobeMeasurement, alias_candidates,
                                 resolve_aliases)
from stillcap.ball.fit import fit_reference_trajectory
from stillcap.ball.metrics import FT, MPH, spin_vector
from stillcap.ball.orientation import fit_spin, fit_spin_seed, simulate_observations
from stillcap.ball.physics import FlightModel, simulate

P0 = np.array([-0.6, 54.5 * FT, 1.8])
V0 = 85 * MPH * np.array([0.03, -np.cos(np.radians(2)), -np.sin(np.radians(2))])
FRONT_VIEW = np.array([1.0, 0.2, 0.1])
BACK_VIEW = np.array([0.5, 1.0, 0.6])
METHODS = {
    "seed": lambda t, o: fit_spin_seed(t, o),
    "seed+cap": lambda t, o: fit_spin_seed(t, o, cap_deg=8.0),
    "global": lambda t, o: fit_spin(t, o),
}


def capture(seed, rpm, noise_deg):
    rng = np.random.default_rng(seed)
    w = spin_vector(rpm, rng.uniform(0, 360), V0, rng.uniform(0.5, 1.0), rng.choice([-1.0, 1.0]))
    R0 = Rotation.random(random_state=rng).as_matrix()
    k = int(rng.integers(6, 11))
    t_front = np.arange(k) / 80.0
    t_back = 0.33 + np.arange(7) / 50.0
    caps = np.full(k, 99)
    caps[rng.choice(np.arange(1, k), 2, replace=False)] = rng.integers(0, 2, size=2)
    front = simulate_observations(t_front, R0, w, FRONT_VIEW + rng.normal(scale=0.1, size=3),
                                  t0=0.0, noise_deg=noise_deg, miss_rate=0.1, mistype_rate=0.03,
                                  max_per_flash=caps, rng=rng)
    back = simulate_observations(t_back, R0, w, BACK_VIEW + rng.normal(scale=0.1, size=3), t0=0.0,
                                 noise_deg=1.5 * noise_deg, margin_deg=20.0, miss_rate=0.1,
                                 mistype_rate=0.03, rng=rng)
    model = FlightModel()
    times = np.concatenate([t_front, t_back])
    pos = simulate(P0, V0, w, times, model).positions + rng.normal(scale=0.002, size=(len(times), 3))
    fit = fit_reference_trajectory(times, pos, pos[0], (pos[1] - pos[0]) * 80.0, None, model)
    curv = CurvatureMeasurement.from_reference_fit(fit, model) if fit.success else None
    return w, (t_front, front), (t_back, back), curv


def angle_deg(a, b):
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))


def score(w, front_res, back_res, curv):
    """Errors of the front pair's alias nearest the truth (estimation accuracy), and the
    alias-resolution outcome per evidence: "ok" (right and not flagged), "ambiguous" (flagged),
    "wrong" (a wrong alias, not flagged)."""
    out = {}
    try:
        m80 = StrobeMeasurement.from_result(front_res, "80 Hz")
    except ValueError:
        return None
    try:
        m50 = StrobeMeasurement.from_result(back_res, "50 Hz")
    except ValueError:
        m50 = None
    rate_true = np.linalg.norm(w) * 60 / (2 * np.pi)

    def outcome(res):
        right = abs(res.best.spin_rpm - rate_true) < 50 and angle_deg(res.best.spin, w) < 5
        return "ambiguous" if res.ambiguous else ("ok" if right else "wrong")

    combos = {"80+50": ([m80, m50], None), "80+curv": ([m80], curv), "all": ([m80, m50], curv)}
    for name, (ms, c) in combos.items():
        ms = [m for m in ms if m is not None]  # a failed back fit leaves the front alone
        out[name] = outcome(resolve_aliases(ms, c))
    cands = alias_candidates(m80.spin, 80.0, max_rpm=6000)
    pick = min(cands, key=lambda c: np.linalg.norm(c.spin - w))
    out["rate_err"] = abs(pick.spin_rpm - rate_true)
    out["axis_err"] = angle_deg(pick.spin, w)
    out["rate_cov"] = out["rate_err"] < 1.96 * front_res.sigma_rpm
    out["axis_cov"] = out["axis_err"] < 2.448 * front_res.sigma_axis_deg
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--rates", type=float, nargs="+", default=[1200, 1600, 2400, 3000])
    ap.add_argument("--noise", type=float, default=1.0, help="deg per component")
    args = ap.parse_args()
    console = Console(width=180)
    tab = Table(title=f"Spin from markers, {args.seeds} captures per rate, noise {args.noise:g} deg "
                      f"per component (RMS {args.noise * 2 ** 0.5:.2g} deg)")
    for col in ("rpm", "method", "rate err med/mean/max rpm", "axis err med/mean/max deg",
                "95% cover rate/axis", "gross", "alias 80+50 ok/amb/wrong", "80+curv",
                "all three", "failed", "ms/pair"):
        tab.add_column(col, justify="right")
    for rpm in args.rates:
        caps = [capture(1000 * int(rpm) + s, rpm, args.noise) for s in range(args.seeds)]
        for name, fn in METHODS.items():
            rows, times_ms, failed = [], [], 0
            for w, (tf, of), (tb, ob), curv in caps:
                t = time.perf_counter()
                rf = fn(tf, of)
                times_ms.append((time.perf_counter() - t) * 1e3)
                rb = fn(tb, ob)
                r = score(w, rf, rb, curv) if rf.success else None
                if r is None:
                    failed += 1
                else:
                    rows.append(r)
            if not rows:
                tab.add_row(f"{rpm:g}", name, *["-"] * 7, f"{failed}", f"{np.mean(times_ms):.0f}")
                continue
            re = np.array([r["rate_err"] for r in rows])
            ae = np.array([r["axis_err"] for r in rows])

            def pct(key):
                return f"{100 * np.mean([r[key] for r in rows]):.0f}%"

            def alias(key):
                return " / ".join(f"{100 * np.mean([r[key] == o for r in rows]):.0f}"
                                  for o in ("ok", "ambiguous", "wrong"))
            tab.add_row(f"{rpm:g}", name, f"{np.median(re):.1f} / {re.mean():.1f} / {re.max():.1f}",
                        f"{np.median(ae):.2f} / {ae.mean():.2f} / {ae.max():.2f}",
                        f"{pct('rate_cov')} / {pct('axis_cov')}",
                        f"{100 * np.mean((re > 30) | (ae > 3)):.0f}%", alias("80+50"), alias("80+curv"), alias("all"), f"{failed}",
                        f"{np.mean(times_ms):.0f}")
        tab.add_section()
    console.print(tab)


if __name__ == "__main__":
    main()
