"""Cells of the CSV tables users give (trajectories, pitch exports): one way to read a number and
to name the file, row and column when it is not one."""

from __future__ import annotations

import math

__all__ = ["number_cell"]


def number_cell(text: str, where: str) -> float:
    """``text`` as a finite float, or ``ValueError`` ``"WHERE: 'TEXT' is not a (finite) number"``
    (``where``: e.g. ``"rally.csv: row 3, column 'y'"``)."""
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{where}: {text!r} is not a finite number")
    return v
