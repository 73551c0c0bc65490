"""The spin fit's weights scaled by each observation's centroid noise read from its own photo
(issue 12, :mod:`stillcap.ball.orientation._photo_noise`)."""

import numpy as np
import pytest

from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation import RPM_PER_RAD_S, MarkerObservations, direction_information, fit_spin
from stillcap.ball.orientation import _photo_noise
from stillcap.ball.orientation._photo_noise import photo_noise_exponent, photo_noise_factors

LAYOUT = BallLayout.seed()
VIEW = np.array([0.0, -1.0, 0.0])


def _draw(rng, n, p_true, one_component_share=0.0):
    """Squared residual lengths of ``n`` observations whose variance goes as sigma^(2 p_true):
    chi^2 with 2 components (1 for a share of them), shrunk by a leverage of 0-0.3."""
    sigma = np.exp(rng.normal(np.log(0.1), 0.5, n))
    k = np.where(rng.uniform(size=n) < one_component_share, 1, 2)
    lev = rng.uniform(0.0, 0.3, n)
    dof = k - lev
    e2 = (sigma / 0.1) ** (2 * p_true) * rng.chisquare(k) * dof / k
    return e2, dof, sigma


@pytest.mark.parametrize("p_true", [0.0, 1.0])
def test_exponent_recovers_the_noises_dependence_on_the_stated_sigma(p_true):
    ps = [photo_noise_exponent(*_draw(np.random.default_rng(s), 200, p_true, 0.3)) for s in range(20)]
    # the slope's standard error at n = 200 and a log-sigma spread of 0.5: sqrt(pi^2/2 / (200 x 1))
    # = 0.16; 20 draws' mean within 0.15 (the clip at 0 or 1 lifts / lowers it by ~0.06)
    assert abs(np.mean(ps) - p_true) < 0.15, ps


def test_exponent_needs_enough_sigmas_and_factors_keep_the_median():
    e2, dof, sigma = _draw(np.random.default_rng(3), 200, 1.0)
    sigma[19:] = np.nan
    assert photo_noise_exponent(e2, dof, sigma) == 0.0  # 19 known: below MIN_SIGMAS
    f = photo_noise_factors(np.array([0.1, 0.2, 0.4, np.nan]), 1.0)
    np.testing.assert_allclose(f, [2.0, 1.0, 0.5, 1.0])
    np.testing.assert_allclose(photo_noise_factors(np.array([0.1, 0.2]), 0.0), 1.0)


def _observations(seed, spread=0.6, proportional=True):
    """Exact observations of a spinning seed ball (12 flashes at 80 Hz, one view, 15 px radius),
    each moved by centroid noise of its own sigma (log-normal spread ``spread``) when
    ``proportional``, else by 0.2 px for all; the stated sigmas are given either way."""
    from scipy.spatial.transform import Rotation

    from stillcap.ball.orientation import simulate_observations

    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    w = axis / np.linalg.norm(axis) * rng.uniform(1200, 2400) / RPM_PER_RAD_S
    R0 = Rotation.random(random_state=rng).as_matrix()
    times = 0.01 + np.arange(12) / 80.0
    obs = simulate_observations(times, R0, w, VIEW, LAYOUT, noise_deg=0.0, margin_deg=5.0, rng=rng)
    u, r_px = obs.directions, 15.0
    c = u @ VIEW
    toward = VIEW[None] - c[:, None] * u
    toward /= np.linalg.norm(toward, axis=1, keepdims=True)
    around = np.cross(u, toward)
    sigma = 0.2 * np.exp(rng.normal(0.0, spread, len(u)))
    s = sigma if proportional else np.full(len(u), 0.2)
    e = rng.normal(size=(len(u), 2)) * s[:, None]
    v = u + (e[:, :1] * around + e[:, 1:] * toward / np.maximum(c, 0.1)[:, None]) / r_px
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    info = direction_information(v, np.broadcast_to(VIEW, v.shape), r_px)
    return times, MarkerObservations(obs.flash, obs.types, v, None, info, centroid_sigma_px=sigma), w


def test_fit_weighs_noisy_photos_less_and_its_intervals_still_cover(monkeypatch):
    """Centroid noise 0.2 px x a log-normal factor (sigma 0.6), stated per observation: the fit
    that reads the stated sigmas is more accurate than the one that does not (the same
    observations with the module switched off), and its rate intervals cover."""
    err_on, err_off, z = [], [], []
    for seed in range(20):
        times, obs, w = _observations(seed)
        rate = np.linalg.norm(w) * RPM_PER_RAD_S
        on = fit_spin(times, obs, LAYOUT, spin_init=w)
        monkeypatch.setattr(_photo_noise, "ENABLED", False)
        off = fit_spin(times, obs, LAYOUT, spin_init=w)
        monkeypatch.setattr(_photo_noise, "ENABLED", True)
        err_on.append(np.linalg.norm(on.spin - w))
        err_off.append(np.linalg.norm(off.spin - w))
        z.append((on.spin_rpm - rate) / on.sigma_rpm)
    assert np.mean(err_on) < 0.9 * np.mean(err_off), (np.mean(err_on), np.mean(err_off))
    assert np.mean(np.abs(z) <= 1.96) >= 0.8


def test_fit_with_uninformative_sigmas_stays_as_it_was(monkeypatch):
    """Equal noise for all, random stated sigmas: p stays near 0, so the spin barely moves."""
    d = []
    for seed in range(10):
        times, obs, w = _observations(seed, proportional=False)
        on = fit_spin(times, obs, LAYOUT, spin_init=w)
        monkeypatch.setattr(_photo_noise, "ENABLED", False)
        off = fit_spin(times, obs, LAYOUT, spin_init=w)
        monkeypatch.setattr(_photo_noise, "ENABLED", True)
        d.append(abs(on.spin_rpm - off.spin_rpm) / off.sigma_rpm)
    assert np.median(d) < 0.2, d


def test_observations_name_a_centroid_sigma_of_the_wrong_shape():
    with pytest.raises(ValueError, match=r"centroid_sigma_px must have shape \(2,\), got \(3,\)"):
        MarkerObservations([0, 1], [0, 0], [[1.0, 0, 0], [0, 1.0, 0]], centroid_sigma_px=[0.1, 0.2, 0.3])
    obs = MarkerObservations([0, 1], [0, 0], [[1.0, 0, 0], [0, 1.0, 0]], centroid_sigma_px=[0.1, 0.0])
    assert obs.centroid_sigma_px[0] == 0.1 and np.isnan(obs.centroid_sigma_px[1])  # not positive: unknown
