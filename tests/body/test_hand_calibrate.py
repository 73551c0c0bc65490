"""stillcap hand-calibrate (issue 12): the person's hand model from a calibration pose."""

import numpy as np
import pytest

from stillcap.body.hand import hand_markerset, hand_pose, hand_skeleton
from stillcap.body.hand_calibrate import calibrate_hand, calibrate_hand_from_points, phalanx_lengths
from stillcap.body.hand_label import hand_points_from_truth
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand

PHALANGES = [f"{d}-{j}" for d in ("index", "middle", "ring", "little") for j in ("pip", "dip")]


def _errors(sk, person):
    Lt, L = phalanx_lengths(person.skeleton), phalanx_lengths(sk)
    return np.array([abs(L[n] - Lt[n]) for n in PHALANGES])


@pytest.fixture(scope="module")
def calibrated():
    person = another_hand(6)
    truth = hand_capture(206, image_size=(320, 240), supersample=1, person=person, calibration_pose="flat").truth
    d = hand_points_from_truth(truth, noise_m=0.0003, drop=0.0, n_spurious=3, rng=6)
    return person, calibrate_hand_from_points(d["points"], d["colours"], strobe_hz=truth.strobe_hz)


@pytest.mark.xfail(strict=True, reason="not reached yet: measured mean phalanx length error 2.54 mm calibrated "
                   "against 1.79 mm for the template scaled to the hand (another_hand(6)); the curl of the studio's "
                   "calibration capture (<= 55 deg) does not fix the joint centres")
def test_calibration_recovers_phalanx_lengths_better_than_the_scaled_template(calibrated):
    person, cal = calibrated
    assert cal.n_posed >= 1 and cal.n_free >= 2
    assert cal.pose_rms < 0.0006  # noise 0.3 mm per axis
    scaled = hand_skeleton()
    e_cal = _errors(cal.skeleton, person)
    L0, Lt = phalanx_lengths(scaled), phalanx_lengths(person.skeleton)
    e_tpl = np.array([abs(L0[n] * cal.size - Lt[n]) for n in PHALANGES])
    assert e_cal.mean() < 0.003
    assert e_cal.mean() < e_tpl.mean()


@pytest.mark.xfail(strict=True, reason="not working yet: with one flash in the stated pose, the free joint and "
                   "marker offsets absorb fingers curled 50 deg (residual stays at the noise)")
def test_a_wrong_pose_is_refused():
    person = another_hand(7)
    sk, ms = person.skeleton, person.markerset
    ang = np.zeros((sk.n_joints, 3))
    for i, n in enumerate(sk.names):
        if n.split("-")[-1] in ("mcp", "pip", "dip") and not n.startswith("thumb"):
            ang[i, 1] = 50.0  # curled fingers stated as flat
    pts = ms.positions(hand_pose(sk, np.eye(4), ang))
    with pytest.raises(ValueError, match="not in the 'flat' pose"):
        calibrate_hand(pts, skeleton=hand_skeleton(), markerset=hand_markerset())
    flat = ms.positions(hand_pose(sk, np.eye(4), np.zeros((sk.n_joints, 3))))
    assert calibrate_hand(flat).pose_rms < 1e-4
