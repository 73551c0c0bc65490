"""``stillcap.detect._small_linalg``: np.linalg's numbers bit for bit, and its errors."""

import numpy as np
import pytest

from stillcap.detect import _small_linalg as sl


def test_fast_path_is_in_use():
    # this NumPy has the gufuncs: the comparisons below are of the fast path, not of np.linalg with itself
    assert sl._U is not None


@pytest.mark.parametrize("n", [2, 3])
def test_bit_identical_to_np_linalg(n):
    rng = np.random.default_rng(n)
    for _ in range(300):
        scale = 10.0 ** rng.uniform(-6, 6)
        a = rng.normal(size=(n, n)) * scale
        s = a @ a.T + 1e-3 * scale * scale * np.eye(n)  # symmetric positive definite, as the callers'
        b = rng.normal(size=n)
        assert np.array_equal(sl.solve(a, b), np.linalg.solve(a, b))
        assert np.array_equal(sl.solve(s, b), np.linalg.solve(s, b))
        assert np.array_equal(sl.inv(a), np.linalg.inv(a))
        w, v = sl.eigh(s)
        w0, v0 = np.linalg.eigh(s)
        assert np.array_equal(w, w0) and np.array_equal(v, v0)
        assert np.array_equal(sl.svdvals(a), np.linalg.svd(a, compute_uv=False))


def test_lstsq_bit_identical_on_circle_fit_shapes():
    rng = np.random.default_rng(5)
    for m in (3, 4, 17, 150, 600):
        for _ in range(20):
            pts = rng.normal(500.0, 30.0, (m, 2))
            a = np.column_stack([2 * pts, np.ones(m)])  # kasa_circle's system
            b = (pts ** 2).sum(axis=1)
            assert np.array_equal(sl.lstsq(a, b), np.linalg.lstsq(a, b, rcond=None)[0])


def test_singular_and_nan_behave_as_np_linalg():
    sing = np.array([[1.0, 2.0], [2.0, 4.0]])
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(sing, np.ones(2))
    with pytest.warns(RuntimeWarning), pytest.raises(np.linalg.LinAlgError):  # (the fast call warns first)
        sl.solve(sing, np.ones(2))
    with pytest.warns(RuntimeWarning), pytest.raises(np.linalg.LinAlgError):
        sl.inv(sing)
    nan = np.array([[np.nan, 0.0], [0.0, 1.0]])
    for fast, slow in ((sl.svdvals, lambda a: np.linalg.svd(a, compute_uv=False)),):
        try:
            want = slow(nan)
        except np.linalg.LinAlgError:
            with pytest.raises(np.linalg.LinAlgError):
                fast(nan)
        else:
            np.testing.assert_array_equal(fast(nan), want)


def test_other_inputs_take_np_linalg():
    # lists, float32 and stacked matrices are np.linalg's own call (same result types)
    a32 = np.array([[2.0, 1.0], [1.0, 3.0]], np.float32)
    got = sl.inv(a32)
    assert got.dtype == np.float32 and np.array_equal(got, np.linalg.inv(a32))
    stack = np.stack([np.eye(2), 2 * np.eye(2)])
    assert np.array_equal(sl.inv(stack), np.linalg.inv(stack))
    assert np.array_equal(sl.solve(np.eye(2) * 2, [1.0, 2.0]), np.array([0.5, 1.0]))
