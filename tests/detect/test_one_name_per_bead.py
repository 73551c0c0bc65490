"""detect.beads.one_name_per_bead: two markers triangulated onto one bead keep one name."""
from types import SimpleNamespace

import numpy as np
import pytest

from stillcap.calibrate.turntable import turntable_rig
from stillcap.detect.beads import one_name_per_bead


def _views(rig, points, cost_at_shared):
    """Each view's candidates at the projections of ``points`` (the first two markers share one
    bead: one candidate), with colour costs: ``cost_at_shared`` for the shared candidate against
    the markers 0 and 1, 0.1 for marker 2's own, 5 elsewhere."""
    out = []
    for cam in rig:
        px = cam.project(points)
        cand = np.stack([0.5 * (px[0] + px[1]), px[2]])
        cost = np.full((2, 3), 5.0)
        cost[0, :2] = cost_at_shared
        cost[1, 2] = 0.1
        out.append(SimpleNamespace(circles=SimpleNamespace(centers=cand),
                                   identification=SimpleNamespace(cost=cost, max_distance=1.0)))
    return out


def test_the_name_whose_colour_fits_worse_loses_its_point():
    rig = turntable_rig()
    p = np.array([[0.0, 0.15, 0.0], [0.0001, 0.15, 0.0], [0.03, 0.1, 0.0]])
    pts, dropped = one_name_per_bead(rig, p, _views(rig, p, [0.2, 0.8]), 0.003)
    assert dropped.tolist() == [False, True, False]
    assert np.isnan(pts[1]).all() and np.array_equal(pts[[0, 2]], p[[0, 2]])
    pts, dropped = one_name_per_bead(rig, p, _views(rig, p, [0.9, 0.3]), 0.003)
    assert dropped.tolist() == [True, False, False]


def test_beads_a_diameter_apart_keep_both_names():
    rig = turntable_rig()
    p = np.array([[0.0, 0.15, 0.0], [0.0065, 0.15, 0.0], [0.03, 0.1, 0.0]])
    pts, dropped = one_name_per_bead(rig, p, _views(rig, p, [0.2, 0.8]), 0.003)
    assert not dropped.any() and np.array_equal(pts, p)


def test_bad_shapes_are_named():
    rig = turntable_rig()
    with pytest.raises(ValueError, match="points_3d must have shape"):
        one_name_per_bead(rig, np.zeros((3, 2)), [None] * len(rig))
    with pytest.raises(ValueError, match="one ViewResult per view"):
        one_name_per_bead(rig, np.zeros((3, 3)), [])
    with pytest.raises(ValueError, match="points_3d must have shape"):
        one_name_per_bead(rig, np.zeros(3), [None] * len(rig))
    with pytest.raises(ValueError, match="bead_radius_m must be > 0"):
        one_name_per_bead(rig, np.zeros((3, 3)), [None] * len(rig), 0.0)
    with pytest.raises(ValueError, match="gate_radius must be > 0"):
        one_name_per_bead(rig, np.zeros((3, 3)), [None] * len(rig), 0.003, float("nan"))
