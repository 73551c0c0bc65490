"""Speed of the camera-response estimate: its share of ``analyse_pitch`` on the speed benchmark's
pitch (issue 16: goal about 0.08 s of the pitch's time).

1. ``analyse_pitch`` of the bench pitch (threads, the default options, load included): best of
   ``--repeat``.
2. The response self-check's estimates of that capture, as the pipeline makes them
   (:func:`stillcap.pipelines.pitch.workers.pair_response_estimates`: both cameras of a pair in
   one batch, on the decoded photos, at the pair's refined centres and projected radii), one
   pair after the other on one thread: best of ``--repeat``, wall and CPU time.
3. ``--response auto``'s estimate of the same capture
   (:func:`stillcap.pipelines._response.pitch_auto_estimates`: it finds the ball images again,
   up to three rounds), which runs only when asked for.

The pitch is bench_speed.py's (a 2560x1920 JPEG studio pitch, rendered into ``--cache`` once).
Run it on a quiet machine: under load every time is stretched (best of N helps, CPU time helps
more; the ratio of 2 to 1 is the figure to read).

    PYTHONPATH=src python benchmarks/bench_response_speed.py [--cache DIR] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import best_time  # noqa: E402
from bench_speed import render  # noqa: E402


def best_cpu(fn, repeat: int) -> float:
    """Shortest of ``repeat`` CPU times of ``fn()`` (this process, all threads), seconds."""
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stillcap-bench-speed"))
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    from stillcap.ball.layout import BASEBALL_RADIUS
    from stillcap.io.capture import Capture
    from stillcap.pipelines._response import pitch_auto_estimates
    from stillcap.pipelines.pitch import PitchOptions, analyse_pitch
    from stillcap.pipelines.pitch.workers import pair_response_estimates

    pitch, _ = render(args.cache)
    cap = Capture.load(pitch)
    result = analyse_pitch(cap, PitchOptions())  # warm-up, and the pairs' centres and radii
    api = best_time(lambda: analyse_pitch(Capture.load(pitch), PitchOptions()), args.repeat)
    jobs = []
    for p in result.pairs:
        photos = [cap.read_image(cap.images_of(name)[0]) for name in p.cameras]
        jobs.append((photos, p))

    def estimates():
        return [pair_response_estimates(photos, p) for photos, p in jobs]

    found = estimates()
    wall, cpu = best_time(estimates, args.repeat), best_cpu(estimates, args.repeat)
    auto = best_time(lambda: pitch_auto_estimates(cap, BASEBALL_RADIUS), max(1, args.repeat // 2))
    load = os.getloadavg()
    print(f"bench_response_speed: {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
          f"best of {args.repeat}; {pitch}")
    n = sum(e.n_spheres for f in found for e in f.values())
    print(f"{'analyse_pitch (load included, threads)':<62} {api:8.3f} s")
    print(f"{f'response self-check estimates ({n} ball images), wall':<62} {wall:8.3f} s  "
          f"{100 * wall / api:5.1f} % of analyse_pitch  (goal <= ~0.08 s)")
    print(f"{'  the same, CPU time':<62} {cpu:8.3f} s")
    print(f"{'--response auto estimate (finds the balls again)':<62} {auto:8.3f} s")
    for f in found:
        for name, e in f.items():
            print(f"  {name}: {e.evidence}")


if __name__ == "__main__":
    main()
