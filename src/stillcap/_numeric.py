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


#: rpm per rad/s, the one conversion of spin rates (SI inside, rpm at the edges).
RPM_PER_RAD_S = 60.0 / (2.0 * np.pi)
