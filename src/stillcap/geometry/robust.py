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
    """What :func:`consensus` needs of a model."""

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
    best = best_count = best_cost = inliers = None
    for index, hypothesis in enumerate(hypotheses):
        r = np.asarray(model.residuals(model.estimate(hypothesis)), float)
        inl = (r <= threshold) if inclusive else (r < threshold)  # NaN: never an inlier
        count = inl.sum(axis=0)
        cost = np.where(inl, r, 0.0).sum(axis=0)
        if best is None:
            best = np.full(count.shape, -1)
            best_count = np.zeros(count.shape, int)
            best_cost = np.full(count.shape, np.inf)
            inliers = np.zeros(inl.shape, bool)
        better = count > best_count
        if tie_break:
            better |= (count == best_count) & (count >= min_inliers) & (cost < best_cost)
        best = np.where(better, index, best)
        best_count = np.where(better, count, best_count)
        best_cost = np.where(better, cost, best_cost)
        inliers = np.where(better, inl, inliers)  # better (batch) broadcasts over the data axis
    if best is None:
        raise ValueError("consensus needs at least one hypothesis")
    return Consensus(best, inliers, best_count, best_cost)
