"""The puppet pipeline's per-bone skeleton checks judge by the noise the photos show
(bead_noise), not the stated 0.2 mm per bead, and the pose is fitted with that noise (issue 12)."""
import numpy as np
import pytest
from scipy import stats

from stillcap.body.puppet_checks import FALSE_ALARM_P, bead_noise, skeleton_checks
from stillcap.body.skeleton import Skeleton
from stillcap.pipelines.puppet import DEFAULT, analyse_puppet, analyse_puppet_views, with_options
from stillcap.studio.puppet import puppet_scene, webcam_sensor


@pytest.fixture(scope="module")
def scene():
    return puppet_scene(pose="random:3", rng=3, supersample=1)


def test_a_forearm_4_percent_too_long_fails_its_check_the_stated_noise_would_pass(scene):
    sk = Skeleton.puppet()
    right = analyse_puppet_views(scene.rig, scene.images, skeleton=sk)
    assert all(c.passed for c in right.self_checks if c.name in ("bone_residual", "bead_pair_direction"))
    off = sk.offsets.copy()
    off[sk.index("r-elbow")] *= 1.04  # the r-elbow joint's offset 4 % too long: the arm's beads ~0.3 mm off
    # the noise test alone (bone tolerance 0): its limit is what is checked below
    res = analyse_puppet_views(scene.rig, scene.images, skeleton=sk.with_offsets(off),
                               options=with_options(DEFAULT, bone_tolerance_deg=0.0))
    bad = [c for c in res.self_checks if c.name in ("bone_residual", "bead_pair_direction") and not c.passed]
    # named on the right arm only (the pose, fitted with each bead's own noise, follows the
    # well-measured arm.R3, seen in 7 views, and leaves the misfit on the upper arm's beads)
    assert bad and {c.subject for c in bad} <= {"r-elbow", "r-hand"}
    assert all("calibrate-skeleton" in c.message and "false-alarm chance" in c.message for c in bad)
    m = res.markers
    bn = bead_noise(res.rig, m.points, m.observations, m.used, exclude=m.partly_hidden)
    elbow = next(c for c in bad if c.name == "bone_residual")
    idx = [k for k, b in enumerate(res.markerset.markers)
           if b.bone == elbow.subject and m.ok[k] and not m.partly_hidden[k]]
    # the limit: the F quantile of the beads' misfit over the photos' noise at FALSE_ALARM_P
    w = 1 / bn.sd_m[idx] ** 2
    lim = 3 * len(idx) * stats.f.isf(FALSE_ALARM_P, 3 * len(idx), np.min(bn.sd_dof[idx]))
    assert elbow.limit == pytest.approx(np.sqrt(lim / w.sum()) * 1e3)
    # the stated 0.2 mm per bead would have passed this misfit
    stated = np.full(len(m.points), DEFAULT.marker_sigma_m)
    loose = skeleton_checks(res.markerset, res.fit, m.points, stated, exclude=m.partly_hidden, tolerance_deg=0.0)
    assert all(c.passed for c in loose)
    # with the default 0.5 deg bone tolerance the arm is still named: its bead pair points 1.1 deg
    # off (over both limits); the elbow's 0.13 mm of residual is under the 0.23 mm a 0.5 deg turn
    # leaves, so that check passes
    stated_tol = analyse_puppet_views(scene.rig, scene.images, skeleton=sk.with_offsets(off))
    named = {(c.name, c.subject) for c in stated_tol.self_checks if not c.passed}
    assert ("bead_pair_direction", "r-elbow") in named and ("bone_residual", "r-elbow") not in named


def test_the_demo_puppet_raises_no_false_alarm(tmp_path):
    # named bug (issue 12): `stillcap demo puppet` (seed 0: the studio's default puppet and the
    # built-in skeleton, which match exactly) warned "bone_residual [r-elbow]": bead arm.R2 rests
    # on three views, one partly hidden, and is 0.6 mm off; its residual-based noise said 0.07 mm,
    # and the pose fitted with one error for all beads pulled arm.R1 and the torso off too
    scene = puppet_scene(pose="random:0", rng=0, sensor=webcam_sensor(jpeg_quality=None))
    cap, images = scene.to_capture(".jpg")
    cap.save(tmp_path / "capture", images, jpeg_quality=85)
    res, _ = analyse_puppet(tmp_path / "capture", workers=1)
    checks = [c for c in res.self_checks if c.name in ("bone_residual", "bead_pair_direction")]
    assert len({c.subject for c in checks}) >= 9
    assert all(c.passed for c in checks), [c.message for c in checks if not c.passed]
    # the forearm bead not recovered is still named (that warning is right)
    assert any(c.name == "bone_measured" and c.subject == "l-hand" and not c.passed for c in res.self_checks)


def test_the_pose_weights_are_the_bead_noise_scaled_to_the_stated_error_at_their_median():
    from types import SimpleNamespace

    from stillcap.pipelines.puppet.analyse import _relative_sigma

    noise = np.array([0.01e-3, 0.02e-3, 0.04e-3, 0.5e-3, np.nan])
    solve = SimpleNamespace(ok=np.array([True, True, True, True, False]),
                            partly_hidden=np.array([False, False, False, True, False]))
    sigma = _relative_sigma(noise, solve, DEFAULT)
    # the median of the beads seen whole (0.02 mm) becomes marker_sigma_m; ratios kept
    assert sigma[1] == pytest.approx(DEFAULT.marker_sigma_m) and sigma[2] / sigma[0] == pytest.approx(4)
    assert sigma[3] == pytest.approx(25 * DEFAULT.marker_sigma_m) and sigma[4] == DEFAULT.marker_sigma_m
    none = SimpleNamespace(ok=np.zeros(5, bool), partly_hidden=np.zeros(5, bool))
    assert np.all(_relative_sigma(noise, none, DEFAULT) == DEFAULT.marker_sigma_m)
