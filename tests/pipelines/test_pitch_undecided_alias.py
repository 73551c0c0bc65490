"""A spin the markers cannot decide is withheld, not reported with the local covariance of one of
its minima (issue 12, "everything varied" #0 of the robustness benchmark: 5 marker observations,
two of them cut by the limb, gave 1467 rpm about an axis 58 deg off the truth with an axis sigma
of 0.54 deg).

The markers' own test (:func:`stillcap.ball.alias.marker_misfit_test`) knows how little
redundancy a few observations leave: the noise it compares the minima with is estimated from the
same residuals, so the statistic is F-distributed, not chi-square with a known sigma."""

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.ball.alias import UNDECIDED_P, CurvatureMeasurement, _is_alias, marker_misfit_test, resolve_joint_fits
from stillcap.ball.metrics import RPM_PER_RAD_S
from stillcap.pipelines.pitch.checks import pitch_self_checks
from stillcap.pipelines.pitch.spin import _combined_spin, _joint_decision, _resolve_alias
from support import SimulatedPair

# a mostly gyro spin (2520 rpm, axis nearly along the flight): the curvature sees little of it
W = np.array([-25.6455243, 244.20636031, 96.75166898])
R0 = Rotation.from_rotvec([0.0919686846878418, 0.9093812120668606, -1.8114980612469853]).as_matrix()
VIEWS = [[0.3, -1, 0.2], [-0.3, -1, 0.2]]


def _curvature(w, sigma_rpm=8.0):
    """The flight along +y, Nathan's lift: the curvature shows w's x and z parts."""
    basis = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    return CurvatureMeasurement(basis, basis.T @ w, np.eye(2) * (sigma_rpm / RPM_PER_RAD_S) ** 2, "transverse")


def _decide(pair, w_true=W):
    messages = []
    fit = SimpleNamespace(spin_basis=np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                          params=np.r_[np.zeros(6), w_true[1], w_true[0], w_true[2]],
                          covariance=np.eye(9) * (8 / RPM_PER_RAD_S) ** 2)
    w, alias = _resolve_alias([pair], fit, SimpleNamespace(kind="nathan"), messages)
    first, t = _combined_spin([pair], w, None, [])
    spin, _, joint = _joint_decision([pair], first, t, alias, _curvature(w_true), None, messages)
    return first, spin, joint, messages


def _covers(spin):
    rate = spin.spin_rpm - np.linalg.norm(W) * RPM_PER_RAD_S
    ang = np.degrees(np.arccos(np.clip(spin.axis @ W / np.linalg.norm(W), -1, 1)))
    return abs(rate) <= 1.96 * spin.sigma_rpm and ang <= 2.45 * spin.sigma_axis_deg


def test_five_observations_leave_the_spin_undecided_and_it_is_withheld(monkeypatch):
    pair = SimulatedPair("front", 80.0, [0, 0, 1, 1, 1, 2, 0, 0, 0], 0.0, 0, VIEWS, 4, R0, W)
    first, spin, joint, messages = _decide(pair)
    assert first.success and not _covers(first)  # the strobes' choice: a wrong minimum, confident
    # main reported a minimum 1532 rpm off (axis 65 deg) with sigmas of 6 rpm and 0.8 deg, unflagged
    assert spin is None
    assert joint.undecided and joint.marker_dof >= 0
    # the markers reject none of the minima that differ from the best in their rotation per interval
    best = joint.best
    for c in joint.undecided:
        assert c.p_markers >= UNDECIDED_P and c is not best
    assert any(m.startswith("spin undetermined (spin alias undecided)") for m in messages)
    # the message names the best and every undecided rate (one text for it and the spin_alias check)
    text = joint.undecided_text()
    assert text.startswith(f"the markers fit {best.spin_rpm:.0f} rpm and ")
    assert all(f"{c.spin_rpm:.0f} rpm (axis" in text for c in joint.undecided[:3])
    assert any(text in m for m in messages)
    # and the result's self-checks say so (no pairs: the flight's checks are stubbed)
    monkeypatch.setattr("stillcap.pipelines.pitch.checks.flight_chi2", lambda *a: (0.0, 1, {}))
    checks = pitch_self_checks([], SimpleNamespace(pair_index=np.zeros(0, int)), SimpleNamespace(spin=None, alias=joint),
                               SimpleNamespace(v0=np.array([0.0, 1.0, 0.0]), p0=np.zeros(3)), None, None, None,
                               SimpleNamespace(center_sigma_px=0.5, marker_epipolar_px=2.0))
    failed = [c for c in checks if c.name == "spin_alias"]
    assert len(failed) == 1 and not failed[0].passed and text in failed[0].message


def test_many_observations_decide_the_same_spin():
    pair = SimulatedPair("front", 80.0, [3] * 9, 0.0, 0, VIEWS, 4, R0, W)
    first, spin, joint, messages = _decide(pair)
    assert spin is not None and _covers(spin)
    assert not getattr(joint, "undecided", [])
    assert not any("undecided" in m for m in messages)


def _solution(w, e, ranks, inliers=None):
    e = np.asarray(e, float)
    return SimpleNamespace(spin=np.asarray(w, float), spin_covariance=np.eye(3) * 1e-2, residuals_noise=e,
                           residual_ranks=np.asarray(ranks), residuals_deg=np.degrees(e),
                           inliers=np.ones(len(e), bool) if inliers is None else np.asarray(inliers, bool))


def test_marker_misfit_test_knows_the_redundancy():
    rng = np.random.default_rng(1)
    # 20 observations, 0.1 px noise: 34 degrees of freedom; a minimum 3 px off on five of them is rejected
    e0 = np.abs(rng.normal(0, 0.1, 20))
    e1 = e0.copy()
    e1[:5] = 0.3
    ref, dof, p = marker_misfit_test([_solution(W, e0, [2] * 20), _solution(-W, e1, [2] * 20)])
    assert ref == 0 and dof == 34 and p[0] == 1.0 and p[1] < 1e-3
    # the same misfits with 4 observations, two cut by the limb (6 components): no redundancy, no rejection
    ref, dof, p = marker_misfit_test([_solution(W, e0[:4], [2, 2, 1, 1]), _solution(-W, e1[:4], [2, 2, 1, 1])])
    assert dof == 0 and np.all(p == 1.0)
    # 5 observations (2 degrees of freedom): the same misfit ratio is not enough to reject
    ref, dof, p = marker_misfit_test([_solution(W, e0[:5], [2, 2, 1, 1, 2]), _solution(-W, e1[:5], [2, 2, 1, 1, 2])])
    assert dof == 2 and p[1] > 0.05
    # an observation the reference leaves out costs the same cap in every solution
    inl = np.ones(20, bool)
    inl[0] = False
    e2 = e0.copy()
    e2[0] = 50.0
    ref, dof, p = marker_misfit_test([_solution(W, e2, [2] * 20, inl), _solution(-W, e2, [2] * 20, inl)])
    assert dof == 32 and p[1] == 1.0


def test_aliases_at_the_strobe_rate_are_not_undecided():
    a = W / np.linalg.norm(W)
    # a full turn more per interval at 80 Hz: the same rotation between flashes
    alias = _solution(W + 2 * np.pi * 80.0 * a, [0.1], [2])
    other = _solution(Rotation.from_rotvec([0, 0, 0.4]).apply(W), [0.1], [2])
    best = _solution(W, [0.1], [2])
    assert _is_alias(alias, best, [80.0], 30 / RPM_PER_RAD_S, np.radians(2))
    assert not _is_alias(alias, best, [50.0], 30 / RPM_PER_RAD_S, np.radians(2))  # another strobe tells them apart
    # an alias at one of two rates: the alias family, which the curvature and the other rate decide
    assert _is_alias(alias, best, [50.0, 80.0], 30 / RPM_PER_RAD_S, np.radians(2))
    assert not _is_alias(other, best, [80.0], 30 / RPM_PER_RAD_S, np.radians(2))


def test_a_minimum_rejected_only_between_95_and_99_9_percent_leaves_the_spin_undecided():
    # 5 observations on 9 flashes, a 2205 rpm spin: the strobes' choice and the joint ranking end on a
    # reversed axis 390 rpm off (179 deg), and the markers reject the two other minima found only at
    # p = 0.005: at the 95 % level main took that as a decision and reported the wrong spin
    w = np.array([-11.851389465507044, -212.01698321656332, -90.64759315976606])
    r0 = Rotation.from_rotvec([0.760732301227252, -2.5834965238803758, 1.20326083749902]).as_matrix()
    pair = SimulatedPair("front", 80.0, [1, 0, 1, 0, 0, 1, 0, 0, 2], 0.0, 0, VIEWS, 657679502, r0, w)
    first, spin, joint, messages = _decide(pair, w)
    truth = w / np.linalg.norm(w)
    assert np.degrees(np.arccos(np.clip(joint.best.axis @ truth, -1, 1))) > 90  # the best found is wrong
    assert spin is None and joint.undecided
    assert all(UNDECIDED_P <= c.p_markers < 0.05 for c in joint.undecided)
    assert any(m.startswith("spin undetermined (spin alias undecided)") for m in messages)


def test_a_best_the_markers_reject_is_no_decision():
    # the curvature picks a spin (w1) the markers reject (p < 1e-3), the markers' own best (w0, another
    # rotation per interval) the curvature rejects: the evidence contradicts itself, the spin is withheld
    rng = np.random.default_rng(2)
    e0 = np.abs(rng.normal(0, 0.1, 20))
    e1 = e0.copy()
    e1[:5] = 0.3
    w0, w1 = W, Rotation.from_rotvec([0, 0, 1.0]).apply(W)
    sols = [_solution(w0, np.radians(e0), [2] * 20), _solution(w1, np.radians(e1), [2] * 20)]
    joint = resolve_joint_fits(sols, _curvature(w1), strobes_hz=[80.0])
    assert joint.best.source == 1 and joint.best.p_markers < UNDECIDED_P
    assert [c.source for c in joint.undecided] == [0]
    assert "they reject the best itself" in joint.message


def test_the_reference_is_not_a_minimum_that_keeps_few_observations_at_a_tiny_noise():
    # 15 observations: the right spin explains 12 at 0.1 px, a wrong minimum 6 at 0.025 px (and drops 9;
    # "light to the side" #7: 0.10 and 0.024 px)
    right = np.full(15, 3.0)
    right[:12] = 0.1 * np.sqrt(1.5)  # 24 components - 6: a noise of 0.1 px per component
    wrong = np.full(15, 2.0)
    wrong[:6] = 0.025  # 12 components - 6: 0.025 px
    inl_r, inl_w = np.arange(15) < 12, np.arange(15) < 6
    ref, dof, p = marker_misfit_test([_solution(W, right, [2] * 15, inl_r), _solution(-W, wrong, [2] * 15, inl_w)])
    # the yardstick is the right spin's noise, and at it the wrong minimum is rejected
    assert ref == 0 and dof == 18 and p[0] == 1.0 and p[1] < UNDECIDED_P
