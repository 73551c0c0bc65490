"""Designed marker layouts (stillcap balls design)."""

from __future__ import annotations

import numpy as np

from stillcap.ball.design import design_layout, near_separation_deg, score_layout, spread_directions
from stillcap.ball.layout import BallLayout, check_layout


def test_spread_directions_are_spread():
    d = spread_directions(12, rng=0)
    cos = d @ d.T
    np.fill_diagonal(cos, -1)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    assert np.degrees(np.arccos(cos.max())) > 55  # the best 12 points (icosahedron) are 63.4 deg apart


def test_design_beats_a_bad_assignment_and_is_determined():
    lay, score = design_layout(10, 3, restarts=2, sweeps=2, rng=1)
    assert len(lay) == 10 and lay.n_types == 3 and np.bincount(lay.types).tolist() in ([4, 3, 3], [3, 4, 3], [3, 3, 4])
    for margin in (0, 10):
        assert check_layout(lay, margin).n_ambiguous == 0
    assert score.share_determined > 0.95
    # the same positions with the types in spatial order (neighbours share types) fix the frame worse
    order = np.argsort(np.arctan2(lay.directions[:, 1], lay.directions[:, 0]))
    bad_types = np.empty(10, int)
    bad_types[order] = np.repeat([0, 1, 2], [4, 3, 3])
    bad = BallLayout(lay.directions, bad_types, lay.type_names, lay.type_shapes, lay.palette)
    # what the design maximises: determined from the views at 15 deg, then its score at 10 deg
    assert (score_layout(bad, 15).share_determined, score_layout(bad).key()) < \
        (score_layout(lay, 15).share_determined, score.key())


def test_near_separation_finds_the_seed_layouts_near_ambiguities():
    seed = BallLayout.seed()
    vis = seed.visible(np.array([[0, 0, 1.0]]), 10)
    # the exact search's rotations are among the near ones: never a larger separation
    assert near_separation_deg(seed, vis)[0] <= seed.separation_deg(vis[0]) + 1e-9
    # one marker alone never fixes the frame
    one = np.zeros((1, 12), bool)
    one[0, 0] = True
    assert near_separation_deg(seed, one)[0] == 0.0
