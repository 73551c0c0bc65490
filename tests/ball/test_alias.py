"""Spin-rate aliasing: candidates, second strobe rate, flight curvature (SPEC J1 "beyond")."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.ball.alias import (AliasResolution, CurvatureMeasurement, StrobeMeasurement,
                                 alias_candidates, resolve_aliases)
from stillcap.ball.fit import fit_reference_trajectory
from stillcap.ball.metrics import FT, MPH, spin_vector
from stillcap.ball.orientation import RPM_PER_RAD_S, fit_spin, simulate_observations
from stillcap.ball.physics import FlightModel, simulate

P0 = np.array([-0.6, 54.5 * FT, 1.8])
V0 = 85 * MPH * np.array([0.03, -np.cos(np.radians(2)), -np.sin(np.radians(2))])
T_FRONT = np.arange(9) / 80.0  # front pair, 80 Hz, right after release
T_BACK = 0.33 + np.arange(7) / 50.0  # back pair, 50 Hz, near the plate (own clock)


def principal(spin, f, rng=None, sigma=0.3):
    """What a fit at ``f`` Hz reports: the principal alias, plus noise (rad/s)."""
    p = Rotation.from_rotvec(np.asarray(spin) / f).as_rotvec() * f
    if rng is not None:
        p = p + rng.normal(scale=sigma, size=3)
    return p


def measurement(spin, f, rng=None, sigma=0.3):
    return StrobeMeasurement(principal(spin, f, rng, sigma), f, np.eye(3) * sigma ** 2, f"{f:g} Hz")


def curvature_from_flight(spin, model, seed=0):
    """Reference fit (no spin prior) to 2 mm-noise positions of both pairs."""
    rng = np.random.default_rng(seed)
    times = np.concatenate([T_FRONT, T_BACK])
    pos = simulate(P0, V0, spin, times, model).positions + rng.normal(scale=0.002, size=(len(times), 3))
    v0m = (pos[1] - pos[0]) * 80.0
    fit = fit_reference_trajectory(times, pos, pos[0], v0m, None, model)
    assert fit.success
    return CurvatureMeasurement.from_reference_fit(fit, model)


def test_candidates_above_nyquist():
    a = np.array([0.6, 0.0, 0.8])
    c = alias_candidates(a * 3000 / RPM_PER_RAD_S, 80.0)
    assert [round(x.spin_rpm) for x in c] == [1800, 3000]
    assert c[0].axis @ a == pytest.approx(-1) and c[1].axis @ a == pytest.approx(1)
    # what the fit reports (1800 rpm about -a) has the same candidates
    c2 = alias_candidates(-a * 1800 / RPM_PER_RAD_S, 80.0)
    assert np.allclose([x.spin for x in c2], [x.spin for x in c], atol=1e-9)
    # at the Nyquist rate both axis signs are candidates
    c3 = alias_candidates(a * 2400 / RPM_PER_RAD_S, 80.0)
    assert [round(x.spin_rpm) for x in c3] == [2400, 2400] and c3[0].axis @ c3[1].axis == pytest.approx(-1)
    # 3000 rpm at 50 Hz is a full turn per flash: looks like no spin
    c4 = alias_candidates(a * 3000 / RPM_PER_RAD_S, 50.0)
    assert [round(x.spin_rpm) for x in c4] == [0, 3000, 3000]
    assert [round(x.spin_rpm) for x in alias_candidates(a * 1000 / RPM_PER_RAD_S, 80.0)] == [1000, 3800]
    assert len(alias_candidates(a * 1000 / RPM_PER_RAD_S, 80.0, max_rpm=3000)) == 1


def test_two_strobe_rates_resolve_3000_rpm():
    rng = np.random.default_rng(1)
    for k in range(5):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        w = axis * 3000 / RPM_PER_RAD_S
        res = resolve_aliases([measurement(w, 80.0, rng), measurement(w, 50.0, rng)])
        assert isinstance(res, AliasResolution) and not res.ambiguous, res.message
        assert res.best.spin_rpm == pytest.approx(3000, abs=10)  # noise 0.3 rad/s = 2.9 rpm
        assert res.best.axis @ axis > np.cos(np.radians(1))
        assert res.best.source == 0  # the 50 Hz pair's aliases have unknown axes (full turn)
        assert res.evidence == ["80 Hz", "50 Hz"]
    # one strobe alone cannot tell
    alone = resolve_aliases(measurement(w, 80.0, rng))
    assert alone.ambiguous and "ambiguous" in alone.message
    assert {round(c.spin_rpm, -1) for c in alone.candidates[:2]} == {1800, 3000}


def test_end_to_end_front_80hz_back_50hz():
    """Markers of a 3000 rpm ball through both pairs: per-pair global fits, then aliases."""
    rng = np.random.default_rng(5)
    axis = spin_vector(3000, 210, V0, 0.9)
    w = axis
    R0 = Rotation.random(random_state=rng).as_matrix()
    front = simulate_observations(T_FRONT, R0, w, [1.0, 0.2, 0.1], t0=0.0, noise_deg=1.0,
                                  miss_rate=0.1, rng=rng)
    back = simulate_observations(T_BACK, R0, w, [0.5, 1.0, 0.6], t0=0.0, noise_deg=1.5,
                                 margin_deg=20.0, miss_rate=0.1, rng=rng)
    r80 = fit_spin(T_FRONT, front)
    r50 = fit_spin(T_BACK, back)
    assert r80.success and r50.success
    assert r80.spin_rpm == pytest.approx(1800, abs=10)  # principal alias at 80 Hz
    assert r50.spin_rpm < 30  # a full turn per flash at 50 Hz
    res = resolve_aliases([r80, r50])
    assert not res.ambiguous, res.message
    assert res.best.spin_rpm == pytest.approx(3000, abs=10)
    refit = fit_spin(T_FRONT, front, spin_init=res.best.spin)
    e_rate, e_axis = refit.angle_errors_deg(w)
    assert abs(e_rate) < 5 and e_axis < 1.0


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_curvature_alone_resolves(kind):
    """80 Hz only: 1800 rpm about -a and 3000 rpm about a bend the flight opposite ways."""
    model = FlightModel(kind=kind)
    w = spin_vector(3000, 200, V0, 0.9)
    curv = curvature_from_flight(w, model)
    assert curv.lift == ("transverse" if kind == "nathan" else "total")
    res = resolve_aliases([measurement(w, 80.0, np.random.default_rng(2))], curv)
    assert not res.ambiguous, res.message
    assert res.best.spin_rpm == pytest.approx(3000, abs=5)
    assert res.evidence == ["80 Hz", "curvature"] and res.best.probability > 0.99


def test_curvature_fixes_the_axis_sign_at_nyquist():
    """2400 rpm at 80 Hz is half a turn per flash: the axis sign is unknown from the markers."""
    w = spin_vector(2400, 180, V0, 1.0)
    curv = curvature_from_flight(w, FlightModel(kind="nathan"))
    res = resolve_aliases([measurement(w, 80.0, np.random.default_rng(3))], curv)
    assert not res.ambiguous and res.best.axis @ w > 0.99 * np.linalg.norm(w)


def test_gyro_spin_with_one_strobe_is_ambiguous():
    """Pure gyro spin does not bend the flight (Nathan's lift): curvature cannot decide."""
    model = FlightModel(kind="nathan")
    w = spin_vector(3000, 200, V0, 0.0)
    curv = curvature_from_flight(w, model, seed=4)
    res = resolve_aliases([measurement(w, 80.0, np.random.default_rng(4))], curv)
    assert res.ambiguous and res.likelihood_ratio >= 0.05
    assert "ambiguous" in res.message
    # a second strobe rate settles it
    res2 = resolve_aliases([measurement(w, 80.0), measurement(w, 50.0)], curv)
    assert not res2.ambiguous and res2.best.spin_rpm == pytest.approx(3000, abs=5)


def test_curvature_effective_spin():
    basis = np.array([[1.0, 0], [0, 0], [0, 1.0]])  # flight along y
    c = CurvatureMeasurement(basis, [100.0, 0.0], np.eye(2), "total")
    assert np.allclose(c.effective([30.0, 40.0, 0.0]), [50.0, 0.0])  # |w| along w_perp
    t = CurvatureMeasurement(basis, [100.0, 0.0], np.eye(2), "transverse")
    assert np.allclose(t.effective([30.0, 40.0, 0.0]), [30.0, 0.0])


def test_bad_input_names_shapes():
    with pytest.raises(ValueError, match=r"spin must have shape \(3,\), got \(2,\)"):
        StrobeMeasurement([1.0, 2.0], 80.0, np.eye(3))
    with pytest.raises(ValueError, match=r"covariance must have shape \(3, 3\), got \(2, 2\)"):
        StrobeMeasurement([1.0, 2.0, 3.0], 80.0, np.eye(2))
    with pytest.raises(ValueError, match="strobe_hz must be positive"):
        StrobeMeasurement([1.0, 2.0, 3.0], 0.0, np.eye(3))
    with pytest.raises(ValueError, match=r"basis must have shape \(3, 2\), got \(3, 3\)"):
        CurvatureMeasurement(np.eye(3), [1.0, 2.0], np.eye(2))
    with pytest.raises(ValueError, match="lift must be"):
        CurvatureMeasurement(np.eye(3)[:, :2], [1.0, 2.0], np.eye(2), "magnus")
    with pytest.raises(ValueError, match="at least one strobe measurement"):
        resolve_aliases([])
    with pytest.raises(ValueError, match="min_rpm <= max_rpm"):
        alias_candidates([1.0, 0, 0], 80.0, min_rpm=100, max_rpm=50)
    with pytest.raises(ValueError, match="no alias candidate"):
        resolve_aliases(measurement(np.array([0, 0, 100.0]), 80.0), min_rpm=3900, max_rpm=3950)
