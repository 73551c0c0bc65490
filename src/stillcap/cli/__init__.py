"""The ``stillcap`` command line: parses arguments and calls pipelines, nothing more.

Each command group lives in its own module (``cli/calibrate.py``, ``cli/studio.py``, ...).
Errors a user can fix (bad file, missing camera, bad option) are ``ValueError``s raised by the
library; :func:`main` prints them in one red line and exits with status 2, as it does a file
that cannot be read or written (an ``OSError``: no permission, a full disk).

Start-up: :func:`main` imports only the module of the command it runs (``stillcap pitch ...``
builds an app holding ``pitch`` alone, from :data:`COMMANDS`); ``stillcap --help``, a name that
is no command and :data:`app` build every command. ``tests/test_cli_lazy.py`` checks that each
one-command app gives its command exactly as the full app does.
"""

from __future__ import annotations

import sys
from importlib import import_module

import typer

#: Every command in the order ``stillcap --help`` lists them: name -> (module under
#: ``stillcap.cli``, attribute, ``"group"`` for a typer sub-app or ``"command"`` for a function).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "calibrate": ("calibrate", "app", "group"),
    "studio": ("studio", "app", "group"),
    "demo": ("demo", "demo", "command"),
    "markers": ("markers", "markers", "command"),
    "puppet": ("puppet", "app", "group"),
    "export": ("export", "export", "command"),
    "palette": ("palette", "palette", "command"),
    "pitch": ("pitch", "pitch", "command"),
    "hand": ("hand", "hand", "command"),
    "hand-calibrate": ("hand_calibrate", "hand_calibrate", "command"),
    "flight": ("flight", "flight", "command"),
    "metrics": ("metrics", "metrics", "command"),
    "gui": ("gui", "gui", "command"),
    "batch": ("batch", "batch", "command"),
    "balls": ("balls", "app", "group"),
    "serve": ("serve", "serve", "command"),
}
HELP = "stillcap: optical motion capture from still photographs."


def _one_group() -> None:
    """(The callback of a one-command app: it keeps the app a group, so that the command is
    still called by its name, as in the full app.)"""


def build_app(only: str | None = None) -> typer.Typer:
    """The typer app with every command, or with the command ``only`` alone (its module is then
    the only command module imported)."""
    app = typer.Typer(no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False, help=HELP)
    if only is not None:
        app.callback()(_one_group)
    for name, (module, attr, kind) in COMMANDS.items():
        if only is not None and name != only:
            continue
        obj = getattr(import_module(f"stillcap.cli.{module}"), attr)
        if kind == "group":
            app.add_typer(obj, name=name)
        else:
            app.command(name)(obj)
    return app


_full_app: typer.Typer | None = None


def __getattr__(name: str):
    """``stillcap.cli.app``: the full app, built when first asked for (PEP 562)."""
    global _full_app
    if name == "app":
        if _full_app is None:
            _full_app = build_app()
        return _full_app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _err():
    from rich.console import Console

    return Console(stderr=True)


def main(argv=None) -> None:
    """Run the CLI. Usage errors are click's (exit 2); a ValueError from the library, i.e. bad
    input the user can fix, prints one red line and exits 2; anything else is a bug and shows
    its traceback. Returns normally on success (so that it can be called from Python)."""
    args = list(sys.argv[1:] if argv is None else argv)
    command = args[0] if args and args[0] in COMMANDS else None
    the_app = build_app(command) if command is not None else __getattr__("app")
    try:
        the_app(args=args, prog_name="stillcap")
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    except (ValueError, FileNotFoundError) as e:
        from rich.markup import escape

        # escaped: names read from files are not rich markup ("[/x]" would crash the printing)
        _err().print(f"[bold red]error:[/] {escape(str(e))}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except OSError as e:  # reading or writing a file failed (permission, full disk): the place, not a bug
        from stillcap.cli._outputs import oserror_text

        _err().print(f"[bold red]error:[/] {oserror_text(e)}", highlight=False, soft_wrap=True)
        sys.exit(2)


def run() -> None:
    """A run of the ``stillcap`` command in this process (:func:`stillcap._entry.run`, the script's
    and ``python -m stillcap``'s entry point, calls it when no warm server takes the run): :func:`main`,
    then the objects left are frozen out of the garbage collector, so that the interpreter's exit
    does not walk all of them once more (SciPy's and the pipelines' modules hold about a million:
    ~0.1 s of every run). Not in :func:`main`, which Python callers (the tests) use in a process
    that goes on."""
    import gc

    try:
        main()
    finally:
        gc.freeze()
