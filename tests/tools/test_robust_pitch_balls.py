"""benchmarks/_robust_pitch's ball conditions: each capture's ball is drawn from its own seed and
declared in capture.json as a user declares theirs (its ball file), with the true radius. And its
``scenes``: a condition that changes only the photos (JPEG) drawn from another condition's scenes
photographs the same pitch as it, saved its own way."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture
def rp(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCH))
    import _robust_pitch

    yield _robust_pitch
    sys.modules.pop("_robust_pitch", None)


def test_fixed_balls_in_turn(rp):
    names = [rp._draw_ball("builtin", i, np.random.default_rng(0)).name for i in range(6)]
    assert names == ["baseball", "repainted-baseball", "softball", "cricket", "tennis", "baseball"]


def test_painted_ball_is_declared_in_the_capture(rp, tmp_path):
    pc, folder, (preset, cap_kw, _, quality) = rp.render_capture("ball painted at random", 2, 0, (160, 120),
                                                                  str(tmp_path))
    ball = cap_kw["ball"]
    again = rp._draw_ball("painted", 2, np.random.default_rng([0, 2, 7]))  # same seed, same ball
    assert np.array_equal(ball.layout.directions, again.layout.directions)
    declared = json.loads((folder / "capture.json").read_text())["ball"]
    assert declared["radius_m"] == pytest.approx(ball.radius) == pytest.approx(pc.truth.studio["ball_radius_m"])
    assert len(declared["markers"]) == len(ball.layout) and quality is None


def _truth_positions(folder: Path) -> np.ndarray:
    pairs = json.loads((folder / "truth.json").read_text())["pairs"]
    return np.concatenate([np.asarray(p["positions"], float).reshape(-1, 3) for p in pairs])


def test_jpeg_condition_on_the_clean_scenes_photographs_the_same_pitch(rp, tmp_path):
    _, clean, _ = rp.render_capture("clean", 1, 0, (160, 120), str(tmp_path))
    _, same, (_, _, _, quality) = rp.render_capture("JPEG 70", 1, 0, (160, 120), str(tmp_path), scenes="clean")
    _, own, _ = rp.render_capture("JPEG 70", 1, 0, (160, 120), str(tmp_path))
    assert quality == 70 and any(same.rglob("*.jpg")) and not any(clean.rglob("*.jpg"))
    assert np.array_equal(_truth_positions(same), _truth_positions(clean))
    a, b = _truth_positions(own), _truth_positions(clean)
    assert a.shape != b.shape or not np.allclose(a, b)  # its own scenes are other pitches


def test_unknown_scenes_are_named(rp):
    with pytest.raises(ValueError, match="no such"):
        rp.rows(True, n=1, conditions=["clean"], scenes="no such")
