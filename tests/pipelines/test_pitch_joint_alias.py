"""The spin alias and the minimum of the markers' fit decided on all pairs' markers and the
flight's curvature (issue 12: "light to the side" #0 of the robustness benchmark took a spin
91 deg off the truth at the right rate, from a pair whose own fit, on about one marker per
flash, settled on a wrong minimum)."""

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.ball.alias import CurvatureMeasurement, StrobeMeasurement, resolve_aliases
from stillcap.ball.metrics import RPM_PER_RAD_S
from stillcap.pipelines.pitch.spin import _combined_spin, _joint_decision, _resolve_alias
from support import SimulatedPair

W = np.array([-133.9, -68.8, -82.1])  # 1637 rpm: above the 50 Hz pair's Nyquist limit
R0 = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()


def _pairs(seed=0):
    # about one marker per flash, as the side-lit capture's pairs saw (front: three at one flash)
    front = SimulatedPair("front", 80.0, [1, 1, 3, 1, 0, 1, 1, 0, 1], 0.0, 0, [[0.3, -1, 0.2], [-0.3, -1, 0.2]], seed,
                          R0, W)
    back = SimulatedPair("back", 50.0, [1, 1, 1, 1, 1, 0, 0], 0.004, 1, [[0.3, -1, 0.1]], seed + 1000, R0, W)
    return [front, back]


def _curvature(w, sigma_rpm=8.0):
    """The flight along +y, Nathan's lift: the curvature shows w's x and z parts."""
    basis = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    return CurvatureMeasurement(basis, basis.T @ w, np.eye(2) * (sigma_rpm / RPM_PER_RAD_S) ** 2, "transverse")


def _errors(spin):
    rate = spin.spin_rpm - np.linalg.norm(W) * RPM_PER_RAD_S
    ang = np.degrees(np.arccos(np.clip(spin.axis @ W / np.linalg.norm(W), -1, 1)))
    return rate, ang


def test_wrong_minimum_of_the_chosen_alias_is_replaced_by_the_one_markers_and_flight_agree_on():
    pairs = _pairs()
    # a pair's wrong spin: the right rate about an axis at right angles to the true one
    w_wrong = np.linalg.norm(W) * np.cross(W, [0, 0, 1.0]) / np.linalg.norm(np.cross(W, [0, 0, 1.0]))
    first, t = _combined_spin(pairs, w_wrong, None, [])
    assert first.success and _errors(first)[1] > 30  # the fit of all markers stays in a wrong minimum there
    assert first.n_inliers < first.n_observations
    alias = resolve_aliases([StrobeMeasurement(w_wrong, 80.0, np.eye(3) * 0.25, "pair front (80 Hz)")],
                            _curvature(W))
    assert not alias.consistent  # the flight disagrees with the pair
    messages = []
    spin, times, joint = _joint_decision(pairs, first, t, alias, _curvature(W), None, messages)
    rate, ang = _errors(spin)
    assert abs(rate) < 3 and ang < 1.5
    assert spin.n_inliers == spin.n_observations
    assert joint.consistent and not joint.ambiguous and joint.evidence == ["markers of all pairs", "curvature"]
    assert joint.candidates[1].chi2 - joint.best.chi2 > 100  # the wrong minimum: far worse on the markers
    assert len(times) == spin.n_observations
    assert any(m.startswith("spin decided on all pairs' markers and the flight") for m in messages)


def test_without_the_flight_the_markers_alone_decide():
    pairs = _pairs()
    w_wrong = np.linalg.norm(W) * np.cross(W, [0, 0, 1.0]) / np.linalg.norm(np.cross(W, [0, 0, 1.0]))
    first, t = _combined_spin(pairs, w_wrong, None, [])
    alias = resolve_aliases([StrobeMeasurement(w_wrong, 80.0, np.eye(3) * 0.25, "pair front (80 Hz)")])
    spin, _, joint = _joint_decision(pairs, first, t, alias, None, None, [])
    # the fit's own starts over every pair's markers find the minimum that explains them all
    assert _errors(spin)[1] < 1.5 and spin.n_inliers == spin.n_observations
    assert joint.evidence == ["markers of all pairs"] and joint.dof == 0


def test_a_clear_choice_that_the_flight_confirms_is_kept_unchanged():
    pairs = _pairs(seed=3)
    messages = []
    fit = SimpleNamespace(spin_basis=np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                          params=np.r_[np.zeros(6), W[1], W[0], W[2]], covariance=np.eye(9) * (8 / RPM_PER_RAD_S) ** 2)
    w, alias = _resolve_alias(pairs, fit, SimpleNamespace(kind="nathan"), messages)
    first, t = _combined_spin(pairs, w, None, [])
    assert alias.consistent and not alias.ambiguous
    spin, times, joint = _joint_decision(pairs, first, t, alias, _curvature(W), None, messages)
    assert spin is first and times is t and joint is alias
