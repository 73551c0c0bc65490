"""Ball orientation at one flash from its markers alone, by aligning marker types
(:func:`orient_flash`, no temporal information), and the nearest same-type marker of every
observation under a rotation."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.layout import BallLayout, _triad
from stillcap.ball.orientation._observations import _default_layout, _unit_rows
from stillcap.ball.orientation._so3 import _angles_to, _kabsch, _rot_angles


def _nearest_same_type(R, u, t, layout):
    """For rotations R (H,3,3): angle (rad) from each observation u (n,3) of type t (n,) to the
    nearest rotated model marker of its type, and that marker's index: (H, n), (H, n)."""
    model = np.einsum("hab,jb->hja", R, layout.directions)  # (H, 12, 3)
    cos = np.einsum("na,hja->hnj", u, model)  # (H, n, 12)
    same = layout.types[None, :] == t[:, None]  # (n, 12)
    cos = np.where(same[None], cos, -2.0)
    # the largest cosine is the one at argmax; np.minimum/np.maximum clip with less overhead
    # than take_along_axis and np.clip (this runs ~10 times per flash in orient_flash)
    return np.arccos(np.minimum(np.maximum(cos.max(-1), -1.0), 1.0)), cos.argmax(-1)


@dataclass
class FlashOrientation:
    """Orientation of the ball at one flash from its markers alone (:func:`orient_flash`).

    Attributes
    ----------
    ball2world : ndarray, shape (3, 3)
        NaN when undetermined (fewer than 2 usable markers).
    cost : float
        Robust cost ``sum min(D_M, cap)^2`` (rad^2) of the best hypothesis.
    n_inliers : int
        Markers within ``cap`` of a model marker of their type.
    rms_deg : float
        RMS angle of the inliers to their model markers.
    assigned : ndarray of int, shape (n,)
        Model marker of each observation.
    runner_up_cost : float
        Cost of the best hypothesis more than ``distinct_deg`` away (inf if none): close to
        ``cost`` means the flash alone is ambiguous.
    candidates : list of ndarray, shape (3, 3)
        The best distinct hypotheses, best first (starting points for the seed method).
    determined : bool
    """

    ball2world: np.ndarray
    cost: float
    n_inliers: int
    rms_deg: float
    assigned: np.ndarray
    runner_up_cost: float
    candidates: list = field(default_factory=list)
    determined: bool = True


_MODEL_TRIADS = {}


def _model_triads_t(m):
    """``_triad(m_i, m_j)^T`` of every ordered pair of layout markers, (n, n, 3, 3), kept per
    layout (orient_flash needs the same ones on every flash; row-wise the same numbers)."""
    key = m.tobytes()
    T = _MODEL_TRIADS.get(key)
    if T is None:
        n = len(m)
        i, j = np.divmod(np.arange(n * n), n)
        with np.errstate(invalid="ignore", divide="ignore"):  # i = j (never used) or antipodal
            T = np.transpose(_triad(m[i], m[j]), (0, 2, 1)).reshape(n, n, 3, 3)
        T.flags.writeable = False
        if len(_MODEL_TRIADS) >= 8:
            _MODEL_TRIADS.clear()
        _MODEL_TRIADS[key] = T
    return T


def orient_flash(directions, types, layout: BallLayout | None = None, *, cap_deg: float = 8.0,
                 pair_tol_deg: float = 8.0, n_candidates: int = 4,
                 distinct_deg: float = 10.0) -> FlashOrientation:
    """Ball orientation from one flash's markers, by aligning marker types (no prior).

    Every pair of observed markers and every pair of model markers with the same two types and
    nearly the same angle between them (within ``pair_tol_deg``) give a hypothesis; each is
    scored with the capped cost ``sum_i min(D_M(i), cap)^2`` and the best few are refined by
    re-assigning nearest same-type markers and a weighted Kabsch alignment of the inliers.

    Parameters
    ----------
    directions : array_like, shape (n, 3)
        Observed marker directions from the ball centre, world frame.
    types : array_like, shape (n,)
        Type names or indices.
    layout : BallLayout, optional
    cap_deg : float
        Inlier threshold / cost cap (about 4-5 times the direction noise).
    pair_tol_deg : float
        Tolerance on the angle between two markers when pairing.
    n_candidates : int
        Distinct hypotheses kept in ``candidates``.
    distinct_deg : float
        Hypotheses closer than this (rotation angle) count as the same.

    Returns
    -------
    FlashOrientation
    """
    layout = _default_layout(layout)
    u = as_array(directions, (None, 3), "directions")
    tt = np.asarray(types)
    if (len(u) and tt.dtype.kind in "iu" and tt.ndim == 1 and tt.size
            and 0 <= tt.min() and tt.max() < layout.n_types):
        t = tt.astype(int)  # indices already (fit_spin's observations): no per-element lookup
    else:
        t = layout.type_index(np.asarray(types, dtype=object).reshape(-1)) if len(u) else np.zeros(0, int)
    if len(t) != len(u):
        raise ValueError(f"types must have shape ({len(u)},), got {np.shape(types)}")
    nan3 = np.full((3, 3), np.nan)
    if len(u) < 2:
        return FlashOrientation(nan3, np.inf, 0, np.nan, np.full(len(u), -1), np.inf, [], False)
    u = _unit_rows(u, "directions")
    cap = np.radians(cap_deg)
    m = layout.directions
    # hypotheses: observed pair (a, b) -> model pair (i, j) of the same types and angle
    a_idx, b_idx = np.triu_indices(len(u), 1)
    cos_ab = np.einsum("ij,ij->i", u[a_idx], u[b_idx])
    ok = np.abs(cos_ab) < np.cos(np.radians(5.0))  # a pair must not be (anti)parallel
    a_idx, b_idx, cos_ab = a_idx[ok], b_idx[ok], cos_ab[ok]
    ang_model = np.arccos(np.clip(m @ m.T, -1, 1))
    # all (observed pair, model marker i, model marker j) at once: i of a's type, j of b's, i != j,
    # model angle within pair_tol_deg of the observed one; np.nonzero keeps the order of the
    # loop over observed pairs, then i, then j
    n_m = len(m)
    keep = ((layout.types[None, :, None] == t[a_idx][:, None, None])
            & (layout.types[None, None, :] == t[b_idx][:, None, None])
            & ~np.eye(n_m, dtype=bool)[None]
            & (np.abs(ang_model[None] - np.arccos(np.clip(cos_ab, -1, 1))[:, None, None])
               < np.radians(pair_tol_deg)))
    hp, hi, hj = np.nonzero(keep)
    if not len(hp):
        return FlashOrientation(nan3, np.inf, 0, np.nan, np.full(len(u), -1), np.inf, [], False)
    ha, hb = a_idx[hp], b_idx[hp]
    R = _triad(u[ha], u[hb]) @ _model_triads_t(m)[hi, hj]
    d, jh = _nearest_same_type(R, u, t, layout)
    cost = np.sum(np.minimum(d, cap) ** 2, axis=1)
    order = np.argsort(cost)
    # refine the best distinct hypotheses
    refined = []  # (R, cost, angles, assigned markers)
    # hypotheses within distinct_deg of a refined one are skipped: the mask is updated once per
    # refined rotation for all hypotheses (instead of testing each hypothesis against the list)
    near = np.zeros(len(R), bool)
    for h in order:
        if near[h]:
            continue
        refined.append(_refine(R[h], u, t, layout, cap, nearest=(d[h:h + 1], jh[h:h + 1])))
        if len(refined) >= max(n_candidates, 2) + 2:
            break
        near |= _angles_to(refined[-1][0], R) < np.radians(distinct_deg)
    refined.sort(key=lambda rc: rc[1])
    close = _rot_angles([rc[0] for rc in refined]) < np.radians(distinct_deg)  # all pairs at once
    kept = []
    for i in range(len(refined)):
        if not close[i, kept].any():
            kept.append(i)
    distinct = [refined[i] for i in kept]
    best, best_cost, d, j = distinct[0]
    inl = d < cap
    rms = float(np.degrees(np.sqrt(np.mean(d[inl] ** 2)))) if inl.any() else np.nan
    runner = distinct[1][1] if len(distinct) > 1 else np.inf
    determined = int(inl.sum()) >= 2
    return FlashOrientation(best if determined else nan3, float(best_cost), int(inl.sum()), rms, j,
                            float(runner), [rc[0] for rc in distinct[:n_candidates]], determined)


def _orient_flashes(obs, flashes, layout: BallLayout, cap_deg: float, kept: dict | None = None) -> dict:
    """:func:`orient_flash` of each flash in ``flashes`` of ``obs`` (MarkerObservations), the
    determined ones by flash index. ``kept``: a dict the caller keeps over several fits of the
    same markers (the pitch pipeline's fits of all pairs' markers from every alias candidate when
    the alias is in doubt: 8 fits of 16 flashes, ~1 ms a flash): each alignment is found there by
    its content (the flash's directions and types, the layout, ``cap_deg``; it depends on nothing
    else) or made and put there, read-only. None: every alignment made anew."""
    out = {}
    lay = (layout.directions.tobytes(), np.asarray(layout.types).tobytes(), float(cap_deg))
    for k in flashes:
        u, t = obs.of_flash(k)
        key = None if kept is None else (np.ascontiguousarray(u).tobytes(), t.tobytes(), t.dtype.str) + lay
        fo = None if key is None else kept.get(key)
        if fo is None:
            fo = orient_flash(u, t, layout, cap_deg=cap_deg)
            if key is not None:
                for a in [fo.ball2world, fo.assigned, *fo.candidates]:
                    a.flags.writeable = False
                kept[key] = fo
        if fo.determined:
            out[int(k)] = fo
    return out


def _refine(R, u, t, layout, cap, iters: int = 5, nearest=None):
    """Re-assign nearest same-type markers and realign the inliers (Kabsch); keep the best.

    ``nearest``: ``_nearest_same_type(R[None], u, t, layout)`` when known (orient_flash has it
    for every hypothesis). Returns ``(R, cost, angles (n,), assigned markers (n,))`` of the best."""
    d, j = _nearest_same_type(R[None], u, t, layout) if nearest is None else nearest
    best = (R, float(np.sum(np.minimum(d[0], cap) ** 2)), d[0], j[0])
    for _ in range(iters):
        inl = d[0] < cap
        if inl.sum() < 2:
            break
        R = _kabsch(layout.directions[j[0][inl]], u[inl])
        d, j = _nearest_same_type(R[None], u, t, layout)
        cost = float(np.sum(np.minimum(d[0], cap) ** 2))
        if cost >= best[1] - 1e-12:
            break
        best = (R, cost, d[0], j[0])
    return best
