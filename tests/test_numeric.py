"""Shared numeric helpers (stillcap._numeric)."""
import math

import numpy as np

from stillcap._numeric import median, median_columns


def test_median_is_numpys_bit_for_bit():
    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 4, 11, 500, 1001):
        for dtype in (np.float32, np.float64):
            a = rng.random(n).astype(dtype)
            assert median(a) == float(np.median(a))
    assert median(np.array([3.0, 3.0, 1.0, 7.0])) == 3.0  # ties
    assert math.isnan(median(np.zeros(0)))


def test_median_columns_is_numpys_axis0_median_bit_for_bit():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 4, 7, 8, 9, 150, 151):
        for dtype in (np.float32, np.float64):
            a = rng.random((n, 3)).astype(dtype)
            ref = np.median(a, axis=0)
            got = median_columns(a)
            assert got.dtype == ref.dtype and got.tobytes() == ref.tobytes()
            t = np.round(a * 4).astype(dtype)  # ties
            assert median_columns(t).tobytes() == np.median(t, axis=0).tobytes()
    a = rng.random((9, 3))
    a[4, 1] = np.nan  # a NaN column gives NaN, the others their medians (as np.median)
    got, ref = median_columns(a), np.median(a, axis=0)
    assert np.isnan(got[1]) and got[[0, 2]].tobytes() == ref[[0, 2]].tobytes()
