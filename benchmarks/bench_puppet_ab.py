"""Two source trees' puppet pipelines alternated in one process: the calling thread's CPU time
of the warm call and of its tail, where a change of a few milliseconds shows on a loaded machine.

    python benchmarks/bench_puppet_ab.py --tree OLD/src --tree NEW/src [--capture DIR | --cache DIR]
                                         [--repeat 40]

Each tree is imported in turn into this process (its ``stillcap`` modules are dropped from
``sys.modules`` before the next is imported; the functions of the first keep their own module
globals), runs ``analyse_puppet`` on the capture once (the default options, two threads, as
``bench_speed.py``'s puppet row) and records what ``analyse_puppet_views`` was given. Then
``--repeat`` rounds alternate the trees: per round, per tree, the whole call (``whole``) and
``analyse_puppet_views`` on the recorded detections (``tail``: triangulation, re-identification,
the pose fit and the self-checks), each timed in ``time.thread_time`` of this thread. The table
gives the least, the lower quartile and the median per tree.

Why: in fresh processes (``bench_puppet_timeline.py``, ``bench_puppet_stages.py``) the first
call's CPU scatters by 20-40 ms between rounds at load average 10-20, which hides changes of
~5 ms; alternating warm calls in one process, the other load falls on both trees alike. This
does not time a process's first call (one-off costs: kernels, BLAS's controller, loading): use
those benchmarks on a quiet machine for that. Measured on main 6713d3e against the eighth
session's branch: ``docs/benchmarks.md`` ("stacked views, one matmul per depth, gains at once").
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def load_tree(src: Path, folder: Path):
    """``(analyse_puppet, DEFAULT, analyse_puppet_views, args, kwargs)`` of the tree ``src``, the
    views' arguments recorded from one call on ``folder``."""
    for name in [m for m in sys.modules if m == "stillcap" or m.startswith("stillcap.")]:
        del sys.modules[name]
    sys.path.insert(0, str(src))
    try:
        analyse = importlib.import_module("stillcap.pipelines.puppet.analyse")
        puppet = importlib.import_module("stillcap.pipelines.puppet")
    finally:
        sys.path.remove(str(src))
    views = analyse.analyse_puppet_views
    seen = {}

    def record(*a, **k):
        seen["a"], seen["k"] = a, k
        return views(*a, **k)

    analyse.analyse_puppet_views = record
    try:
        puppet.analyse_puppet(folder, puppet.DEFAULT, save=False)
    finally:
        analyse.analyse_puppet_views = views
    return puppet.analyse_puppet, puppet.DEFAULT, views, seen["a"], seen["k"]


def main(argv=None) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_puppet_stages import add_capture_arguments, capture_folder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_capture_arguments(ap)
    ap.add_argument("--tree", action="append", type=Path, required=True,
                    help="a source folder (src); give two or more")
    ap.add_argument("--repeat", type=int, default=40, help="alternated rounds")
    args = ap.parse_args(argv)
    if len(args.tree) < 2:
        raise SystemExit("give --tree twice or more")
    folder = capture_folder(args)
    trees = {str(t.resolve()): load_tree(t.resolve(), folder) for t in args.tree}
    cpu = {(t, w): [] for t in trees for w in ("whole", "tail")}
    for _ in range(args.repeat):
        for t, (whole, default, views, a, k) in trees.items():
            c = time.thread_time()
            whole(folder, default, save=False)
            cpu[t, "whole"].append(time.thread_time() - c)
            c = time.thread_time()
            views(*a, **k)
            cpu[t, "tail"].append(time.thread_time() - c)
    print(f"{folder}: {args.repeat} alternated rounds; calling thread CPU, ms (least, lower quartile, median)")
    print(f"{'tree':40s} | {'whole call: least':>17s} {'q25':>7s} {'median':>7s} | {'tail: least':>11s} {'q25':>7s} "
          f"{'median':>7s}")
    for t in trees:
        w, tl = (1e3 * np.array(cpu[t, k]) for k in ("whole", "tail"))
        print(f"{t[-40:]:40s} | {w.min():17.1f} {np.percentile(w, 25):7.1f} {statistics.median(w):7.1f} | "
              f"{tl.min():11.1f} {np.percentile(tl, 25):7.1f} {statistics.median(tl):7.1f}")

if __name__ == "__main__":
    main()
