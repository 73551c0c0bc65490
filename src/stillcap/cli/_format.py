"""Number formatting shared by the command tables."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table


def num(v, digits: int = 2) -> str:
    """``v`` with ``digits`` decimals; ``-`` for None and NaN; text as it is."""
    if v is None:
        return "-"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "-" if x != x else f"{x:.{digits}f}"


def print_notes(messages) -> None:
    """Each message as a yellow ``note:`` line on stderr."""
    err = Console(stderr=True)
    for m in messages:
        err.print(f"[yellow]note:[/] {m}", highlight=False, soft_wrap=True)


def right_table(title: str, columns) -> Table:
    """A table titled ``title`` whose ``columns`` are all right-justified."""
    t = Table(title=title)
    for c in columns:
        t.add_column(c, justify="right")
    return t
