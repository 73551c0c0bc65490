"""Skeleton data, forward kinematics, poses, animations, skeleton files."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body import Animation, Joint, Pose, Skeleton, forward_kinematics

SPEC_JOINTS = [
    "root", "l-hip", "r-hip", "l-knee", "r-knee", "l-foot", "r-foot", "l-toes", "r-toes", "lower-back",
    "upper-back", "head", "l-shoulder", "r-shoulder", "l-elbow", "r-elbow", "l-hand", "r-hand", "l-finger", "r-finger",
]  # fmt: skip


@pytest.fixture(scope="module")
def puppet():
    return Skeleton.puppet()


def random_pose(skel, seed=0, scale=0.5):
    rng = np.random.default_rng(seed)
    local = Rotation.from_rotvec(rng.normal(scale=scale, size=(skel.n_joints, 3))).as_matrix()
    r2w = skel.rest_root2world()
    r2w[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    r2w[:3, 3] += rng.normal(scale=0.1, size=3)
    return Pose(skel, r2w, local)


def test_puppet_has_the_spec_joints_and_hierarchy(puppet):
    assert sorted(puppet.names) == sorted(SPEC_JOINTS)
    parent = {j.name: j.parent for j in puppet.joints}
    assert parent["root"] is None
    for side in "lr":
        assert [parent[f"{side}-{b}"] for b in ("hip", "knee", "foot", "toes")] == ["root", f"{side}-hip", f"{side}-knee", f"{side}-foot"]
        assert [parent[f"{side}-{b}"] for b in ("shoulder", "elbow", "hand", "finger")] == ["upper-back", f"{side}-shoulder", f"{side}-elbow", f"{side}-hand"]
    assert parent["lower-back"] == "root" and parent["upper-back"] == "lower-back" and parent["head"] == "upper-back"


def test_puppet_proportions_fit_a_210mm_lay_figure(puppet):
    pos = puppet.rest_pose().positions
    p = dict(zip(puppet.names, pos))
    assert 0.200 <= p["head"][1] <= 0.215  # top of the head
    assert 0.0 <= p["l-foot"][1] <= 0.015  # ankles just above the platform
    span = p["l-finger"][0] - p["r-finger"][0]
    assert 0.19 <= span <= 0.23  # arm span about the height
    assert p["l-shoulder"][0] > 0 and p["r-shoulder"][0] < 0  # puppet's left is +x
    assert p["l-toes"][2] > p["l-foot"][2]  # feet point forward (+z)
    np.testing.assert_allclose(p["root"], [0, 0.110, 0])  # pelvis on the turntable axis
    # left and right mirror each other in x
    for n in puppet.names:
        if n.startswith("l-"):
            np.testing.assert_allclose(p[n] * [-1, 1, 1], p["r-" + n[2:]])


def test_rest_pose_is_within_limits_and_pelvis_is_locked(puppet):
    assert not puppet.limit_violations(np.tile(np.eye(3), (puppet.n_joints, 1, 1))).any()
    np.testing.assert_array_equal(puppet.limits_deg[puppet.index("root")], np.zeros((3, 2)))
    bent = np.tile(np.eye(3), (puppet.n_joints, 1, 1))
    bent[puppet.index("l-knee")] = Rotation.from_euler("x", -30, degrees=True).as_matrix()  # knee bent forward
    bad = puppet.limit_violations(bent)
    assert bad[puppet.index("l-knee"), 0] and bad.sum() == 1


def test_forward_kinematics_rotates_children_about_the_joint(puppet):
    local = np.tile(np.eye(3), (puppet.n_joints, 1, 1))
    e = puppet.index("l-elbow")
    local[puppet.index("l-shoulder")] = Rotation.from_euler("z", -90, degrees=True).as_matrix()  # arm down
    pose = Pose(puppet, puppet.rest_root2world(), local)
    p = dict(zip(puppet.names, pose.positions))
    np.testing.assert_allclose(p["l-shoulder"], [0.022, 0.172, 0], atol=1e-12)
    np.testing.assert_allclose(p["l-elbow"], [0.022, 0.172 - 0.036, 0], atol=1e-12)
    np.testing.assert_allclose(p["l-finger"], [0.022, 0.172 - 0.086, 0], atol=1e-12)
    assert pose.bone_vectors()[e] == pytest.approx([0, -0.036, 0], abs=1e-12)


def test_forward_kinematics_matches_a_recursive_reference(puppet):
    pose = random_pose(puppet)
    ref = {}

    def frame(j):
        if j not in ref:
            lt = np.eye(4)
            lt[:3, :3] = pose.local_rotations[j]
            p = puppet.parents[j]
            if p < 0:
                ref[j] = pose.root2world @ lt
            else:
                lt[:3, 3] = puppet.offsets[j]
                ref[j] = frame(p) @ lt
        return ref[j]

    np.testing.assert_allclose(pose.joint2world, np.array([frame(j) for j in range(puppet.n_joints)]), atol=1e-12)
    # bone lengths are preserved by any pose
    lengths = np.linalg.norm(pose.bone_vectors(), axis=1)
    np.testing.assert_allclose(lengths, puppet.bone_lengths, atol=1e-12)


def test_moving_the_root_moves_everything_rigidly(puppet):
    pose = random_pose(puppet, seed=3)
    move = np.eye(4)
    move[:3, :3] = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    move[:3, 3] = [0.1, 0, -0.2]
    moved = Pose(puppet, move @ pose.root2world, pose.local_rotations)
    np.testing.assert_allclose(moved.positions, pose.positions @ move[:3, :3].T + move[:3, 3], atol=1e-12)


def test_animation_batches_poses(puppet):
    poses = [random_pose(puppet, seed=s) for s in range(4)]
    anim = Animation.from_poses(poses, frame_rate=25)
    assert anim.n_frames == 4 and anim.frame_rate == pytest.approx(25)
    np.testing.assert_allclose(anim.positions, np.stack([p.positions for p in poses]), atol=1e-12)
    np.testing.assert_allclose(anim[2].positions, poses[2].positions)
    np.testing.assert_allclose(
        forward_kinematics(puppet, anim.root2world, anim.local_rotations)[1], poses[1].joint2world, atol=1e-12
    )
    assert Animation.from_poses(poses, times=[0, 0.1, 0.3, 0.4]).frame_rate is None
    with pytest.raises(ValueError, match="strictly increasing"):
        Animation.from_poses(poses, times=[0, 0.2, 0.1, 0.4])


def test_bad_inputs_name_the_shape_that_came(puppet):
    with pytest.raises(ValueError, match=r"local_rotations must have shape \(20, 3, 3\), got \(19, 3, 3\)"):
        Pose(puppet, np.eye(4), np.tile(np.eye(3), (19, 1, 1)))
    with pytest.raises(ValueError, match=r"root2world must have shape \(4, 4\), got \(3, 3\)"):
        Pose(puppet, np.eye(3), np.tile(np.eye(3), (20, 1, 1)))
    scaled = np.tile(np.eye(3), (20, 1, 1))
    scaled[4] *= 2
    with pytest.raises(ValueError, match="rotation matrices"):
        Pose(puppet, np.eye(4), scaled)


def test_skeleton_file_round_trip(puppet, tmp_path):
    for unit in ("m", "mm"):
        path = puppet.save(tmp_path / f"skel_{unit}.json", length_unit=unit)
        back = Skeleton.load(path)
        assert back.names == puppet.names and back.name == puppet.name
        np.testing.assert_allclose(back.offsets, puppet.offsets, atol=1e-12)
        np.testing.assert_array_equal(np.isnan(back.limits_deg), np.isnan(puppet.limits_deg))
        assert json.loads(path.read_text())["length_unit"] == unit
    assert not list(tmp_path.glob(".*"))  # atomic writes leave no temporary files


def _write(tmp_path, joints, name="bad.json"):
    path = tmp_path / name
    path.write_text(json.dumps({"format": "stillcap-skeleton", "length_unit": "mm", "joints": joints}))
    return path


def test_skeleton_file_errors_name_the_joint_and_file(tmp_path):
    p = _write(tmp_path, [{"name": "root", "parent": None}, {"name": "a", "parent": "nobody"}], "unknown.json")
    with pytest.raises(ValueError,
                       match=r"unknown\.json: joints\.1\.parent: joint 'a' has unknown parent 'nobody' \(joint"
                              r"s: root, a\)$"):
        Skeleton.load(p)
    p = _write(tmp_path, [{"name": "root", "parent": None}, {"name": "a", "parent": "b"}, {"name": "b", "parent": "a"}], "cycle.json")
    with pytest.raises(ValueError, match=r"joint 'a' is in a cycle .* in .*cycle\.json"):
        Skeleton.load(p)
    p = _write(tmp_path, [{"name": "root", "parent": None}, {"name": "a", "parent": "root"}, {"name": "a", "parent": "root"}], "dup.json")
    with pytest.raises(ValueError, match=r"dup\.json: joints\.2\.name: duplicate joint name 'a'$"):
        Skeleton.load(p)
    p = _write(tmp_path, [{"name": "root", "parent": None}, {"name": "a", "parent": "root", "offset": [1, 2]}], "offset.json")
    with pytest.raises(ValueError, match=r"offset\.json: joints\.1\.offset\.2: field required$"):
        Skeleton.load(p)
    p = _write(tmp_path, [{"name": "r1", "parent": None}, {"name": "r2", "parent": None}], "roots.json")
    with pytest.raises(ValueError, match="exactly one root"):
        Skeleton.load(p)
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        Skeleton.load(tmp_path / "junk.json")


def test_joint_limits_are_checked():
    with pytest.raises(ValueError, match=r"limits_deg\[y\] of joint 'k' must have min <= max"):
        Joint("k", None, [0, 0, 0], [[0, 1], [5, -5], None])


def test_depth_first_order_puts_parents_first():
    skel = Skeleton((Joint("c", "b", [0, 1, 0]), Joint("b", "a", [0, 1, 0]), Joint("a", None, [0, 0, 0])))
    order = skel.depth_first
    assert [skel.names[i] for i in order] == ["a", "b", "c"]
    np.testing.assert_allclose(skel.rest_pose().positions, [[0, 2, 0], [0, 1, 0], [0, 0, 0]])


def test_forward_kinematics_is_the_joint_by_joint_product_to_the_bit(puppet):
    """The joints of one depth are multiplied in one stacked product: the same numbers as one
    4 x 4 product per joint in depth-first order, for one pose and for a batch, on the puppet
    and a deeper skeleton (the hand's); every joint after its parent's level."""
    from pathlib import Path

    import stillcap

    hand = Skeleton.load(Path(stillcap.__file__).parent / "data" / "hand_skeleton.json")
    rng = np.random.default_rng(3)
    for sk in (puppet, hand):
        levels = sk.depth_levels
        assert sorted(np.concatenate(levels).tolist()) == list(range(sk.n_joints))
        depth = {int(j): d for d, lv in enumerate(levels) for j in lv}
        assert all(sk.parents[j] < 0 or depth[int(sk.parents[j])] == depth[j] - 1 for j in range(sk.n_joints))
        for batch in ((), (3,)):
            local = Rotation.random(int(np.prod(batch, dtype=int)) * sk.n_joints, random_state=rng).as_matrix()
            local = local.reshape(batch + (sk.n_joints, 3, 3))
            r2w = np.eye(4)
            r2w[:3, :3] = Rotation.random(random_state=rng).as_matrix()
            r2w[:3, 3] = rng.normal(0, 1, 3)
            want = np.empty(batch + (sk.n_joints, 4, 4))
            for j in sk.depth_first:
                lt = np.zeros(batch + (4, 4))
                lt[..., :3, :3], lt[..., 3, 3] = local[..., j, :, :], 1.0
                p = sk.parents[j]
                if p >= 0:
                    lt[..., :3, 3] = sk.offsets[j]
                want[..., j, :, :] = (r2w if p < 0 else want[..., p, :, :]) @ lt
            np.testing.assert_array_equal(forward_kinematics(sk, r2w, local), want)
