"""Progress reports: a caller's optional ``progress`` callback, called by pipelines and the studio."""

from __future__ import annotations

__all__ = ["report_progress"]


def report_progress(cb, done, total, label=None):
    """Call ``cb(done, total, label)`` (``cb(done, total)`` without a label) unless ``cb`` is None."""
    if cb is not None:
        if label is None:
            cb(done, total)
        else:
            cb(done, total, label)
