"""The truth comparison of a pitch throws the true ball with its own flight: a ball flying as a
baseball (``flight: "baseball"``) but of another mass and size is compared against its own
trajectory, not a 145 g, 73.7 mm baseball's (issue 12: the robustness benchmark's painted balls)."""

from types import SimpleNamespace

import numpy as np
import pytest

from stillcap.ball.ballfile import Ball, builtin_ball
from stillcap.ball.physics import simulate
from stillcap.studio.compare.pitch import compare_with_truth, truth_flight_model


class _Pair(SimpleNamespace):
    def __len__(self):
        return len(self.positions)


def _heavy_ball() -> Ball:
    d = builtin_ball("baseball").to_dict()
    d.update(name="heavy", radius_m=0.041, mass_kg=0.23)  # flies as a baseball, mass and size its own
    return Ball.from_dict(d, "heavy ball")


def test_truth_flight_model_uses_the_true_balls_mass_and_size():
    ball = _heavy_ball()
    for kind in ("seed", "nathan"):
        m = truth_flight_model({"model": kind, "ball": {"file": ball.to_dict()}})
        assert m.kind == kind
        assert m.ball.mass == pytest.approx(0.23) and m.ball.diameter == pytest.approx(0.082)
    assert truth_flight_model({"model": "seed"}).ball.mass == pytest.approx(0.145)  # no ball file: the baseball


def test_compare_with_truth_speed_of_a_heavy_ball_is_its_own():
    """A result whose velocity is exactly the heavy ball's true velocity at its first image has
    zero speed and direction error (a baseball's drag would put it about 0.1 mph off)."""
    ball = _heavy_ball()
    model = ball.flight_model("seed")
    p0, v0, w = np.array([0.0, 16.0, 1.8]), np.array([0.3, -38.0, 1.5]), np.array([-180.0, 20.0, 5.0])
    t0, times = 0.25, 0.25 + 0.05 + np.arange(6) / 80.0
    tr = simulate(p0, v0, w, times, model, t0=t0)
    truth = {"model": "seed", "ball": {"file": ball.to_dict()},
             "release": {"p0": p0.tolist(), "v0": v0.tolist(), "spin": w.tolist(), "t0_s": t0},
             "pairs": [{"name": "front", "positions": tr.positions.tolist(), "times_s": times.tolist(),
                        "flash_index": list(range(6))}], "metrics": {}}
    pair = _Pair(name="front", positions=tr.positions, flash_index=np.arange(6))
    result = SimpleNamespace(pairs=[pair], fit=SimpleNamespace(v0=tr.velocities[0], spin=w),
                             velocity_two_point=tr.velocities[0], spin_available=False,
                             metrics=SimpleNamespace(to_dict=dict), metrics_sigma={})
    out = compare_with_truth(result, truth)
    assert abs(out["speed_diff_mph_fitted"]) < 1e-4
    assert out["velocity_angle_deg_fitted"] < 1e-4
