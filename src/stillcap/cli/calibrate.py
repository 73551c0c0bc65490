"""`stillcap calibrate ...` commands."""

import typer

app = typer.Typer(no_args_is_help=True, help="calibrate commands")
