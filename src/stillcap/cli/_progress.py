"""The progress bar of the long commands (``calibrate``, ``studio``, ``puppet run``)."""

from __future__ import annotations

from contextlib import contextmanager


@contextmanager
def progress(label: str, console, total: int | None = None):
    """A transient rich progress bar on ``console``: ``label``, the bar, done of total, the
    elapsed time and the current item.

    Yields an ``update(done, total=None, item=None)`` callback (the library's
    ``progress(done, total, name)`` signature); ``total`` and ``item`` change only when given.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    cols = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            TextColumn("{task.fields[item]}"))
    with Progress(*cols, console=console, transient=True) as bar:
        task = bar.add_task(label, total=total, item="")

        def update(done: int, total: int | None = None, item: str | None = None) -> None:
            fields = {} if item is None else {"item": item}
            bar.update(task, completed=done, total=total, **fields)

        yield update
