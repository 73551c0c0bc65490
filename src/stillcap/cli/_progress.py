"""The progress display of the long commands (the demo, ``pitch``, ``hand``, ``puppet run``,
``markers``, ``calibrate``, ``studio``): one helper, :func:`progress`.

The display goes to stderr, so stdout keeps only the results (``--json`` stays machine-readable
and ``stillcap demo > log`` still shows the progress), and it is shown only when stderr is a
terminal: tests, CI and redirected stderr get nothing. It is transient: it disappears when the
step ends, leaving the printed results.
"""

from __future__ import annotations

from contextlib import contextmanager

__all__ = ["progress"]


class _Quiet:
    """The callback when stderr is not a terminal: does nothing."""

    def __call__(self, done: int, total: int | None = None, item: str | None = None) -> None:
        pass

    def stage(self, label: str, total: int | None = None) -> None:
        pass


class _Bar:
    """``update(done, total=None, item=None)``, the library's ``progress(done, total, label)``
    signature (``total`` and ``item`` change only when given), and :meth:`stage` for the next step."""

    def __init__(self, bar, task):
        self._bar, self._task = bar, task

    def __call__(self, done: int, total: int | None = None, item: str | None = None) -> None:
        fields = {} if item is None else {"item": item}
        if total is not None:
            fields["total"] = total
        self._bar.update(self._task, completed=done, **fields)

    def stage(self, label: str, total: int | None = None) -> None:
        """The next step: a new label, done 0 of ``total`` (None: a pulsing bar), no item."""
        if total is None:  # reset keeps the old total when given None: unknown again (a pulsing bar)
            for t in self._bar.tasks:
                if t.id == self._task:
                    t.total = None
        self._bar.reset(self._task, total=total, description=label, item="")


def _stderr():
    from rich.console import Console

    return Console(stderr=True)


@contextmanager
def progress(label: str, console=None, total: int | None = None):
    """A transient rich progress bar on stderr: ``label``, the bar (pulsing while ``total`` is
    unknown), done of total, the elapsed time and the current item.

    Parameters
    ----------
    label : str
        What runs (``"rendering"``); :meth:`stage` changes it for the next step.
    console : rich.console.Console, optional
        Default: a console on stderr. Nothing is shown unless it is a terminal.
    total : int, optional

    Yields
    ------
    callable
        ``update(done, total=None, item=None)``, to give as a pipeline's ``progress`` callback
        (``lambda i, n, label: update(i, n, label)`` for three-argument ones), with
        ``update.stage(label, total=None)`` to start the next step on the same line.
    """
    console = _stderr() if console is None else console
    if not console.is_terminal:
        yield _Quiet()
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    cols = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            TextColumn("{task.fields[item]}"))
    # stdout is not redirected through the display (it would send results printed meanwhile to stderr)
    with Progress(*cols, console=console, transient=True, redirect_stdout=False) as bar:
        yield _Bar(bar, bar.add_task(label, total=total, item=""))
