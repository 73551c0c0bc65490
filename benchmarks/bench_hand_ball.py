"""Hand capture: ball positions, flash numbers, release and spin against the studio truth.

    python benchmarks/bench_hand_ball.py --seeds 10 --size 2560x1920

The hand comes from the truth (``root2world`` per flash, flash ``k`` at ``k / strobe_hz`` from the
first rendered flash); the ball from the photos, numbered by the hand
(``hand_ball_positions(..., hand=...)``). Columns: ball images found of those visible in 2+
cameras, position error mean/max, flash numbers right, held flashes, release time / point /
speed / direction errors, and each error over its reported 1-sigma (``z``: |z| <= 2 on 95 % of
seeds when the sigmas are honest).
"""

import argparse
import time

import numpy as np

from stillcap.ball.metrics import RPM_PER_RAD_S
from stillcap.ball.release import estimate_release
from stillcap.pipelines.hand.ball import hand_ball_positions, hand_ball_spin
from stillcap.studio.hand import hand_capture


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--size", default="2560x1920")
    a = ap.parse_args()
    size = tuple(int(v) for v in a.size.split("x"))
    print(f"{'seed':>4} {'found':>5} {'pos mean/max mm':>15} {'num':>4} {'held':>4} {'dt ms':>6} {'z':>5} {'dp mm':>6} "
          f"{'z':>5} {'dv mph':>6} {'z':>5} {'dir deg':>7} {'z':>5} {'spin':>22} {'time s':>6}")
    rows = []
    for seed in range(a.first, a.first + a.seeds):
        cap = hand_capture(seed, image_size=size)
        tr = cap.truth
        th = tr.times - tr.times[0]
        t = time.perf_counter()
        hb = hand_ball_positions(cap, hand=(th, tr.root2world))
        truth = tr.ball2world[:, :3, 3]
        k = np.array([np.argmin(np.linalg.norm(truth - x, axis=1)) for x in hb.positions], int)
        d = np.linalg.norm(truth[k] - hb.positions, axis=1) * 1e3
        vis2 = tr.ball_visible.sum(axis=0) >= 2
        found = len(set(k.tolist()) & set(np.flatnonzero(vis2).tolist()))
        numbered = int(np.sum(np.abs(hb.times - th[k]) < 1e-6))
        r = estimate_release(hb.times, hb.positions, th, tr.root2world, strobe_hz=tr.strobe_hz,
                             position_sigma_m=hb.sigma_m)
        sp = hand_ball_spin(cap, hb, ~r.held & np.all(np.isfinite(hb.positions), axis=1))
        dt_s = time.perf_counter() - t
        rel = tr.release
        dt = (r.t_release - (rel.t0 - tr.times[0])) * 1e3
        dpv = r.position - rel.p0
        dp = np.linalg.norm(dpv) * 1e3
        dv = r.speed_mph - rel.speed_mph
        ang = (np.degrees(np.arccos(np.clip(r.velocity @ rel.v0 / np.linalg.norm(r.velocity) / np.linalg.norm(rel.v0), -1, 1)))
               if r.success else np.nan)
        z_t = dt / (r.t_release_sigma * 1e3)
        z_p = np.sqrt(np.sum((dpv / r.position_sigma) ** 2) / 3)  # RMS per-axis z
        z_v = dv / r.speed_sigma_mph
        z_a = ang / r.direction_sigma_deg
        if sp.available:
            best = min(sp.candidates, key=lambda c: np.linalg.norm(c - rel.spin))
            spin = f"{len(sp.candidates_rpm)} cand, near {np.linalg.norm(best - rel.spin) * RPM_PER_RAD_S:.0f} rpm"
        else:
            spin = "n/a (" + ("<2 free" if "free" in sp.message else "no markers") + ")"
        print(f"{seed:>4} {found}/{int(vis2.sum()):>3} {d.mean():6.2f}/{d.max():6.2f} {numbered}/{len(hb):>2} {r.n_held:>4} "
              f"{dt:6.2f} {z_t:5.1f} {dp:6.1f} {z_p:5.1f} {dv:6.2f} {z_v:5.1f} {ang:7.2f} {z_a:5.1f} {spin:>22} {dt_s:6.2f}")
        rows.append((d.mean(), d.max(), abs(dt), dp, abs(dv), ang, dt_s, found == vis2.sum(), numbered == len(hb),
                     abs(z_t) <= 2, z_p <= 2, abs(z_v) <= 2, z_a <= 2))
    R = np.array(rows, float)
    n = len(R)
    print(f"median: pos mean {np.median(R[:, 0]):.2f} mm, pos max {np.median(R[:, 1]):.2f} mm, |dt| {np.nanmedian(R[:, 2]):.2f} ms, "
          f"dp {np.nanmedian(R[:, 3]):.1f} mm, |dv| {np.nanmedian(R[:, 4]):.2f} mph, dir {np.nanmedian(R[:, 5]):.2f} deg, "
          f"time {np.median(R[:, 6]):.2f} s")
    print(f"all found {int(R[:, 7].sum())}/{n}, all numbered right {int(R[:, 8].sum())}/{n}; within 2 sigma: "
          f"time {int(R[:, 9].sum())}/{n}, point {int(R[:, 10].sum())}/{n}, speed {int(R[:, 11].sum())}/{n}, "
          f"direction {int(R[:, 12].sum())}/{n}")


if __name__ == "__main__":
    main()
