"""Spin from the flight alone (stillcap.ball.spin_from_flight), measured.

1. Simulated pitches (seed and Nathan models, 0.36 s at 200 Hz, noise at the pitch pipeline's
   position sigma 2 mm per coordinate): rate and axis error of the transverse spin against the
   truth, and how often the 95 % intervals (rate and axis) cover it.
2. A studio pitch (seed-4seam, seed 0, 2560x1920 through the true rig, rendered here): the
   pipeline's flight spin against the truth and the marker spin.
3. The real table-tennis flights in ../shared/data/tt3d-flights: one free flight cut per file
   (breaks where the 3-sample velocity jumps by more than 1.5 m/s, or the ball is within 3 cm of
   the table, z < 0.03 m; 3 samples dropped beside each break; the longest run of >= 12), the
   drag + lift fit with the spin fitted: RMS and cross-track residuals (mm) and the fitted spins.

Table-tennis coefficients (defined here; the same as the ``table-tennis`` ball preset being added
to ball/physics): 2.7 g, 40 mm (ITTF Handbook 2.3); C_D = 0.50 (flight experiments, 3e4 < Re <
9e4, "Lift crisis of a spinning table tennis ball", Eur. J. Phys. 2020; range 0.40-0.60);
C_L = 1.3 S / (1 + 1.9 S), S = r w_perp / |v| (saturating near 0.4 as those measurements).

Usage: python benchmarks/bench_spin_from_flight.py [--flights 50]
"""

from __future__ import annotations

import argparse
import glob
import json
import tempfile
from pathlib import Path

import numpy as np

from stillcap.ball.physics import RPM_PER_RAD_S, BallProperties, FlightModel, NathanCoefficients, simulate
from stillcap.ball.spin_from_flight import spin_from_flight

ROOT = Path(__file__).resolve().parents[1]
TT3D = ROOT.parent / "shared" / "data" / "tt3d-flights"
TABLE_TENNIS = FlightModel(kind="nathan", ball=BallProperties(mass=0.0027, diameter=0.040),
                           nathan=NathanCoefficients(cd0=0.50, cdspin=0.0, cl0=1.0, cl1=1.9, cl2=1.3, tau0=1e9))


def simulated(kind: str, n: int) -> dict:
    model = FlightModel(kind=kind)
    dr, da, cov = [], [], 0
    for seed in range(n):
        r = np.random.default_rng(seed)
        v0 = np.array([r.normal(0, 1), -38 + r.normal(0, 1), r.normal(-1, 0.5)])
        w = r.normal(0, 1, 3)
        w = w / np.linalg.norm(w) * r.uniform(150, 280)
        t = np.arange(0, 0.36, 1 / 200)
        pos = simulate(np.array([0, 16, 1.8]), v0, w, t, model).positions + r.normal(0, 0.002, (len(t), 3))
        fs = spin_from_flight(t, pos, model, position_sigma=0.002)
        vh = v0 / np.linalg.norm(v0)
        wp = w - (w @ vh) * vh
        if fs.lift_from == "total":  # the seed model: the flight sees |w| along w_perp
            wp = wp / np.linalg.norm(wp) * np.linalg.norm(w)
        e_r = fs.rate_rpm - np.linalg.norm(wp) * RPM_PER_RAD_S
        e_a = np.degrees(np.arccos(np.clip(fs.axis @ wp / np.linalg.norm(wp), -1, 1)))
        dr.append(abs(e_r))
        da.append(e_a)
        hr, ha = fs.interval95()
        cov += abs(e_r) < hr and e_a < ha
    return {"model": kind, "n": n, "median_rate_err_rpm": float(np.median(dr)),
            "median_axis_err_deg": float(np.median(da)), "covered_95": cov / n}


def kept_pitch() -> dict | None:
    from stillcap.pipelines.pitch import analyse_pitch
    from stillcap.studio.pitch import pitch_capture
    with tempfile.TemporaryDirectory() as tmp:
        capture, photos = pitch_capture("seed-4seam", rng=0, calibrate=False).to_capture()
        root = capture.save(Path(tmp) / "pitch", photos)
        d = analyse_pitch(root, n_samples=0).to_dict()
        truth = json.loads((root / "truth.json").read_text())
    f, c = d["spin_from_flight"], d["spin_comparison"]
    w = np.asarray(truth["spin"])
    v = np.asarray(f["velocity"])
    wp = w - (w @ v) * v / (v @ v)
    wp = wp / np.linalg.norm(wp) * np.linalg.norm(w)  # the seed model
    return {"truth_rpm": truth["spin_rpm"], "flight_rpm": f["spin_rpm"], "flight_sigma_rpm": f["spin_sigma_rpm"],
            "axis_err_deg": float(np.degrees(np.arccos(np.clip(np.asarray(f["axis"]) @ wp / np.linalg.norm(wp), -1, 1)))),
            "axis_sigma_deg": f["axis_sigma_deg"], "vs_markers_deg": c["axis_angle_deg"], "chi2": c["chi2"],
            "agree": c["agree"]}


def cut_flight(t, p, jump=1.5, table_z=0.03, k=3, min_len=12):
    """The longest free flight: no velocity jump (bounce, hit) and off the table."""
    n = len(t)
    bad = np.zeros(n, bool)
    for i in range(k, n - k):
        vb = (p[i] - p[i - k]) / (t[i] - t[i - k])
        va = (p[i + k] - p[i]) / (t[i + k] - t[i])
        bad[i] |= np.linalg.norm(va - vb) > jump
    bad |= p[:, 2] < table_z
    bad |= np.r_[False, np.diff(t) > 3 * np.median(np.diff(t))]
    mask = ~np.convolve(bad, np.ones(2 * k + 1), "same").astype(bool)
    best, start = (0, 0), None
    for i, m in enumerate(np.r_[mask, False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            best = max(best, (i - start, start))
            start = None
    length, s = best
    return slice(s, s + length) if length >= min_len else None


def tt3d() -> list:
    rows = []
    for f in sorted(glob.glob(str(TT3D / "*.csv"))):
        a = np.loadtxt(f, delimiter=",", skiprows=1)
        t, p = a[:, 0], a[:, 1:4]
        sl = cut_flight(t, p)
        if sl is None:
            continue
        try:
            fs = spin_from_flight(t[sl], p[sl], TABLE_TENNIS, position_sigma=0.002, where=Path(f).name)
        except ValueError as e:
            print(f"  {Path(f).name}: {e}")
            continue
        rows.append({"file": Path(f).name, "n": fs.n_positions, "rms_mm": fs.rms_error_m * 1e3,
                     "cross_mm": fs.cross_track_rms_m * 1e3, "rpm": fs.rate_rpm, "sigma_rpm": fs.rate_sigma_rpm,
                     "axis_sigma_deg": fs.axis_sigma_deg, "tilt_deg": fs.axis_tilt_deg,
                     "speed": float(np.linalg.norm(fs.velocity))})
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=50)
    args = ap.parse_args()
    print("simulated pitches (2 mm noise, 0.36 s at 200 Hz):")
    print(f"  {'model':8s} {'n':>4s} {'rate err rpm':>13s} {'axis err deg':>13s} {'95% covered':>12s}")
    for kind in ("seed", "nathan"):
        s = simulated(kind, args.flights)
        print(f"  {kind:8s} {s['n']:4d} {s['median_rate_err_rpm']:13.1f} {s['median_axis_err_deg']:13.2f} "
              f"{s['covered_95']:12.0%}")
    k = kept_pitch()
    print("studio pitch (pipeline, seed model):", {a: (round(b, 3) if isinstance(b, float) else b)
                                                    for a, b in k.items()})
    if not TT3D.is_dir():
        print(f"tt3d flights: {TT3D} absent")
        return
    rows = tt3d()
    r = {key: np.array([x[key] for x in rows]) for key in rows[0]} if rows else {}
    print(f"tt3d flights: {len(rows)} of {len(glob.glob(str(TT3D / '*.csv')))} files gave a free flight of >= 12 "
          "positions")
    if rows:
        for key, unit in (("n", ""), ("speed", "m/s"), ("rms_mm", "mm"), ("cross_mm", "mm"), ("rpm", "rpm"),
                          ("sigma_rpm", "rpm"), ("axis_sigma_deg", "deg")):
            q = np.percentile(r[key], [10, 50, 90])
            print(f"  {key:15s} p10 {q[0]:8.2f}  median {q[1]:8.2f}  p90 {q[2]:8.2f} {unit}")
        print(f"  flights with cross-track RMS <= 2 mm: {np.mean(r['cross_mm'] <= 2.0):.0%}")
        print(f"  rate/sigma median {np.median(r['rpm'] / r['sigma_rpm']):.1f}")


if __name__ == "__main__":
    main()
