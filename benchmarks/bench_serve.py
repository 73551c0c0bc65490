"""Where the time of one pitch through a warm ``stillcap serve`` goes (issue 16, goal 3b: the CLI
through the server <= 1.3x ``analyse_pitch``), piece by piece, in wall and CPU time.

    python benchmarks/bench_serve.py [--cache DIR] [--repeat 7] [--src SRC]

Rows (each the best and the median of ``--repeat`` runs, wall and CPU time):

- a bare interpreter (``python -c pass``) and the client's own imports (``stillcap._entry`` and
  ``stillcap._server_link``, the fingerprint computed): the client's start;
- ``python -m stillcap pitch CAPTURE --json`` through a warm server (started by the benchmark on
  a socket of its own), as ``bench_speed.py`` times it; CPU: the client process's own;
- the run in the server's fork, from the server's log (fork to reap; its CPU and page faults are
  logged since the server uses ``wait4``; for an older server the CPU is the mean of its reaped
  children's, from /proc);
- outside the run: the whole minus the run (client start, request, reply, client exit);
- ``Capture.load`` + ``analyse_pitch`` in a fork of a process that has imported what the server
  imports (:func:`stillcap.cli._server.preload`), with the settings the server gives its runs,
  against the same in that process once warm (the fork's first-run cost: page faults, threads);
- the run's command line around the analysis: the run in the fork minus the analysis in a fork.

``--src`` runs another tree's stillcap (e.g. an export of main, to compare before and after).
The pitch is ``bench_speed.py``'s (rendered into ``--cache`` once). Timings on a loaded machine
are distorted; the CPU times hold better. Run it on a quiet machine for the wall times.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _self() -> tuple[float, int]:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime, r.ru_minflt


def _process(args, env, repeat):
    """Wall and CPU time of ``repeat`` runs of a subprocess (after one untimed)."""
    walls, cpus = [], []
    for i in range(repeat + 1):
        c, t = _children_cpu(), time.perf_counter()
        subprocess.run(args, env=env, capture_output=True, check=True)
        if i:
            walls.append(time.perf_counter() - t)
            cpus.append(_children_cpu() - c)
    return walls, cpus


LOG_LINE = re.compile(r"run \d+ \(stillcap pitch .*\): exit 0 after ([\d.]+) s(?:; CPU ([\d.]+) s, (\d+) page faults)?")


def _through_server(src: Path, capture: Path, repeat: int):
    """The client's wall and CPU, and the run's wall, CPU and faults from the server's log."""
    folder = tempfile.mkdtemp(prefix="stillcap-bench-serve-")  # mode 0700
    sock = os.path.join(folder, "s.sock")
    env = dict(os.environ, PYTHONPATH=str(src), STILLCAP_SOCKET=sock)
    env.pop("STILLCAP_SERVER", None)
    subprocess.run([sys.executable, "-m", "stillcap", "serve", "--detach", "--idle-timeout", "3600"], env=env,
                   check=True, capture_output=True)
    try:
        said = subprocess.run([sys.executable, "-m", "stillcap", "pitch", str(capture), "--json"], check=True,
                              env=dict(env, STILLCAP_SERVER="verbose"), capture_output=True, text=True).stderr
        if not said.startswith("stillcap: via the server"):
            raise SystemExit(f"the run did not go through the warm server: {said.splitlines()[:1]}")
        pid = json.loads(subprocess.run([sys.executable, "-m", "stillcap", "serve", "--status", "--json"], env=env,
                                        check=True, capture_output=True, text=True).stdout)["pid"]
        before = _reaped_cpu(pid)
        walls, cpus = _process([sys.executable, "-m", "stillcap", "pitch", str(capture), "--json"], env, repeat)
        reaped = (_reaped_cpu(pid) - before) / (repeat + 1)  # _process runs one untimed first
    finally:
        subprocess.run([sys.executable, "-m", "stillcap", "serve", "--stop"], env=env, capture_output=True, check=False)
    runs = [m.groups() for m in LOG_LINE.finditer(Path(sock + ".log").read_text())][-repeat:]
    run_wall = [float(w) for w, _, _ in runs]
    run_cpu = [float(c) for _, c, _ in runs if c is not None]
    faults = [int(f) for _, _, f in runs if f is not None]
    return walls, cpus, run_wall, run_cpu or [reaped], faults


def _reaped_cpu(pid: int) -> float:
    """The CPU time of the server's reaped children (``cutime`` + ``cstime`` of /proc/PID/stat):
    the runs' CPU, in 1/100 s, for a server that does not log it."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[13]) + int(fields[14])) / os.sysconf("SC_CLK_TCK")


FORKED = r"""
import json, os, resource, sys, time
src, capture, repeat = sys.argv[1], sys.argv[2], int(sys.argv[3])
sys.path.insert(0, src)
from stillcap.cli import _server
_server.preload()
from stillcap.io.capture import Capture
from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

def measure():
    r0, t = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    analyse_pitch(Capture.load(capture), PitchOptions())
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    return (time.perf_counter() - t, r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime,
            r1.ru_minflt - r0.ru_minflt)

forked = []
for _ in range(repeat):
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        settings = getattr(_server, "_keep_freed_memory", None)  # what the server does in a run's process
        if settings is not None:
            settings()
        os.write(w, json.dumps(measure()).encode())
        os._exit(0)
    os.close(w)
    with os.fdopen(r) as f:
        forked.append(json.loads(f.read()))
    os.waitpid(pid, 0)
measure()  # warm-up: the parent's first-call costs
parent = [measure() for _ in range(repeat)]
print(json.dumps({"forked": forked, "parent": parent}))
"""


def _forked_vs_parent(src: Path, capture: Path, repeat: int):
    out = subprocess.run([sys.executable, "-c", FORKED, str(src), str(capture), str(repeat)], check=True,
                         capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(src))).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stillcap-bench-speed"))
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--src", type=Path, default=BENCH.parent / "src", help="the stillcap source tree to time")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(BENCH))
    sys.path.insert(0, str(args.src))
    from bench_speed import render

    capture, _ = render(args.cache)
    src = args.src.resolve()
    env = dict(os.environ, PYTHONPATH=str(src))
    bare = _process([sys.executable, "-c", "pass"], env, args.repeat)
    client = _process([sys.executable, "-c", "import stillcap._entry, stillcap._server_link as l; l.fingerprint()"],
                      env, args.repeat)
    whole_wall, whole_cpu, run_wall, run_cpu, faults = _through_server(src, capture, args.repeat)
    fp = _forked_vs_parent(src, capture, args.repeat)
    fork_wall, fork_cpu, fork_faults = ([r[i] for r in fp["forked"]] for i in range(3))
    par_wall, par_cpu, par_faults = ([r[i] for r in fp["parent"]] for i in range(3))

    def pair(values):
        """(best, median) of a list, or a pair already made (:func:`diff`)."""
        if isinstance(values, tuple):
            return values
        return (min(values), statistics.median(values)) if values else None

    def row(what, walls, cpus=(), extra=""):
        w, c = pair(walls), pair(cpus)
        w = f"{w[0]:7.3f} {w[1]:7.3f}" if w else f"{'':7} {'':7}"
        c = f"{c[0]:7.3f} {c[1]:7.3f}" if c else f"{'':7} {'':7}"
        print(f"{what:<66} {w}  {c}  {extra}")

    def diff(a, b):
        """best minus best, median minus median"""
        return (min(a) - min(b), statistics.median(a) - statistics.median(b)) if a and b else ()
    load = os.getloadavg()
    print(f"bench_serve: {src}; {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
          f"{args.repeat} runs each")
    print(f"{'piece (s); differences: best - best, median - median':<66} {'wall':>7} {'median':>7}  "
          f"{'CPU':>7} {'median':>7}")
    row("bare interpreter (python -c pass)", *bare)
    row("client's start: its imports and the fingerprint", *client)
    row("  the same minus the bare interpreter", diff(client[0], bare[0]), diff(client[1], bare[1]))
    row("`stillcap pitch CAPTURE --json` through the warm server (client CPU)", whole_wall, whole_cpu)
    row("  the run in the server's fork (server log: fork to reap)", run_wall, run_cpu,
        f"page faults {statistics.median(faults):.0f}" if faults else "(CPU not logged by this server)")
    row("  outside the run: client start, request, reply, exit", diff(whole_wall, run_wall))
    row("analyse_pitch in a fork of a preloaded process (first run)", fork_wall, fork_cpu,
        f"page faults {statistics.median(fork_faults):.0f}")
    row("analyse_pitch in that process, warm", par_wall, par_cpu, f"page faults {statistics.median(par_faults):.0f}")
    row("  the fork's first-run cost (fork minus warm)", diff(fork_wall, par_wall), diff(fork_cpu, par_cpu))
    row("  the run's command line around the analysis (run minus fork)", diff(run_wall, fork_wall),
        diff(run_cpu, fork_cpu) if run_cpu else ())
    row("whole through the server vs analyse_pitch warm: ratio", [w / min(par_wall) for w in whole_wall])


if __name__ == "__main__":
    main()
