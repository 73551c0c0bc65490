"""Spin and position accuracy of studio pitches of differently painted balls, analysed through the
CLI with and without their ball file (issue 12, "A ball file").

For each ball (the seed's baseball; a repainted baseball: polar markers at other azimuths,
colours assigned to other markers, radius 36.6 mm; the built-in softball, cricket and tennis
balls) N pitches are rendered by ``stillcap studio pitch --ball`` (true rig, so calibration
error is out) and analysed by ``stillcap pitch`` twice: with the capture's ball (capture.json
``ball``) and with ``--ball baseball`` (the wrong layout, radius and flight for every ball but the
baseball). Prints mean spin-axis error (deg), mean |spin-rate error| (rpm), mean position error
(mm) and how often the ``ball_layout`` self-check failed.

    PYTHONPATH=src python benchmarks/bench_ball_layouts.py [N] [--size 1280x960] [--out DIR]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPAINTED = HERE.parent / "tests" / "data" / "repainted-baseball.json"
BALLS = [("baseball", "baseball"), ("repainted", str(REPAINTED)), ("softball", "softball"), ("cricket", "cricket"),
         ("tennis", "tennis")]


def _run(args):
    p = subprocess.run([sys.executable, "-m", "stillcap", *args], capture_output=True, text=True,
                       env=dict(os.environ, COLUMNS="200"))
    if p.returncode != 0:
        raise RuntimeError(f"stillcap {' '.join(args)}: {p.stderr.strip()[-400:]}")
    return p.stdout


def _errors(out: str) -> tuple:
    d = json.loads(out)
    t = d.get("truth_comparison") or {}
    checks = {c["name"]: c for c in d.get("self_checks", [])}
    lay = checks.get("ball_layout")
    return (t.get("spin_axis_angle_deg"), t.get("spin_rate_diff_rpm"), t.get("mean_err_mm"),
            None if lay is None else (not lay["passed"]), None if lay is None else lay["value"])


def main(argv):
    n = int(argv[0]) if argv and argv[0].isdigit() else 3
    size = argv[argv.index("--size") + 1] if "--size" in argv else "1280x960"
    root = Path(argv[argv.index("--out") + 1]) if "--out" in argv else Path(tempfile.mkdtemp(prefix="bench-balls-"))
    rows = []
    for label, spec in BALLS:
        for seed in range(n):
            cap = root / f"{label}-{seed}"
            if not (cap / "capture.json").is_file():
                _run(["studio", "pitch", "--out", str(cap), "--seed", str(100 + seed), "--ball", spec,
                      "--no-calibrate", "--size", size, "--force"])
            right = _errors(_run(["pitch", str(cap), "--json"]))
            wrong = _errors(_run(["pitch", str(cap), "--json", "--ball", "baseball"]))
            rows.append((label, seed, right, wrong))
            print(label, seed, "right", right, "wrong", wrong, flush=True)

    def mean(vals):
        vals = [abs(v) for v in vals if v is not None]
        return sum(vals) / len(vals) if vals else float("nan")
    print(f"\n{n} pitches per ball, {size}, true rig; with the ball file | with --ball baseball")
    print(f"{'ball':<10} {'axis deg':>9} {'rate rpm':>9} {'pos mm':>7} {'check fails':>11} {'rms deg':>8} |"
          f" {'axis deg':>9} {'rate rpm':>9} {'pos mm':>7} {'check fails':>11} {'rms deg':>8}")
    for label, _ in BALLS:
        rs = [r for r in rows if r[0] == label]
        cells = []
        for k in (2, 3):
            e = [r[k] for r in rs]
            fails = sum(1 for x in e if x[3])
            cells.append(f"{mean([x[0] for x in e]):9.3f} {mean([x[1] for x in e]):9.2f} {mean([x[2] for x in e]):7.2f}"
                         f" {fails:>6}/{len(e):<4} {mean([x[4] for x in e]):8.2f}")
        print(f"{label:<10} {cells[0]} | {cells[1]}")
    print(f"captures in {root}")


if __name__ == "__main__":
    main(sys.argv[1:])
