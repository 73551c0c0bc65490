import numpy as np
import pytest

from stillcap.geometry.robust import consensus


class Lines:
    """A batch of 2D line problems: y[:, b] = slope[b] x + c[b], some points off the line."""

    def __init__(self, x, y):
        self.x, self.y = x, y

    def estimate(self, pair):
        i, j = pair
        slope = (self.y[j] - self.y[i]) / (self.x[j] - self.x[i])
        return slope, self.y[i] - slope * self.x[i]

    def residuals(self, params):
        slope, c = params
        return np.abs(self.y - (slope[None] * self.x[:, None] + c[None]))


def test_recovers_lines_with_outliers_in_a_batch():
    rng = np.random.default_rng(0)
    n, batch = 12, 200
    x = np.linspace(0, 1, n)
    slope, c = rng.normal(size=batch), rng.normal(size=batch)
    y = slope[None] * x[:, None] + c[None] + rng.normal(0, 1e-3, (n, batch))
    bad = rng.random((n, batch)) < 0.3
    y = np.where(bad, y + rng.uniform(0.5, 2, (n, batch)), y)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    found = consensus(Lines(x, y), pairs, threshold=0.01)
    assert np.all(found.best >= 0)
    # the winners' inliers are the points on the line (the noise is 10x below the threshold)
    assert np.mean(found.inliers == ~bad) > 0.995
    assert np.array_equal(found.n_inliers, found.inliers.sum(axis=0))


class Table:
    """Residuals given directly: hypothesis h's residuals are rows[h]."""

    def __init__(self, rows):
        self.rows = np.asarray(rows, float)

    def estimate(self, h):
        return h

    def residuals(self, h):
        return self.rows[h]


def test_ties_go_to_the_smaller_cost_then_to_the_first():
    rows = [[0.5, 0.5, 5.0], [0.1, 0.2, 5.0], [0.1, 0.2, 5.0]]
    assert int(consensus(Table(rows), range(3), 1.0).best) == 1  # as many inliers, smaller sum, first of equals
    assert int(consensus(Table(rows), range(3), 1.0, tie_break=False).best) == 0
    # below min_inliers the first of the most wins
    assert int(consensus(Table(rows), range(3), 1.0, min_inliers=3).best) == 0


def test_threshold_inclusive_or_not_and_nan_never_counts():
    rows = [[1.0, np.nan, 0.0]]
    assert consensus(Table(rows), range(1), 1.0).inliers.tolist() == [True, False, True]
    assert consensus(Table(rows), range(1), 1.0, inclusive=False).inliers.tolist() == [False, False, True]


def test_no_inlier_anywhere_says_so():
    found = consensus(Table([[5.0, 6.0]]), range(1), 1.0)
    assert int(found.best) == -1 and not found.inliers.any() and np.isinf(found.cost)


def test_no_hypothesis_is_an_error():
    with pytest.raises(ValueError, match="at least one hypothesis"):
        consensus(Table([[0.0]]), [], 1.0)


class TableOfAll(Table):
    """The same residuals, judged all at once."""

    def residuals_of_all(self, hypotheses):
        return self.rows[hypotheses]


@pytest.mark.parametrize("tie_break", [True, False])
@pytest.mark.parametrize("min_inliers", [1, 2, 3])
def test_all_at_once_is_the_same_as_one_by_one(tie_break, min_inliers):
    """Random residual tables with many ties: both ways pick the same hypothesis and inliers."""
    rng = np.random.default_rng(min_inliers)
    for _ in range(50):
        rows = rng.choice([0.0, 0.5, 1.0, 2.0, np.nan], size=(rng.integers(1, 8), 4, 6))
        a = consensus(Table(rows), range(len(rows)), 1.0, min_inliers=min_inliers, tie_break=tie_break)
        b = consensus(TableOfAll(rows), range(len(rows)), 1.0, min_inliers=min_inliers, tie_break=tie_break)
        assert np.array_equal(a.best, b.best) and np.array_equal(a.inliers, b.inliers)
        assert np.array_equal(a.n_inliers, b.n_inliers) and np.array_equal(a.cost, b.cost)
        # and the rule: the winner has the most inliers
        counts = (rows <= 1.0).sum(axis=1)
        assert np.array_equal(a.n_inliers, counts.max(axis=0))
