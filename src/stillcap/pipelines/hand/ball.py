"""The ball in a hand capture: 3D positions per flash, and optionally its spin (issue 5).

Wiring only (``docs/hand-ball.md``):

1. **Whiteness image.** The glove and sleeves are dark grey, the hand markers saturated colours,
   the ball white: the per-pixel minimum over B, G, R keeps the ball and drops the rest. It is
   what :func:`stillcap.ball.stereo.ball_centers_stereo` sees (detection, matching, known-radius
   Hough refinement), thresholded per photo between the glove and the ball (:func:`white_threshold_level`).
2. **Every two cameras** (``pairs="all"``, default; or the rig's stereo pairs): matched ball
   images whose refinement failed, whose size disagrees with the projected radius, or that touch
   the border are dropped (as the pitch pipeline does). Fingers often hide the first free ball
   from one camera of each stereo pair; the cross pairs still see it.
3. **Merge**: the point most other views agree with wins; its centre is refined again in every
   view that sees the ball and all agreeing views are triangulated together with view outlier
   rejection (:func:`stillcap.geometry.triangulate.triangulate`, ``outlier_px``).
4. **Order and flashes**: positions sorted along the throw (field frame: toward -y). With the
   hand's poses (``hand=(hold_times, root2world)``) the flashes are numbered from the hand
   (:func:`stillcap.ball.flashes.number_flashes_from_hand`), on the hand's clock; without them from the
   spacing (:func:`stillcap.ball.flashes.number_flashes_from_spacing`: a missed flash leaves a gap, but an
   accelerating arm can fool it), time of flash ``k`` ``k / strobe_hz`` from the first ball.
   The hand pipeline finds the ball first (its discs mask the glove-marker search) and numbers
   its flashes once the hand poses exist.
5. **Uncertainty** per position: the reprojection RMS (at least ``pixel_sigma``; at least
   ``two_view_pixel_sigma`` for a ball seen by two views only, which no third view can check)
   carried through the views' ray geometry (Gauss-Newton covariance).

:func:`hand_ball_spin` fits the spin from the painted markers of the free-flight flashes
(:func:`stillcap.ball.orientation.fit_spin`); one 75 Hz strobe leaves the alias open: the
candidates are reported and the result says it is ambiguous.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from stillcap.ball.layout import BASEBALL_RADIUS
from stillcap.camera import Rig
from stillcap.detect.ball import BallFlag
from stillcap.ball.stereo import ball_centers_stereo
from stillcap.geometry.triangulate import triangulate

__all__ = ["HandBalls", "HandBallSpin", "hand_ball_positions", "hand_ball_spin", "white_threshold_level", "whiteness"]

_DROP = int(BallFlag.REFINE_FAILED | BallFlag.SIZE_MISMATCH | BallFlag.TOUCHES_BORDER)


def whiteness(image) -> np.ndarray:
    """Per-pixel minimum over the colour channels, ``uint8`` (H, W): white stays bright, the
    dark glove and the saturated hand markers go dark."""
    img = np.asarray(image)
    if img.ndim == 2:
        return img
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3) or (H, W), got {img.shape}")
    if img.dtype == np.uint8:  # OpenCV's per-element minimum: 10x faster than a NumPy reduction
        b, g, r = cv2.split(np.ascontiguousarray(img))
        return cv2.min(cv2.min(b, g), r)
    return img.min(axis=2)


@dataclass
class HandBalls:
    """Ball positions of a hand capture, in flash order (rig world frame, SI).

    Attributes
    ----------
    positions : ndarray, shape (K, 3)
        Ball centres, m.
    sigma_m : ndarray, shape (K,)
        1-sigma per coordinate (RMS over the three axes) of each position, m.
    flash_index : ndarray of int, shape (K,)
        Flash of each position: on the hand's clock when ``hand`` was given (and numbering from
        it succeeded), else counted from the first ball position (gaps = flashes without a
        ball position).
    times : ndarray, shape (K,)
        ``flash_index / strobe_hz``, s.
    centers_px : ndarray, shape (n_cams, K, 2)
        Refined ball centre in every camera's photo (raw pixels), NaN where not used.
    radius_px : ndarray, shape (n_cams, K)
        Projected ball radius in every camera (NaN where the ball is outside the photo).
    views : ndarray of bool, shape (n_cams, K)
        Views used by the triangulation.
    pair_points : dict
        Per pair name the 3D points it gave (after its own quality filter), (k, 3).
    reproj_error_px : ndarray, shape (K,)
    strobe_hz : float
    messages : list of str
    """

    positions: np.ndarray
    sigma_m: np.ndarray
    flash_index: np.ndarray
    times: np.ndarray
    centers_px: np.ndarray
    radius_px: np.ndarray
    views: np.ndarray
    reproj_error_px: np.ndarray
    strobe_hz: float
    pair_points: dict = field(default_factory=dict)
    messages: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.positions)

    def ball_discs_px(self, camera: int) -> tuple[np.ndarray, np.ndarray]:
        """Centres (k, 2) and radii (k,) of the ball images in camera ``camera`` (rig index),
        e.g. to mask the ball's painted markers out of the hand-marker detection."""
        c, r = self.centers_px[camera], self.radius_px[camera]
        ok = np.isfinite(r) & np.all(np.isfinite(c), axis=1)
        return c[ok], r[ok]

    def to_dict(self) -> dict:
        return {"positions": self.positions.tolist(), "sigma_mm": (self.sigma_m * 1e3).tolist(),
                "flash_index": self.flash_index.tolist(), "times_s": self.times.tolist(),
                "reproj_error_px": self.reproj_error_px.tolist(), "strobe_hz": self.strobe_hz,
                "messages": list(self.messages)}


def _position_sigma(cams, X, used, pixel_sigma):
    """1-sigma (RMS per axis) of a point from the views used: ``s^2 (J^T J)^-1``, ``J`` the
    projections' derivatives (numerical, 0.1 mm steps)."""
    J = []
    for cam in (c for c, u in zip(cams, used) if u):
        rows = []
        for d in np.eye(3) * 1e-4:
            rows.append((cam.project((X + d)[None])[0] - cam.project((X - d)[None])[0]) / 2e-4)
        J.append(np.array(rows).T)
    J = np.concatenate(J)
    try:
        cov = np.linalg.inv(J.T @ J) * pixel_sigma ** 2
    except np.linalg.LinAlgError:
        return float("nan")
    return float(np.sqrt(np.trace(cov) / 3))


def _refine_in_all_views(rig, white, X, ball_radius_m):
    """Centres (n_cams, K, 2) of the balls ``X`` (K, 3) refined in every camera whose photo holds
    their whole projected disc (NaN elsewhere, where the centre is NaN or the refinement fails)."""
    from stillcap.detect.ball import refine_ball_centers, sphere_outline_px

    n_cams, K = len(rig), len(X)
    out = np.full((n_cams, K, 2), np.nan)
    ok = np.all(np.isfinite(X), axis=1)
    if not ok.any():
        return out
    for ci, cam in enumerate(rig):
        p, outl, r = sphere_outline_px(cam, X[ok], ball_radius_m)
        W, H = cam.image_size
        inside = (np.all(np.isfinite(outl), axis=(1, 2)) & (outl[..., 0].min(1) > 1) & (outl[..., 1].min(1) > 1)
                  & (outl[..., 0].max(1) < W - 2) & (outl[..., 1].max(1) < H - 2))
        if not inside.any():
            continue
        ref = refine_ball_centers(white[ci], p[inside], r[inside], np.maximum(2.0, 0.15 * r[inside]),
                                  outl[inside] - p[inside][:, None], response=cam.response)
        c = np.where((ref.flags[:, None] & int(BallFlag.REFINE_FAILED)) == 0, ref.centers, np.nan)
        idx = np.flatnonzero(ok)[inside]
        out[ci, idx] = c
    return out


def _robust_points(rig, obs, outlier_px):
    """Triangulate each ball image from its views (n_cams, K, 2): every two views give a
    candidate, the one most other views agree with (within ``outlier_px``; ties: lowest RMS)
    wins, then all agreeing views are triangulated together. A finger across one view's limb
    pulls its Hough centre by several pixels; the other views outvote it."""
    from itertools import combinations

    n_cams, K = obs.shape[:2]
    X = np.full((K, 3), np.nan)
    used = np.zeros((n_cams, K), bool)
    rms = np.full(K, np.nan)
    for g in range(K):
        seen = [c for c in range(n_cams) if np.all(np.isfinite(obs[c, g]))]
        best = None
        for a, b in combinations(seen, 2):
            x = np.full((n_cams, 1, 2), np.nan)
            x[[a, b], 0] = obs[[a, b], g]
            t = triangulate(rig, x)
            P = t.points[0]
            if not np.all(np.isfinite(P)):
                continue
            err = np.array([np.linalg.norm(rig[c].project(P[None])[0] - obs[c, g]) for c in seen])
            inl = [c for c, e in zip(seen, err) if e < outlier_px]
            key = (len(inl), -float(np.sqrt(np.mean(err[[seen.index(c) for c in inl]] ** 2))) if inl else 0.0)
            if best is None or key > best[0]:
                best = (key, inl)
        if best is None or len(best[1]) < 2:
            continue
        x = np.full((n_cams, 1, 2), np.nan)
        x[best[1], 0] = obs[best[1], g]
        t = triangulate(rig, x)
        X[g], used[best[1], g], rms[g] = t.points[0], True, t.reproj_error_px[0]
    return X, used, rms


def _median(w: np.ndarray, about: float | None = None) -> float:
    """``np.median(w)`` (or of ``|w - about|``), exactly, from a histogram when ``w`` is
    ``uint8``: 20x faster than partitioning a 5-megapixel photo."""
    if w.dtype != np.uint8 or w.size == 0:
        return float(np.median(w if about is None else np.abs(w - about)))
    counts = cv2.calcHist([np.ascontiguousarray(w)], [0], None, [256], [0, 256]).ravel().astype(np.int64)
    values = np.arange(256.0) if about is None else np.abs(np.arange(256.0) - about)
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(counts[order])
    n = w.size
    lo, hi = (values[order][np.searchsorted(cum, r + 1)] for r in ((n - 1) // 2, n // 2))
    return float(0.5 * (lo + hi))


def white_threshold_level(white) -> float:
    """Whiteness level that separates the ball from the glove in one photo (grey levels).

    Otsu's threshold (``skimage.filters.threshold_otsu``) over the pixels brighter than the dark
    room (median + max(6 sigma, 20)): those are the lit glove and sleeves (whiteness up to ~90
    grey levels where the strobe hits them squarely) and the ball (150-250); their valley moves
    with the exposure, so a fixed level does not fit every camera (80 cut into the glove of the
    inner cameras and merged fingers into the ball's silhouette). Falls back to median + 80
    when fewer than 100 pixels stand out.
    """
    from skimage.filters import threshold_otsu

    w = np.asarray(white)
    med = _median(w)
    mad = 1.4826 * _median(w, med)
    fg = w[w > med + max(6 * mad, 20.0)]
    if fg.size < 100 or fg.min() == fg.max():
        return med + 80.0
    return float(threshold_otsu(fg))


def hand_ball_positions(capture, pairs: dict | str | None = "all", *, images=None, ball_radius_m: float = BASEBALL_RADIUS,
                        strobe_hz: float = 75.0, white_threshold: float | None = None, merge_m: float = 0.06,
                        outlier_px: float | None = None, pixel_sigma: float = 0.3, refine_all_views: bool = True,
                        two_view_pixel_sigma: float = 2.0,
                        hand: tuple | None = None,
                        direction=(0.0, -1.0, 0.0)) -> HandBalls:
    """Ball centres of a hand capture per flash, merged over its stereo pairs (module docstring).

    Parameters
    ----------
    capture : HandCapture-like or Rig
        An object with ``.rig`` (a Rig, or something with ``.rig``) and ``.images`` (studio
        captures), or a Rig with ``images`` given.
    pairs : dict or "all" or None
        ``{name: (camera a, camera b)}``; ``"all"`` (default): every two cameras of the rig (a
        ball image hidden by the fingers in one camera of a stereo pair is still matched
        between the other cameras that see it); None: ``capture.rig.pairs``.
    images : list of ndarray, optional
        BGR photos in rig order (default ``capture.images``).
    ball_radius_m, strobe_hz : float
    white_threshold : float, optional
        Whiteness (grey levels above the photo's median) a ball pixel exceeds; default per
        photo from :func:`white_threshold_level` (the larger of the pair's two).
    merge_m : float
        3D distance below which points of different pairs are one ball image.
    outlier_px : float, optional
        Views reprojecting further than this are dropped when 3+ views see the ball; default
        ``0.1`` times the median ball radius (at least 1.5 px).
    pixel_sigma : float
        Floor of the pixel noise used for the uncertainty (3+ views agreeing).
    two_view_pixel_sigma : float
        The floor for positions from two views only (no view can outvote a centre that a finger
        pulled).
    refine_all_views : bool
        After the first triangulation, refine the ball's centre in every camera it projects
        into (known-radius Hough from the projected outline, small window) and triangulate
        again: a view whose pair failed (the fingers split its silhouette) still votes.
    direction : array_like, shape (3,)
        The throw's direction in the rig world (field frame: -y).
    hand : (hold_times, root2world), optional
        The hand's poses per reconstructed flash (``hold_times`` (n,) s, flash ``k`` at
        ``k / strobe_hz``; ``root2world`` (n, 4, 4)). Given, the flashes are numbered from the
        hand (:func:`stillcap.ball.flashes.number_flashes_from_hand`) and ``times`` / ``flash_index`` are
        on the hand's clock; without it (or when that fails, see ``messages``) they come from
        the ball's spacing with the first ball position at 0.

    Returns
    -------
    HandBalls
    """
    if isinstance(capture, Rig):
        rig = capture
    else:
        rig = capture.rig.rig if hasattr(capture.rig, "rig") else capture.rig
        if pairs is None:
            pairs = getattr(capture.rig, "pairs", None)
    if isinstance(pairs, str):
        if pairs != "all":
            raise ValueError(f"pairs must be a dict, 'all' or None, got {pairs!r}")
        from itertools import combinations
        pairs = {f"{a}+{b}": (a, b) for a, b in combinations(list(rig.names), 2)}
    if images is None and not isinstance(capture, Rig):
        images = capture.images
    if pairs is None or images is None:
        raise ValueError("give pairs and images (or a capture that has them)")
    if len(images) != len(rig):
        raise ValueError(f"images must have one photo per camera ({len(rig)}), got {len(images)}")
    names = list(rig.names)
    white = [whiteness(im) for im in images]
    levels = [_median(w) for w in white]
    thr_abs = [white_threshold_level(w) if white_threshold is None else lv + float(white_threshold)
               for w, lv in zip(white, levels)]
    messages: list[str] = []
    cand = []  # (pair name, point, {cam index: centre}, {cam index: radius})
    pair_points = {}
    for name, (a, b) in pairs.items():
        ia, ib = names.index(a), names.index(b)
        # detect_balls thresholds at the photo's median + threshold; one threshold per pair
        thr = max(thr_abs[ia] - levels[ia], thr_abs[ib] - levels[ib])
        st = ball_centers_stereo(rig[ia], white[ia], rig[ib], white[ib], ball_radius_m, threshold=thr)
        ok = st.ok & ((st.flags & _DROP) == 0)
        pair_points[name] = st.points_3d[ok]
        if not ok.any():
            messages.append(f"pair {name!r}: no usable ball image ({len(st)} matched)")
        for k in np.flatnonzero(ok):
            cand.append((name, st.points_3d[k], {ia: st.centers_a[k], ib: st.centers_b[k]},
                         {ia: st.radius_px[k, 0], ib: st.radius_px[k, 1]}))
    n_cams = len(rig)
    if not cand:
        z = np.zeros((0, 3))
        return HandBalls(z, np.zeros(0), np.zeros(0, int), np.zeros(0), np.zeros((n_cams, 0, 2)),
                         np.zeros((n_cams, 0)), np.zeros((n_cams, 0), bool), np.zeros(0), float(strobe_hz),
                         pair_points, messages + ["no ball found"])
    # merge: greedy clusters of points closer than merge_m (a pair gives one point per ball image)
    pts = np.array([c[1] for c in cand])
    cluster = -np.ones(len(cand), int)
    groups = []
    for i in range(len(cand)):
        if cluster[i] >= 0:
            continue
        d = np.linalg.norm(pts - pts[i], axis=1)
        members = [j for j in np.flatnonzero((d < merge_m) & (cluster < 0))]
        # at most one point per pair in a cluster: the nearest
        by_pair = {}
        for j in members:
            nm = cand[j][0]
            if nm not in by_pair or d[j] < d[by_pair[nm]]:
                by_pair[nm] = j
        for j in members:
            cluster[j] = len(groups)
        groups.append(list(by_pair.values()))
        if len(members) > len(by_pair):
            messages.append(f"{len(members) - len(by_pair)} duplicate ball image(s) of one pair merged")
    K = len(groups)
    obs = np.full((n_cams, K, 2), np.nan)
    rad = np.full((n_cams, K), np.nan)
    for g, members in enumerate(groups):
        for j in members:
            for ci, c in cand[j][2].items():
                obs[ci, g] = c
            for ci, r in cand[j][3].items():
                rad[ci, g] = r
    if outlier_px is None:
        outlier_px = max(1.5, 0.1 * float(np.nanmedian(rad)))
    X, used_all, rms = _robust_points(rig, obs, outlier_px)
    if refine_all_views:
        obs2 = _refine_in_all_views(rig, white, X, ball_radius_m)
        # the views now start from one consistent point: a tighter vote (a finger pulls a
        # Hough centre by 2-5 px, within the first vote's 0.1 radius)
        tight = max(1.0, 0.4 * outlier_px)
        X2, used2, rms2 = _robust_points(rig, obs2, tight)
        n1 = used_all.sum(0)
        n2 = used2.sum(0)
        # keep the re-refined point where 3+ views agree on it tightly, or where it has more views
        better = np.all(np.isfinite(X2), axis=1) & ((n2 >= 3) | (n2 > n1) | ~np.all(np.isfinite(X), axis=1))
        X[better], rms[better] = X2[better], rms2[better]
        used_all[:, better] = used2[:, better]
        obs[:, better] = obs2[:, better]
    good = np.all(np.isfinite(X), axis=1)
    if not good.all():
        messages.append(f"{int((~good).sum())} ball image(s) not triangulated")
    # order along the throw and flash indices
    from stillcap.ball.flashes import number_flashes_from_spacing
    Xg = X[good]
    idx_good = np.flatnonzero(good)
    order, k, spacing = number_flashes_from_spacing(Xg, np.asarray(direction, float), strobe_hz)
    sel = idx_good[order]
    times = k / float(strobe_hz)
    if hand is not None:
        from stillcap.ball.flashes import number_flashes_from_hand

        hold_times, root2world = hand
        fn = number_flashes_from_hand(X[sel], hold_times, root2world, strobe_hz=strobe_hz)
        if fn.success:
            k, times = fn.flash, fn.times
            messages.append(fn.message)
        else:
            messages.append(f"{fn.message}; flashes numbered from the ball's spacing (clock: first ball at 0)")
    X = X[sel]
    used = used_all[:, sel]
    # two views have no redundancy: their reprojection RMS is ~0 whatever a finger did to a
    # centre (2-5 px at 2560x1920), so they get the larger floor
    sig = np.array([_position_sigma(rig, x, u, max(pixel_sigma if u.sum() >= 3 else two_view_pixel_sigma,
                                                    float(e) if np.isfinite(e) else 0.0))
                    for x, u, e in zip(X, used.T, rms[sel])])
    centers = np.where(used[..., None], obs[:, sel], np.nan)
    # projected radius in every camera from the final centre
    radius = np.full((n_cams, len(sel)), np.nan)
    for ci, cam in enumerate(rig):
        d = cam.world_to_cam(X)[:, 2]
        radius[ci] = np.where(d > ball_radius_m, cam.K[0, 0] * ball_radius_m / np.maximum(d, ball_radius_m), np.nan)
    return HandBalls(X, sig, np.asarray(k).astype(int), np.asarray(times, float), centers, radius, used, rms[sel],
                     float(strobe_hz), pair_points, messages)


@dataclass
class HandBallSpin:
    """Spin of the free ball in a hand capture.

    Attributes
    ----------
    available : bool
        A spin was fitted (2+ free flashes with markers).
    spin : ndarray, shape (3,)
        Principal alias at the strobe rate, rad/s (NaN when unavailable).
    candidates_rpm : list of float
        Rates of the aliases in the plausible range (0-4000 rpm), with ``candidates`` (n, 3) rad/s.
    ambiguous : bool
        More than one candidate in range: one strobe cannot tell them apart.
    fit : SpinResult or None
    message : str
    """

    available: bool
    spin: np.ndarray
    candidates: np.ndarray
    candidates_rpm: list
    ambiguous: bool
    fit: object = None
    message: str = ""


def hand_ball_spin(capture, balls: HandBalls, free, *, pairs: dict | None = None, images=None,
                   max_rpm: float = 4000.0) -> HandBallSpin:
    """Spin from the painted markers of the free-flight flashes (``free``: bool (K,) per ball
    position, e.g. ``~Release.held``). ``capture`` is a studio capture, or a Rig with ``pairs``
    and ``images`` given (as :func:`hand_ball_positions`). Markers per pair with
    :func:`stillcap.ball.markers.pair_marker_observations`, one constant spin with
    :func:`stillcap.ball.orientation.fit_spin`, aliases with
    :func:`stillcap.ball.alias.alias_candidates`."""
    from stillcap.ball.alias import alias_candidates
    from stillcap.ball.orientation import MarkerObservations, fit_spin
    from stillcap.ball.markers import pair_marker_observations

    nan3 = np.full(3, np.nan)
    free = np.asarray(free, bool)
    if free.shape != (len(balls),):
        raise ValueError(f"free must have shape ({len(balls)},), got {free.shape}")
    idx = np.flatnonzero(free)
    if len(idx) < 2:
        return HandBallSpin(False, nan3, np.zeros((0, 3)), [], False, None,
                            f"{len(idx)} free-flight flash(es): a spin needs markers on at least 2; spin unavailable")
    if isinstance(capture, Rig):
        if pairs is None or images is None:
            raise ValueError("hand_ball_spin with a Rig needs pairs and images")
        rig = capture
    else:
        rig = capture.rig.rig if hasattr(capture.rig, "rig") else capture.rig
        pairs = pairs if pairs is not None else capture.rig.pairs
        images = images if images is not None else capture.images
    names = list(rig.names)
    parts = []
    for _, (a, b) in pairs.items():
        ia, ib = names.index(a), names.index(b)
        ok = balls.views[ia, idx] & balls.views[ib, idx]
        if not ok.any():
            continue
        sub = idx[ok]
        o, _, _ = pair_marker_observations(rig[ia], images[ia], rig[ib], images[ib], balls.centers_px[ia, sub],
                                           balls.centers_px[ib, sub], balls.radius_px[ia, sub],
                                           balls.radius_px[ib, sub], balls.positions[sub])
        if len(o):
            # flash = index into idx (the free flashes)
            parts.append(MarkerObservations(np.searchsorted(idx, sub[o.flash]), o.types, o.directions, o.from_ray))
    if not parts:
        return HandBallSpin(False, nan3, np.zeros((0, 3)), [], False, None, "no painted markers found on the free ball")
    obs = MarkerObservations.concatenate(parts)
    if len(np.unique(obs.flash)) < 2:
        return HandBallSpin(False, nan3, np.zeros((0, 3)), [], False, None,
                            "markers on one free flash only: spin unavailable")
    fit = fit_spin(balls.times[idx], obs, strobe_hz=balls.strobe_hz)
    if not fit.success:
        return HandBallSpin(False, nan3, np.zeros((0, 3)), [], False, fit, f"spin fit failed: {fit.message}")
    cands = alias_candidates(fit.spin, balls.strobe_hz, max_rpm=max_rpm)
    amb = len(cands) > 1
    msg = (f"spin {fit.spin_rpm:.0f} rpm (principal alias at {balls.strobe_hz:g} Hz); "
           + (f"ambiguous: {len(cands)} aliases within 0-{max_rpm:.0f} rpm "
              f"({', '.join(f'{c.spin_rpm:.0f}' for c in cands)}), one strobe cannot tell them apart"
              if amb else "no other alias in range"))
    return HandBallSpin(True, fit.spin.copy(), np.array([c.spin for c in cands]), [c.spin_rpm for c in cands],
                        amb, fit, msg)
