"""Robust estimation: one model protocol and one consensus loop, shared by N-view triangulation,
the puppet's marker triangulation and the spin fit's grouping of rotations.

A model, in the manner of scikit-image's ``measure`` models used by ``measure.ransac``, has two
methods: :meth:`RobustModel.estimate` makes parameters from one hypothesis (a minimal subset of
the data, e.g. one pair of views), and :meth:`RobustModel.residuals` gives the residual of every
datum under them (NaN: the datum cannot be judged, e.g. a view that did not see the point).
:func:`consensus` tries the hypotheses in order and keeps the one with the most inliers (residual
within the threshold); among hypotheses with as many inliers, at least ``min_inliers`` of them,
the smaller sum of inlier residuals wins, otherwise the first.

Two things differ from ``skimage.measure.ransac``, and are why this loop is written here:
hypotheses are enumerated, not sampled (a capture rig has a handful of view pairs: trying all of
them is cheaper than sampling and deterministic), and every quantity is vectorised over a batch
of independent problems (residuals of shape ``(n_data, *batch)``: one problem per 3D point), so
that a million points cost one loop over the view pairs, not a million loops.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

__all__ = ["RobustModel", "Consensus", "consensus"]


class RobustModel(Protocol):
    """What :func:`consensus` needs of a model. A model whose residuals are cheaper for all
    hypotheses at once may also define ``residuals_of_all(hypotheses)``, shape
    (n_hypotheses, n_data, *batch): the loop then judges them in one step, by the same rule."""

    def estimate(self, hypothesis) -> Any:
        """Parameters from one hypothesis (a minimal subset of the data)."""

    def residuals(self, params) -> np.ndarray:
        """Residual of every datum under ``params``, shape (n_data, *batch); NaN: not judged."""


@dataclass
class Consensus:
    """Result of :func:`consensus`, per problem of the batch.

    Attributes
    ----------
    best : ndarray of int, shape batch
        Index of the winning hypothesis; -1 where no hypothesis had an inlier.
    inliers : ndarray of bool, shape (n_data, *batch)
        The winner's inliers (all False where ``best`` is -1).
    n_inliers : ndarray of int, shape batch
    cost : ndarray, shape batch
        The winner's summed inlier residuals (inf where ``best`` is -1).
    """

    best: np.ndarray
    inliers: np.ndarray
    n_inliers: np.ndarray
    cost: np.ndarray


def consensus(model: RobustModel, hypotheses: Iterable, threshold: float, *, min_inliers: int = 2,
              inclusive: bool = True, tie_break: bool = True) -> Consensus:
    """The hypothesis with the largest consensus set, per problem of the batch.

    Parameters
    ----------
    model : RobustModel
    hypotheses : iterable
        Passed one by one to ``model.estimate``, in order (the order breaks remaining ties).
    threshold : float
        A datum is an inlier when its residual is ``<= threshold`` (``< threshold`` with
        ``inclusive=False``).
    min_inliers : int
        Ties in the number of inliers go to the smaller summed residual only among hypotheses
        with at least this many inliers (a single inlier has residual zero by construction).
    tie_break : bool
        False: ties always go to the first hypothesis (the largest group, as ``argmax`` picks).

    Examples
    --------
    The line through two of four points that most points agree with (a batch of one problem):

    >>> import numpy as np
    >>> x = np.array([0.0, 1.0, 2.0, 3.0]); y = np.array([0.0, 1.0, 2.0, 10.0])
    >>> class Line:
    ...     def estimate(self, pair):
    ...         i, j = pair
    ...         slope = (y[j] - y[i]) / (x[j] - x[i])
    ...         return slope, y[i] - slope * x[i]
    ...     def residuals(self, params):
    ...         return np.abs(y - (params[0] * x + params[1]))
    >>> found = consensus(Line(), [(0, 3), (0, 1), (1, 2)], threshold=0.1)
    >>> int(found.best), found.inliers.tolist()
    (1, [True, True, True, False])
    """
    hypotheses = list(hypotheses)
    if not hypotheses:
        raise ValueError("consensus needs at least one hypothesis")
    if hasattr(model, "residuals_of_all"):
        steps = [(0, model.residuals_of_all(hypotheses))]
    else:
        steps = ((i, np.asarray(model.residuals(model.estimate(h)), float)[None]) for i, h in enumerate(hypotheses))
    found = None
    for start, r in steps:
        r = np.asarray(r, float)
        inl = (r <= threshold) if inclusive else (r < threshold)  # NaN: never an inlier
        count = inl.sum(axis=1)
        cost = np.where(inl, r, 0.0).sum(axis=1)
        index = np.broadcast_to(np.arange(start, start + len(r)).reshape((-1,) + (1,) * (count.ndim - 1)),
                                count.shape)
        if found is not None:  # the best so far comes first, so that it wins ties
            count = np.concatenate([found.n_inliers[None], count])
            cost = np.concatenate([found.cost[None], cost])
            inl = np.concatenate([found.inliers[None], inl])
            index = np.concatenate([found.best[None], index])
        w = _winner(count, cost, min_inliers, tie_break)
        n = _take(count, w)
        found = Consensus(np.where(n > 0, _take(index, w), -1), _take(inl, w) & (n > 0), n,
                          np.where(n > 0, _take(cost, w), np.inf))
    return found


def _winner(count, cost, min_inliers, tie_break):
    """Index along the first axis of the best hypothesis of each problem: the most inliers; among
    as many (at least ``min_inliers``), the smallest cost; then the first."""
    most = count.max(axis=0)
    cost_key = np.where(count >= min_inliers, cost, 0.0) if tie_break else np.zeros(cost.shape)
    return np.argmin(np.where(count == most, cost_key, np.inf), axis=0)


def _take(a, w):
    """``a[w[b], ..., b]`` for every problem ``b`` (``a``: (n_hypotheses, [n_data,] *batch))."""
    idx = np.asarray(w).reshape((1,) * (a.ndim - np.ndim(w)) + np.shape(w))
    return np.take_along_axis(a, idx, axis=0)[0]
