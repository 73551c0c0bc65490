"""Flash numbering: which strobe flash each of a throw's ball positions was photographed at.

Two ways, for two kinds of capture; both give a flash index per ball position, counted along
the flight, with gaps where flashes were missed:

- :func:`number_flashes_from_spacing` (the pitch pipeline, and the hand capture without hand poses): the
  positions are ordered along the flight direction and each gap counted in flashes from the
  spacing (``round(gap / base spacing)``). It needs nothing but the positions and trusts the
  ball's speed to be nearly constant across a gap (a pitch in flight: drag changes it by ~10 %
  over the whole flight).
- :func:`number_flashes_from_hand` (the hand capture): the positions, already in time order, are mapped
  onto the flashes of the hand's poses so that the leading ones sit at one point of the hand
  and the rest leave it along the hold point's path. An accelerating arm fools the spacing; the
  hand does not. It returns ``success=False`` when no map has a held run, and the caller falls
  back to :func:`number_flashes_from_spacing`.

:func:`flight_axis` and :func:`off_flight_path` are the pitch pipeline's helpers around
:func:`number_flashes_from_spacing`: the flight's principal direction, and the stray detections off it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.release import hold_point_path

__all__ = ["FlashNumbers", "flight_axis", "number_flashes_from_hand", "off_flight_path", "number_flashes_from_spacing"]


def flight_axis(points: np.ndarray) -> np.ndarray:
    """Principal direction of a set of 3D points (first right singular vector of the centred
    points; sign arbitrary)."""
    c = points - points.mean(axis=0)
    return np.linalg.svd(c, full_matrices=False)[2][0]


def off_flight_path(points: np.ndarray, direction: np.ndarray, tol_m: float = 0.03) -> np.ndarray:
    """Points further than ``tol_m`` (or 6 robust sigmas) from a quadratic fitted to the lateral
    coordinates along ``direction``: stray detections, wrong matches (bool mask)."""
    n = len(points)
    bad = np.zeros(n, bool)
    if n < 5:
        return bad
    s = points @ direction
    lat = points - np.outer(s, direction)
    A = np.stack([np.ones(n), s - s.mean(), (s - s.mean()) ** 2], axis=1)
    for _ in range(2):
        keep = ~bad
        if keep.sum() < 4:
            break
        coef, *_ = np.linalg.lstsq(A[keep], lat[keep], rcond=None)
        r = np.linalg.norm(lat - A @ coef, axis=1)
        mad = 1.4826 * np.median(r[keep])
        bad = r > max(tol_m, 6.0 * mad)
    return bad


def number_flashes_from_spacing(points, direction, strobe_hz: float, expected_spacing_m: float | None = None):
    """Order a pair's 3D ball positions along the flight and give each its flash index.

    Parameters
    ----------
    points : array_like, shape (K, 3)
    direction : array_like, shape (3,)
        Flight direction (any length).
    strobe_hz : float
    expected_spacing_m : float, optional
        Distance between consecutive flashes (``speed / strobe_hz``); default: the smallest
        spacing refined by the spacing ratios (each rounded to a whole number of flashes).

    Returns
    -------
    order : ndarray of int, shape (K',)
        Indices into ``points`` in flight order (duplicates, spacing ~0, dropped).
    flash_index : ndarray of int, shape (K',)
        Flash counted from the first, gaps for missed flashes.
    spacing_m : float
        Base spacing, m.
    """
    P = np.asarray(points, float)
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    order = np.argsort(P @ d)
    if len(order) < 2:
        return order, np.zeros(len(order), int), float("nan")
    # drop duplicates (two detections of one ball image)
    keep = [order[0]]
    for i in order[1:]:
        if np.linalg.norm(P[i] - P[keep[-1]]) > 0.3 * (expected_spacing_m or 0.0) + 0.02:
            keep.append(i)
    order = np.array(keep)
    gaps = np.linalg.norm(np.diff(P[order], axis=0), axis=1)
    if len(gaps) == 0:
        return order, np.zeros(1, int), float("nan")
    s = float(expected_spacing_m) if expected_spacing_m else float(gaps.min())
    for _ in range(3):
        k = np.maximum(np.rint(gaps / s), 1)
        s = float(gaps.sum() / k.sum())
    k = np.maximum(np.rint(gaps / s), 1).astype(int)
    return order, np.concatenate([[0], np.cumsum(k)]).astype(int), s


@dataclass
class FlashNumbers:
    """Flash of each ball position, from the hand poses (:func:`number_flashes_from_hand`).

    Attributes
    ----------
    success : bool
        An assignment with a held run was found (else ``flash`` / ``times`` are NaN/-1).
    flash : ndarray of int, shape (m,)
        Flash number of each ball position on the hand's clock (``round(t * strobe_hz)``).
    times : ndarray, shape (m,)
        ``flash / strobe_hz``, s (same clock as ``hold_times``).
    n_held : int
        Leading positions at one point of the hand.
    cost, margin : float
        Normalised squared misfit of the best assignment, and how much worse the runner-up is.
    message : str
    """

    success: bool
    flash: np.ndarray
    times: np.ndarray
    n_held: int = 0
    cost: float = float("nan")
    margin: float = float("nan")
    message: str = ""


def number_flashes_from_hand(ball_positions, hold_times, root2world, *, strobe_hz: float, hold_tol_m: float = 0.012,
                   hold_sigma_m: float = 0.004, free_sigma_m: float = 0.03, min_held: int = 2,
                   max_after: int = 3) -> FlashNumbers:
    """Number the ball's flashes by the hand poses instead of by the ball's spacing.

    The arm speeds up across the window, so a gap in the ball's spacing does not say how many
    flashes are missing. The hand does: every increasing map of the ball positions (given in
    time order, e.g. along the throw) onto the flashes from one before the first hand pose to
    ``max_after`` after the last is scored, and the best kept:

    - **held** positions: the leading run (at least ``min_held`` with a hand pose) whose
      hand-frame positions ``R^T (p - t)`` at their flash agree within ``hold_tol_m``; misfit
      to their mean over ``hold_sigma_m``; positions at flashes before the first hand pose
      (whose back of the hand was not seen) lead the run unchecked;
    - **free** positions (the rest): they lie on the tangent to the hold-point path from one
      release time between the last held and the first free flash,
      ``h(t_r) + h'(t_r) (t - t_r)`` (the model of
      :func:`stillcap.ball.release.estimate_release`, without its small gravity term); misfit
      over ``free_sigma_m`` (the speed's few-% model error).

    A wrong flash number moves a free prediction by a whole flash of travel (~0.4 m), or breaks
    the held run. Without a map that has a held run, ``success`` is False: the caller falls back
    to the spacing.

    Parameters
    ----------
    ball_positions : array_like, shape (m, 3)
        In time order, no NaN.
    hold_times : array_like, shape (n,)
        Times of the hand poses, s (flash ``k`` at ``k / strobe_hz``).
    root2world : array_like, shape (n, 4, 4)
    strobe_hz : float

    Returns
    -------
    FlashNumbers
    """
    from itertools import combinations

    P = as_array(ball_positions, (None, 3), "ball_positions")
    t_h = as_array(hold_times, (None,), "hold_times")
    T = as_array(root2world, (len(t_h), 4, 4), "root2world")
    if not (np.isfinite(strobe_hz) and strobe_hz > 0):
        raise ValueError(f"strobe_hz must be positive, got {strobe_hz}")
    m = len(P)
    fail = FlashNumbers(False, np.full(m, -1), np.full(m, np.nan))
    hand_ok = np.all(np.isfinite(T.reshape(len(t_h), -1)), axis=1) & np.isfinite(t_h)
    t_h, T = t_h[hand_ok], T[hand_ok]
    if len(t_h) < 2 or m < min_held or not np.all(np.isfinite(P)):
        fail.message = "flash numbering from the hand needs 2+ hand poses and finite ball positions"
        return fail
    f_h = np.rint(t_h * strobe_hz).astype(int)
    cand = np.arange(f_h.min() - 1, f_h.max() + max_after + 1)
    if m > len(cand):
        fail.message = f"{m} ball positions but only {len(cand)} candidate flashes"
        return fail
    j_of = {int(f): j for j, f in enumerate(f_h)}
    Q = np.einsum("jba,ijb->ija", T[:, :3, :3], P[:, None, :] - T[None, :, :3, 3])  # (m, n, 3)
    results = []
    path_cache = {}
    for combo in combinations(cand, m):
        fl = np.array(combo)
        run, verified = [], []
        for i in range(m):
            j = j_of.get(int(fl[i]))
            if j is None:
                if not verified and fl[i] < f_h.min():
                    run.append(i)  # before the first hand pose: held, but nothing to check it against
                    continue
                break
            trial = verified + [i]
            q = np.array([Q[r, j_of[int(fl[r])]] for r in trial])
            if np.max(np.linalg.norm(q - q.mean(axis=0), axis=1)) > hold_tol_m:
                break
            verified = trial
            run.append(i)
        if len(verified) < min_held:
            continue
        q = np.array([Q[r, j_of[int(fl[r])]] for r in verified])
        c = q.mean(axis=0)
        # an unchecked held position costs a 3-sigma misfit: a flash with a hand pose that
        # agrees is preferred to one before the hand poses, where nothing can disagree
        cost = float(np.sum((q - c) ** 2)) / hold_sigma_m ** 2 + 9.0 * (len(run) - len(verified))
        free = list(range(len(run), m))
        if free:
            key = tuple(np.round(c, 6))
            if key not in path_cache:
                hp = np.einsum("kab,b->ka", T[:, :3, :3], c) + T[:, :3, 3]
                path_cache[key] = hold_point_path(t_h, hp)
            h, dh = path_cache[key]
            t_lo, t_hi = fl[run[-1]] / strobe_hz, fl[free[0]] / strobe_hz
            tf = fl[free] / strobe_hz
            best = np.inf
            for tr in np.linspace(t_lo, t_hi, 25):
                pred = np.asarray(h(tr)) + np.outer(tf - tr, np.asarray(dh(tr)))
                best = min(best, float(np.sum((pred - P[free]) ** 2)))
            cost += best / free_sigma_m ** 2
        results.append((cost, fl, len(run)))
    if not results:
        fail.message = "no flash numbering puts 2+ leading ball positions at one point of the hand"
        return fail
    results.sort(key=lambda r: r[0])
    cost, fl, nh = results[0]
    margin = results[1][0] - cost if len(results) > 1 else float("inf")
    return FlashNumbers(True, fl.copy(), fl / float(strobe_hz), nh, cost, margin,
                        f"flashes numbered from the hand: {nh} held, {m - nh} free; cost {cost:.1f}, "
                        f"runner-up +{margin:.1f}")
