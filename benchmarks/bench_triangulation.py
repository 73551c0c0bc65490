"""Triangulation speed (points per second) and 3D accuracy vs pixel noise.

    python benchmarks/bench_triangulation.py [--points 1000000]

Four cameras on a 3 m circle (1280x960, f = 1100 px) look at a 1 m cube of points. Speed is
measured for the linear solve alone and with refinement / outlier rejection, with and without
lens distortion (undistorting the pixels is part of the work when the lens distorts).
Goal: >= 1e6 points/s for 4 views.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support import ring_rig  # noqa: E402

from stillcap.geometry.triangulate import triangulate  # noqa: E402

from _timing import best_time

GOAL = 1e6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    args = ap.parse_args(argv)
    con = Console()
    rng = np.random.default_rng(0)
    n = args.points

    speed = Table(title=f"Triangulation speed, 4 views, {n:,} points (best of 3)")
    for col in ("lens", "method", "refine", "outliers", "time s", "points/s", "ratio to goal 1e6/s"):
        speed.add_column(col, justify="right")
    for lens, dist in (("pinhole", (0, 0, 0, 0, 0)), ("distorted", (-0.12, 0.05, 0.001, -0.0005, 0))):
        rig = ring_rig(4, dist=dist)
        X = rng.uniform(-0.5, 0.5, (n, 3))
        x = rig.project(X) + rng.normal(0, 0.5, (4, n, 2))
        cases = [("dlt", False, None), ("midpoint", False, None), ("dlt", True, None)]
        if lens == "pinhole":
            cases.append(("dlt", True, 3.0))
        for method, refine, out in cases:
            m = n if out is None else n // 10  # RANSAC over 6 pairs: measured on a tenth
            t = best_time(lambda: triangulate(rig, x[:, :m], method=method, refine=refine, outlier_px=out),
                          repeat=3 if out is None else 1)
            speed.add_row(lens, method, str(refine), "-" if out is None else f"{out} px", f"{t:.3f}",
                          f"{m / t:,.0f}", f"{m / t / GOAL:.2f}")
    con.print(speed)

    acc = Table(title="3D error vs pixel noise (4 views, 20,000 points, DLT + refinement)")
    for col in ("noise px", "RMS mm", "max mm", "reproj RMS px"):
        acc.add_column(col, justify="right")
    rig = ring_rig(4, dist=(-0.12, 0.05, 0.001, -0.0005, 0))
    X = rng.uniform(-0.5, 0.5, (20_000, 3))
    for sigma in (0.0, 0.1, 0.25, 0.5, 1.0, 2.0):
        x = rig.project(X) + rng.normal(0, sigma, (4, len(X), 2))
        tri = triangulate(rig, x)
        e = np.linalg.norm(tri.points - X, axis=1) * 1e3
        acc.add_row(f"{sigma:.2f}", f"{np.sqrt(np.mean(e**2)):.4f}", f"{e.max():.4f}",
                    f"{np.mean(tri.reproj_error_px):.3f}")
    con.print(acc)


if __name__ == "__main__":
    main()
