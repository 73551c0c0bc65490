"""``stillcap.detect._small_linalg``: np.linalg's numbers bit for bit, and its errors."""

import warnings

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
    """Singular, nearly singular and NaN input: np.linalg's result or error, and no warning
    (the bare gufuncs would warn on a singular matrix)."""
    cases = [np.array([[1.0, 2.0], [2.0, 4.0]]), np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]]),
             np.array([[1.0, 1.0], [1.0, 1.0 + 1e-14]]), np.array([[np.nan, 0.0], [0.0, 1.0]]),
             np.array([[np.inf, 0.0], [0.0, 1.0]]), np.zeros((3, 3)), np.array([[1e200, 0.0], [0.0, 1e200]])]
    pairs = [(sl.solve, np.linalg.solve, True), (sl.inv, np.linalg.inv, False),
             (lambda a: sl.eigh(a)[0], lambda a: np.linalg.eigh(a)[0], False),
             (sl.svdvals, lambda a: np.linalg.svd(a, compute_uv=False), False)]
    for a in cases:
        for fast, slow, with_b in pairs:
            args = (a, np.ones(len(a))) if with_b else (a,)
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # a warning np.linalg does not give fails the test
                try:
                    want = slow(*args)
                except np.linalg.LinAlgError as e:
                    with pytest.raises(np.linalg.LinAlgError, match=str(e)):
                        fast(*args)
                else:
                    np.testing.assert_array_equal(fast(*args), want)


def test_other_inputs_take_np_linalg():
    # lists, float32 and stacked matrices are np.linalg's own call (same result types)
    a32 = np.array([[2.0, 1.0], [1.0, 3.0]], np.float32)
    got = sl.inv(a32)
    assert got.dtype == np.float32 and np.array_equal(got, np.linalg.inv(a32))
    stack = np.stack([np.eye(2), 2 * np.eye(2)])
    assert np.array_equal(sl.inv(stack), np.linalg.inv(stack))
    assert np.array_equal(sl.solve(np.eye(2) * 2, [1.0, 2.0]), np.array([0.5, 1.0]))


def test_circle_fit_systems_take_the_fast_path(monkeypatch):
    """The Newton steps' normal matrices of arcs as short as 30 deg, and 2x2 outline ellipses,
    are clearly regular: the fast call serves them (np.linalg is not called)."""
    def no(*a, **k):
        raise AssertionError("np.linalg called")
    rng = np.random.default_rng(3)
    systems = []
    for span in (0.5, 1.5, 6.0):
        th = rng.uniform(0.0, span, 60)
        p = np.stack([30 * np.cos(th), 30 * np.sin(th)], 1) + rng.normal(0, 0.3, (60, 2))
        u = p / np.hypot(p[:, 0], p[:, 1])[:, None]
        J = np.column_stack([-u, -np.ones(60)])
        systems.append((J.T @ J, J.sum(axis=0)))
    ellipses = [np.array([[30.0, 2.0], [2.0, 18.0]]), np.array([[12.0, 0.0], [0.0, 12.0]])]
    want = [np.linalg.solve(n, g) for n, g in systems], [np.linalg.inv(a) for a in ellipses]
    monkeypatch.setattr(np.linalg, "solve", no)
    monkeypatch.setattr(np.linalg, "inv", no)
    assert all(np.array_equal(sl.solve(n, g), w) for (n, g), w in zip(systems, want[0]))
    assert all(np.array_equal(sl.inv(a), w) for a, w in zip(ellipses, want[1]))
