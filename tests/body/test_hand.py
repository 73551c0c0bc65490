"""The hand model: skeleton and marker-set files, forward kinematics, limits, colour rule,
scaling to a person and fitting the hand to markers."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body import MarkerSet, Pose, Skeleton
from stillcap.body.hand import (BACK_MARKERS, DIGITS, HAND_COLORS, SCALE_GROUPS, fit_hand, hand_dofs,
                                hand_markerset, hand_pose, hand_skeleton, marker_colors, personalise_hand,
                                same_color_min_distance, scale_groups, scale_hand)


@pytest.fixture(scope="module")
def hand():
    return hand_skeleton(), hand_markerset()


def random_angles(skeleton, rng, lo=0.15, hi=0.85):
    lim = skeleton.limits_deg
    u = rng.uniform(lo, hi, lim.shape[:2])
    return np.where(np.isnan(lim[..., 0]), 0.0, lim[..., 0] + u * (lim[..., 1] - lim[..., 0]))


def test_skeleton_structure_and_proportions(hand):
    sk, ms = hand
    assert sk.n_joints == 21 and sk.names[sk.root] == "wrist"
    for d in DIGITS:
        chain = ["thumb-cmc", "thumb-mcp", "thumb-ip", "thumb-tip"] if d == "thumb" else \
            [f"{d}-mcp", f"{d}-pip", f"{d}-dip", f"{d}-tip"]
        parents = [sk.joints[sk.index(j)].parent for j in chain]
        assert parents == ["wrist"] + chain[:-1]
    rest = Pose.rest(sk)
    # adult hand: wrist to middle fingertip 17-21 cm, index shorter than middle, little shortest
    tip = {d: np.linalg.norm(rest.position(f"{d}-tip")) for d in DIGITS[1:]}
    assert 0.17 < tip["middle"] < 0.21 and tip["little"] < tip["ring"] < tip["middle"] and tip["index"] < tip["middle"]
    assert np.all(sk.bone_lengths[sk.parents >= 0] > 0.015)
    # the files round-trip
    ms.check_skeleton(sk)
    assert len(ms) == 18 and set(BACK_MARKERS) <= set(ms.names)


def test_files_round_trip(hand, tmp_path):
    sk, ms = hand
    sk2 = Skeleton.load(sk.save(tmp_path / "h.json", length_unit="mm"))
    ms2 = MarkerSet.load(ms.save(tmp_path / "m.json", length_unit="mm"))
    assert np.allclose(sk2.offsets, sk.offsets) and np.allclose(ms2.offsets, ms.offsets)
    assert marker_colors(ms2) == marker_colors(ms)


def test_rest_pose_forward_kinematics(hand):
    sk, ms = hand
    R = Rotation.from_euler("zyx", [30, -20, 10], degrees=True).as_matrix()
    r2w = np.eye(4)
    r2w[:3, :3], r2w[:3, 3] = R, [0.1, 16.5, 1.7]
    pose = hand_pose(sk, r2w)
    # at rest every joint is its summed offsets, turned and moved by root2world
    rest = np.zeros((sk.n_joints, 3))
    for i in sk.depth_first:
        p = sk.parents[i]
        rest[i] = 0 if p < 0 else rest[p] + sk.offsets[i]
    assert np.allclose(pose.positions, rest @ R.T + r2w[:3, 3])
    # markers sit on the back (dorsal, +z) side of their digit at rest
    pts = ms.positions(Pose(sk, np.eye(4), pose.local_rotations))
    thumb = np.array([n.startswith("thumb") for n in ms.names])
    assert np.all(pts[~thumb, 2] > 0.01)
    u = sk.offsets[sk.index("thumb-mcp")] / np.linalg.norm(sk.offsets[sk.index("thumb-mcp")])
    perp = ms.offsets[thumb] - np.outer(ms.offsets[thumb] @ u, u)  # off the thumb's axis, toward the back
    assert np.all(perp[:, 2] > 0.01)


def test_flexion_curls_toward_the_palm(hand):
    sk, _ = hand
    pose = hand_pose(sk, angles_deg={"index-mcp": (0, 90, 0)})
    d = pose.position("index-pip") - pose.position("index-mcp")
    assert np.allclose(d / np.linalg.norm(d), [0, 0, -1], atol=1e-9)  # palm side is -z
    pose = hand_pose(sk, angles_deg={"index-mcp": (0, 0, 20)})
    assert (pose.position("index-pip") - pose.position("index-mcp"))[1] > 0  # + abduction: toward the thumb


def test_limits_and_degrees_of_freedom(hand):
    sk, _ = hand
    dofs = hand_dofs(sk)
    assert len(dofs) == 21
    lim = sk.limits_deg
    assert np.all(lim[sk.root] == 0)
    assert all(np.all(lim[sk.index(f"{d}-tip")] == 0) for d in DIGITS)  # leaves carry no bone
    for f in DIGITS[1:]:  # PIP and DIP are hinges that flex toward the palm
        for j in ("pip", "dip"):
            i = sk.index(f"{f}-{j}")
            assert [(i, a) in dofs for a in range(3)] == [False, True, False]
            assert lim[i, 1, 1] >= 80
    rng = np.random.default_rng(0)
    for _ in range(20):  # poses drawn inside the limits pass the check, outside fail it
        ang = random_angles(sk, rng, 0.0, 1.0)
        assert not hand_pose(sk, angles_deg=ang).skeleton.limit_violations(hand_pose(sk, angles_deg=ang).local_rotations).any()
    bad = np.zeros((sk.n_joints, 3))
    bad[sk.index("index-pip")] = (0, -20, 0)  # hyperextended PIP
    bad[sk.index("ring-dip")] = (0, 30, 10)  # a DIP bent sideways
    viol = sk.limit_violations(hand_pose(sk, angles_deg=bad).local_rotations)
    assert viol[sk.index("index-pip"), 1] and viol[sk.index("ring-dip"), 2] and viol.sum() == 2


def test_marker_placement_three_per_digit(hand):
    sk, ms = hand
    groups = scale_groups(sk)
    per = {}
    for m in ms.markers:
        g = groups[sk.index(m.bone)]
        per[g] = per.get(g, 0) + 1
    assert per == {"palm": 3, **{d: 3 for d in DIGITS}}
    assert all(abs(m.diameter - 0.010) < 1e-9 for m in ms.markers)


def test_color_rule_four_colors_far_apart(hand):
    sk, ms = hand
    cols = marker_colors(ms)
    assert set(cols) == set(HAND_COLORS) and sorted(np.unique(cols, return_counts=True)[1]) == [4, 4, 5, 5]
    best = same_color_min_distance(ms)
    assert best > 0.035  # the nearest two same-colour markers are 38 mm apart at rest
    # better than any of 2000 random balanced assignments, and no swap of two colours improves it
    rng = np.random.default_rng(1)
    base = np.array(cols)
    for _ in range(2000):
        assert same_color_min_distance(ms, colors=rng.permutation(base)) <= best + 1e-12
    for i, j in itertools.combinations(range(18), 2):
        if base[i] != base[j]:
            c = base.copy()
            c[i], c[j] = c[j], c[i]
            assert same_color_min_distance(ms, colors=c) <= best + 1e-12
    # neighbouring markers on one digit never share a colour; the back of the hand shows three colours
    for d in DIGITS:
        c = [cols[k] for k, n in enumerate(ms.names) if n.startswith(d + ".")]
        assert c[0] != c[1] and c[1] != c[2]
    assert len({cols[ms.index(n)] for n in BACK_MARKERS}) == 3


def test_scale_hand(hand):
    sk, ms = hand
    sk2, ms2 = scale_hand(sk, ms, 1.1)
    assert np.allclose(sk2.offsets, 1.1 * sk.offsets) and np.allclose(ms2.offsets, 1.1 * ms.offsets)
    sk3, _ = scale_hand(sk, ms, {"index": 1.2})
    i, m = sk.index("index-pip"), sk.index("middle-pip")
    assert np.isclose(sk3.bone_lengths[i], 1.2 * sk.bone_lengths[i]) and np.isclose(sk3.bone_lengths[m], sk.bone_lengths[m])
    assert np.isclose(sk3.bone_lengths[sk.index("index-mcp")], sk.bone_lengths[sk.index("index-mcp")])  # palm
    with pytest.raises(ValueError, match="unknown scale groups"):
        scale_hand(sk, ms, {"toe": 1.0})
    with pytest.raises(ValueError, match="> 0"):
        scale_hand(sk, ms, 0.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_personalisation_recovers_scale(hand, seed):
    sk, ms = hand
    rng = np.random.default_rng(seed)
    true = {g: float(rng.uniform(0.88, 1.15)) for g in SCALE_GROUPS}
    sk2, ms2 = scale_hand(sk, ms, true)
    r2w = np.eye(4)
    r2w[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    r2w[:3, 3] = rng.uniform(-1, 1, 3) + [0, 16.5, 1.7]
    ang = random_angles(sk, rng)
    pts = ms2.positions(hand_pose(sk2, r2w, ang))
    fit = personalise_hand(sk, ms, pts)
    assert fit.success and fit.rms < 1e-5
    for g in SCALE_GROUPS:
        assert fit.scales[g] == pytest.approx(true[g], rel=0.01)
    # with 0.5 mm marker noise the scales stay within 2 %
    noisy = pts + rng.normal(0, 0.0005, pts.shape)
    fit = personalise_hand(sk, ms, noisy)
    assert max(abs(fit.scales[g] / true[g] - 1) for g in SCALE_GROUPS) < 0.02


def test_personalise_uniform_scale_from_rest(hand):
    sk, ms = hand
    sk2, ms2 = scale_hand(sk, ms, 1.07)
    fit = personalise_hand(sk, ms, ms2.positions(Pose.rest(sk2)))
    assert all(abs(v - 1.07) < 0.0107 for v in fit.scales.values())
    assert np.allclose(fit.skeleton.offsets, sk2.offsets, atol=2e-4)


def test_fit_hand_recovers_joint_angles_and_handles_unseen(hand):
    sk, ms = hand
    rng = np.random.default_rng(5)
    ang = random_angles(sk, rng)
    r2w = np.eye(4)
    r2w[:3, :3] = Rotation.random(random_state=5).as_matrix()
    pts = ms.positions(hand_pose(sk, r2w, ang))
    fit = fit_hand(sk, ms, pts)
    assert fit.success and np.abs(fit.angles_deg - ang).max() < 0.05
    assert np.allclose(fit.pose.root2world, r2w, atol=1e-5)
    # a finger's nail unseen: the rest still fits, the residual for it is NaN
    pts2 = pts.copy()
    pts2[ms.index("ring.nail")] = np.nan
    fit = fit_hand(sk, ms, dict(zip(ms.names, pts2)))
    assert np.isnan(fit.residuals[ms.index("ring.nail")]) and fit.n_markers == 17 and fit.success
    i = sk.index("index-pip")
    assert abs(fit.angles_deg[i, 1] - ang[i, 1]) < 0.05
    pts2[ms.index("back.2")] = np.nan
    with pytest.raises(ValueError, match="back-of-hand markers"):
        fit_hand(sk, ms, pts2)


def test_fit_hand_weights_let_a_doubtful_marker_bend_the_hand_less(hand):
    """A marker whose centroid is shifted (partly hidden) pulls its joints off; weighted 10x
    less, the joints it shares with good markers stay near the truth."""
    sk, ms = hand
    rng = np.random.default_rng(8)
    ang = random_angles(sk, rng)
    pts = ms.positions(hand_pose(sk, np.eye(4), ang))
    bad = ms.index("index.dip")
    pts[bad] += [0.004, -0.003, 0.002]  # 5.4 mm off
    i = sk.index("index-pip")
    w = np.ones(len(pts))
    w[bad] = 0.1
    plain = abs(fit_hand(sk, ms, pts).angles_deg[i, 1] - ang[i, 1])
    weighted = abs(fit_hand(sk, ms, pts, weights=w).angles_deg[i, 1] - ang[i, 1])
    assert weighted < 0.5 * plain
    with pytest.raises(ValueError, match="weights"):
        fit_hand(sk, ms, pts, weights=np.zeros(len(pts)))
