"""`stillcap flight TRAJ.csv --ball NAME`: cut a tracked rally into free flights and fit each one."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

console = Console()


def _parse_up(text: str):
    parts = [s.strip() for s in str(text).split(",")]
    try:
        up = [float(s) for s in parts]
    except ValueError:
        raise ValueError(f"--up {text!r}: expected three numbers x,y,z (e.g. 0,0,1)") from None
    if len(up) != 3 or not any(up) or not all(abs(u) < float("inf") for u in up):
        raise ValueError(f"--up {text!r}: expected three finite numbers x,y,z, not all 0 (e.g. 0,0,1)")
    return up


def flight(
    traj: Path = typer.Argument(..., help="CSV of t, x, y, z (s, m; header names t/time/timestamp, x, y, z)."),
    ball: str = typer.Option("table-tennis", "--ball", help="Ball preset: baseball, softball, cricket, tennis, "
                             "table-tennis (docs/flight.md)."),
    fit_coefficients: bool = typer.Option(False, "--fit-coefficients", help="Fit the drag coefficient of each "
                                          "flight too (the lift comes with the fitted spin)."),
    up: str = typer.Option("0,0,1", "--up", help="The trajectory frame's up direction x,y,z (gravity is "
                           "9.80665 m/s^2 against it)."),
    as_json: bool = typer.Option(False, "--json", help="Print the flights as JSON."),
    out: Path = typer.Option(None, "--out", help="Write the flights as JSON to this file."),
    force: bool = typer.Option(False, "--force", help="Overwrite --out if it exists."),
):
    """Cut a rally into free flights at bounces and hits and fit gravity, drag and Magnus force.

    Prints one row per flight: duration, points, speed, fitted spin, RMS residual and the RMS
    across the flight direction in mm, and the drag and lift coefficients (docs/flight.md).
    """
    import numpy as np

    from stillcap._numeric import RPM_PER_RAD_S
    from stillcap.ball.physics import G0, ball_model
    from stillcap.ball.rally import cut_flights, fit_flight, read_trajectory_csv
    from stillcap.cli._outputs import check

    u = np.asarray(_parse_up(up), float)
    model = ball_model(ball, gravity=tuple(-G0 * u / np.linalg.norm(u)))
    check(out, "file", "--out", force)
    if not traj.is_file():
        raise ValueError(f"{traj}: no such trajectory file")
    t, p = read_trajectory_csv(traj)
    rally = cut_flights(t, p, model.gravity)
    if not rally.flights:
        raise ValueError(f"{traj}: no free flight of at least 10 points found ({len(t)} positions, "
                         f"{len(rally.contacts)} contacts)")
    fits = [fit_flight(t[a:b], p[a:b], model, fit_coefficients=fit_coefficients) for a, b in rally.flights]
    result = {
        "file": str(traj), "ball": model.name, "fit_coefficients": fit_coefficients,
        "up": [float(x) for x in u / np.linalg.norm(u)],
        "published_cd_range": list(model.cd_range), "published_cl_range": list(model.cl_range),
        "contacts": [{"index": c.index, "time": c.time, "kind": c.kind,
                      "velocity_jump_m_s": None if np.isnan(c.velocity_jump) else c.velocity_jump}
                     for c in rally.contacts],
        "flights": [dict(first_row=int(a), last_row=int(b - 1), **f.summary())
                    for (a, b), f in zip(rally.flights, fits)],
    }
    text = json.dumps(result, indent=2)
    if out is not None:
        from stillcap.cli._outputs import Outputs

        outputs = Outputs(lambda: text, "flight.json")
        with outputs.writing(f"--out {out}"):
            out.write_text(text + "\n")
        outputs.finish()
    if as_json:
        print(text)
        return
    tab = Table(title=f"{traj.name}: {len(fits)} flights ({model.name}; contacts: "
                      + (", ".join(f"{c.kind} at {c.time:.3f} s" for c in rally.contacts) or "none") + ")")
    for c in ("#", "t start s", "duration s", "points", "speed m/s", "spin rpm", "RMS mm", "cross-track mm",
              "C_D", "C_L"):
        tab.add_column(c, justify="right")
    for k, f in enumerate(fits, 1):
        cd = f"{f.cd:.3f} ± {f.cd_sigma:.3f}" if fit_coefficients else f"{f.cd:.3f}"
        tab.add_row(str(k), f"{f.times[0]:.3f}", f"{f.duration:.3f}", str(len(f.times)), f"{f.speed:.2f}",
                    f"{f.spin_rpm:.0f} ± {f.spin_sigma * RPM_PER_RAD_S:.0f}", f"{f.rms * 1e3:.2f}",
                    f"{f.cross_rms * 1e3:.2f}", cd + ("" if f.cd_in_range else " !"),
                    f"{f.cl:.3f} ± {f.cl_sigma:.3f}" + ("" if f.cl_in_range else " !"))
    console.print(tab)
    console.print(f"published ranges: C_D {model.cd_range[0]}-{model.cd_range[1]}, "
                  f"C_L {model.cl_range[0]}-{model.cl_range[1]} (! outside)")
