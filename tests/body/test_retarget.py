"""Retargeting mocap (BVH) poses onto the puppet: bone directions copied within the joint limits."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body import Animation, Joint, Pose, Skeleton
from stillcap.body.retarget import (clamp_to_limits, euler_bounds_deg, resolve_joint_map, retarget_animation,
                                    retarget_pose)
from stillcap.io.bvh_read import read_bvh
from support import shared_data


@pytest.fixture(scope="module")
def puppet():
    return Skeleton.puppet()


def _single_child_bones(skel):
    """Bones whose start joint drives only them (a multi-bone joint is a compromise fit)."""
    return [n for j, n in enumerate(skel.names) if skel.parents[j] >= 0 and len(skel.children(skel.parents[j])) == 1]


@pytest.mark.parametrize("name, frames", [("walk01.bvh", (0, 25, 50, 75, 100)),
                                         ("test_mocapbank.bvh", (0, 100, 200, 300, 454))])
def test_bvh_bone_directions_are_copied(puppet, name, frames):
    anim = read_bvh(shared_data("bvh") / name)
    jmap = resolve_joint_map(anim.skeleton)
    assert set(jmap) == set(puppet.names)  # the default map knows both namings
    single = _single_child_bones(puppet)
    checked = 0
    for k in frames:
        res = retarget_pose(anim[k], puppet)
        pose = res.pose
        assert not puppet.limit_violations(pose.local_rotations).any()
        np.testing.assert_allclose(pose.position("root"), [0, 0.110, 0], atol=1e-12)  # pelvis on the axis
        np.testing.assert_allclose(pose.joint2world[puppet.root, :3, :3], np.eye(3), atol=1e-12)
        # the wanted directions are the BVH's, relative to its pelvis
        src = anim[k]
        R = src.joint2world[src.skeleton.index("Hips"), :3, :3]
        v = src.position(jmap["l-knee"]) - src.position(jmap["l-hip"])
        np.testing.assert_allclose(res.directions["l-knee"], R.T @ v / np.linalg.norm(v), atol=1e-9)
        got = pose.bone_vectors()
        for bone in single:
            if bone not in res.directions or res.at_limit[bone]:
                continue
            d = got[puppet.index(bone)] / np.linalg.norm(got[puppet.index(bone)])
            assert np.degrees(np.arccos(np.clip(d @ res.directions[bone], -1, 1))) < 3.0, (name, k, bone)
            assert res.error_deg[bone] < 3.0
            checked += 1
    assert checked >= 8 * len(frames)  # most limbs are free, not at a limit


def test_keep_root_rotation_copies_the_pelvis(puppet):
    anim = read_bvh(shared_data("bvh") / "walk01.bvh")
    res = retarget_pose(anim[30], puppet, keep_root_rotation=True)
    R_src = anim[30].joint2world[0, :3, :3]
    np.testing.assert_allclose(res.pose.root2world[:3, :3], R_src, atol=1e-9)  # BVH axes = puppet axes here
    np.testing.assert_allclose(res.pose.root2world[:3, 3], [0, 0.110, 0])


def test_retarget_animation_and_rest_pose(puppet):
    # a source skeleton in the puppet's own rest pose, named like a BVH: rest -> rest
    names = {"root": "Hips", "lower-back": "Spine", "upper-back": "Neck", "head": "Head_end"}
    for side, s in (("l", "Left"), ("r", "Right")):
        names.update({f"{side}-hip": f"{s}UpLeg", f"{side}-knee": f"{s}Leg", f"{side}-foot": f"{s}Foot",
                      f"{side}-toes": f"{s}Foot_end", f"{side}-shoulder": f"{s}Arm",
                      f"{side}-elbow": f"{s}ForeArm", f"{side}-hand": f"{s}Hand", f"{side}-finger": f"{s}Hand_end"})
    src = Skeleton(tuple(Joint(names[j.name], None if j.parent is None else names[j.parent], 2 * j.offset)
                         for j in puppet.joints), name="twice")
    res = retarget_pose(Pose.rest(src), puppet)
    np.testing.assert_allclose(res.pose.local_rotations, np.tile(np.eye(3), (puppet.n_joints, 1, 1)), atol=1e-6)
    # bend the source's left elbow by 60 degrees: the puppet's follows
    local = np.tile(np.eye(3), (src.n_joints, 1, 1))
    local[src.index("LeftForeArm")] = Rotation.from_euler("y", -60, degrees=True).as_matrix()
    rest = np.tile(np.eye(3), (src.n_joints, 1, 1))
    source = Animation(src, [0.0, 0.1], np.tile(src.rest_root2world(), (2, 1, 1)), np.stack([rest, local]))
    anim = retarget_animation(source, puppet)
    assert anim.n_frames == 2 and anim.skeleton is puppet
    fore = anim[1].bone_vectors()[puppet.index("l-hand")]
    np.testing.assert_allclose(fore / np.linalg.norm(fore), [0.5, 0, np.sqrt(3) / 2], atol=1e-6)


def test_clamp_to_limits(puppet):
    rng = np.random.default_rng(0)
    rots = Rotation.random(puppet.n_joints, random_state=rng).as_matrix()
    assert puppet.limit_violations(rots).any()
    clamped = clamp_to_limits(puppet, rots)
    assert not puppet.limit_violations(clamped).any()
    b = euler_bounds_deg(puppet)
    assert b.shape == (puppet.n_joints, 3, 2) and np.all(np.abs(b[:, 1]) <= 89.5)
    with pytest.raises(ValueError, match="local_rotations must have shape"):
        clamp_to_limits(puppet, rots[:3])


def test_joint_map_errors(puppet):
    src = Skeleton((Joint("Hips", None, [0, 1, 0]), Joint("Foo", "Hips", [0, 1, 0])), name="tiny")
    with pytest.raises(ValueError, match="source joint 'Bar'"):
        resolve_joint_map(src, {"head": "Bar"})
    with pytest.raises(ValueError, match="target joint 'tail'"):
        resolve_joint_map(src, {"tail": "Foo"})
    with pytest.raises(ValueError, match="could map only"):
        retarget_pose(Pose.rest(src), puppet)
    # a user map makes it work, and can switch a default entry off
    m = resolve_joint_map(src, {"upper-back": "Foo", "l-hip": None})
    assert m == {"root": "Hips", "upper-back": "Foo"}
