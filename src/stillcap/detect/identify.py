"""Which bead is which: identify circle candidates by colour against a palette of markers.

The thesis (section 3.3.3, SPEC J3) measures each candidate's colour as the mean of a 5x5 patch
at its centre, computes the HSB distance ``sqrt(dh^2 + ds^2 + db^2)`` (periodic hue) to every
reference colour, sorts all (candidate, reference) pairs by distance and accepts them greedily
below a threshold, each candidate and each reference used once. :func:`identify_markers` does
that with ``method="greedy", metric="hsb", sampler="patch"`` (:data:`THESIS`).

Greedy acceptance is not optimal: the closest pair can take a candidate that a second marker
needed more, leaving that marker unidentified or wrong. ``method="assignment"`` instead solves
the assignment problem (:func:`scipy.optimize.linear_sum_assignment`): the least total distance
of the accepted pairs plus ``max_distance`` for every marker left unidentified (:func:`optimal_match`),
in a perceptual colour space (CIEDE2000 with lightness
down-weighted, since the light changes brightness more than hue), with the colour measured over
the bead's inner disc, and, with ``adapt=True``, corrects the photo's white balance and
exposure from a first assignment before the final one (:data:`RECOMMENDED`).

:func:`calibrate_palette` measures reference colours from photos with known marker positions,
as the thesis did with its twelve T-pose photos.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from stillcap._checks import as_array
from stillcap.detect.palette import (
    METRICS,
    Palette,
    _lab_pairwise,
    color_distance,
    rgb_to_lab,
)

__all__ = [
    "RECOMMENDED",
    "SAMPLERS",
    "THESIS",
    "ColorCalibration",
    "Identification",
    "calibrate_palette",
    "greedy_match",
    "identify_colors",
    "identify_colors_views",
    "identify_markers",
    "identify_markers_views",
    "optimal_match",
    "sample_colors",
]

#: Colour samplers of :func:`sample_colors`.
SAMPLERS = ("patch", "disc")

#: The thesis's identification.
THESIS = dict(method="greedy", metric="hsb", sampler="patch", max_distance=0.15, adapt=False)

#: The measured best (see ``docs/puppet-detection.md``); also the defaults of ``method="assignment"``.
RECOMMENDED = dict(method="assignment", metric="ciede2000", sampler="disc", lightness_weight=0.5,
                   max_distance=15.0, adapt=True)

#: :func:`sample_colors`' default share of the radius the ``disc`` sampler averages over.
DISC_FRACTION = 0.7

_DEFAULT_MAX = {"hsb": 0.15, "lab": 25.0, "ciede2000": 15.0}


def _as_image(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3) (BGR), got {img.shape}")
    return img


def sample_colors(image, centers, radii=None, sampler: str = "patch", size: int = 5,
                  disc_fraction: float = DISC_FRACTION, radius: float = 6.0) -> np.ndarray:
    """Colour of each candidate, sRGB in [0, 1].

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
        BGR photo, uint8 (0-255) or float in [0, 1].
    centers : array_like, shape (N, 2)
        Pixel centres (x, y); NaN rows give NaN colours.
    radii : array_like, shape (N,), optional
        Bead radii for ``disc`` (default ``radius`` for all).
    sampler : {"patch", "disc"}
        ``patch``: mean of the ``size`` x ``size`` pixels around the nearest pixel (the
        thesis); ``disc``: mean of the pixels whose centres lie within ``disc_fraction`` x
        radius of the sub-pixel centre (more pixels, less noise, and it follows the centre).
    size : int
        Patch size (odd).
    disc_fraction : float
        Share of the radius sampled by ``disc`` (the shaded, JPEG-smeared rim left out).
    radius : float
        Radius used when ``radii`` is not given, pixels.

    Returns
    -------
    ndarray, shape (N, 3)
        sRGB in [0, 1] (RGB order); NaN where the sample lies outside the image.
    """
    img, c, r, scale = _disc_inputs(image, centers, radii, radius)
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")
    if int(size) != size or size < 1 or size % 2 == 0:
        raise ValueError(f"size must be a positive odd integer, got {size}")
    h, w = img.shape[:2]
    out = np.full((len(c), 3), np.nan)
    if sampler == "disc":
        return _sample_discs([img], [c], [r], disc_fraction, [scale])[0]
    for i, ((x, y), ri) in enumerate(zip(c, r)):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        if sampler == "patch":
            xi, yi, hs = int(round(x)), int(round(y)), int(size) // 2
            x0, x1, y0, y1 = max(0, xi - hs), min(w, xi + hs + 1), max(0, yi - hs), min(h, yi + hs + 1)
            if x1 <= x0 or y1 <= y0:
                continue
            px = img[y0:y1, x0:x1].reshape(-1, 3)
        else:
            R = max(disc_fraction * ri, 0.75)
            x0, x1 = max(0, int(np.ceil(x - R))), min(w - 1, int(np.floor(x + R)))
            y0, y1 = max(0, int(np.ceil(y - R))), min(h - 1, int(np.floor(y + R)))
            if x1 < x0 or y1 < y0:
                continue
            ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
            sel = (xs - x) ** 2 + (ys - y) ** 2 <= R * R
            if not sel.any():
                continue
            px = img[y0:y1 + 1, x0:x1 + 1][sel]
        out[i] = px.astype(float).mean(axis=0)[::-1] / scale
    return np.clip(out, 0.0, 1.0)


def _sample_discs(imgs: list, cs: list, rs: list, disc_fraction: float, scales: list) -> list:
    """The ``disc`` sampler of :func:`sample_colors` for all candidates of several photos at once
    (checked arrays, one list entry per photo): the pixels of each disc (the same sets as a loop
    over the candidates) gathered from one common window size and averaged with a mask (a loop
    cost ~0.1 ms per candidate). uint8 photos' sums are of whole numbers, exact in any order, so
    their discs are sampled together (the identification samples 6-12 photos per call: one set
    of array operations instead of one per photo); each float photo on its own."""
    if len(imgs) > 1 and not all(im.dtype == np.uint8 for im in imgs):
        return [_sample_discs([im], [c], [r], disc_fraction, [s])[0] for im, c, r, s in zip(imgs, cs, rs, scales)]
    out = [np.full((len(c), 3), np.nan) for c in cs]
    with np.errstate(invalid="ignore"):
        lives = [np.isfinite(c).all(axis=1) & np.isfinite(r) for c, r in zip(cs, rs)]
    counts = [int(np.count_nonzero(live)) for live in lives]
    if not sum(counts):
        return out
    cl = np.concatenate([c[live] for c, live in zip(cs, lives)])
    R = np.maximum(disc_fraction * np.concatenate([r[live] for r, live in zip(rs, lives)]), 0.75)
    hw = np.repeat(np.array([im.shape[:2] for im in imgs]), counts, axis=0)
    h, w = hw[:, 0], hw[:, 1]
    x0 = np.maximum(0, np.ceil(cl[:, 0] - R)).astype(int)
    x1 = np.minimum(w - 1, np.floor(cl[:, 0] + R)).astype(int)
    y0 = np.maximum(0, np.ceil(cl[:, 1] - R)).astype(int)
    y1 = np.minimum(h - 1, np.floor(cl[:, 1] + R)).astype(int)
    S = int(max(np.max(x1 - x0), np.max(y1 - y0), 0)) + 1
    off = np.arange(S)
    xs = (x0[:, None] + off)[:, None, :]  # (m, 1, S)
    ys = (y0[:, None] + off)[:, :, None]  # (m, S, 1)
    sel = ((xs <= x1[:, None, None]) & (ys <= y1[:, None, None])
           & ((xs - cl[:, 0, None, None]) ** 2 + (ys - cl[:, 1, None, None]) ** 2 <= (R * R)[:, None, None]))
    # each disc's S x S window: gathered whole from a zero-copy view of all windows where it
    # lies inside the photo (~5x faster than indexing every pixel), else with clipped indices
    # (cells outside the photo are outside the disc: any value)
    inner = (y0 + S <= h) & (x0 + S <= w)
    px = np.empty((len(cl), S, S, 3))
    bounds = np.cumsum([0] + counts)
    for img, a, b in zip(imgs, bounds[:-1], bounds[1:]):
        if a == b:
            continue
        p, ins = px[a:b], inner[a:b]
        hh, ww = img.shape[:2]
        if ins.any():
            im = np.ascontiguousarray(img)
            win = np.lib.stride_tricks.as_strided(im, (hh - S + 1, ww - S + 1, S, S, im.shape[2]),
                                                  im.strides[:2] * 2 + im.strides[2:], writeable=False)
            p[ins] = win[y0[a:b][ins], x0[a:b][ins]]
        if not ins.all():
            o = ~ins
            p[o] = img[np.minimum(ys[a:b][o], hh - 1), np.minimum(xs[a:b][o], ww - 1)]
    k = sel.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (px * sel[..., None]).sum(axis=(1, 2)) / k[:, None]
    mean = np.where((k > 0)[:, None], mean, np.nan)
    for o, live, a, b, scale in zip(out, lives, bounds[:-1], bounds[1:], scales):
        o[live] = mean[a:b, ::-1] / scale
    return [np.clip(o, 0.0, 1.0) for o in out]


def _disc_inputs(image, centers, radii, radius: float) -> tuple:
    """:func:`sample_colors`' checked photo, centres and radii, and the photo's value scale."""
    img = _as_image(image)
    c = as_array(centers, (None, 2), "centers")
    r = np.full(len(c), float(radius)) if radii is None else as_array(radii, (len(c),), "radii")
    return img, c, r, 255.0 if img.dtype == np.uint8 else 1.0


# -- matching ----------------------------------------------------------------------------------
def greedy_match(cost, max_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """The thesis's acceptance: all pairs by increasing cost, each row and column used once.

    Parameters
    ----------
    cost : array_like, shape (N, K)
        Distances (NaN = impossible).
    max_distance : float
        Pairs at or above it are never accepted.

    Returns
    -------
    rows, cols : ndarray of int, shape (M,)
        Accepted pairs, in the order they were accepted.
    """
    C = as_array(cost, (None, None), "cost")
    C = np.where(np.isfinite(C), C, np.inf)
    order = np.argsort(C, axis=None, kind="stable")
    used_r = np.zeros(C.shape[0], bool)
    used_c = np.zeros(C.shape[1], bool)
    rows, cols = [], []
    for flat in order:
        i, j = divmod(int(flat), C.shape[1])
        if not C[i, j] < max_distance:
            break
        if not used_r[i] and not used_c[j]:
            used_r[i] = used_c[j] = True
            rows.append(i)
            cols.append(j)
    return np.array(rows, int), np.array(cols, int)


def optimal_match(cost, max_distance: float, objective: str = "total") -> tuple[np.ndarray, np.ndarray]:
    """Globally optimal one-to-one matching with rejection (:func:`scipy.optimize.linear_sum_assignment`).

    Rows and columns may stay unmatched; pairs at or above ``max_distance`` are never made.

    Parameters
    ----------
    cost : array_like, shape (N, K)
        Distances (NaN = impossible).
    max_distance : float
    objective : {"total", "count"}
        ``total``: minimise the sum of the accepted distances plus ``max_distance`` for every
        column left unmatched (a pair is worth making if it is closer than ``max_distance``,
        and pairs are never reshuffled just to make one more); ``count``: first the most
        pairs, then the least total distance.

    Returns
    -------
    rows, cols : ndarray of int, shape (M,)
        Accepted pairs, sorted by row.
    """
    C = as_array(cost, (None, None), "cost")
    if objective not in ("total", "count"):
        raise ValueError(f"objective must be 'total' or 'count', got {objective!r}")
    if C.size == 0:
        return np.zeros(0, int), np.zeros(0, int)
    ok = np.isfinite(C) & (C < max_distance)
    if not ok.any():
        return np.zeros(0, int), np.zeros(0, int)
    if objective == "total":
        # Sum over pairs of (distance - max_distance): an unmatched column costs max_distance
        # more than a matched one, so this is the "unmatched = max_distance" objective.
        r, c = linear_sum_assignment(np.where(ok, C - max_distance, 0.0))
    else:
        # A forbidden pair costs more than any full set of allowed pairs.
        big = float(np.where(ok, C, 0).sum()) + 1.0 + float(max_distance) * min(C.shape)
        r, c = linear_sum_assignment(np.where(ok, C, big))
    keep = ok[r, c]
    return r[keep], c[keep]


@dataclass(eq=False)
class Identification:
    """Result of :func:`identify_markers` / :func:`identify_colors`.

    Attributes
    ----------
    names : tuple of str, length K
        Reference markers, in palette order.
    points : ndarray, shape (K, 2)
        Pixel position (x, y) of each marker, NaN if not identified.
    distances : ndarray, shape (K,)
        Colour distance of each accepted match (``metric`` units), NaN if none.
    candidate : ndarray of int, shape (K,)
        Index of the candidate identified as each marker, -1 if none.
    rejected : ndarray of int, shape (M,)
        Candidates identified as no marker.
    colors : ndarray, shape (N, 3)
        Measured colour of every candidate, sRGB [0, 1] (after the white-balance correction
        when ``adapt``).
    cost : ndarray, shape (N, K)
        Distance of every candidate to every reference colour.
    method, metric, sampler : str
    max_distance : float
    gains : ndarray, shape (3,)
        RGB gains that were divided out of the measured colours (ones without ``adapt``).
    radii : ndarray, shape (K,)
        Radius of the candidate identified as each marker, pixels (NaN if none or unknown).
    """

    names: tuple[str, ...]
    points: np.ndarray
    distances: np.ndarray
    candidate: np.ndarray
    rejected: np.ndarray
    colors: np.ndarray
    cost: np.ndarray
    method: str
    metric: str
    sampler: str
    max_distance: float
    gains: np.ndarray
    radii: np.ndarray | None = None

    def __post_init__(self):
        if self.radii is None:
            self.radii = np.full(len(self.names), np.nan)

    @property
    def found(self) -> np.ndarray:
        """Whether each marker was identified, shape (K,)."""
        return self.candidate >= 0

    @property
    def n_found(self) -> int:
        return int(self.found.sum())

    def as_dict(self) -> dict[str, tuple[float, float]]:
        """``{name: (x, y)}`` of the identified markers (the project file's per-photo list)."""
        return {n: (float(p[0]), float(p[1])) for n, p, f in zip(self.names, self.points, self.found) if f}

    def labels(self, n_candidates: int | None = None) -> list:
        """Marker name of each candidate (None for rejected ones)."""
        n = len(self.colors) if n_candidates is None else n_candidates
        out = [None] * n
        for k, i in enumerate(self.candidate):
            if i >= 0:
                out[i] = self.names[k]
        return out


def _srgb_to_linear(c):
    c = np.asarray(c, float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(c):
    c = np.clip(np.asarray(c, float), 0, 1)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def _gains_views(costs: list, measured: list, reference: list) -> np.ndarray:
    """Per-channel gains (linear light) that map each photo's references onto its
    measurements, shape (n_photos, 3): of a photo's matched pairs' colours (``measured``,
    ``reference``: (M, 3) each) those whose cost (``costs``: (M,)) is at most the median cost
    (the confident half), per channel the median of the finite ratios measured / reference
    (references above 0.02); ones where fewer than three pairs are confident (von Kries
    adaptation).

    The same numbers as a loop over the photos taking :func:`~stillcap._numeric.median` of
    each set: the medians are the middle values of each row sorted with the missing entries
    last (element-wise arithmetic and sorting do not depend on what else is in the array), in
    one set of array operations for all photos (~1 ms less per puppet capture: two rounds per
    identification, ~50 us per photo each)."""
    n = np.array([len(c) for c in costs])
    rows = np.arange(len(costs))
    pad = np.full((len(costs), max(int(n.max(initial=0)), 1)), np.inf)
    view = np.repeat(rows, n)
    slot = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    pad[view, slot] = np.concatenate(costs) if len(view) else np.zeros(0)
    srt = np.sort(pad, axis=1)
    k = n // 2
    mid = np.where(n % 2 == 1, srt[rows, k], (srt[rows, np.maximum(k - 1, 0)] + srt[rows, k]) / 2)
    good = pad[view, slot] <= mid[view]  # the confident half (a photo without matches: none)
    m = _srgb_to_linear(np.concatenate(measured)[good]) if len(view) else np.zeros((0, 3))
    r = _srgb_to_linear(np.concatenate(reference)[good]) if len(view) else np.zeros((0, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(r > 0.02, m / r, np.nan)
    # per photo and channel the median of the finite ratios (those not finite sorted last)
    gv = view[good]
    cnt = np.bincount(gv, minlength=len(costs))
    gslot = np.arange(len(gv)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    R = np.full((len(costs), max(int(cnt.max(initial=0)), 1), 3), np.inf)
    R[gv, gslot] = np.where(np.isfinite(ratio), ratio, np.inf)
    fin = np.isfinite(R).sum(axis=1)  # (n_photos, 3)
    R = np.sort(R, axis=1)
    kk = fin // 2
    c3 = np.arange(3)[None]
    hi = R[rows[:, None], np.minimum(kk, R.shape[1] - 1), c3]
    lo = R[rows[:, None], np.maximum(kk - 1, 0), c3]
    with np.errstate(invalid="ignore"):
        g = np.where(fin == 0, np.nan, np.where(fin % 2 == 1, hi, (lo + hi) / 2))
    g = np.where(np.isfinite(g) & (g > 0), g, 1.0)
    return np.where((cnt >= 3)[:, None], g, 1.0)


_REF_LAB: dict = {}


def _ref_lab(ref: np.ndarray) -> np.ndarray:
    """:func:`rgb_to_lab` of a palette's reference colours, remembered (every photo of a capture
    converts the same palette); a read-only array."""
    key = (ref.shape, ref.tobytes())
    lab = _REF_LAB.get(key)
    if lab is None:
        if len(_REF_LAB) > 64:
            _REF_LAB.clear()
        lab = rgb_to_lab(ref)
        lab.setflags(write=False)
        _REF_LAB[key] = lab
    return lab


def identify_colors(colors_rgb, palette: Palette, centers=None, method: str = "assignment",
                    metric: str | None = None, max_distance: float | None = None,
                    lightness_weight: float | None = None, adapt: bool | None = None, sampler: str = "given",
                    radii=None) -> Identification:
    """Identify candidates from their measured colours.

    Parameters
    ----------
    colors_rgb : array_like, shape (N, 3)
        Candidate colours, sRGB [0, 1] (NaN rows are never identified).
    palette : Palette
        Reference colours of the K markers.
    centers : array_like, shape (N, 2), optional
        Candidate positions, copied into the result's ``points``.
    method : {"greedy", "assignment"}
        The thesis's greedy acceptance (:func:`greedy_match`) or the optimal assignment
        (:func:`optimal_match`).
    metric : {"hsb", "lab", "ciede2000"}, optional
        Default ``hsb`` for greedy, ``ciede2000`` for assignment.
    max_distance : float, optional
        Rejection threshold in ``metric`` units; default 0.15 (hsb), 25 (lab), 15 (ciede2000).
    lightness_weight : float, optional
        Weight of lightness differences for ``lab`` / ``ciede2000``; default 1 for greedy,
        0.5 for assignment.
    adapt : bool, optional
        Estimate per-channel gains (exposure and white balance) from a first matching, divide
        them out of the measured colours and match again (twice); default off for greedy, on
        for assignment.
    sampler : str
        Recorded in the result.
    radii : array_like, shape (N,), optional
        Candidate radii, copied into the result's ``radii``.

    Returns
    -------
    Identification
    """
    return identify_colors_views([colors_rgb], palette, [centers], method=method, metric=metric,
                                 max_distance=max_distance, lightness_weight=lightness_weight, adapt=adapt,
                                 sampler=sampler, radii=[radii])[0]


def identify_colors_views(colors_rgb, palette: Palette, centers=None, method: str = "assignment",
                          metric: str | None = None, max_distance: float | None = None,
                          lightness_weight: float | None = None, adapt: bool | None = None,
                          sampler: str = "given", radii=None) -> list:
    """:func:`identify_colors` of several photos' candidates at once (each photo on its own:
    its own matching and white-balance gains), the same result per photo.

    The identification's cost is mostly NumPy call overhead on small matrices (CIEDE2000 is
    ~70 operations on ~20 x 16 pairs, three matrices per photo); here each of the three rounds
    computes the matrices of all photos in one CIEDE2000 call.

    Parameters
    ----------
    colors_rgb : sequence of array_like, each shape (N_v, 3)
        Candidate colours of every photo, sRGB [0, 1].
    palette : Palette
    centers, radii : sequence of array_like, optional
        Per photo, shapes (N_v, 2) and (N_v,).
    method, metric, max_distance, lightness_weight, adapt, sampler
        As :func:`identify_colors`.

    Returns
    -------
    list of Identification
    """
    cols = [as_array(c, (None, 3), "colors_rgb") for c in colors_rgb]
    nv = len(cols)
    centers = [None] * nv if centers is None else list(centers)
    radii = [None] * nv if radii is None else list(radii)
    if len(centers) != nv or len(radii) != nv:
        raise ValueError(f"{nv} colour sets but {len(centers)} centre sets and {len(radii)} radius sets")
    pts = [np.full((len(c), 2), np.nan) if p is None else as_array(p, (len(c), 2), "centers")
           for c, p in zip(cols, centers)]
    rad = [np.full(len(c), np.nan) if r is None else as_array(r, (len(c),), "radii") for c, r in zip(cols, radii)]
    return _identify_views(cols, palette, pts, rad, method, metric, max_distance, lightness_weight, adapt, sampler)


def _identify_views(cols: list, palette: Palette, pts: list, rad: list, method: str, metric, max_distance,
                    lightness_weight, adapt, sampler: str) -> list:
    """:func:`identify_colors` of checked per-photo arrays, the cost matrices of all photos of a
    round in one call (:func:`identify_colors_views`)."""
    if method not in ("greedy", "assignment"):
        raise ValueError(f"method must be 'greedy' or 'assignment', got {method!r}")
    greedy = method == "greedy"
    metric = ("hsb" if greedy else "ciede2000") if metric is None else metric
    lightness_weight = (1.0 if greedy else 0.5) if lightness_weight is None else float(lightness_weight)
    adapt = (not greedy) if adapt is None else bool(adapt)
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    max_d = _DEFAULT_MAX[metric] if max_distance is None else float(max_distance)
    match = greedy_match if method == "greedy" else optimal_match
    ref = palette.rgb
    K = len(palette)
    cols = list(cols)
    valid = [np.isfinite(c).all(axis=1) for c in cols]

    # the references' Lab colours once for all cost matrices rather than in every
    # color_distance call (the same numbers: color_distance converts both sides the same way)
    ref_lab = _ref_lab(ref) if metric in ("lab", "ciede2000") and len(ref) else None

    def costs(views):
        """Cost matrices of ``views`` (photo indices), {view: (N_v, K)}; the Lab metrics for all
        of them in one pairwise call (element-wise arithmetic: the same numbers as per photo)."""
        out = {v: np.full((len(cols[v]), len(ref)), np.nan) for v in views}
        todo = [v for v in views if valid[v].any()]
        if not todo:
            return out
        if ref_lab is not None:
            if not lightness_weight > 0:
                raise ValueError(f"lightness_weight must be > 0, got {lightness_weight}")
            # every photo's colours in one conversion, each photo's rows as on their own
            rows = [cols[v][valid[v]] for v in todo]
            counts = np.array([len(x) for x in rows])
            D = _lab_pairwise(rgb_to_lab(np.concatenate(rows), groups=counts), ref_lab, metric, lightness_weight)
            start = 0
            for v, k in zip(todo, counts):
                out[v][valid[v]] = D[start:start + k]
                start += k
        else:
            for v in todo:
                out[v][valid[v]] = color_distance(cols[v][valid[v]], ref, metric, lightness_weight)
        return out

    C = costs(range(len(cols)))
    matches = {v: match(C[v], max_d) for v in C}
    gains = [np.ones(3) for _ in cols]
    active = [v for v in C if adapt and len(matches[v][0]) >= 3]
    for _ in range(2 if active else 0):
        # Gains from the confident half of the matches; colours corrected in linear light
        # (every active photo's at once: _gains_views)
        g = _gains_views([C[v][matches[v]] for v in active], [cols[v][matches[v][0]] for v in active],
                         [ref[matches[v][1]] for v in active])
        corrected = _linear_to_srgb(_srgb_to_linear(np.concatenate([cols[v] for v in active]))
                                    / np.repeat(g, [len(cols[v]) for v in active], axis=0))
        start = 0
        for v, gv in zip(active, g):
            gains[v] = gains[v] * gv
            cols[v], start = corrected[start:start + len(cols[v])], start + len(cols[v])
        C.update(costs(active))
        for v in active:
            matches[v] = match(C[v], max_d)
    out = []
    for v in range(len(cols)):
        rows, cm = matches[v]
        n = len(cols[v])
        cand = np.full(K, -1)
        cand[cm] = rows
        points = np.full((K, 2), np.nan)
        points[cm] = pts[v][rows]
        dist = np.full(K, np.nan)
        dist[cm] = C[v][rows, cm]
        unmatched = np.ones(n, bool)
        unmatched[rows] = False
        rejected = np.flatnonzero(unmatched)  # np.setdiff1d(np.arange(n), rows)
        r_out = np.full(K, np.nan)
        r_out[cm] = rad[v][rows]
        out.append(Identification(palette.names, points, dist, cand, rejected, cols[v], C[v], method, metric,
                                  sampler, max_d, gains[v], r_out))
    return out


def identify_markers(image, centers, palette: Palette, radii=None, method: str = "assignment",
                     metric: str | None = None, sampler: str | None = None, max_distance: float | None = None,
                     lightness_weight: float | None = None, adapt: bool | None = None,
                     radius: float = 6.0) -> Identification:
    """Identify bead candidates in a photo by colour.

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
        BGR photo.
    centers : array_like, shape (N, 2), or Circles
        Candidate centres (x, y); a :class:`~stillcap.detect.circles.Circles` also gives radii.
    palette : Palette
        Reference colours (e.g. ``Palette.from_markerset(MarkerSet.puppet())`` or :func:`calibrate_palette` output).
    radii : array_like, shape (N,), optional
        Candidate radii for the ``disc`` sampler.
    method : {"greedy", "assignment"}
    metric : {"hsb", "lab", "ciede2000"}, optional
    sampler : {"patch", "disc"}, optional
        Default ``patch`` for greedy (thesis), ``disc`` for assignment.
    max_distance : float, optional
        See :func:`identify_colors`.
    lightness_weight : float, optional
        Default 1 for greedy, 0.5 for assignment.
    adapt : bool, optional
        Default False for greedy, True for assignment (see :func:`identify_colors`).
    radius : float
        Radius for the ``disc`` sampler when no radii are known, pixels.

    Returns
    -------
    Identification

    Examples
    --------
    The thesis's chain and the recommended one:

    >>> ident = identify_markers(img, find_circles(img, method="thesis"), pal, **THESIS)  # doctest: +SKIP
    >>> ident = identify_markers(img, find_circles(img), pal)  # doctest: +SKIP
    """
    return identify_markers_views([image], [centers], palette, [radii], method=method, metric=metric,
                                  sampler=sampler, max_distance=max_distance, lightness_weight=lightness_weight,
                                  adapt=adapt, radius=radius)[0]


def identify_markers_views(images, centers, palette: Palette, radii=None, method: str = "assignment",
                           metric: str | None = None, sampler: str | None = None,
                           max_distance: float | None = None, lightness_weight: float | None = None,
                           adapt: bool | None = None, radius: float = 6.0) -> list:
    """:func:`identify_markers` of several photos, the same result per photo, faster
    (:func:`identify_colors_views`).

    Parameters
    ----------
    images : sequence of array_like, each shape (H, W, 3)
        BGR photos.
    centers : sequence of (array_like, shape (N_v, 2), or Circles)
        Candidates of every photo.
    palette : Palette
    radii : sequence of array_like, shape (N_v,), optional
    method, metric, sampler, max_distance, lightness_weight, adapt, radius
        As :func:`identify_markers`.

    Returns
    -------
    list of Identification
    """
    images, centers = list(images), list(centers)
    if len(images) != len(centers):
        raise ValueError(f"{len(images)} images but {len(centers)} candidate sets")
    radii = [None] * len(images) if radii is None else list(radii)
    if len(radii) != len(images):
        raise ValueError(f"{len(images)} images but {len(radii)} radius sets")
    sampler = ("patch" if method == "greedy" else "disc") if sampler is None else sampler
    cs, rs = [], []
    for c, r in zip(centers, radii):
        if hasattr(c, "centers") and hasattr(c, "radii"):
            r = c.radii if r is None else r
            c = c.centers
        cs.append(c)
        rs.append(r)
    if sampler == "disc":  # every photo's discs sampled together (the same colours as one by one)
        inputs = [_disc_inputs(img, c, r, radius) for img, c, r in zip(images, cs, rs)]
        imgs, cs_in, rs_in, scales = (list(x) for x in zip(*inputs)) if inputs else ([], [], [], [])
        colors = _sample_discs(imgs, cs_in, rs_in, DISC_FRACTION, scales) if inputs else []
    else:
        colors = [sample_colors(img, c, r, sampler=sampler, radius=radius) for img, c, r in zip(images, cs, rs)]
    return identify_colors_views(colors, palette, cs, method=method, metric=metric, max_distance=max_distance,
                                 lightness_weight=lightness_weight, adapt=adapt, sampler=sampler, radii=rs)


# -- colour calibration ------------------------------------------------------------------------
@dataclass(eq=False)
class ColorCalibration:
    """Result of :func:`calibrate_palette`.

    Attributes
    ----------
    palette : Palette
        Updated reference colours (markers never seen keep their old colour).
    n_samples : ndarray of int, shape (K,)
        Photos each marker was measured in.
    spread : ndarray, shape (K,)
        RMS CIEDE2000 distance of the single measurements from the new reference colour
        (NaN when never seen): how much the light and the noise change a marker's colour.
    samples : list of ndarray, length K
        The single measurements, each shape (n_samples, 3), sRGB.
    """

    palette: Palette
    n_samples: np.ndarray
    spread: np.ndarray
    samples: list


def calibrate_palette(images, points, palette: Palette, radii=None, sampler: str = "patch",
                      radius: float = 6.0) -> ColorCalibration:
    """Reference colours measured from photos (the thesis's T-pose calibration).

    The thesis measured every marker in twelve T-pose photos (30-degree turntable steps) and
    took the mean as its reference colour. The mean is taken here in sRGB (the thesis averaged
    HSB values, which breaks for hues near 0 = 1).

    Parameters
    ----------
    images : sequence of array_like, each shape (H, W, 3)
        BGR photos.
    points : sequence of (array_like, shape (K, 2)) or of Identification
        Per photo, the pixel position of each palette marker in palette order (NaN = not
        seen), or a first-pass identification of the photo.
    palette : Palette
        The markers (names, order) and their current colours.
    radii : sequence of (array_like, shape (K,)), optional
        Per photo, bead radii for the ``disc`` sampler (default: those of an Identification,
        else ``radius``).
    sampler : {"patch", "disc"}
        Must match the sampler used later for identification.
    radius : float

    Returns
    -------
    ColorCalibration
    """
    images = list(images)
    points = list(points)
    if len(images) != len(points):
        raise ValueError(f"{len(images)} images but {len(points)} point sets")
    K = len(palette)
    radii = [None] * len(images) if radii is None else list(radii)
    if len(radii) != len(images):
        raise ValueError(f"{len(images)} images but {len(radii)} radius sets")
    samples = [[] for _ in range(K)]
    for img, pts, rr in zip(images, points, radii):
        if isinstance(pts, Identification):
            if tuple(pts.names) != tuple(palette.names):
                raise ValueError("identification names differ from the palette's")
            if rr is None and np.isfinite(pts.radii).any():
                rr = np.where(np.isfinite(pts.radii), pts.radii, radius)
            pts = pts.points
        p = as_array(pts, (K, 2), "points")
        col = sample_colors(img, p, None if rr is None else as_array(rr, (K,), "radii"), sampler=sampler,
                            radius=radius)
        for k in range(K):
            if np.isfinite(col[k]).all():
                samples[k].append(col[k])
    rgb = palette.rgb.copy()
    n = np.zeros(K, int)
    spread = np.full(K, np.nan)
    arrays = []
    for k in range(K):
        s = np.array(samples[k]).reshape(-1, 3)
        arrays.append(s)
        n[k] = len(s)
        if len(s):
            rgb[k] = s.mean(axis=0)
            spread[k] = float(np.sqrt(np.mean(color_distance(s, rgb[k][None], "ciede2000") ** 2)))
    return ColorCalibration(palette.with_colors(np.clip(rgb, 0, 1)), n, spread, arrays)
