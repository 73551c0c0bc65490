"""Each ball image's own error level (ball.image_levels): the spread of the levels measured from
the residuals, and the per-image covariances of position_covariances that take it."""

import numpy as np
import pytest

from stillcap.ball.image_levels import level_dispersion, level_factors, whitened_levels
from stillcap.ball.uncertainty import position_covariances


def test_level_dispersion_recovers_the_spread_of_the_images_levels():
    """m2 = lambda chi2_3 with lambda of mean 1 and variance v (gamma), each pair at its own
    overall scale: with 40 images per pair the pooled estimate finds v; with 12 it is low (each
    pair's mean rises with its large levels) but not 0; one level for all gives about 0."""
    rng = np.random.default_rng(0)

    def estimate(v, K):
        pairs = []
        for _ in range(6000 // K):
            lam = rng.gamma(1.0 / v, v, K) if v > 0 else np.ones(K)
            pairs.append(rng.uniform(0.1, 10.0) * lam * rng.chisquare(3, K))
        return level_dispersion(pairs)

    for v in (0.0, 0.25, 0.5):
        assert estimate(v, 40) == pytest.approx(v, abs=0.06)
    assert estimate(0.0, 12) < 0.03
    assert 0.25 < estimate(0.5, 12) < 0.5
    assert level_dispersion([np.array([1.0, np.nan]), np.array([2.0])]) == 0.0  # too few images
    with pytest.raises(ValueError, match="levels must be 1-D"):
        level_dispersion([np.ones((2, 2))])


def test_level_factors_widen_the_images_whose_residual_is_large_and_are_one_without_spread():
    m2 = np.array([0.5, 3.0, 3.0, 12.0, np.nan])
    np.testing.assert_array_equal(level_factors(m2, 0.0), np.ones(5))
    f = level_factors(m2, 0.5)
    assert f[4] == 1.0  # no residual: the pair's level
    assert f[0] < f[1] == f[2] < f[3]
    assert f[3] > 1.5
    with pytest.raises(ValueError, match="dispersion must be"):
        level_factors(m2, -0.1)
    with pytest.raises(ValueError, match=r"levels must have shape \(K,\)"):
        level_factors(np.ones((2, 2)), 0.1)
    with pytest.raises(ValueError, match="shape_covariance"):
        whitened_levels(np.zeros((3, 3)), np.zeros((2, 3, 3)))


def _capture(rng, K, shapes, v):
    """Two pairs' errors from per-image thin ellipsoids, each image's level drawn with variance
    ``v`` about 1, and their residuals to a fitted constant offset per pair (generalised least
    squares, 3 parameters)."""
    out = []
    for S in shapes:
        lam = rng.gamma(1.0 / v, v, K) if v > 0 else np.ones(K)
        L = np.linalg.cholesky(S)
        err = np.sqrt(lam)[:, None] * np.einsum("kij,kj->ki", L, rng.normal(size=(K, 3)))
        Winv = np.linalg.inv(S)
        c = np.linalg.solve(Winv.sum(0), np.einsum("kij,kj->i", Winv, err))
        out.append((err, err - c))
    return out


def _shapes(rng, K, level):
    """Thin ellipsoids (one axis 3x, one 0.45x the third) turned at random, m^2."""
    Q = np.linalg.qr(rng.normal(size=(K, 3, 3)))[0]
    return level * 1e-8 * np.einsum("kij,j,klj->kil", Q, [9.0, 0.2, 1.0], Q)


def _coverage(v_true, n_trials=300, K=12, seed=5):
    rng = np.random.default_rng(seed)
    shapes = [_shapes(rng, K, 1.0), _shapes(rng, K, 3.0)]
    dof = 3 * K / (3 * K - 3)
    inside = {"one level": 0, "own levels": 0}
    for _ in range(n_trials):
        cap = _capture(rng, K, shapes, v_true)
        v = level_dispersion([whitened_levels(r, S) for (_, r), S in zip(cap, shapes)])
        for (err, r), S in zip(cap, shapes):
            for name, disp in (("one level", 0.0), ("own levels", v)):
                C, _ = position_covariances(r, S, None, dof, disp)
                m2 = np.einsum("ki,ki->k", err, np.linalg.solve(C, err[:, :, None])[:, :, 0])
                inside[name] += int(np.sum(m2 <= 7.815))
    return {k: n / (n_trials * 2 * K) for k, n in inside.items()}


def test_own_levels_cover_images_whose_error_levels_differ():
    """Levels spread with variance 0.5 (a scale mixture): one level per pair is right on average
    but its 95 % regions cover ~92 %; each image's own level covers at least 95 % (97-98 %: here
    an image's residual is most of its error, so knowing it is worth more than the t allows)."""
    cov = _coverage(0.5)
    assert cov["one level"] < 0.93
    assert 0.95 <= cov["own levels"] <= 0.985


def test_own_levels_barely_widen_where_the_images_share_one_level():
    """One level for all: the spread estimated from 24 images is noise (0 or small), and the
    regions cover as the one-level ones do, within 2 %."""
    cov = _coverage(0.0)
    assert 0.935 <= cov["one level"] <= 0.965
    assert cov["one level"] <= cov["own levels"] <= cov["one level"] + 0.02
