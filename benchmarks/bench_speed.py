"""Speed of one capture: three ratios and their goals in one table (issue 16).

1. ``Capture.load`` + ``analyse_pitch`` of one pitch capture (threads, the default options) vs
   decoding its 4 JPEGs (``cv2.imread`` one after the other). Goal <= 2x.
2. The CLI's wall time for that capture (``python -m stillcap pitch CAPTURE --json`` as a fresh
   process) vs 1. Goal <= 1.3x. Two rows: the command in its own process (``STILLCAP_SERVER=off``:
   interpreter and imports included), and through a warm ``stillcap serve`` (started by the
   benchmark on a socket of its own before the timing, docs/serve.md: the command's process is
   the interpreter and the client, the run a fork of the server, which has the imports done).
   The server's own start (its imports, once) is printed below the table. Beside them: with no
   server running, the first run (in its own process; it then starts a server in the background,
   docs/serve.md) and the run right after it (in its own process too while that server imports).
3. The puppet end to end, loading included (a fresh process: ``analyse_puppet`` on the capture
   folder, its first call, so every set-up it does once is counted; imports are not) vs decoding
   its 12 JPEGs. Goal <= 4x. Beside it: its CPU time (all threads of that process: the first call
   uses two, one decoding while the other detects) against the decode's, which holds better than
   the wall times on a loaded machine; the same call again in that process (warm); and the
   import of ``stillcap.pipelines.puppet`` plus the first call.

Beside row 1, for comparison (no goal): ``analyse_pitch`` with ``processes=2`` (each stereo pair's
work in a worker process of a pool started before the timing), and the CPU time of row 1 (all
threads of the process) against the decode's. The CPU ratio holds on a loaded machine, where the
wall times do not; on two idle cores the threads overlap little beyond decoding (the stages after
it hold the GIL), so row 1's wall is close to its CPU, while worker processes run the two pairs'
work (ball images, markers, the pair's spin, the response estimates) side by side.

Every time is the best of ``--repeat`` runs (the least disturbed by other work). The captures are
rendered by the studio into ``--cache`` once (a 2560x1920 JPEG pitch, a 640x480 JPEG puppet of 12
views), so the benchmark needs no folder from elsewhere. Run it on a quiet machine: on a loaded
one every ratio is distorted (the one-off costs of a fresh process suffer most).

    python benchmarks/bench_speed.py [--cache DIR] [--repeat 3] [--pitch-only] [--switch-interval MS]

``--pitch-only``: the pitch rows only (rows 1 and 2, without the puppet's); ``--puppet-only``: the
puppet's rows only (row 3). Row 3 for two code versions, alternated round by round (their ratio
to the same decode, and their CPU): ``bench_puppet_timeline.py --tree OLD/src --tree NEW/src``. ``--switch-interval MS``: row 1 again with Python's GIL hand-over
interval set to MS milliseconds (default 5): a thread that released the GIL for an OpenCV call or
a decode may wait up to that long to take it back from a thread running Python (the "convoy"
effect), so on threads a shorter interval may overlap the capture's GIL-free work better (not
measurable on a loaded machine; issue 16).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import cv2

from _timing import best_time

SRC = Path(__file__).resolve().parents[1] / "src"
# this tree's stillcap, in this process as in the ones it starts (not whichever is installed)
sys.path.insert(0, str(SRC))
PUPPET_RUN = r"""
import json, sys, time
t = time.perf_counter()
from stillcap.pipelines.puppet import DEFAULT, analyse_puppet
imp = time.perf_counter() - t
t, c = time.perf_counter(), time.process_time()
analyse_puppet(sys.argv[1], DEFAULT)
cold, cold_cpu = time.perf_counter() - t, time.process_time() - c
t = time.perf_counter(); analyse_puppet(sys.argv[1], DEFAULT); warm = time.perf_counter() - t
print(json.dumps({"cold": cold, "cold_cpu": cold_cpu, "warm": warm, "import": imp}))
"""


def _env(**extra):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]))
    env.pop("STILLCAP_SOCKET", None)
    env.update(extra)
    return env


def auto_started(cli, repeat: int) -> tuple[float, float]:
    """Best wall seconds of the first run with no server running (``STILLCAP_SERVER`` unset: it
    runs in its own process, then starts a server) and of the run right after it (in its own
    process too while that server imports), each pair on a socket of its own."""
    firsts, seconds = [], []
    for _ in range(repeat):
        folder = tempfile.mkdtemp(prefix="stillcap-bench-")  # mode 0700
        env = _env(STILLCAP_SOCKET=os.path.join(folder, "s.sock"))
        env.pop("STILLCAP_SERVER", None)
        try:
            t = time.perf_counter()
            cli(env)
            firsts.append(time.perf_counter() - t)
            t = time.perf_counter()
            cli(env)
            seconds.append(time.perf_counter() - t)
        finally:
            subprocess.run([sys.executable, "-m", "stillcap", "serve", "--stop"], env=env, capture_output=True)
    return min(firsts), min(seconds)


@contextmanager
def warm_server():
    """A ``stillcap serve`` on a socket in a private temporary folder, listening (imports done):
    the environment for its clients, the seconds its imports took and its log's path."""
    folder = tempfile.mkdtemp(prefix="stillcap-bench-")  # mode 0700
    sock = os.path.join(folder, "s.sock")
    env = _env(STILLCAP_SOCKET=sock)
    subprocess.run([sys.executable, "-m", "stillcap", "serve", "--detach", "--idle-timeout", "3600"], check=True,
                   env=env, capture_output=True)
    try:
        st = subprocess.run([sys.executable, "-m", "stillcap", "serve", "--status", "--json"], check=True, env=env,
                            capture_output=True, text=True)
        yield env, json.loads(st.stdout)["preload_s"], sock + ".log"
    finally:
        subprocess.run([sys.executable, "-m", "stillcap", "serve", "--stop"], env=env, capture_output=True)


def render(cache: Path) -> tuple[Path, Path]:
    """The pitch and puppet captures of the benchmark (rendered once into ``cache``)."""
    pitch, puppet = cache / "pitch-seed-4seam-1-jpg", cache / "puppet-16-0-jpg"
    if not (pitch / "capture.json").is_file():
        from stillcap.studio.pitch import pitch_capture

        cap, images = pitch_capture("seed-4seam", 1, calibrate=False).to_capture(".jpg")
        cap.save(pitch, images, jpeg_quality=95)
    if not (puppet / "capture.json").is_file():
        subprocess.run([sys.executable, "-m", "stillcap", "studio", "puppet", "--out", str(puppet), "--seed", "0"],
                       check=True, env=_env(), capture_output=True)
    return pitch, puppet


def decode(folder: Path, repeat: int, cpu: bool = False):
    """Best wall time of decoding the folder's JPEGs one after the other (and its best CPU time)."""
    files = sorted(str(p) for p in (folder / "images").iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
    wall, cpu_s = best_wall_cpu(lambda: [cv2.imread(f) for f in files], repeat)
    return (wall, cpu_s) if cpu else wall


def best_wall_cpu(fn, repeat: int) -> tuple[float, float]:
    """The shortest wall time and the shortest CPU time (``time.process_time``: every thread of
    this process, not its worker processes) of ``repeat`` runs of ``fn()``."""
    walls, cpus = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    return min(walls), min(cpus)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stillcap-bench-speed"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--pitch-only", action="store_true", help="the pitch rows only (no puppet)")
    ap.add_argument("--puppet-only", action="store_true", help="the puppet's rows only (no pitch)")
    ap.add_argument("--switch-interval", type=float, default=None, metavar="MS",
                    help="also row 1 with sys.setswitchinterval(MS / 1000) (Python's default 5 ms), for comparison")
    args = ap.parse_args(argv)
    if args.pitch_only and args.puppet_only:
        raise SystemExit("give --pitch-only or --puppet-only, not both")
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

    pitch, puppet = render(args.cache)
    n_pitch = len(list((pitch / "images").iterdir()))
    n_puppet = len(list((puppet / "images").iterdir()))
    if args.puppet_only:
        return _puppet_only(args, puppet, n_puppet)
    dec_pitch, dec_pitch_cpu = decode(pitch, args.repeat, cpu=True)
    analyse_pitch(Capture.load(pitch), PitchOptions())  # warm-up: first-call costs belong to row 2's process
    api, api_cpu = best_wall_cpu(lambda: analyse_pitch(Capture.load(pitch), PitchOptions()), args.repeat)
    api_switch = None
    if args.switch_interval is not None:  # the same with a shorter (or longer) GIL hand-over interval
        before = sys.getswitchinterval()
        sys.setswitchinterval(args.switch_interval / 1000.0)
        try:
            api_switch = best_time(lambda: analyse_pitch(Capture.load(pitch), PitchOptions()), args.repeat)
        finally:
            sys.setswitchinterval(before)
    # for comparison: the pairs' work in 2 worker processes (the pool started by the warm-up)
    analyse_pitch(Capture.load(pitch), PitchOptions(processes=2))
    api_proc = best_time(lambda: analyse_pitch(Capture.load(pitch), PitchOptions(processes=2)), args.repeat)

    def cli(env):
        return subprocess.run([sys.executable, "-m", "stillcap", "pitch", str(pitch), "--json"], check=True,
                              env=env, capture_output=True, text=True)
    wall = best_time(lambda: cli(_env(STILLCAP_SERVER="off")), args.repeat)
    first, second = auto_started(cli, args.repeat)
    with warm_server() as (env, preload_s, log):
        said = cli(dict(env, STILLCAP_SERVER="verbose")).stderr  # untimed: check that the runs go through it
        if not said.startswith("stillcap: via the server"):
            raise SystemExit(f"the run did not go through the warm server: {said.splitlines()[:1]}")
        wall_warm = best_time(lambda: cli(env), args.repeat)
        # the runs in the server's forks (fork to reap), as its log gives them (docs/serve.md)
        forks = [(float(w), float(c)) for w, c in re.findall(r"exit 0 after ([\d.]+) s; CPU ([\d.]+) s", Path(log).read_text())]
    runs = []
    for _ in range(0 if args.pitch_only else args.repeat):
        p = subprocess.run([sys.executable, "-c", PUPPET_RUN, str(puppet)], check=True, env=_env(),
                           capture_output=True, text=True)
        runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    if not args.pitch_only:
        dec_puppet, dec_puppet_cpu = decode(puppet, args.repeat, cpu=True)
        cold, warm = min(r["cold"] for r in runs), min(r["warm"] for r in runs)
        cold_cpu = min(r["cold_cpu"] for r in runs)
        imp = min(r["import"] for r in runs)
    rows = [(f"analyse_pitch (load included, threads) vs decoding its {n_pitch} JPEGs", api, dec_pitch, 2.0),
            ("  (the same, CPU time of all its threads vs the decode's CPU time, for comparison)", api_cpu,
             dec_pitch_cpu, None),
            ("  (the same with processes=2, worker pool started before, for comparison)", api_proc, dec_pitch, None),
            *([] if api_switch is None else [
                (f"  (the same on threads with sys.setswitchinterval({args.switch_interval:g} ms), for comparison)",
                 api_switch, dec_pitch, None)]),
            ("`stillcap pitch CAPTURE --json` wall time vs analyse_pitch (its own process)", wall, api, 1.3),
            ("`stillcap pitch CAPTURE --json` through a warm `stillcap serve` vs analyse_pitch", wall_warm, api, 1.3),
            ("  (no server running: the first run, in its own process, then starting one)", first, api, None),
            ("  (the run right after it, in its own process while that server imports)", second, api, None)]
    rows += [] if args.pitch_only else [
            (f"puppet end to end, loading included (first call) vs decoding its {n_puppet} JPEGs", cold, dec_puppet, 4.0),
            ("  (the same, CPU time of all its threads vs the decode's CPU time, for comparison)", cold_cpu,
             dec_puppet_cpu, None),
            (f"  (the same call again in that process, for comparison)", warm, dec_puppet, None),
            (f"  (import stillcap.pipelines.puppet, which loads io.capture's schema, + the first call)", imp + cold,
             dec_puppet, None)]
    load = os.getloadavg()
    print(f"bench_speed: {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
          f"best of {args.repeat}")
    print(f"{'ratio':<86} {'time s':>8} {'ref s':>8} {'ratio':>6} {'goal':>6}  met")
    for what, t, ref, goal in rows:
        r = t / ref
        met = "" if goal is None else ("yes" if r <= goal else "MISSED")
        print(f"{what:<86} {t:8.3f} {ref:8.3f} {r:6.2f} {'' if goal is None else f'<= {goal:g}':>6}  {met}")
    print(f"(the warm server's imports, once at its start: {preload_s:.3f} s)")
    if forks:
        print(f"(the runs in the warm server's forks, fork to reap, from its log: best wall {min(w for w, _ in forks):.3f} s, "
              f"best CPU {min(c for _, c in forks):.3f} s; benchmarks/bench_serve.py splits the rest)")



def _puppet_only(args, puppet: Path, n_puppet: int) -> None:
    """``--puppet-only``: row 3 and its comparison rows."""
    runs = []
    for _ in range(args.repeat):
        p = subprocess.run([sys.executable, "-c", PUPPET_RUN, str(puppet)], check=True, env=_env(),
                           capture_output=True, text=True)
        runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    dec, dec_cpu = decode(puppet, args.repeat, cpu=True)
    cold, warm = min(r["cold"] for r in runs), min(r["warm"] for r in runs)
    cold_cpu, imp = min(r["cold_cpu"] for r in runs), min(r["import"] for r in runs)
    load = os.getloadavg()
    print(f"bench_speed --puppet-only: {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} "
          f"{load[2]:.2f}; best of {args.repeat}")
    print(f"{'ratio':<86} {'time s':>8} {'ref s':>8} {'ratio':>6} {'goal':>6}  met")
    for what, t, ref, goal in [
            (f"puppet end to end, loading included (first call) vs decoding its {n_puppet} JPEGs", cold, dec, 4.0),
            ("  (the same, CPU time of all its threads vs the decode's CPU time, for comparison)", cold_cpu, dec_cpu,
             None),
            ("  (the same call again in that process, for comparison)", warm, dec, None),
            ("  (import stillcap.pipelines.puppet, which loads io.capture's schema, + the first call)", imp + cold,
             dec, None)]:
        r = t / ref
        met = "" if goal is None else ("yes" if r <= goal else "MISSED")
        print(f"{what:<86} {t:8.3f} {ref:8.3f} {r:6.2f} {'' if goal is None else f'<= {goal:g}':>6}  {met}")


if __name__ == "__main__":
    main()
