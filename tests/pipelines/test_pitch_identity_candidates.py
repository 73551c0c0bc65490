"""Misidentified markers (issue 12): when the ``ball_layout`` check fails and the flight's
curvature disagrees with the marker spin, the spin's intervals cover the spin the flight shows
as well (``checks.identity_candidates`` with ``widen_spin_for_aliases``)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from pipelines.test_pitch_ambiguous_alias import _covers, _spin

from stillcap._selfcheck import SelfCheck
from stillcap.pipelines.pitch.checks import identity_candidates, widen_spin_for_aliases

RPM = 60.0 / (2 * np.pi)


def _layout(passed):
    return SelfCheck("ball_layout", passed, 2.0 if passed else 18.0, 4.0, "x", "baseball", "deg")


def _flight(w_flight, lift_from="transverse"):
    return SimpleNamespace(spin=np.asarray(w_flight, float), lift_from=lift_from)


def _cmp(marker_transverse, agree, flight_rpm=None):
    mt = np.asarray(marker_transverse, float)
    return SimpleNamespace(marker_transverse=mt, marker_transverse_rpm=float(np.linalg.norm(mt) * RPM),
                           flight_rpm=flight_rpm, agree=agree)


def test_no_candidate_while_identities_hold_or_the_flight_agrees():
    spin = _spin(np.array([0.0, 300.0, 40.0]), np.eye(3) * 1.0)
    fl, cm = _flight([0.0, 290.0, 0.0]), _cmp([0.0, 300.0, 0.0], agree=False)
    assert identity_candidates(spin, _layout(True), fl, cm) == []
    assert identity_candidates(spin, _layout(False), fl, _cmp([0.0, 300.0, 0.0], agree=True)) == []
    assert identity_candidates(spin, _layout(False), None, cm) == []
    assert identity_candidates(spin, None, fl, cm) == []


def test_misidentified_markers_intervals_cover_the_flights_spin():
    """A marker spin 8 % too fast with a tight covariance (the misfit is systematic): the truth,
    which the flight's transverse spin shows, lies far outside its interval until widened."""
    truth = np.array([0.0, 300.0, 40.0])
    w = 1.08 * truth
    spin = _spin(w, np.eye(3) * 1.0)
    cm = _cmp([0.0, w[1], 0.0], agree=False)  # the marker spin's transverse part (flight along z)
    fl = _flight([0.0, truth[1], 0.0])
    assert not _covers(spin, truth)
    cands = identity_candidates(spin, _layout(False), fl, cm)
    assert len(cands) == 1 and np.allclose(cands[0].spin, [0.0, 300.0, w[2]])
    wide, extra = widen_spin_for_aliases(spin, cands)
    assert _covers(wide, cands[0].spin) and _covers(wide, w)
    assert np.all(np.linalg.eigvalsh(extra) >= -1e-9)


def test_seed_lift_law_takes_the_flights_rate():
    w = np.array([0.0, 320.0, 0.0])
    spin = _spin(w, np.eye(3) * 1.0)
    cm = _cmp(w, agree=False, flight_rpm=300.0 * RPM)
    cands = identity_candidates(spin, _layout(False), _flight([0.0, 300.0, 0.0], "total"), cm)
    assert np.allclose(cands[0].spin, [0.0, 300.0, 0.0])
