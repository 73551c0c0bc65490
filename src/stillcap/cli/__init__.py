"""The ``stillcap`` command line: parses arguments and calls pipelines, nothing more.

Each command group lives in its own module (``cli/calibrate.py``, ``cli/studio.py``, ...).
Errors a user can fix (bad file, missing camera, bad option) are ``ValueError``s raised by the
library; :func:`main` prints them in one red line and exits with status 2.
"""

from __future__ import annotations

import sys

import typer
from rich.console import Console

from stillcap.cli import calibrate, demo, studio

app = typer.Typer(no_args_is_help=True, add_completion=False,
                  help="stillcap: optical motion capture from still photographs.")
app.add_typer(calibrate.app, name="calibrate")
app.add_typer(studio.app, name="studio")
app.command("demo")(demo.demo)

err = Console(stderr=True)


def main(argv=None) -> None:
    try:
        app(args=argv, prog_name="stillcap", standalone_mode=False)
    except (ValueError, FileNotFoundError) as e:
        err.print(f"[bold red]error:[/] {e}", highlight=False)
        sys.exit(2)
    except typer.Exit as e:
        sys.exit(e.exit_code)
    except typer.Abort:
        err.print("aborted")
        sys.exit(130)
    except Exception as e:  # click usage errors arrive here in non-standalone mode
        import click

        if isinstance(e, click.ClickException):
            e.show()
            sys.exit(e.exit_code)
        raise
