"""adapt_hand_model's per-parameter priors (a covariance per joint and per marker) and per-marker
noise: what the calibration's partly hidden markers and a calibrated model's own uncertainty use."""

import numpy as np
import pytest

from stillcap.body.hand import BACK_MARKERS, hand_pose
from stillcap.body.hand_adapt import adapt_hand_model
from stillcap.body.hand_calibrate import calibrate_hand
from stillcap.studio.hand_variation import another_hand


def _markers(person, steps, noise_m=0.0003, rng=0):
    """Markers of ``person`` in the studio protocol's steps (no rendering: every marker seen)."""
    from stillcap.studio.hand_calibration import PROTOCOL_STEPS, _step_angles

    rng = np.random.default_rng(rng)
    sk, ms = person.skeleton, person.markerset
    out, poses = [], []
    for i, name in enumerate(steps):
        step = next(s for s in PROTOCOL_STEPS if s[0] == name)
        T = np.eye(4)
        T[:3, 3] = (0.04 * i, 0.0, 0.0)
        pose = hand_pose(sk, T, _step_angles(sk, step))
        p = ms.positions(pose)
        out.append(p + rng.normal(0, noise_m, p.shape))
        poses.append(pose)
    return np.array(out), poses


@pytest.fixture(scope="module")
def hand():
    person = another_hand(3)
    pts, poses = _markers(person, ["flat", "table top", "hook", "fist"], rng=5)
    return person, pts, poses


def test_an_explicit_prior_covariance_equal_to_the_default_gives_the_same_model(hand):
    person, pts, poses = hand
    sk, ms = person.skeleton, person.markerset
    a = adapt_hand_model(sk, ms, pts, initial=poses, loss="linear", max_nfev=20)
    sig_j = 0.12 * np.linalg.norm(sk.offsets, axis=1) + 0.002
    jcov = np.eye(3)[None] * sig_j[:, None, None] ** 2
    mcov = np.repeat(np.eye(3)[None] * 0.004 ** 2, len(ms), axis=0)
    b = adapt_hand_model(sk, ms, pts, initial=poses, loss="linear", max_nfev=20, joint_prior_cov=jcov,
                         marker_prior_cov=mcov, point_sigma_m=np.full(pts.shape[:2], 0.0005))
    assert np.abs(a.skeleton.offsets - b.skeleton.offsets).max() < 1e-9
    assert np.abs(a.markerset.offsets - b.markerset.offsets).max() < 1e-9


def test_a_tight_prior_holds_the_model_and_a_loose_one_lets_the_markers_move_it(hand):
    person, pts, poses = hand
    sk, ms = person.skeleton, person.markerset
    # start from a model whose index PIP joint sits 4 mm too far along the finger
    j = sk.names.index("index-pip")
    wrong = sk.offsets.copy()
    wrong[j, 0] += 0.004
    from stillcap.body.skeleton import Joint, Skeleton

    sk_w = Skeleton(tuple(Joint(q.name, q.parent, o, q.limits_deg) for q, o in zip(sk.joints, wrong)), name=sk.name)
    J, M = sk.n_joints, len(ms)
    tight = adapt_hand_model(sk_w, ms, pts, initial=poses, loss="linear", max_nfev=40,
                             joint_prior_cov=np.repeat(np.eye(3)[None] * 1e-5 ** 2, J, axis=0),
                             marker_prior_cov=np.repeat(np.eye(3)[None] * 1e-5 ** 2, M, axis=0))
    loose = adapt_hand_model(sk_w, ms, pts, initial=poses, loss="linear", max_nfev=40,
                             joint_prior_cov=np.repeat(np.eye(3)[None] * 0.01 ** 2, J, axis=0),
                             marker_prior_cov=np.repeat(np.eye(3)[None] * 1e-5 ** 2, M, axis=0))
    assert abs(tight.skeleton.offsets[j, 0] - wrong[j, 0]) < 0.0002  # held at the start
    # the hook and the fist bend the PIP: the markers put it back (measured error: see the print)
    err = abs(loose.skeleton.offsets[j, 0] - sk.offsets[j, 0])
    print("index-pip error mm, loose prior", err * 1e3)
    assert err < 0.001


def test_a_marker_given_its_larger_noise_bends_the_model_less(hand):
    """A partly hidden marker's centroid shifts by millimetres; weighed by its own noise it
    moves the calibrated model less than at the common noise."""
    person, pts, _ = hand
    k = person.markerset.index("middle.dip")
    bad = pts.copy()
    bad[1:, k] += np.array([0.0, 0.0, 0.004])  # shifted 4 mm in every curled flash
    sig = np.full(pts.shape[:2], 0.0004)
    sig[1:, k] = 0.004
    plain = calibrate_hand(bad[:1], bad[1:])
    weighed = calibrate_hand(bad[:1], bad[1:], posed_sigma_m=sig[:1], free_sigma_m=sig[1:])
    true = person.skeleton.offsets
    names = [n for n in person.skeleton.names if n.startswith("middle-")]
    idx = [person.skeleton.names.index(n) for n in names]

    def err(cal):
        return np.linalg.norm(cal.skeleton.offsets[idx] - true[idx], axis=1).max()

    print("middle finger's worst joint error mm: plain", err(plain) * 1e3, "weighed", err(weighed) * 1e3)
    assert err(weighed) < err(plain)


def test_a_flash_without_its_back_of_hand_markers_starts_from_its_given_pose(hand):
    person, pts, poses = hand
    ms = person.markerset
    p = pts.copy()
    p[2, [ms.index(b) for b in BACK_MARKERS[:1]]] = np.nan
    with pytest.raises(ValueError, match="back-of-hand"):
        adapt_hand_model(person.skeleton, ms, p, max_nfev=2)
    ad = adapt_hand_model(person.skeleton, ms, p, initial=poses, loss="linear", max_nfev=20)
    assert ad.rms < 0.001


def test_a_bad_prior_covariance_is_refused_with_its_name(hand):
    person, pts, poses = hand
    J = person.skeleton.n_joints
    cov = np.repeat(np.eye(3)[None] * 1e-6, J, axis=0)
    cov[5] = -cov[5]
    with pytest.raises(ValueError, match=r"joint_prior_cov\[5\].*positive definite"):
        adapt_hand_model(person.skeleton, person.markerset, pts, initial=poses, joint_prior_cov=cov, max_nfev=2)
    with pytest.raises(ValueError, match="joint_prior_cov"):
        adapt_hand_model(person.skeleton, person.markerset, pts, initial=poses, joint_prior_cov=cov[:3], max_nfev=2)
