"""Ranking fits of one spin to the same markers on the markers and the flight's curvature
(stillcap.ball.alias.resolve_joint_fits), and the flight-informed start."""

from dataclasses import replace

import numpy as np
import pytest

from stillcap.ball.alias import (CurvatureMeasurement, StrobeMeasurement, curvature_chi2, flight_informed_spin,
                                 resolve_aliases, resolve_joint_fits)
from stillcap.ball.metrics import RPM_PER_RAD_S
from stillcap.ball.orientation._result import _failed, _spin_summary

W = np.array([-133.9, -68.8, -82.1])
BASIS = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])  # flight along +y


def _solution(w, residuals_deg, inliers=None, sigma_rad_s=0.05):
    base = _failed("global", np.zeros(3), [], "x", 0.0, 80.0)
    cov = np.eye(3) * sigma_rad_s ** 2
    rate, axis, s_r, s_a = _spin_summary(np.asarray(w, float), cov)
    r = np.asarray(residuals_deg, float)
    inl = r < 4.0 if inliers is None else np.asarray(inliers, bool)
    return replace(base, spin=np.asarray(w, float), spin_rpm=rate, axis=axis, sigma_rpm=s_r, sigma_axis_deg=s_a,
                   spin_covariance=cov, residuals_deg=r, inliers=inl, n_inliers=int(inl.sum()),
                   n_observations=len(r), success=True)


@pytest.mark.parametrize("lift", ["transverse", "total"])
def test_flight_informed_spin_keeps_the_gyro_part_and_takes_the_flights_transverse_part(lift):
    # what the flight's curvature shows of W under each lift law
    seen = CurvatureMeasurement(BASIS, np.zeros(2), np.eye(2), lift).effective(W)
    curv = CurvatureMeasurement(BASIS, seen, np.eye(2), lift)
    wrong = np.array([60.0, W[1], -150.0])  # the right part along the flight, a wrong transverse part
    w = flight_informed_spin(curv, wrong)
    assert np.allclose(w, W, atol=1e-9)


def test_curvature_chi2_is_the_one_the_alias_ranking_uses():
    curv = CurvatureMeasurement(BASIS, BASIS.T @ W + [3.0, -4.0], np.eye(2) * 4.0, "transverse")
    res = resolve_aliases([StrobeMeasurement(W, 80.0, np.eye(3) * 0.1)], curv)
    c = next(c for c in res.candidates if c.n == 0)
    assert c.chi2_curvature == pytest.approx(curvature_chi2(curv, c.spin))
    # 0.1 * |measured| (+) 5 rad/s tolerance added to the fit's covariance
    tol2 = (0.1 * np.linalg.norm(curv.transverse)) ** 2 + 25.0
    d = BASIS.T @ W - curv.transverse
    assert curvature_chi2(curv, W) == pytest.approx(float(d @ d) / (4.0 + tol2))


def test_the_solution_that_explains_the_markers_wins_and_a_contradicting_pair_is_named():
    rng = np.random.default_rng(0)
    right = _solution(W, np.abs(rng.normal(0, 1.0, 14)))
    wrong_w = np.linalg.norm(W) * np.array([0.468, 0.198, -0.861])
    bad = np.abs(rng.normal(0, 1.0, 14))
    bad[[1, 9, 11, 12]] = [48.6, 53.3, 67.7, 43.3]  # four markers no rotation of the layout explains
    wrong = _solution(wrong_w, bad)
    curv = CurvatureMeasurement(BASIS, BASIS.T @ W, np.eye(2) * (8 / RPM_PER_RAD_S) ** 2, "transverse")
    pair = StrobeMeasurement(wrong_w, 80.0, np.eye(3) * 0.25, "pair front (80 Hz)")
    res = resolve_joint_fits([wrong, right], curv, [pair])
    assert res.best.source == 1 and res.consistent and not res.ambiguous
    assert res.left_out == ["pair front (80 Hz)"]
    # four capped outliers at the best solution's ~1 deg noise: about 4 * 64, plus the curvature
    assert res.candidates[1].chi2_markers > 150 and res.candidates[1].chi2_curvature > 100
    # the markers alone decide the same
    assert resolve_joint_fits([wrong, right]).best.source == 1


def test_equally_good_distinct_solutions_are_ambiguous_and_near_ones_are_one():
    r = np.abs(np.random.default_rng(1).normal(0, 1.0, 12))
    a, b = _solution(W, r), _solution(-W * 0.9, r)
    res = resolve_joint_fits([a, b])
    assert res.ambiguous and len(res.candidates) == 2 and res.likelihood_ratio == pytest.approx(1.0)
    near = _solution(W + 0.02, r * 1.01)  # within the summed covariances: the same spin
    res = resolve_joint_fits([a, near])
    assert len(res.candidates) == 1 and not res.ambiguous


def test_solutions_of_different_observations_are_refused():
    with pytest.raises(ValueError, match="same observations"):
        resolve_joint_fits([_solution(W, np.ones(5)), _solution(W, np.ones(6))])
    with pytest.raises(ValueError, match="at least one"):
        resolve_joint_fits([])
