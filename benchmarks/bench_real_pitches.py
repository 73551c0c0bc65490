"""Pitch metrics against real Statcast, PITCHf/x and Rapsodo files (../shared/data).

Prints, per file, the median and maximum absolute differences between the file's numbers and
stillcap's recomputation (docs/pitch-metrics.md, "Checked on real data").

    PYTHONPATH=src python benchmarks/bench_real_pitches.py
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from stillcap.ball.metrics import rapsodo_spin_break_in
from stillcap.io.pitch_table import read_pitch_table, table_metrics

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def _col(path, name, rows):
    with open(path, newline="", encoding="utf-8-sig") as f:
        body = list(csv.DictReader(f))
    return np.array([float(body[r - 1][name]) if body[r - 1][name] not in ("", "NA") else np.nan for r in rows])


def _line(name, diff, goal):
    d = np.abs(diff[np.isfinite(diff)])
    print(f"| {name:28s} | {np.median(d):9.4f} | {np.percentile(d, 90):9.4f} | {d.max():9.4f} | {goal:>10s} |")


def statcast():
    path = DATA / "statcast" / "statcast-2019-one-pitcher-part.csv"
    tab = read_pitch_table(path)
    m = table_metrics(tab)
    print(f"\nStatcast {path.name}: {len(tab.rows)} pitches")
    print("| quantity                     |    median |       p90 |       max |       goal |")
    print("|---|---|---|---|---|")
    _line("pfx_x (in)", m["pfx_x_in"] - 12 * _col(path, "pfx_x", tab.rows), "0.1")
    _line("pfx_z (in)", m["pfx_z_in"] - 12 * _col(path, "pfx_z", tab.rows), "0.1")
    d = (m["spin_axis_from_movement_deg"] - _col(path, "spin_axis", tab.rows) + 180) % 360 - 180
    _line("spin_axis (deg)", d, "0.5")
    _line("plate_x (ft)", m["plate_x_ft"] - _col(path, "plate_x", tab.rows), "0.01")
    _line("plate_z (ft)", m["plate_z_ft"] - _col(path, "plate_z", tab.rows), "0.01")
    _line("release_speed (mph)", m["release_speed_mph"] - _col(path, "release_speed", tab.rows), "-")
    _line("release_extension (ft)", m["release_extension_ft"] - _col(path, "release_extension", tab.rows), "-")


def pitchfx():
    path = DATA / "pitchfx" / "pitchRx_pitches.csv"
    tab = read_pitch_table(path)
    m = table_metrics(tab)
    print(f"\nPITCHf/x {path.name}: {len(tab.rows)} pitches")
    print("| quantity                     |    median |       p90 |       max |       goal |")
    print("|---|---|---|---|---|")
    _line("pfx_x (in, PITCHf/x)", m["pitchfx_pfx_x_in"] - _col(path, "pfx_x", tab.rows), "0.1")
    _line("pfx_z (in, PITCHf/x)", m["pitchfx_pfx_z_in"] - _col(path, "pfx_z", tab.rows), "0.1")
    _line("px (ft)", m["plate_x_ft"] - _col(path, "px", tab.rows), "0.01")
    _line("pz (ft)", m["plate_z_ft"] - _col(path, "pz", tab.rows), "0.01")
    _line("start_speed (mph)", m["start_speed_mph"] - _col(path, "start_speed", tab.rows), "-")


def read_rapsodo(path):
    """The pitches of a Rapsodo export (five header lines, then a CSV table) with spin and break."""
    lines = Path(path).read_text(encoding="utf-8-sig").splitlines()[4:]
    return [r for r in csv.DictReader(lines) if r["Total Spin"] not in ("", "-") and r["VB (spin)"] not in ("", "-")]


def rapsodo_predictions(rows):
    out = []
    for r in rows:
        out.append(rapsodo_spin_break_in(float(r["Velocity"]), float(r["Release Angle"]), float(r["Horizontal Angle"]),
                                         float(r["Release Height"]), float(r["Release Side"]), float(r["Total Spin"]),
                                         r["Spin Direction"], float(r["Gyro Degree (deg)"])))
    return np.array(out)


def rapsodo():
    path = DATA / "rapsodo" / "rapsodo-2022-04-19-pitcher-a.csv"
    rows = read_rapsodo(path)
    pred = rapsodo_predictions(rows)
    vb = np.array([float(r["VB (spin)"]) for r in rows])
    hb = np.array([float(r["HB (spin)"]) for r in rows])
    print(f"\nRapsodo {path.name}: {len(rows)} pitches; Nathan flight model, 6 ft extension assumed, no fitted constant")
    print("| quantity                     |    median |       p90 |       max |       goal |")
    print("|---|---|---|---|---|")
    _line("VB (spin) (in)", pred[:, 0] - vb, "1.5")
    _line("HB (spin) (in)", pred[:, 1] - hb, "1.5")
    print(f"median ratio predicted / Rapsodo: VB {np.median(pred[:, 0] / vb):.3f}, HB {np.median(pred[:, 1] / hb):.3f}")


if __name__ == "__main__":
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent (see shared/data/README.md)")
    statcast()
    pitchfx()
    rapsodo()
