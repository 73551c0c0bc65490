"""Hands larger or smaller than the model (issue 12): the back-of-hand triangle is found at any
size in the range, the model and every gate scale with the size found, no capture is lost."""

import numpy as np
import pytest

from stillcap.body.hand_label import hand_points_from_truth, label_hand_markers
from stillcap.studio.hand import hand_capture
from stillcap.studio.hand_variation import another_hand


@pytest.mark.parametrize("size", [0.85, 1.15])
def test_hand_of_another_size_is_labelled(size):
    v = another_hand(3, size=size)
    truth = hand_capture(3, image_size=(320, 240), supersample=1, person=v).truth
    d = hand_points_from_truth(truth, noise_m=0.0003, drop=0.0, n_spurious=3, rng=3)
    lab = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz)
    assert abs(lab.hand_scale - size) < 0.03
    back_seen = (truth.markers_visible.sum(axis=0) >= 2)[:, :3].all(axis=1)
    assert lab.pose_source.count("triplet") == back_seen.sum() > 0
    # with the fixed 6 mm triangle gate of a model-sized hand, the capture is lost (the bug)
    fixed = label_hand_markers(d["points"], d["colours"], strobe_hz=truth.strobe_hz, hand_scale=1.0)
    assert fixed.reconstructed.sum() == 0
    # labels are right: every labelled point is the marker it names
    lp = lab.labels()
    given = lp[:, 0] >= 0
    assert np.all(lp[given, 1] == d["marker"][given])


def test_another_hand_is_seeded_and_unlike_the_model():
    a, b = another_hand(7), another_hand(7)
    assert np.array_equal(a.skeleton.offsets, b.skeleton.offsets)
    assert np.array_equal(a.markerset.offsets, b.markerset.offsets)
    c = another_hand(8)
    assert not np.allclose(a.skeleton.offsets, c.skeleton.offsets)
    assert 0.85 <= a.size <= 1.15
    with pytest.raises(ValueError, match="size"):
        another_hand(1, size=3.0)
