"""Small numeric helpers and constants shared across packages (exact medians for the detectors' hot
paths, the rpm conversion)."""

from __future__ import annotations

import numpy as np


def median(a: np.ndarray) -> float:
    """``float(np.median(a))`` of a 1-D array without NaN (NaN when empty), bit for bit.

    The middle value, or the mean ``(a + b) / 2`` of the two middle ones in ``a``'s dtype, found
    by ``np.partition``: ``np.median``'s generic machinery costs ~30 us per call, which the
    detectors pay a few times per photo or crop.
    """
    n = len(a)
    if n == 0:
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    p = np.partition(a, [k - 1, k])
    return float((p[k - 1] + p[k]) / 2)


def median_columns(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=0)`` of a 2-D float array, bit for bit (a column with NaN gives NaN).

    The middle row, or the mean ``(a + b) / 2`` of the two middle ones in ``a``'s dtype, found by
    one ``np.partition`` along the rows (with the last row, where NaN sorts: np.median's own NaN
    test). ``np.median``'s generic machinery costs ~40 us per call; the marker detector takes one
    per marker region (speed only, issue 16). Other input (empty, integer, not 2-D) goes to
    ``np.median``.
    """
    a = np.asarray(a)
    n = len(a)
    if a.ndim != 2 or n == 0 or a.dtype.kind != "f":
        return np.median(a, axis=0)
    k = n // 2
    p = np.partition(a, [k, n - 1] if n % 2 else [k - 1, k, n - 1], axis=0)
    out = p[k].copy() if n % 2 else (p[k - 1] + p[k]) / 2
    last = p[n - 1]
    nan = np.isnan(last)
    if nan.any():
        out[nan] = last[nan]
    return out


#: rpm per rad/s, the one conversion of spin rates (SI inside, rpm at the edges).
RPM_PER_RAD_S = 60.0 / (2.0 * np.pi)
