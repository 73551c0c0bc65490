"""Spin rate and axis per condition of the robustness benchmark, for chosen conditions only.

    python benchmarks/bench_spin_conditions.py [--conditions "blur 1.5 px,clean"] [--n 6] [--full]
                                               [--seed 0] [--jobs 2] [--jsonl FILE]

The same captures as ``bench_robustness.py --only pitch`` (``_robust_pitch.run``: same seeds,
so ``--n 6`` repeats its quick rows), one line per condition: mean absolute rate and axis
errors, the 95 % intervals' coverage, and the z-scores behind them (rate error over its sigma:
mean and spread; axis angle over its sigma: RMS over the two axis components, expected 1), the
fitted marker-centroid noise (px, median) and how many captures the ``spin_noise`` self-check
failed; a last line pools the conditions (z over captures whose alias is right). ``--full``
renders 2560x1920 photos instead of 1280x960.

``--decompose`` analyses every capture three times: as is, with ``shading_model_error=0`` (no
stated wrong share of the shading correction) and with ``center_bias_px=0`` (no shared
ball-centre error at all), and prints per condition and quantity (speed, direction, spin rate,
spin axis) the RMS sigma and how its variance splits into the random part (the fits' own
residuals, clocks), the shading model's own error (``shading_residual_lookup``) and the stated
share. Timings on a loaded machine are not the benchmark's: run it on a quiet one for those.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import _robust_pitch as rp  # noqa: E402


def summary(condition: str, rows: list) -> str:
    ok = [r for r in rows if r.get("ok") and r.get("rate_rpm") is not None]
    if not ok:
        return f"{condition:20s} n {len(rows):3d}  no spin"
    rate = np.array([r["rate_rpm"] for r in ok])
    axis = np.array([r["axis_deg"] for r in ok])
    s_r = np.array([r.get("rate_sigma_rpm") or np.nan for r in ok])
    s_a = np.array([r.get("axis_sigma_deg") or np.nan for r in ok])
    z_r = rate / s_r
    z_a = axis / s_a / math.sqrt(2.0)  # angle^2 / sigma^2 ~ chi2(2): RMS of z per component ~ 1
    cov_r = np.mean([r["coverage"].get("spin_rate", False) for r in ok])
    cov_a = np.mean([r["coverage"].get("spin_axis", False) for r in ok])
    noise = [r.get("marker_noise_px") for r in ok if r.get("marker_noise_px") is not None]
    fired = sum("spin_noise" in r.get("checks_failed", []) for r in ok)
    wrong = sum(not r.get("alias_ok", True) for r in ok)
    right = np.array([rp.alias_right(r) for r in ok])
    zr_right, za_right = z_r[right], z_a[right]
    return (f"{condition:20s} n {len(ok):3d}  rate {np.mean(np.abs(rate)):6.2f} rpm (median {np.median(np.abs(rate)):5.2f})"
            f"  axis {np.mean(axis):5.2f} deg  cov rate {100 * cov_r:3.0f} %  axis {100 * cov_a:3.0f} %"
            f"  z rate mean {np.nanmean(z_r):+5.2f} sd {np.nanstd(z_r):4.2f}  z axis rms {np.sqrt(np.nanmean(z_a ** 2)):4.2f}"
            f"  noise {np.median(noise) if noise else float('nan'):4.2f} px  spin_noise fired {fired}"
            f"  wrong alias {wrong}  (right aliases: z rate rms {np.sqrt(np.nanmean(zr_right ** 2)):4.2f}"
            f" axis rms {np.sqrt(np.nanmean(za_right ** 2)):4.2f})")


#: (label, row key, component of a 2-vector or None)
DECOMPOSE = (("speed", "speed_sigma_mph", None), ("dir h", "dir_sigma_hv_deg", 0), ("dir v", "dir_sigma_hv_deg", 1),
             ("rate", "rate_sigma_rpm", None), ("axis", "axis_sigma_deg", None))
VARIANTS = {"no share": {"shading_model_error": 0.0}, "no centre bias": {"center_bias_px": 0.0}}


def decomposition(condition: str, rows: list) -> str:
    """The variance of each quantity's sigma split into its terms, mean over the captures:
    ``random`` (no shared centre error), ``model`` (the shading model's own error: no share
    minus random) and ``share`` (the stated share: as is minus no share), in % of the whole.
    Spin rate and axis leave out wrong aliases and ambiguous ones (sigma above 20 rpm: the
    interval spans the aliases)."""
    ok = [r for r in rows if r.get("ok") and r.get("variants")]
    cells = []
    for label, key, i in DECOMPOSE:
        v = []
        for r in ok:
            if key in ("rate_sigma_rpm", "axis_sigma_deg") and (not rp.alias_right(r)
                                                                or (r.get("rate_sigma_rpm") or 0.0) > 20.0):
                continue  # a wrong alias, or an ambiguous one whose sigma spans the aliases
            s = [r.get(key), r["variants"]["no share"].get(key), r["variants"]["no centre bias"].get(key)]
            if i is not None:
                s = [x[i] if x is not None else None for x in s]
            if all(x is not None and np.isfinite(x) for x in s):
                v.append([x * x for x in s])
        if not v:
            cells.append(f"{label} -")
            continue
        a, b, c = np.mean(v, axis=0)
        parts = 100 * np.array([c, max(b - c, 0.0), max(a - b, 0.0)]) / a
        cells.append(f"{label} {np.sqrt(a):.3g} ({parts[0]:.0f}/{parts[1]:.0f}/{parts[2]:.0f})")
    return f"{condition:20s} n {len(ok):3d}  " + "  ".join(cells)


def pooled(rows: list) -> str:
    """z RMS and coverage of rate and axis over every condition's captures whose alias is right."""
    ok = [r for r in rows if r.get("ok") and r.get("rate_rpm") is not None and rp.alias_right(r)]
    if not ok:
        return "pooled: no spin"
    z_r = np.array([r["rate_rpm"] / (r.get("rate_sigma_rpm") or np.nan) for r in ok])
    z_a = np.array([r["axis_deg"] / (r.get("axis_sigma_deg") or np.nan) / math.sqrt(2.0) for r in ok])
    cov_r = np.mean([r["coverage"].get("spin_rate", False) for r in ok])
    cov_a = np.mean([r["coverage"].get("spin_axis", False) for r in ok])
    return (f"{'pooled (right alias)':20s} n {len(ok):3d}  cov rate {100 * cov_r:3.0f} %  axis {100 * cov_a:3.0f} %"
            f"  z rate rms {np.sqrt(np.nanmean(z_r ** 2)):4.2f}  z axis rms {np.sqrt(np.nanmean(z_a ** 2)):4.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conditions", default="blur 1.5 px,everything varied,clean")
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--full", action="store_true", help="2560x1920 photos (default 1280x960, as --quick)")
    ap.add_argument("--jsonl", type=Path, default=None)
    ap.add_argument("--decompose", action="store_true",
                    help="analyse each capture 3 times and split each sigma's variance into its terms")
    args = ap.parse_args(argv)
    conds = [c.strip() for c in args.conditions.split(",") if c.strip()]
    unknown = [c for c in conds if c not in rp.CONDITIONS]
    if unknown:
        raise SystemExit(f"unknown conditions {unknown}; known: {list(rp.CONDITIONS)}")
    size = (2560, 1920) if args.full else (1280, 960)
    rows = rp.run(conds, args.n, args.seed, size, args.jobs, variants=VARIANTS if args.decompose else None)
    if args.jsonl is not None:
        with open(args.jsonl, "w") as f:
            for r in rows:
                f.write(json.dumps(r, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)) + "\n")
    for c in conds:
        print(summary(c, [r for r in rows if r["condition"] == c]))
    print(pooled(rows))
    if args.decompose:
        print("\nsigma (RMS over the captures) and its variance in % random / shading model / stated share")
        for c in conds:
            print(decomposition(c, [r for r in rows if r["condition"] == c]))


if __name__ == "__main__":
    main()
