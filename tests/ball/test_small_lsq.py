"""The spin fit's hand-written least-squares solver against scipy.optimize.least_squares (whose
trust-region algorithm it repeats): the same path (evaluations) to the same minimum of the same
robust cost, and SciPy's stopping codes."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from stillcap.ball.orientation._lsq import solve_small_lsq


def _problem(rng, n=60, outliers=6):
    """Exponential decay plus a sine, with Gaussian noise and a few gross outliers."""
    t = np.linspace(0.0, 3.0, n)
    x_true = np.array([2.0, -1.3, 0.7, 1.9])
    y = x_true[0] * np.exp(x_true[1] * t) + x_true[2] * np.sin(x_true[3] * t)
    y = y + rng.normal(0.0, 0.02, n)
    y[rng.choice(n, outliers, replace=False)] += rng.normal(0.0, 1.0, outliers)

    def fun(x, s):
        return (x[0] * np.exp(x[1] * t) + x[2] * np.sin(x[3] * t) - y) * s

    def jac(x, s):
        return np.stack([np.exp(x[1] * t), x[0] * t * np.exp(x[1] * t), np.sin(x[3] * t),
                         x[2] * t * np.cos(x[3] * t)], axis=1) * s
    return fun, jac


@pytest.mark.parametrize("loss", ["linear", "soft_l1", "huber", "cauchy"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_same_minimum_as_scipy(loss, seed):
    rng = np.random.default_rng(seed)
    fun, jac = _problem(rng)
    x0 = np.array([1.0, -1.0, 0.5, 2.1])
    kw = {"loss": loss, "f_scale": 0.05, "x_scale": np.array([1.0, 1.0, 1.0, 0.5]), "xtol": 1e-12,
          "ftol": 1e-12, "gtol": 1e-12, "max_nfev": 500}
    ref = least_squares(fun, x0, jac=jac, args=(1.0,), **kw)
    res = solve_small_lsq(fun, jac, x0, args=(1.0,), **kw)
    assert ref.status > 0 and res.status > 0
    assert res.cost == pytest.approx(ref.cost, rel=1e-12)
    np.testing.assert_allclose(res.x, ref.x, rtol=0, atol=1e-9)
    assert res.nfev == ref.nfev  # the same steps, not only the same end


def test_same_steps_as_scipy_from_a_far_start():
    """Far from the minimum the trust region (radius updates, More's parameter search) decides
    the path: every evaluated point must be SciPy's."""
    fun, jac = _problem(np.random.default_rng(5))
    seen = {"scipy": [], "small": []}

    def rec(key):
        def f(x, s):
            seen[key].append(np.array(x))
            return fun(x, s)
        return f
    x0 = np.array([0.3, -0.2, 1.5, 1.2])
    kw = {"loss": "soft_l1", "f_scale": 0.05, "x_scale": 1.0, "xtol": 1e-10, "ftol": 1e-10, "gtol": 1e-10}
    least_squares(rec("scipy"), x0, jac=jac, args=(1.0,), **kw)
    solve_small_lsq(rec("small"), jac, x0, args=(1.0,), **kw)
    assert len(seen["small"]) == len(seen["scipy"]) > 5
    np.testing.assert_allclose(np.array(seen["small"]), np.array(seen["scipy"]), rtol=0, atol=1e-9)


def test_stops_at_max_nfev_with_status_0():
    fun, jac = _problem(np.random.default_rng(3))
    res = solve_small_lsq(fun, jac, np.array([1.0, -1.0, 0.5, 2.1]), args=(1.0,), loss="soft_l1", max_nfev=2)
    assert res.status == 0 and res.nfev == 2


def test_unknown_loss_is_refused():
    fun, jac = _problem(np.random.default_rng(4))
    with pytest.raises(ValueError, match="loss"):
        solve_small_lsq(fun, jac, np.zeros(4), args=(1.0,), loss="arctan")
