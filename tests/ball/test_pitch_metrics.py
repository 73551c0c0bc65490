"""Pitch metrics in the field frame (SPEC J1 "Baseball conventions"), checked on real PITCHf/x data."""

import csv
import json

import numpy as np
import pytest
from support import shared_data

from stillcap.ball.metrics import (
    FT, NINE_NAMES, PLATE_FRONT_Y_FT, NineParameterFit, PitchMetrics, clock_tilt,
    fit_nine_parameter, fit_nine_parameter_batch, movement_axis_deg, movement_in, pitch_metrics, pitch_metrics_batch, pitch_metrics_from_flight,
    plate_location_ft, spin_axis_deg, spin_efficiency, spin_rate_rpm, spin_vector, time_at_y,
)
from stillcap.ball.physics import FlightModel, simulate

P0 = np.array([-0.6, 54.5 * FT, 1.8])  # 6 ft extension, right-hander's arm slot
V0 = np.array([1.0, -38.0, -1.5])  # about 85 mph
NATHAN = FlightModel.nathan_model()


@pytest.fixture(scope="module")
def pitchfx():
    path = shared_data("pitchfx") / "pitchRx_pitches.csv"  # skips when ../shared/data is absent
    if not path.exists():
        pytest.skip(f"real PITCHf/x data {path} is absent (see shared/data/README.md)")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    cols = list(NINE_NAMES) + ["px", "pz", "pfx_x", "pfx_z", "start_speed"]
    return np.array([[float(r[c]) for c in cols] for r in rows])


def test_pitchfx_plate_location_and_movement_reproduce_the_file(pitchfx):
    nine = pitchfx[:, :9]
    assert len(nine) == 1858
    px, pz = plate_location_ft(nine)
    mx, mz = movement_in(nine)
    err = {"px_ft": np.abs(px - pitchfx[:, 9]).max(), "pz_ft": np.abs(pz - pitchfx[:, 10]).max(),
           "pfx_x_in": np.abs(mx - pitchfx[:, 11]).max(), "pfx_z_in": np.abs(mz - pitchfx[:, 12]).max()}
    print("PITCHf/x max errors over 1858 pitches:", err)
    assert err["px_ft"] < 0.01 and err["pz_ft"] < 0.01
    assert err["pfx_x_in"] < 0.1 and err["pfx_z_in"] < 0.1


def test_pitchfx_dataclass_path_matches_vectorised(pitchfx):
    for row in pitchfx[::300]:
        m = PitchMetrics.from_nine_parameter(NineParameterFit.from_array(row[:9]))
        assert m.plate_x_ft == pytest.approx(row[9], abs=0.01)
        assert m.pitchfx_pfx_z_in == pytest.approx(row[12], abs=0.1)
        assert np.isnan(m.induced_vertical_break_in)  # Statcast's needs the release point
        assert m.start_speed_mph == pytest.approx(row[13], abs=0.06)


def test_time_at_y_roots():
    nine = np.array([0, 50, 6, 0, -130, -5, 0, 30, -15.0])
    t = time_at_y(nine, PLATE_FRONT_Y_FT)
    y = 50 - 130 * t + 15 * t * t
    assert 0.35 < t < 0.45 and y == pytest.approx(PLATE_FRONT_Y_FT)
    assert time_at_y(nine, 50.0) == 0.0
    assert time_at_y(nine, 55.0) < 0
    assert np.isnan(time_at_y(np.array([0, 50, 6, 0, 10, 0, 0, -1, 0.0]), 200.0))


def test_nine_parameter_fit_recovers_a_constant_acceleration_pitch():
    truth = np.array([-2.0, 50.0, 6.0, 6.0, -130.0, -4.0, -8.0, 28.0, -15.0])
    t = np.linspace(-0.05, 0.42, 40)
    pos_ft = truth[:3] + truth[3:6] * t[:, None] + 0.5 * truth[6:] * t[:, None] ** 2
    pos = pos_ft * FT
    pos[5] = np.nan  # a gap
    fit = fit_nine_parameter(t + 10.0, pos)  # arbitrary clock
    assert fit.success and fit.t_ref == pytest.approx(10.0, abs=1e-9)
    np.testing.assert_allclose(fit.as_array(), truth, atol=1e-8)
    assert fit.rms_residual_ft < 1e-9 and fit.n_points == 39


def test_nine_parameter_fit_reports_failure():
    fit = fit_nine_parameter([0.0, 0.1], np.zeros((2, 3)))
    assert not fit.success and np.isnan(fit.x0)
    m = pitch_metrics([0.0, 0.1], np.zeros((2, 3)))
    assert not m.success and "9-parameter" in m.message


# ---- spin ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("axis, tilt", [(180, "12:00"), (210, "1:00"), (225, "1:30"), (0, "6:00"),
                                        (90, "9:00"), (270, "3:00"), (187.4, "12:15"), (359, "6:00")])
def test_clock_tilt(axis, tilt):
    assert clock_tilt(axis) == tilt


def test_clock_tilt_nan_and_resolution():
    assert clock_tilt(float("nan")) == ""
    assert clock_tilt(181.0, resolution_min=1) == "12:02"
    with pytest.raises(ValueError):
        clock_tilt(180.0, resolution_min=0)


@pytest.mark.parametrize("axis", [0.0, 45.0, 135.0, 180.0, 212.0, 300.0])
@pytest.mark.parametrize("eff", [1.0, 0.6])
def test_spin_vector_round_trip(axis, eff):
    w = spin_vector(2250.0, axis, V0, efficiency=eff)
    assert spin_rate_rpm(w) == pytest.approx(2250.0)
    assert spin_axis_deg(w, V0) == pytest.approx(axis, abs=1e-9)
    assert spin_efficiency(w, V0) == pytest.approx(eff, abs=1e-12)


def test_backspin_direction_is_minus_x_for_a_pitch():
    w = spin_vector(1000.0, 180.0, [0, -1.0, 0])
    np.testing.assert_allclose(w / np.linalg.norm(w), [-1, 0, 0], atol=1e-12)


def test_pure_backspin_pitch():
    w = spin_vector(2300.0, 180.0, V0)
    m = pitch_metrics_from_flight(P0, V0, w, NATHAN)
    assert m.success
    assert m.spin_axis_deg == pytest.approx(180.0, abs=1e-9)
    assert m.spin_tilt == "12:00"
    assert m.spin_efficiency == pytest.approx(1.0)
    assert m.active_spin_rpm == pytest.approx(2300.0)
    assert m.gyro_angle_deg == pytest.approx(0.0, abs=1e-4)
    assert 8.0 < m.induced_vertical_break_in < 25.0
    assert m.pitchfx_spin_dir_deg == pytest.approx(180.0, abs=3.0)
    assert m.release_speed_mph == pytest.approx(np.linalg.norm(V0) / 0.44704)
    assert m.release_extension_ft == pytest.approx(6.0)
    assert m.release_pos_x_ft == pytest.approx(-0.6 / FT)
    assert 0.35 < m.plate_time_s < 0.5


def test_gyro_spin_has_zero_efficiency_and_little_movement():
    w = V0 / np.linalg.norm(V0) * (2300.0 * 2 * np.pi / 60)
    m = pitch_metrics_from_flight(P0, V0, w, NATHAN)
    none = pitch_metrics_from_flight(P0, V0, np.zeros(3), NATHAN)
    back = pitch_metrics_from_flight(P0, V0, spin_vector(2300.0, 180.0, V0), NATHAN)
    assert m.spin_efficiency == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(m.spin_axis_deg) and m.spin_tilt == ""
    # only the small angle gravity bends the velocity away from the spin axis lets it act
    assert abs(m.pfx_z_in - none.pfx_z_in) < 0.1 * (back.pfx_z_in - none.pfx_z_in)


@pytest.mark.parametrize("kind", ["seed", "nathan"])
def test_topspin_curveball_breaks_down(kind):
    v = np.array([0.5, -33.0, 0.5])  # 74 mph, released slightly upward
    w = spin_vector(2600.0, 20.0, v, efficiency=0.8)
    m = pitch_metrics_from_flight(P0, v, w, FlightModel(kind=kind))
    assert m.induced_vertical_break_in < -3.0
    assert m.spin_tilt in ("6:30", "6:45")


def test_mirror_symmetry_left_and_right_handers():
    # reflect x -> -x: positions and velocities flip x; the spin (a pseudovector) flips y and z
    flip_v = np.array([-1.0, 1.0, 1.0])
    flip_w = np.array([1.0, -1.0, -1.0])
    w = spin_vector(2400.0, 225.0, V0, efficiency=0.85)
    r = pitch_metrics_from_flight(P0, V0, w, NATHAN)
    lft = pitch_metrics_from_flight(P0 * flip_v, V0 * flip_v, w * flip_w, NATHAN)
    assert lft.pfx_x_in == pytest.approx(-r.pfx_x_in, abs=1e-9)
    assert lft.pfx_z_in == pytest.approx(r.pfx_z_in, abs=1e-9)
    assert lft.plate_x_ft == pytest.approx(-r.plate_x_ft, abs=1e-9)
    assert lft.release_pos_x_ft == pytest.approx(-r.release_pos_x_ft)
    assert lft.spin_axis_deg == pytest.approx(360.0 - r.spin_axis_deg)
    assert lft.pitchfx_spin_dir_deg == pytest.approx(360.0 - r.pitchfx_spin_dir_deg)
    assert (r.spin_tilt, lft.spin_tilt) == ("1:30", "10:30")
    assert lft.spin_efficiency == pytest.approx(r.spin_efficiency)


def test_arm_side_run_for_a_right_hander():
    w = spin_vector(2300.0, 215.0, V0)  # 1:10 tilt: movement up and toward third base (-x)
    m = pitch_metrics_from_flight(P0, V0, w, NATHAN)
    assert m.horizontal_break_in < -2.0 and m.induced_vertical_break_in > 8.0
    assert 180.0 < m.pitchfx_spin_dir_deg < 240.0


def test_metrics_from_sparse_measured_positions_with_gaps():
    w = spin_vector(2300.0, 200.0, V0)
    ts = np.linspace(0.0, 0.42, 30)
    dense = pitch_metrics_from_flight(P0, V0, w, NATHAN)
    tr = simulate(P0, V0, w, ts, NATHAN)
    pos = tr.positions.copy()
    pos[10:14] = np.nan
    m = pitch_metrics(ts, pos, w)
    assert m.pfx_z_in == pytest.approx(dense.pfx_z_in, abs=0.3)
    assert m.plate_x_ft == pytest.approx(dense.plate_x_ft, abs=0.02)
    assert m.release_speed_mph == pytest.approx(dense.release_speed_mph, abs=0.5)  # from the 9P fit


def test_to_dict_is_json_with_unit_named_keys():
    m = pitch_metrics_from_flight(P0, V0, spin_vector(2000.0, 190.0, V0), NATHAN)
    d = m.to_dict()
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    for key in ("release_speed_mph", "spin_rate_rpm", "spin_axis_deg", "spin_tilt", "pfx_x_in",
                "induced_vertical_break_in", "plate_x_ft", "release_extension_ft", "spin_efficiency"):
        assert key in back
    assert back["nine_parameter"]["y0"] == pytest.approx(50.0)
    assert PitchMetrics().to_dict()["spin_rate_rpm"] is None


def test_movement_axis_matches_pitchfx_definition():
    assert movement_axis_deg(0.0, 10.0) == pytest.approx(180.0)
    assert movement_axis_deg(-0.54, 12.14) == pytest.approx(182.55, abs=0.01)


def test_bad_input_names_shape():
    with pytest.raises(ValueError, match=r"positions must have shape \(3, 3\), got \(3, 2\)"):
        pitch_metrics([0, 0.1, 0.2], np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"spin must have shape \(3,\)"):
        spin_axis_deg([1, 2], V0)
    with pytest.raises(ValueError, match=r"\(\.\.\., 9\)"):
        plate_location_ft(np.zeros(8))
    with pytest.raises(ValueError, match="efficiency"):
        spin_vector(2000.0, 180.0, V0, efficiency=1.5)


# ---- many flights at once (the metric sigmas) ----------------------------------------------------
@pytest.mark.parametrize("gap", [False, True])
def test_batch_metrics_match_the_flight_by_flight_ones(gap):
    """Flights of different lengths on one grid (NaN = no sample), with and without a gap in
    one coordinate (the axes then fitted apart), pure gyro spin, no spin (no spin axis) and a
    flight too short to fit: the batch gives what pitch_metrics / fit_nine_parameter give for
    each flight's own samples."""
    ts = np.linspace(0.0, 0.45, 60)
    spins = [spin_vector(2300.0, 200.0, V0), spin_vector(2600.0, 30.0, V0, efficiency=0.4),
             spin_vector(2000.0, 180.0, V0, efficiency=0.0), np.zeros(3), spin_vector(1800.0, 90.0, V0)]
    starts = [0, 7, 13, 3, 58]  # the last flight keeps two samples: no fit
    T = np.full((len(spins), len(ts)), np.nan)
    P, V = np.full(T.shape + (3,), np.nan), np.full(T.shape + (3,), np.nan)
    for m, (w, i0) in enumerate(zip(spins, starts)):
        tr = simulate(P0 + 0.01 * m, V0 * (1.0 + 0.01 * m), w, ts, NATHAN)
        T[m, i0:], P[m, i0:], V[m, i0:] = ts[i0:], tr.positions[i0:], tr.velocities[i0:]
    if gap:
        P[1, 30, 2] = np.nan  # one coordinate not observed
    vals, nine = pitch_metrics_batch(T, P, np.array(spins), velocities=V)
    fits = fit_nine_parameter_batch(T, P)
    for m, i0 in enumerate(starts):
        one = pitch_metrics(T[m, i0:], P[m, i0:], spins[m], velocities=V[m, i0:])
        d, dn = one.to_dict(), one.to_dict()["nine_parameter"]
        assert bool(vals["success"][m]) == one.success == (m != 4)
        assert fits["n_points"][m] == dn["n_points"] and bool(fits["success"][m]) == dn["success"]
        for k, v in vals.items():
            if k != "success":
                ref = np.nan if d[k] is None else d[k]
                np.testing.assert_allclose(v[m], ref, rtol=1e-10, atol=1e-10, err_msg=f"flight {m} {k}")
        for k, v in nine.items():
            ref = np.nan if dn[k] is None else dn[k]
            np.testing.assert_allclose(v[m], ref, rtol=1e-10, atol=1e-10, err_msg=f"flight {m} nine {k}")
    assert np.isnan(vals["spin_axis_deg"][3]) and np.isnan(vals["spin_efficiency"][3])  # no spin
    no_spin, _ = pitch_metrics_batch(T, P, velocities=V)
    assert np.all(np.isnan(no_spin["spin_rate_rpm"])) and np.array_equal(no_spin["pfx_z_in"], vals["pfx_z_in"],
                                                                          equal_nan=True)
    with pytest.raises(ValueError, match="positions"):
        fit_nine_parameter_batch(ts, P[0])


def test_batch_metrics_bad_input_names_the_shape():
    ts = np.linspace(0.0, 0.45, 10)
    tr = simulate(P0, V0, np.zeros(3), ts, NATHAN)
    T, P, V = ts[None], tr.positions[None], tr.velocities[None]
    with pytest.raises(ValueError, match=r"velocities must have the shape of positions \(1, 10, 3\)"):
        pitch_metrics_batch(T, P, velocities=V[:, :5])
    with pytest.raises(ValueError, match=r"spins must have shape \(1, 3\)"):
        pitch_metrics_batch(T, P, np.zeros(3), velocities=V)
