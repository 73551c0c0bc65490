"""circle_fit.fit_circle's own Newton solver (free radius) against scipy's least_squares with the
same soft-L1 loss: the same circle, and the fallback when the steps do not converge."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from stillcap.detect import circle_fit
from stillcap.detect.circle_fit import fit_circle, kasa_circle


def _arc(rng, n, r, span, noise, outliers):
    a = rng.uniform(0.0, span, n)
    c = rng.uniform(100.0, 900.0, 2)
    p = c + r * np.c_[np.cos(a), np.sin(a)] + rng.normal(0.0, noise, (n, 2))
    p[:outliers] += rng.normal(0.0, 4.0, (outliers, 2))  # e.g. a marker's notch
    return p


def _scipy_fit(p, f_scale=0.5):
    start = kasa_circle(p)[0]

    def res(x):
        return np.hypot(p[:, 0] - x[0], p[:, 1] - x[1]) - x[2]
    x0 = np.r_[start, np.mean(np.hypot(*(p - start).T))]
    sol = least_squares(res, x0, loss="soft_l1", f_scale=f_scale, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return sol.x


def _cost(p, x, f_scale=0.5):
    e = np.hypot(p[:, 0] - x[0], p[:, 1] - x[1]) - x[2]
    return float(np.sum(np.sqrt(1.0 + (e / f_scale) ** 2)))


@pytest.mark.parametrize("seed", range(40))
def test_free_radius_fit_matches_least_squares(seed):
    # ball-image limbs: 8-40 px radius, 60-360 deg of arc, 0.1-0.5 px noise, up to a fifth of
    # the points pulled off by a few px
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 250))
    p = _arc(rng, n, rng.uniform(8.0, 40.0), np.radians(rng.uniform(60.0, 360.0)), rng.uniform(0.1, 0.5),
             int(rng.integers(0, n // 5 + 1)))
    c, r, rms = fit_circle(p)
    ref = _scipy_fit(p)
    assert np.max(np.abs(np.r_[c, r] - ref)) < 1e-4  # px
    assert _cost(p, np.r_[c, r]) <= _cost(p, ref) + 1e-9
    e = np.hypot(*(p - c).T) - r
    assert rms == pytest.approx(np.sqrt(np.mean(e ** 2)))


def test_not_converged_falls_back_to_least_squares(monkeypatch):
    rng = np.random.default_rng(7)
    p = _arc(rng, 120, 20.0, np.radians(200.0), 0.3, 10)
    calls = []
    real = circle_fit._soft_l1_newton

    def one_step(points, x0, f_scale, **kw):  # too few steps to converge: None
        got = real(points, x0, f_scale, max_iter=1)
        calls.append(got)
        return got
    monkeypatch.setattr(circle_fit, "_soft_l1_newton", one_step)
    c, r, _ = fit_circle(p)
    assert calls == [None]
    assert np.max(np.abs(np.r_[c, r] - _scipy_fit(p))) < 1e-4


def test_known_radius_keeps_least_squares(monkeypatch):
    # a known radius has a mirror minimum on a short arc's far side: the trust-region solver only
    monkeypatch.setattr(circle_fit, "_soft_l1_newton", lambda *a, **k: pytest.fail("Newton used"))
    rng = np.random.default_rng(3)
    p = _arc(rng, 80, 15.0, np.radians(120.0), 0.2, 0)
    c, r, _ = fit_circle(p, radius=15.0)
    assert r == 15.0 and np.all(np.isfinite(c))
