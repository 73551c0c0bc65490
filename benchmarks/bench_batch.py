"""Parallel efficiency of ``stillcap batch`` (Dask), and the batch against ``stillcap pitch A B ...``.

1. :func:`stillcap.batch.run_batch` over ``-n`` studio pitch captures on a ``LocalCluster`` of 1
   worker process, then of 2 (1 thread each; every capture analysed afresh: a new results
   folder each time). The clusters are started and their workers have imported the pipelines
   before the clock starts. Parallel efficiency = T(1) / (2 T(2)); goal >= 80 %.
2. The same captures through the two commands as a user runs them, fresh processes, start-up
   included: ``stillcap pitch A B ... --json`` (its own pool of 2 worker processes, one stereo
   pair each, captures one after the other) and ``stillcap batch A B ... --workers 2`` (a
   LocalCluster, one capture per worker). This is what docs/batch.md's choice rests on.

The captures (2560x1920 JPEG, the presets below in turn, seeds 1, 2, ...) are rendered once
into ``--cache``. Run on a quiet machine: on a loaded one two workers cannot get two cores and
the efficiency says more about the load than about the batch.

    python benchmarks/bench_batch.py [-n 8] [--cache DIR] [--skip-commands]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
# this tree's stillcap, in this process as in the ones it starts (not whichever is installed)
sys.path.insert(0, str(SRC))
PRESETS = ("seed-4seam", "seed-curveball", "mlb-4seam")
PITCH_TYPES = {"seed-4seam": "FF", "seed-curveball": "CU", "mlb-4seam": "FF"}


def _env():
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]))


def render(cache: Path, n: int) -> list[Path]:
    import json

    from stillcap.studio.pitch import pitch_capture

    out = []
    for i in range(n):
        preset = PRESETS[i % len(PRESETS)]
        folder = cache / f"{preset}-{i + 1}"
        if not (folder / "capture.json").is_file():
            cap, images = pitch_capture(preset, i + 1, calibrate=False).to_capture(".jpg")
            cap.save(folder, images, jpeg_quality=95)
            d = json.loads((folder / "capture.json").read_text())
            d["pitch_type"] = PITCH_TYPES[preset]
            (folder / "capture.json").write_text(json.dumps(d, indent=2))
        out.append(folder)
    return out


def time_batch(folders: list[Path], workers: int) -> tuple[float, int]:
    """Seconds for run_batch over ``folders`` on a ready LocalCluster of ``workers`` processes,
    and how many captures failed."""
    import logging

    from distributed import Client, LocalCluster

    from stillcap.batch import read_inputs, run_batch

    inputs = read_inputs(folders)
    os.environ["PYTHONPATH"] = _env()["PYTHONPATH"]  # the workers import this tree's stillcap too
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, silence_logs=logging.ERROR,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.run(lambda: __import__("stillcap.pipelines.pitch") and None)  # imports before the clock
        out = Path(tempfile.mkdtemp(prefix="bench-batch-"))
        try:
            t = time.perf_counter()
            run = run_batch(inputs, out, client)
            return time.perf_counter() - t, len(run.failed)
        finally:
            shutil.rmtree(out, ignore_errors=True)


def time_command(args: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "stillcap", *args], check=False, env=_env(), capture_output=True)
    return time.perf_counter() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=8, help="captures")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stillcap-bench-batch"))
    ap.add_argument("--skip-commands", action="store_true", help="only the efficiency (part 1)")
    args = ap.parse_args(argv)
    folders = render(args.cache, args.n)
    load0 = os.getloadavg()
    t1, f1 = time_batch(folders, 1)
    t2, f2 = time_batch(folders, 2)
    eff = t1 / (2 * t2)
    print(f"bench_batch: {len(folders)} pitch captures (2560x1920 JPEG), {os.cpu_count()} cores, load average "
          f"{load0[0]:.2f} before, {os.getloadavg()[0]:.2f} after")
    print(f"{'':<44} {'wall s':>8} {'s / capture':>12} {'failed':>7}")
    print(f"{'run_batch, LocalCluster of 1 worker':<44} {t1:8.2f} {t1 / len(folders):12.2f} {f1:7d}")
    print(f"{'run_batch, LocalCluster of 2 workers':<44} {t2:8.2f} {t2 / len(folders):12.2f} {f2:7d}")
    print(f"parallel efficiency T1 / (2 T2) = {eff * 100:.0f} % (goal >= 80 %: {'met' if eff >= 0.8 else 'MISSED'})")
    if args.skip_commands:
        return
    out = Path(tempfile.mkdtemp(prefix="bench-batch-cmd-"))
    try:
        tp = time_command(["pitch", *map(str, folders), "--json"])
        tb = time_command(["batch", *map(str, folders), "--workers", "2", "--out", str(out / "r")])
    finally:
        shutil.rmtree(out, ignore_errors=True)
    print(f"{'command (fresh process, start-up included)':<44} {'wall s':>8} {'s / capture':>12}")
    print(f"{'stillcap pitch A B ... --json (own pool of 2)':<44} {tp:8.2f} {tp / len(folders):12.2f}")
    print(f"{'stillcap batch A B ... --workers 2':<44} {tb:8.2f} {tb / len(folders):12.2f}")


if __name__ == "__main__":
    main()
