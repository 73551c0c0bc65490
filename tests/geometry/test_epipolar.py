import numpy as np
import pytest

from stillcap.geometry.epipolar import epipolar_distances, fundamental_matrix, match_epipolar



def test_fundamental_matrix_satisfied_by_true_correspondences(rig4):
    X = np.random.default_rng(0).uniform(-0.5, 0.5, (100, 3))
    a, b = rig4[0], rig4[1]
    xa, xb = a.undistort_points(a.project(X)), b.undistort_points(b.project(X))
    F = fundamental_matrix(a, b)
    h = lambda p: np.concatenate([p, np.ones((len(p), 1))], 1)
    assert np.abs(np.einsum("ni,ij,nj->n", h(xb), F, h(xa))).max() < 1e-9
    d = epipolar_distances(a, b, a.project(X), b.project(X))
    assert np.diag(d).max() < 1e-6


def test_matching_shuffled_points_with_noise_and_extras(rig4):
    rng = np.random.default_rng(1)
    X = rng.uniform(-0.5, 0.5, (30, 3))
    a, b = rig4[0], rig4[1]
    xa = a.project(X) + rng.normal(0, 0.3, (30, 2))
    perm = rng.permutation(30)
    xb = b.project(X)[perm] + rng.normal(0, 0.3, (30, 2))
    xb = np.concatenate([xb, [[5.0, 5.0]]])  # a spurious blob in b
    m = match_epipolar(a, b, xa, xb, max_px=2.0)
    truth = {int(perm[j]): j for j in range(30)}
    right = sum(truth[i] == j for i, j in m.pairs)
    assert right >= 28  # points that happen to lie on the same epipolar line can swap
    assert 30 in m.unmatched_b


def test_labels_restrict_matches(rig4):
    a, b = rig4[0], rig4[2]
    X = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3]])
    xa, xb = a.project(X), b.project(X)
    m = match_epipolar(a, b, xa, xb[::-1], labels_a=["red", "blue"], labels_b=["blue", "red"])
    assert sorted(map(tuple, m.pairs)) == [(0, 1), (1, 0)]
    m = match_epipolar(a, b, xa, xb, labels_a=["red", "blue"], labels_b=["green", "green"])
    assert len(m.pairs) == 0 and list(m.unmatched_a) == [0, 1]
    with pytest.raises(ValueError, match="one label per point"):
        match_epipolar(a, b, xa, xb, labels_a=["red"], labels_b=["red", "blue"])


def test_empty_and_nan(rig4):
    m = match_epipolar(rig4[0], rig4[1], np.zeros((0, 2)), np.zeros((3, 2)))
    assert len(m.pairs) == 0 and len(m.unmatched_b) == 3
    m = match_epipolar(rig4[0], rig4[1], [[np.nan, np.nan]], [[100.0, 100.0]])
    assert len(m.pairs) == 0
