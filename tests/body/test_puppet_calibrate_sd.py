"""The calibration's stated direction error in a new pose, and the bones its captures' poses
leave weakly fixed (stillcap.body.puppet_calibrate_sd), on a puppet unlike the default."""

import numpy as np

from stillcap.body.markerset import MarkerSet
from stillcap.body.puppet_calibrate import calibrate_skeleton
from stillcap.body.puppet_calibrate_sd import probe_local_rotations
from stillcap.body.puppet_pose import fit_pose
from stillcap.body.skeleton import Pose, Skeleton
from stillcap.studio.puppet import random_pose
from stillcap.studio.puppet_variation import another_puppet


def _bone_error_deg(fitted: Pose, true: Pose, bone: int) -> float:
    a, b = fitted.bone_vectors()[bone], true.bone_vectors()[bone]
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def test_a_joint_no_capture_bends_is_named_and_its_error_in_a_new_pose_is_covered():
    # named bug (issue 12, "pupverify"): the predicted direction error was carried through the
    # calibration captures' own poses only. A joint those poses never bend can slide along its
    # bone (its beads' offsets moved back) and every capture is explained as well, so on seed 12
    # of benchmarks/_robust_puppet.py the upper-back was predicted at 0.085 deg and came out
    # 1.74 deg off in the test pose. Here the further captures hold the lower back at rest.
    sk, ms = another_puppet(3)
    sigma = 0.03e-3
    rng = np.random.default_rng(3)

    def noisy(p):
        return p + rng.normal(0.0, sigma, p.shape)

    def still_lower_back(seed):
        p = random_pose(sk, seed, ms)
        local = p.local_rotations.copy()
        local[sk.index("lower-back")] = np.eye(3)
        return Pose(sk, p.root2world, local)

    rest = noisy(ms.positions(Pose.rest(sk)))
    others = [noisy(ms.positions(still_lower_back(103 + i))) for i in range(2)]
    cal = calibrate_skeleton(rest, Skeleton.puppet(), MarkerSet.puppet(), others, marker_sigma_m=sigma)
    assert "upper-back" in cal.weakly_posed
    assert "add a capture (--pose) with lower-back and upper-back bent" in cal.weakly_posed["upper-back"]
    e = []
    for k in range(6):  # new poses that bend the lower back
        test = random_pose(sk, 500 + k, ms)
        fitted = fit_pose(cal.skeleton, cal.markerset, noisy(ms.positions(test)), marker_sigma_m=sigma,
                          root="free").pose
        e.append(_bone_error_deg(fitted, test, sk.index("upper-back")))
    measured = float(np.sqrt(np.mean(np.square(e))))
    # the captures' poses hide the error; the stated sigma (a new pose) covers it
    assert measured > 1.5 * cal.direction_sd_captures_deg["upper-back"]
    assert measured < 1.96 * cal.direction_sd_deg["upper-back"]


def test_probe_poses_are_seeded_and_within_the_limits():
    sk = Skeleton.puppet()
    a, b = probe_local_rotations(sk, 4), probe_local_rotations(sk, 4)
    assert a.shape == (4, sk.n_joints, 3, 3) and np.array_equal(a, b)
    assert np.allclose(a[:, sk.root], np.eye(3))
    lim = sk.limits_deg
    for local in a:
        ang = sk.limit_angles_deg(local)
        ok = np.isnan(lim[..., 0]) | ((ang >= lim[..., 0] - 1e-6) & (ang <= lim[..., 1] + 1e-6))
        assert ok.all()
