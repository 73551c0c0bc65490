"""Posing from markers: rotations between directions, rigid alignment, the thesis's rules."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body import (
    Marker,
    MarkerSet,
    Pose,
    Skeleton,
    bone_directions,
    pose_from_bone_directions,
    pose_from_markers,
    rigid_alignment,
    rotation_between,
)


@pytest.fixture(scope="module")
def puppet():
    return Skeleton.puppet(), MarkerSet.puppet()


def deg(axis, angle):
    return Rotation.from_euler(axis, angle, degrees=True).as_matrix()


def posed(skel, rotations: dict, root2world=None):
    local = np.tile(np.eye(3), (skel.n_joints, 1, 1))
    for name, r in rotations.items():
        local[skel.index(name)] = r
    return Pose(skel, skel.rest_root2world() if root2world is None else root2world, local)


def test_rotation_between_is_minimal():
    r = rotation_between([0, 1, 0], [1, 0, 0])
    np.testing.assert_allclose(r.apply([0, 1, 0]), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r.as_rotvec(), [0, 0, -np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(rotation_between([0, 0, 2], [0, 0, 5]).as_matrix(), np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="non-zero"):
        rotation_between([0, 0, 0], [1, 0, 0])


def test_rigid_alignment_recovers_a_known_transform_ignoring_nan():
    rng = np.random.default_rng(1)
    model = rng.normal(scale=0.02, size=(5, 3))
    rot = Rotation.from_rotvec([0.3, -1.2, 0.5])
    t = np.array([0.1, 0.2, -0.3])
    meas = rot.apply(model) + t
    meas[2] = np.nan
    fit = rigid_alignment(model, meas)
    assert fit.n_points == 4 and fit.rmsd < 1e-12
    np.testing.assert_allclose(fit.rotation.as_matrix(), rot.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(fit.model2world[:3, 3], t, atol=1e-12)
    with pytest.raises(ValueError, match="3\\+ finite point pairs, got 2"):
        rigid_alignment(model[:3], np.vstack([meas[:2], [np.nan] * 3]))
    with pytest.raises(ValueError, match="collinear"):
        rigid_alignment([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 0, 0], [0, 1, 0], [0, 2, 0]])
    with pytest.raises(ValueError, match=r"measured_points must have shape \(5, 3\), got \(4, 3\)"):
        rigid_alignment(model, meas[:4])


def test_rest_markers_give_the_rest_pose(puppet):
    skel, ms = puppet
    rest = skel.rest_pose()
    pose = pose_from_markers(skel, ms, ms.positions(rest))
    np.testing.assert_allclose(pose.positions, rest.positions, atol=1e-12)
    np.testing.assert_allclose(pose.local_rotations, rest.local_rotations, atol=1e-12)


def test_turned_puppet_is_recovered_exactly(puppet):
    """The turntable turns the whole figure: the rules' axes follow the root frame."""
    skel, ms = puppet
    r2w = skel.rest_root2world()
    r2w[:3, :3] = deg("y", 120)
    truth = Pose.rest(skel, r2w)
    pose = pose_from_markers(skel, ms, ms.positions(truth), root2world=r2w)
    np.testing.assert_allclose(pose.positions, truth.positions, atol=1e-12)


def test_limb_poses_from_markers(puppet):
    """Swinging limbs and bending elbows and knees about their hinge axes is recovered exactly
    (the shared elbow/knee bead sits on the hinge axis); a bend off the hinge axis moves that bead
    off the lower bone's line, a few millimetres of error (the thesis's method cannot do better)."""
    skel, ms = puppet
    swing = {
        "l-shoulder": deg("z", -70), "r-shoulder": deg("zy", [60, 30]),
        "l-hip": deg("x", -40), "r-hip": deg("x", 20), "lower-back": deg("x", 25),
        "l-elbow": deg("y", -60), "r-knee": deg("x", 50), "l-knee": deg("x", 90),
    }  # fmt: skip
    truth = posed(skel, swing)
    got = pose_from_markers(skel, ms, ms.positions(truth))
    np.testing.assert_allclose(got.positions, truth.positions, atol=1e-9)
    off_axis = posed(skel, {**swing, "r-elbow": deg("z", 40)})
    got = pose_from_markers(skel, ms, ms.positions(off_axis))
    err = np.linalg.norm(got.positions - off_axis.positions, axis=1)
    assert 1e-4 < err.max() < 0.006
    assert err[skel.index("r-elbow")] < 1e-9  # the upper arm is exact


def test_head_nods_about_the_shoulder_line(puppet):
    """Head and shoulders share the upper-back joint: the shoulder line (primary rule) is kept
    exactly and the head's nod is fitted about it."""
    skel, ms = puppet
    truth = posed(skel, {"lower-back": deg("x", 20)})
    markers = dict(zip(ms.names, ms.positions(truth)))
    head_axis = truth.joint2world[skel.index("upper-back"), :3, :3]
    nod = head_axis @ deg("x", 25) @ head_axis.T  # tilt the head forward by 25 degrees about its x
    ub = truth.position("upper-back")
    for name in ("head.1", "head.2"):
        markers[name] = ub + nod @ (markers[name] - ub)
    got = pose_from_markers(skel, ms, markers)
    dirs = bone_directions(ms, markers)
    head_vec = got.bone_vectors()[skel.index("head")]
    np.testing.assert_allclose(head_vec / np.linalg.norm(head_vec), dirs["head"], atol=1e-9)
    for side in ("l-shoulder", "r-shoulder"):
        np.testing.assert_allclose(got.position(side), truth.position(side), atol=1e-9)


def test_missing_markers_leave_joints_at_rest_relative_to_parent(puppet):
    skel, ms = puppet
    truth = posed(skel, {"l-shoulder": deg("z", -70)})
    pts = ms.positions(truth)
    pts[ms.index("arm.L1")] = np.nan
    got = pose_from_markers(skel, ms, pts)
    np.testing.assert_allclose(got.local_rotations[skel.index("l-shoulder")], np.eye(3), atol=1e-12)
    assert np.isnan(bone_directions(ms, pts)["l-elbow"]).all()


def test_three_markers_on_a_segment_give_its_twist():
    """Rigid alignment of 3+ markers on one segment recovers the rotation about the bone (twist)."""
    skel = Skeleton.puppet()
    ms = MarkerSet(
        tuple(
            Marker(f"fa{i}", "l-hand", off)
            for i, off in enumerate([[0.005, 0, 0.007], [0.025, 0, 0.007], [0.015, 0.006, 0]])
        )
    )
    truth = posed(skel, {"l-elbow": deg("x", 50) @ deg("y", -30)})
    got = pose_from_markers(skel, ms, ms.positions(truth))
    np.testing.assert_allclose(got.joint2world[skel.index("l-elbow")], truth.joint2world[skel.index("l-elbow")], atol=1e-12)


def test_weights_allow_only_one_exact_bone_per_joint(puppet):
    skel, _ = puppet
    dirs = {"l-shoulder": [1, 0, 0], "r-shoulder": [-1, 0, 0]}
    with pytest.raises(ValueError, match="at most one bone"):
        pose_from_bone_directions(skel, dirs, weights={"l-shoulder": math.inf, "r-shoulder": math.inf})
    with pytest.raises(ValueError, match="unknown joint 'nose'"):
        pose_from_bone_directions(skel, {"nose": [0, 1, 0]})


def test_normalised_one_vector_equals_the_batched_form():
    # normalised's fast path for one (3,) vector gives the numbers of its array path, bit for bit
    # (the length summed in np.linalg.norm's order), NaN for zero, tiny or NaN vectors
    from stillcap.body.kinematics import normalised

    rng = np.random.default_rng(5)
    vs = rng.normal(size=(20000, 3)) * 10.0 ** rng.uniform(-14, 3, (20000, 1))
    batched = normalised(vs)
    one = np.array([normalised(v) for v in vs])
    assert np.array_equal(one, batched, equal_nan=True)
    assert np.isnan(batched).any() and np.isfinite(batched).any()  # both branches met
    for v in ([0.0, 0.0, 0.0], [np.nan, 1.0, 2.0], [1e-13, 0.0, 0.0]):
        assert np.all(np.isnan(normalised(v)))
    assert np.array_equal(normalised([3.0, 0.0, 4.0]), [0.6, 0.0, 0.8])
