"""`stillcap pitch` and the pitch demo: outputs written, options honoured, bad captures exit 2."""

import json
import shutil

import cv2
import numpy as np
import pytest

from support import PITCH_SIZE as SIZE, run_cli as run, studio_pitch


@pytest.fixture(scope="module")
def fastball(tmp_path_factory):
    return studio_pitch(tmp_path_factory, "fastball")


def test_pitch_json_report_csv(fastball, tmp_path, capsys):
    code, out, err = run(["pitch", str(fastball), "--json", "--report", str(tmp_path / "rep"),
                          "--csv", str(tmp_path / "pos.csv")], capsys)
    assert code == 0, err
    d = json.loads(out)
    truth = json.loads((fastball / "truth.json").read_text())
    assert set(d["metrics"]) == set(truth["metrics"])
    assert d["spin_fit"]["method"] == "global" and d["reference_fit"]["method"] == "least_squares"
    assert abs(d["spin_rpm"] - truth["spin_rpm"]) < 10
    assert d["truth_comparison"]["mean_err_mm"] < 3
    for f in ("report.html", "pitch.json", "positions.csv", "metrics.csv", "side.png", "top.png", "spin.png",
              "residuals.png"):
        assert (tmp_path / "rep" / f).stat().st_size > 100, f
    assert (tmp_path / "pos.csv").read_text().startswith("pair,camera_a,camera_b,strobe_hz,flash_index,time_s,x_m")


def test_pitch_table_output_and_options(fastball, capsys, monkeypatch):
    import stillcap.pipelines.pitch.stages as pipeline

    methods, real_fit = [], pipeline.fit_reference_trajectory

    def fit(*args, **kw):  # record the optimiser asked for; run the fast one (Powell is tested in tests/ball)
        methods.append(kw["method"])
        return real_fit(*args, **{**kw, "method": "least_squares"})

    monkeypatch.setattr(pipeline, "fit_reference_trajectory", fit)
    code, out, err = run(["pitch", str(fastball), "--spin", "seed", "--fit", "powell", "--physics", "nathan"], capsys)
    assert code == 0, err
    assert methods == ["least_squares", "powell"]  # positions-only fit, then the selected optimiser
    assert "Pitch metrics" in out and "Table 1" in out and "spin (seed)" in out and "release_speed_mph" in out


def test_pitch_bad_input_exits_2(fastball, tmp_path, capsys):
    code, _, err = run(["pitch", str(tmp_path / "nowhere")], capsys)
    assert code == 2 and "does not exist" in err
    code, _, err = run(["pitch", str(fastball), "--spin", "magic"], capsys)
    assert code == 2 and "magic" in err
    cap = tmp_path / "black"
    shutil.copytree(fastball, cap)
    for f in (cap / "images").glob("*.png"):
        cv2.imwrite(str(f), np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    code, _, err = run(["pitch", str(cap)], capsys)
    assert code == 2 and "no ball found" in err
    (cap / "images" / "front_top.png").write_bytes(b"not an image at all")
    code, _, err = run(["pitch", str(cap)], capsys)
    assert code == 2 and "front_top.png" in err


def test_pitch_demo(tmp_path, capsys):
    from stillcap.cli.demo_pitch import pitch_demo

    res = pitch_demo(tmp_path / "demo", 5, calibrate=False, image_size=SIZE)
    out = capsys.readouterr().out
    assert "vs truth" in out and "seed paper" in out and "release_speed_mph" in out
    assert (tmp_path / "demo" / "report" / "report.html").is_file()
    assert (tmp_path / "demo" / "capture" / "truth.json").is_file()
    assert res.truth["mean_err_mm"] < 3 and abs(res.truth["metrics"]["release_speed_mph"]["diff"]) < 0.3


def test_pitch_session_of_several_captures(fastball, tmp_path, capsys):
    """Several captures: one result each (worker processes by default), failures named and skipped, exit 2."""
    second = tmp_path / "second"
    shutil.copytree(fastball, second)
    black = tmp_path / "black"
    shutil.copytree(fastball, black)
    for f in (black / "images").glob("*.png"):
        cv2.imwrite(str(f), np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    code, out, err = run(["pitch", str(fastball), str(black), str(second), "--json", "--report", str(tmp_path / "rep")],
                         capsys)
    assert code == 2 and "black:" in err and "no ball found" in err
    d = json.loads(out)
    assert [x["capture"] for x in d] == [str(fastball), str(black), str(second)]
    assert "no ball found" in d[1]["error"] and "metrics" not in d[1]
    code1, out1, err1 = run(["pitch", str(fastball), "--json"], capsys)  # one capture: threads
    assert code1 == 0, err1
    single = json.loads(out1)["metrics"]
    for k in ("release_speed_mph", "spin_rate_rpm", "induced_vertical_break_in"):
        assert d[0]["metrics"][k] == pytest.approx(single[k], rel=1e-12), k  # processes give the threads' result
        assert d[2]["metrics"][k] == pytest.approx(single[k], rel=1e-12), k
    assert (tmp_path / "rep" / fastball.name / "report.html").is_file()
    assert (tmp_path / "rep" / "second" / "report.html").is_file() and not (tmp_path / "rep" / "black").exists()
    code, out, err = run(["pitch", str(fastball), str(second), "--processes", "0"], capsys)
    assert code == 0, err
    assert "2 pitches (0 failed)" in out and "second" in out
    code, _, err = run(["pitch", str(fastball), str(second), "--csv", str(tmp_path / "x.csv")], capsys)
    assert code == 2 and "--csv takes one capture" in err


def test_pitch_session_report_needs_distinct_names(fastball, tmp_path, capsys):
    """--report with several captures writes one sub-folder each: two folders of one name exit 2, named."""
    twin = tmp_path / "a" / fastball.name
    shutil.copytree(fastball, twin)
    code, _, err = run(["pitch", str(fastball), str(twin), "--report", str(tmp_path / "rep")], capsys)
    assert code == 2 and "distinct folder names" in err
    assert not (tmp_path / "rep").exists()


def test_pitch_uncertainty_assumptions_are_options(fastball, capsys):
    """--center-sigma-px and --shading-model-error are stated assumptions: a larger one gives wider
    position uncertainties, and a bad one is refused in one line with exit status 2."""
    sig = {}
    for value in ("0.5", "3"):
        code, out, err = run(["pitch", str(fastball), "--json", "--shading-model-error", value,
                              "--center-sigma-px", "0.2"], capsys)
        assert code == 0, err
        d = json.loads(out)
        sig[value] = np.mean([np.trace(np.asarray(c)) for p in d["pairs"] for c in p["position_covariance_mm2"]])
    assert sig["3"] > sig["0.5"] > 0
    code, _, err = run(["pitch", str(fastball), "--shading-model-error", "-1"], capsys)
    assert code == 2 and "shading_model_error" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(["pitch", str(fastball), "--center-sigma-px", "0"], capsys)
    assert code == 2 and "center_sigma_px" in err
