"""Marker-ball reconstruction accuracy and speed on studio scenes with ground truth.

    python benchmarks/bench_markers.py [--seeds 10]

Each seed renders a 4-camera, 1280x960 scene (marker_rig, marker_scene with 12 balls) and runs
the marker pipeline (blobs -> colour labels -> N-view matching -> triangulation) with the true
rig, so the numbers measure detection and triangulation alone (calibration error is measured by
`stillcap demo`). Time is compared with decoding the four PNG photos, in the same run.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from rich.console import Console
from rich.table import Table

from stillcap.pipelines.markers import reconstruct_markers
from stillcap.studio.scenes import marker_rig, marker_scene


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    args = ap.parse_args(argv)
    errs, reproj, found, expected, wrong, t_pipe, t_dec = [], [], 0, 0, 0, [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            rig = marker_rig(4, rng=seed)
            scene = marker_scene(rig, 12, rng=1000 + seed)
            files = []
            for k, img in enumerate(scene.images):
                files.append(Path(tmp) / f"{seed}_{k}.png")
                cv2.imwrite(str(files[-1]), img)
            t = time.perf_counter()
            imgs = [cv2.imread(str(f)) for f in files]
            t_dec.append(time.perf_counter() - t)
            t = time.perf_counter()
            rec = reconstruct_markers(rig, imgs)
            t_pipe.append(time.perf_counter() - t)
            tr = scene.truth
            idx = [i for i, k in enumerate(tr.ball_kinds) if k == "marker"]
            centers = tr.ball_centers[idx]
            color = [tr.ball_names[i].rstrip("0123456789") for i in idx]
            expected += int((np.isfinite(tr.ball_centers_px[:, idx, 0]).sum(axis=0) >= 2).sum())
            for lab, p, e in zip(rec.labels, rec.points, rec.triangulation.reproj_error_px):
                d = np.linalg.norm(centers - p, axis=1)
                i = int(d.argmin())
                found += 1
                wrong += color[i] != lab or d[i] > 5e-3
                errs.append(d[i] * 1e3)
                reproj.append(e)
    errs = np.array(errs)
    t = Table(title=f"Marker balls, {args.seeds} scenes x 4 cameras (true rig)")
    for c in ("balls seen by 2+ cameras", "recovered", "wrong", "3D mean mm", "3D RMS mm", "3D max mm",
              "reproj mean px", "pipeline s/scene", "decode s/scene", "ratio"):
        t.add_column(c, justify="right")
    t.add_row(str(expected), str(found), str(wrong), f"{errs.mean():.3f}", f"{np.sqrt(np.mean(errs**2)):.3f}",
              f"{errs.max():.3f}", f"{np.mean(reproj):.3f}", f"{np.mean(t_pipe):.3f}", f"{np.mean(t_dec):.3f}",
              f"{np.mean(t_pipe) / np.mean(t_dec):.1f}")
    Console().print(t)


if __name__ == "__main__":
    main()
