"""Epipolar geometry of two calibrated cameras and optimal two-view matching."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from stillcap._checks import as_array
from stillcap.camera import Camera


def _skew(v) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def essential_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """E with ``xn_b^T E xn_a = 0`` for normalised coordinates of the same world point."""
    a2b = cam_b.world2cam @ cam_a.cam2world
    return _skew(a2b[:3, 3]) @ a2b[:3, :3]


def fundamental_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """F with ``x_b^T F x_a = 0`` for undistorted pixels ``x_a`` (camera a), ``x_b`` (camera b)."""
    F = np.linalg.inv(cam_b.K).T @ essential_matrix(cam_a, cam_b) @ np.linalg.inv(cam_a.K)
    return F / np.linalg.norm(F)


def epipolar_distances(cam_a: Camera, cam_b: Camera, pts_a, pts_b) -> np.ndarray:
    """Symmetric epipolar distance (px) between every pair, shape (Na, Nb).

    The mean of the distance of ``b`` to the epipolar line of ``a`` and vice versa, on
    undistorted pixels. NaN points give NaN rows/columns.
    """
    xa = cam_a.undistort_points(as_array(pts_a, (None, 2), "pts_a"))
    xb = cam_b.undistort_points(as_array(pts_b, (None, 2), "pts_b"))
    F = fundamental_matrix(cam_a, cam_b)
    ha = np.concatenate([xa, np.ones((len(xa), 1))], axis=1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1)
    lines_b = ha @ F.T  # epipolar lines in b of points in a, (Na, 3)
    lines_a = hb @ F    # epipolar lines in a of points in b, (Nb, 3)
    num = hb @ lines_b.T  # (Nb, Na): x_b^T F x_a
    da = np.abs(num.T) / np.linalg.norm(lines_b[:, :2], axis=1)[:, None]
    db = np.abs(num.T) / np.linalg.norm(lines_a[:, :2], axis=1)[None, :]
    return 0.5 * (da + db)


@dataclass
class EpipolarMatches:
    """Matched index pairs between two views.

    pairs : (K, 2) int array of (index in a, index in b); distance_px : (K,) epipolar distance.
    """

    pairs: np.ndarray
    distance_px: np.ndarray
    unmatched_a: np.ndarray
    unmatched_b: np.ndarray


def match_epipolar(cam_a: Camera, cam_b: Camera, pts_a, pts_b, max_px: float = 3.0,
                   labels_a=None, labels_b=None, order_a=None, order_b=None) -> EpipolarMatches:
    """Optimal one-to-one matching of two views' points by epipolar distance.

    Minimises the total symmetric epipolar distance (``linear_sum_assignment``) over pairs whose
    distance is below ``max_px`` and, if labels (e.g. marker colours) are given, whose labels are
    equal. Points that have no admissible partner stay unmatched.

    With ``order_a`` and ``order_b`` (each point's place along one curve seen by both views, e.g.
    a flight's ball images along its track), the choice among several admissible partners also
    keeps that order: see :func:`_order_ambiguous`. Where every point has at most one admissible
    partner the result is the same as without.

    Parameters
    ----------
    pts_a : array_like, shape (Na, 2); pts_b : array_like, shape (Nb, 2)
        Distorted pixels; NaN rows never match.
    labels_a, labels_b : sequence of hashable, optional, lengths Na and Nb
    order_a, order_b : array_like of float, optional, shapes (Na,) and (Nb,)
        The points' coordinate along the curve in each view (either direction; both or neither).
    """
    pa = as_array(pts_a, (None, 2), "pts_a")
    pb = as_array(pts_b, (None, 2), "pts_b")
    empty = np.zeros((0, 2), int)
    if len(pa) == 0 or len(pb) == 0:
        return EpipolarMatches(empty, np.zeros(0), np.arange(len(pa)), np.arange(len(pb)))
    d = epipolar_distances(cam_a, cam_b, pa, pb)
    allowed = np.isfinite(d) & (d <= max_px)
    if labels_a is not None or labels_b is not None:
        if labels_a is None or labels_b is None or len(labels_a) != len(pa) or len(labels_b) != len(pb):
            raise ValueError(
                f"labels must be given for both views with one label per point "
                f"(points {len(pa)} and {len(pb)})"
            )
        la, lb = np.asarray(labels_a, object), np.asarray(labels_b, object)
        allowed &= la[:, None] == lb[None, :]
    # Forbidden pairs get a cost above any sum of admissible ones, then are dropped.
    big = 1e6 * (max_px + 1.0) * (min(d.shape) + 1)
    cost = np.where(allowed, d, big)
    rows, cols = linear_sum_assignment(cost)
    keep = allowed[rows, cols]
    rows, cols = rows[keep], cols[keep]
    if (order_a is None) != (order_b is None):
        raise ValueError("order_a and order_b must be given together")
    if order_a is not None:
        rows, cols = _order_ambiguous(d, allowed, rows, cols, as_array(order_a, (len(pa),), "order_a"),
                                      as_array(order_b, (len(pb),), "order_b"))
    return EpipolarMatches(np.stack([rows, cols], axis=1).astype(int), d[rows, cols],
                           np.setdiff1d(np.arange(len(pa)), rows), np.setdiff1d(np.arange(len(pb)), cols))


def _order_ambiguous(d, allowed, rows, cols, order_a, order_b):
    """The minimum-distance assignment ``(rows, cols)`` with each ambiguous group of points
    re-assigned in the order of their curve coordinates ``order_a`` / ``order_b``.

    A group is a connected component of the admissible pairs (``allowed``, (Na, Nb)) with more
    than one pair: the gate let a point choose among several partners, and the smallest total
    distance decides by the points' centre noise when they lie along the epipolar lines (a
    flight's ball images near its vanishing point). The images of one curve keep their order
    along it in both views, so the group takes the order-preserving assignment (same or
    reversed order: the one the minimum-distance pairs show overall, else the group's own
    choice) with the most pairs and then the smallest total distance
    (:func:`_monotone_assignment`). It has fewer pairs than the minimum-distance one only where
    that one breaks the order, e.g. where centre noise put a true pair outside the gate and the
    smallest distance filled the gap with wrong pairs (a drawn flight, 17 of 600 noise draws:
    30 wrong pairs kept, 10 taking the order). Groups of one pair are never touched."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    na, nb = allowed.shape
    ia, ib = np.nonzero(allowed)
    n_comp, lab = connected_components(coo_matrix((np.ones(len(ia)), (ia, na + ib)), shape=(na + nb,) * 2),
                                       directed=False)
    edges = np.bincount(lab[ia], minlength=n_comp)
    groups = [c for c in np.unique(lab[ia]) if edges[c] > 1]
    if not groups:
        return rows, cols
    # the direction the matches show (Kendall's sign over all pairs: a swap inside a group
    # turns a few of its pairs' signs only)
    sa, sb = order_a[rows], order_b[cols]
    direction = int(np.sign(np.sum(np.sign(sa[:, None] - sa[None]) * np.sign(sb[:, None] - sb[None]))))
    pairs = dict(zip(rows.tolist(), cols.tolist()))
    for c in groups:
        ga, gb = np.flatnonzero(lab[:na] == c), np.flatnonzero(lab[na:] == c)
        ga, gb = ga[np.argsort(order_a[ga], kind="stable")], gb[np.argsort(order_b[gb], kind="stable")]
        best = None
        for sgn in ((direction,) if direction else (1, -1)):
            gbs = gb if sgn > 0 else gb[::-1]
            cand = _monotone_assignment(d[np.ix_(ga, gbs)], allowed[np.ix_(ga, gbs)])
            score = (len(cand), -sum(d[ga[i], gbs[j]] for i, j in cand))
            if best is None or score > best[0]:
                best = (score, [(ga[i], gbs[j]) for i, j in cand])
        for a in ga:
            pairs.pop(a, None)
        pairs.update((int(a), int(b)) for a, b in best[1])
    rows = np.array(sorted(pairs), int)
    return rows, np.array([pairs[a] for a in rows.tolist()], int)


def _monotone_assignment(d, allowed) -> list:
    """Order-preserving one-to-one pairs ``(i, j)`` (``i`` and ``j`` both increasing) among the
    ``allowed`` ones (n, m) with the most pairs, then the smallest total ``d``: the dynamic
    programme of a sequence alignment (no library has it; n, m are a handful of ball images)."""
    n, m = allowed.shape
    # best[i, j] = (pairs, -distance) over the first i rows and j columns
    best = np.zeros((n + 1, m + 1, 2))
    step = np.zeros((n + 1, m + 1), int)  # 0: skip row, 1: skip column, 2: pair (i-1, j-1)
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            opts = [tuple(best[i - 1, j]), tuple(best[i, j - 1])]
            if allowed[i - 1, j - 1]:
                opts.append((best[i - 1, j - 1, 0] + 1, best[i - 1, j - 1, 1] - d[i - 1, j - 1]))
            k = max(range(len(opts)), key=lambda q: opts[q])
            best[i, j], step[i, j] = opts[k], k
    out, i, j = [], n, m
    while i > 0 and j > 0:
        if step[i, j] == 2:
            out.append((i - 1, j - 1))
            i, j = i - 1, j - 1
        elif step[i, j] == 1:
            j -= 1
        else:
            i -= 1
    return out[::-1]
