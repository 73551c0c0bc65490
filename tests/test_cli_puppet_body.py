"""`stillcap puppet run --skeleton/--markers` and `stillcap puppet calibrate-skeleton` on a rendered
puppet of other proportions (stillcap.studio.puppet_variation); the result reports bead-pair
directions, partly hidden beads and per-bone self-checks."""

import json

import numpy as np
import pytest
from support import run_cli as run

from stillcap.studio.puppet import puppet_scene
from stillcap.studio.puppet_variation import another_puppet


@pytest.fixture(scope="module")
def other(tmp_path_factory):
    """Another puppet (seed 3): its files, a rest-pose capture and a posed one, 6 views 60 deg apart."""
    from stillcap.calibrate.turntable import turntable_rig

    root = tmp_path_factory.mktemp("other")
    sk, ms = another_puppet(3)
    sk.save(root / "true.json", "mm")
    ms.save(root / "true-markers.json", "mm")
    rig = turntable_rig(n_views=6, step_deg=60.0)
    for name, spec in (("rest", "tpose"), ("test", "random:13")):
        cap, images = puppet_scene(rig, pose=spec, rng=3, markerset=ms, skeleton=sk).to_capture(".png")
        cap.save(root / name, images)
    return root


def test_run_with_the_puppets_own_files_fits_and_the_builtin_skeleton_is_flagged(other, capsys):
    code, out, err = run(["puppet", "run", other / "test", "--json"], capsys)
    assert code == 0, err
    d = json.loads(out)
    failed = [c for c in d["self_checks"] if not c["passed"] and c["name"] != "bead_whole_views"]
    assert failed and "calibrate-skeleton" in failed[0]["message"] and "WARNING: puppet: self-check" in err
    assert d["bead_pair_directions"] and d["pose_fit"]["root"] == "free"
    builtin = d["comparison"]["bone_direction_error_deg"]["fit"]["full"]["rms"]
    code, out, err = run(["puppet", "run", other / "test", "--json", "--skeleton", other / "true.json",
                          "--markers", other / "true-markers.json"], capsys)
    assert code == 0, err
    d = json.loads(out)
    assert not [c for c in d["self_checks"] if not c["passed"] and c["name"] != "bead_whole_views"]
    user = d["comparison"]["bone_direction_error_deg"]["fit"]["full"]["rms"]
    assert user < 1.0 < builtin
    assert d["skeleton"]["name"] == "puppet-210mm-varied"
    assert set(d["partly_hidden"]) == {m["name"] for m in d["markers"] if m["partly_hidden"]}


def test_run_names_a_bad_skeleton_file(other, tmp_path, capsys):
    code, _, err = run(["puppet", "run", other / "test", "--skeleton", tmp_path / "none.json"], capsys)
    assert code == 2 and "--skeleton" in err and "none.json" in err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "stillcap-skeleton", "joints": [{"name": "a", "parent": "b"}]}))
    code, _, err = run(["puppet", "run", other / "test", "--skeleton", bad], capsys)
    assert code == 2 and "bad.json" in err and "unknown parent" in err


def test_calibrate_skeleton_writes_files_the_run_reads(other, tmp_path, capsys):
    out = tmp_path / "cal.json"
    code, text, err = run(["puppet", "calibrate-skeleton", other / "rest", "--out", out], capsys)
    assert code == 0, err
    assert out.is_file() and (tmp_path / "cal-markers.json").is_file() and "add --pose" in text and "direction" in text
    assert "bead noise the photos show" in text and " px = " in text and "rest capture turned" in text
    from stillcap.body.skeleton import Skeleton

    cal = Skeleton.load(out)
    assert np.isclose(cal.offsets[cal.root][1], Skeleton.load(other / "true.json").offsets[0][1], atol=1e-3)
    code, text, err = run(["puppet", "run", other / "test", "--json", "--skeleton", out, "--markers",
                           tmp_path / "cal-markers.json"], capsys)
    assert code == 0, err
    assert json.loads(text)["skeleton"]["name"] == "puppet-210mm-calibrated"


def test_calibrate_skeleton_names_a_rest_turn_that_is_not_an_angle(tmp_path, capsys):
    # checked before any capture is read (the folder does not exist)
    code, _, err = run(["puppet", "calibrate-skeleton", tmp_path / "rest", "--out", tmp_path / "cal.json",
                           "--rest-turn-deg", "nan"], capsys)
    assert code == 2 and "--rest-turn-deg must be a finite angle in degrees" in err
    assert not (tmp_path / "cal.json").exists()


def test_run_and_reconstruct_name_a_bone_tolerance_that_is_not_an_angle(tmp_path, capsys):
    # checked before any capture is read (the folder does not exist)
    for cmd in ("run", "reconstruct"):
        for bad in ("nan", "-0.5", "90"):
            code, _, err = run(["puppet", cmd, tmp_path / "nothing", "--bone-tolerance-deg", bad], capsys)
            assert code == 2 and "--bone-tolerance-deg must be an angle in [0, 90) degrees" in err, (cmd, bad, err)


def test_new_keeps_the_puppets_files_in_the_project_and_reconstruct_names_a_missing_one(tmp_path, capsys):
    from stillcap.io.project import Project

    sk, ms = another_puppet(4)
    sk.save(tmp_path / "sk.json", "mm")
    ms.save(tmp_path / "ms.json", "mm")
    code, _, err = run(["puppet", "new", tmp_path / "proj", "--skeleton", tmp_path / "sk.json", "--markers",
                        tmp_path / "ms.json"], capsys)
    assert code == 0, err
    p = Project.load(tmp_path / "proj")
    assert p.skeleton is not None and np.allclose(p.skeleton.offsets, sk.offsets, atol=1e-6)
    assert np.allclose(p.markerset.offsets, ms.offsets, atol=1e-6)
    code, _, err = run(["puppet", "reconstruct", tmp_path / "proj", "--skeleton", tmp_path / "none.json"], capsys)
    assert code == 2 and "--skeleton" in err and "none.json" in err
    code, _, err = run(["puppet", "new", tmp_path / "proj2", "--markers", tmp_path / "none.json"], capsys)
    assert code == 2 and "--markers" in err
