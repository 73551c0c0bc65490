"""Flight physics: air, coefficients, forces, integrators (SPEC J1 "Flight physics")."""

import numpy as np
import pytest

from stillcap.ball.physics import (
    G0, PLATE_FRONT_Y, AirProperties, Atmosphere, BallProperties, FlightModel, cross_plane,
    saturation_vapour_pressure, simulate, simulate_batch,
)

MPH = 0.44704
P0 = np.array([-0.5, 16.6, 1.8])
V0 = np.array([0.4, -28.0, -0.8])
BACKSPIN = np.array([-160.0, 0.0, 0.0])  # -x spin on a ball flying -y: Magnus force up


# ---- air ----------------------------------------------------------------------------------------
def test_dry_standard_air_density():
    atm = Atmosphere(temperature_c=15.0, pressure_pa=101325.0, relative_humidity=0.0)
    assert atm.density == pytest.approx(1.225, abs=0.001)


def test_humidity_heat_and_altitude_thin_the_air():
    base = Atmosphere(21.1, 101325.0, 0.0, 0.0).density
    assert Atmosphere(21.1, 101325.0, 1.0, 0.0).density < base
    assert Atmosphere(35.0, 101325.0, 0.0, 0.0).density < base
    denver = Atmosphere(21.1, 101325.0, 0.0, 1609.0).density
    assert denver / base == pytest.approx(np.exp(-1.217e-4 * 1609.0), rel=1e-9)


def test_saturation_vapour_pressure_known_values():
    assert saturation_vapour_pressure(0.0) == pytest.approx(611.2, rel=1e-3)
    assert saturation_vapour_pressure(20.0) == pytest.approx(2339.0, rel=2e-3)
    assert saturation_vapour_pressure(100.0) == pytest.approx(101325.0, rel=1e-2)


def test_atmosphere_air_viscosity_close_to_seed_default():
    air = Atmosphere(20.0, 101325.0, 0.5).air()
    assert air.kinematic_viscosity == pytest.approx(1.5e-5, rel=0.03)
    assert air.density == pytest.approx(1.2, rel=0.01)


@pytest.mark.parametrize("bad", [dict(relative_humidity=1.5), dict(pressure_pa=-1.0)])
def test_atmosphere_rejects_nonsense(bad):
    with pytest.raises(ValueError):
        Atmosphere(**bad)


# ---- coefficients -------------------------------------------------------------------------------
@pytest.mark.parametrize("mph, cd", [(40, 0.60), (60, 0.26), (80, 0.12)])
def test_seed_drag_crisis_values_from_spec(mph, cd):
    assert FlightModel().drag_coefficient(mph * MPH) == pytest.approx(cd, abs=0.005)


def test_seed_drag_is_clamped_outside_fitted_reynolds_range():
    m = FlightModel()
    lo = m.drag_coefficient(0.8e5 * m.air.kinematic_viscosity / m.ball.diameter)
    assert m.drag_coefficient(1.0) == pytest.approx(lo)
    assert m.drag_coefficient(200.0) == pytest.approx(m.drag_coefficient(2.2e5 * 1.5e-5 / 0.0737))


def test_seed_lift_is_alaways():
    m = FlightModel()
    assert m.lift_coefficient(30.0, 200.0) == pytest.approx(1.5 * 0.03685 * 200.0 / 30.0)


def test_nathan_coefficients():
    m = FlightModel.nathan_model()
    r = m.ball.radius
    s = r * 200.0 / 40.0
    assert m.lift_coefficient(40.0, 200.0) == pytest.approx(1.12 * s / (0.583 + 2.333 * s))
    assert m.lift_coefficient(1.0, 1e9) == pytest.approx(1.12 / 2.333, rel=1e-3)  # saturates
    rpm2000 = 2000 * 2 * np.pi / 60
    assert m.drag_coefficient(40.0, rpm2000) == pytest.approx(0.3008 + 2 * 0.0292)


# ---- forces -------------------------------------------------------------------------------------
def test_vacuum_flight_is_a_parabola():
    vac = FlightModel(air=AirProperties(density=1e-30))
    t = np.linspace(0.0, 0.5, 6)
    tr = simulate(P0, V0, BACKSPIN, t, vac)
    expect = P0 + V0 * t[:, None] + 0.5 * np.array([0, 0, -G0]) * t[:, None] ** 2
    np.testing.assert_allclose(tr.positions, expect, atol=1e-9)


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_drag_opposes_velocity_and_backspin_lifts(kind):
    m = FlightModel(kind=kind)
    a0 = m.acceleration(V0, np.zeros(3)) - np.array(m.gravity)
    assert np.linalg.norm(np.cross(a0, V0)) < 1e-9 * np.linalg.norm(a0) * np.linalg.norm(V0)
    assert np.dot(a0, V0) < 0
    a1 = m.acceleration(V0, BACKSPIN) - m.acceleration(V0, np.zeros(3))
    assert a1[2] > 0.5  # several m/s^2 of lift at 63 mph, 1500 rpm


def test_nathan_gyro_spin_has_no_effect_seed_gyro_has_no_magnus():
    gyro = V0 / np.linalg.norm(V0) * 150.0
    n = FlightModel.nathan_model()
    np.testing.assert_allclose(n.acceleration(V0, gyro), n.acceleration(V0, np.zeros(3)), atol=1e-12)
    s = FlightModel()
    np.testing.assert_allclose(s.acceleration(V0, gyro), s.acceleration(V0, np.zeros(3)), atol=1e-12)


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_scalar_and_vector_accelerations_agree(kind):
    m = FlightModel(kind=kind, wind=(1.0, -2.0, 0.5))
    rng = np.random.default_rng(3)
    for v, w in zip(rng.normal(0, 20, (5, 3)), rng.normal(0, 150, (5, 3))):
        np.testing.assert_allclose(m._fixed_spin_scalar(w)(*v, 0.3), m.acceleration(v, w, 0.3),
                                   rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("wind", [(0.0, 0.0, 0.0), (1.0, -2.0, 0.5)])
def test_seed_scalar_acceleration_is_bit_identical(wind):
    # simulate / cross_plane use the float twin for the seed model: it must not change a bit
    m = FlightModel(kind="seed", wind=wind)
    rng = np.random.default_rng(5)
    vs = V0 + rng.normal(0, 15, (200, 3))
    ws = rng.normal(0, 200, (200, 3))
    ws[0] = 0.0
    ws[1] = 2.0 * vs[1]
    vs[2] = 1.0  # below the polynomial's Reynolds range
    for v, w in zip(vs, ws):
        a = m.acceleration(v, w, 0.1)
        b = np.array(m._fixed_spin_scalar(w)(*v.tolist(), 0.1))
        assert np.array_equal(a, b), (v, w, a - b)


@pytest.mark.parametrize("wind", [(0.0, 0.0, 0.0), (1.0, -2.0, 0.5)])
@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_fixed_spin_scalar_kernel_on_edge_cases(kind, wind):
    # the single-flight integrators' float kernel against the NumPy method: no spin, a huge spin
    # (Reynolds clamp, lift saturation), a slow ball, times before t0; bit for bit for the seed
    # model, to rounding for Nathan's (math.exp vs np.exp)
    m = FlightModel(kind=kind, wind=wind)
    rng = np.random.default_rng(11)
    vs = V0 + rng.normal(0, 15, (50, 3))
    vs[0] = 1.0  # slow ball: Re below the seed polynomial's range
    for w in (rng.normal(0, 200, 3), np.zeros(3), 1e6 * rng.normal(0, 1, 3)):
        acc = m._fixed_spin_scalar(w)
        for v in vs:
            for dt in (0.0, 0.25, -0.1):
                got, want = np.array(acc(*v.tolist(), dt)), m.acceleration(v, w, dt)
                if kind == "seed":
                    assert np.array_equal(got, want), (v, w, dt)
                else:
                    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("wind", [(0.0, 0.0, 0.0), (1.0, -2.0, 0.5)])
@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_fixed_spin_kernel_is_bit_identical_to_acceleration(kind, wind):
    # the integrators' in-place kernel must not change a single bit of the physics
    m = FlightModel(kind=kind, wind=wind)
    rng = np.random.default_rng(7)
    v = V0 + rng.normal(0, 8, (19, 3))
    w = rng.normal(0, 200, (19, 3))
    w[3] = 0.0  # no spin: zero Magnus force
    w[4] = 2.5 * v[4]  # pure gyro spin: w x v = 0
    w[5] = 1e6 * w[5]  # seed model's Reynolds clamp and Nathan's lift saturation
    v[6] = 1.0  # slow ball: Re below the seed polynomial's range
    acc = m._fixed_spin(w)
    for dt in (0.0, 0.37):
        expected = m.acceleration(v, w, dt)
        got = acc(v, dt)
        assert got.shape == (19, 3)
        assert np.array_equal(got, expected)


def test_acceleration_broadcasts_over_many_balls():
    m = FlightModel()
    v = np.tile(V0, (4, 1))
    a = m.acceleration(v, BACKSPIN)
    assert a.shape == (4, 3)
    np.testing.assert_allclose(a, np.tile(m.acceleration(V0, BACKSPIN), (4, 1)))


def test_wind_is_relative_velocity():
    still = FlightModel()
    windy = FlightModel(wind=(0.0, 5.0, 0.0))
    np.testing.assert_allclose(windy.acceleration(V0, BACKSPIN),
                               still.acceleration(V0 - [0, 5, 0], BACKSPIN))


# ---- integrators --------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_backward_integration_returns_to_start(kind):
    m = FlightModel(kind=kind)
    fwd = simulate(P0, V0, BACKSPIN, [0.4], m)
    back = simulate(fwd.positions[0], fwd.velocities[0], BACKSPIN, [0.0], m, t0=0.4)
    if kind == "seed":  # the Nathan spin decay is referred to t0, so only the seed model is reversible
        np.testing.assert_allclose(back.positions[0], P0, atol=1e-7)
    assert back.success


@pytest.mark.parametrize("kind", ["seed", "nathan"])
@pytest.mark.parametrize("method", ["rk4", "dopri5"])
def test_fast_integrator_matches_reference(kind, method):
    m = FlightModel(kind=kind)
    t = np.concatenate([[-0.05], np.linspace(0.0, 0.6, 17), [0.61]])
    ref = simulate(P0, V0, BACKSPIN, t, m)
    fast = simulate_batch(P0, V0, BACKSPIN, t, m, method=method, max_step=0.02)
    assert fast.positions.shape == (1, len(t), 3)
    assert np.abs(fast.positions[0] - ref.positions).max() < 1e-6
    assert np.abs(fast.velocities[0] - ref.velocities).max() < 1e-5


def test_batch_equals_single_runs():
    rng = np.random.default_rng(0)
    p = P0 + rng.normal(0, 0.1, (5, 3))
    v = V0 + rng.normal(0, 1.0, (5, 3))
    w = BACKSPIN + rng.normal(0, 20, (5, 3))
    t = np.linspace(0, 0.5, 7)
    batch = simulate_batch(p, v, w, t)
    for i in range(5):
        one = simulate_batch(p[i], v[i], w[i], t)
        np.testing.assert_allclose(batch.positions[i], one.positions[0], atol=1e-12)


def test_requested_time_at_t0_returns_initial_state():
    tr = simulate(P0, V0, BACKSPIN, [0.0, 0.1])
    np.testing.assert_allclose(tr.positions[0], P0)
    b = simulate_batch(P0, V0, BACKSPIN, [0.0])
    np.testing.assert_allclose(b.positions[0, 0], P0)


def test_cross_plane_reaches_front_of_plate():
    c = cross_plane(P0, V0, BACKSPIN)
    assert c.success and 0.5 < c.time < 0.8
    assert c.position[1] == pytest.approx(PLATE_FRONT_Y, abs=1e-9)
    state = c.trajectory(c.time)
    np.testing.assert_allclose(state[:3], c.position, atol=1e-9)
    miss = cross_plane(P0, -V0, BACKSPIN, t_max=0.2)  # thrown away from the plate
    assert not miss.success and np.isnan(miss.time)


def test_bad_input_names_shape():
    with pytest.raises(ValueError, match=r"p0 must have shape \(3,\), got \(2,\)"):
        simulate([0, 1], V0, BACKSPIN, [0.1])
    with pytest.raises(ValueError, match=r"times must have shape \(N,\), got \(2, 2\)"):
        simulate(P0, V0, BACKSPIN, np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"v0 must have shape"):
        simulate_batch(P0, np.zeros((2, 4)), BACKSPIN, [0.1])
    with pytest.raises(ValueError, match="kind"):
        FlightModel(kind="golf")
    with pytest.raises(ValueError, match="method"):
        simulate_batch(P0, V0, BACKSPIN, [0.1], method="euler")
    with pytest.raises(ValueError, match="positive"):
        BallProperties(mass=0.0)


class _GravityOnly:
    """A model with only the AccelerationModel protocol (no FlightModel kernels)."""

    def acceleration(self, velocity, spin, dt):
        return np.broadcast_to(np.array([0.0, 0.0, -9.80665]), np.broadcast_shapes(
            np.shape(velocity), np.shape(spin))).copy()


def test_simulate_batch_with_a_protocol_model_is_a_parabola():
    # the generic path of the batch integrator (one and several flights): RK4 is exact on a
    # parabola, and so is the quintic Hermite interpolation between the nodes
    ts = np.linspace(-0.1, 0.45, 7)
    v0 = np.array([[0.5, -30.0, 1.0], [1.0, -35.0, 2.0]])
    for v in (v0[:1], v0):
        tr = simulate_batch(np.zeros(3), v, np.ones(3), ts, _GravityOnly(), t0=0.05)
        dt = (ts - 0.05)[None, :, None]
        g = np.array([0.0, 0.0, -9.80665])
        np.testing.assert_allclose(tr.positions, v[:, None] * dt + 0.5 * g * dt ** 2, atol=1e-12)
        np.testing.assert_allclose(tr.velocities, v[:, None] + g * dt, atol=1e-12)
