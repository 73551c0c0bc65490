"""Alias ranking flags evidence that contradicts itself (issue 3, mlb-high-spin seed 0)."""

import numpy as np
from scipy.spatial.transform import Rotation

import pytest

from stillcap.ball.alias import RPM_PER_RAD_S, CurvatureMeasurement, StrobeMeasurement, resolve_aliases


def _principal(w, hz):
    return Rotation.from_rotvec(np.asarray(w, float) / hz).as_rotvec() * hz


def test_mlb_high_spin_seed0_wrong_back_pair_is_flagged():
    # recorded per-pair spin fits of `mlb-high-spin` seed 0 (true spin 3038 rpm): the back pair's
    # few half-moon markers gave a wrong principal spin (1463 rpm) that no alias of the front
    # pair's 1760 rpm matches; the ranking used to pick 1463 rpm, unflagged
    front = StrobeMeasurement([159.68359146, 46.16341887, 79.64197961], 80.0,
                              np.diag([0.5375651, 1.05833232, 0.89884613]) ** 2, "front")
    back = StrobeMeasurement([134.82022519, 35.99696013, 63.24013209], 50.0,
                             np.diag([5.24650909, 1.69019024, 11.80555085]) ** 2, "back")
    res = resolve_aliases([front, back])
    assert not res.consistent
    assert res.ambiguous
    assert res.dof == 3
    assert "disagrees" in res.message


def _both_pairs(w, seed: int, named: bool = False) -> list:
    """The 80 Hz and 50 Hz pairs' principal aliases of ``w``, each measured with 0.5 rad/s noise."""
    rng = np.random.default_rng(seed)
    meas = []
    for hz, name in ((80.0, "front"), (50.0, "back")):
        cov = np.eye(3) * 0.5 ** 2
        extra = (name,) if named else ()
        meas.append(StrobeMeasurement(_principal(w, hz) + rng.multivariate_normal(np.zeros(3), cov), hz, cov, *extra))
    return meas


def test_consistent_aliases_stay_resolved():
    w = np.array([-275.8, -81.7, -135.9])  # 3038 rpm: above both strobes' Nyquist limits
    meas = _both_pairs(w, 3, named=True)
    res = resolve_aliases(meas)
    assert res.consistent and not res.ambiguous
    assert abs(res.best.spin_rpm - np.linalg.norm(w) * RPM_PER_RAD_S) < 20
    assert np.degrees(np.arccos(res.best.axis @ (w / np.linalg.norm(w)))) < 2


# --- a contradicting item of evidence left out (deletion diagnostics) -------------------------

W_TRUE = np.array([-275.8, -81.7, -135.9])  # the mlb-high-spin seed 0 pitch, 3038 rpm


def _curvature(w, sigma=2.0):
    """What a flight along +y shows of spin w (Nathan's transverse lift), with sigma rad/s."""
    basis = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    return CurvatureMeasurement(basis, basis.T @ np.asarray(w, float), np.eye(2) * sigma ** 2, "transverse")


def _front_back():
    front = StrobeMeasurement([159.68359146, 46.16341887, 79.64197961], 80.0,
                              np.diag([0.5375651, 1.05833232, 0.89884613]) ** 2, "front")
    back = StrobeMeasurement([134.82022519, 35.99696013, 63.24013209], 50.0,
                             np.diag([5.24650909, 1.69019024, 11.80555085]) ** 2, "back")
    return front, back


def _close(cand, w, rpm=20.0, deg=2.0):
    return (abs(cand.spin_rpm - np.linalg.norm(w) * RPM_PER_RAD_S) < rpm
            and np.degrees(np.arccos(np.clip(cand.axis @ (w / np.linalg.norm(w)), -1, 1))) < deg)


def test_wrong_pair_is_left_out_when_the_rest_agrees():
    # the recorded wrong back pair, with a curvature that agrees with the front pair's right
    # alias: the back pair is the one item whose removal leaves agreeing evidence
    front, back = _front_back()
    full = resolve_aliases([front, back], _curvature(W_TRUE))
    assert full.left_out == ["back"]
    assert full.consistent and not full.ambiguous
    assert _close(full.best, W_TRUE)
    assert full.dof == 2  # front pair + curvature
    assert "back left out" in full.message
    # the left-out pair's contradiction is still on record
    assert full.best.chi2_strobes[1] > 100
    assert full.best.chi2 == pytest.approx(full.best.chi2_curvature)


def test_nothing_left_out_when_the_evidence_agrees():
    meas = _both_pairs(W_TRUE, 5)
    res = resolve_aliases(meas, _curvature(W_TRUE))
    assert res.left_out == [] and res.consistent and not res.ambiguous
    assert res.dof == 5
    assert _close(res.best, W_TRUE)


def test_wrong_curvature_is_left_out():
    # both pairs agree on the truth; the curvature (e.g. a wrong flight model) bends the flight
    # 90 deg away from where this spin would: no alias of either pair matches it
    meas = _both_pairs(W_TRUE, 6)
    res = resolve_aliases(meas, _curvature(Rotation.from_rotvec([0, np.pi / 2, 0]).apply(W_TRUE)))
    assert res.left_out == ["curvature"]
    assert res.consistent and _close(res.best, W_TRUE)


def test_two_items_that_disagree_stay_ambiguous():
    # one pair and the curvature only: nothing tells which is wrong
    front, back = _front_back()
    res = resolve_aliases([back], _curvature(W_TRUE))
    assert not res.consistent and res.ambiguous and res.left_out == []


def test_removals_pointing_to_different_spins_stay_ambiguous():
    # a vague curvature agrees with both pairs' own spins, which contradict each other: leaving
    # out either pair gives agreeing evidence, about different spins - no removal is preferred
    front, back = _front_back()
    res = resolve_aliases([front, back], _curvature(W_TRUE, sigma=400.0))
    assert res.left_out == []
    assert not res.consistent and res.ambiguous
