"""Each labelled marker's own noise in the hand model's adaptation and calibration
(``point_sigma_m``; ``posed_sigma_m``/``free_sigma_m``): a partly hidden marker, whose centroid
shifts by millimetres, can count less."""

import numpy as np
import pytest

from stillcap.body.hand import hand_pose
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


def test_the_common_noise_given_per_marker_gives_the_same_model(hand):
    person, pts, poses = hand
    sk, ms = person.skeleton, person.markerset
    a = adapt_hand_model(sk, ms, pts, initial=poses, loss="linear", max_nfev=10)
    b = adapt_hand_model(sk, ms, pts, initial=poses, loss="linear", max_nfev=10,
                         point_sigma_m=np.full(pts.shape[:2], 0.0005))  # NOISE_M
    assert np.array_equal(a.skeleton.offsets, b.skeleton.offsets)
    assert np.array_equal(a.markerset.offsets, b.markerset.offsets)


def test_a_marker_given_its_larger_noise_bends_the_model_less(hand):
    """A marker shifted 4 mm in every curled flash (a partly hidden centroid): weighed by its own
    noise it moves the calibrated model less than at the common noise."""
    person, pts, _ = hand
    k = person.markerset.index("middle.dip")
    bad = pts.copy()
    bad[1:, k] += np.array([0.0, 0.0, 0.004])
    sig = np.full(pts.shape[:2], 0.0004)
    sig[1:, k] = 0.004
    plain = calibrate_hand(bad[:1], bad[1:], max_nfev=40)
    weighed = calibrate_hand(bad[:1], bad[1:], posed_sigma_m=sig[:1], free_sigma_m=sig[1:], max_nfev=40)
    true = person.skeleton.offsets
    idx = [i for i, n in enumerate(person.skeleton.names) if n.startswith("middle-")]

    def err(cal):
        return np.linalg.norm(cal.skeleton.offsets[idx] - true[idx], axis=1).max()

    print("middle finger's worst joint error mm: plain", err(plain) * 1e3, "weighed", err(weighed) * 1e3)
    assert err(weighed) < err(plain)


def test_a_bad_noise_is_refused(hand):
    person, pts, poses = hand
    sig = np.full(pts.shape[:2], 0.0004)
    sig[2, 7] = 0.0
    with pytest.raises(ValueError, match="point_sigma_m must be positive"):
        adapt_hand_model(person.skeleton, person.markerset, pts, initial=poses, point_sigma_m=sig, max_nfev=2)
    with pytest.raises(ValueError, match="point_sigma_m"):
        adapt_hand_model(person.skeleton, person.markerset, pts, initial=poses, point_sigma_m=sig[:2], max_nfev=2)
