"""Spin from the flight alone (stillcap.ball.spin_from_flight): simulated flights with noise,
their 95 % intervals, a flight with no spin, another up direction, the comparison with a
measured spin and the errors for too few positions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.ball.physics import RPM_PER_RAD_S, FlightModel, simulate
from stillcap.ball.spin_from_flight import MIN_POSITIONS, compare_spins, spin_from_flight

SIGMA = 0.002  # m per coordinate: the pitch pipeline's default position_sigma_m


def flight(seed, model, spin_rate=(150.0, 280.0), rot=None):
    """A pitch-like flight (0.36 s at 200 Hz) with a random spin, noisy positions."""
    r = np.random.default_rng(seed)
    v0 = np.array([r.normal(0, 1), -38 + r.normal(0, 1), r.normal(-1, 0.5)])
    w = r.normal(0, 1, 3)
    w = w / np.linalg.norm(w) * r.uniform(*spin_rate)
    p0 = np.array([0.0, 16.0, 1.8])
    if rot is not None:
        p0, v0, w = rot.apply(p0), rot.apply(v0), rot.apply(w)
    t = np.arange(0.0, 0.36, 1 / 200.0)
    noise = r.normal(0, SIGMA, (len(t), 3))
    if rot is not None:  # the same noise, turned with the flight
        noise = rot.apply(noise)
    pos = simulate(p0, v0, w, t, model).positions + noise
    return t, pos, v0, w


def transverse(w, v):
    vh = v / np.linalg.norm(v)
    return w - (w @ vh) * vh


def test_the_95_percent_intervals_cover_the_truth_in_most_of_50_flights():
    model = FlightModel(kind="nathan")
    cover, rate_err, axis_err = 0, [], []
    for seed in range(50):
        t, pos, v0, w = flight(seed, model)
        fs = spin_from_flight(t, pos, model, position_sigma=SIGMA)
        wp = transverse(w, v0)
        dr = fs.rate_rpm - np.linalg.norm(wp) * RPM_PER_RAD_S
        da = np.degrees(np.arccos(np.clip(fs.axis @ wp / np.linalg.norm(wp), -1, 1)))
        half_r, half_a = fs.interval95()
        cover += abs(dr) < half_r and da < half_a
        rate_err.append(abs(dr))
        axis_err.append(da)
        assert fs.lift_from == "transverse" and abs(fs.spin @ fs.velocity) < 1e-9 * np.linalg.norm(fs.velocity)
    # both intervals at once: 0.95^2 = 0.90 expected; a wide band (the fit is linearised)
    assert 40 <= cover <= 50, cover
    assert np.median(axis_err) < 5.0 and np.median(rate_err) < 150.0


def test_seed_model_gives_the_total_rate_along_the_transverse_axis():
    model = FlightModel(kind="seed")
    t, pos, v0, w = flight(3, model)
    fs = spin_from_flight(t, pos, model, position_sigma=SIGMA)
    wp = transverse(w, v0)
    assert fs.lift_from == "total"
    assert abs(fs.rate_rpm - np.linalg.norm(w) * RPM_PER_RAD_S) < 4 * fs.rate_sigma_rpm
    assert np.degrees(np.arccos(fs.axis @ wp / np.linalg.norm(wp))) < 4 * fs.axis_sigma_deg


def test_a_flight_with_no_spin():
    model = FlightModel(kind="nathan")
    t, pos, v0, w = flight(7, model, spin_rate=(0.0, 0.0))
    fs = spin_from_flight(t, pos, model, position_sigma=SIGMA)
    assert fs.rate_rpm < 3.0 * fs.rate_sigma_rpm + 1.0 and fs.rate_rpm < 150.0


@pytest.mark.parametrize("up", [(1.0, 0.0, 0.0), (0.3, -0.5, 0.8)])
def test_any_up_direction_from_the_models_gravity(up):
    up = np.asarray(up) / np.linalg.norm(up)
    rot, _ = Rotation.align_vectors([up], [[0.0, 0.0, 1.0]])
    model_z = FlightModel(kind="nathan")
    model = FlightModel(kind="nathan", gravity=tuple(-9.80665 * up))
    t, pos, v0, w = flight(11, model, rot=rot)
    fs = spin_from_flight(t, pos, model, position_sigma=SIGMA)
    assert np.allclose(fs.up, up)
    t_z, pos_z, v0_z, w_z = flight(11, model_z)
    fz = spin_from_flight(t_z, pos_z, model_z, position_sigma=SIGMA)
    wp = transverse(w, v0)
    assert np.linalg.norm(fs.spin - wp) < 4 * np.sqrt(np.trace(fs.covariance))
    # the same flight turned: the same rate and the same tilt about the flight (up-relative)
    assert abs(fs.rate_rpm - fz.rate_rpm) < 0.05 * fz.rate_sigma_rpm
    assert abs(fs.axis_tilt_deg - fz.axis_tilt_deg) < 0.05 * fz.axis_sigma_deg
    assert np.allclose(rot.apply(fz.spin), fs.spin, atol=0.05 * np.sqrt(np.trace(fz.covariance)))


def test_the_comparison_with_a_measured_spin():
    model = FlightModel(kind="nathan")
    t, pos, v0, w = flight(5, model)
    fs = spin_from_flight(t, pos, model, position_sigma=SIGMA)
    cov = np.eye(3) * 1.0
    good = compare_spins(fs, w, cov)
    assert good.agree and good.dof == 2 and good.p_value > 0.01
    eff = np.linalg.norm(transverse(w, v0)) / np.linalg.norm(w)
    assert abs(good.spin_efficiency - eff) < 3 * good.spin_efficiency_sigma + 0.02
    wrong = compare_spins(fs, Rotation.from_rotvec(np.radians(40) * v0 / np.linalg.norm(v0)).apply(w), cov)
    assert not wrong.agree and wrong.axis_angle_deg > 25
    d = good.to_dict()
    assert {"chi2", "p_value", "agree", "spin_efficiency", "spin_efficiency_sigma", "axis_angle_deg"} <= set(d)


def test_too_few_positions_and_bad_times():
    model = FlightModel(kind="nathan")
    t, pos, _, _ = flight(1, model)
    with pytest.raises(ValueError, match=f"at least {MIN_POSITIONS} positions.*got 3"):
        spin_from_flight(t[:3], pos[:3], model)
    holes = pos[:6].copy()
    holes[[1, 3, 5], 0] = np.nan
    with pytest.raises(ValueError, match=r"rally\.csv: spin from flight needs at least 4 positions.*got 3"):
        spin_from_flight(t[:6], holes, model, where="rally.csv")
    with pytest.raises(ValueError, match="distinct"):
        spin_from_flight(np.r_[t[:5], t[4]], pos[:6], model)
    with pytest.raises(ValueError, match="positions must have shape"):
        spin_from_flight(t[:6], pos[:5], model)
    with pytest.raises(ValueError, match="no motion"):
        spin_from_flight(t[:6], np.zeros((6, 3)), model)
