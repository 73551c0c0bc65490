"""NumPy values <-> strict JSON values (NaN and inf as null)."""

from __future__ import annotations

import math

import numpy as np


def to_jsonable(x):
    """Arrays -> nested lists with NaN/inf -> None, recursively (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def from_jsonable(x) -> np.ndarray:
    """Nested lists with None (as :func:`to_jsonable` writes NaN) -> float array with NaN."""
    def nan(v):
        return [nan(e) for e in v] if isinstance(v, list) else (np.nan if v is None else v)
    return np.array(nan(x), dtype=float)
