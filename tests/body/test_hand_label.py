"""Automatic labelling of hand markers: flashes, time order, labels and manual overrides, from
the studio's truth (points made by ``hand_points_from_truth``: visible markers, noise, dropouts,
spurious points, shuffled)."""

import json
from functools import lru_cache

import numpy as np
import pytest

from stillcap.body.hand import BACK_MARKERS
from stillcap.body.hand_label import (LabelOverride, apply_label_overrides, hand_points_from_truth,
                                      label_hand_markers, read_label_overrides)
from stillcap.studio.hand import hand_capture

SEEDS = (0, 1, 2, 3)


@lru_cache(maxsize=None)
def truth(seed):
    return hand_capture(seed, image_size=(320, 240), supersample=1).truth


def true_flash_of(labels, data):
    """The truth flash each found flash holds most points of (-1 if none)."""
    out = []
    for mem in labels.members:
        f = data["flash"][mem]
        f = f[f >= 0]
        out.append(int(np.bincount(f).argmax()) if len(f) else -1)
    return np.array(out)


def score(labels, data):
    """(right, total, wrong, given): points of flashes whose back triplet is among the points."""
    n_truth = data["flash"].max() + 1
    has_back = np.array([all(((data["flash"] == k) & (data["marker"] == b)).any() for b in range(3))
                         for k in range(n_truth)])
    fmap = true_flash_of(labels, data)
    lab = labels.labels()
    ok = np.array([lab[i, 0] >= 0 and fmap[lab[i, 0]] == data["flash"][i] and lab[i, 1] == data["marker"][i]
                   for i in range(len(lab))])
    sel = (data["flash"] >= 0) & has_back[np.maximum(data["flash"], 0)]
    given = lab[:, 0] >= 0
    return int((ok & sel).sum()), int(sel.sum()), int((given & ~ok).sum()), int(given.sum()), has_back


@pytest.fixture(scope="module")
def runs():
    out = {}
    for s in SEEDS:
        d = hand_points_from_truth(truth(s), noise_m=0.0005, drop=0.05, n_spurious=3, rng=s)
        out[s] = (d, label_hand_markers(d["points"], d["colours"], strobe_hz=75.0))
    return out


def test_labels_right_over_seeds(runs):
    right = total = wrong = given = 0
    for s, (d, lab) in runs.items():
        r, t, w, g, has_back = score(lab, d)
        right, total, wrong, given = right + r, total + t, wrong + w, given + g
        # every flash whose three back markers are among the points gets a pose from them; others
        # only from their other markers and a neighbour's pose (body.hand_label_fill)
        assert lab.pose_source.count("triplet") == has_back.sum(), s
        assert set(lab.pose_source) <= {"triplet", "neighbours", ""}
        assert np.array_equal(lab.reconstructed, np.array(lab.pose_source) != "")
        assert np.all(np.isfinite(lab.rms[lab.reconstructed])) and np.all(lab.rms[lab.reconstructed] < 0.0015)
        assert all(lab.skipped[k] == "" for k in np.flatnonzero(lab.reconstructed))
        assert all("no back-of-hand triplet" in lab.skipped[k] for k in np.flatnonzero(~lab.reconstructed))
    assert right / total >= 0.995, (right, total)
    assert wrong / given <= 0.005, (wrong, given)


def test_flash_order_follows_time(runs):
    for s, (d, lab) in runs.items():
        fmap = true_flash_of(lab, d)
        assert np.all(np.diff(fmap) > 0), (s, fmap)  # time order, one found flash per true flash
        assert np.allclose(lab.times, lab.order / 75.0) and lab.order[0] == 0


def test_reversed_throw_reverses_order(runs):
    d, lab = runs[SEEDS[0]]
    back = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, throw_direction=(0, 1, 0))
    assert np.array_equal(back.point_index, lab.point_index[::-1])


def test_shuffled_points_same_labels(runs):
    d, lab = runs[SEEDS[1]]
    perm = np.random.default_rng(7).permutation(len(d["points"]))
    again = label_hand_markers(d["points"][perm], d["colours"][perm], strobe_hz=75.0)
    remapped = np.where(again.point_index >= 0, perm[np.maximum(again.point_index, 0)], -1)
    assert np.array_equal(remapped, lab.point_index)


def test_flash_without_back_marker_is_skipped_with_reason():
    tr = truth(SEEDS[3])
    d = hand_points_from_truth(tr, noise_m=0.0005, drop=0.0, n_spurious=0, rng=1)
    # take back.2 out of the second flash that has all three
    ok = [k for k in range(tr.n) if all(((d["flash"] == k) & (d["marker"] == b)).any() for b in range(3))]
    k = ok[1]
    keep = ~((d["flash"] == k) & (d["marker"] == 1))
    # the first pass alone (fill=False: no posing from a neighbour, test_hand_label_fill.py)
    lab = label_hand_markers(d["points"][keep], d["colours"][keep], strobe_hz=75.0, fill=False)
    assert lab.reconstructed.sum() == len(ok) - 1
    skipped = np.flatnonzero(~lab.reconstructed)
    fmap = true_flash_of(lab, {"flash": d["flash"][keep]})
    j = int(np.flatnonzero(fmap == k)[0])
    assert j in skipped and "no back-of-hand triplet" in lab.skipped[j]
    assert np.all(lab.point_index[j] == -1) and len(lab.members[j]) >= 4


def test_to_dict_is_strict_json(runs):
    d, lab = runs[SEEDS[0]]
    out = json.loads(json.dumps(lab.to_dict(), allow_nan=False))
    assert out["flashes"]["point_index"] == lab.point_index.tolist()
    assert len(out["flashes"]["markers"]) == lab.n_flashes and out["marker_names"][:3] == list(BACK_MARKERS)


def write_overrides(path, entries, **top):
    path.write_text(json.dumps({"format": "stillcap-label-overrides", "version": 1, **top, "overrides": entries}))
    return path


def test_overrides_relabel_and_delete(runs, tmp_path):
    d, lab = runs[SEEDS[2]]
    k = int(np.flatnonzero(lab.reconstructed)[-1])
    ms = lab.markerset
    # swap two same-coloured labels of a flash by hand, delete a third point (positions moved by
    # 1 mm, as a re-run would)
    a, b = ms.index("middle.pip"), ms.index("middle.nail")
    pa, pb = lab.point_index[k, a], lab.point_index[k, b]
    assert pa >= 0 and pb >= 0
    pc = lab.point_index[k, ms.index("index.dip")]
    shift = np.array([0.001, 0, 0])
    path = write_overrides(tmp_path / "labels.json", [
        {"flash": k, "position_m": (lab.points[pa] + shift).tolist(), "label": "middle.nail"},
        {"flash": k, "position_m": (lab.points[pb] - shift).tolist(), "label": "middle.pip"},
        {"flash": k, "position_m": lab.points[pc].tolist(), "delete": True}], tolerance_mm=3)
    ov = read_label_overrides(path)
    new = apply_label_overrides(lab, ov)
    assert new.point_index[k, a] == pb and new.point_index[k, b] == pa
    assert new.point_index[k, ms.index("index.dip")] == -1 and pc in new.deleted and pc not in new.unassigned
    assert new.rms[k] > 0.01  # the swapped labels do not fit the hand: the refit says so
    assert np.array_equal(lab.point_index[k, [a, b]], [pa, pb])  # the input is left alone
    # the same file through label_hand_markers
    again = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0, overrides=path)
    assert np.array_equal(again.point_index, new.point_index)


def test_override_taking_a_back_marker_skips_the_flash(runs):
    d, lab = runs[SEEDS[0]]
    k = lab.pose_source.index("triplet")  # a flash posed from its back-of-hand triplet
    p = lab.point_index[k, lab.markerset.index("back.3")]
    q = lab.point_index[k, lab.markerset.index("index.pip")]
    gone = apply_label_overrides(lab, [LabelOverride(k, lab.points[q], delete=True)])
    assert gone.reconstructed[k] and q in gone.deleted and gone.rms[k] < 0.0015
    moved = apply_label_overrides(lab, [LabelOverride(k, lab.points[p], label="ring.nail")])
    assert not moved.reconstructed[k] and "back.3" in moved.skipped[k] and np.isnan(moved.rms[k])
    # and labelling it back rescues the flash
    back = apply_label_overrides(moved, [LabelOverride(k, lab.points[p], label="back.3")])
    assert back.reconstructed[k] and back.rms[k] < 0.0015


def test_override_errors_name_the_entry(runs, tmp_path):
    d, lab = runs[SEEDS[0]]
    k = lab.pose_source.index("triplet")
    p = lab.points[lab.point_index[k, 0]]
    far = write_overrides(tmp_path / "far.json", [{"flash": k, "position_m": (p + 0.01).tolist(), "delete": True}])
    with pytest.raises(ValueError, match=r"far.json: overrides\.0: no point within 3 mm"):
        apply_label_overrides(lab, read_label_overrides(far))
    unknown = write_overrides(tmp_path / "u.json", [{"flash": k, "position_m": p.tolist(), "label": "pinky.nail"}])
    with pytest.raises(ValueError, match=r"u.json: overrides\.0: unknown marker 'pinky.nail'"):
        apply_label_overrides(lab, read_label_overrides(unknown))
    bad_flash = write_overrides(tmp_path / "f.json", [{"flash": 99, "position_m": p.tolist(), "delete": True}])
    with pytest.raises(ValueError, match=r"f.json: overrides\.0: flash 99 is not one of"):
        apply_label_overrides(lab, read_label_overrides(bad_flash))
    both = write_overrides(tmp_path / "b.json", [{"flash": 0, "position_m": [0, 0, 0]},
                                                 {"flash": 0, "position_m": [0, 0, 0], "delete": True}])
    with pytest.raises(ValueError, match=r"b.json: overrides\.0: needs either a 'label' or"):
        read_label_overrides(both)
    nopos = write_overrides(tmp_path / "p.json", [{"flash": 0, "position_m": [0, 0], "delete": True}])
    with pytest.raises(ValueError, match=r"p.json: overrides\.0\.position_m\.2: field required$"):
        read_label_overrides(nopos)
    (tmp_path / "x.json").write_text('{"format": "other"}')
    with pytest.raises(ValueError, match="format 'stillcap-label-overrides'"):
        read_label_overrides(tmp_path / "x.json")
    with pytest.raises(ValueError, match="does not exist"):
        read_label_overrides(tmp_path / "missing.json")


def test_bad_input():
    pts = np.zeros((4, 3))
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\), got \(4, 2\)"):
        label_hand_markers(np.zeros((4, 2)), ["red"] * 4, strobe_hz=75)
    with pytest.raises(ValueError, match=r"colours must have shape \(4,\)"):
        label_hand_markers(pts, ["red"] * 3, strobe_hz=75)
    with pytest.raises(ValueError, match=r"colours must be names in .*'purple'"):
        label_hand_markers(pts, ["red", "purple", "red", "red"], strobe_hz=75)
    with pytest.raises(ValueError, match="strobe_hz must be finite and > 0"):
        label_hand_markers(pts, ["red"] * 4, strobe_hz=0)
    with pytest.raises(ValueError, match="throw_direction must be a non-zero"):
        label_hand_markers(pts, ["red"] * 4, strobe_hz=75, throw_direction=(0, 0, 0))
    with pytest.raises(ValueError, match=r"reprojection_px must have shape \(4,\)"):
        label_hand_markers(pts, ["red"] * 4, strobe_hz=75, reprojection_px=[1.0])
    empty = label_hand_markers(np.zeros((0, 3)), [], strobe_hz=75)
    assert empty.n_flashes == 0 and len(empty.unassigned) == 0


def test_reprojection_gate_drops_points(runs):
    d, lab = runs[SEEDS[0]]
    k = lab.pose_source.index("triplet")
    p = lab.point_index[k, lab.markerset.index("index.pip")]
    assert p >= 0
    rep = np.full(len(d["points"]), 0.5)
    rep[p] = 9.0
    new = label_hand_markers(d["points"], d["colours"], strobe_hz=75, reprojection_px=rep, max_reprojection_px=2.0)
    assert p not in new.point_index and p in new.unassigned
