"""The pitch pipeline's alias step names a pair whose spin contradicts the rest (issue 12)."""

from types import SimpleNamespace

import numpy as np

from stillcap.ball.alias import RPM_PER_RAD_S
from stillcap.pipelines.pitch.spin import _resolve_alias

W_TRUE = np.array([-275.8, -81.7, -135.9])  # mlb-high-spin seed 0, 3038 rpm


def _pair(name, hz, spin, sigmas):
    s = SimpleNamespace(success=True, spin=np.asarray(spin, float), spin_covariance=np.diag(sigmas) ** 2)
    return SimpleNamespace(name=name, strobe_hz=hz, spin=s)


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
