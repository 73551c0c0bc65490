"""The camera's response estimated from chessboard photos: the symmetry of blurred edges.

A black/white edge of the board, photographed, is a step blurred by the lens and the pixels.
In linear light (radiance) the blurred step is point-symmetric about its 50 % crossing for any
symmetric blur: ``y(t0 + u) + y(t0 - u) = 1`` with ``y`` the profile scaled to run from 0 (black
plateau) to 1 (white plateau). A camera that encodes the radiance (``v = L ** (1 / g)``) bends
the profile: the dark side sharpens and the bright side spreads, so the profile of the encoded
values is asymmetric. Linearising the values with the right gamma makes the profiles symmetric
again; :func:`edge_response` finds the gamma that does, for each photo (a grid over gamma and a
parabola), and combines the photos (median; the spread over photos says how sure it is).

The profiles are the edges' spread functions measured as the slanted-edge method of ISO 12233
does: the pixels near the middle of every edge between two neighbouring inner corners (away
from the corners, where four squares meet) are binned by their distance across the edge into
quarter-pixel bins (the edge's tilt against the pixel grid fills them); each pixel is linearised
before it is averaged (interpolating or averaging encoded values would itself bend the
profile). The two plateaus are estimated per edge from the profile's ends.

The estimate says it cannot tell (and calibration writes no response) when fewer than
:data:`MIN_PHOTOS` photos give an estimate, when the board's squares are clipped (white at 255
or black at 0: the plateaus are then not the radiance), when the edges are too sharp to show a
profile, when the photos' estimates disagree (``max_spread``) or when the class is not sure
(``class_margin``).
Chessboards only: a ChArUco board's white squares hold markers too close to the edges.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stillcap.calibrate.detect import find_chessboard, image_name, read_gray
from stillcap.calibrate.targets import Chessboard
from stillcap.response import LINEAR_LIMIT, EstimatedResponse

__all__ = ["EdgeResponseEstimate", "board_response", "combine_photos", "edge_response", "image_edge_gamma",
           "rig_responses", "MIN_PHOTOS"]

#: Fewest photos with an estimate for a confident answer.
MIN_PHOTOS = 3
_GAMMAS = np.geomspace(0.5, 4.0, 28)  # the grid over gamma (7.7 % apart), then a parabola
_BIN = 0.25  # px: the bins of the edge spread function
_HALF_PX = 6.0  # px: the spread function is measured this far either side of the edge (at most)
_K_PLATEAU = 6  # bins at either end that give the plateaus (1.5 px)
_MIN_CONTRAST = 40.0  # code values between the plateaus of a usable edge
_CLIPPED = 0.05  # share of plateau samples at 0 or 255 above which the board is clipped


@dataclass
class EdgeResponseEstimate(EstimatedResponse):
    """What a camera's board photos say about its response.

    Attributes
    ----------
    response_class : str or None
        ``"linear"`` or ``"gamma"``; None when the photos cannot tell (``reason`` says why).
    gamma : float
        Effective gamma (median over the photos), NaN when no photo gave one.
    spread : float
        Robust spread (1.4826 MAD) of the photos' ln gamma.
    n_photos : int
        Photos that gave an estimate.
    gammas : dict
        Photo name -> its gamma.
    edge_width_px : float
        Median 10-90 % rise of the edges (linearised with the estimate), px.
    clipped : float
        Share of the plateau samples at 0 or 255.
    evidence : str
        One line: what was measured and what it gave, or why it cannot tell.
    """

    response_class: str | None
    gamma: float
    spread: float
    n_photos: int
    gammas: dict = field(default_factory=dict)
    edge_width_px: float = float("nan")
    clipped: float = 0.0
    evidence: str = ""

    def to_json(self) -> dict:
        r = self.response()
        fin = (lambda x: None if not np.isfinite(x) else round(float(x), 3))
        return {"class": self.response_class, "gamma": fin(self.gamma), "spread": fin(self.spread),
                "n_photos": int(self.n_photos), "edge_width_px": fin(self.edge_width_px),
                "clipped": round(float(self.clipped), 4), "response": None if r is None else r.to_json(),
                "photos": {k: round(float(v), 3) for k, v in self.gammas.items()}, "evidence": self.evidence}


def _edges(corners: np.ndarray, cols: int, rows: int):
    """The edges between neighbouring inner corners: start points (E, 2), directions (E, 2), lengths (E,)."""
    P = np.asarray(corners, float).reshape(rows, cols, 2)
    a = np.concatenate([P[:, :-1].reshape(-1, 2), P[:-1, :].reshape(-1, 2)])
    b = np.concatenate([P[:, 1:].reshape(-1, 2), P[1:, :].reshape(-1, 2)])
    d = b - a
    return a, d, np.linalg.norm(d, axis=1)


def _esf_pixels(gray: np.ndarray, corners: np.ndarray, cols: int, rows: int):
    """Every usable edge's pixels as samples of its edge spread function (the slanted-edge
    method of ISO 12233): each pixel near the middle of an edge, at its signed distance across
    the edge (dark side negative), falls in a bin :data:`_BIN` px wide; the edge's tilt against
    the pixel grid spreads its pixels over every bin. No interpolation: each sample is one
    pixel's value (interpolating would mix values before they are linearised).

    Returns
    -------
    (codes, bins, n_bins) : codes (N,) of the pixels, their global bin ``edge * n_bins + bin``
    (sorted), and the bins per edge; None when no edge is usable.
    """
    a, d, length = _edges(corners, cols, rows)
    ok = np.isfinite(length) & (length >= 10.0)
    if not ok.any():
        return None
    a, d, length = a[ok], d[ok], length[ok]
    half = min(_HALF_PX, 0.4 * float(length.min()))  # stays inside the two squares
    nb = int(round(2 * half / _BIN))
    H, W = gray.shape
    codes, bins, k = [], [], _K_PLATEAU
    for e_i, (a_i, d_i, l_i) in enumerate(zip(a, d, length)):
        e = d_i / l_i
        n = np.array([-e[1], e[0]])
        # the pixels of the edge's middle (0.2-0.8 of its length) within `half` of it
        quad = np.array([a_i + f * d_i + s * half * n for f in (0.2, 0.8) for s in (-1, 1)])
        x0, y0 = np.floor(quad.min(0)).astype(int)
        x1, y1 = np.ceil(quad.max(0)).astype(int)
        if x0 < 0 or y0 < 0 or x1 >= W or y1 >= H:
            continue
        X, Y = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        rel = np.stack([X.ravel() - a_i[0], Y.ravel() - a_i[1]], 1)
        along, across = rel @ e / l_i, rel @ n
        sel = (along >= 0.2) & (along <= 0.8) & (np.abs(across) < half)
        c = gray[Y.ravel()[sel], X.ravel()[sel]].astype(float)
        t = across[sel]
        b = np.clip(((t + half) / _BIN).astype(int), 0, nb - 1)
        cnt = np.bincount(b, minlength=nb)
        if cnt.min() == 0:  # an edge almost along the pixel grid: bins left empty
            continue
        mean = np.bincount(b, c, minlength=nb) / cnt
        lo, hi = mean[:k].mean(), mean[-k:].mean()
        if abs(hi - lo) < _MIN_CONTRAST:
            continue
        if lo > hi:  # orient dark -> bright
            b = nb - 1 - b
        codes.append(c)
        bins.append(len(bins) * nb + b)
    if not codes:
        return None
    codes, bins = np.concatenate(codes), np.concatenate(bins)
    order = np.argsort(bins, kind="stable")
    return codes[order], bins[order], nb


def _profiles(codes, bins, nb, gammas):
    """Each edge's spread function linearised with each gamma, scaled to its plateaus: ``(G, E, nb)``."""
    lin = (codes[None, :] / 255.0) ** np.asarray(gammas, float)[:, None]  # (G, N)
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    cnt = np.diff(np.r_[starts, len(bins)])
    prof = (np.add.reduceat(lin, starts, axis=1) / cnt).reshape(len(gammas), -1, nb)
    k = _K_PLATEAU
    lo, hi = prof[..., :k].mean(-1), prof[..., -k:].mean(-1)
    span = hi - lo
    return (prof - lo[..., None]) / np.where(span > 1e-9, span, 1e-9)[..., None]


def _asymmetry(y: np.ndarray) -> np.ndarray:
    """Sum over the profile of ``(y(t0 + u) + y(t0 - u) - 1)^2`` about its 0.5 crossing ``t0``
    (sample units, linear interpolation), for profiles ``y`` (..., T) running from ~0 to ~1."""
    T = y.shape[-1]
    j = np.clip((y < 0.5).sum(-1), 1, T - 1)  # the first sample at or above 0.5 (a monotone profile)
    y0 = np.take_along_axis(y, (j - 1)[..., None], -1)[..., 0]
    y1 = np.take_along_axis(y, j[..., None], -1)[..., 0]
    t0 = (j - 1) + np.clip((0.5 - y0) / np.where(y1 - y0 > 1e-9, y1 - y0, 1e-9), 0.0, 1.0)
    u = np.arange(1, T // 2 - T // 12)  # up to the plateaus' start
    out = 0.0
    for sign in (1.0, -1.0):
        s = np.clip(t0[..., None] + sign * u, 0.0, T - 1.0)
        i0 = np.clip(np.floor(s).astype(int), 0, T - 2)
        w = s - i0
        out = out + ((1 - w) * np.take_along_axis(y, i0, -1) + w * np.take_along_axis(y, i0 + 1, -1))
    return ((out - 1.0) ** 2).sum(-1)


def image_edge_gamma(gray: np.ndarray, corners, pattern: tuple[int, int]) -> dict | None:
    """One photo's effective gamma from its board's edges.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
        The photo, grey.
    corners : array_like, shape (cols * rows, 2)
        The board's inner corners in OpenCV's order (row by row), px.
    pattern : (cols, rows)
        Inner corners along x and y.

    Returns
    -------
    dict or None
        ``gamma``, ``n_edges``, ``width_px`` (median 10-90 % rise at that gamma), ``clipped``
        (share of plateau samples at 0 or 255); None when no edge is usable.
    """
    cols, rows = (int(v) for v in pattern)
    got = _esf_pixels(np.asarray(gray), np.asarray(corners, float), cols, rows)
    if got is None:
        return None
    codes, bins, nb = got
    k = _K_PLATEAU
    where = bins % nb
    plateau = codes[(where < k) | (where >= nb - k)]
    clipped = float(np.mean((plateau <= 0.5) | (plateau >= 254.5)))
    y = _profiles(codes, bins, nb, _GAMMAS)
    cost = _asymmetry(y).sum(-1)  # (G,)
    i = int(np.argmin(cost))
    lg = np.log(_GAMMAS)
    best = lg[i]
    if 0 < i < len(lg) - 1:  # the parabola's vertex through the best point and its neighbours
        c0, c1, c2 = cost[i - 1:i + 2]
        den = c0 - 2 * c1 + c2
        if den > 0:
            best = lg[i] + 0.5 * (c0 - c2) / den * (lg[1] - lg[0])
    g = float(np.exp(best))
    yb = _profiles(codes, bins, nb, np.array([g]))[0]
    # the 10-90 % rise of each edge, px
    width = float(np.median(((yb < 0.9).sum(-1) - (yb < 0.1).sum(-1)) * _BIN))
    return {"gamma": g, "n_edges": int(yb.shape[0]), "width_px": width, "clipped": clipped,
            "at_grid_end": i in (0, len(lg) - 1)}


def edge_response(grays, corners_list, pattern: tuple[int, int], names=None, class_margin: float = 3.0,
                  max_spread: float = 0.15, min_width_px: float = 0.75) -> EdgeResponseEstimate:
    """A camera's response class and effective gamma from photos of a chessboard.

    Parameters
    ----------
    grays : sequence of ndarray, shape (H, W), uint8
        The photos, grey.
    corners_list : sequence of array_like, shape (cols * rows, 2)
        Each photo's inner corners (OpenCV's order).
    pattern : (cols, rows)
    names : sequence of str, optional
        Photo names (for the report).
    class_margin : float
        The class is sure when ln(gamma) lies at least this many standard errors (of the median
        over the photos) from the class boundary :data:`stillcap.response.LINEAR_LIMIT`.
    max_spread : float
        Photos whose estimates spread more than this (1.4826 MAD of ln gamma) disagree: the
        response is not one power law over the photos' exposures (a knee, a tone curve that
        changes with the scene), or the edges are processed (sharpened): cannot tell. The
        studio's boards spread 0.004-0.03.
    min_width_px : float
        Edges sharper than this (10-90 % rise, px; a pixel's own aperture gives 0.8) show no
        profile (a thresholded or nearest-neighbour image): cannot tell.

    Returns
    -------
    EdgeResponseEstimate
    """
    names = [f"#{i}" for i in range(len(grays))] if names is None else list(names)
    fits = {name: image_edge_gamma(gray, c, pattern) for name, gray, c in zip(names, grays, corners_list)
            if c is not None and len(c)}
    return combine_photos(fits, class_margin, max_spread, min_width_px)


def combine_photos(fits: dict, class_margin: float = 3.0, max_spread: float = 0.15,
                   min_width_px: float = 0.75) -> EdgeResponseEstimate:
    """:func:`edge_response` from the photos' :func:`image_edge_gamma` results (name -> dict or
    None); the parameters as there."""
    per, widths, clips = {}, [], []
    for name, f in fits.items():
        if f is None:
            continue
        clips.append(f["clipped"])
        widths.append(f["width_px"])
        if not f["at_grid_end"]:
            per[name] = f["gamma"]
    n = len(per)
    clipped = float(np.mean(clips)) if clips else 0.0
    width = float(np.median(widths)) if widths else float("nan")
    if n == 0:
        return EdgeResponseEstimate(None, float("nan"), float("nan"), 0, {}, width, clipped,
                                    "no board edge gave an estimate: cannot tell")
    lg = np.log(np.array(list(per.values())))
    med = float(np.median(lg))
    spread = float(1.4826 * np.median(np.abs(lg - med))) if n > 1 else float("nan")
    gamma = float(np.exp(med))
    cls = "linear" if gamma < LINEAR_LIMIT else "gamma"
    q1, q3 = np.exp(np.percentile(lg, [25, 75]))
    what = (f"symmetry of the blurred board edges in {n} photo(s): effective gamma {gamma:.2f} "
            f"(quartiles {q1:.2f}-{q3:.2f}), edges {width:.1f} px wide")
    # the median's standard error (1.2533 sigma / sqrt(n)); a floor for photos that agree closely
    se = 1.2533 * max(spread if np.isfinite(spread) else 0.0, 0.02) / np.sqrt(n)
    why = None
    if n < MIN_PHOTOS:
        why = f"only {n} photo(s) gave an estimate (need {MIN_PHOTOS})"
    elif clipped > _CLIPPED:
        why = f"the squares are clipped ({100 * clipped:.0f} % of their samples at 0 or 255)"
    elif not width >= min_width_px:
        why = f"the edges are too sharp to show a profile ({width:.1f} px, need {min_width_px:g})"
    elif spread > max_spread:
        why = (f"the photos disagree (their gammas spread {spread:.2f} in ln gamma, more than {max_spread:g}: the "
               "response is not one power law over their exposures, or the edges are processed)")
    elif abs(med - np.log(LINEAR_LIMIT)) < class_margin * se:
        why = f"the photos disagree too much to tell the class (spread {spread:.2f} in ln gamma)"
    if why is not None:
        return EdgeResponseEstimate(None, gamma, spread, n, per, width, clipped, f"{what}; cannot tell: {why}")
    return EdgeResponseEstimate(cls, gamma, spread, n, per, width, clipped, f"{what} -> {cls}")


def board_response(images, target, names=None, progress=None) -> EdgeResponseEstimate:
    """:func:`edge_response` of one camera's board photos (paths or arrays), found and read here
    one at a time (a photo's grey image is dropped before the next is read).

    Parameters
    ----------
    images : sequence of path or ndarray (None entries are skipped)
    target : Chessboard, or another target (then: not estimated, says why)
    names : sequence of str, optional
    progress : callable(done, total, name), optional
    """
    if not isinstance(target, Chessboard):
        return EdgeResponseEstimate(None, float("nan"), float("nan"), 0, evidence=(
            "not estimated: the board-edge estimate needs a chessboard (a ChArUco board's markers sit too "
            "close to its square edges)"))
    images = list(images)
    names = [image_name(im, i) for i, im in enumerate(images)] if names is None else list(names)
    fits = {}
    for i, (im, name) in enumerate(zip(images, names)):
        if im is not None:
            gray = read_gray(im, name)
            c = find_chessboard(gray, target)
            if c is not None:
                fits[name] = image_edge_gamma(gray, c, target.pattern_size)
        if progress is not None:
            progress(i + 1, len(images), name)
    return combine_photos(fits)


def rig_responses(rig, images: dict, target, stated=None, progress=None):
    """The rig with each camera's response, and the report of where it came from.

    Parameters
    ----------
    rig : Rig
        The calibrated rig.
    images : dict camera name -> sequence of its board photos
    target : the calibration target
    stated : None, "auto" or Response
        A response the user stated (``--response``): every camera gets it, nothing is estimated
        (stated wins). None or "auto": each camera's is estimated from its photos
        (:func:`board_response`) and written where the estimate is sure; elsewhere the rig keeps
        its cameras' (sRGB, the default, when nothing was stated before).
    progress : callable(done, total, name), optional

    Returns
    -------
    (Rig, dict)
        The report: ``source`` ("stated" or "estimated"), ``cameras`` (name -> the response in
        the rig, rig-file form), for "estimated" ``estimates`` (name -> :meth:`EdgeResponseEstimate.to_json`)
        and ``written`` (name -> bool), and ``messages`` (one line per camera, for the terminal).
    """
    if stated is not None and stated != "auto":
        out = rig.with_responses(stated)
        return out, {"source": "stated", "cameras": {c.name: c.response.to_json() for c in out},
                     "messages": [f"response of {c.name}: {c.response} (stated)" for c in out]}
    found, chosen, msgs = {}, {}, []
    for c in rig:
        e = board_response(images.get(c.name, []), target, progress=progress)
        found[c.name] = e
        r = e.response()
        if r is None:
            msgs.append(f"response of {c.name}: not written ({e.evidence}); the rig keeps {c.response} - state "
                        "it with --response if you know it")
        else:
            chosen[c.name] = r
            msgs.append(f"response of {c.name}: {e.response_class} (effective gamma {e.gamma:.2f}), wrote {r}; "
                        f"{e.evidence}")
    out = rig.with_responses(chosen) if chosen else rig
    return out, {"source": "estimated", "cameras": {c.name: c.response.to_json() for c in out},
                 "estimates": {k: v.to_json() for k, v in found.items()},
                 "written": {k: k in chosen for k in found}, "messages": msgs}
