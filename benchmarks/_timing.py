"""Timing helper shared by the benchmark scripts (run as ``python benchmarks/bench_X.py``, so this
folder is on ``sys.path``)."""

import time

import numpy as np


def best_time(fn, repeat=3):
    """Shortest of ``repeat`` wall-clock runs of ``fn()``, seconds (the least disturbed by other jobs)."""
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best
