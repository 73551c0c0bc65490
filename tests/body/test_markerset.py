"""The puppet marker set: names, colours, placement, bone-direction rules, files, trajectories."""

import colorsys
import json

import numpy as np
import pytest

from stillcap.body import Animation, MarkerSet, MarkerTrajectories, Skeleton, bone_directions

SPEC_HSB = {
    "head.1": (0.499, 0.176, 0.754), "head.2": (0.303, 0.611, 0.607), "torso.1": (0.768, 0.329, 0.562),
    "torso.2": (0.187, 0.633, 0.706), "arm.L1": (0.589, 0.234, 0.804), "arm.L2": (0.286, 0.251, 0.694),
    "arm.L3": (0.077, 0.715, 0.575), "arm.R1": (0.558, 0.605, 0.827), "arm.R2": (0.978, 0.265, 0.598),
    "arm.R3": (0.240, 0.619, 0.675), "leg.L1": (0.514, 0.540, 0.599), "leg.L2": (0.867, 0.387, 0.575),
    "leg.L3": (0.286, 0.505, 0.515), "leg.R1": (0.387, 0.667, 0.558), "leg.R2": (0.188, 0.237, 0.777),
    "leg.R3": (0.554, 0.431, 0.790),
}  # fmt: skip

SPEC_RULES = {
    "head": ("head.2", "head.1"), "upper-back": ("torso.2", "torso.1"),
    "l-elbow": ("arm.L1", "arm.L2"), "l-hand": ("arm.L2", "arm.L3"),
    "r-elbow": ("arm.R1", "arm.R2"), "r-hand": ("arm.R2", "arm.R3"),
    "l-knee": ("leg.L1", "leg.L2"), "l-foot": ("leg.L2", "leg.L3"),
    "r-knee": ("leg.R1", "leg.R2"), "r-foot": ("leg.R2", "leg.R3"),
}  # fmt: skip


@pytest.fixture(scope="module")
def puppet():
    return Skeleton.puppet(), MarkerSet.puppet()


def test_sixteen_markers_with_spec_colors(puppet):
    skel, ms = puppet
    assert sorted(ms.names) == sorted(SPEC_HSB)
    for m in ms.markers:
        assert m.hsb == pytest.approx(SPEC_HSB[m.name])
        assert m.rgb == pytest.approx(colorsys.hsv_to_rgb(*SPEC_HSB[m.name]))
        assert m.diameter == pytest.approx(0.006)
        assert all(0 <= c <= 255 for c in m.rgb8)
    ms.check_skeleton(skel)


def test_spec_rules_are_the_marker_set_rules(puppet):
    _, ms = puppet
    rules = {r.bone: r for r in ms.rules}
    for bone, (m1, m2) in SPEC_RULES.items():
        assert (rules[bone].start, rules[bone].end) == (m1, m2)
    assert rules["l-finger"].copy == "l-hand" and rules["r-finger"].copy == "r-hand"
    assert rules["l-toes"].cross == "l-foot" and rules["l-toes"].axis == (1, 0, 0)
    assert rules["l-shoulder"].axis == (0, 0, 1) and rules["r-shoulder"].axis == (0, 0, -1)


def test_marker_directions_match_bone_directions_at_rest(puppet):
    """The thesis's rules (head.2 -> head.1 etc., and the derived bones) hold exactly at rest."""
    skel, ms = puppet
    rest = skel.rest_pose()
    markers = ms.positions(rest)
    dirs = bone_directions(ms, markers)
    assert set(dirs) == {r.bone for r in ms.rules}
    for bone, d in dirs.items():
        v = rest.bone_vectors()[skel.index(bone)]
        np.testing.assert_allclose(d, v / np.linalg.norm(v), atol=1e-12, err_msg=bone)


def test_markers_sit_near_their_bones(puppet):
    """Beads sit on the surface: 5-15 mm from the bone line, elbow/knee beads at the joint."""
    skel, ms = puppet
    rest = skel.rest_pose()
    pos = dict(zip(ms.names, ms.positions(rest)))
    joints = dict(zip(skel.names, rest.positions))
    for m in ms.markers:
        a, b = joints[skel.joints[skel.index(m.bone)].parent], joints[m.bone]
        t = np.clip(np.dot(pos[m.name] - a, b - a) / np.dot(b - a, b - a), 0, 1)
        dist = np.linalg.norm(pos[m.name] - (a + t * (b - a)))
        assert 0.005 <= dist <= 0.015, m.name
    assert np.linalg.norm(pos["arm.L2"] - joints["l-elbow"]) < 0.01
    assert np.linalg.norm(pos["leg.R2"] - joints["r-knee"]) < 0.01


def test_marker_set_file_round_trip_and_errors(puppet, tmp_path):
    _, ms = puppet
    back = MarkerSet.load(ms.save(tmp_path / "m.json", length_unit="mm"))
    assert back.names == ms.names and [r.to_dict() for r in back.rules] == [r.to_dict() for r in ms.rules]
    np.testing.assert_allclose(back.offsets, ms.offsets, atol=1e-12)
    data = ms.to_dict()
    data["markers"][0]["rgb"] = [1, 0, 0]
    (tmp_path / "rgb.json").write_text(json.dumps(data))
    with pytest.raises(ValueError,
                       match=r"rgb\.json: markers\.0\.rgb: marker 'head.1': rgb \[1\.0, 0\.0, 0\.0\] disagrees"
                              r" with hsb"):
        MarkerSet.load(tmp_path / "rgb.json")
    data = ms.to_dict()
    data["bone_rules"][0]["to"] = "nose"
    (tmp_path / "rule.json").write_text(json.dumps(data))
    with pytest.raises(ValueError,
                       match=r"rule\.json: bone_rules\.0\.to: bone rule for 'head' names unknown marker 'nose'$"):
        MarkerSet.load(tmp_path / "rule.json")
    data = ms.to_dict()
    data["markers"][1]["name"] = data["markers"][0]["name"]
    with pytest.raises(ValueError, match=r"^<dict>: markers\.1\.name: duplicate marker name 'head.1'$"):
        MarkerSet.from_dict(data)


def test_trajectories_from_an_animation(puppet):
    skel, ms = puppet
    rest = skel.rest_pose()
    anim = Animation.from_poses([rest, rest, rest], frame_rate=10)
    traj = ms.trajectories(anim)
    assert traj.points.shape == (3, 16, 3) and traj.frame_rate == 10
    np.testing.assert_allclose(traj.times, [0, 0.1, 0.2])
    assert traj.seen.all()


def test_trajectories_validate_shapes():
    with pytest.raises(ValueError, match=r"points must have shape \(N, 2, 3\), got \(4, 3, 3\)"):
        MarkerTrajectories(("a", "b"), np.zeros((4, 3, 3)), 50)
    with pytest.raises(ValueError, match="frame_rate must be > 0"):
        MarkerTrajectories(("a",), np.zeros((4, 1, 3)), 0)
    with pytest.raises(ValueError, match="unique"):
        MarkerTrajectories(("a", "a"), np.zeros((4, 2, 3)), 50)


def test_bone_frames_follow_the_skeleton_asked_about():
    # bone_frames keeps its answer for the last skeleton: asked about two skeletons in turn, each
    # gets its own frames (a fresh marker set's), and a skeleton without a bone is still refused
    ms = MarkerSet.puppet()
    sk1 = Skeleton.puppet()
    d = sk1.to_dict()
    head = next(j for j in d["joints"] if j["name"] == "head")
    assert head["parent"] != "root"
    head["parent"] = "root"
    sk2 = Skeleton.from_dict(d)
    want1, want2 = MarkerSet.puppet().bone_frames(sk1), MarkerSet.puppet().bone_frames(sk2)
    assert not np.array_equal(want1, want2)
    for sk, want in ((sk1, want1), (sk2, want2), (sk1, want1), (sk1, want1), (sk2, want2)):
        got = ms.bone_frames(sk)
        assert np.array_equal(got, want)
        got[:] = -5  # a copy: changing it changes nothing kept
    d["joints"] = [j for j in d["joints"] if j["name"] != "head" and j.get("parent") != "head"]
    with pytest.raises(ValueError, match="which skeleton .* lacks"):
        ms.bone_frames(Skeleton.from_dict(d))
