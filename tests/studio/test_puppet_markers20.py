"""`stillcap studio puppet --markers puppet-20`: the capture stores its marker set, the pipeline
uses it untold, and the forearms' and shins' twist is measured (docs/puppet.md, puppet-20)."""

import json

import numpy as np
import pytest
from support import run_cli as run

from stillcap.body import MarkerSet
from stillcap.io.capture import Capture
from stillcap.pipelines.puppet import analyse_puppet
from stillcap.studio.compare.puppet import compare_with_capture
from stillcap.studio.puppet import puppet_scene, webcam_sensor

LOWER = ("l-hand", "r-hand", "l-foot", "r-foot")  # forearm and shin bones
POSE = "random:11"  # the right forearm 13 deg off with puppet-16 in the benchmark (its twist is open there)
#: Largest forearm/shin direction error over the benchmark's 52 puppet-20 poses where both
#: beads of the segment were recovered (200 segments, RMS 0.23 deg; docs/puppet.md).
TOL_DEG = 1.23


@pytest.fixture(scope="module")
def capture20(tmp_path_factory):
    out = tmp_path_factory.mktemp("p20") / "cap"
    from stillcap.cli import main

    main(["studio", "puppet", "--out", str(out), "--pose", POSE, "--seed", "1", "--markers", "puppet-20"])
    return out


def test_the_capture_stores_the_marker_set_and_the_pipeline_uses_it(capture20):
    cap = Capture.load(capture20)
    stored = MarkerSet.resolve(cap.meta["markerset"])
    assert stored.to_dict() == MarkerSet.puppet("puppet-20").to_dict()
    truth = json.loads((capture20 / "truth.json").read_text())
    assert [m["name"] for m in truth["markers"]] == list(stored.names)
    res, _ = analyse_puppet(capture20)
    res.comparison = compare_with_capture(res, capture20)
    assert res.markerset.name == "puppet-20" and len(res.names) == 20
    assert res.to_dict()["markerset"] == "puppet-20" and res.comparison is not None
    cmp = res.comparison
    assert cmp.wrong == 0 and cmp.recovered_seen_twice == cmp.seen_twice
    # every forearm and shin has both beads: fully measured, twist included
    assert set(LOWER) <= set(cmp.measured_bone_groups["full"]) and "partial" not in cmp.bone_groups
    errs = np.array([cmp.bone_errors_deg[b] for b in LOWER])
    assert errs.max() < TOL_DEG
    # the thesis's 16 beads on the same pose leave the forearms' twist open
    sc = puppet_scene(pose=POSE, rng=1, sensor=webcam_sensor())
    c16, imgs = sc.to_capture(".png")
    folder = capture20.parent / "cap16"
    c16.save(folder, imgs)
    r16, _ = analyse_puppet(folder)
    r16.comparison = compare_with_capture(r16, folder)
    e16 = np.array([r16.comparison.bone_errors_deg[b] for b in LOWER])
    assert r16.markerset.name == "puppet-16" and e16.max() > 5.0


def test_cli_marker_set_option(capture20, tmp_path, capsys):
    code, _, err = run(["studio", "puppet", "--out", tmp_path / "x", "--markers", "puppet-99"], capsys)
    assert code == 2 and "puppet-99" in err and not (tmp_path / "x").exists()
    ms = MarkerSet.puppet("puppet-20")
    ms.save(tmp_path / "m.json")
    code, _, err = run(["studio", "puppet", "--out", tmp_path / "y", "--markers", tmp_path / "m.json", "--views", "2",
                        "--pose", "tpose"], capsys)
    assert code == 0
    assert MarkerSet.resolve(Capture.load(tmp_path / "y").meta["markerset"]).to_dict() == ms.to_dict()
    code, out, _ = run(["puppet", "run", capture20, "--json"], capsys)
    assert code == 0 and json.loads(out)["markerset"] == "puppet-20" and len(json.loads(out)["markers"]) == 20
