"""Another person's hand (issue 12, parts 3 and 5): its own hand model and marker set from files
(--hand-model, --markers, capture.json hand_model / hand_markers), the self-checks that fire
with the built-in model and pass with the hand's own, and bad files named in one line (exit 2)."""

import json
import shutil

import pytest

from support import run_cli as run

SIZE = (1280, 960)


@pytest.fixture(scope="module")
def other(tmp_path_factory):
    """A studio capture of another person's hand (another_hand(6): own proportions, motion, light
    and cameras), with that hand's model and marker set written beside it."""
    from stillcap.studio.hand import hand_capture
    from stillcap.studio.hand_variation import another_hand

    root = tmp_path_factory.getbasetemp() / "cli-hand-other"
    v = another_hand(6)
    cap, images = hand_capture(6, image_size=SIZE, person=v).to_capture(".jpg")
    cap.save(root, images, jpeg_quality=92)
    v.skeleton.save(root / "my_hand.json", length_unit="mm")
    v.markerset.save(root / "my_markers.json", length_unit="mm")
    return root


@pytest.fixture(scope="module")
def results(other):
    from stillcap.pipelines.hand import HandOptions, analyse_hand
    from stillcap.studio.compare.hand import compare_with_capture

    out = {}
    for name, opts in (("built-in", HandOptions()),
                       ("own", HandOptions(hand_model=other / "my_hand.json", hand_markers=other / "my_markers.json"))):
        r = analyse_hand(other, opts)
        r.truth = compare_with_capture(r)
        out[name] = r
    return out


def test_own_hand_model_gives_the_joint_angles(results):
    own, builtin = results["own"].truth, results["built-in"].truth
    # measured: 6.2 deg RMS with the built-in model, 1.1 deg with the hand's own (the model-sized
    # studio hand of tests/pipelines/test_hand_pipeline.py: about 0.9 deg)
    assert own["joint_angle_rms_deg"] < 2.0
    assert builtin["joint_angle_rms_deg"] > 2 * own["joint_angle_rms_deg"]
    assert own["labels_right_pct"] >= 99.0


def test_self_checks_fire_with_the_built_in_model_only(results):
    from stillcap._selfcheck import failed_checks

    bad = failed_checks(results["built-in"].self_checks)
    assert any(c.name == "marker_fit_residual" for c in bad)
    assert sum(c.name == "finger_misfit" for c in bad) >= 2
    # with the hand's own model nothing misfits
    assert failed_checks(results["own"].self_checks) == []


def test_cli_prints_failed_checks_and_takes_the_files(other, capsys):
    code, out, err = run(["hand", other, "--json"], capsys)
    assert code == 0, err
    assert "self-check finger_misfit" in err and "does not match this hand on" in err
    d = json.loads(out)
    assert any(not c["passed"] for c in d["self_checks"])
    code, out, err = run(["hand", other, "--json", "--hand-model", other / "my_hand.json", "--markers",
                          other / "my_markers.json"], capsys)
    assert code == 0, err
    assert "self-check" not in err
    assert all(c["passed"] for c in json.loads(out)["self_checks"])


def test_capture_json_names_the_hand(other, tmp_path, results):
    from stillcap.pipelines.hand import analyse_hand

    cap = tmp_path / "cap"
    shutil.copytree(other, cap)
    meta = json.loads((cap / "capture.json").read_text())
    meta.update(hand_model="my_hand.json", hand_markers="my_markers.json")
    (cap / "capture.json").write_text(json.dumps(meta))
    r = analyse_hand(cap)
    assert r.skeleton.n_joints == results["own"].skeleton.n_joints
    assert r.labels.hand_scale == pytest.approx(results["own"].labels.hand_scale)
    assert r.sequence.angles_deg == pytest.approx(results["own"].sequence.angles_deg, abs=1e-6)
    # built-in names work too; a path that leaves the capture folder does not
    meta.update(hand_model="hand-right-adult", hand_markers="hand-18")
    (cap / "capture.json").write_text(json.dumps(meta))
    assert analyse_hand(cap).labels.hand_scale == pytest.approx(results["built-in"].labels.hand_scale)
    meta["hand_model"] = "../my_hand.json"
    (cap / "capture.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match='capture.json "hand_model".*leaves the capture folder'):
        analyse_hand(cap)


@pytest.mark.parametrize("flag, content, message", [
    ("--hand-model", "{not json", "is not valid JSON"),
    ("--hand-model", '{"format": "stillcap-skeleton", "version": 1, "joints": [{"name": "wrist", "offset": [0, 0]}]}',
     "joints.0.offset"),
    ("--hand-model", '{"format": "stillcap-skeleton", "version": 1, "joints": [{"name": "root"}, '
                     '{"name": "knee", "parent": "root"}]}', "skeleton 'skeleton' lacks"),
    ("--markers", '{"format": "stillcap-ball", "version": 1}', "not a marker-set file"),
    ("--markers", '{"format": "stillcap-markerset", "version": 1, "markers": []}', "no back-of-hand marker"),
])
def test_bad_hand_files_exit_2_naming_the_file(other, tmp_path, capsys, flag, content, message):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    code, out, err = run(["hand", other, flag, bad], capsys)
    assert code == 2
    assert "bad.json" in err and message in err
    assert len(err.strip().splitlines()) == 1


def test_missing_hand_file_exits_2(other, tmp_path, capsys):
    code, out, err = run(["hand", other, "--markers", tmp_path / "nowhere.json"], capsys)
    assert code == 2 and "nowhere.json" in err and "does not exist" in err


def test_adapt_model_is_experimental_and_says_so(other, results, capsys):
    # the adapted model absorbs the misfit: its residual checks pass although the angles are off
    # (measured on this hand: 6.3 deg RMS), so the result always warns that it was adapted
    code, out, err = run(["hand", other, "--json", "--adapt-model"], capsys)
    assert code == 0, err
    d = json.loads(out)
    adapted = [c for c in d["self_checks"] if c["name"] == "model_adapted"]
    assert len(adapted) == 1 and not adapted[0]["passed"]
    assert "self-check model_adapted" in err
    assert d["truth_comparison"]["labels_right_pct"] >= 99.0
    assert not any(c.name == "model_adapted" for c in results["own"].self_checks)


def test_markers_the_posed_hand_predicts_are_found_again_and_labelled_right(other, results):
    """Issue 12: markers the blind matching left out (fingers on the ball's disc, which the glove
    search masks; two-view matches a rival blob explains as well) are looked for again from their
    blobs where the posed hand puts them (stage recover_markers); every point found so carries a
    label, and each label names the true marker (measured on this capture: 3 with the built-in
    model, 4 with the hand's own, 0.2-3.3 mm from the truth)."""
    import numpy as np

    from stillcap.studio.compare.hand import LABEL_TOLERANCE_M, truth_arrays

    tr = truth_arrays(json.loads((other / "truth.json").read_text()))
    for name, r in results.items():
        new = np.flatnonzero(r.points.pairs == "predicted")
        assert len(new) >= 2, name
        lp = r.labels.labels()
        assert np.all(lp[new, 0] >= 0), name  # points that got no label are not kept
        for p in new:
            k, m = lp[p]
            d = np.linalg.norm(tr["markers"][r.truth["flash_match"][k]] - r.points.points[p], axis=1)
            assert int(np.nanargmin(d)) == m and d[m] <= LABEL_TOLERANCE_M, (name, r.labels.marker_names[m])
        assert any(f"{len(new)} marker(s) labelled where the posed hand predicted them" in msg for msg in r.messages)


def test_angles_only_partly_hidden_markers_fix_are_scored_apart(results):
    """A joint angle that only a partly hidden marker fixes (its centroid shifted by the
    occlusion) is scored apart from those the whole markers fix, as its 3D error is; together
    they are every angle the labelled markers fix."""
    from stillcap.body.hand_track import observed_dofs

    for r in results.values():
        c, seq = r.truth, r.sequence
        fixed = sum(len(observed_dofs(seq, i)) for i, k in enumerate(seq.flashes) if c["flash_match"][k] >= 0)
        assert c["joint_angles_compared"] + c["joint_angles_compared_partly_hidden"] == fixed
        assert c["joint_angles_compared"] > 0
