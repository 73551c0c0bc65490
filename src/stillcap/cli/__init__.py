"""The ``stillcap`` command line: parses arguments and calls pipelines, nothing more.

Each command group lives in its own module (``cli/calibrate.py``, ``cli/studio.py``, ...).
Errors a user can fix (bad file, missing camera, bad option) are ``ValueError``s raised by the
library; :func:`main` prints them in one red line and exits with status 2, as it does a file
that cannot be read or written (an ``OSError``: no permission, a full disk).
"""

from __future__ import annotations

import sys

import typer
from rich.console import Console
from rich.markup import escape

from stillcap.cli import balls as balls_cli, batch as batch_cli, calibrate, demo, markers, studio
from stillcap.cli import export as export_cli, palette as palette_cli, puppet as puppet_cli
from stillcap.cli import flight as flight_cli, hand as hand_cli, hand_calibrate as hand_calibrate_cli
from stillcap.cli import metrics as metrics_cli, pitch as pitch_cli
from stillcap.cli import gui as gui_cli

app = typer.Typer(no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                  help="stillcap: optical motion capture from still photographs.")
app.add_typer(calibrate.app, name="calibrate")
app.add_typer(studio.app, name="studio")
app.command("demo")(demo.demo)
app.command("markers")(markers.markers)
app.add_typer(puppet_cli.app, name="puppet")
app.command("export")(export_cli.export)
app.command("palette")(palette_cli.palette)
app.command("pitch")(pitch_cli.pitch)
app.command("hand")(hand_cli.hand)
app.command("hand-calibrate")(hand_calibrate_cli.hand_calibrate)
app.command("flight")(flight_cli.flight)
app.command("metrics")(metrics_cli.metrics)
app.command("gui")(gui_cli.gui)
app.command("batch")(batch_cli.batch)
app.add_typer(balls_cli.app, name="balls")

err = Console(stderr=True)


def main(argv=None) -> None:
    """Run the CLI. Usage errors are click's (exit 2); a ValueError from the library, i.e. bad
    input the user can fix, prints one red line and exits 2; anything else is a bug and shows
    its traceback. Returns normally on success (so that it can be called from Python)."""
    try:
        app(args=argv, prog_name="stillcap")
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    except (ValueError, FileNotFoundError) as e:
        # escaped: names read from files are not rich markup ("[/x]" would crash the printing)
        err.print(f"[bold red]error:[/] {escape(str(e))}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except OSError as e:  # reading or writing a file failed (permission, full disk): the place, not a bug
        from stillcap.cli._outputs import oserror_text

        err.print(f"[bold red]error:[/] {oserror_text(e)}", highlight=False, soft_wrap=True)
        sys.exit(2)
