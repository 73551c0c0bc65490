"""The spin covariance's centre-shift term computed for all moved copies at once (speed only,
issue 16): each copy's residuals are, bit for bit, those of its own ``_GlobalProblem``."""

import numpy as np
import pytest

from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation import RPM_PER_RAD_S, MarkerObservations, direction_information, simulate_observations
from stillcap.ball.orientation._batched import _observation_weights, _shifted_residuals
from stillcap.ball.orientation._global import _GlobalProblem

LAYOUT = BallLayout.seed()
VIEW = np.array([1.0, 0.1, 0.25]) / np.linalg.norm([1.0, 0.1, 0.25])


def _problem(seed, information=True, classes=True):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    w = axis / np.linalg.norm(axis) * rng.uniform(1200, 2400) / RPM_PER_RAD_S
    from scipy.spatial.transform import Rotation

    R0 = Rotation.random(random_state=rng).as_matrix()
    times = 0.01 + np.arange(10) / 80.0
    obs = simulate_observations(times, R0, w, VIEW, LAYOUT, noise_deg=0.4, margin_deg=5.0, rng=rng)
    u = obs.directions
    info = direction_information(u, np.broadcast_to(VIEW, u.shape), 15.0) if information else None
    cls = (u @ VIEW < 0.5).astype(int) if classes else None
    views = np.broadcast_to(VIEW, u.shape).copy()
    obs = MarkerObservations(obs.flash, obs.types, u, None, info, cls, views)
    prob = _GlobalProblem(times - times[0], obs, LAYOUT, 0.0)
    x = np.concatenate([rng.normal(0, 0.01, 3), w])
    j, _ = prob.assign(R0, w)
    return prob, x, R0, j, rng


@pytest.mark.parametrize("information, classes", [(True, True), (True, False), (False, False)])
def test_shifted_residuals_are_each_copys_own_problem_bit_for_bit(information, classes):
    for seed in range(4):
        prob, x, R0, j, rng = _problem(seed, information, classes)
        f = None
        if prob.W is not None and classes:  # noise classes weighed apart, as fit_spin does
            prob.W = prob.W_base * np.where(prob.noise_class == 1, 0.5, 1.0)[:, None, None]
            f = prob.W[:, 0, 0] / prob.W_base[:, 0, 0]
        sel = rng.random(len(prob.u)) > 0.2  # some observations left out (outliers)
        u, obs = prob.u, prob.obs
        D = np.stack([u - 1e-4 * rng.normal(size=u.shape) for _ in range(5)])
        got = _shifted_residuals(prob, x, R0, j, sel, D, f)
        assert got.shape == (5, 2 * sel.sum())
        for c in range(5):
            p2 = _GlobalProblem(prob.dt, MarkerObservations(obs.flash, obs.types, D[c], obs.from_ray, obs.information,
                                                            obs.noise_class, obs.views), LAYOUT, 0.0)
            if f is not None:
                p2.W = p2.W_base * f[:, None, None]
            assert np.array_equal(got[c], p2.residuals(x, R0, j, sel))


def test_observation_weights_of_several_sets_are_each_sets_own():
    prob, *_ = _problem(7)
    t1, t2 = prob.t1, prob.t2
    W1, s1 = _observation_weights(t1[None], t2[None], prob.obs.information)
    W3, s3 = _observation_weights(np.stack([t2, t1, t1]), np.stack([t1, t2, t2]), prob.obs.information)
    assert np.array_equal(W1[0], prob.W_base) and np.array_equal(W3[1], W1[0]) and np.array_equal(W3[2], W1[0])
    assert s3[1] == s1[0] == prob.info_scale
    assert not np.array_equal(W3[0], W1[0])  # (swapped bases: other weights)
    none, _ = _observation_weights(t1[None], t2[None], np.zeros_like(prob.obs.information))
    assert none is None


def test_kept_pieces_follow_the_weights_assignment_and_subset():
    # _GlobalProblem keeps pieces over a fit's evaluations (the rotation vectors for the Jacobian,
    # W[sel]'s entries, the assigned markers): after W, j, sel or x change, each residual and
    # Jacobian is, bit for bit, a fresh problem's at the same state
    prob, x, R0, j, rng = _problem(11)
    obs = prob.obs
    sel = np.ones(len(prob.u), bool)
    states = [(x, j, sel, None), (x + 1e-3, j, sel, None), (x, np.roll(j, 1), sel, None),
              (x, j, rng.random(len(prob.u)) > 0.3, None), (x, j, sel, 0.5), (x, j, sel, 2.0)]
    for xs, js, ss, scale in states:
        f = 1.0 if scale is None else np.where(prob.noise_class == 1, scale, 1.0)[:, None, None]
        prob.W = prob.W_base if scale is None else prob.W_base * f
        fresh = _GlobalProblem(prob.dt, obs, LAYOUT, 0.0)
        fresh.W = prob.W
        r, J = prob.residuals(xs, R0, js, ss), prob.jacobian(xs, R0, js, ss)
        assert np.array_equal(r, fresh.residuals(xs, R0, js, ss))
        assert np.array_equal(J, fresh.jacobian(xs, R0, js, ss))
