"""`stillcap metrics TABLE.csv`: every pitch metric of a Statcast or PITCHf/x export, recomputed
from each pitch's 9-parameter fit (docs/pitch-metrics.md)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console

console = Console()


def metrics(
    table: Path = typer.Argument(..., help="A Statcast (Baseball Savant) or PITCHf/x CSV export."),
    out: Path = typer.Option(None, "--out", help="Write the recomputed metrics as CSV (Statcast's column names "
                             "where the meaning is the same, the rest with units in the names)."),
    as_json: bool = typer.Option(False, "--json", help="Print the metrics as JSON (one record per pitch)."),
    force: bool = typer.Option(False, "--force", help="Overwrite --out even if stillcap did not write it."),
):
    """Recompute every pitch metric of a Statcast or PITCHf/x table from its 9-parameter fits.

    The kind of table is recognised by its columns; a Statcast export's missing x0, z0 are
    rebuilt by carrying release_pos_x/y/z along the fit. Movement follows Statcast (spin alone,
    release to plate) and PITCHf/x (the last 40 ft) under their own names.
    """
    import numpy as np

    from stillcap.cli._outputs import Outputs, check
    from stillcap.cli._progress import progress
    from stillcap.io.pitch_table import (
        read_pitch_table,
        table_metrics,
        write_metrics_csv,
    )

    if not table.is_file():
        raise ValueError(f"{table}: no such file (a Statcast or PITCHf/x CSV export)")
    check(out, "file", "--out", force)
    with progress(f"reading {table.name}") as update:
        tab = read_pitch_table(table, progress=lambda i, n: update(i, n))
    vals = table_metrics(tab)
    records = []
    for i in range(len(tab.nine)):
        rec = {"row": tab.rows[i], **tab.ids[i]}
        rec.update({k: (float(v[i]) if np.isfinite(v[i]) else None) for k, v in vals.items()})
        records.append(rec)
    result = {"file": str(table), "kind": tab.kind, "n_pitches": len(records), "pitches": records}
    text = lambda: json.dumps(result, indent=1, allow_nan=False)
    outputs = Outputs(text, "metrics.json")
    if out is not None:
        with outputs.writing(f"--out {out}"):
            outputs.record([write_metrics_csv(tab, vals, out)])
    if as_json:
        print(text())
    else:
        med = {k: float(np.nanmedian(v)) if np.any(np.isfinite(v)) else float("nan") for k, v in vals.items()}
        console.print(f"{table}: {len(records)} pitches ({tab.kind} export); medians:")
        for k in ("release_speed_mph", "start_speed_mph", "pfx_x_in", "pfx_z_in", "spin_axis_from_movement_deg",
                  "pitchfx_pfx_x_in", "pitchfx_pfx_z_in", "vertical_approach_angle_deg", "plate_time_s"):
            if k in med:
                console.print(f"  {k:32s} {med[k]:9.3f}")
        if out is not None and not outputs.failed:
            console.print(f"metrics in [bold]{out}[/]")
    outputs.finish(printed_json=as_json)

