"""Free flights of a table-tennis ball on the real tt3d rallies (../shared/data/tt3d-flights).

    python benchmarks/bench_flights.py [--files N] [--ball table-tennis]

Every file is cut into free flights (``stillcap.ball.rally.cut_flights``: bounces, hits, gaps)
and every flight fitted with gravity, drag and Magnus force, the spin fitted: once with the
preset's coefficients and once with the drag coefficient fitted too (``fit_coefficients``).
Printed: the flights cut and the contacts found; the median (and 90th percentile) RMS residual
across the flight direction (goal <= 2 mm), along it (timestamp jitter) and in 3D; the fitted
C_D and C_L (median, quartiles) and the share of flights inside the published ranges
(``BallModel.cd_range``, ``cl_range``; goal: within them). Flights with fewer than 20 points
determine C_D poorly (sigma > 0.1): the coefficient rows are shown for all flights and for
those with at least 20 points.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data" / "tt3d-flights"


def run(files, ball: str):
    from stillcap.ball.physics import ball_model
    from stillcap.ball.rally import cut_flights, fit_flight, read_trajectory_csv

    model = ball_model(ball)
    rows = []
    contacts = Counter()
    for f in files:
        t, p = read_trajectory_csv(f)
        rally = cut_flights(t, p, model.gravity)
        contacts.update(c.kind for c in rally.contacts)
        for a, b in rally.flights:
            fixed = fit_flight(t[a:b], p[a:b], model)
            free = fit_flight(t[a:b], p[a:b], model, fit_coefficients=True)
            rows.append((f.name, b - a, fixed, free))
    return model, rows, contacts


def _q(x):
    x = np.asarray(x, float)
    return np.median(x), np.percentile(x, 25), np.percentile(x, 75), np.percentile(x, 90)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=0, help="only the first N files (0: all)")
    ap.add_argument("--ball", default="table-tennis")
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"real data folder {DATA} is absent (see shared/data/README.md)")
        return 0
    files = sorted(DATA.glob("*.csv"))
    if args.files:
        files = files[:args.files]
    model, rows, contacts = run(files, args.ball)
    con = Console(width=150)
    con.print(f"{len(files)} files, {len(rows)} flights cut; contacts: "
              + ", ".join(f"{k} {v}" for k, v in sorted(contacts.items())))
    t = Table(title="residuals, mm (median / 25% / 75% / 90%)")
    for c in ("fit", "flights", "cross-track RMS", "along-track RMS", "3D RMS"):
        t.add_column(c)
    for label, k in (("preset C_D, spin fitted", 2), ("C_D and spin fitted", 3)):
        fits = [r[k] for r in rows]
        cells = []
        for attr in ("cross_rms", "along_rms", "rms"):
            m, a, b, c = _q([getattr(f, attr) * 1e3 for f in fits])
            cells.append(f"{m:.2f} / {a:.2f} / {b:.2f} / {c:.2f}")
        t.add_row(label, str(len(fits)), *cells)
    con.print(t)
    t = Table(title=f"fitted coefficients ({model.name}: published C_D {model.cd_range[0]}-{model.cd_range[1]}, "
                    f"C_L {model.cl_range[0]}-{model.cl_range[1]})")
    for c in ("flights", "n", "C_D median [IQR]", "C_D sigma (median)", "C_D in range", "C_L median [IQR]",
              "C_L in range", "spin rpm median"):
        t.add_column(c)
    for label, sel in (("all", lambda r: True), (">= 20 points", lambda r: r[1] >= 20)):
        fits = [r[3] for r in rows if sel(r)]
        if not fits:
            continue
        cd = _q([f.cd for f in fits])
        cl = _q([f.cl for f in fits])
        t.add_row(label, str(len(fits)), f"{cd[0]:.3f} [{cd[1]:.3f}, {cd[2]:.3f}]",
                  f"{np.median([f.cd_sigma for f in fits]):.3f}",
                  f"{np.mean([f.cd_in_range for f in fits]):.0%}",
                  f"{cl[0]:.3f} [{cl[1]:.3f}, {cl[2]:.3f}]", f"{np.mean([f.cl_in_range for f in fits]):.0%}",
                  f"{np.median([f.spin_rpm for f in fits]):.0f}")
    con.print(t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
