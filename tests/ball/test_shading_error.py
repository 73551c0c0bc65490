"""The shading correction's leftover share estimated from a flight fit's residuals
(``stillcap.ball.shading_error``), and the remaining-bias modes it would size
(``stillcap.ball.uncertainty.remaining_bias_modes``)."""

import numpy as np
import pytest

from stillcap.ball.fit import fit_reference_trajectory
from stillcap.ball.physics import flight_model, simulate
from stillcap.ball.shading_error import estimate_shading_share, fitted_response

MODEL = flight_model("seed")
P0, V0, W = np.array([0.3, 16.0, 1.8]), np.array([-0.5, -38.0, -1.0]), np.array([-150.0, -20.0, 10.0])


def _two_clock_flight(rng, noise_m=5e-4):
    """Positions of a pitch seen by two pairs on their own clocks (10 + 8 flashes, 300 Hz)."""
    t = np.r_[np.arange(10) / 300.0, 0.25 + np.arange(8) / 300.0]
    groups = np.r_[np.zeros(10, int), np.ones(8, int)]
    P = simulate(P0, V0, W, t, MODEL, t0=0.0).positions
    local = t.copy()
    local[10:] -= 0.25
    return local, P, P + rng.normal(0.0, noise_m, P.shape), groups


def _fit(local, P, groups, spin=None):
    return fit_reference_trajectory(local, P, P[0], V0, spin, model=MODEL, t0=0.0, position_sigma=1e-3,
                                    time_groups=groups, time_offsets=np.array([0.25]))


def test_fitted_response_is_what_a_refit_moves():
    """``fitted_response`` (the flight's hat matrix, ``H d``) against refitting the shifted
    positions of a positions-only fit (no spin prior, as the pipeline's): the same move."""
    rng = np.random.default_rng(1)
    local, _, P, groups = _two_clock_flight(rng)
    spin = None
    f1 = _fit(local, P, groups, spin)
    D = rng.normal(0.0, 1e-3, P.shape)
    D[:10] = 0.0  # the second pair only: its clock offset and the flight both respond
    eps = 0.1
    f2 = _fit(local, P + eps * D, groups, spin)
    moved = (f2.positions - f1.positions) / eps
    lin = fitted_response(f1, MODEL, groups, D[None])[0]
    assert np.abs(moved).max() > 1e-4  # the fit does respond
    assert np.abs(lin - moved).max() < 0.05 * np.abs(moved).max()
    with pytest.raises(ValueError, match="modes must have shape"):
        fitted_response(f1, MODEL, groups, D[None, :5])


def test_estimate_finds_a_pattern_the_flight_cannot_absorb_and_falls_back_to_the_prior():
    """A per-image pattern the flight cannot take up, added at a known share, is found within
    its sigma (over 40 noise draws: |z| < 3 each, mean z near 0); without it the estimate is 0
    within its sigma; and a pattern the flight absorbs entirely (a constant shift of the
    reference clock's positions) leaves the prior."""
    rng = np.random.default_rng(7)
    local, P_true, _, groups = _two_clock_flight(rng)
    N = len(P_true)
    # a zig-zag across the flight on the second pair's images: no flight bends like that
    pattern = np.zeros((N, 3))
    pattern[10:, 0] = 1e-3 * (-1.0) ** np.arange(8)
    S = np.broadcast_to(np.eye(3) * (5e-4) ** 2, (N, 3, 3))
    z = []
    for kappa in (0.0, 0.8):
        for _ in range(20):
            P = P_true + kappa * pattern + rng.normal(0.0, 5e-4, P_true.shape)
            est = estimate_shading_share(_fit(local, P, groups), MODEL, groups, {"b/cam": pattern}, S, prior=0.5)
            z.append((est.kappa_hat[0] - kappa) / est.kappa_sigma[0])
            assert est.dof > 0 and np.isfinite(est.misfit)
    z = np.array(z)
    assert np.all(np.abs(z) < 3.5) and abs(z.mean()) < 0.6
    # a constant shift of the front pair is the release point's: nothing to tell
    shift = np.zeros((N, 3))
    shift[:10] = [1e-3, 0.0, 0.0]
    P = P_true + rng.normal(0.0, 5e-4, P_true.shape)
    est = estimate_shading_share(_fit(local, P, groups), MODEL, groups, {"f/cam": shift}, S, prior=0.5)
    assert est.kappa_used[0] == pytest.approx(0.5, rel=0.05)
    with pytest.raises(ValueError, match="prior must be > 0"):
        estimate_shading_share(_fit(local, P, groups), MODEL, groups, {"f/cam": shift}, S, prior=0.0)


def test_remaining_bias_takes_a_share_per_camera():
    """``model_error`` one per camera (as an estimate per camera would give it): each camera's
    modes grow with its own share only, and a negative share is refused."""
    from detect.test_ball import FLIGHT, R_BALL, draw_balls_camera, front_pair
    from stillcap.ball.stereo import ball_centers_stereo
    from stillcap.ball.uncertainty import remaining_bias_modes

    a, b = front_pair()
    light = (1.0, 0.0, 0.3)
    st = ball_centers_stereo(a, draw_balls_camera(a, FLIGHT, R_BALL, light_world=light, rng=11),
                             b, draw_balls_camera(b, FLIGHT, R_BALL, light_world=light, rng=12), R_BALL)
    x = np.stack([st.centers_a, st.centers_b])
    flags = np.zeros(len(st), int)
    m0 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.0)
    m = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, [0.5, 0.0])
    both = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5)
    assert m.shape == m0.shape == (14, len(st), 3)
    # camera 0's modes (0-5) grew, camera 1's (6-11) are the model's own error alone
    np.testing.assert_array_equal(m[6:], m0[6:])
    assert np.sum(m[:6] ** 2) > np.sum(m0[:6] ** 2)
    np.testing.assert_array_equal(m[:6], both[:6])
    with pytest.raises(ValueError, match="model_error must be >= 0"):
        remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, [0.5, -1.0])


def _pair_modes(N):
    """Remaining-bias modes (m) at the stated share: a shift across the flight of the second
    pair's positions, a drift of its height, and a height shift of the first pair's."""
    M = np.zeros((3, N, 3))
    M[0, 10:, 0] = 2e-3
    M[1, 10:, 2] = 2e-3 * np.linspace(-1.0, 1.0, 8)
    M[2, :10, 2] = 2e-3
    return M


def test_share_scale_follows_how_far_the_pairs_disagree():
    """``share_scale_from_pairs`` on two pairs whose positions carry the modes at a known scale:
    pairs that agree (no bias) give a scale well below 1, pairs biased 3x the stated share one
    well above 1, each over 12 noise draws; the posterior's ``E[s^2]`` tends to the prior's (1)
    when the pairs' disagreement tells nothing (one pair)."""
    from stillcap.ball.shading_error import share_scale_from_pairs

    rng = np.random.default_rng(3)
    # two pairs over the same stretch of the flight (a shift of one against the other is not
    # a change of the flight's direction, as it is for pairs far apart)
    t = np.r_[np.arange(10) / 300.0, 0.01 + np.arange(8) / 300.0]
    groups = np.r_[np.zeros(10, int), np.ones(8, int)]
    P_true = simulate(P0, V0, W, t, MODEL, t0=0.0).positions
    local = t - np.where(groups == 1, 0.01, 0.0)

    def _fit(local, P, groups):
        return fit_reference_trajectory(local, P, P[0], V0, None, model=MODEL, t0=0.0, position_sigma=1e-3,
                                        time_groups=groups, time_offsets=np.array([0.01]))
    N = len(P_true)
    M = _pair_modes(N)
    S = np.broadcast_to(np.eye(3) * (5e-4) ** 2, (N, 3, 3))
    pairs = groups.copy()
    used = {}
    for s_true in (0.0, 3.0):
        used[s_true] = []
        for _ in range(12):
            bias = s_true * np.einsum("m,mnj->nj", rng.normal(size=len(M)), M)
            P = P_true + bias + rng.normal(0.0, 5e-4, P_true.shape)
            sc = share_scale_from_pairs(_fit(local, P, groups), MODEL, groups, pairs, S, lambda s: s * M)
            assert sc.dof > 0 and np.isfinite(sc.chi2_stated)
            used[s_true].append(sc.scale_used)
    assert np.median(used[0.0]) < 0.6
    assert np.median(used[3.0]) > 1.8
    # one pair: nothing to compare, the stated share
    P = P_true + rng.normal(0.0, 5e-4, P_true.shape)
    one = share_scale_from_pairs(_fit(local, P, groups), MODEL, groups, np.zeros(N, int), S, lambda s: s * M)
    assert one.scale_used == 1.0 and one.dof == 0 and "one pair" in one.note
    with pytest.raises(ValueError, match="pair_index must have shape"):
        share_scale_from_pairs(_fit(local, P, groups), MODEL, groups, pairs[:5], S, lambda s: s * M)


def test_share_scale_option_is_checked():
    """``PitchOptions.shading_share_scale`` takes ``"stated"`` (default) or ``"pairs"`` only."""
    from stillcap.pipelines.pitch.options import PitchOptions

    assert PitchOptions().shading_share_scale == "stated"
    assert PitchOptions(shading_share_scale="pairs").to_dict()["shading_share_scale"] == "pairs"
    with pytest.raises(ValueError, match="shading_share_scale must be"):
        PitchOptions(shading_share_scale="capture")
