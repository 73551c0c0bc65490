"""CPU time of the puppet pipeline's pieces in its first call (where ``bench_speed.py``'s puppet
row goes), in fresh processes.

    python benchmarks/bench_puppet_stages.py [--capture DIR | --cache DIR] [--repeat 8]

Each of ``--repeat`` fresh processes imports ``stillcap.pipelines.puppet`` and calls
``analyse_puppet`` on the capture twice (the default options, two threads, as ``bench_speed.py``).
The pieces are the functions the pipeline calls, patched where it calls them; each is timed in
``time.thread_time`` of the *main* thread only (the other thread decodes and prepares the photos;
when the main thread has nothing to detect it decodes too, the ``decoding``/``preparing`` rows),
so the rows show the main thread's path, whose end is the call's end. ``main thread`` is that
thread's whole CPU time for the call, ``process`` every thread's (``time.process_time``). Every
number is the least over the processes (the least disturbed by other work). CPU times hold on a
loaded machine far better than wall times, but they are not the wall time of the call: run
``bench_speed.py`` on a quiet machine for that. To compare two versions of the code, run this
script from each version's tree (it puts its own ``src`` first on the path), alternately.

Below the pieces, per call: the other threads' CPU (``process`` minus ``main thread``: the
decoding thread), how many photos the main thread decoded itself (it does when the decoding
thread is behind; the median over the processes), and, where Linux's per-thread scheduler
statistics exist (``/proc/thread-self/schedstat``), the main thread's wall time split into its
CPU time, its time waiting for a core (run queue: other processes, so large on a loaded machine)
and the rest, its time blocked (waiting for a decoded photo or for the GIL; to ~2 ms: the
scheduler's counters move at its ticks, so a median can come out slightly below 0). On a quiet
machine the call's wall time is about the main thread's CPU time plus that blocked time: the
main thread's path is the call's.

``--switch-interval S``: the children call ``sys.setswitchinterval(S)`` first (Python's default
is 0.005 s), to see whether the decoding thread waits for the GIL (measured: no; 5, 1 and 0.2 ms
gave first calls of 79.1, 77.5 and 77.4 ms, best of 8, medians 81.2, 79.1 and 79.9 ms).

On a loaded Linux machine, running as root under ``chrt -f 10`` (real-time scheduling: the
benchmark's processes take the cores from every ordinary process for the seconds they run)
gives near-quiet wall times: the main thread then waited 0.2 ms for a core in a 78.5 ms call.
Decoding itself ran ~20 % slower that way than on the quiet machine (12 JPEGs: 19-20 ms
against 16 ms), so compare two versions alternately rather than with quiet-machine numbers.

Without ``--capture``, the puppet capture of ``bench_speed.py`` (rendered into ``--cache`` once).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: (row, module whose global the pipeline calls, name there); "Class.method" patches the class
PIECES = (
    ("loading the capture", "stillcap.pipelines.puppet.analyse", "_load_capture"),
    ("BLAS controller (first use)", "stillcap._blas", "_blas_controller"),
    ("cameras, marker set, skeleton", "stillcap.pipelines.puppet.analyse", "_capture_inputs"),
    ("decoding (on the main thread)", "stillcap.io.capture", "Capture.read_image"),
    ("preparing (on the main thread)", "stillcap.pipelines.puppet.analyse", "_prepare"),
    ("candidates", "stillcap.pipelines.puppet.analyse", "find_bead_candidates"),
    ("sub-pixel refinement", "stillcap.pipelines.puppet.analyse", "refine_bead_candidates"),
    ("naming by colour", "stillcap.pipelines.puppet.analyse", "identify_views"),
    ("triangulation (+ fill, re-identification)", "stillcap.pipelines.puppet.analyse", "triangulate_beads"),
    ("bead noise (jackknife)", "stillcap.pipelines.puppet.analyse", "bead_noise"),
    ("pose stage", "stillcap.pipelines.puppet.analyse", "pose_skeleton"),
    ("  fit_pose", "stillcap.pipelines.puppet.stages", "fit_pose"),
    ("    its start (_start_angles)", "stillcap.body.puppet_pose", "_start_angles"),
    ("    its thesis pose (pose_from_markers)", "stillcap.body.puppet_pose", "_pose_and_directions"),
    ("    its least squares", "stillcap.body.puppet_pose", "least_squares"),
    ("self-checks", "stillcap.pipelines.puppet.analyse", "skeleton_checks"),
)

CHILD = r"""
import functools, importlib, json, os, sys, threading, time
pieces = json.loads(sys.argv[2])
if float(sys.argv[3]) > 0:
    sys.setswitchinterval(float(sys.argv[3]))
from stillcap.pipelines.puppet import DEFAULT, analyse_puppet
from stillcap.io.capture import Capture
acc = {}
main = threading.main_thread()
SCHED = "/proc/thread-self/schedstat"

def sched():  # (CPU s, run-queue wait s) of this thread, or None
    try:
        with open(SCHED) as f:
            run, wait = f.read().split()[:2]
        return int(run) * 1e-9, int(wait) * 1e-9
    except (OSError, ValueError):
        return None

def counted(*a, **k):
    if threading.current_thread() is main:
        acc["photos decoded on the main thread"] = acc.get("photos decoded on the main thread", 0) + 1
    return read_image(*a, **k)

def patch(row, mod, name):
    owner = importlib.import_module(mod)
    cls, _, attr = name.rpartition(".")
    if cls:
        owner = getattr(owner, cls)
    f = getattr(owner, attr, None)
    if f is None:
        return
    @functools.wraps(f)
    def timed(*a, **k):
        if threading.current_thread() is not main:
            return f(*a, **k)
        c = time.thread_time()
        try:
            return f(*a, **k)
        finally:
            acc[row] = acc.get(row, 0.0) + time.thread_time() - c
    setattr(owner, attr, timed)

for row, mod, name in pieces:
    patch(row, mod, name)
read_image = Capture.read_image  # the timed piece's wrapper: counted around it
Capture.read_image = functools.wraps(read_image)(counted)
out = []
for call in range(2):
    acc.clear()
    s0 = sched()
    t, c, p = time.perf_counter(), time.thread_time(), time.process_time()
    analyse_puppet(sys.argv[1], DEFAULT, save=False)
    wall = time.perf_counter() - t
    r = dict(acc)
    r["main thread"], r["process"] = time.thread_time() - c, time.process_time() - p
    r["other threads (process - main thread)"] = r["process"] - r["main thread"]
    r.setdefault("photos decoded on the main thread", 0)
    s1 = sched()
    if s0 is not None and s1 is not None:
        r["main thread: wall"] = wall
        r["main thread: waiting for a core (run queue)"] = s1[1] - s0[1]
        r["main thread: blocked (photos, GIL)"] = wall - (s1[0] - s0[0]) - (s1[1] - s0[1])
    out.append(r)
print(json.dumps(out))
"""

#: rows after the pieces: (row, how the processes' values are combined)
EXTRA = (("main thread", "least"), ("process", "least"), ("other threads (process - main thread)", "least"),
         ("photos decoded on the main thread", "median"), ("main thread: wall", "least"),
         ("main thread: waiting for a core (run queue)", "median"), ("main thread: blocked (photos, GIL)", "median"))


def add_capture_arguments(ap: argparse.ArgumentParser) -> None:
    """``--capture`` and ``--cache``: the puppet capture a benchmark times (shared with
    ``bench_puppet_timeline.py``; :func:`capture_folder` reads them)."""
    ap.add_argument("--capture", type=Path, default=None, help="a puppet capture folder")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stillcap-bench-speed"),
                    help="where bench_speed.py renders its captures (without --capture)")


def capture_folder(args) -> Path:
    """``--capture``, or bench_speed.py's puppet capture rendered (once) into ``--cache``."""
    if args.capture is not None:
        return args.capture
    sys.path.insert(0, str(SRC))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_speed import render

    return render(args.cache)[1]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_capture_arguments(ap)
    ap.add_argument("--repeat", type=int, default=8, help="fresh processes")
    ap.add_argument("--switch-interval", type=float, default=0.0,
                    help="sys.setswitchinterval in the children, seconds (default: Python's own)")
    args = ap.parse_args(argv)
    folder = capture_folder(args)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]))
    runs = []
    for _ in range(args.repeat):
        p = subprocess.run([sys.executable, "-c", CHILD, str(folder), json.dumps(PIECES), str(args.switch_interval)],
                           check=True, env=env, capture_output=True, text=True)
        runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    how = {r: "least" for r, _, _ in PIECES} | dict(EXTRA)
    print(f"{folder}: CPU ms, least of {args.repeat} fresh processes (main thread unless said; counts and "
          f"waits: median)" + (f"; switch interval {args.switch_interval:g} s" if args.switch_interval > 0 else ""))
    print(f"{'piece':45s} | {'first call':>10s} | {'second call':>11s}")
    for row, combine in how.items():
        if any(row not in run[0] for run in runs):
            continue  # no scheduler statistics here
        vals = []
        for k in (0, 1):
            v = [run[k].get(row, 0.0) for run in runs]
            vals.append(min(v) if combine == "least" else statistics.median(v))
        if row == "photos decoded on the main thread":
            print(f"{row:45s} | {vals[0]:10.1f} | {vals[1]:11.1f}")
        else:
            print(f"{row:45s} | {vals[0] * 1e3:10.2f} | {vals[1] * 1e3:11.2f}")


if __name__ == "__main__":
    main()
