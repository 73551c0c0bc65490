"""The pitch pipeline's alias step names a pair whose spin contradicts the rest (issue 12)."""

from types import SimpleNamespace

import numpy as np

from stillcap.ball.alias import RPM_PER_RAD_S
from stillcap.pipelines.pitch.spin import _resolve_alias

W_TRUE = np.array([-275.8, -81.7, -135.9])  # mlb-high-spin seed 0, 3038 rpm


def _pair(name, hz, spin, sigmas):
    s = SimpleNamespace(success=True, spin=np.asarray(spin, float), spin_covariance=np.diag(sigmas) ** 2)
    return SimpleNamespace(name=name, strobe_hz=hz, spin=s, observations=None)


def _flight_fit(w, sigma=2.0):
    """A reference fit along +y whose transverse spin (Nathan's lift) is w's."""
    basis = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # columns: flight, e1, e2
    params = np.zeros(9)
    params[6:9] = basis.T @ w
    cov = np.eye(9) * sigma ** 2
    return SimpleNamespace(spin_basis=basis, params=params, covariance=cov)


def test_wrong_back_pair_left_out_and_reported():
    # the recorded per-pair fits of that pitch: the back pair's few markers gave a wrong spin
    pairs = [_pair("front", 80.0, [159.68359146, 46.16341887, 79.64197961], [0.5375651, 1.05833232, 0.89884613]),
             _pair("back", 50.0, [134.82022519, 35.99696013, 63.24013209], [5.24650909, 1.69019024, 11.80555085])]
    messages = []
    w, res = _resolve_alias(pairs, _flight_fit(W_TRUE), SimpleNamespace(kind="nathan"), messages)
    assert res.left_out == ["pair back (50 Hz)"]
    assert not res.ambiguous
    assert abs(np.linalg.norm(w) * RPM_PER_RAD_S - np.linalg.norm(W_TRUE) * RPM_PER_RAD_S) < 20
    assert np.degrees(np.arccos(w @ W_TRUE / np.linalg.norm(w) / np.linalg.norm(W_TRUE))) < 2
    assert any("without pair back (50 Hz)" in m for m in messages)
    assert not any("ambiguous" in m for m in messages)


def test_without_the_curvature_the_contradiction_stays_flagged():
    pairs = [_pair("front", 80.0, [159.68359146, 46.16341887, 79.64197961], [0.5375651, 1.05833232, 0.89884613]),
             _pair("back", 50.0, [134.82022519, 35.99696013, 63.24013209], [5.24650909, 1.69019024, 11.80555085])]
    messages = []
    _, res = _resolve_alias(pairs, None, SimpleNamespace(kind="nathan"), messages)
    assert res.left_out == [] and res.ambiguous
    assert any("ambiguous" in m for m in messages)


class _Obs:
    def __init__(self, flashes):
        self.flash = np.asarray(flashes, int)

    def __len__(self):
        return len(self.flash)


def _pairs(front_flashes, back_flashes):
    front = _pair("front", 80.0, [159.68359146, 46.16341887, 79.64197961], [0.5375651, 1.05833232, 0.89884613])
    back = _pair("back", 50.0, [134.82022519, 35.99696013, 63.24013209], [5.24650909, 1.69019024, 11.80555085])
    for p, fl in ((front, front_flashes), (back, back_flashes)):
        p.observations = _Obs(fl)
        p.spin.inliers = np.ones(len(fl), bool)
    return [front, back]


def test_pair_whose_markers_fix_no_two_orientations_chooses_no_alias():
    # the back pair saw one marker per flash (two at one flash): its spin is not alias evidence
    # while the front pair's markers fix the orientation at every flash
    pairs = _pairs([0, 0, 0, 1, 1, 2, 2, 2, 3, 3], [0, 1, 2, 3, 3, 4])
    messages = []
    w, res = _resolve_alias(pairs, None, SimpleNamespace(kind="nathan"), messages)
    assert res.evidence == ["pair front (80 Hz)"]
    assert any("pair back (50 Hz): its own spin was not used" in m and "at 1 flash," in m for m in messages)
    # with the flight's curvature the front pair's right alias is chosen, unflagged
    messages = []
    w, res = _resolve_alias(pairs, _flight_fit(W_TRUE), SimpleNamespace(kind="nathan"), messages)
    assert res.evidence == ["pair front (80 Hz)", "curvature"] and not res.ambiguous
    assert np.degrees(np.arccos(w @ W_TRUE / np.linalg.norm(w) / np.linalg.norm(W_TRUE))) < 2


def test_pairs_are_kept_when_none_fixes_two_orientations():
    pairs = _pairs([0, 1, 2, 3], [0, 1, 2, 3, 3, 4])
    messages = []
    _, res = _resolve_alias(pairs, None, SimpleNamespace(kind="nathan"), messages)
    assert res.evidence == ["pair front (80 Hz)", "pair back (50 Hz)"]
    assert not any("not used" in m for m in messages)
    # and when both do, both count
    pairs = _pairs([0, 0, 1, 1], [0, 0, 2, 2])
    _, res = _resolve_alias(pairs, None, SimpleNamespace(kind="nathan"), [])
    assert res.evidence == ["pair front (80 Hz)", "pair back (50 Hz)"]
