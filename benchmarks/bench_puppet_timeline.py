"""The puppet's first call in a fresh process as a timeline of its two threads, and an A/B of
two source trees in alternating fresh processes.

    python benchmarks/bench_puppet_timeline.py [--capture DIR | --cache DIR] [--repeat 8]
                                               [--tree SRC ...] [--timeline]

Each of ``--repeat`` rounds runs, for every ``--tree`` in turn (default: this tree's ``src``),
a fresh process that imports ``stillcap.pipelines.puppet`` and calls ``analyse_puppet`` on the
capture twice (the default options, two threads, as ``bench_speed.py``'s puppet row), and
prints per tree the first call's wall time, the main thread's CPU time and every thread's
(least and median over the rounds), and the second call's wall time. Alternating the trees
round by round spreads the machine's other load over both alike; the trees' ``src`` folders
go first on the path (export another version with ``git archive COMMIT | tar -x -C DIR``).
Each round also decodes the capture's JPEGs one after the other (``cv2.imread``, in this
process, as ``bench_speed.py``'s reference): the table's ``ratio`` is a tree's least first-call
wall time over the least decode, issue 16's goal (<= 4) as ``bench_speed.py --puppet-only``
gives it for one tree.

``--timeline``: also the first call's timeline of the last round of each tree: when each
piece (loading, set-up, decoding, preparing, finding the candidates, refining, naming, the rest
of the pipeline: ``TAIL``) ran on which thread (``M`` the calling thread, ``W`` the decoding
one), wall milliseconds from the call's start, and its CPU time. A decoding thread that ends
long before the calling thread stops detecting is the imbalance to look at; the pieces' wall
time above their CPU time is waiting (for a core or the GIL).

Wall times on a loaded machine are worthless: run this on a quiet one, or as root under
``chrt -f 10 python ...`` (real-time scheduling: the children take the cores from every
ordinary process for the seconds they run; the children inherit it). Measured so on the
loaded 2-core machine (main bbff8f2, 6-8 rounds): first call 88-99 ms wall (least), the main
thread 84-97 ms CPU, all threads 128-134 ms. The calling thread read 6 of the 12 photos itself,
and the decoding thread sat idle for the detection's last ~16-19 ms (``docs/benchmarks.md``,
"The puppet's two threads").
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2

SRC = Path(__file__).resolve().parents[1] / "src"

CHILD = r"""
import functools, json, sys, threading, time
sys.path.insert(0, sys.argv[1])
from stillcap.pipelines.puppet import DEFAULT, analyse_puppet
import stillcap.pipelines.puppet.analyse as A
import stillcap.io.capture as C
events = []
main = threading.main_thread()

def wrap(owner, name, label):
    f = getattr(owner, name, None)
    if f is None:
        return
    @functools.wraps(f)
    def timed(*a, **k):
        t, c = time.perf_counter(), time.thread_time()
        try:
            return f(*a, **k)
        finally:
            events.append((label, threading.current_thread() is main, t, time.perf_counter(),
                           time.thread_time() - c))
    setattr(owner, name, timed)

if sys.argv[3] == "1":
    for owner, name, label in ((A, "_load_capture", "load"), (A, "_capture_inputs", "set-up"),
                               (C.Capture, "read_image", "decode"), (A, "_prepare", "prepare"),
                               (A, "find_bead_candidates", "find"), (A, "refine_bead_candidates", "refine"),
                               (A, "identify_views", "name"), (A, "analyse_puppet_views", "TAIL")):
        wrap(owner, name, label)
t0, c0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
analyse_puppet(sys.argv[2], DEFAULT, save=False)
first = (time.perf_counter() - t0, time.thread_time() - c0, time.process_time() - p0)
t1 = time.perf_counter()
n = len(events)
analyse_puppet(sys.argv[2], DEFAULT, save=False)
second = time.perf_counter() - t1
print(json.dumps({"first": first, "second": second,
                  "events": [(l, m, a - t0, b - t0, c) for l, m, a, b, c in events[:n]]}))
"""


def main(argv=None) -> None:
    from bench_puppet_stages import add_capture_arguments, capture_folder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_capture_arguments(ap)
    ap.add_argument("--repeat", type=int, default=8, help="rounds (fresh processes per tree)")
    ap.add_argument("--tree", action="append", type=Path, default=None,
                    help="a source folder (src) to compare; give it twice or more (default: this tree's)")
    ap.add_argument("--timeline", action="store_true", help="print the first call's timeline per tree")
    args = ap.parse_args(argv)
    folder = capture_folder(args)
    trees = [t.resolve() for t in (args.tree or [SRC])]
    runs = {t: [] for t in trees}
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    files = sorted(str(f) for f in (folder / "images").iterdir() if f.suffix.lower() in (".jpg", ".jpeg"))
    decode = []  # seconds to decode the capture's JPEGs, once per round (bench_speed.py's reference)
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        for f in files:
            cv2.imread(f)
        decode.append(time.perf_counter() - t0)
        for t in trees:
            p = subprocess.run([sys.executable, "-c", CHILD, str(t), str(folder), "1" if args.timeline else "0"],
                               check=True, env=env, capture_output=True, text=True)
            runs[t].append(json.loads(p.stdout.strip().splitlines()[-1]))
    load = os.getloadavg()
    print(f"{folder}: {args.repeat} rounds, load average {load[0]:.2f}; milliseconds; decoding its {len(files)} "
          f"JPEGs: least {1e3 * min(decode):.1f}, median {1e3 * statistics.median(decode):.1f}")
    print(f"{'tree':40s} | first call wall: least  median  ratio | main CPU: least  median | all threads CPU: least "
          f"| second call wall: least  median")
    for t in trees:
        f = [r["first"] for r in runs[t]]
        s = [r["second"] for r in runs[t]]
        wall, cpu, proc = ([1e3 * x[i] for x in f] for i in range(3))
        print(f"{str(t)[-40:]:40s} | {min(wall):22.1f} {statistics.median(wall):7.1f} {min(wall) / (1e3 * min(decode)):6.2f} "
              f"| {min(cpu):14.1f} {statistics.median(cpu):7.1f} | {min(proc):21.1f} "
              f"| {1e3 * min(s):24.1f} {1e3 * statistics.median(s):7.1f}")
    if args.timeline:
        for t in trees:
            print(f"\n{t}: the first call of the last round (thread, piece, start -> end wall ms, CPU ms)")
            for label, on_main, a, b, c in sorted(runs[t][-1]["events"], key=lambda e: e[2]):
                print(f"  {'M' if on_main else ' W'} {label:8s} {1e3 * a:7.2f} -> {1e3 * b:7.2f}  CPU {1e3 * c:5.2f}")


if __name__ == "__main__":
    main()
