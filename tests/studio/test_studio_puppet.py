"""The puppet scenario: the marked lay figure on the thesis's turntable, with consistent truth."""

import numpy as np
import pytest

from stillcap.body import MarkerSet, Pose, Skeleton
from stillcap.calibrate.turntable import turntable_rig
from stillcap.cli import main
from stillcap.io.capture import Capture
from stillcap.studio import render_radiance
from stillcap.studio.puppet import (PuppetTruth, pose_from_spec, puppet_collisions, puppet_scene, random_pose,
                                    turn_angle_deg)
from support import shared_data


@pytest.fixture(scope="module")
def tpose():
    """The T-pose from the 12 default turntable views (the thesis's setup), webcam sensor."""
    return puppet_scene(pose="tpose", rng=0, supersample=1)


def _blob_centroid(radiance, xy, r=9, level=0.06):
    """Brightness-weighted centroid of the blob around ``xy`` (pixels above ``level``)."""
    x0, y0 = (int(round(v)) for v in xy)
    win = radiance[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1].mean(axis=2)
    w = np.clip(win - level, 0, None)
    ys, xs = np.mgrid[y0 - r:y0 + r + 1, x0 - r:x0 + r + 1]
    return np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()


def test_default_views_are_the_thesis_turntable(tpose):
    assert len(tpose.images) == 12 and len(tpose.rig) == 12
    assert all(im.shape == (480, 640, 3) and im.dtype == np.uint8 for im in tpose.images)
    np.testing.assert_allclose(tpose.truth.angles_deg, np.arange(12) * 30.0, atol=1e-9)
    assert tpose.rig[0].K[0, 0] == pytest.approx(859.016)
    assert tpose.truth.source == {"type": "tpose"}
    # truth: rest joints and beads of the puppet, pelvis centre on the turn axis
    skel, ms = Skeleton.puppet(), MarkerSet.puppet()
    np.testing.assert_allclose(tpose.truth.joint_positions, Pose.rest(skel).positions)
    np.testing.assert_allclose(tpose.truth.marker_positions, ms.positions(Pose.rest(skel)))
    np.testing.assert_allclose(tpose.truth.joint_positions[skel.root], [0, 0.110, 0])
    assert tpose.truth.marker_names == list(ms.names)


def test_every_marker_is_seen_twice_in_the_tpose(tpose):
    assert np.all(tpose.truth.views_per_marker >= 2)
    seen = tpose.truth.visible
    assert np.array_equal(seen, np.isfinite(tpose.truth.markers_px).all(axis=2))
    assert seen[0].all()  # from the front, every bead shows


def test_visible_bead_pixel_is_its_blob_center(tpose):
    rad = render_radiance(tpose.rig[0], tpose.view_scene(0), supersample=5)
    tr = tpose.truth
    px = tr.markers_px[0]
    checked = 0
    for m in range(len(px)):
        others = np.delete(px, m, axis=0)
        if tr.coverage[0, m] < 0.99 or np.nanmin(np.linalg.norm(others - px[m], axis=1)) < 25:
            continue  # only whole, isolated blobs
        assert np.linalg.norm(_blob_centroid(rad, px[m]) - px[m]) < 0.2, tr.marker_names[m]
        checked += 1
    assert checked >= 8


def test_bead_behind_the_torso_is_hidden(tpose):
    tr = tpose.truth
    back = 6  # 180 degrees: the camera looks at the puppet's back
    assert tr.angles_deg[back] == pytest.approx(180.0)
    rad_back = render_radiance(tpose.rig[back], tpose.view_scene(back), supersample=1)
    for name in ("torso.1", "torso.2"):
        m = tr.marker_names.index(name)
        assert tr.visible[0, m] and not tr.visible[back, m] and np.isnan(tr.markers_px[back, m]).all()
        assert tr.coverage[back, m] == 0.0
        x, y = np.round(tpose.rig[back].project(tr.marker_positions[m])).astype(int)
        assert rad_back[y - 2:y + 3, x - 2:x + 3].mean(axis=2).max() < 0.06  # black torso, no bead colour
        x0, y0 = np.round(tr.markers_px[0, m]).astype(int)
        assert tpose.images[0][y0, x0].astype(int).sum() > 3 * 100  # while the front view shows it bright


def test_random_poses_respect_limits_and_do_not_intersect():
    skel = Skeleton.puppet()
    for seed in range(6):
        pose = random_pose(skel, seed)
        assert not skel.limit_violations(pose.local_rotations).any()
        assert puppet_collisions(pose) == []
        np.testing.assert_allclose(pose.root2world, skel.rest_root2world())
    assert not np.allclose(random_pose(skel, 0).local_rotations, random_pose(skel, 1).local_rotations)
    np.testing.assert_allclose(random_pose(skel, 3).local_rotations, random_pose(skel, 3).local_rotations)


def test_pose_specs_and_bad_input(tmp_path):
    pose, src = pose_from_spec("random", rng=5)
    assert src["type"] == "random"
    np.testing.assert_allclose(pose.local_rotations, pose_from_spec(f"random:{src['seed']}")[0].local_rotations)
    assert pose_from_spec("tpose")[1] == {"type": "tpose"}
    with pytest.raises(ValueError, match="unknown pose spec 'dance'"):
        pose_from_spec("dance")
    missing = tmp_path / "nothere.bvh"
    with pytest.raises(ValueError, match="nothere.bvh"):
        pose_from_spec(f"bvh:{missing}:3")
    with pytest.raises(ValueError, match="unknown pose spec"):
        puppet_scene(pose="bvh:")
    with pytest.raises(ValueError, match="pose must be"):
        puppet_scene(pose=42)


def test_bvh_pose_scene_and_capture_round_trip(tmp_path):
    bvh = shared_data("bvh") / "walk01.bvh"
    rig = turntable_rig(2, 90.0)
    ps = puppet_scene(rig, f"bvh:{bvh}:40", rng=1, supersample=1)
    tr = ps.truth
    assert tr.source["type"] == "bvh" and tr.source["frame"] == 40 and tr.source["file"].endswith("walk01.bvh")
    assert tr.source["joint_map"]["l-elbow"] == "LeftForeArm"
    assert tr.markers_px.shape == (2, 16, 2) and [turn_angle_deg(c) for c in rig] == pytest.approx([0, 90])
    with pytest.raises(ValueError, match="frame 500"):
        pose_from_spec(f"bvh:{bvh}:500")

    cap, images = ps.to_capture()
    cap.save(tmp_path / "cap", images)
    back = Capture.load(tmp_path / "cap")
    assert back.kind == "puppet" and back.rig.names == rig.names and back.meta["rig_calibrated"]
    assert [im.meta["angle_deg"] for im in back.images] == [0.0, 90.0]
    assert (back.read_image(1) == ps.images[1]).all()  # PNG: lossless
    t2 = PuppetTruth.from_dict(back.truth)
    for k in ("marker_positions", "joint_positions", "local_rotations", "root2world", "markers_px", "coverage"):
        np.testing.assert_allclose(getattr(t2, k), getattr(tr, k), atol=1e-12, err_msg=k)
    assert np.array_equal(t2.visible, tr.visible) and t2.source == tr.source
    np.testing.assert_allclose(t2.pose().positions, tr.joint_positions, atol=1e-12)


def _run(args) -> int:
    """Exit status of the CLI (``main`` may return or raise SystemExit on success)."""
    try:
        main(args)
    except SystemExit as e:
        return e.code
    return 0


def test_cli_writes_a_puppet_capture(tmp_path, capsys):
    out = tmp_path / "pup"
    assert _run(["studio", "puppet", "--out", str(out), "--seed", "3", "--pose", "tpose", "--views", "2",
                 "--step-deg", "45", "--jpeg", "80"]) == 0
    cap = Capture.load(out)
    assert cap.kind == "puppet" and len(cap.images) == 2 and cap.images[1].file.endswith(".jpg")
    assert cap.rig.names == ["turn_000.0deg", "turn_045.0deg"] and cap.rig[0].image_size == (640, 480)
    tr = PuppetTruth.from_dict(cap.truth)
    assert tr.visible.shape == (2, 16) and tr.source == {"type": "tpose"}
    cap.verify()
    assert _run(["studio", "puppet", "--out", str(tmp_path / "x"), "--pose", "bvh:missing.bvh"]) == 2
    assert "missing.bvh" in capsys.readouterr().err
