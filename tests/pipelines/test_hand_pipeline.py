"""The hand pipeline end to end on studio captures: labelled markers, poses, animation, release,
truth-shared JSON keys, exports, and clear errors for bad captures."""

import json
import shutil
from dataclasses import replace

import cv2
import numpy as np
import pytest

from stillcap.io.capture import Capture
from stillcap.pipelines.hand import HandOptions, analyse_hand
from stillcap.studio.compare.hand import compare_with_capture, compare_with_truth, truth_arrays

SIZE = (1280, 960)


def studio_hand(factory, name, seed, size=SIZE):
    """Render a studio hand capture (JPEG 92) into the session's temp folder once; its folder."""
    from stillcap.studio.hand import hand_capture

    root = factory.getbasetemp() / f"hand-{name}"
    if not (root / "capture.json").is_file():
        hc = hand_capture(seed, image_size=size)
        cap, images = hc.to_capture(".jpg")
        cap.save(root, images, jpeg_quality=92)
    return root


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return studio_hand(tmp_path_factory, "seed1", 1)


@pytest.fixture(scope="module")
def result(capture):
    res = analyse_hand(capture)
    res.truth = compare_with_capture(res)
    return res


def test_recovers_the_truth(result):
    c = result.truth
    assert c is not None
    assert c["labels"] >= 30 and c["labels_right_pct"] >= 99.0
    assert c["flashes_reconstructed"] >= max(2, c["flashes_back_seen_2plus"] - 1)
    # the flashes whose back is seen are counted apart from those posed from their neighbours
    assert c["flashes_reconstructed_back_seen"] <= min(c["flashes_back_seen_2plus"], c["flashes_reconstructed"])
    assert c["flashes_reconstructed_back_seen"] >= max(2, c["flashes_back_seen_2plus"] - 1)
    assert c["marker_rms_mm"] < 1.2
    assert c["joint_angle_rms_deg"] < 2.0  # the goal (measured 1.0)
    assert c["ball_mean_mm"] < 3.0


def test_release_from_hand_and_ball(result):
    c, rel = result.truth, result.release
    assert rel is not None and rel.success, result.messages
    assert abs(c["release_time_ms"]) < 3 * max(c["release_time_sigma_ms"], 0.1)
    assert abs(c["release_speed_mph"]) < 3 * max(c["release_speed_sigma_mph"], 0.2)
    assert c["release_point_mm"] < 30


def test_animation_passes_through_the_keyframes(result):
    seq, an = result.sequence, result.animation
    assert an is not None and an.frame_rate == pytest.approx(1000.0)
    assert an.times[0] == pytest.approx(seq.times[0])
    # a frame that falls on a keyframe reproduces its pose
    for t, pose in zip(seq.times, seq.poses):
        k = int(np.argmin(np.abs(an.times - t)))
        if abs(an.times[k] - t) < 1e-9:
            assert np.allclose(an.local_rotations[k], pose.local_rotations, atol=1e-9)


def test_json_keys_shared_with_the_truth(result, capture):
    d = result.to_dict()
    json.dumps(d, allow_nan=False)
    truth = json.loads((capture / "truth.json").read_text())
    assert d["kind"] == truth["kind"] == "hand"
    assert d["marker_names"] == truth["marker_names"] and d["joint_names"] == truth["joint_names"]
    for key in ("times_s", "markers", "angles_deg", "root2world", "joints"):
        assert key in d["flashes"] and key in truth["flashes"], key
    n = len(d["flashes"]["times_s"])
    assert np.array(d["flashes"]["markers"], dtype=float).shape == (n, 18, 3)
    for key in ("t0_s", "p0", "v0", "speed_mph"):
        assert key in d["release"] and key in truth["release"], key


def test_overrides_delete_and_relabel(result, capture, tmp_path):
    lab = result.labels
    k = int(np.flatnonzero(lab.reconstructed)[0])
    j = int(np.flatnonzero(lab.point_index[k] >= 0)[-1])
    p = lab.positions[k, j]
    path = tmp_path / "labels.json"
    path.write_text(json.dumps({"overrides": [{"flash": int(lab.order[k]), "position_m": p.tolist(), "delete": True}]}))
    res = analyse_hand(capture, HandOptions(overrides=path, spin=False))
    k2 = int(np.flatnonzero(res.labels.order == lab.order[k])[0])
    assert res.labels.point_index[k2, j] == -1
    assert int(np.sum(res.labels.point_index >= 0)) == int(np.sum(lab.point_index >= 0)) - 1


def test_exports_hold_the_animation_and_markers(result, tmp_path):
    import ezc3d

    from stillcap.io.export import export

    export(tmp_path / "hand.bvh", result)
    export(tmp_path / "hand.c3d", result)
    text = (tmp_path / "hand.bvh").read_text()
    assert "ROOT wrist" in text and f"Frames: {result.animation.n_frames}" in text
    c = ezc3d.c3d(str(tmp_path / "hand.c3d"))
    labels = c["parameters"]["POINT"]["LABELS"]["value"]
    assert labels[:18] == list(result.labels.marker_names)


def test_report_writes_animation_and_plots(result, tmp_path):
    from stillcap.report.hand import write_result_report

    paths = write_result_report(result, tmp_path / "rep", truth_arrays=truth_arrays(result.capture.truth))
    for key in ("html", "animation", "joint_angles", "json"):
        assert paths[key].is_file() and paths[key].stat().st_size > 100, key
    assert cv2.imread(str(paths["joint_angles"])) is not None


def test_not_a_hand_capture(tmp_path_factory):
    from support import studio_pitch

    with pytest.raises(ValueError, match="is a 'pitch' capture, not a hand capture"):
        analyse_hand(studio_pitch(tmp_path_factory, "fastball"))


def test_black_photos_name_the_problem(capture, tmp_path):
    root = tmp_path / "black"
    shutil.copytree(capture, root)
    for f in (root / "images").iterdir():
        cv2.imwrite(str(f), np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    with pytest.raises(ValueError, match="no glove marker seen by both cameras of a pair"):
        analyse_hand(root)


def test_missing_camera_photo_is_named(capture, tmp_path):
    root = tmp_path / "missing"
    shutil.copytree(capture, root)
    (root / "images" / "left_inner.jpg").unlink()
    with pytest.raises(ValueError, match="left_inner.jpg does not exist"):
        analyse_hand(root)


def test_bad_options():
    with pytest.raises(ValueError, match="interpolation must be"):
        HandOptions(interpolation="cubic")
    with pytest.raises(ValueError, match="frame_rate must be"):
        HandOptions(frame_rate=0)


def test_compare_rejects_other_marker_sets(result, capture):
    truth = json.loads((capture / "truth.json").read_text())
    truth["marker_names"] = truth["marker_names"][::-1]
    with pytest.raises(ValueError, match="different marker sets"):
        compare_with_truth(result, truth)


def test_capture_without_strobe_position_says_so(capture, tmp_path):
    root = tmp_path / "nolight"
    shutil.copytree(capture, root)
    d = json.loads((root / "capture.json").read_text())
    d.pop("strobe_position_m")
    (root / "capture.json").write_text(json.dumps(d))
    res = analyse_hand(Capture.load(root), spin=False)
    assert any("strobe position unknown" in m for m in res.messages)
    assert not res.points.bias_corrected


def test_bad_strobe_position_is_named(capture):
    with pytest.raises(ValueError, match="strobe_position_m"):
        analyse_hand(capture, strobe_position_m=(1.0, 2.0))


def test_pairs_with_different_strobes_are_refused(capture, tmp_path):
    root = tmp_path / "two-strobes"
    shutil.copytree(capture, root)
    d = json.loads((root / "capture.json").read_text())
    d["images"][0]["strobe_hz"] = d["images"][1]["strobe_hz"] = 60.0
    (root / "capture.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="different strobe rates"):
        analyse_hand(root)


def test_point_sigma_must_match_the_points(result):
    from stillcap.body.hand_track import fit_hand_sequence

    with pytest.raises(ValueError, match="point_sigma_m"):
        fit_hand_sequence(result.labels, point_sigma_m=np.ones(3))
    with pytest.raises(ValueError, match="point_sigma_m must be finite and > 0"):
        fit_hand_sequence(result.labels, point_sigma_m=np.zeros(len(result.labels.points)))


def test_ball_held_per_flash(result):
    held = result.ball_held()
    assert held and set(held) <= set(int(k) for k in result.labels.order)
    assert any(held.values()) and not all(held.values())  # held, then released


def test_self_checks_pass_on_the_models_hand_and_are_in_the_json(result):
    from stillcap._selfcheck import checks_from_json, failed_checks

    names = {c.name for c in result.self_checks}
    assert {"hand_scale", "marker_fit_residual", "finger_misfit", "unlabelled_markers"} <= names
    assert failed_checks(result.self_checks) == []
    d = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert checks_from_json(d["self_checks"]) == result.self_checks


def test_partly_hidden_markers_are_listed_and_scored_apart(result):
    hid = result.partly_hidden_markers()
    assert [h["point"] for h in hid] == list(np.flatnonzero(result.points.partly_hidden))
    assert len(hid) > 0  # the studio's fingers hide part of some markers
    c = result.truth
    # a partly hidden marker never counts as recovered with the fully seen ones
    total = 100.0 * c["labels_right"] / c["markers_seen_2plus"]
    assert c["markers_recovered_pct"] + c["markers_recovered_partly_hidden_pct"] == pytest.approx(total)
    labelled = [h for h in hid if h["marker"] is not None]
    assert c["partly_hidden_labels"] == len([h for h in labelled if h["flash"] is not None])
    if c["partly_hidden_labels_right"]:
        assert c["partly_hidden_rms_mm"] > c["marker_rms_mm"]
    d = result.to_dict()
    assert d["partly_hidden"] == hid


def test_angles_resting_only_on_partly_hidden_markers_are_flagged(result):
    """The result names the joint angles only partly hidden markers fix (issue 12): in the JSON per
    flash, in a note and in the terminal's table; as the comparison scores them apart."""
    from stillcap.body.hand_track import dofs_on_partly_hidden, observed_dofs
    from stillcap.pipelines.hand.stages import partly_hidden_angle_note

    seq, lab, pts = result.sequence, result.labels, result.points
    flags = result.angles_partly_hidden()
    assert flags.shape == (lab.n_flashes, seq.skeleton.n_joints, 3)
    assert not flags[~lab.reconstructed].any()
    # the comparison's split: as many angles as it scores apart (every posed flash matched here)
    assert np.all(np.asarray(result.truth["flash_match"])[lab.reconstructed] >= 0)
    assert int(flags.sum()) == result.truth["joint_angles_compared_partly_hidden"]
    assert "angles_partly_hidden" not in {c.name for c in result.self_checks}  # a note, not a failed check
    notes = [m for m in result.messages if "rest only on partly hidden markers" in m]
    assert len(notes) == int(flags.any()) and all(m.startswith(f"{int(flags.sum())} joint angle(s)") for m in notes)
    d = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    assert np.array_equal(np.array(d["flashes"]["angles_partly_hidden"], bool), flags)
    # with no partly hidden point nothing is flagged; one nail marker hidden flags its DIP alone
    none = np.zeros(len(pts), bool)
    assert not dofs_on_partly_hidden(seq, lab.point_index, none).any()
    assert partly_hidden_angle_note(lab, seq, replace(pts, flux_ratio=np.ones_like(pts.flux_ratio))) is None
    sk, names = seq.skeleton, list(lab.marker_names)
    dip = sk.index("index-dip")
    i = next(i for i in range(seq.n) if (dip, 1) in observed_dofs(seq, i))
    one = none.copy()
    one[lab.point_index[seq.flashes[i], names.index("index.nail")]] = True
    f = dofs_on_partly_hidden(seq, lab.point_index, one)
    assert f[i, dip, 1] and np.flatnonzero(f[i].any(axis=1)).tolist() == [dip]
    assert not np.delete(f, i, axis=0).any()
    with pytest.raises(ValueError, match="partly_hidden must have one flag per point"):
        dofs_on_partly_hidden(seq, lab.point_index, none[:3])
    with pytest.raises(ValueError, match="point_index must have shape"):
        dofs_on_partly_hidden(seq, lab.point_index[:, :3], none)


def test_terminal_marks_the_angles_resting_on_partly_hidden_markers(result, capsys):
    from stillcap.cli.hand import print_hand_result

    print_hand_result(result)
    out = capsys.readouterr()
    flexion = result.angles_partly_hidden()[:, :, 1]
    assert ("rests only on partly hidden markers" in " ".join(out.out.split())) == bool(flexion.any())
    assert "self-check angles_partly_hidden" not in out.err


def test_marker_misfit_alike_in_every_flash_does_not_contradict_a_label():
    """Issue 12 (studio hand 11, built-in model): the model misses a marker the same way in
    every flash (its bone frame), so whole points of it sit ~7 mm from the fitted hand; a partly
    hidden point of two views 1 mm from that place was unlabelled as "beyond the gate" (8.4 mm
    against 7.1). Its residual is now measured from the marker's median offset in the other
    flashes; a point 15 mm from that place is still contradicted."""
    from types import SimpleNamespace

    from stillcap.body.hand import hand_markerset, hand_skeleton
    from stillcap.body.hand_label import contradicted_labels
    from stillcap.pipelines.hand.stages import misfit_residuals

    sk, ms = hand_skeleton(), hand_markerset()
    pose = sk.rest_pose()
    model = ms.positions(pose)
    frames = ms.bone_frames(sk)
    rot = pose.joint2world[frames, :3, :3]
    m = ms.names.index("index.pip")
    shift = rot[m] @ np.array([0.0075, 0.0045, 0.0])  # the model's misfit, 8.7 mm, bone frame
    n_m = len(ms.names)
    pts, pi = [], np.full((4, n_m), -1)
    for k in range(4):
        X = model.copy()
        X[m] += shift
        if k == 2:
            X[m] += rot[m] @ np.array([0.0, 0.0, 0.001])  # partly hidden: 1 mm more
        if k == 3:
            X[m] += rot[m] @ np.array([0.0, 0.015, 0.0])  # a wrong point, 15 mm from the place
        pi[k] = np.arange(n_m) + len(pts)
        pts.extend(X)
    pts = np.array(pts)
    unconfirmed = np.zeros(len(pts), bool)
    unconfirmed[pi[2:, m]] = True
    res = np.linalg.norm(pts[pi] - model[None], axis=2)
    labels = SimpleNamespace(point_index=pi, points=pts, marker_names=list(ms.names), hand_scale=1.0)
    seq = SimpleNamespace(skeleton=sk, markerset=ms, flashes=np.arange(4), poses=[pose] * 4, residuals=res)
    plain = contradicted_labels(labels, res, seq.flashes, unconfirmed)
    assert sorted(plain) == sorted(pi[2:, m])  # both beyond the 8 mm gate from the model
    fixed = misfit_residuals(labels, seq, unconfirmed)
    assert abs(fixed[2, m] - 0.001) < 1e-9 and fixed[3, m] > 0.014
    assert contradicted_labels(labels, fixed, seq.flashes, unconfirmed).tolist() == [pi[3, m]]


def _floating_root_case(wrong_mm: float):
    """Two flashes of the rest hand with every marker at its true place: flash 1 with its whole
    back-of-hand triplet, fitted right; flash 0 with only a partly hidden back.1 (back.2/back.3
    unseen), whose weighted fit left the root turned 10 deg about back.1. Flash 0's partly hidden
    index.pip is right; its partly hidden middle.dip is ``wrong_mm`` off."""
    from scipy.spatial.transform import Rotation

    from stillcap.body.hand import hand_markerset, hand_skeleton
    from stillcap.body.hand_label import HandLabels
    from stillcap.body.hand_track import HandSequence
    from stillcap.body.skeleton import Pose

    sk, ms = hand_skeleton(), hand_markerset()
    pose = sk.rest_pose()
    X = ms.positions(pose)
    names = list(ms.names)
    b1, b2, b3, ip, md = (names.index(n) for n in ("back.1", "back.2", "back.3", "index.pip", "middle.dip"))
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_rotvec(np.radians(10.0) * np.array([0.0, 0.6, 0.8])).as_matrix()
    turn[:3, 3] = X[b1] - turn[:3, :3] @ X[b1]
    floated = Pose(sk, turn @ pose.root2world, pose.local_rotations)
    n_m = len(names)
    pts = np.concatenate([X, X])
    pts[md] += np.array([0.0, 0.0, wrong_mm * 1e-3])
    pi = np.stack([np.arange(n_m), np.arange(n_m) + n_m])
    pi[0, [b2, b3]] = -1
    unconfirmed = np.zeros(len(pts), bool)
    unconfirmed[[b1, ip, md]] = True
    positions = np.where((pi >= 0)[..., None], pts[np.maximum(pi, 0)], np.nan)
    labels = HandLabels(names, list(ms.colors) if hasattr(ms, "colors") else [""] * n_m, np.arange(2), np.arange(2.0),
                        10.0, pi, positions, np.ones(2, bool), ["", ""], [pi[0][pi[0] >= 0], pi[1]], np.array([], int),
                        np.array([], int), np.zeros(2), [None, None], pts, np.array([""] * len(pts)), sk, ms, 1.0)
    poses = [floated, pose]
    res = np.stack([np.linalg.norm(positions[k] - ms.positions(p), axis=1) for k, p in enumerate(poses)])
    seq = HandSequence(sk, ms, np.arange(2), np.arange(2.0), poses, np.zeros((2, len(sk.names), 3)), res,
                       np.zeros(2), np.full(2, n_m), np.ones(2, bool), {}, None)
    return labels, seq, unconfirmed, ip, md


def test_unconfirmed_labels_in_a_flash_without_a_whole_triplet_are_tested_by_the_unweighted_fit():
    """Issue 12 (studio hand 12, built-in model): in a flash posed without its back-of-hand
    triplet, the fit that weighs partly hidden points by their noise left the root 10 mm off,
    and a right partly hidden index.pip 12.6 mm from the fitted hand lost its label. Such a
    flash's unconfirmed labels are now tested by the flash fitted without each of them, every
    other point weighted alike (testing_residuals); a point 15 mm off is still contradicted, and
    a flash whose whole triplet fixes the root keeps the weighted fit's residuals."""
    from stillcap.body.hand_label import contradicted_labels
    from stillcap.pipelines.hand.stages import misfit_residuals, root_fixed, testing_residuals

    labels, seq, unconfirmed, ip, md = _floating_root_case(15.0)
    assert root_fixed(labels, seq.flashes, unconfirmed).tolist() == [False, True]
    plain = misfit_residuals(labels, seq, unconfirmed)
    assert labels.point_index[0, ip] in contradicted_labels(labels, plain, seq.flashes, unconfirmed)
    res = testing_residuals(labels, seq, unconfirmed)
    assert np.array_equal(res[1], plain[1], equal_nan=True)
    assert res[0, ip] < 0.002 and res[0, md] > 0.012
    far = contradicted_labels(labels, res, seq.flashes, unconfirmed)
    assert far.tolist() == [labels.point_index[0, md]]
