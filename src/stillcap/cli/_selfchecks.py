"""Print a result's failed self-checks on the terminal (one line each, on stderr)."""

from __future__ import annotations

from stillcap._selfcheck import failed_checks


def print_failed_checks(checks, what: str = "") -> int:
    """Print every failed check as ``WARNING: self-check NAME [SUBJECT]: MESSAGE``; returns how many."""
    import typer

    bad = failed_checks(checks)
    for c in bad:
        where = f" [{c.subject}]" if c.subject else ""
        prefix = f"{what}: " if what else ""
        typer.secho(f"WARNING: {prefix}self-check {c.name}{where}: {c.message}", fg="yellow", err=True)
    return len(bad)
