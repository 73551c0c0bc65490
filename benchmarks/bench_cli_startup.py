"""Start-up time of the command line: ``stillcap ... --help`` as a fresh process.

    python benchmarks/bench_cli_startup.py [--repeat 10]

Each command runs ``--repeat`` times as a subprocess (``python -m stillcap``, which imports what
the ``stillcap`` script imports) after one untimed warm-up run; the table gives the median and
the shortest wall time and the ratio of the median to the 0.3 s goal. Commands import their
heavy modules (NumPy, SciPy, OpenCV, the pipelines) only when they run, so ``--help`` costs
Python, typer and rich plus the command definitions. For reference, the floors: an empty Python,
``import typer`` and ``--help`` of a one-command typer app.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

from rich.console import Console
from rich.table import Table

GOAL_S = 0.3
COMMANDS = ("--help", "pitch --help", "puppet run --help", "hand --help", "studio pitch --help")
TYPER_APP = ("import typer\napp = typer.Typer()\n@app.command()\ndef f(x: int = typer.Option(1, help='x')):\n"
             "    '''One command.'''\napp()\n")
FLOORS = (("python -c pass", ["-c", "pass"]),
          ('python -c "import typer"', ["-c", "import typer"]),
          ("a one-command typer app --help", ["-c", TYPER_APP, "--help"]))


def wall_times(args: list[str], repeat: int) -> list[float]:
    """Wall seconds of ``repeat`` runs of ``python ARGS`` (after one untimed run)."""
    cmd = [sys.executable, *args]
    subprocess.run(cmd, check=True, capture_output=True)
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        times.append(time.perf_counter() - t)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10, help="Runs per command (default 10).")
    args = ap.parse_args()
    t = Table(title=f"stillcap start-up: wall seconds over {args.repeat} runs each")
    for c in ("command", "median s", "min s", "goal s", "ratio to goal"):
        t.add_column(c, justify="right" if c != "command" else "left")
    for command in COMMANDS:
        times = wall_times(["-m", "stillcap", *command.split()], args.repeat)
        med = statistics.median(times)
        t.add_row(f"stillcap {command}", f"{med:.3f}", f"{min(times):.3f}", f"{GOAL_S:g}", f"{med / GOAL_S:.2f}")
    t.add_section()
    for name, floor in FLOORS:
        times = wall_times(floor, args.repeat)
        t.add_row(f"[dim]{name}[/]", f"{statistics.median(times):.3f}", f"{min(times):.3f}", "-", "-")
    Console().print(t)


if __name__ == "__main__":
    main()
