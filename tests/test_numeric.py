"""Shared numeric helpers (stillcap._numeric)."""
import math

import numpy as np

from stillcap._numeric import median


def test_median_is_numpys_bit_for_bit():
    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 4, 11, 500, 1001):
        for dtype in (np.float32, np.float64):
            a = rng.random(n).astype(dtype)
            assert median(a) == float(np.median(a))
    assert median(np.array([3.0, 3.0, 1.0, 7.0])) == 3.0  # ties
    assert math.isnan(median(np.zeros(0)))
