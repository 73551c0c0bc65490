"""The light of a flash from all the balls it lit (:func:`stillcap.ball.light.fit_light`): lines
from the ball centres toward one place, met robustly; synthetic truth."""

import numpy as np
import pytest

from stillcap.ball.light import fit_light

LIGHT = np.array([-0.5, 11.7, 1.62])  # a strobe 3 m beside a pitch's flight, like the studio's side light


def _balls(n, span, rng):
    y = np.linspace(16.5, 16.5 - span, n)
    return np.stack([0.1 * rng.standard_normal(n), y, 1.7 + 0.1 * rng.standard_normal(n)], axis=1)


def _deg(a, b):
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


@pytest.mark.parametrize("span", [2.8, 6.5])
def test_the_joint_light_is_closer_to_the_truth_than_each_balls_own_and_drops_a_wild_one(span):
    rng = np.random.default_rng(3)
    P = _balls(12, span, rng)
    true = LIGHT - P
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    seen = true + np.radians(4.0) * rng.standard_normal(true.shape)
    seen[4] = [1.0, 0.0, 0.0]  # one ball's shading misread (a crescent, a seam): ~90 deg off
    fit = fit_light(P, seen)
    own = _deg(seen / np.linalg.norm(seen, axis=1, keepdims=True), true)
    joint = _deg(fit.directions, true)
    assert not fit.inliers[4] and fit.inliers.sum() == 11
    rms = lambda e: np.sqrt(np.mean(e ** 2))
    assert rms(joint) < 0.8 * rms(own[fit.inliers])
    assert joint[4] < 5.0  # the wild ball gets the light the others show
    # the stated errors are the right size: the errors within 3 sigmas, and not all far inside
    assert np.all(joint < 3.0 * fit.sigma_deg) and np.mean(joint / fit.sigma_deg) > 0.2
    assert 2.5 < fit.scatter_deg < 6.0  # 4 deg per component given


def test_a_distant_light_is_a_common_direction():
    rng = np.random.default_rng(1)
    P = rng.standard_normal((8, 3))
    d = np.array([0.3, 0.4, 0.8]) / np.linalg.norm([0.3, 0.4, 0.8])
    fit = fit_light(P, d + 0.01 * rng.standard_normal((8, 3)))
    assert np.all(_deg(fit.directions, np.tile(d, (8, 1))) < 0.6)
    assert abs(fit.position_h[3]) < 0.05  # (nearly) at infinity


def test_too_few_or_unseen_balls():
    P = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    d = np.tile([0.0, 0.0, 1.0], (4, 1))
    d[1:3] = np.nan
    assert fit_light(P, d) is None
    d[1] = [0.0, 0.0, 1.0]
    fit = fit_light(P, d)
    assert fit is not None and np.all(np.isfinite(fit.directions))  # the unseen ball gets the fitted light
    with pytest.raises(ValueError, match="directions"):
        fit_light(P, d[:3])
    with pytest.raises(ValueError, match="min_points must be >= 3"):
        fit_light(P, d, min_points=2)
