"""Start-up time of the command line: ``stillcap ... --help`` and ``stillcap pitch CAPTURE --json``
as fresh processes.

    python benchmarks/bench_cli_startup.py [--repeat 10] [--pitch-repeat 5] [--cache DIR] [--importtime N]

Each command runs ``--repeat`` times as a subprocess (``python -m stillcap``, which imports what
the ``stillcap`` script imports) after one untimed warm-up run; the tables give the median and
the shortest wall time, and the shortest CPU time (user + system, the process's own: on a
loaded machine it moves far less than the wall time). Commands import their heavy modules
(NumPy, SciPy, OpenCV, the pipelines) only when they run, and ``main`` builds only the command
it runs, so ``--help`` costs Python, typer and rich plus one command's definition. For
reference, the floors: an empty Python, ``import typer`` and ``--help`` of a one-command typer
app.

The second table is issue 16's goal 2, one pitch through the CLI: the JPEG pitch of
``bench_speed.py`` (rendered into ``--cache`` once), as ``python -m stillcap pitch CAP --json``,
and what each start-up measure saves, by switching it off in an otherwise identical process
(``main`` without ``run``'s GC freeze at exit; ``Capture.start_decoding`` made a no-op, so the
pipeline decodes the photos itself after its imports), against ``Capture.load`` +
``analyse_pitch`` in process (warm: imports and first-call costs left out; best of
``--pitch-repeat``). Goal: the CLI <= 1.3x that. ``--importtime N`` prints the N modules of the
command's start-up with the largest own import time (``python -X importtime``, the least of
three runs), summed by top-level package too.

The processes keep stillcap's bytecode in ``--cache``/pycache (``PYTHONPYCACHEPREFIX``), as an
installed package has it, also where ``PYTHONDONTWRITEBYTECODE`` is set (the development
machine sets it: every process then compiles stillcap's modules again; one row shows that).

Every process runs the command itself (``STILLCAP_SERVER=off``): the run through a warm
``stillcap serve`` is a row of ``bench_speed.py`` (docs/serve.md).

Run it on a quiet machine: on a loaded one every ratio is distorted (a fresh process's one-off
costs suffer most, and the decoding ahead needs the second core to be free).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from rich.console import Console
from rich.table import Table

SRC = Path(__file__).resolve().parents[1] / "src"
sys.path.insert(0, str(SRC))  # this tree's stillcap, here and in the processes started
GOAL_S = 0.3
PITCH_GOAL = 1.3
COMMANDS = ("--help", "pitch --help", "puppet run --help", "hand --help", "studio pitch --help")
TYPER_APP = ("import typer\napp = typer.Typer()\n@app.command()\ndef f(x: int = typer.Option(1, help='x')):\n"
             "    '''One command.'''\napp()\n")
FLOORS = (("python -c pass", ["-c", "pass"]),
          ('python -c "import typer"', ["-c", "import typer"]),
          ("a one-command typer app --help", ["-c", TYPER_APP, "--help"]))
# the pitch command with one start-up measure switched off (argv: the capture)
NO_FREEZE = "import sys\nfrom stillcap.cli import main\nmain(['pitch', sys.argv[1], '--json'])\n"
NO_DECODING_AHEAD = ("import sys\nfrom stillcap.io.capture import Capture\nCapture.start_decoding = lambda self, "
                     "images=None: None\nfrom stillcap.cli import run\nsys.argv = ['stillcap', 'pitch', sys.argv[1], "
                     "'--json']\nrun()\n")
PITCH_IMPORTS = "import stillcap.cli.pitch, stillcap.io.capture, stillcap.pipelines.pitch"


PYCACHE: Path | None = None  # where the processes keep stillcap's bytecode (main() sets it)


def _env(bytecode: bool = True) -> dict:
    """The processes' environment: this tree's ``src`` first; with ``bytecode``, stillcap's compiled
    modules kept in :data:`PYCACHE` (as an installed package has them: a process started with
    ``PYTHONDONTWRITEBYTECODE`` compiles every stillcap module from source, ~0.1 s)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]),
               STILLCAP_SERVER="off")  # each run in its own process, even when a `stillcap serve` runs
    if bytecode and PYCACHE is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(PYCACHE)
    else:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def times(args: list[str], repeat: int, bytecode: bool = True) -> tuple[list[float], list[float]]:
    """Wall and CPU (user + system) seconds of ``repeat`` runs of ``python ARGS`` (after one
    untimed run, which also compiles the bytecode)."""
    cmd, env = [sys.executable, *args], _env(bytecode)
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    wall, cpu = [], []
    for _ in range(repeat):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        wall.append(time.perf_counter() - t)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
    return wall, cpu


def in_process_pitch(capture: Path, repeat: int) -> float:
    """Best wall seconds of ``Capture.load`` + ``analyse_pitch`` (threads, default options), warm."""
    from _timing import best_time

    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

    analyse_pitch(Capture.load(capture), PitchOptions())  # first-call costs belong to the CLI's process
    return best_time(lambda: analyse_pitch(Capture.load(capture), PitchOptions()), repeat)


def importtime(args: list[str], top: int) -> None:
    """The ``top`` modules with the largest own import time (least of 3 runs), and the sums by package."""
    own: dict[str, int] = {}
    for _ in range(3):
        r = subprocess.run([sys.executable, "-X", "importtime", *args], check=True, capture_output=True, text=True,
                           env=_env())
        for line in r.stderr.splitlines():
            if line.startswith("import time:") and "self [us]" not in line:
                us, _cum, name = line[len("import time:"):].split("|")
                name = name.strip()
                own[name] = min(own.get(name, 1 << 62), int(us))
    by_package = Counter()
    for name, us in own.items():
        by_package[name.split(".")[0]] += us
    t = Table(title=f"python -X importtime {' '.join(args)}: own import time, least of 3 runs "
                    f"(total {sum(own.values()) / 1e3:.0f} ms, {len(own)} modules)")
    for c in ("module", "ms", "package", "package ms"):
        t.add_column(c, justify="left" if "ms" not in c else "right")
    mods, pkgs = sorted(own.items(), key=lambda kv: -kv[1])[:top], by_package.most_common(top)
    for i in range(top):
        m = mods[i] if i < len(mods) else ("", 0)
        p = pkgs[i] if i < len(pkgs) else ("", 0)
        t.add_row(m[0], f"{m[1] / 1e3:.1f}" if m[0] else "", p[0], f"{p[1] / 1e3:.1f}" if p[0] else "")
    Console(width=150).print(t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10, help="Runs per --help command (default 10).")
    ap.add_argument("--pitch-repeat", type=int, default=5, help="Runs per pitch row (default 5; 0: no pitch table).")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stillcap-bench-speed"),
                    help="Where bench_speed.py's captures are (rendered there once).")
    ap.add_argument("--importtime", type=int, default=0, metavar="N",
                    help="Also print the N largest own import times of the pitch command.")
    args = ap.parse_args()
    global PYCACHE
    PYCACHE = args.cache / "pycache"
    t = Table(title=f"stillcap start-up: seconds over {args.repeat} runs each")
    for c in ("command", "median s", "min s", "min CPU s", "goal s", "ratio to goal"):
        t.add_column(c, justify="right" if c != "command" else "left")
    for command in COMMANDS:
        wall, cpu = times(["-m", "stillcap", *command.split()], args.repeat)
        med = statistics.median(wall)
        t.add_row(f"stillcap {command}", f"{med:.3f}", f"{min(wall):.3f}", f"{min(cpu):.3f}", f"{GOAL_S:g}",
                  f"{med / GOAL_S:.2f}")
    t.add_section()
    for name, floor in FLOORS:
        wall, cpu = times(floor, args.repeat)
        t.add_row(f"[dim]{name}[/]", f"{statistics.median(wall):.3f}", f"{min(wall):.3f}", f"{min(cpu):.3f}", "-", "-")
    Console(width=150).print(t)
    if args.pitch_repeat <= 0:
        return
    from bench_speed import render

    capture, _ = render(args.cache)
    n = args.pitch_repeat
    inproc = in_process_pitch(capture, n)
    p = Table(title=f"stillcap pitch {capture.name} --json (fresh process) vs analyse_pitch in process; "
                    f"best of {n}")
    for c in ("run", "min s", "median s", "min CPU s", "ratio to analyse_pitch", "goal"):
        p.add_column(c, justify="right" if c != "run" else "left")
    rows = (("python -m stillcap pitch CAP --json", ["-m", "stillcap", "pitch", str(capture), "--json"]),
            ("  without the GC freeze at exit", ["-c", NO_FREEZE, str(capture)]),
            ("  without decoding the photos ahead", ["-c", NO_DECODING_AHEAD, str(capture)]),
            ("  without bytecode (PYTHONDONTWRITEBYTECODE)", ["-m", "stillcap", "pitch", str(capture), "--json"]),
            ("[dim]imports of the pitch path only[/]", ["-c", PITCH_IMPORTS]),
            ("[dim]python -c pass[/]", ["-c", "pass"]))
    for i, (name, argv) in enumerate(rows):
        wall, cpu = times(argv, n, bytecode="bytecode" not in name)
        p.add_row(name, f"{min(wall):.3f}", f"{statistics.median(wall):.3f}", f"{min(cpu):.3f}",
                  f"{min(wall) / inproc:.2f}", f"<= {PITCH_GOAL:g}" if i == 0 else "")
    p.add_section()
    p.add_row("Capture.load + analyse_pitch (in process, warm)", f"{inproc:.3f}", "", "", "1.00", "")
    Console(width=150).print(p)
    if args.importtime:
        importtime(["-m", "stillcap", "pitch", str(capture), "--json"], args.importtime)


if __name__ == "__main__":
    main()
