"""Digits whose fitted pose is a guess, searched over their range of motion
(:func:`stillcap.body.hand_label_fill.digit_search`, issue 12)."""

from functools import lru_cache

import numpy as np
import pytest

from stillcap.body.hand_label import (
    GATE_M,
    GRID_GATE_M,
    hand_points_from_truth,
    label_hand_markers,
)
from stillcap.body.hand_label_fill import digit_search, label_recovered
from stillcap.studio.hand import hand_capture


@lru_cache(maxsize=None)
def digit_taken_out(seed=3, digit="middle"):
    """Points of the default hand labelled without one digit's points in one posed flash, which
    are returned apart: ``(labels, their points, their colours, their true markers, the flash)``."""
    tr = hand_capture(seed, image_size=(320, 240), supersample=1).truth
    d = hand_points_from_truth(tr, noise_m=0.0003, drop=0.0, n_spurious=0, rng=1)
    full = label_hand_markers(d["points"], d["colours"], strobe_hz=75.0)
    names = full.marker_names
    on = np.array([n.startswith(digit + ".") for n in names])
    k = next(k for k in range(full.n_flashes) if full.reconstructed[k] and (full.point_index[k, on] >= 0).sum() >= 2)
    marks = np.flatnonzero(on & (full.point_index[k] >= 0))
    out = full.point_index[k, marks]
    keep = ~np.isin(np.arange(len(d["points"])), out)
    lab = label_hand_markers(d["points"][keep], d["colours"][keep], strobe_hz=75.0)
    j = int(np.argmin([np.nanmin(np.linalg.norm(lab.positions[q] - full.positions[k][None], axis=-1))
                       for q in range(lab.n_flashes)]))
    return lab, d["points"][out], d["colours"][out], marks, j


def _with(lab, X, cols):
    pts = np.concatenate([lab.points, X])
    return pts, np.concatenate([lab.colors, cols]), np.arange(len(lab.points), len(pts))


def test_a_digit_without_labels_is_found_over_its_range_of_motion():
    lab, X, cols, marks, k = digit_taken_out()
    assert lab.reconstructed[k] and np.all(lab.point_index[k, marks] < 0)
    pts, c, cand = _with(lab, X, cols)
    props, pred = digit_search(lab, pts, c, cand, grid_gate_m=GRID_GATE_M, gate_m=GATE_M)
    assert sorted(props) == sorted((int(p), k, int(m)) for p, m in zip(cand, marks))
    assert pred.shape == (len(props), 3)
    assert np.all(np.linalg.norm(pred - pts[[p for p, _, _ in props]], axis=1) <= GATE_M)
    out = label_recovered(lab, pts, c, props, gate_m=GATE_M, predicted=pred)
    assert [int(out.point_index[k, m]) for m in marks] == [int(p) for p in cand]


def test_one_point_alone_on_a_digit_without_labels_is_not_proposed():
    lab, X, cols, marks, k = digit_taken_out()
    pts, c, cand = _with(lab, X[:1], cols[:1])
    props, _ = digit_search(lab, pts, c, cand, grid_gate_m=GRID_GATE_M, gate_m=GATE_M)
    assert props == []
    # the same point with two markers asked of a digit: none either way with min_markers=3
    pts, c, cand = _with(lab, X, cols)
    props, _ = digit_search(lab, pts, c, cand, grid_gate_m=GRID_GATE_M, gate_m=GATE_M, min_markers=len(marks) + 1)
    assert props == []


def test_points_that_fit_no_pose_of_the_digit_are_not_proposed():
    lab, X, cols, marks, k = digit_taken_out()
    # the digit's points moved apart along their join: no pose of the digit puts both markers there
    mid = X.mean(axis=0)
    far = mid + 2.5 * (X - mid)
    pts, c, cand = _with(lab, far, cols)
    props, _ = digit_search(lab, pts, c, cand, grid_gate_m=GRID_GATE_M, gate_m=GATE_M)
    assert not any(k == kk and m in marks for _, kk, m in props)


def test_bad_input_is_named():
    lab, X, cols, marks, k = digit_taken_out()
    pts, c, cand = _with(lab, X, cols)
    with pytest.raises(ValueError, match="candidates must be rows"):
        digit_search(lab, pts, c, [len(pts)], grid_gate_m=GRID_GATE_M, gate_m=GATE_M)
    with pytest.raises(ValueError, match="points must have shape"):
        digit_search(lab, pts[:, :2], c, cand, grid_gate_m=GRID_GATE_M, gate_m=GATE_M)
