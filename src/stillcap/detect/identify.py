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
    "ColourCalibration",
    "Identification",
    "calibrate_palette",
    "greedy_match",
    "identify_colors",
    "identify_markers",
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

_DEFAULT_MAX = {"hsb": 0.15, "lab": 25.0, "ciede2000": 15.0}


def _as_image(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3) (BGR), got {img.shape}")
    return img


def sample_colors(image, centers, radii=None, sampler: str = "patch", size: int = 5,
                  disc_fraction: float = 0.7, radius: float = 6.0) -> np.ndarray:
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
    img = _as_image(image)
    scale = 255.0 if img.dtype == np.uint8 else 1.0
    c = as_array(centers, (None, 2), "centers")
    r = np.full(len(c), float(radius)) if radii is None else as_array(radii, (len(c),), "radii")
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")
    if int(size) != size or size < 1 or size % 2 == 0:
        raise ValueError(f"size must be a positive odd integer, got {size}")
    h, w = img.shape[:2]
    out = np.full((len(c), 3), np.nan)
    if sampler == "disc":
        return _sample_discs(img, c, r, disc_fraction, scale)
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


def _sample_discs(img: np.ndarray, c: np.ndarray, r: np.ndarray, disc_fraction: float, scale: float) -> np.ndarray:
    """The ``disc`` sampler of :func:`sample_colors` for all candidates at once: the pixels of
    each disc (the same sets as a loop over the candidates) gathered from one common window
    size and averaged with a mask (a loop cost ~0.1 ms per candidate)."""
    h, w = img.shape[:2]
    out = np.full((len(c), 3), np.nan)
    with np.errstate(invalid="ignore"):
        live = np.all(np.isfinite(c), axis=1) & np.isfinite(r)
    if not live.any():
        return out
    cl, R = c[live], np.maximum(disc_fraction * r[live], 0.75)
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
    px = img[np.minimum(ys, h - 1), np.minimum(xs, w - 1)].astype(float)  # (m, S, S, 3)
    k = sel.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (px * sel[..., None]).sum(axis=(1, 2)) / k[:, None]
    mean = np.where((k > 0)[:, None], mean, np.nan)
    out[np.flatnonzero(live)] = mean[:, ::-1] / scale
    return np.clip(out, 0.0, 1.0)


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


def _gains(measured, reference):
    """Per-channel gains (linear light) that map the references onto the measurements:
    the median ratio over the matched pairs, normalised to green (von Kries adaptation)."""
    m = _srgb_to_linear(measured)
    r = _srgb_to_linear(reference)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(r > 0.02, m / r, np.nan)
    # per channel the median of the finite ratios: np.nanmedian's value (its masked-array
    # path cost ~0.5 ms per call on these few rows)
    g = np.array([np.median(col[np.isfinite(col)]) if np.isfinite(col).any() else np.nan for col in ratio.T])
    return np.where(np.isfinite(g) & (g > 0), g, 1.0)


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
    col = as_array(colors_rgb, (None, 3), "colors_rgb")
    n = len(col)
    pts = np.full((n, 2), np.nan) if centers is None else as_array(centers, (n, 2), "centers")
    rad = np.full(n, np.nan) if radii is None else as_array(radii, (n,), "radii")
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
    valid = np.all(np.isfinite(col), axis=1)
    ref = palette.rgb
    gains = np.ones(3)

    # the references' Lab colours once for the (up to three) cost matrices rather than in
    # every color_distance call (the same numbers: color_distance converts both sides the same way)
    ref_lab = rgb_to_lab(ref) if metric in ("lab", "ciede2000") and len(ref) else None

    def costs(c):
        C = np.full((n, len(ref)), np.nan)
        if valid.any():
            if ref_lab is not None:
                if not lightness_weight > 0:
                    raise ValueError(f"lightness_weight must be > 0, got {lightness_weight}")
                C[valid] = _lab_pairwise(rgb_to_lab(c[valid]), ref_lab, metric, lightness_weight)
            else:
                C[valid] = color_distance(c[valid], ref, metric, lightness_weight)
        return C

    C = costs(col)
    rows, cols = match(C, max_d)
    if adapt and len(rows) >= 3:
        for _ in range(2):
            # Gains from the confident half of the matches; colours corrected in linear light.
            good = C[rows, cols] <= np.median(C[rows, cols])
            g = _gains(col[rows[good]], ref[cols[good]]) if good.sum() >= 3 else np.ones(3)
            gains = gains * g
            col = _linear_to_srgb(_srgb_to_linear(col) / g)
            C = costs(col)
            rows, cols = match(C, max_d)
    K = len(palette)
    cand = np.full(K, -1)
    cand[cols] = rows
    points = np.full((K, 2), np.nan)
    points[cols] = pts[rows]
    dist = np.full(K, np.nan)
    dist[cols] = C[rows, cols]
    rejected = np.setdiff1d(np.arange(n), rows)
    r_out = np.full(K, np.nan)
    r_out[cols] = rad[rows]
    return Identification(palette.names, points, dist, cand, rejected, col, C, method, metric, sampler,
                          max_d, gains, r_out)


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
        Reference colours (e.g. ``Palette.thesis()`` or :func:`calibrate_palette` output).
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
    if hasattr(centers, "centers") and hasattr(centers, "radii"):
        radii = centers.radii if radii is None else radii
        centers = centers.centers
    sampler = ("patch" if method == "greedy" else "disc") if sampler is None else sampler
    colors = sample_colors(image, centers, radii, sampler=sampler, radius=radius)
    return identify_colors(colors, palette, centers, method=method, metric=metric, max_distance=max_distance,
                           lightness_weight=lightness_weight, adapt=adapt, sampler=sampler, radii=radii)


# -- colour calibration ------------------------------------------------------------------------
@dataclass(eq=False)
class ColourCalibration:
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
                      radius: float = 6.0) -> ColourCalibration:
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
    ColourCalibration
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
            if rr is None and np.any(np.isfinite(pts.radii)):
                rr = np.where(np.isfinite(pts.radii), pts.radii, radius)
            pts = pts.points
        p = as_array(pts, (K, 2), "points")
        col = sample_colors(img, p, None if rr is None else as_array(rr, (K,), "radii"), sampler=sampler,
                            radius=radius)
        for k in range(K):
            if np.all(np.isfinite(col[k])):
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
    return ColourCalibration(palette.with_colors(np.clip(rgb, 0, 1)), n, spread, arrays)
