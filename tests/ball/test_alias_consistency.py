"""Alias ranking flags evidence that contradicts itself (issue 3, mlb-high-spin seed 0)."""

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.ball.alias import RPM_PER_RAD_S, StrobeMeasurement, resolve_aliases


def _principal(w, hz):
    return Rotation.from_rotvec(np.asarray(w, float) / hz).as_rotvec() * hz


def test_mlb_high_spin_seed0_wrong_back_pair_is_flagged():
    # recorded per-pair spin fits of `mlb-high-spin` seed 0 (true spin 3038 rpm): the back pair's
    # few half-moon markers gave a wrong principal spin (1463 rpm) that no alias of the front
    # pair's 1760 rpm matches; the ranking used to pick 1463 rpm, unflagged
    front = StrobeMeasurement([159.68359146, 46.16341887, 79.64197961], 80.0,
                              np.diag([0.5375651, 1.05833232, 0.89884613]) ** 2, "front")
    back = StrobeMeasurement([134.82022519, 35.99696013, 63.24013209], 50.0,
                             np.diag([5.24650909, 1.69019024, 11.80555085]) ** 2, "back")
    res = resolve_aliases([front, back])
    assert not res.consistent
    assert res.ambiguous
    assert res.dof == 3
    assert "disagrees" in res.message


def test_consistent_aliases_stay_resolved():
    rng = np.random.default_rng(3)
    w = np.array([-275.8, -81.7, -135.9])  # 3038 rpm: above both strobes' Nyquist limits
    meas = []
    for hz, name in ((80.0, "front"), (50.0, "back")):
        cov = np.eye(3) * 0.5 ** 2
        meas.append(StrobeMeasurement(_principal(w, hz) + rng.multivariate_normal(np.zeros(3), cov), hz, cov, name))
    res = resolve_aliases(meas)
    assert res.consistent and not res.ambiguous
    assert abs(res.best.spin_rpm - np.linalg.norm(w) * RPM_PER_RAD_S) < 20
    assert np.degrees(np.arccos(res.best.axis @ (w / np.linalg.norm(w)))) < 2
