"""A command's outputs: checked before its work (``check``), written after it without losing the
result when the writing fails (:class:`Outputs`).

See :mod:`stillcap.files.outputs` for what counts as a stillcap output and ``docs/errors.md``
for the messages.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import typer
from rich.console import Console

from stillcap.files.outputs import check_writable, record_outputs, save_fallback

__all__ = ["Outputs", "check", "oserror_text"]

err = Console(stderr=True, highlight=False)


def check(path: Path | None, kind: str, option: str, force: bool = False, names=None) -> None:
    """:func:`stillcap.files.outputs.check_writable` for an optional CLI path (None: not asked)."""
    if path is not None:
        check_writable(path, kind, option=option, force=force, names=names)


def oserror_text(e: OSError) -> str:
    """``FILE: reason`` of an OSError (``[Errno 28] No space left on device: 'x'`` reads badly)."""
    why = e.strerror or str(e) or type(e).__name__
    return f"{e.filename}: {why}" if e.filename else why


class Outputs:
    """The writing of one command's outputs after its analysis.

    Each output is written inside ``with outputs.writing("--report out"):``; an ``OSError``
    there (disk full, folder removed or made read-only meanwhile) is kept, and the other outputs
    and the printing go on. :meth:`finish` then saves the result as JSON in a temporary folder
    (or prints it on stdout when even that fails), prints one line per failed output naming
    where the result went, and exits with status 2.

    Parameters
    ----------
    result_json : callable
        Gives the result as JSON text (called only when a write failed).
    name : str
        File name of the saved result (``pitch.json``).
    """

    def __init__(self, result_json: Callable[[], str], name: str):
        self.result_json = result_json
        self.name = name
        self.failed: list[tuple[str, OSError]] = []

    @contextmanager
    def writing(self, what: str):
        """Write one output (``what``: the option and its path, for the message)."""
        try:
            yield
        except OSError as e:
            self.failed.append((what, e))

    def claim(self, folder: Path, names) -> None:
        """Record the files about to be written in ``folder`` (``names``: relative paths or glob
        patterns) as stillcap's, so that a report cut short is still recognised as stillcap's."""
        record_outputs([Path(folder) / n for n in names], folder)

    def record(self, paths, root=None) -> None:
        """Record written files as stillcap outputs (:func:`stillcap.files.outputs.record_outputs`)."""
        record_outputs([p for p in paths if p is not None], root)

    def finish(self, printed_json: bool = False) -> None:
        """Nothing when every output was written; else save the result, name where, exit 2."""
        if not self.failed:
            return
        text = self.result_json()
        saved = save_fallback(text, self.name)
        if saved is not None:
            where = f"the result is saved in {saved}"
        elif printed_json:
            where = "the result is the JSON printed on stdout"
        else:
            print(text)
            where = "the result is printed on stdout as JSON"
        for what, e in self.failed:
            err.print(f"[bold red]error:[/] cannot write {what} ({oserror_text(e)}); {where}", soft_wrap=True)
        raise typer.Exit(2)
