"""Progress reports of the pipelines: a caller's optional ``progress(done, total, label)`` callback."""

from __future__ import annotations

__all__ = ["report_progress"]


def report_progress(cb, done, total, label):
    """Call ``cb(done, total, label)`` unless ``cb`` is None."""
    if cb is not None:
        cb(done, total, label)
