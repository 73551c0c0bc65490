"""The pitch pipeline on studio pitches: positions, timing, spin and metrics against the truth;
bad captures fail with clear messages; a capture without markers still gives the flight."""

import json
import shutil

import cv2
import numpy as np
import pytest

from stillcap.ball.flashes import number_flashes_from_spacing
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.pipelines.pitch import PitchOptions, analyse_pitch
from stillcap.report.pitch import POSITION_COLUMNS, write_report
from stillcap.studio.compare.pitch import add_truth_comparison

from support import PITCH_SIZE as SIZE, studio_pitch

WHITE = (0.75, 0.75, 0.72)  # the ball's leather: markers painted in it are invisible


def analysed(root, **kwargs):
    """analyse_pitch, then the comparison with the capture's truth (``result.truth``)."""
    cap = Capture.load(root)
    return add_truth_comparison(analyse_pitch(cap, **kwargs), cap.truth)


@pytest.fixture(scope="module")
def fastball(tmp_path_factory):
    return studio_pitch(tmp_path_factory, "fastball")


@pytest.fixture(scope="module")
def result(fastball):
    truth = json.loads((fastball / "truth.json").read_text())
    return analysed(fastball, release_y_ft=truth["metrics"]["release_pos_y_ft"], n_samples=100)


def test_positions_timing_and_velocity_match_the_truth(result):
    tc = result.truth
    assert [p.name for p in result.pairs] == ["front", "back"]
    assert all(v["flash_index_ok"] for v in tc["positions"].values())  # order and gaps right
    assert len(result.pairs[0]) >= 7 and len(result.pairs[1]) >= 8
    assert tc["mean_err_mm"] < 3.0 and tc["max_err_mm"] < 6.0
    assert abs(tc["speed_diff_mph_fitted"]) < 0.3 and tc["velocity_angle_deg_fitted"] < 0.3
    assert abs(tc["speed_diff_mph_two_point"]) < 0.5
    assert abs(tc["time_offsets"]["back"]["error_ms"]) < 0.5  # unsynchronised strobes
    assert abs(tc["metrics"]["release_speed_mph"]["diff"]) < 0.3
    assert abs(tc["metrics"]["plate_z_ft"]["diff"]) < 0.02 and abs(tc["metrics"]["pfx_z_in"]["diff"]) < 0.5
    assert result.messages == []


def test_global_spin_matches_the_truth_and_keys_are_the_truths(result, fastball):
    tc = result.truth
    assert result.spin_available and result.spin.method == "global"
    assert abs(tc["spin_rate_diff_rpm"]) < 10 and tc["spin_axis_angle_deg"] < 2.0
    assert abs(tc["metrics"]["spin_axis_deg"]["diff"]) < 2.0
    assert result.alias is not None and not result.alias.ambiguous
    truth = json.loads((fastball / "truth.json").read_text())
    d = result.to_dict()
    assert set(d["metrics"]) == set(truth["metrics"])
    assert set(d["metrics"]["nine_parameter"]) == set(truth["metrics"]["nine_parameter"])
    assert set(d["release"]) >= {"t0_s", "p0", "v0", "spin", "speed_mph", "spin_rpm"} and "spin_rpm" in d
    # every numeric metric has an uncertainty, small but not zero
    for k, v in d["metrics"].items():
        if isinstance(v, float) and k != "release_pos_y_ft":
            s = d["metrics_sigma"][k]
            assert s is not None and np.isfinite(s), k
    assert 0 < d["metrics_sigma"]["release_speed_mph"] < 0.3 and 0 < d["metrics_sigma"]["spin_rate_rpm"] < 20
    assert json.loads(json.dumps(d, allow_nan=False)) == d  # strict JSON


def test_report_files(result, tmp_path):
    paths = write_report(result, tmp_path / "rep")
    html = (tmp_path / "rep" / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and html.count("data:image/png;base64,") == 4
    assert "release_speed_mph" in html and "Table 1" in html
    rows = (tmp_path / "rep" / "positions.csv").read_text().splitlines()
    assert rows[0].split(",") == list(POSITION_COLUMNS) and len(rows) == 1 + len(result.times)
    # each row's covariance columns are its pair's position_covariance_m2 entry, in mm^2
    import csv
    first = next(csv.DictReader(rows))
    p = next(p for p in result.pairs if p.name == first["pair"])
    C = p.position_covariance_m2[0] * 1e6
    got = [float(first[k]) for k in ("cov_xx_mm2", "cov_yy_mm2", "cov_zz_mm2", "cov_xy_mm2", "cov_xz_mm2", "cov_yz_mm2")]
    np.testing.assert_allclose(got, [C[0, 0], C[1, 1], C[2, 2], C[0, 1], C[0, 2], C[1, 2]], rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(C) > 0)
    assert json.loads(paths["json"].read_text())["metrics"] == result.to_dict()["metrics"]
    assert "spin_rate_rpm" in (tmp_path / "rep" / "metrics.csv").read_text()
    assert not list((tmp_path / "rep").glob(".*"))  # atomic writes leave no temporary files


def test_seed_spin_method(fastball):
    res = analysed(fastball, spin_method="seed", n_samples=0)
    assert res.spin.method == "seed" and res.spin_available
    assert abs(res.truth["spin_rate_diff_rpm"]) < 40 and res.truth["spin_axis_angle_deg"] < 5


def test_no_markers_still_gives_positions_and_velocity(tmp_path_factory):
    root = studio_pitch(tmp_path_factory, "nomarkers", palette={k: WHITE for k in ("red", "blue", "green", "black")})
    res = analysed(root, n_samples=20)
    assert res.spin is None and not res.spin_available
    assert any("no markers" in m for m in res.messages)
    d = res.to_dict()
    assert d["spin"] is None and d["metrics"]["spin_rate_rpm"] is None and d["metrics"]["spin_axis_deg"] is None
    assert d["metrics"]["release_speed_mph"] > 50 and d["metrics_sigma"]["spin_rate_rpm"] is None
    # the spin from flight is the reported spin, flagged as such (transverse: the seed model's total rate)
    assert d["spin_source"] == "flight" and d["spin_reported"]["source"] == "flight" and d["spin_comparison"] is None
    f = d["spin_from_flight"]
    truth = Capture.load(root).truth
    assert abs(f["spin_rpm"] - truth["spin_rpm"]) < max(4 * f["spin_sigma_rpm"], 20.0)
    assert any("spin from flight alone" in m for m in res.messages)
    assert res.truth["mean_err_mm"] < 3.0 and abs(res.truth["speed_diff_mph_fitted"]) < 0.3


def test_markers_on_one_side_only(tmp_path_factory):
    """Only the red markers are painted (one type, three markers): the flight is reported either
    way; the spin is reported only if it is determined, with a message otherwise."""
    root = studio_pitch(tmp_path_factory, "redonly", palette={k: WHITE for k in ("blue", "green", "black")})
    res = analysed(root, n_samples=0)
    assert len(res.times) >= 15 and res.truth["mean_err_mm"] < 3.0
    if not res.spin_available:
        assert any("spin" in m for m in res.messages)


# ---------------------------------------------------------------------------------------------
# bad captures
# ---------------------------------------------------------------------------------------------
def copy_capture(src, dst):
    shutil.copytree(src, dst)
    return dst


def test_missing_camera_image(fastball, tmp_path):
    cap = copy_capture(fastball, tmp_path / "cap")
    (cap / "images" / "back_left.png").unlink()
    with pytest.raises(ValueError, match="back_left.png does not exist"):
        analyse_pitch(cap)


def test_camera_missing_from_capture_skips_its_pair(fastball, tmp_path):
    cap = copy_capture(fastball, tmp_path / "cap")
    d = json.loads((cap / "capture.json").read_text())
    d["images"] = [im for im in d["images"] if im["camera"] != "back_right"]
    (cap / "capture.json").write_text(json.dumps(d))
    res = analyse_pitch(cap, n_samples=0)
    assert [p.name for p in res.pairs] == ["front"]
    assert any("back_right has no photo" in m for m in res.messages)


def test_corrupt_image(fastball, tmp_path):
    cap = copy_capture(fastball, tmp_path / "cap")
    (cap / "images" / "front_top.png").write_bytes(b"\x89PNG garbage" + bytes(range(256)) * 4)
    with pytest.raises(ValueError, match="front_top.png is not an image"):
        analyse_pitch(cap)
    png = (cap / "images" / "back_left.png").read_bytes()
    (cap / "images" / "front_top.png").write_bytes(png[:len(png) // 2])  # a valid header, cut short
    with pytest.raises(ValueError, match=r"front_top.png is truncated \(PNG chunk 'IDAT' runs past the end of the file\)"):
        analyse_pitch(cap)


def test_no_ball(fastball, tmp_path):
    cap = copy_capture(fastball, tmp_path / "cap")
    black = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    for f in (cap / "images").glob("*.png"):
        cv2.imwrite(str(f), black)
    with pytest.raises(ValueError, match="no ball found"):
        analyse_pitch(cap)


def test_too_few_flashes(fastball, tmp_path):
    """Only two ball images left in the front pair, none in the back pair."""
    cap = copy_capture(fastball, tmp_path / "cap")
    truth = json.loads((cap / "truth.json").read_text())
    c = Capture.load(cap)
    for i, im in enumerate(c.images):
        img = c.read_image(i)
        out = np.full_like(img, int(np.median(img)))
        pair = next(p for p in truth["pairs"] if im.camera in p["cameras"])
        if pair["name"] == "front":
            k = pair["cameras"].index(im.camera)
            seen = [(c, r) for c, r in zip(pair["centers_px"][k], pair["radius_px"][k]) if c[0] is not None]
            for (x, y), r in seen[2:4]:
                x0, x1, y0, y1 = (max(int(v), 0) for v in (x - 2 * r, x + 2 * r, y - 2 * r, y + 2 * r))
                out[y0:y1, x0:x1] = img[y0:y1, x0:x1]
        cv2.imwrite(str(cap / im.file), out)
    with pytest.raises(ValueError, match="too few ball images.*2 position"):
        analyse_pitch(cap)


def test_not_a_pitch_capture_and_bad_options(fastball, tmp_path):
    cap = copy_capture(fastball, tmp_path / "cap")
    d = json.loads((cap / "capture.json").read_text())
    d["kind"] = "markers"
    (cap / "capture.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="not a pitch capture"):
        analyse_pitch(cap)
    with pytest.raises(ValueError, match="spin_method must be one of global, seed"):
        PitchOptions(spin_method="magic")
    with pytest.raises(ValueError, match="physics must be one of"):
        PitchOptions(physics="aristotle")
    with pytest.raises(ValueError, match="workers must be >= 1"):
        PitchOptions(workers=0)


def test_bad_uncertainty_options():
    with pytest.raises(ValueError, match="sigma_method must be one of linear, monte_carlo"):
        PitchOptions(sigma_method="bootstrap")
    with pytest.raises(ValueError, match="calibration_focal_sigma must be >= 0"):
        PitchOptions(calibration_focal_sigma=-1e-4)
    with pytest.raises(ValueError, match="calibration_focal_sigma must be >= 0"):
        PitchOptions(calibration_focal_sigma=float("nan"))
    with pytest.raises(ValueError, match="shading_model_error must be >= 0"):
        PitchOptions(shading_model_error=-0.1)


def test_threads_do_not_change_the_result(fastball, result):
    """The per-pair work on a thread pool (default 2 workers) gives the serial run's numbers."""
    truth = json.loads((fastball / "truth.json").read_text())
    serial = analyse_pitch(fastball, release_y_ft=truth["metrics"]["release_pos_y_ft"], n_samples=100, workers=1)
    for a, b in zip(serial.pairs, result.pairs):
        assert a.name == b.name
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.centers_px, b.centers_px)
        np.testing.assert_array_equal(a.observations.directions, b.observations.directions)
    np.testing.assert_array_equal(serial.spin.spin, result.spin.spin)
    assert serial.metrics.to_dict() == result.metrics.to_dict()
    assert {"markers", "markers_wait"} <= set(result.timings_s)


# ---------------------------------------------------------------------------------------------
# stages
# ---------------------------------------------------------------------------------------------
def test_order_flashes_with_missed_flashes():
    rng = np.random.default_rng(0)
    k_true = np.array([0, 1, 2, 4, 5, 8, 9])
    pts = np.outer(k_true * 0.35, [0.05, -1.0, 0.0]) + rng.normal(0, 0.001, (7, 3))
    perm = rng.permutation(7)
    order, k, spacing = number_flashes_from_spacing(pts[perm], (0, -1, 0), 80.0)
    assert np.array_equal(perm[order], np.arange(7)) and np.array_equal(k, k_true)
    assert abs(spacing - 0.35 * np.linalg.norm([0.05, 1, 0])) < 0.002
    # flying the other way: the order reverses
    order, k, _ = number_flashes_from_spacing(pts[perm], (0, 1, 0), 80.0)
    assert np.array_equal(perm[order], np.arange(7)[::-1]) and k[-1] == 9


def test_stereo_pairs_from_meta_and_rates(fastball):
    cap = Capture.load(fastball)
    pairs, msgs = stereo_pairs(cap)
    assert [(p.name, p.cameras, p.strobe_hz) for p in pairs] == [
        ("front", ("front_top", "front_bottom"), 80.0), ("back", ("back_left", "back_right"), 50.0)]
    assert msgs == []
    for im in cap.images:  # without pair names: grouped by strobe rate
        im.meta = {}
    cap.meta.pop("pairs")
    pairs, _ = stereo_pairs(cap)
    assert sorted(p.cameras for p in pairs) == [("back_left", "back_right"), ("front_top", "front_bottom")]


def test_each_pair_reports_the_lens_blur_its_shading_correction_used(result):
    """The studio photos are blurred with 0.5 px (Gaussian sigma): the blur read from the balls'
    limbs and reported per camera is near it, not a fixed default pretending to be a measurement."""
    for p in result.to_dict()["pairs"]:
        blur = p["blur_px"]
        assert len(blur) == 2 and all(0.3 < b < 0.8 for b in blur), (p["name"], blur)
        assert 0.5 not in blur  # read from the photos, not the fallback
