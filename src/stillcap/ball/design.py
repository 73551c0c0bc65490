"""Designing a marker layout for N markers of K types (``stillcap balls design``).

What makes a layout good is what :mod:`stillcap.ball.layout` describes and checks: from every
view direction the visible markers (those within ``90 deg - margin`` of the view) must fix the
ball frame, i.e. no rotation other than the identity may carry the visible markers onto markers
of the same types, and the best wrong rotation should miss by as much as possible (the
*separation*); and every view should show several types.

:meth:`BallLayout.separation_deg` searches the rotations that map a marker pair exactly onto
another pair of the same angle, which suits symmetric layouts (the seed's). A designed layout has
no exact symmetries, so here the search also takes the *near* matches: every rotation carrying
an ordered pair of markers onto another pair of the same types whose angle differs by less than
``tol_deg`` (:func:`near_separation_deg`); a wrong rotation that nearly explains the visible
markers then counts, as it does for the orientation fit with noisy markers.

The design (:func:`design_layout`):

1. positions spread evenly on the sphere: a Fibonacci lattice relaxed by a few hundred steps of
   Coulomb repulsion (hand-written: a dozen lines; no library does the Thomson problem);
2. types: ``N`` markers split into ``K`` nearly equal groups, the assignment chosen by random
   restarts and pairwise swaps (hill climbing), maximising lexicographically (a) the share of
   views, at a 10 deg margin, from which the frame is determined to better than ``min_sep_deg``,
   (b) the smallest near-separation over those views, (c) the share of views showing 3 types.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from stillcap._checks import as_rng
from stillcap.ball.layout import BallLayout, fibonacci_sphere, _triad

__all__ = ["spread_directions", "near_rotations", "near_separation_deg", "LayoutScore", "score_layout",
           "design_layout"]


def spread_directions(n: int, steps: int = 300, rng=0) -> np.ndarray:
    """``n`` unit vectors spread evenly (relaxed Fibonacci lattice, slightly jittered first so
    that no exact symmetry survives), shape (n, 3)."""
    rng = as_rng(rng)
    if n < 2:
        raise ValueError(f"a layout needs at least 2 markers, got {n}")
    p = fibonacci_sphere(n) + 0.02 * rng.standard_normal((n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    step = 0.1 / n
    for _ in range(int(steps)):
        d = p[:, None, :] - p[None, :, :]
        r2 = np.einsum("ijk,ijk->ij", d, d) + np.eye(n)
        f = (d / r2[..., None] ** 1.5).sum(1)
        f -= np.einsum("ij,ij->i", f, p)[:, None] * p  # tangential part
        p = p + step * f / max(np.abs(f).max(), 1e-12)
        p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p


def near_rotations(directions, tol_deg: float = 8.0) -> np.ndarray:
    """Rotations other than the identity carrying an ordered marker pair ``(i, j)`` onto another
    ``(a, b)`` whose angle differs by less than ``tol_deg`` (the pair's bisector and plane onto
    the other's), shape (q, 3, 3). Types do not enter: a rotation is wrong when it carries the
    *visible* markers onto markers of their types, whichever pair suggested it."""
    d = np.asarray(directions, float)
    n = len(d)
    ang = np.degrees(np.arccos(np.clip(d @ d.T, -1.0, 1.0)))
    i, j = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    ok = (i != j) & (ang[i, j] < 179.0)
    i, j = i[ok], j[ok]
    src, dst = np.nonzero(np.abs(ang[i, j][:, None] - ang[i, j][None, :]) < tol_deg)
    keep = src != dst
    src, dst = src[keep], dst[keep]
    if not len(src):
        return np.zeros((0, 3, 3))
    qs = _triad(d[i[dst]], d[j[dst]]) @ np.swapaxes(_triad(d[i[src]], d[j[src]]), -1, -2)
    qs = qs[np.abs(qs - np.eye(3)).max(axis=(1, 2)) > 1e-6]
    if not len(qs):
        return qs
    # many pairs suggest nearly the same rotation: one per cell of 0.05 in the matrix entries
    # (~3 deg), so the separations are found to within about that (and a design runs in seconds)
    _, first = np.unique(np.round(qs.reshape(len(qs), 9) / 0.05), axis=0, return_index=True)
    return qs[np.sort(first)]


@lru_cache(maxsize=4)
def _rotated_cosines(directions_bytes: bytes, n: int, tol_deg: float) -> np.ndarray:
    """``cos`` of the angles between each near-rotated marker and every marker, (q, n, n)
    (geometry only: cached, the type assignments of a design share it)."""
    d = np.frombuffer(directions_bytes).reshape(n, 3)
    qs = near_rotations(d, tol_deg)
    return np.einsum("qab,nb->qna", qs, d) @ d.T


def near_separation_deg(layout: BallLayout, visible, tol_deg: float = 8.0) -> np.ndarray:
    """Per view (rows of ``visible``, bool (V, n)): the smallest, over the near rotations
    (:func:`near_rotations`), of the largest angle between a rotated visible marker and the
    nearest marker of its type, deg; 0 for fewer than 2 visible markers."""
    vis = np.atleast_2d(np.asarray(visible, bool))
    d = np.ascontiguousarray(layout.directions)
    cos = _rotated_cosines(d.tobytes(), len(d), float(tol_deg))
    if not len(cos):
        return np.where(vis.sum(1) >= 2, 180.0, 0.0)
    same = layout.types[:, None] == layout.types[None, :]
    mis = np.degrees(np.arccos(np.clip(np.where(same[None], cos, -1.0).max(-1), -1.0, 1.0)))  # (q, n)
    worst = np.where(vis[:, None, :], mis[None], -np.inf).max(-1)  # (V, q)
    return np.where(vis.sum(1) >= 2, np.maximum(worst.min(-1), 0.0), 0.0)


@dataclass(frozen=True)
class LayoutScore:
    """How well a layout fixes the ball frame from sampled views at a visibility margin.

    Attributes
    ----------
    margin_deg : float
    share_determined : float
        Views whose near-separation reaches ``min_sep_deg``.
    min_separation_deg, median_separation_deg : float
        Near-separation over the views.
    share_3_types : float
        Views showing at least 3 types (or all types when there are fewer).
    min_types : int
    """

    margin_deg: float
    share_determined: float
    min_separation_deg: float
    median_separation_deg: float
    share_3_types: float
    min_types: int

    def key(self) -> tuple:
        return (round(self.share_determined, 4), round(self.min_separation_deg, 3), round(self.share_3_types, 4),
                round(self.median_separation_deg, 3))


def score_layout(layout: BallLayout, margin_deg: float = 10.0, n_views: int = 300, tol_deg: float = 8.0,
                 min_sep_deg: float = 5.0, view_dirs=None) -> LayoutScore:
    """:class:`LayoutScore` of ``layout`` from ``n_views`` Fibonacci view directions."""
    v = fibonacci_sphere(n_views) if view_dirs is None else np.asarray(view_dirs, float)
    vis = layout.visible(v, margin_deg)
    sep = near_separation_deg(layout, vis, tol_deg)
    onehot = np.eye(layout.n_types, dtype=int)[layout.types]
    ntypes = ((vis.astype(int) @ onehot) > 0).sum(1)
    return LayoutScore(float(margin_deg), float(np.mean(sep >= min_sep_deg)), float(sep.min()),
                       float(np.median(sep)), float(np.mean(ntypes >= min(3, layout.n_types))), int(ntypes.min()))


@dataclass(frozen=True)
class _Both:
    """Scores at the design margin and 5 deg more: determined from both first."""

    at: LayoutScore
    wider: LayoutScore

    def key(self) -> tuple:
        return (round(self.wider.share_determined, 4),) + self.at.key()


def design_layout(n: int, n_types: int = 4, *, template: BallLayout | None = None, directions=None,
                  restarts: int = 6, sweeps: int = 3, rng=0, margin_deg: float = 10.0, n_views: int = 300,
                  **layout_kwargs) -> tuple[BallLayout, LayoutScore]:
    """A layout of ``n`` markers of ``n_types`` types maximising :func:`score_layout` (module
    docstring).

    Parameters
    ----------
    n, n_types : int
    template : BallLayout, optional
        Type names, shapes, palette, size and radius to use (default the seed's, whose 4 types
        are red square, blue ring, green triangle, black disc); ``n_types`` of its types.
    directions : array_like, shape (n, 3), optional
        Marker positions to keep (only the types are designed); default :func:`spread_directions`.
    restarts, sweeps : int
        Random type assignments tried, and rounds of pairwise swaps from each.
    rng : int or Generator
    margin_deg, n_views : see :func:`score_layout`.
    layout_kwargs
        Passed to :class:`BallLayout` (``radius``, ``name``, ``marker_size``, ...).

    Returns
    -------
    (BallLayout, LayoutScore)
    """
    rng = as_rng(rng)
    tpl = template or BallLayout.seed()
    if not 1 <= n_types <= tpl.n_types:
        raise ValueError(f"n_types must be in 1..{tpl.n_types} (the template's types), got {n_types}")
    if n < max(2, n_types):
        raise ValueError(f"need at least {max(2, n_types)} markers for {n_types} types, got {n}")
    d = spread_directions(n, rng=rng) if directions is None else np.asarray(directions, float)
    if d.shape != (n, 3):
        raise ValueError(f"directions must have shape ({n}, 3), got {d.shape}")
    views = fibonacci_sphere(n_views)
    names = tpl.type_names[:n_types]
    kw = {"type_names": names, "type_shapes": tpl.type_shapes[:n_types],
          "palette": {k: tpl.palette[k] for k in names}, "marker_size": tpl.marker_size, "radius": tpl.radius,
          "type_sizes": tuple(tpl.sizes_of_types[:n_types]) if tpl.type_sizes else (), **layout_kwargs}
    base = np.arange(n) % n_types

    def score(t):
        lay = BallLayout(d, t, **kw)
        return _Both(score_layout(lay, margin_deg, view_dirs=views), score_layout(lay, margin_deg + 5.0, view_dirs=views))

    best_t, best = None, None
    for _ in range(int(restarts)):
        t = rng.permutation(base)
        s = score(t)
        for _ in range(int(sweeps)):
            improved = False
            for a in range(n):
                for b in range(a + 1, n):
                    if t[a] == t[b]:
                        continue
                    t2 = t.copy()
                    t2[a], t2[b] = t[b], t[a]
                    s2 = score(t2)
                    if s2.key() > s.key():
                        t, s, improved = t2, s2, True
            if not improved:
                break
        if best is None or s.key() > best.key():
            best_t, best = t, s
    return BallLayout(d, best_t, **kw), best.at
