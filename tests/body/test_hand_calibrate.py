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
    # the first calibration motion (flat, then curling together), which the xfail's reason measured;
    # the protocol motion is tested below on markers without rendering
    truth = hand_capture(206, image_size=(320, 240), supersample=1, person=person, calibration_pose="flat",
                         calibration_motion="curl").truth
    d = hand_points_from_truth(truth, noise_m=0.0003, drop=0.0, n_spurious=3, rng=6)
    return person, calibrate_hand_from_points(d["points"], d["colours"], strobe_hz=truth.strobe_hz)


@pytest.mark.xfail(strict=True, reason="not reached yet: measured mean phalanx length error 2.54 mm calibrated "
                   "against 1.79 mm for the template scaled to the hand (another_hand(6)); the 'curl' calibration motion "
                   "(<= 55 deg, every joint together) does not fix the joint centres")
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


def test_a_wrong_pose_is_refused():
    # the free offsets absorb fingers curled 50 deg stated as flat (the residual stays at the
    # noise), but only by moving markers 25-31 mm from the template's place: 6-7 prior sigmas
    # (measured on another_hand(7, 8, 9); a flat hand moves them < 1 sigma)
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
    cal = calibrate_hand(flat)
    # measured 0.18 mm with the back-of-hand triangle held to the template's shape (this hand's
    # back markers are placed +-1 mm otherwise); the triangle's own shape estimated: 0.02 mm
    assert cal.pose_rms < 0.0005
    assert all(c.passed for c in cal.self_checks if c.name != "calibration_fixes_the_model")
    # a flat flash alone bends no joint: the joint centres stay at the template's, and it says so
    fixes = next(c for c in cal.self_checks if c.name == "calibration_fixes_the_model")
    assert not fixes.passed and "did not fix" in fixes.message


def _protocol_markers(person, steps, noise_m=0.0003, rng=0):
    """Markers of ``person`` in the studio protocol's steps (no rendering: every marker seen)."""
    from stillcap.studio.hand_calibration import PROTOCOL_STEPS, _step_angles

    rng = np.random.default_rng(rng)
    sk, ms = person.skeleton, person.markerset
    out = []
    for i, name in enumerate(steps):
        step = next(s for s in PROTOCOL_STEPS if s[0] == name)
        T = np.eye(4)
        T[:3, 3] = (0.04 * i, 0.0, 0.0)
        p = ms.positions(hand_pose(sk, T, _step_angles(sk, step)))
        out.append(p + rng.normal(0, noise_m, p.shape))
    return np.array(out)


@pytest.fixture(scope="module")
def protocol_calibration():
    person = another_hand(3)
    steps = ["flat", "spread", "table top", "hook", "fist", "opposition", "half curl, knuckles back"]
    pts = _protocol_markers(person, steps, rng=3)
    return person, calibrate_hand(pts[:1], pts[1:])


def test_the_protocol_fixes_the_phalanx_lengths_with_honest_sigmas(protocol_calibration):
    person, cal = protocol_calibration
    e_cal = _errors(cal.skeleton, person)
    L0, Lt = phalanx_lengths(hand_skeleton()), phalanx_lengths(person.skeleton)
    e_tpl = np.array([abs(L0[n] * cal.size - Lt[n]) for n in PHALANGES])
    assert e_cal.mean() < 0.5 * e_tpl.mean()
    sig = {p.name: p.sigma for p in cal.parameters if p.kind == "length"}
    names = [f"{n.split('-')[0]}-{'mcp' if n.endswith('pip') else 'pip'} to {n}" for n in PHALANGES]
    s = np.array([sig[n] for n in names]) * 1e-3
    prior = 0.12 * np.array([Lt[n] for n in PHALANGES]) + 0.002  # hand_adapt's prior spread of a length
    # measured on another_hand(3): 1.3 mm (proximal) and 2.2-2.6 mm (middle phalanges)
    assert np.all(s > 0) and np.all(s < 0.75 * prior)  # the protocol's flashes, not the prior, fix them
    print("length errors mm", np.round(e_cal * 1e3, 2), "sigmas mm", np.round(s * 1e3, 2))
    assert np.all(e_cal < 3 * s)  # the errors within the stated uncertainty


def test_the_calibration_report_lists_every_parameter_and_its_checks(protocol_calibration):
    from stillcap._selfcheck import checks_from_json

    _, cal = protocol_calibration
    d = cal.to_dict()
    assert d["format"] == "stillcap-hand-calibration"
    kinds = {p["kind"] for p in d["parameters"]}
    assert kinds == {"length", "knuckle", "height", "axis"}
    assert all(np.isfinite(p["value"]) and p["sigma"] >= 0 for p in d["parameters"])
    checks = checks_from_json(d["self_checks"])
    assert {c.name for c in checks} >= {"calibration_pose_residual", "model_plausibility"}


def test_a_capture_that_does_not_bend_the_joints_is_refused_when_asked():
    person = another_hand(4)
    pts = _protocol_markers(person, ["flat", "spread"], rng=4)
    with pytest.raises(ValueError, match="does not fix the length .* did not bend enough"):
        calibrate_hand(pts[:1], pts[1:], max_length_sigma_m=0.0015)


def test_protocol_capture_flashes_are_labelled_apart():
    """Named for the fixed bug: the studio's protocol capture drifted 4 cm per flash, less than the
    hand's width, so the labelling gave curled fingers the markers of the neighbouring flash (12 of
    141 labels wrong on exact markers of another_hand(5)) and hand-calibrate refused its own
    capture (2.0 mm misfit). At 12 cm per flash, measured: 2 of 144 wrong."""
    from stillcap.body.hand_label import label_hand_markers

    truth = hand_capture(205, image_size=(320, 240), supersample=1, person=another_hand(5), calibration_pose="flat",
                         calibration_motion="protocol").truth
    d = hand_points_from_truth(truth, noise_m=0.0003, drop=0.0, n_spurious=3, rng=5)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz, fill=False)
    assert lab.reconstructed.sum() == len(truth.times)  # every flash posed
    n = wrong = 0
    for k in range(lab.n_flashes):
        p = lab.positions[k]
        ok = np.isfinite(p).all(axis=1)
        f = int(np.argmin([np.linalg.norm(p[:3] - truth.markers[j, :3]) for j in range(len(truth.times))]))
        e = np.linalg.norm(p[ok] - truth.markers[f, ok], axis=1)
        n, wrong = n + ok.sum(), wrong + int((e > 0.003).sum())
    assert n >= 0.9 * (d["flash"] >= 0).sum()
    assert wrong <= 0.02 * n


def test_the_protocol_fixes_the_finger_lengths_and_says_which_parameters_it_did_not(protocol_calibration):
    """Every finger phalanx length is fixed by the protocol's steps (1-sigma well under the
    prior's), and the self-check ``calibration_fixes_the_model`` names only parameters whose
    1-sigma stayed above UNFIXED_SIGMA_RATIO of their prior's."""
    from stillcap.body.hand_calibrate import UNFIXED_SIGMA_RATIO

    _, cal = protocol_calibration
    lengths = {p.name: p for p in cal.parameters if p.kind == "length"}
    for n in PHALANGES:
        p = lengths[f"{n.split('-')[0]}-{'mcp' if n.endswith('pip') else 'pip'} to {n}"]
        assert p.fixed < UNFIXED_SIGMA_RATIO, p
    check = next(c for c in cal.self_checks if c.name == "calibration_fixes_the_model")
    unfixed = [p.name for p in cal.parameters if p.kind != "height" and p.fixed > UNFIXED_SIGMA_RATIO]
    assert check.passed == (not unfixed)
    for name in unfixed[:6]:
        assert name in check.message


def test_a_joint_the_capture_never_bends_is_named_unfixed():
    """Flat and spread only: no finger joint bends, so the phalanx lengths stay at their prior and
    the (warning) self-check names them; the calibration itself is kept."""
    from stillcap.body.hand_calibrate import UNFIXED_SIGMA_RATIO

    person = another_hand(4)
    pts = _protocol_markers(person, ["flat", "spread"], rng=4)
    cal = calibrate_hand(pts[:1], pts[1:])
    check = next(c for c in cal.self_checks if c.name == "calibration_fixes_the_model")
    assert not check.passed
    assert check.value > UNFIXED_SIGMA_RATIO
    # the middle phalanges (PIP to DIP): nothing bends about their ends (measured 0.83-0.89 of the
    # prior's 1-sigma; the proximal ones 0.63-0.76: the flat flash fixes each one's sum with its
    # marker's place along it, whose prior is narrower)
    middle = [p for p in cal.parameters if p.kind == "length" and "-pip to " in p.name]
    assert len(middle) == 4 and all(p.fixed > UNFIXED_SIGMA_RATIO for p in middle)
    assert check.subject in {p.name for p in cal.parameters if p.kind != "height"}
    assert "did not fix" in check.message and "height" not in check.message


def test_a_parameter_the_capture_does_not_show_keeps_its_prior_sigma_never_more():
    """Named for the fixed bug: noisier markers than assumed scaled the whole covariance by the
    reduced chi-square, so a parameter the data do not touch (a nail marker's height when the
    nail never turns in view) came out with a 1-sigma up to 1.35x its prior's (another_hand(5),
    protocol capture). Only the data's weight is scaled now."""
    person = another_hand(3)
    steps = ["flat", "spread", "table top", "hook"]
    pts = _protocol_markers(person, steps, noise_m=0.0012, rng=13)  # 3x the assumed noise
    cal = calibrate_hand(pts[:1], pts[1:], noise_m=0.0004)
    rated = [p for p in cal.parameters if np.isfinite(p.fixed)]
    assert len(rated) == len(cal.parameters)
    assert max(p.fixed for p in rated) <= 1.0 + 1e-6


def test_a_wrong_label_fails_the_misfit_check_and_is_left_out():
    """A wrong label in a bent flash (the ring's DIP marker labelled the middle's: a point of
    another finger) bends the shared model toward it; the self-check ``calibration_labels_fit``
    names it (its misfit against its stated noise), and fitting again without it brings the
    model back (what ``calibrate_hand_from_point_sets`` does)."""
    from stillcap.body.hand_calibrate import _without_misfits

    person = another_hand(3)
    steps = ["flat", "table top", "hook", "fist"]
    pts = _protocol_markers(person, steps, rng=23)
    clean = calibrate_hand(pts[:1], pts[1:])
    check = next(c for c in clean.self_checks if c.name == "calibration_labels_fit")
    assert check.passed, check.message
    ms = person.markerset
    wrong = pts.copy()
    wrong[2, ms.index("middle.dip")] = pts[2, ms.index("ring.dip")]  # the hook
    fit = dict(posed=wrong[:1], free=wrong[1:], pose="flat", skeleton=None, markerset=None)
    bent = calibrate_hand(**fit)
    check = next(c for c in bent.self_checks if c.name == "calibration_labels_fit")
    assert not check.passed and "middle.dip of fitted flash 2" in check.message
    again = _without_misfits(bent, fit)
    assert np.isnan(again.markers[2, ms.index("middle.dip")]).all()
    assert any("left out" in m for m in again.messages)
    assert next(c for c in again.self_checks if c.name == "calibration_labels_fit").passed
    err = {n: _errors(c.skeleton, person) for n, c in (("clean", clean), ("bent", bent), ("again", again))}
    print({n: np.round(e * 1e3, 2) for n, e in err.items()})
    assert err["again"].max() < err["bent"].max()


def test_a_fit_refused_for_a_wrong_label_of_a_bent_flash_is_fitted_again_without_it():
    """Named for the fixed bug: another_hand(12)'s rendered protocol capture was refused ("fitting
    it moves marker 'middle.pip' 37 mm"), although two of its flashes are flat and the flash taken
    as flat was labelled right: a label 55 mm off in a bent flash (a point of another flash)
    dragged the linear fit's shared model, and the plausibility check blamed the flat flash. A fit
    with a robust loss names the wrong label (and only it); without its digit's labels of that flash
    the model is accepted."""
    from stillcap.body.hand_calibrate import _without_misfits

    person = another_hand(3)
    steps = ["flat", "spread", "table top", "hook", "fist"]
    pts = _protocol_markers(person, steps, rng=23)
    ms = person.markerset
    m = ms.index("middle.nail")
    wrong = pts.copy()
    wrong[3, m] = pts[1, m]  # the hook's middle nail labelled on the spread flash's: 56 mm off
    fit = dict(posed=wrong[:1], free=wrong[1:], pose="flat", skeleton=None, markerset=None)
    with pytest.raises(ValueError, match="not in the 'flat' pose") as refused:
        calibrate_hand(**fit)
    cal = _without_misfits(None, fit, refused=refused.value)
    left_out = np.argwhere(np.isnan(cal.markers).any(axis=2)).tolist()
    # the hook's middle finger goes whole (its angles are free: which of its labels is wrong is
    # not known), nothing else
    assert left_out == [[3, ms.index(f"middle.{k}")] for k in ("pip", "dip", "nail")]
    assert any("left out" in s and "middle.nail of fitted flash 3" in s for s in cal.messages)
    assert all(c.passed for c in cal.self_checks if c.name != "calibration_fixes_the_model")
    sig = {p.name: p.sigma for p in cal.parameters if p.kind == "length"}
    s = np.array([sig[f"{n.split('-')[0]}-{'mcp' if n.endswith('pip') else 'pip'} to {n}"] for n in PHALANGES])
    err = _errors(cal.skeleton, person)
    print("length errors mm", np.round(err * 1e3, 2), "sigmas mm", np.round(s, 2))
    assert np.all(err * 1e3 < 3 * s)  # within the stated uncertainty, as a clean capture's


def test_a_posed_flash_not_flat_stays_refused_after_the_robust_refit():
    """The robust refit of a refused fit must not rescue a flash that is not in the pose: fingers
    curled 50 deg stated as flat, with four right protocol flashes, stay refused (measured: 10.8 mm
    RMS misfit linear, 3.8 mm after leaving out the labels the robust fit names; curled 20 deg:
    2.6 and 1.7 mm, limit 1.5)."""
    from stillcap.body.hand_calibrate import _without_misfits

    person = another_hand(7)
    sk, ms = person.skeleton, person.markerset
    pts = _protocol_markers(person, ["flat", "spread", "table top", "hook", "fist"], rng=7)
    ang = np.zeros((sk.n_joints, 3))
    for i, n in enumerate(sk.names):
        if n.split("-")[-1] in ("mcp", "pip", "dip") and not n.startswith("thumb"):
            ang[i, 1] = 50.0
    pts[0] = ms.positions(hand_pose(sk, np.eye(4), ang)) + np.random.default_rng(1).normal(0, 3e-4, pts[0].shape)
    fit = dict(posed=pts[:1], free=pts[1:], pose="flat", skeleton=None, markerset=None)
    with pytest.raises(ValueError, match="not in the 'flat' pose") as refused:
        calibrate_hand(**fit)
    with pytest.raises(ValueError, match="not in the 'flat' pose"):
        _without_misfits(None, fit, refused=refused.value)


def test_the_back_of_hand_triangle_is_the_persons_and_the_frame_the_bones():
    """Named for the fixed model quantity: the back-of-hand triangle kept the template's shape
    (only its size was free), so a glove whose back markers sit a millimetre off that shape
    tilted the hand frame (2.0 deg on another_hand(7)) and the fingers' markers absorbed the tilt:
    exact markers then missed the calibrated model by 0.21 mm RMS. The flat flash's bones define
    the frame; the triangle's own shape is estimated."""
    from stillcap.body.hand import BACK_MARKERS
    from stillcap.body.kinematics import rigid_alignment

    person = another_hand(7)
    steps = ["flat", "spread", "table top", "hook", "fist", "opposition", "half curl, knuckles back", "flat"]
    pts = _protocol_markers(person, steps, noise_m=0.0)
    cal = calibrate_hand(pts[:1], pts[1:])
    b = [person.markerset.index(n) for n in BACK_MARKERS]
    est, true = cal.markerset.offsets[b], person.markerset.offsets[b]
    # the triangle's shape and its orientation in the hand frame (a common shift of the whole hand
    # against its root is the frame's origin, which only the priors fix)
    shape_err = np.abs((est - est.mean(0)) - (true - true.mean(0))).max()
    tilt = np.degrees(np.linalg.norm(rigid_alignment(true, est).rotation.as_rotvec()))
    print(f"triangle shape error {shape_err * 1e3:.3f} mm, frame tilt {tilt:.3f} deg, rms {cal.rms * 1e3:.3f} mm")
    # measured: 0.06 mm, 0.11 deg, 0.021 mm RMS (with the template's shape: 0.21 mm RMS)
    assert shape_err < 0.0002
    assert tilt < 0.3
    assert cal.rms < 0.00005
    assert all(c.passed for c in cal.self_checks)
