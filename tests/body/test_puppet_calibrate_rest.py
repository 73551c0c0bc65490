"""calibrate_skeleton on rest captures and bead placements a user would choose (issue 12)."""
import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.body.puppet_calibrate import calibrate_skeleton
from stillcap.body.puppet_pose import fit_pose
from stillcap.body.skeleton import Pose, Skeleton
from stillcap.studio.puppet import random_pose
from stillcap.studio.puppet_variation import another_puppet

_BONES = ("l-knee", "r-knee", "upper-back", "l-elbow", "r-elbow", "l-shoulder", "r-shoulder")


def _bone_error_deg(sk, fitted, true_pose):
    fb, tb = fitted.bone_vectors(), true_pose.bone_vectors()
    e = [np.degrees(np.arccos(np.clip(fb[j] @ tb[j] / np.linalg.norm(fb[j]) / np.linalg.norm(tb[j]), -1, 1)))
         for j in map(sk.index, _BONES)]
    return float(np.sqrt(np.mean(np.square(e))))


def _calibrate(sk, ms, rest_pose, sigma_m, seed=0, **kw):
    """Calibrate from ``rest_pose`` and two random poses with beads at ``sigma_m`` (given as the
    beads' noise, as the pipeline's bead_noise would); the bone error of a new pose fitted with it."""
    rng = np.random.default_rng(seed)
    noisy = lambda p: p + rng.normal(0, sigma_m, p.shape)  # noqa: E731
    pts = [noisy(ms.positions(rest_pose))] + [noisy(ms.positions(random_pose(sk, 200 + i, ms))) for i in range(2)]
    noise = [np.full(len(ms), sigma_m)] * 3
    cal = calibrate_skeleton(pts[0], Skeleton.puppet(), MarkerSet.puppet(), pts[1:], noise_m=noise, **kw)
    test = random_pose(sk, 999, ms)
    fitted = fit_pose(cal.skeleton, cal.markerset, noisy(ms.positions(test)), root="free").pose
    return cal, _bone_error_deg(sk, fitted, test)


def test_a_rest_pose_turned_on_the_turntable_is_estimated():
    # the puppet set on the turntable 25 deg round from the template's rest frame: assumed
    # upright, the calibration was ~19 deg off on the bones
    sk, ms = another_puppet(11, proportions=0.15)
    r2w = sk.rest_root2world()
    a = np.radians(25.0)
    r2w[:3, :3] = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    cal, err = _calibrate(sk, ms, Pose.rest(sk, r2w), 0.02e-3)
    assert abs(cal.rest_turn_deg - 25.0) < 1.0
    assert err < 1.0
    assert cal.rms_m < 0.1e-3
    # the stated 0 deg (the default) is rejected by the beads, so the estimate is used
    assert not cal.rest_turn_stated and cal.rest_turn_deg == cal.rest_turn_estimated_deg
    assert abs(cal.rest_turn_estimated_deg) > 3.29 * cal.rest_turn_sd_deg


def test_a_rest_turn_the_beads_do_not_reject_is_held_where_stated():
    # a puppet set as stated, beads at 0.1 mm: the free turn's estimate scatters by its own sigma,
    # which every bone's direction would carry; held at the stated turn instead, the estimate
    # still reported (this case's bone error, 1.13 deg held, is the two noisy poses' and is not
    # asserted here; the benchmark measures held against free on rendered captures)
    sk, ms = another_puppet(13, proportions=0.15)
    cal, _ = _calibrate(sk, ms, Pose.rest(sk), 0.1e-3, seed=3)
    assert cal.rest_turn_stated and cal.rest_turn_deg == 0.0
    assert np.isfinite(cal.rest_turn_estimated_deg) and 0.0 < cal.rest_turn_sd_deg < 2.0
    assert abs(cal.rest_turn_estimated_deg) <= 3.29 * cal.rest_turn_sd_deg
    free, _ = _calibrate(sk, ms, Pose.rest(sk), 0.1e-3, seed=3, rest_turn_deg=None)
    assert not free.rest_turn_stated and free.rest_turn_deg == pytest.approx(free.rest_turn_estimated_deg)
    with pytest.raises(ValueError, match="rest_turn_deg must be a finite angle"):
        _calibrate(sk, ms, Pose.rest(sk), 0.1e-3, rest_turn_deg=float("nan"))


def test_beads_turned_far_round_their_bones_with_sharp_beads():
    # beads moved +-6 mm and turned +-60 deg round their bones, beads at 0.015 mm (a sharp
    # capture): the joint fit needs its coarse-to-fine levels to get there
    sk, ms = another_puppet(18, proportions=0.15, bead_shift_m=0.006, bead_turn_deg=60.0)
    cal, err = _calibrate(sk, ms, Pose.rest(sk), 0.015e-3)
    assert abs(cal.rest_turn_deg) < 1.0
    assert err < 1.0
    assert cal.rms_m < 0.1e-3
    # named bug (issue 12): every joint fit stopped at max_nfev unconverged (SciPy's inexact LSMR
    # steps under jac_sparsity), so the bones depended on the path; exact steps converge
    assert cal.joint_converged is True and cal.joint_evaluations < 200


def _measured_seed18():
    """The pipeline's beads on a rendered puppet with beads turned +-60 deg (tests/data, see its "about")."""
    import json
    from pathlib import Path

    d = json.loads((Path(__file__).parents[1] / "data" / "puppet-turned-beads-seed18.json").read_text())
    nan = lambda a: np.array([[np.nan if v is None else v for v in np.atleast_1d(r)] for r in a], float)  # noqa: E731
    return [nan(p) for p in d["points_m"]], [nan(n).ravel() for n in d["noise_m"]]


def test_calibration_on_the_beads_a_rendered_capture_gave():
    # condition 3 of benchmarks/_robust_puppet.py, seed 18: on main bbff8f2 (one coarse level at
    # 0.1 mm, the rest capture assumed upright) the joint fit settled at 3.5 mm RMS with the bones
    # 18.5 deg off (the benchmark's failed calibration)
    sk, ms = another_puppet(18, proportions=0.15, bead_shift_m=0.006, bead_turn_deg=60.0)
    pts, noise = _measured_seed18()
    cal = calibrate_skeleton(pts[0], Skeleton.puppet(), MarkerSet.puppet(), pts[1:], noise_m=noise)
    test = random_pose(sk, 25, ms)
    fitted = fit_pose(cal.skeleton, cal.markerset, ms.positions(test), root="free").pose
    assert cal.rms_m < 0.1e-3 and _bone_error_deg(sk, fitted, test) < 1.0


def test_the_grouped_jacobian_equals_plain_forward_differences():
    # the joint fit's dense Jacobian perturbs unknowns with disjoint residual rows together
    from scipy.optimize import approx_fprime
    from scipy.sparse import csc_matrix

    from stillcap.body._grouped_jacobian import grouped_jacobian

    A = np.array([[1.0, 0, 2, 0, 0], [0, 3, 0, 0, 1], [0, 0, 0, 4, 0], [5, 0, 0, 0, 0]])
    fun = lambda x: np.sin(A @ x) + (A != 0) @ x ** 2  # noqa: E731 - each row reads A's columns
    x = np.array([0.3, -0.2, 0.5, 1.5, 0.9])
    upper = np.full(5, np.inf)
    upper[3] = 1.5 + 1e-12  # at its bound: stepped backwards
    J = grouped_jacobian(fun, csc_matrix(A != 0), np.full(5, -np.inf), upper)(x)
    assert np.allclose(J, approx_fprime(x, fun, 1.49e-8), atol=1e-6)
    assert np.all(J[A == 0] == 0)
