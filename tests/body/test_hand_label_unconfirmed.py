"""Points nothing but their own two blobs supports (partly hidden, two views): labelled only where
something tests the label (issue 12: studio hands 3 and 5, a sliver pair 17-21 mm from every
marker took ``ring.dip``, the ring finger bent to it)."""

from functools import cache, lru_cache

import numpy as np
import pytest

from stillcap.body.hand import hand_markerset
from stillcap.body.hand_label import (
    GATE_M,
    contradicted_labels,
    hand_points_from_truth,
    label_hand_markers,
    unlabel_points,
)
from stillcap.studio.hand import hand_capture


@cache
def _data():
    tr = hand_capture(0, image_size=(320, 240), supersample=1).truth
    return tr, hand_points_from_truth(tr, noise_m=0.0002, drop=0.0, n_spurious=0, rng=0)


def _lone_marker_case():
    """Points of studio seed 0 with one digit of one flash reduced to its PIP marker; returns
    (points, colours, strobe, index of the lone point, index of the PIP marker)."""
    tr, d = _data()
    names = list(hand_markerset().names)
    flash = int(np.bincount(d["flash"][d["flash"] >= 0]).argmax())
    for digit in ("index", "middle", "ring", "little"):
        mk = [names.index(f"{digit}.{p}") for p in ("pip", "dip", "nail")]
        here = [int(np.flatnonzero((d["flash"] == flash) & (d["marker"] == m))[0])
                for m in mk if ((d["flash"] == flash) & (d["marker"] == m)).any()]
        if len(here) == 3:
            break
    else:
        pytest.skip("no flash of seed 0 shows a whole finger")
    keep = np.ones(len(d["points"]), bool)
    keep[here[1:]] = False  # the DIP and nail markers gone: the PIP marker alone on its digit
    idx = np.flatnonzero(keep)
    lone = int(np.flatnonzero(idx == here[0])[0])
    return d["points"][keep], d["colours"][keep], tr.strobe_hz, lone, mk[0]


def test_a_lone_unconfirmed_point_is_not_labelled():
    pts, cols, hz, lone, marker = _lone_marker_case()
    plain = label_hand_markers(pts, cols, strobe_hz=hz)
    k = np.flatnonzero((plain.point_index == lone).any(axis=1))
    assert len(k) == 1 and plain.point_index[k[0], marker] == lone  # labelled without the flag
    unc = np.zeros(len(pts), bool)
    unc[lone] = True
    lab = label_hand_markers(pts, cols, strobe_hz=hz, unconfirmed=unc)
    assert not (lab.point_index == lone).any() and lone in lab.unassigned
    # every other label is as before
    other = plain.point_index != lone
    assert np.array_equal(lab.point_index[other], plain.point_index[other])


def test_unconfirmed_points_beside_another_of_their_digit_keep_their_labels():
    tr, d = _data()
    plain = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz,
                             unconfirmed=np.ones(len(d["points"]), bool))
    # whole fingers: no label is lone on its digit except where the truth hides its siblings
    assert (lab.point_index >= 0).sum() >= 0.9 * (plain.point_index >= 0).sum()
    with pytest.raises(ValueError, match="unconfirmed must be"):
        label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz, unconfirmed=[True])


def test_contradicted_labels_and_unlabel_points():
    tr, d = _data()
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=tr.strobe_hz)
    k = int(np.flatnonzero(lab.reconstructed)[0])
    names = lab.marker_names
    j_back, j_nail = names.index("back.1"), names.index("index.nail")
    p_back, p_nail = lab.point_index[k, j_back], lab.point_index[k, j_nail]
    assert p_back >= 0 and p_nail >= 0
    res = np.where(lab.point_index >= 0, 0.0005, np.nan)[[k]]
    res[0, j_back] = res[0, j_nail] = 2 * GATE_M * lab.hand_scale
    unc = np.ones(len(lab.points), bool)
    assert contradicted_labels(lab, res, [k], unc).tolist() == [p_nail]  # never a back marker
    unc[p_nail] = False
    assert len(contradicted_labels(lab, res, [k], unc)) == 0  # a confirmed point is not questioned
    res[0, j_nail] = 0.9 * GATE_M * lab.hand_scale
    assert len(contradicted_labels(lab, res, [k], np.ones(len(lab.points), bool))) == 0
    out = unlabel_points(lab, [p_nail])
    assert out.point_index[k, j_nail] == -1 and np.isnan(out.positions[k, j_nail]).all()
    assert p_nail in out.unassigned and p_nail not in lab.unassigned
    assert (out.point_index >= 0).sum() == (lab.point_index >= 0).sum() - 1
