"""Number formatting shared by the command tables."""

from __future__ import annotations


def num(v, digits: int = 2) -> str:
    """``v`` with ``digits`` decimals; ``-`` for None and NaN; text as it is."""
    if v is None:
        return "-"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "-" if x != x else f"{x:.{digits}f}"
