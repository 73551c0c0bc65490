"""`stillcap pitch CAPTURE_DIR`: ball flight, spin and pitch metrics from strobe photos (SPEC J1)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from stillcap.cli._format import num as _f

console = Console()

SPIN_CHOICES = ("global", "seed")
PHYSICS_CHOICES = ("seed", "nathan")
FIT_CHOICES = ("least-squares", "powell")


def _choice(name: str, value: str, allowed) -> str:
    if value not in allowed:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(allowed)}", param_hint=name)
    return value


def pitch(
    capture: Path = typer.Argument(..., help="Pitch capture folder (capture.json, rig.json, images/)."),
    as_json: bool = typer.Option(False, "--json",
                                 help="Print the result as JSON (keys as in truth.json, docs/pitch.md)."),
    report: Path = typer.Option(None, "--report", help="Write report.html, pitch.json, positions.csv, metrics.csv "
                                "and plots to this folder."),
    csv_file: Path = typer.Option(None, "--csv", help="Write the per-flash ball positions as CSV to this file."),
    spin: str = typer.Option("global", "--spin", help="Spin method: global (one constant spin fitted to all "
                             "flashes) or seed (the seed's per-flash Powell method)."),
    physics: str = typer.Option("seed", "--physics", help="Flight model: seed or nathan."),
    fit: str = typer.Option("least-squares", "--fit", help="Reference-trajectory optimiser: least-squares or "
                            "powell (the seed's)."),
    release_y_ft: float = typer.Option(None, "--release-y-ft", help="Evaluate release at this field y (ft); "
                                       "default: at the front pair's first ball image."),
    expected_speed_mph: float = typer.Option(None, "--expected-speed-mph", help="Anchor the flash spacing "
                                             "(only needed when a pair missed every other flash)."),
):
    """Ball positions, release velocity, spin, reference trajectory and pitch metrics of a capture.

    The capture holds one multi-exposure photo per camera of one or more strobed stereo pairs
    (each photo with its strobe_hz). Every number is reported with its 1-sigma uncertainty.
    Exit status 2 with a one-line message for captures that cannot give a flight.
    """
    from stillcap.pipelines.pitch import TABLE1_COLUMNS, PitchOptions, analyse_pitch

    _choice("--spin", spin, SPIN_CHOICES)
    _choice("--physics", physics, PHYSICS_CHOICES)
    _choice("--fit", fit, FIT_CHOICES)
    opts = PitchOptions(spin_method=spin, physics=physics, fit_method=fit.replace("-", "_"),
                        release_y_ft=release_y_ft, expected_speed_mph=expected_speed_mph)
    res = analyse_pitch(capture, opts)
    written = []
    if csv_file is not None:
        from stillcap.report.pitch import write_positions_csv
        written.append(write_positions_csv(res, csv_file))
    if report is not None:
        from stillcap.report.pitch import write_report
        written.append(write_report(res, report)["html"])
    if as_json:
        print(json.dumps(res.to_dict(), indent=1, allow_nan=False))
        return
    err = Console(stderr=True)
    for m in res.messages:
        err.print(f"[yellow]note:[/] {m}", highlight=False, soft_wrap=True)
    t = Table(title=f"{len(res.times)} ball positions from {len(res.pairs)} stereo pair(s) ({res.frame} frame)")
    for c in ("pair", "strobe Hz", "images", "clock offset s", "position sigma mm", "markers 3D / 1 cam"):
        t.add_column(c, justify="right")
    for p in res.pairs:
        offset = f"{p.time_offset_s:.5f} ± {p.time_offset_sigma_s * 1e3:.3f} ms"
        t.add_row(p.name, _f(p.strobe_hz, 0), str(len(p)), offset, _f(p.position_sigma_m * 1e3, 2),
                  f"{p.n_markers_3d} / {p.n_markers_ray}")
    console.print(t)
    m = res.metrics.to_dict()
    s = res.metrics_sigma
    mt = Table(title=f"Pitch metrics (release {res.release['where']}; ± 1 sigma)")
    for c in ("metric", "value", "± sigma"):
        mt.add_column(c, justify="right")
    for k, v in m.items():
        if k in ("nine_parameter", "success", "message"):
            continue
        mt.add_row(k, v if isinstance(v, str) else _f(v, 3), _f(s.get(k), 3))
    console.print(mt)
    t1 = Table(title="Seed Table 1: reference trajectory vs measured initial parameters")
    t1.add_column("column")
    t1.add_column("value", justify="right")
    for c, unit in TABLE1_COLUMNS:
        t1.add_row(c, _f(res.table1.get(c), 3))
    console.print(t1)
    if res.spin_available:
        console.print(f"spin ({res.spin.method}): {res.release['spin_rpm']:.1f} ± {res.spin.sigma_rpm:.1f} rpm, axis "
                      f"± {res.spin.sigma_axis_deg:.2f} deg; {res.metrics.spin_tilt or '-'}"
                      + (f"; alias: {res.alias.message}" if res.alias is not None else ""), highlight=False)
    else:
        console.print("spin: unavailable (see notes)")
    for w in written:
        console.print(f"wrote [bold]{w}[/]")
