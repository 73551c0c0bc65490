"""`stillcap balls`, `stillcap pitch --ball` and capture.json's `ball` (docs/ball-format.md)."""

from __future__ import annotations

import json
import shutil

import pytest

from stillcap.ball.ballfile import Ball, builtin_ball
from support import run_cli, studio_pitch


def test_balls_list_show_and_design(tmp_path, capsys):
    code, out, _ = run_cli(["balls", "--json"], capsys)
    rows = json.loads(out)
    assert code == 0 and [r["name"] for r in rows] == ["baseball", "cricket", "softball", "tennis"]
    assert {r["name"]: r["markers"] for r in rows} == {"baseball": 12, "cricket": 12, "softball": 16, "tennis": 12}
    code, out, _ = run_cli(["balls", "show", "tennis", "--json"], capsys)
    assert code == 0 and Ball.from_dict(json.loads(out), "shown").layout.radius == builtin_ball("tennis").radius
    code, out, _ = run_cli(["balls", "design", "8", "--types", "3", "--restarts", "1", "--out", tmp_path / "d.json"],
                           capsys)
    assert code == 0, out
    b = Ball.load(tmp_path / "d.json")
    assert len(b.layout) == 8 and b.layout.n_types == 3


def test_bad_ball_file_exits_2_with_one_line(tmp_path, capsys):
    d = builtin_ball("baseball").to_dict()
    d["markers"][2]["type"] = "purple"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    code, _, err = run_cli(["balls", "show", bad], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{bad}: markers.2.type: unknown marker type 'purple'" in err
    code, _, err = run_cli(["pitch", tmp_path, "--ball", "curling"], capsys)
    assert code == 2 and "--ball: 'curling' is neither a built-in ball" in err


@pytest.fixture(scope="module")
def tennis_pitch(tmp_path_factory):
    """A studio pitch of the built-in tennis ball (its ball in capture.json)."""
    return studio_pitch(tmp_path_factory, "tennis-ball", seed=3, ball=builtin_ball("tennis"))


def _spin_axis_error(out):
    d = json.loads(out)
    return d, d["truth_comparison"]["spin_axis_angle_deg"], {c["name"]: c for c in d["self_checks"]}


def test_capture_ball_is_used_and_cli_ball_overrides_it(tennis_pitch, tmp_path, capsys):
    cap = json.loads((tennis_pitch / "capture.json").read_text())
    assert cap["ball"]["name"] == "tennis"
    code, out, _ = run_cli(["pitch", tennis_pitch, "--json"], capsys)
    d, axis_err, checks = _spin_axis_error(out)
    assert code == 0 and d["options"]["ball"]["name"] == "tennis" and d["options"]["ball_radius_m"] == 0.0335
    assert d["model"] == "tennis" and checks["ball_layout"].get("passed")
    assert axis_err < 1.5  # the baseball's on the same photos: 0.6-0.9 deg (benchmarks/bench_ball_layouts.py)
    # --ball overrides capture.json: the baseball's layout does not fit the tennis ball's markers
    code, out, err = run_cli(["pitch", tennis_pitch, "--json", "--ball", "baseball"], capsys)
    d, axis_err, checks = _spin_axis_error(out)
    assert code == 0 and d["options"]["ball"]["name"] == "baseball"
    assert not checks["ball_layout"]["passed"] and "self-check ball_layout" in err


def test_capture_ball_path_stays_inside_the_folder(tennis_pitch, tmp_path, capsys):
    cap = tmp_path / "cap"
    shutil.copytree(tennis_pitch, cap)
    d = json.loads((cap / "capture.json").read_text())
    builtin_ball("tennis").save(cap / "my-ball.json")
    d["ball"] = "my-ball.json"
    (cap / "capture.json").write_text(json.dumps(d))
    code, out, _ = run_cli(["pitch", cap, "--json"], capsys)
    assert code == 0 and json.loads(out)["options"]["ball"]["name"] == "tennis"
    d["ball"] = "../outside.json"
    (cap / "capture.json").write_text(json.dumps(d))
    code, _, err = run_cli(["pitch", cap, "--json"], capsys)
    assert code == 2 and "capture.json: ball: path '../outside.json' leaves the capture folder" in err
