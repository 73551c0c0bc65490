"""Memory over a long session of pitch captures: does the resident memory stay flat?

    python benchmarks/bench_session_memory.py [CAPTURE ...] [--captures 300] [--every 20]
                                              [--mode both|inprocess|session] [--processes 2]

The same few pitch captures (default: ``/tmp/kept/pitch-*``, else one studio pitch rendered at
1280x960 into a temporary folder) are analysed ``--captures`` times in turn, two ways:

- ``inprocess``: ``Capture.load`` + ``analyse_pitch`` (threads, ``processes=0``) in this process,
  one capture after the other, as a program analysing a session would; no result is kept.
- ``session``: the command's session path, ``stillcap pitch A B C ...`` run in this process
  (``stillcap.cli.main``) with worker processes (``--processes``), which keeps every result for
  its summary table, as the command does.

The resident set size (``VmRSS`` of ``/proc/PID/status``) of this process and of all its
descendant processes (the forkserver and the pitch workers) is sampled after the 1st capture and
every ``--every`` captures; the table shows it by captures done, and the growth from the 20th
capture to the last (total and per 100 captures). Linux only (``/proc``). No goal is asserted:
the numbers are for reading.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

console = Console()


def rss_mb(pid: int | str = "self") -> float:
    """Resident set size of process ``pid``, MB (0 when it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (OSError, ValueError):
        pass
    return 0.0


def descendants(root: int) -> list[int]:
    """All processes below ``root`` (children, their children, ...), from ``/proc``."""
    parent = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
                parent[int(d.name)] = int(stat[stat.rindex(")") + 2:].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    found, frontier = [], [root]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        found += kids
        frontier += kids
    return found


def sample(done: int, t0: float) -> dict:
    kids = descendants(os.getpid())
    return {"done": done, "self_mb": rss_mb(), "workers_mb": sum(rss_mb(k) for k in kids), "workers": len(kids),
            "elapsed_s": time.perf_counter() - t0}


def default_captures() -> list[Path]:
    kept = sorted(p for p in Path("/tmp/kept").glob("pitch-*") if (p / "capture.json").is_file())
    if kept:
        return kept
    from stillcap.studio.pitch import pitch_capture

    root = Path(tempfile.mkdtemp(prefix="stillcap-bench-memory-")) / "pitch"
    console.print(f"no /tmp/kept/pitch-* captures: rendering one studio pitch into {root}")
    cap, images = pitch_capture("seed-4seam", 0, calibrate=False, image_size=(1280, 960)).to_capture()
    cap.save(root, images)
    return [root]


def run_inprocess(captures: list[Path], n: int, every: int) -> list[dict]:
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

    rows, t0 = [], time.perf_counter()
    opts = PitchOptions()
    for i in range(n):
        res = analyse_pitch(Capture.load(captures[i % len(captures)]), opts)
        del res
        if i == 0 or (i + 1) % every == 0 or i + 1 == n:
            rows.append(sample(i + 1, t0))
            console.print(f"  in-process: {i + 1} captures, {rows[-1]['self_mb']:.0f} MB", highlight=False)
    return rows


def run_session(captures: list[Path], n: int, every: int, processes: int) -> list[dict]:
    """``stillcap pitch`` over ``n`` captures, sampled from a wrapper of ``analyse_pitch`` (the
    session calls it once per capture)."""
    import stillcap.pipelines.pitch as pipeline
    from stillcap.cli import main

    rows, t0 = [], time.perf_counter()
    real = pipeline.analyse_pitch
    count = [0]

    def counted(cap, opts):
        res = real(cap, opts)
        count[0] += 1
        i = count[0]
        if i == 1 or i % every == 0 or i == n:
            rows.append(sample(i, t0))
            console.print(f"  session: {i} captures, {rows[-1]['self_mb']:.0f} MB + workers "
                          f"{rows[-1]['workers_mb']:.0f} MB", highlight=False)
        return res

    pipeline.analyse_pitch = counted
    try:
        args = ["pitch", *(str(captures[i % len(captures)]) for i in range(n)), "--processes", str(processes)]
        with contextlib.redirect_stdout(io.StringIO()):  # the 300-row summary table
            main(args)
    finally:
        pipeline.analyse_pitch = real
    return rows


def table(title: str, rows: list[dict], workers: bool) -> None:
    t = Table(title=title)
    cols = ["captures done", "this process MB"] + (["workers MB", "processes", "total MB"] if workers else []) \
        + ["elapsed s"]
    for c in cols:
        t.add_column(c, justify="right")
    for r in rows:
        cells = [str(r["done"]), f"{r['self_mb']:.1f}"]
        if workers:
            cells += [f"{r['workers_mb']:.1f}", str(r["workers"]), f"{r['self_mb'] + r['workers_mb']:.1f}"]
        cells.append(f"{r['elapsed_s']:.0f}")
        t.add_row(*cells)
    console.print(t)
    base = next((r for r in rows if r["done"] >= 20), rows[0])
    last = rows[-1]
    span = max(last["done"] - base["done"], 1)
    for key, name in (("self_mb", "this process"), ("workers_mb", "workers")) if workers else (("self_mb", "this process"),):
        g = last[key] - base[key]
        console.print(f"{name}: {g:+.1f} MB from capture {base['done']} to {last['done']} "
                      f"({g / span * 100:+.2f} MB per 100 captures)", highlight=False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("captures", nargs="*", type=Path, help="pitch capture folders (default /tmp/kept/pitch-*)")
    ap.add_argument("--captures", dest="n", type=int, default=300, help="captures analysed per mode")
    ap.add_argument("--every", type=int, default=20, help="sample the memory every N captures")
    ap.add_argument("--mode", choices=("both", "inprocess", "session"), default="both")
    ap.add_argument("--processes", type=int, default=2, help="worker processes of the session mode")
    a = ap.parse_args()
    if not Path("/proc/self/status").is_file():
        sys.exit("this benchmark reads /proc (Linux)")
    caps = a.captures or default_captures()
    console.print(f"{a.n} captures per mode, cycling through {', '.join(c.name for c in caps)}")
    if a.mode in ("both", "inprocess"):
        table(f"analyse_pitch in one process (threads): RSS over {a.n} captures",
              run_inprocess(caps, a.n, a.every), workers=False)
    if a.mode in ("both", "session"):
        table(f"stillcap pitch session, {a.processes} worker processes: RSS over {a.n} captures",
              run_session(caps, a.n, a.every, a.processes), workers=True)


if __name__ == "__main__":
    main()
