"""``label_and_adapt`` (``--adapt-model``) passes the partly hidden, unconfirmed points' flags to
every labelling it does, as the pipeline's plain labelling does (last session's note: it did
not)."""

import numpy as np

import stillcap.body.hand_label as hand_label
from stillcap.body.hand import hand_markerset, hand_skeleton
from stillcap.body.hand_adapt import label_and_adapt


class _Labels:
    """What label_and_adapt reads of a first labelling with no pose."""

    reconstructed = np.zeros(0, bool)
    hand_scale = 1.0


def test_unconfirmed_reaches_every_labelling(monkeypatch):
    calls = []

    def spy(points, colors, **kw):
        calls.append(kw.get("unconfirmed"))
        return _Labels()

    monkeypatch.setattr(hand_label, "label_hand_markers", spy)
    flags = np.array([True, False, True])
    pts = np.zeros((3, 3))
    cols = np.array(["red", "blue", "green"])
    for adapt in (True, False):
        calls.clear()
        label_and_adapt(pts, cols, strobe_hz=75.0, skeleton=hand_skeleton(), markerset=hand_markerset(),
                        adapt=adapt, unconfirmed=flags)
        assert len(calls) == (2 if adapt else 1)
        assert all(c is flags for c in calls)
