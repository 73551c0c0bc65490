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


def _pair_on_one_epipolar_plane():
    """Two cameras 1 m apart along x looking along +y, and 6 points in the plane z = 0 that holds
    their baseline: every point's images lie on one epipolar line, every pair is admissible."""
    from stillcap.camera import Camera, look_at

    cams = [Camera.from_intrinsics(n, 1000.0, 1000.0, 640.0, 480.0, (1280, 960),
                                   world2cam=look_at((x, 0.0, 0.0), (0.0, 10.0, 0.0)))
            for n, x in (("a", -0.5), ("b", 0.5))]
    X = np.stack([np.full(6, 0.3), np.linspace(4.0, 9.0, 6), np.zeros(6)], axis=1)
    return cams, X


def test_order_resolves_points_along_one_epipolar_line():
    (a, b), X = _pair_on_one_epipolar_plane()
    perm = np.array([3, 0, 5, 1, 4, 2])
    xa, xb = a.project(X), b.project(X)[perm]
    plain = match_epipolar(a, b, xa, xb, max_px=3.0)
    right = {(int(perm[j]), j) for j in range(6)}
    assert {tuple(p) for p in plain.pairs.tolist()} != right  # all distances 0: the assignment is arbitrary
    # the points' places along their curve, in either direction per view
    for oa, ob in ((xa[:, 0], xb[:, 0]), (xa[:, 0], -xb[:, 0]), (np.arange(6.0), -perm.astype(float))):
        m = match_epipolar(a, b, xa, xb, max_px=3.0, order_a=oa, order_b=ob)
        assert {tuple(p) for p in m.pairs.tolist()} == right
        assert len(m.unmatched_a) == 0 and len(m.unmatched_b) == 0


def test_order_leaves_single_partner_matches_alone(rig4):
    rng = np.random.default_rng(3)
    X = rng.uniform(-0.5, 0.5, (20, 3))
    a, b = rig4[0], rig4[1]
    xa = a.project(X) + rng.normal(0, 0.3, (20, 2))
    xb = b.project(X)[::-1] + rng.normal(0, 0.3, (20, 2))
    d = epipolar_distances(a, b, xa, xb)
    one = ((d <= 1.0).sum(1) <= 1) & ((d <= 1.0).sum(0) <= 1)[::-1]
    plain = match_epipolar(a, b, xa[one], xb[one[::-1]], max_px=1.0)
    ordered = match_epipolar(a, b, xa[one], xb[one[::-1]], max_px=1.0, order_a=rng.normal(size=one.sum()),
                             order_b=rng.normal(size=one.sum()))
    assert one.sum() >= 10 and np.array_equal(plain.pairs, ordered.pairs)
    np.testing.assert_array_equal(plain.distance_px, ordered.distance_px)
    with pytest.raises(ValueError, match="together"):
        match_epipolar(a, b, xa, xb, order_a=np.zeros(20))
    with pytest.raises(ValueError, match="order_b"):
        match_epipolar(a, b, xa, xb, order_a=np.zeros(20), order_b=np.zeros(3))
