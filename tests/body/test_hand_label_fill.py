"""Labels filled in after the first pass (issue 12, stillcap.body.hand_label_fill): flashes
without a back-of-hand triplet posed from their other markers and a neighbour's pose, points the
gate did not reach labelled when only one marker can be theirs, ambiguous points left alone."""

from functools import lru_cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body.hand import fit_hand, hand_markerset, hand_skeleton
from stillcap.body.hand_checks import hand_self_checks
from stillcap.body.hand_label import GATE_M, flashes_at_one_place, hand_points_from_truth, label_hand_markers
from stillcap.body.hand_label_fill import LEFTOVER_GATE_FACTOR, label_recovered, predicted_missing
from stillcap.body.skeleton import Pose
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand


@lru_cache(maxsize=None)
def truth(seed, person_seed=None):
    person = None if person_seed is None else another_hand(person_seed)
    return hand_capture(seed, image_size=(320, 240), supersample=1, person=person).truth


def wrong_and_missing(lab, d):
    """(labels given that are wrong, real points left unlabelled, real points)."""
    lp = lab.labels()
    fmap = []
    for mem in lab.members:
        f = d["flash"][mem]
        f = f[f >= 0]
        fmap.append(int(np.bincount(f).argmax()) if len(f) else -1)
    given = lp[:, 0] >= 0
    wrong = sum(1 for i in np.flatnonzero(given)
                if fmap[lp[i, 0]] != d["flash"][i] or lp[i, 1] != d["marker"][i])
    real = d["flash"] >= 0
    return wrong, int((real & ~given).sum()), int(real.sum())


def without_back2(seed):
    """Points of the default hand with back.2 taken out of the second flash that has all three."""
    tr = truth(seed)
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=0, rng=1)
    ok = [k for k in range(tr.n) if all(((d["flash"] == k) & (d["marker"] == b)).any() for b in range(3))]
    keep = ~((d["flash"] == ok[1]) & (d["marker"] == 1))
    return {key: v[keep] for key, v in d.items()}, ok[1]


def test_flash_without_triplet_is_posed_from_its_neighbours():
    d, k = without_back2(3)
    first = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, fill=False)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    assert (~first.reconstructed).sum() == 1  # the first pass alone loses the flash
    assert lab.reconstructed.all() and lab.pose_source.count("neighbours") == 1
    j = lab.pose_source.index("neighbours")
    assert lab.skipped[j] == "" and lab.rms[j] < 0.0015
    wrong, missing, _ = wrong_and_missing(lab, d)
    assert wrong == 0
    _, missing_first, _ = wrong_and_missing(first, d)
    assert missing < missing_first
    # its pose is the true one: the fitted markers sit on the true ones where the flash shows them
    # (a digit without a seen marker keeps the neighbour's angles: not observable)
    tr = truth(3)
    f = int(np.bincount(d["flash"][lab.members[j]]).argmax())
    assert f == k
    fitted = lab.markerset.positions(lab.fits[j].pose)
    seen = lab.point_index[j] >= 0
    assert np.sqrt(np.mean(np.sum((fitted[seen] - tr.markers[f][seen]) ** 2, axis=1))) < 0.002
    assert np.linalg.norm(lab.fits[j].pose.root2world[:3, 3] - tr.root2world[f][:3, 3]) < 0.005
    assert lab.to_dict()["pose_source"] == lab.pose_source


def test_self_check_names_flashes_without_pose():
    d, _ = without_back2(3)
    first = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, fill=False)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    c0 = next(c for c in hand_self_checks(first, None, noise_m=0.0003) if c.name == "flashes_without_pose")
    c1 = next(c for c in hand_self_checks(lab, None, noise_m=0.0003) if c.name == "flashes_without_pose")
    assert not c0.passed and "no back-of-hand triplet" in c0.message and c0.value > 0.05
    assert c1.passed and c1.value == 0 and "from their other markers" in c1.message


@pytest.mark.parametrize("person_seed", [11, 12])
def test_another_hand_labelled_as_the_goal_asks(person_seed):
    """Another person's hand (own size and proportions): >= 95 % of the markers seen twice get a
    label and none is wrong (the first pass alone labelled 58-89 % on such hands)."""
    tr = truth(person_seed, person_seed)
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=3, rng=person_seed)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz)
    wrong, missing, real = wrong_and_missing(lab, d)
    assert wrong == 0
    assert 1 - missing / real >= 0.95, (missing, real, lab.skipped)


def test_false_back_of_hand_triplet_is_rejected_and_never_silent():
    """Hand 11's first flash: its back-of-hand markers unseen, three finger markers (ring.pip,
    ring.dip, little.nail) pass as a back-of-hand triplet. Kept, that false hand labels its points
    wrong and a second hand is posed from the rest of the same flash; the self-check
    flashes_at_one_place names it. By default the labeller labels again without it."""
    tr = truth(11, 11)
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=3, rng=11)
    kept = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz, reject_false_triplets=False)
    wrong, _, _ = wrong_and_missing(kept, d)
    assert wrong > 0  # the false hand is there to catch
    pairs = flashes_at_one_place(kept)
    assert pairs
    c = next(c for c in hand_self_checks(kept, None, noise_m=0.0003) if c.name == "flashes_at_one_place")
    assert not c.passed and c.value == len(pairs) and "false back-of-hand triplet" in c.message
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz)
    assert wrong_and_missing(lab, d)[0] == 0 and flashes_at_one_place(lab) == []
    c = next(c for c in hand_self_checks(lab, None, noise_m=0.0003) if c.name == "flashes_at_one_place")
    assert c.passed
    # every flash found is a true flash, in time order, one strobe period apart
    firsts = [int(np.bincount(d["flash"][m]).argmax()) for m in lab.members]
    assert firsts == list(range(tr.n)) and np.allclose(lab.times, np.arange(tr.n) / tr.strobe_hz)
    # its first flash is at the true hand's place (the false hand was 5 cm off)
    assert np.linalg.norm(lab.fits[0].pose.root2world[:3, 3] - tr.root2world[0][:3, 3]) < 0.03


def test_flashes_of_right_labels_are_not_at_one_place():
    """On the default hand no posed hand explains another flash's points (the check cannot be
    failing everywhere)."""
    tr = truth(3)
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=3, rng=3)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    assert lab.reconstructed.sum() >= 3 and flashes_at_one_place(lab) == []


def _displaced():
    """Default hand, its index.pip points moved 12 mm (past the 8 mm gate, within the second
    pass's 20 mm) the same way in the hand frame in every flash, as a finger of other proportions
    would put them, away from every other marker of their colour."""
    tr = truth(0)
    d = hand_points_from_truth(tr, noise_m=0.0002, drop=0.0, n_spurious=0, rng=2)
    ms = hand_markerset()
    m = ms.index("index.pip")
    cols = np.array(tr.marker_colors)
    rows = np.flatnonzero(d["marker"] == m)
    axes = np.vstack([np.eye(3), -np.eye(3)])

    def shift(i, a):
        return tr.root2world[d["flash"][i]][:3, :3] @ (0.012 * a)

    def far(a):
        return min(np.linalg.norm(tr.markers[d["flash"][i], (cols == cols[m]) & (np.arange(len(cols)) != m)]
                                  - (d["points"][i] + shift(i, a)), axis=1).min() for i in rows)

    a = axes[int(np.argmax([far(a) for a in axes]))]
    return d, rows, m, np.array([shift(i, a) for i in rows])


def test_unreached_points_labelled_when_only_one_marker_can_be_them():
    assert 0.012 < LEFTOVER_GATE_FACTOR * GATE_M
    d, rows, m, sh = _displaced()
    d["points"][rows] += sh
    first = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, fill=False)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    assert np.sum(first.labels()[rows, 1] == -1) >= 2  # the gate does not reach them (a fit may bend to one)
    assert np.all(lab.labels()[rows, 1] == m)


def test_stray_point_near_a_missing_marker_stays_unlabelled():
    """One flash alone shows a point 12 mm off: no other flash misses the marker that way (the
    stray point that took a dropped marker's label)."""
    d, rows, m, sh = _displaced()
    d["points"][rows[0]] += sh[0]
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    assert lab.labels()[rows[0], 1] == -1 and rows[0] in lab.unassigned


def test_two_candidates_within_the_gate_leave_both_unlabelled():
    d, rows, m, sh = _displaced()
    d["points"][rows] += sh
    i = rows[0]
    a = sh[0] / np.linalg.norm(sh[0])
    side = np.cross(a, [1.0, 1.0, 1.0])
    extra = d["points"][i] - sh[0] + 0.012 * side / np.linalg.norm(side)
    d = {"points": np.vstack([d["points"], extra]), "colours": np.append(d["colours"], d["colours"][i]),
         "flash": np.append(d["flash"], -1), "marker": np.append(d["marker"], -1)}
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    n = len(d["points"]) - 1
    assert lab.labels()[i, 1] == -1 and lab.labels()[n, 1] == -1
    assert i in lab.unassigned and n in lab.unassigned


def test_fit_hand_without_a_back_marker_from_an_initial_pose():
    sk, ms = hand_skeleton(), hand_markerset()
    rng = np.random.default_rng(4)
    ang = np.zeros((sk.n_joints, 3))
    ang[:, 1] = rng.uniform(5, 30, sk.n_joints)
    r2w = np.eye(4)
    r2w[:3, :3] = Rotation.from_euler("xyz", [20, -30, 50], degrees=True).as_matrix()
    r2w[:3, 3] = [0.1, 16.5, 1.6]
    true = Pose(sk, r2w, Rotation.from_euler("XYZ", np.radians(sk.limit_angles_deg(
        Rotation.from_euler("XYZ", ang, degrees=True).as_matrix()))).as_matrix())
    pts = ms.positions(true)
    pts[ms.index("back.2")] = np.nan
    with pytest.raises(ValueError, match="back-of-hand"):
        fit_hand(sk, ms, pts)
    start = np.eye(4)
    start[:3, :3] = Rotation.from_euler("xyz", [3, -2, 4], degrees=True).as_matrix() @ r2w[:3, :3]
    start[:3, 3] = r2w[:3, 3] + [0.004, -0.003, 0.002]
    fit = fit_hand(sk, ms, pts, initial=Pose(sk, start, true.local_rotations))
    assert fit.success and fit.rms < 1e-4
    assert np.linalg.norm(fit.pose.root2world[:3, 3] - r2w[:3, 3]) < 1e-3


def _neighbour_posed(person):
    """Seed 100's throw (its first flash shows no back-of-hand marker to two cameras): labels, the
    sequence and the joint-angle error of each flash on the degrees of freedom its markers fix."""
    from stillcap.body.hand_track import fit_hand_sequence, observed_dofs

    tr = hand_capture(100, image_size=(320, 240), supersample=1, person=person).truth
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=3, rng=100)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz)
    seq = fit_hand_sequence(lab)
    err = {}
    for i, k in enumerate(seq.flashes):
        f = int(np.bincount(d["flash"][lab.members[k]][d["flash"][lab.members[k]] >= 0]).argmax())
        e = [seq.angles_deg[i, j, a] - tr.angles_deg[f, j, a] for j, a in observed_dofs(seq, i)]
        err[lab.pose_source[k]] = err.get(lab.pose_source[k], []) + e
    return lab, seq, {s: float(np.sqrt(np.mean(np.square(v)))) for s, v in err.items()}


def test_pose_without_back_markers_is_flagged_when_the_model_misfits():
    """Issue 12: joint angles rose on hands unlike the model when the fill began posing flashes
    without their back-of-hand markers. Verified per flash: the rise is all in those flashes (their
    palm rests on the finger markers and the model; a fit from the true pose ends in the same
    place, so no local minimum); with the model's own hand they are as good as the others. The
    self-check says so when the model misfits, and only then."""
    lab, seq, rms = _neighbour_posed(another_hand(100))
    assert "neighbours" in lab.pose_source
    assert rms["neighbours"] > 1.3 * rms["triplet"]  # measured: 14.0 against 7.5 deg
    c = next(c for c in hand_self_checks(lab, seq, noise_m=0.0003) if c.name == "pose_without_back")
    assert not c.passed and c.value >= 1 and "joint angles are not measured" in c.message
    lab, seq, rms = _neighbour_posed(None)  # the model's own hand: the filled flash holds
    assert "neighbours" in lab.pose_source and rms["neighbours"] < 2.0  # measured: 1.37 deg
    c = next(c for c in hand_self_checks(lab, seq, noise_m=0.0003) if c.name == "pose_without_back")
    assert c.passed and "joint angles hold" in c.message


# ---- markers found again where the posed hand predicts them (label_recovered) -------------------
def one_marker_taken_out(seed=3):
    """Points of the default hand labelled without one finger point, which is returned apart:
    ``(labels, the point, its true marker, its flash in the labels)``."""
    tr = truth(seed)
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=0, rng=1)
    full = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    names = full.marker_names
    m = names.index("middle.pip")
    k = int(np.flatnonzero((full.point_index[:, m] >= 0) & full.reconstructed)[0])
    p = int(full.point_index[k, m])
    keep = np.arange(len(d["points"])) != p
    lab = label_hand_markers(d["points"][keep], d["colours"][keep], strobe_hz=75.0)
    j = int(np.argmin([np.nanmin(np.linalg.norm(lab.positions[q] - full.positions[k][None], axis=-1))
                       for q in range(lab.n_flashes)]))
    return lab, d["points"][p], str(d["colours"][p]), m, j


def test_a_point_found_where_the_hand_predicts_its_marker_is_labelled():
    lab, X, colour, m, k = one_marker_taken_out()
    assert lab.point_index[k, m] < 0
    flash, marker, pred = predicted_missing(lab)
    i = int(np.flatnonzero((flash == k) & (marker == m))[0])
    assert np.linalg.norm(pred[i] - X) < GATE_M
    pts = np.concatenate([lab.points, X[None]])
    cols = np.concatenate([lab.colors, [colour]])
    out = label_recovered(lab, pts, cols, [(len(pts) - 1, k, m)], gate_m=GATE_M, predicted=pred[i:i + 1])
    assert out.point_index[k, m] == len(pts) - 1
    assert np.allclose(out.positions[k, m], X) and len(out.points) == len(pts)
    assert (out.point_index >= 0).sum() == (lab.point_index >= 0).sum() + 1
    assert out.rms[k] < 0.0015 and len(out.points) - 1 not in out.unassigned


def test_a_point_claimed_for_the_wrong_marker_or_flash_stays_unlabelled():
    lab, X, colour, m, k = one_marker_taken_out()
    pts = np.concatenate([lab.points, X[None]])
    cols = np.concatenate([lab.colors, [colour]])
    p = len(pts) - 1
    other = next(q for q in range(lab.n_flashes) if q != k and lab.fits[q] is not None)
    out = label_recovered(lab, pts, cols, [(p, other, m)], gate_m=GATE_M)  # another flash's marker: far away
    assert (out.point_index == p).sum() == 0
    # a confirmed point (3+ views) may be farther from its prediction, but not beyond the wider gate
    far = X + [0.0, 0.0, 2.6 * GATE_M]
    out = label_recovered(lab, np.concatenate([lab.points, far[None]]), cols, [(p, k, m)], gate_m=GATE_M,
                          predicted=[X], confirmed=np.arange(len(pts)) == p)
    assert (out.point_index == p).sum() == 0


def test_an_unconfirmed_point_alone_on_its_digit_stays_unlabelled():
    lab, X, colour, m, k = one_marker_taken_out()
    digit = [j for j, n in enumerate(lab.marker_names) if n.startswith("middle.")]
    lab.point_index[k, digit] = -1  # the digit's other markers unlabelled too
    pts = np.concatenate([lab.points, X[None]])
    cols = np.concatenate([lab.colors, [colour]])
    p = len(pts) - 1
    unconfirmed = np.arange(len(pts)) == p
    out = label_recovered(lab, pts, cols, [(p, k, m)], gate_m=GATE_M, predicted=[X], unconfirmed=unconfirmed)
    assert out.point_index[k, m] < 0
    out = label_recovered(lab, pts, cols, [(p, k, m)], gate_m=GATE_M, predicted=[X])
    assert out.point_index[k, m] == p


def test_two_proposals_for_one_point_leave_it_unlabelled():
    lab, X, colour, m, k = one_marker_taken_out()
    pts = np.concatenate([lab.points, X[None]])
    cols = np.concatenate([lab.colors, [colour]])
    p = len(pts) - 1
    out = label_recovered(lab, pts, cols, [(p, k, m), (p, k, m)], gate_m=GATE_M, predicted=[X, X])
    assert out.point_index[k, m] < 0


def test_a_confirmed_point_beyond_the_gate_needs_its_digit_fixed_by_other_labels():
    """A point three cameras agree on may be up to 2.5 gates from its prediction (a model of
    other proportions), but only when its digit's other markers are labelled in that flash: a
    digit without labels is wherever the fit left it, no evidence for a prediction."""
    lab, X, colour, m, k = one_marker_taken_out()
    R = lab.fits[k].pose.joint2world[lab.markerset.bone_frames(lab.skeleton)[m], :3, :3]
    far = X + R @ [0.0, 0.0, 1.3 * GATE_M]  # beyond the gate, off the bone
    pts = np.concatenate([lab.points, far[None]])
    cols = np.concatenate([lab.colors, [colour]])
    p = len(pts) - 1
    confirmed = np.arange(len(pts)) == p
    out = label_recovered(lab, pts, cols, [(p, k, m)], gate_m=GATE_M, predicted=[X], confirmed=confirmed)
    assert out.point_index[k, m] == p
    out = label_recovered(lab, pts, cols, [(p, k, m)], gate_m=GATE_M, predicted=[X])  # two views: the gate
    assert out.point_index[k, m] < 0
    digit = [j for j, n in enumerate(lab.marker_names) if n.startswith("middle.") and j != m]
    lab.point_index[k, digit] = -1
    out = label_recovered(lab, pts, cols, [(p, k, m)], gate_m=GATE_M, predicted=[X], confirmed=confirmed)
    assert out.point_index[k, m] < 0


def _first_flash_of_hand_8(seed):
    """Points of another person's hand (studio hand 8, as ``bench_hand_matching.py`` renders it) with
    the first flash showing the ten markers the rendered capture gives (``back.2`` seen by one
    camera only: no back-of-hand triplet), the other flashes every marker seen twice."""
    tr = truth(8, 8)
    names = list(tr.marker_names)
    first = [names.index(n) for n in ("back.1", "back.3", "thumb.mcp", "thumb.ip", "thumb.nail", "middle.pip",
                                      "ring.nail", "little.pip", "little.dip", "little.nail")]
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=0, rng=seed)
    keep = (d["flash"] != 0) | np.isin(d["marker"], first)
    mp = names.index("middle.pip")  # seen by one camera in the truth; the capture's 3D stage had it
    extra = tr.markers[0, mp] + np.random.default_rng(seed).normal(0, 0.0003, 3)
    return {"points": np.concatenate([d["points"][keep], extra[None]]),
            "colours": np.concatenate([d["colours"][keep], [tr.marker_colors[mp]]]),
            "flash": np.append(d["flash"][keep], 0), "marker": np.append(d["marker"][keep], mp)}


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_rival_labellings_that_bend_the_hand_more_do_not_compete(seed):
    # issue 12: on studio hand 8 with its own model the first flash got no pose: its rivals, two
    # markers fewer, disagreed with the right labelling; they bend the hand 2-9 times as much
    # from the neighbouring flash as it does
    d = _first_flash_of_hand_8(seed)
    v = another_hand(8)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, skeleton=v.skeleton, markerset=v.markerset)
    assert lab.reconstructed.all() and lab.pose_source[0] == "neighbours"
    wrong, _, _ = wrong_and_missing(lab, d)
    assert wrong == 0
    assert (lab.point_index[0] >= 0).sum() >= 8  # the flash's ten points, both back markers among them


@pytest.mark.xfail(strict=True, reason=(
    "open (issue 12, hand): this scenario was built on main's studio, whose held ball sat inside the "
    "glove; with the ball seated clear of it (studio.hand_grip) hand 8's hand path changed and the "
    "rivals no longer block the flash even without SHAPE_RATIO, so the scenario no longer shows the "
    "rule is needed: a new one must be found"))
@pytest.mark.parametrize("seed", [0, 2, 3])
def test_without_the_rule_the_rivals_lose_the_flash(seed, monkeypatch):
    import stillcap.body.hand_label_fill as fill

    d = _first_flash_of_hand_8(seed)
    v = another_hand(8)
    monkeypatch.setattr(fill, "SHAPE_RATIO", np.inf)  # every rival competes: the flash is lost
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, skeleton=v.skeleton, markerset=v.markerset)
    assert not lab.reconstructed[0] and "competing labellings" in lab.skipped[0]


def test_shape_change_is_the_rms_of_the_angle_differences():
    from stillcap.body.hand_label_fill import shape_change_deg

    a = np.zeros((4, 3))
    b = a.copy()
    b[0, 1] = 12.0
    assert shape_change_deg(b, a) == pytest.approx(np.sqrt(144 / 12))
    assert shape_change_deg(a, a) == 0.0


def test_back_of_hand_points_are_confirmed_by_the_captures_own_back_triangle():
    """Issue 12 (studio hand 12, built-in model): in a flash posed without its triplet the fitted
    root was 10 mm off, and a partly hidden back.3 lay 9.6 mm from its prediction, beyond the
    gate, though 0.2 mm from its side to back.1 as the other flashes measure it. A back-of-hand
    point at the capture's own sides (within the tolerance) from its flash's other back-of-hand
    points is confirmed; one 8 mm off the side, a finger marker, or a capture without a whole
    triplet to measure the sides on are not."""
    from types import SimpleNamespace

    from stillcap.body.hand_label import TRIANGLE_TOL_M
    from stillcap.body.hand_label_fill import on_back_triangle

    ms = hand_markerset()
    names = list(ms.names)
    X = ms.positions(hand_skeleton().rest_pose())
    b1, b2, b3, ip = (names.index(n) for n in ("back.1", "back.2", "back.3", "index.pip"))
    rng = np.random.default_rng(0)
    pts, pi = [], np.full((5, len(names)), -1)
    for k in range(3):  # flashes with a whole triplet, the hand turned and moved
        R = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
        for m in (b1, b2, b3):
            pi[k, m] = len(pts)
            pts.append(R @ X[m] + rng.normal(0, 0.05, 3))
    R = Rotation.from_rotvec([0.3, -0.2, 0.4]).as_matrix()
    t = np.array([0.1, 0.2, 0.0])
    pi[3, b1] = len(pts)
    pts.append(R @ X[b1] + t)  # flash 3: back.1 labelled; back.2/back.3 proposed
    along = (X[b3] - X[b1]) / np.linalg.norm(X[b3] - X[b1])
    right, off, finger = len(pts), len(pts) + 1, len(pts) + 2
    pts += [R @ X[b3] + t + R @ np.array([0.0, 0.0, 0.002]), R @ (X[b3] + 0.008 * along) + t, R @ X[ip] + t]
    pair = len(pts)  # flash 4: no back-of-hand label; back.1 and back.3 both proposed
    pts += [X[b1] - 0.3, X[b3] - 0.3]
    pts = np.array(pts)
    labels = SimpleNamespace(marker_names=names, point_index=pi)
    props = [(right, 3, b3), (off, 3, b3), (finger, 3, ip), (pair, 4, b1), (pair + 1, 4, b3)]
    tol = TRIANGLE_TOL_M
    # one proposal at a time (two proposals of one marker in a flash are each other's no partner)
    got = [bool(on_back_triangle(labels, pts, [p], tol_m=tol)[0]) for p in props[:3]]
    assert got == [True, False, False]
    assert on_back_triangle(labels, pts, props[3:], tol_m=tol).tolist() == [True, True]
    assert not on_back_triangle(labels, pts, [props[3]], tol_m=tol).any()  # no partner in its flash
    unconfirmed = np.zeros(len(pts), bool)
    unconfirmed[pi[:3, b2]] = True  # no whole triplet: no sides measured
    assert not on_back_triangle(labels, pts, props, unconfirmed=unconfirmed, tol_m=tol).any()
