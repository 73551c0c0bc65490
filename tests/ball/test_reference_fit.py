"""Reference-trajectory fit (seed section 4.5): recovery, uncertainties, gaps, both optimisers."""

import numpy as np
import pytest

from stillcap.ball.fit import FitPriors, fit_reference_trajectory, spin_basis
from stillcap.ball.metrics import FT, spin_vector
from stillcap.ball.physics import FlightModel, cross_plane, simulate

P0 = np.array([-0.5, 54.5 * FT, 1.8])
V0 = np.array([0.3, -28.0, -0.5])  # 63 mph, like the seed's pitches
SPIN = spin_vector(1600.0, 200.0, V0, efficiency=0.9)


def seed_capture(model, p0=P0, v0=V0, spin=SPIN):
    """Times like the seed's rig: front pair at 80 Hz after release, back pair at 50 Hz near the
    plate, and one lost flash in between (NaN)."""
    t_plate = cross_plane(p0, v0, spin, model).time
    tf = np.arange(0.0, 0.12, 1 / 80)
    tb = np.arange(t_plate - 0.22, t_plate, 1 / 50)
    times = np.concatenate([tf, [0.3], tb])
    truth = simulate(p0, v0, spin, times, model).positions
    return times, truth, len(tf)


def noisy_measurement(truth, gap, rng, priors, noise=0.002, spin=SPIN):
    meas = truth + rng.normal(0, noise, truth.shape)
    meas[gap] = np.nan
    meas[2, 1] = np.nan  # a single missing coordinate is fine too
    p0m = P0 + rng.normal(0, priors.position_sigma, 3)
    v0m = V0 + rng.normal(0, priors.velocity_sigma, 3)
    b = spin_basis(v0m)
    sig = [priors.spin_axial_sigma, priors.spin_transverse_sigma, priors.spin_transverse_sigma]
    wm = spin + b @ (rng.normal(0, 1, 3) * sig)
    return meas, p0m, v0m, wm


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_least_squares_recovers_pitch_and_its_uncertainty_covers_the_error(kind):
    model = FlightModel(kind=kind)
    times, truth, gap = seed_capture(model)
    priors = FitPriors()
    z_all, v_err = [], []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        noise = rng.uniform(0.001, 0.002)  # 1-2 mm per coordinate
        meas, p0m, v0m, wm = noisy_measurement(truth, gap, rng, priors, noise=noise)
        fit = fit_reference_trajectory(times, meas, p0m, v0m, wm, model, position_sigma=noise)
        assert fit.success, fit.message
        s_true = fit.spin_basis.T @ SPIN
        err = np.concatenate([fit.p0 - P0, fit.v0 - V0, fit.params[6:] - s_true])
        z_all.append(err / fit.param_sigma)
        v_err.append(np.abs(fit.v0 - V0).max())
        # transverse spin: a few rad/s out of 150
        assert np.all(np.abs(fit.params[7:] - s_true[1:]) < 4 * fit.spin_transverse_sigma + 1e-9)
        assert np.all(fit.spin_transverse_sigma < 6.0)
        assert fit.mean_error < 0.004 and fit.max_error < 0.01
        assert 0.5 < fit.residual_scale < 1.6
        assert np.isnan(fit.errors[gap]) and np.isfinite(fit.errors[0])
    z = np.abs(np.array(z_all))
    print(f"{kind}: max |v0 error| = {max(v_err):.4f} m/s, share |z| < 1: {np.mean(z < 1):.2f}, "
          f"< 2: {np.mean(z < 2):.2f}, max |z| = {z.max():.2f}")
    assert max(v_err) < 0.05
    assert np.mean(z < 1.0) > 0.5  # 1-sigma covers the error in most cases (68 % expected)
    assert np.mean(z < 2.0) > 0.85
    assert 0.7 < np.sqrt(np.mean(z ** 2)) < 1.3  # calibrated (150 seeds: 0.92-1.05 per parameter)
    assert z.max() < 4.0


def test_powell_seed_objective_agrees_with_least_squares():
    model = FlightModel()
    times, truth, gap = seed_capture(model)
    rng = np.random.default_rng(11)
    meas, p0m, v0m, wm = noisy_measurement(truth, gap, rng, FitPriors())
    ls = fit_reference_trajectory(times, meas, p0m, v0m, wm, model)
    pw = fit_reference_trajectory(times, meas, p0m, v0m, wm, model, method="powell")
    assert pw.success and pw.method == "powell"
    np.testing.assert_allclose(pw.v0, ls.v0, atol=3e-3)
    np.testing.assert_allclose(pw.spin, ls.spin, atol=0.3)
    assert np.abs(pw.v0 - V0).max() < 0.05
    np.testing.assert_allclose(pw.v0_sigma, ls.v0_sigma, rtol=0.05)


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_fit_without_spin_measurement_finds_transverse_spin(kind):
    model = FlightModel(kind=kind)
    times, truth, gap = seed_capture(model)
    rng = np.random.default_rng(5)
    meas = truth + rng.normal(0, 0.0015, truth.shape)
    fit = fit_reference_trajectory(times, meas, P0 + 0.01, V0 + [0.2, 0.3, -0.2], None, model)
    assert fit.success
    s_true = fit.spin_basis.T @ SPIN
    assert np.all(np.abs(fit.params[6:] - s_true) < 3 * fit.param_sigma[6:])
    # the gyro part (73 rad/s here) is barely observable, and the fit says so
    assert fit.param_sigma[6] > 30.0 > 3 * fit.spin_transverse_sigma.min()
    assert np.abs(fit.v0 - V0).max() < 0.05
    assert np.isnan(fit.spin_axis_angle_deg)


def test_unsynchronised_back_pair_time_offset_is_fitted():
    """The two stereo pairs have independent strobes (SPEC J1): fit the back pair's clock offset."""
    model = FlightModel.nathan_model()
    times, truth, gap = seed_capture(model)
    groups = np.zeros(len(times), int)
    groups[gap:] = 1  # back pair (and the lost flash) on its own clock
    delta = 0.0137
    recorded = times - delta * groups
    rng = np.random.default_rng(2)
    meas, p0m, v0m, wm = noisy_measurement(truth, gap, rng, FitPriors())
    fit = fit_reference_trajectory(recorded, meas, p0m, v0m, wm, model, time_groups=groups)
    assert fit.success and fit.time_offsets.shape == (1,)
    assert abs(fit.time_offsets[0] - delta) < 3 * fit.time_offset_sigma[0] < 1e-3
    np.testing.assert_allclose(fit.times, times, atol=1e-3)
    assert fit.mean_error < 0.004 and np.abs(fit.v0 - V0).max() < 0.05
    naive = fit_reference_trajectory(recorded, meas, p0m, v0m, wm, model)
    assert naive.mean_error > 5 * fit.mean_error  # ignoring the offset does not fit
    with pytest.raises(ValueError, match="time_groups"):
        fit_reference_trajectory(recorded, meas, p0m, v0m, wm, model, time_groups=-groups)


def test_exact_data_gives_exact_fit_and_seed_table_row():
    model = FlightModel()
    times, truth, _ = seed_capture(model)
    fit = fit_reference_trajectory(times, truth, P0, V0 + [0.5, -0.5, 0.3], SPIN * 1.05, model,
                                   priors=FitPriors(np.inf, np.inf, np.inf, np.inf))
    assert fit.max_error < 1e-6
    np.testing.assert_allclose(fit.v0, V0, atol=1e-6)
    np.testing.assert_allclose(fit.spin, SPIN, atol=1e-3)
    row = fit.seed_table_row()
    assert row["speed_mph"] == pytest.approx(np.linalg.norm(V0) / 0.44704, abs=1e-3)
    assert row["max_err_mm"] < 0.01
    assert row["velocity_angle_deg"] > 0.5 and row["speed_diff_mph"] < 0


def test_bad_input():
    with pytest.raises(ValueError, match=r"positions must have shape \(3, 3\), got \(3, 2\)"):
        fit_reference_trajectory([0, 1, 2], np.zeros((3, 2)), P0, V0)
    with pytest.raises(ValueError, match="at least 9"):
        fit_reference_trajectory([0, 1], np.zeros((2, 3)), P0, V0)
    with pytest.raises(ValueError, match="method"):
        fit_reference_trajectory(np.arange(4.0), np.zeros((4, 3)), P0, V0, method="nelder")
    with pytest.raises(ValueError, match="non-zero"):
        spin_basis([0, 0, 0])


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_fit_without_spin_starts_from_the_curvature_and_reaches_the_same_optimum(kind, monkeypatch):
    """Regression (issue 3, speed): started at zero spin, the positions-only fit of a studio
    3000 rpm pitch crawled (the seed model's lift grows as |w| w: no gradient at w = 0) for ~3000
    residual evaluations; the curvature start took 5. The start must not change the optimum.
    (Since the fit uses Levenberg-Marquardt, this synthetic seed-model pitch needs fewer
    evaluations from zero spin than from the curvature start, 4952 vs 8744, while the studio
    captures need fewer from the curvature start, e.g. 2844 vs 3385: the evaluation counts are
    measured by the benchmark, not asserted here.)"""
    import stillcap.ball.fit as fit_mod

    model = FlightModel(kind=kind)
    spin = spin_vector(3000.0, 210.0, V0, efficiency=0.95)
    times, truth, gap = seed_capture(model, spin=spin)
    meas = truth + np.random.default_rng(7).normal(0, 0.0005, truth.shape)
    b = spin_basis(V0)
    start = b.T @ fit_mod._spin_start(times, meas, model)
    true = b.T @ spin
    assert np.linalg.norm(start[1:] - true[1:]) < 0.25 * np.linalg.norm(true[1:])  # transverse spin
    fit = fit_reference_trajectory(times, meas, P0, V0 + [0.1, 0.2, -0.1], None, model)
    assert fit.success
    assert np.all(np.abs(fit.params[7:] - true[1:]) < 4 * fit.param_sigma[7:])
    monkeypatch.setattr(fit_mod, "_spin_start", lambda *a, **k: np.zeros(3))
    zero = fit_reference_trajectory(times, meas, P0, V0 + [0.1, 0.2, -0.1], None, model)
    assert np.all(np.abs(fit.params - zero.params) < 0.05 * fit.param_sigma)


def test_spin_start_of_a_spinless_flight_is_near_zero():
    from stillcap.ball.fit import _spin_start

    model = FlightModel(kind="seed")
    t = np.linspace(0.0, 0.4, 10)
    flight = simulate(P0, V0, np.zeros(3), t, model).positions  # gravity and drag only
    assert np.linalg.norm(_spin_start(t, flight, model)) < 10.0  # rad/s (< 100 rpm)
    assert np.all(_spin_start(t[:3], flight[:3], model) == 0.0)  # too few points


def test_gyro_parameterisation_round_trip_and_jacobian():
    from stillcap.ball.fit import _basis_to_gyro, _gyro_jacobian, _gyro_to_basis

    rng = np.random.default_rng(3)
    for s in rng.normal(0, 150, (5, 3)):
        g = _basis_to_gyro(s)
        np.testing.assert_allclose(_gyro_to_basis(g), s, atol=1e-9)
        assert np.linalg.norm(g[1:]) == pytest.approx(np.linalg.norm(s))  # |e| = |w|: the seed lift
        J = np.zeros((3, 3))
        for i in range(3):
            h = np.zeros(3)
            h[i] = 1e-6
            J[:, i] = (_gyro_to_basis(g + h) - _gyro_to_basis(g - h)) / 2e-6
        np.testing.assert_allclose(_gyro_jacobian(g), J, rtol=1e-6, atol=1e-6)


GYRO_V0 = np.array([0.4, -38.3, -1.1])  # 86 mph
GYRO_SPIN = spin_vector(2500.0, 270.0, GYRO_V0, efficiency=0.3)  # a gyro slider


def gyro_flight(rng, noise=0.0005):
    model = FlightModel(kind="seed")
    times, truth, gap = seed_capture(model, p0=P0, v0=GYRO_V0, spin=GYRO_SPIN)
    meas = truth + rng.normal(0, noise, truth.shape)
    meas[gap] = np.nan
    return model, times, meas


def test_positions_only_fit_sees_the_axial_spin_of_a_gyro_pitch():
    """Issue 3: holding the axial spin at 0 without a measured spin (only the transverse part
    "observable") biased the studio gyro sliders and curveballs (1.5-2 mm RMS instead of 0.6,
    velocity 12-17 sigma off): the velocity turns during the flight, so the axial spin is seen.
    The free fit (gyro angle + effective transverse spin) finds it; held, the fit is worse."""
    model, times, meas = gyro_flight(np.random.default_rng(11))
    v0m = GYRO_V0 + [0.05, 0.1, -0.05]
    free = fit_reference_trajectory(times, meas, P0, v0m, None, model, position_sigma=0.0005)
    assert free.success and free.axial_spin_fitted
    s_true = free.spin_basis.T @ GYRO_SPIN
    assert s_true[0] > 200.0  # mostly gyro
    assert np.all(np.abs(free.params[6:9] - s_true) < 4 * free.param_sigma[6:9])
    assert free.param_sigma[6] < 0.2 * s_true[0]  # determined, not a guess
    assert np.all(np.abs(free.v0 - GYRO_V0) < 4 * free.v0_sigma)
    held = fit_reference_trajectory(times, meas, P0, v0m, None, model, position_sigma=0.0005,
                                    fit_axial_spin=False)
    assert not held.axial_spin_fitted and held.params[6] == 0.0
    assert np.all(held.covariance[6] == 0.0) and np.all(held.covariance[:, 6] == 0.0)
    assert held.rms_error > 1.5 * free.rms_error


def test_gyro_parameterisation_reaches_the_plain_optimum():
    """The seed model's positions-only fit runs in (gyro angle, effective transverse spin); the
    same problem in the plain (axial, transverse) coordinates (a measured spin with infinite
    prior sigmas is only a start) reaches the same parameters and covariance."""
    model, times, meas = gyro_flight(np.random.default_rng(12))
    v0m = GYRO_V0 + [0.05, 0.1, -0.05]
    gyro = fit_reference_trajectory(times, meas, P0, v0m, None, model, position_sigma=0.0005)
    inf = FitPriors(spin_axial_sigma=np.inf, spin_transverse_sigma=np.inf)
    plain = fit_reference_trajectory(times, meas, P0, v0m, gyro.spin * 0.98, model, position_sigma=0.0005,
                                     priors=inf)
    assert plain.success and gyro.success
    assert np.all(np.abs(gyro.params - plain.params) < 0.01 * gyro.param_sigma)
    np.testing.assert_allclose(gyro.param_sigma, plain.param_sigma, rtol=0.01)


def test_anisotropic_position_covariance_whitens_the_residuals():
    """Stereo positions are poor in depth: with the covariance shape given, the fit whitens the
    residuals (generalised least squares), so the depth-velocity sigma reflects the depth noise
    and the well-seen directions get their small sigmas; the isotropic fit pools them (the
    direction under-coverage of issue 3). An isotropic shape is the plain fit."""
    model = FlightModel()
    times, truth, gap = seed_capture(model)
    keep = np.all(np.isfinite(truth), axis=1) & (np.arange(len(times)) != gap)
    times, truth = times[keep], truth[keep]
    sd = np.array([0.0024, 0.0004, 0.0004])  # depth (x) 6x worse than y, z
    C = np.broadcast_to(np.diag(sd ** 2), (len(times), 3, 3))
    kw = dict(model=model, position_sigma=0.001, priors=FitPriors(position_sigma=1.0, velocity_sigma=100.0))
    rng = np.random.default_rng(100)
    meas = truth + rng.normal(0, 1, truth.shape) * sd
    fw = fit_reference_trajectory(times, meas, P0, V0, SPIN, position_covariance=C, **kw)
    fi = fit_reference_trajectory(times, meas, P0, V0, SPIN, **kw)
    assert fw.success and fi.success
    assert np.abs(fw.v0 - V0).max() < 0.05
    # pooled s ~ 1.4 mm: too small for the depth (2.4 mm), too large for y, z (0.4 mm)
    assert fw.v0_sigma[0] > 1.4 * fi.v0_sigma[0]
    assert fw.v0_sigma[2] < 0.5 * fi.v0_sigma[2]
    # whitened residuals have unit scale: residual_scale ~ the noise over the mean sigma
    assert 0.6 < fw.residual_scale * 0.001 / np.sqrt(np.mean(sd ** 2)) < 1.4
    iso = fit_reference_trajectory(times, meas, P0, V0, SPIN, position_covariance=np.broadcast_to(
        np.eye(3) * 4e-6, C.shape), **kw)
    assert np.all(np.abs(iso.params - fi.params) <= 1e-4 * fi.param_sigma)  # same optimum
    np.testing.assert_allclose(iso.covariance, fi.covariance, rtol=1e-4, atol=1e-14)
    np.testing.assert_allclose(iso.position_gain, fi.position_gain, rtol=1e-4,
                               atol=1e-4 * np.abs(fi.position_gain).max())
    with pytest.raises(ValueError, match=r"position_covariance must have shape \(\d+, 3, 3\)"):
        fit_reference_trajectory(times, meas, P0, V0, SPIN, position_covariance=np.eye(3), **kw)
