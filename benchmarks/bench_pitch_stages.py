"""CPU time of the pitch pipeline's stages, per capture (where the time of ``analyse_pitch`` goes).

    python benchmarks/bench_pitch_stages.py --captures DIR [--every 6] [--repeat 5] [--workers 1] [--opencv]
    python benchmarks/bench_pitch_stages.py --seeds 5

``--opencv`` adds a row: the CPU of every OpenCV call but decoding, which releases the GIL. The
rest of the non-decoding CPU holds it (Python, NumPy on small arrays), so on threads a capture's
wall time cannot fall below about "whole - decoding - OpenCV" however the stages are scheduled
(issue 16, the 2560x1920 JPEG pitch of ``bench_speed.py``, loaded 2-core machine: of 377 ms of
non-decoding CPU 60 ms were OpenCV's, ~317 ms held the GIL, against 95 ms of decoding). With
``--opencv`` the table ends with that bound: the CPU that held the GIL (at most: NumPy's loops over
large arrays release it as well, so the true share is smaller) and the ratio to the decoding that
threads cannot go under (that CPU, one after the other, after the first photo is decoded).

``--captures DIR``: capture folders kept by ``bench_pitch.py --keep DIR`` (every ``--every``-th);
without it ``--seeds`` pitches of each preset are rendered into a temporary folder (true rig).
Each capture runs ``analyse_pitch`` on threads (``processes=0``) after one warm-up run. Times are
CPU times, which a shared machine disturbs far less than wall times: the whole call in
``time.process_time`` (every thread of the process, OpenCV's own included), and each stage
function in ``time.thread_time`` of the thread that ran it (OpenCV's worker threads not
included), summed per capture. With ``--repeat N`` each capture runs N times and every row takes
its least time over them (best of N, per stage and per capture: the least disturbed by other
work on a loaded machine), then the mean over the captures. To compare two versions of the code, run this script with each
version first on ``PYTHONPATH`` (e.g. ``git worktree add``), alternately, on the same captures.
"""

from __future__ import annotations

import argparse
import importlib
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

import stillcap
from stillcap.io.capture import Capture
from stillcap.pipelines.pitch import analyse_pitch

#: The timed functions, in pipeline order: (row name, [(module that calls it, name there), ...]).
#: The row name is the function's own; each module's name is patched where the pipeline (on
#: threads, ``processes=0``) calls it (``"Class.method"``: patched on the class). Older versions of the code, with the whole pipeline in the
#: module ``stillcap.pipelines.pitch``, are patched there (missing names are skipped).
STAGES = (
    ("decoding (Capture.read_image)", [("stillcap.io.capture", "Capture.read_image")]),
    ("ball_centers_stereo", [("stillcap.pipelines.pitch.workers", "ball_centers_stereo"),
                             ("stillcap.pipelines.pitch", "ball_centers_stereo")]),
    ("  of which detect_balls", [("stillcap.ball.stereo", "detect_balls")]),
    ("    of which _foreground_contours (silhouettes)", [("stillcap.detect.ball._silhouettes",
                                                          "_foreground_contours")]),
    ("    of which crescent_circle (arc fits)", [("stillcap.detect.ball._silhouettes", "crescent_circle")]),
    ("  of which refine_ball_centers", [("stillcap.ball.stereo", "refine_ball_centers")]),
    ("    of which _shading_bias (shading model)", [("stillcap.detect.ball._refine", "_shading_bias")]),
    ("  of which photo_blur_px", [("stillcap.ball.stereo", "photo_blur_px")]),
    ("    of which limb_blur_px (blur fits)", [("stillcap.ball.stereo", "limb_blur_px")]),
    ("    of which _shading_bias (at the blur read)", [("stillcap.ball.stereo", "_shading_bias")]),
    ("pair_marker_observations", [("stillcap.pipelines.pitch.spin", "pair_marker_observations"),
                                  ("stillcap.pipelines.pitch", "pair_marker_observations")]),
    ("  of which detect_ball_markers", [("stillcap.ball.markers", "detect_ball_markers")]),
    ("    of which ball_white_balance", [("stillcap.detect.ball_markers", "ball_white_balance")]),
    ("    of which _measure (marker centroids, shapes)", [("stillcap.detect.ball_markers", "_measure")]),
    ("fit_pair_spin", [("stillcap.pipelines.pitch.spin", "_fit_pair_spin"),
                       ("stillcap.pipelines.pitch", "_fit_pair_spin")]),
    ("combined_spin", [("stillcap.pipelines.pitch.spin", "_combined_spin"),
                       ("stillcap.pipelines.pitch", "_combined_spin")]),
    ("  spin fits' _center_shift_cov (covariance, centre shifts)", [("stillcap.ball.orientation._global",
                                                                    "_center_shift_cov")]),
    ("fit_reference_trajectory", [("stillcap.pipelines.pitch.stages", "fit_reference_trajectory"),
                                  ("stillcap.pipelines.pitch", "fit_reference_trajectory")]),
    ("metrics_sigma", [("stillcap.pipelines.pitch.stages", "metrics_sigma"),
                       ("stillcap.pipelines.pitch", "_metrics_sigma")]),
    ("check_and_inflate (self-checks)", [("stillcap.pipelines.pitch.analyse", "check_and_inflate")]),
    ("pair_response_estimates (response self-check)", [("stillcap.pipelines.pitch.workers",
                                                        "pair_response_estimates")]),
    ("  of which _fit_discs (the shading fits)", [("stillcap.detect.response", "_fit_discs")]),
)

#: the row of ``--opencv``: every OpenCV call but decoding, whose thread CPU is GIL-free
OPENCV_ROW = "OpenCV calls other than decoding (GIL released: may overlap)"


def instrument_opencv(totals: dict) -> None:
    """Wrap every function of the ``cv2`` module (OpenCV releases the GIL inside its calls) to
    add its thread CPU time (s) to ``totals[OPENCV_ROW]``, decoding (``imdecode``/``imread``)
    left out (its own row). What is left of a stage's CPU holds the GIL (Python, and NumPy on
    small arrays): two threads cannot overlap it, so on threads a capture's wall time is at
    least about the whole CPU less the decoding and this row. The wrappers cost ~1 us a call."""
    import cv2

    for name in dir(cv2):
        fn = getattr(cv2, name)
        if type(fn).__name__ != "builtin_function_or_method" or name in ("imdecode", "imread"):
            continue

        def timed(*a, _fn=fn, **k):
            t = time.thread_time()
            try:
                return _fn(*a, **k)
            finally:
                totals[OPENCV_ROW] += time.thread_time() - t
        setattr(cv2, name, timed)


def instrument(totals: dict) -> None:
    """Wrap the stage functions where the pitch pipeline calls them, to add their thread CPU time
    (s) to ``totals[name]`` (measurement only: the results are unchanged)."""
    for name, places in STAGES:
        for module_name, attr in places:
            try:
                module = importlib.import_module(module_name)
            except ImportError:  # a version of the code without this module
                continue
            owner, _, attr = attr.rpartition(".")
            owner = getattr(module, owner, None) if owner else module
            fn = getattr(owner, attr, None)
            if fn is None:  # a version of the code without this stage here
                continue

            def timed(*a, _fn=fn, _name=name, **k):
                t = time.thread_time()
                try:
                    return _fn(*a, **k)
                finally:
                    totals[_name] += time.thread_time() - t
            setattr(owner, attr, timed)


def _captures(args, tmp: Path) -> list:
    if args.captures is not None:
        folders = sorted(p for p in Path(args.captures).iterdir() if (p / "capture.json").is_file())
        if not folders:
            raise SystemExit(f"{args.captures}: no capture folders (capture.json) in it")
        return folders[::args.every]
    from stillcap.studio.pitch import PRESETS, pitch_capture

    out = []
    for preset in PRESETS:
        for seed in range(args.seeds):
            pc = pitch_capture(preset, rng=seed, calibrate=False)
            cap, files = pc.to_capture(".jpg")
            folder = tmp / f"{preset}_{seed}"
            cap.save(folder, files, jpeg_quality=92)
            out.append(folder)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=Path, default=None, help="folders kept by bench_pitch.py --keep")
    ap.add_argument("--every", type=int, default=6, help="every n-th kept capture")
    ap.add_argument("--seeds", type=int, default=2, help="pitches per preset when rendering (no --captures)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per capture; each row the best of them")
    ap.add_argument("--workers", type=int, default=2,
                    help="PitchOptions.workers (1: every stage on the calling thread, so the rows add up)")
    ap.add_argument("--opencv", action="store_true",
                    help="also time every OpenCV call but decoding (GIL-free CPU; adds ~1 us a call)")
    args = ap.parse_args()
    console = Console()
    with tempfile.TemporaryDirectory() as tmp:
        folders = _captures(args, Path(tmp))
        totals: dict = defaultdict(float)
        instrument(totals)
        if args.opencv:
            instrument_opencv(totals)

        photos = [0]

        def run(folder):
            cap = Capture.load(folder)
            photos[0] = len(cap.images)
            rel = cap.truth["metrics"]["release_pos_y_ft"] if isinstance(cap.truth, dict) else None
            t = time.process_time()
            analyse_pitch(cap, release_y_ft=rel, processes=0, workers=args.workers)
            return time.process_time() - t

        run(folders[0])  # warm-up: imports, caches
        best: dict = defaultdict(float)  # stage -> sum over captures of its best time
        whole = []
        for f in folders:
            runs = []
            for _ in range(max(args.repeat, 1)):
                totals.clear()
                t = run(f)
                runs.append((t, dict(totals)))
            whole.append(min(t for t, _ in runs))
            for name in {k for _, tot in runs for k in tot}:
                best[name] += min(tot.get(name, 0.0) for _, tot in runs)
        totals = best
    n = len(folders)
    t = Table(title=f"pitch pipeline CPU per capture, ms ({n} captures, best of {args.repeat}, workers={args.workers}; "
                    f"stillcap from "
                    f"{Path(stillcap.__file__).parent})")
    t.add_column("stage")
    t.add_column("ms per capture", justify="right")
    t.add_column("share", justify="right")
    total = float(np.mean(whole))
    t.add_row("whole analyse_pitch (process CPU)", f"{1e3 * total:.1f}", "100 %")
    for name in [n for n, _ in STAGES] + [OPENCV_ROW]:
        if name in totals:
            t.add_row(name, f"{1e3 * totals[name] / n:.1f}", f"{100 * totals[name] / n / total:.0f} %")
    dec = totals.get(STAGES[0][0], 0.0) / n
    if OPENCV_ROW in totals and dec > 0:
        # what no scheduling on threads removes: the CPU that holds the GIL (at most: NumPy's loops
        # over large arrays release it too) after the first photo's decoding (nothing to do before)
        held = total - dec - totals[OPENCV_ROW] / n
        n_photos = max(photos[0], 1)
        t.add_row("held the GIL (at most): whole - decoding - OpenCV", f"{1e3 * held:.1f}", f"{100 * held / total:.0f} %")
        t.add_row(f"  so threads take at least (held + 1 of {n_photos} decodes) / decoding = "
                  f"{(held + dec / n_photos) / dec:.2f}x the decoding", "", "")
    console.print(t)


if __name__ == "__main__":
    main()
