"""Puppet stop-motion capture (SPEC J3): photos of a marked puppet -> named 2D markers -> 3D
markers -> posed skeleton. Wiring of the stages, plus the marker triangulation
(:func:`solve_markers`, :func:`triangulate_markers`), the comparison with the truth and the result.

::

    photo of every view
      -> detect_beads                candidates in the bright region, named by colour
                                     (detect.beads: find_circles template | thesis,
                                      identify_markers recommended | thesis)
      -> observations (n_views, n_markers, 2), NaN = not identified
      -> bead_fill                   how whole each bead looks  (detect.beads: partly hidden beads
                                                                 are off-centre)
      -> triangulate_markers         3D markers                 (geometry.triangulate, outlier rejection;
                                                                 its view-pair consensus vectorised here)
                                     markers seen in fewer than 2 views: NaN, listed in ``missing``
      -> reidentify                  candidates named after the projected 3D markers (detect.beads),
                                     then fill + triangulation again for the markers it renamed
      -> bone_directions +           the thesis's pose          (body.kinematics)
         pose_from_markers
      -> fit_pose                    joint rotations within the limits, twist where a joint frame
                                     has 3+ points (body.puppet_pose)
      -> PuppetResult                to_dict() keys shared with the studio's truth.json

The stages that moved out (``detect_view``'s work, ``bright_region``, ``bead_fill``,
``reidentify``, ``fit_pose``, ``frame_status``, ``PoseFit``, ``ViewResult``) are still importable
from here.

Units: metres and radians inside; pixels ``(x, y)`` (``docs/conventions.md``); the result's
``to_dict`` says its units. See ``docs/puppet.md``.
"""
from __future__ import annotations

import functools
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from stillcap._blas import one_blas_thread
from stillcap.body.kinematics import normalised
from stillcap.body.markerset import BUILTIN_MARKERSETS, MarkerSet, MarkerTrajectories
from stillcap.body.puppet_pose import PoseFit, fit_pose, frame_status
from stillcap.body.skeleton import Pose, Skeleton
from stillcap.camera import Rig
from stillcap.detect.beads import (DETECTORS, IDENTIFIERS, PreparedView, ViewResult, bead_fill,  # noqa: F401
                                   bead_fill_views, bright_region, detect_beads, expected_radius_px,
                                   find_bead_candidates, identify_views, prepare_view, reidentify, roi_box)
from stillcap.detect.palette import Palette
from stillcap.geometry.triangulate import Triangulation, _Normal3, triangulate
from stillcap.files.jsonfile import read_json

__all__ = ["DETECTORS", "IDENTIFIERS", "DEFAULT", "THESIS_CHAIN", "PuppetSettings", "ViewResult", "MarkerSolve",
           "PoseFit", "PuppetComparison", "PuppetResult", "LoadedResult", "detect_view", "bead_fill",
           "solve_markers", "fit_pose", "frame_status", "compare_with_truth", "reconstruct_puppet",
           "run_capture", "run_project", "reconstruct_project", "run_folder", "load_result", "RESULT_FORMAT",
           "capture_markerset",
           "bright_region", "reidentify", "triangulate_markers", "with_settings"]

RESULT_FORMAT = "stillcap-puppet-result"

# DETECTORS and IDENTIFIERS (the choices PuppetSettings offers) live in stillcap.detect.beads.


@dataclass(frozen=True)
class PuppetSettings:
    """How the pipeline runs. :data:`DEFAULT` is the measured best, :data:`THESIS_CHAIN` the
    thesis's own chain (see ``docs/puppet.md``).

    Attributes
    ----------
    detector : str
        :func:`~stillcap.detect.circles.find_circles` method (:data:`DETECTORS`).
    identify : str
        ``"recommended"`` (assignment, CIEDE2000, white-balance adaptation) or ``"thesis"``
        (greedy HSB).
    radius_range : (float, float)
        Bead radius in the photos, pixels (thesis: 5-7 px at 640x480).
    n_circles : int
        Candidates per photo (thesis: N = 16).
    triangulation : str
        ``"dlt"`` (with reprojection refinement) or ``"midpoint"`` (the thesis's least-squares
        point nearest to the back-projection lines, no refinement).
    outlier_px : float or None
        Views that disagree with a marker's point by more than this are not used (None: keep all).
    use_fill : bool
        Leave out views where a bead looks partly hidden (:func:`bead_fill`) while 2+ whole
        views remain.
    min_fill, fill_ratio : float
        A view is whole when its fill is at least ``min_fill``, or at least ``fill_ratio`` x the
        marker's best fill when that best view is whole.
    pose : str
        The result's pose: ``"fit"`` (:func:`fit_pose`) or ``"thesis"`` (bone directions).
    marker_sigma_m : float
        Expected 3D marker error, metres: weight of the markers against the prior in :func:`fit_pose`.
    roi : bool
        Detect only inside the box around the bright pixels (:func:`bright_region`): faster, the
        same beads.
    reidentify : bool
        After the first triangulation, name the candidates after the 3D markers
        (:func:`reidentify`) and triangulate again from that identification.
    reid_gate : float
        :func:`reidentify`'s pixel gate, share of the projected bead radius.
    reid_colour : float
        :func:`reidentify`'s colour gate, multiple of the identification's acceptance distance.
    coarse : bool
        Template detector: find the contrast peaks at half resolution and climb each to its
        full-resolution maximum (faster); False: the full-resolution contrast map.
    """

    detector: str = "template"
    identify: str = "recommended"
    radius_range: tuple = (5.0, 7.0)
    n_circles: int = 16
    triangulation: str = "dlt"
    outlier_px: float | None = 1.0
    use_fill: bool = True
    min_fill: float = 0.65
    fill_ratio: float = 0.85
    pose: str = "fit"
    marker_sigma_m: float = 0.2e-3
    roi: bool = True
    reidentify: bool = True
    reid_gate: float = 0.6
    reid_colour: float = 2.0
    coarse: bool = True

    def __post_init__(self):
        if self.detector not in DETECTORS:
            raise ValueError(f"unknown detector {self.detector!r}; choose one of {', '.join(DETECTORS)}")
        if self.identify not in IDENTIFIERS:
            raise ValueError(f"unknown identification {self.identify!r}; choose one of {', '.join(IDENTIFIERS)}")
        if self.triangulation not in ("dlt", "midpoint"):
            raise ValueError(f"unknown triangulation {self.triangulation!r}; choose dlt or midpoint")
        if self.pose not in ("fit", "thesis"):
            raise ValueError(f"unknown pose method {self.pose!r}; choose fit or thesis")
        lo, hi = (float(v) for v in self.radius_range)
        if not 0 < lo <= hi:
            raise ValueError(f"radius_range must be 0 < min <= max pixels, got {self.radius_range}")
        if self.outlier_px is not None and not self.outlier_px > 0:
            raise ValueError(f"outlier_px must be > 0 pixels or None, got {self.outlier_px}")

    def to_dict(self) -> dict:
        return {"detector": self.detector, "identify": self.identify, "radius_range_px": list(self.radius_range),
                "n_circles": self.n_circles, "triangulation": self.triangulation, "outlier_px": self.outlier_px,
                "use_fill": self.use_fill, "min_fill": self.min_fill, "fill_ratio": self.fill_ratio,
                "pose": self.pose, "marker_sigma_m": self.marker_sigma_m, "roi": self.roi,
                "reidentify": self.reidentify, "reid_gate": self.reid_gate, "reid_colour": self.reid_colour,
                "coarse": self.coarse}


#: The measured best chain (``benchmarks/bench_puppet.py``).
DEFAULT = PuppetSettings()
#: The thesis's chain: IsoData + outline + Hough, greedy HSB, midpoint triangulation of every
#: identified view, bone directions.
THESIS_CHAIN = PuppetSettings(detector="thesis", identify="thesis", triangulation="midpoint", outlier_px=None, roi=False,
                              use_fill=False, pose="thesis", reidentify=False)


# --- stage 1: detection and identification per photo -------------------------------------------
def detect_view(image, palette: Palette, settings: PuppetSettings = DEFAULT, region=None,
                prepared: PreparedView | None = None) -> ViewResult:
    """:func:`stillcap.detect.beads.detect_beads` with the settings' ``detector``, ``identify``,
    ``radius_range``, ``n_circles`` and ``roi``: the bead candidates of one photo, named by colour.
    ``region``: the photo's :func:`~stillcap.detect.beads.roi_box` if already computed;
    ``prepared``: its :func:`prepare_view` with these settings (:func:`_prepare`)."""
    return detect_beads(image, palette, settings.detector, settings.identify, settings.radius_range,
                        settings.n_circles, settings.roi, settings.coarse, region, prepared)


def _prepare(image, settings: PuppetSettings = DEFAULT) -> PreparedView:
    """:func:`~stillcap.detect.beads.prepare_view` with the settings' detector, radii, roi and coarse."""
    return prepare_view(image, settings.detector, settings.radius_range, settings.roi, settings.coarse)


@functools.lru_cache(maxsize=1)
def _puppet_skeleton() -> Skeleton:
    """:meth:`Skeleton.puppet` (a frozen dataclass), read and built once: ~2 ms per pose."""
    return Skeleton.puppet()


# --- stage 3: triangulation --------------------------------------------------------------------
@dataclass(eq=False)
class MarkerSolve:
    """3D markers from the identified 2D markers of every view.

    Attributes
    ----------
    names : tuple of str, length n_markers
    points : ndarray, shape (n_markers, 3)
        Metres, rig world (puppet frame); NaN for markers identified in fewer than two usable views.
    observations : ndarray, shape (n_views, n_markers, 2)
        Identified pixels (NaN = not identified).
    used : ndarray of bool, shape (n_views, n_markers)
        Observations the final point rests on.
    fill : ndarray, shape (n_views, n_markers)
        :func:`bead_fill` of every observation (NaN without images).
    partial : ndarray of bool, shape (n_views, n_markers)
        Observations left out as partly hidden beads.
    outlier : ndarray of bool, shape (n_views, n_markers)
        Observations left out because they disagree with the other views (> ``outlier_px``):
        a wrong identification, or a bead so hidden that its centre is off.
    whole : ndarray of bool, shape (n_views, n_markers)
        Observations whose bead looks whole (the fill test; all identified ones without it).
    reproj_error_px : ndarray, shape (n_markers,)
        RMS reprojection error over the used views, pixels.
    triangulation : Triangulation
        The final triangulation.
    """

    names: tuple
    points: np.ndarray
    observations: np.ndarray
    used: np.ndarray
    fill: np.ndarray
    partial: np.ndarray
    outlier: np.ndarray
    reproj_error_px: np.ndarray
    triangulation: Triangulation
    whole: np.ndarray | None = None

    @property
    def n_views(self) -> np.ndarray:
        """Views used per marker, shape (n_markers,)."""
        return self.used.sum(axis=0)

    @property
    def identified_views(self) -> np.ndarray:
        """Views that identified each marker, shape (n_markers,)."""
        return np.isfinite(self.observations[..., 0]).sum(axis=0)

    @property
    def ok(self) -> np.ndarray:
        return np.all(np.isfinite(self.points), axis=1)

    @property
    def whole_views(self) -> np.ndarray:
        """Used views per marker whose bead looked whole, shape (n_markers,): a marker with
        fewer than 2 rests on partly hidden (or image-border) views and may be off by a few
        tenths of a millimetre to 2 mm."""
        w = self.used if self.whole is None else self.used & self.whole
        return w.sum(axis=0)

    @property
    def missing(self) -> tuple:
        """Markers without a 3D position (identified in fewer than two usable views): the
        thesis's red entries."""
        return tuple(n for n, good in zip(self.names, self.ok) if not good)


def triangulate_markers(rig: Rig, points_2d, method: str = "dlt", refine: bool = True,
                        outlier_px: float | None = None) -> Triangulation:
    """:func:`stillcap.geometry.triangulate.triangulate` for a handful of markers, same result, faster.

    The shared triangulation checks the views' consensus by looping over the 66 view pairs of
    a turntable, each time solving and projecting every marker into every view (792 small
    projections, ~100 ms for 16 markers). Here every (pair, marker) hypothesis becomes one
    "point" of a single call (16 x 66 points), projected once per view, and the best pair is
    chosen with array operations; the final solve is the shared one with the chosen views.
    Same choice rule as the shared function (most agreeing views, then the smallest summed
    error, then the first pair), so the same points to rounding.

    Parameters
    ----------
    rig : Rig, n_views cameras
    points_2d : array_like, shape (n_views, n_markers, 2)
        Distorted pixels, NaN where unseen.
    method, refine, outlier_px
        As :func:`~stillcap.geometry.triangulate.triangulate`.
    """
    x = np.asarray(points_2d, float)
    if x.ndim != 3 or x.shape[0] != len(rig) or x.shape[2] != 2:
        raise ValueError(f"points_2d must have shape ({len(rig)}, N, 2), got {x.shape}")
    return _triangulate_markers(rig, x, method, refine, outlier_px)


class _Views:
    """The views' cameras as stacked arrays, and the marker observations in normalised
    coordinates, for the many small triangulations of :func:`solve_markers`.

    :func:`stillcap.geometry.triangulate.triangulate` loops over the cameras and undistorts the
    observations again at every call (seven calls per pose, ~4 ms each); here the observations
    are undistorted once and every step (DLT, Gauss-Newton refinement, projection) is one set
    of array operations over all views. The arithmetic is the shared function's (same normal
    equations, same Cramer solve, same stopping rule), so the points agree to rounding.
    """

    def __init__(self, rig: Rig, x: np.ndarray):
        cams = list(rig)
        self.P = np.stack([c.world2cam[:3] for c in cams])  # (nv, 3, 4)
        self.K = np.stack([c.K for c in cams])
        self.dist = np.stack([np.asarray(c.dist, float) for c in cams])
        self.r2max = np.array([c.max_distortion_r2 if np.any(c.dist[[0, 1, 4]]) else np.inf for c in cams])
        self.x = x
        self.xn = np.stack([c.pixels_to_normalized(xi) for c, xi in zip(cams, x)])  # (nv, n, 2)
        self.seen = np.isfinite(self.xn[..., 0]) & np.isfinite(self.xn[..., 1])

    def project(self, X: np.ndarray) -> np.ndarray:
        """Pixels of points ``X`` (N, 3) in every view, (nv, N, 2); as :meth:`Camera.project`."""
        P = self.P
        pc = np.einsum("vij,nj->vni", P[:, :, :3], X) + P[:, None, :, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(pc[..., 2] > 1e-12, pc[..., 2], np.nan)
            x, y = pc[..., 0] / z, pc[..., 1] / z
            r2 = x * x + y * y
            far = r2 > self.r2max[:, None]
        x, y = np.where(far, np.nan, x), np.where(far, np.nan, y)
        r2 = x * x + y * y
        k1, k2, p1, p2, k3 = (self.dist[:, i, None] for i in range(5))
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        K = self.K
        return np.stack([K[:, 0, 0, None] * xd + K[:, 0, 1, None] * yd + K[:, 0, 2, None],
                         K[:, 1, 1, None] * yd + K[:, 1, 2, None]], axis=-1)

    def _rows(self, mask: np.ndarray):
        """DLT rows of every (view, marker): ``J`` (2, nv, n, 3) and ``r`` (2, nv, n), zero where unmasked."""
        P = self.P
        m = mask.astype(float)
        J, r = [], []
        for k in (0, 1):
            c = np.where(mask, self.xn[..., k], 0.0)
            J.append((c[..., None] * P[:, None, 2, :3] - P[:, None, k, :3]) * m[..., None])
            r.append(-(c * P[:, None, 2, 3] - P[:, None, k, 3]) * m)
        return np.stack(J), np.stack(r)

    @staticmethod
    def _normal(J: np.ndarray, r: np.ndarray, axis) -> _Normal3:
        """Normal equations summed over ``axis`` of rows J (..., n, 3), r (..., n)."""
        eq = _Normal3(J.shape[-2])
        j0, j1, j2 = J[..., 0], J[..., 1], J[..., 2]
        eq.a = np.stack([(j0 * j0).sum(axis), (j0 * j1).sum(axis), (j0 * j2).sum(axis), (j1 * j1).sum(axis),
                         (j1 * j2).sum(axis), (j2 * j2).sum(axis)])
        eq.b = np.stack([(j0 * r).sum(axis), (j1 * r).sum(axis), (j2 * r).sum(axis)])
        return eq

    def dlt(self, mask: np.ndarray) -> np.ndarray:
        J, r = self._rows(mask)
        return self._normal(J, r, (0, 1)).solve()

    def refine(self, mask: np.ndarray, X: np.ndarray, iterations: int = 4) -> np.ndarray:
        """Gauss-Newton on the reprojection error in undistorted pixels (``triangulate``'s ``_refine``)."""
        X = X.copy()
        good = np.all(np.isfinite(X), axis=1)
        P, K = self.P, self.K
        R, t = P[:, :, :3], P[:, :, 3]
        fx, s, fy = K[:, 0, 0, None, None], K[:, 0, 1, None, None], K[:, 1, 1, None, None]
        for _ in range(iterations):
            pc = np.einsum("vij,nj->vni", R, np.where(good[:, None], X, 0.0)) + t[:, None]
            w = mask & good[None] & (pc[..., 2] > 0)
            iz = np.where(w, 1.0 / np.where(w, pc[..., 2], 1.0), 0.0)
            u, v = pc[..., 0] * iz, pc[..., 1] * iz
            du = (u - np.where(w, self.xn[..., 0], 0.0)) * w
            dv = (v - np.where(w, self.xn[..., 1], 0.0)) * w
            du_dX = (R[:, None, 0] - R[:, None, 2] * u[..., None]) * iz[..., None]  # (nv, n, 3)
            dv_dX = (R[:, None, 1] - R[:, None, 2] * v[..., None]) * iz[..., None]
            J = np.stack([fx * du_dX + s * dv_dX, fy * dv_dX])
            r = np.stack([-(fx[..., 0] * du + s[..., 0] * dv), -fy[..., 0] * dv])
            step = self._normal(J, r, (0, 1)).solve(damping=1e-12)
            ok = good & np.all(np.isfinite(step), axis=1)
            X[ok] += step[ok]
            if not np.any(np.abs(step[ok]) > 1e-10):
                break
        return X

    def solve(self, mask: np.ndarray, refine: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Points from the masked observations (NaN with fewer than 2) and their pixel errors
        in every view where seen, (n, 3) and (nv, n)."""
        mask = mask & self.seen
        X = self.dlt(mask)
        if refine:
            X = self.refine(mask, X)
        X[mask.sum(axis=0) < 2] = np.nan
        return X, np.linalg.norm(self.project(X) - self.x, axis=-1)

    def pair_errors(self) -> np.ndarray:
        """:func:`_pair_errors`: each view pair's linear point of each marker (from the per-view
        normal equations added pairwise), its pixel error in every view, (nv, n_pairs, n)."""
        nv, n = self.seen.shape
        pairs = _view_pairs(nv)
        J, r = self._rows(self.seen)
        eq1 = self._normal(J, r, 0)  # per view: a (6, nv, n), b (3, nv, n)
        both = self.seen[pairs[:, 0]] & self.seen[pairs[:, 1]]  # (n_pairs, n)
        # only the hypotheses of pairs that saw the marker (a quarter of them on a turntable)
        # are solved and projected (element-wise arithmetic: the same numbers as for all)
        pi, mi = np.nonzero(both)
        p0, p1 = pairs[pi, 0], pairs[pi, 1]
        eq = _Normal3(len(pi))
        eq.a = eq1.a[:, p0, mi] + eq1.a[:, p1, mi]
        eq.b = eq1.b[:, p0, mi] + eq1.b[:, p1, mi]
        proj = self.project(eq.solve())  # (nv, m, 2)
        err = np.full((nv, len(pairs), n), np.nan)
        err[:, pi, mi] = np.linalg.norm(proj - self.x[:, mi], axis=-1)
        return err


@functools.lru_cache(maxsize=16)
def _view_pairs(nv: int) -> np.ndarray:
    """The view pairs ``(i, j)``, ``i < j``, in order, shape (n_pairs, 2), read-only (made once
    per view count: the Python loop cost ~1 ms per call, three calls per pose)."""
    out = np.array([(i, j) for i in range(nv) for j in range(i + 1, nv)], int).reshape(-1, 2)
    out.setflags(write=False)
    return out


def _pair_errors(rig: Rig, x: np.ndarray, method: str) -> np.ndarray:
    """Reprojection error of every (view pair, marker) hypothesis in every view, shape
    (n_views, n_pairs, n_markers), NaN where the pair did not see the marker or the view
    did not: each pair's linear point, from that pair's two views only, projected once per view."""
    nv, n = x.shape[:2]
    seen = np.isfinite(x[..., 0]) & np.isfinite(x[..., 1])
    pairs = _view_pairs(nv)
    n_pairs = len(pairs)
    # hypotheses: (pair, marker) -> only the pair's two views kept
    keep = np.zeros((nv, n_pairs), bool)
    keep[pairs[:, 0], np.arange(n_pairs)] = True
    keep[pairs[:, 1], np.arange(n_pairs)] = True
    both = seen[pairs[:, 0]] & seen[pairs[:, 1]]  # (n_pairs, n)
    m = keep[:, :, None] & both[None]  # (nv, n_pairs, n)
    xp = np.where(m[..., None], x[:, None], np.nan).reshape(nv, n_pairs * n, 2)
    hyp = triangulate(rig, xp, method=method, refine=False).points  # linear, as the consensus
    proj = np.stack([cam.project(hyp) for cam in rig]).reshape(nv, n_pairs, n, 2)
    return np.linalg.norm(proj - x[:, None], axis=-1)


def _triangulate_markers(rig: Rig, x: np.ndarray, method: str, refine: bool, outlier_px: float | None,
                         pair_errors: np.ndarray | None = None, views: _Views | None = None) -> Triangulation:
    """:func:`triangulate_markers` on a checked array. ``pair_errors``: :func:`_pair_errors` of
    observations that include ``x``'s (``x`` may leave some out): a pair's hypothesis depends
    only on its two views, so those of pairs still seen in ``x`` are the same and are reused."""
    nv, n = x.shape[:2]
    seen = np.isfinite(x[..., 0]) & np.isfinite(x[..., 1])
    if outlier_px is None or nv < 3 or n == 0:
        return triangulate(rig, x, method=method, refine=refine, outlier_px=outlier_px)
    pairs = _view_pairs(nv)
    fast = method == "dlt"  # the DLT chain on stacked arrays (_Views); midpoint: the shared function
    if fast and views is None:
        views = _Views(rig, x)
    if pair_errors is None:
        err = views.pair_errors() if fast else _pair_errors(rig, x, method)
    else:
        both = seen[pairs[:, 0]] & seen[pairs[:, 1]]  # pairs whose hypothesis x still has
        err = np.where(both[None], pair_errors, np.nan)
    with np.errstate(invalid="ignore"):
        inl = seen[:, None] & (err <= outlier_px)  # (nv, n_pairs, n)
    count = inl.sum(axis=0)
    score = np.where(inl, err, 0.0).sum(axis=0)
    # the shared rule, pairs in order: a pair wins over the best so far with more inliers, or as
    # many (>= 2) with a smaller summed error; with fewer than 2 the first of the most wins
    best_count = count.max(axis=0)
    cand = count == best_count[None]
    key = np.where(cand & (best_count[None] >= 2), score, np.where(cand, 0.0, np.inf))
    win = np.argmin(key, axis=0)
    mask = np.where(best_count[None] > 0, inl[:, win, np.arange(n)], seen)
    if fast:
        # views.x may hold more observations than x (x leaves some out): only x's are used
        X, errors = views.solve(mask & seen, refine)
        errors = np.where(seen, errors, np.nan)
    else:
        X = triangulate(rig, np.where(mask[..., None], x, np.nan), method=method, refine=refine).points
        errors = np.linalg.norm(np.stack([cam.project(X) for cam in rig]) - x, axis=-1)
    with np.errstate(invalid="ignore"):
        mask2 = seen & (errors <= outlier_px)
    if np.any(mask2 != mask):
        mask = mask2
        if fast:
            X, errors = views.solve(mask, refine)
            errors = np.where(seen, errors, np.nan)
        else:
            X = triangulate(rig, np.where(mask[..., None], x, np.nan), method=method, refine=refine).points
            errors = np.linalg.norm(np.stack([cam.project(X) for cam in rig]) - x, axis=-1)
    used = mask & np.all(np.isfinite(X), axis=1)[None]
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.nansum(np.where(used, errors, np.nan) ** 2, axis=0) / used.sum(axis=0))
    return Triangulation(X, rms, np.where(seen, errors, np.nan), used)


def solve_markers(rig: Rig, points_2d, names: Sequence[str], images=None, settings: PuppetSettings = DEFAULT,
                  bead_radius_m: float = 0.003, radii_px=None) -> MarkerSolve:
    """Triangulate identified markers, leaving out partly hidden beads and disagreeing views.

    1. A first triangulation (``outlier_px`` = 2 px consensus) gives each marker's depth, so
       its expected radius in every photo.
    2. With ``images`` and ``settings.use_fill``: :func:`bead_fill` of every observation;
       where a marker has two or more whole views (see :class:`PuppetSettings`), only those are
       used.
    3. The final triangulation (``settings.triangulation``, ``settings.outlier_px``); markers
       with fewer than two agreeing views are NaN. A marker the final step loses but the first
       had (its whole views disagree) keeps the first estimate.

    Parameters
    ----------
    rig : Rig, n_views cameras
        The camera of every view (a turntable's virtual cameras).
    points_2d : array_like, shape (n_views, n_markers, 2)
        Identified pixels, NaN where a view did not identify a marker.
    names : sequence of str, length n_markers
    images : sequence of n_views images, optional
        The photos, for the fill test.
    settings : PuppetSettings
    bead_radius_m : float
        Bead radius, metres (the thesis's beads: 3 mm).
    radii_px : array_like, shape (n_views, n_markers), optional
        Detected radii, used where a marker has no first 3D point.
    """
    x = np.asarray(points_2d, float)
    if x.ndim != 3 or x.shape[0] != len(rig) or x.shape[2] != 2 or x.shape[1] != len(names):
        raise ValueError(f"points_2d must have shape ({len(rig)}, {len(names)}, 2), got {x.shape}")
    method = settings.triangulation
    refine = method == "dlt"
    seen = np.isfinite(x[..., 0]) & np.isfinite(x[..., 1])
    fill = np.full(seen.shape, np.nan)
    partial = np.zeros(seen.shape, bool)
    good = seen.copy()
    x_used = x
    first = pair_err = views = None
    if images is not None and settings.use_fill:
        images = list(images)
        if len(images) != len(rig):
            raise ValueError(f"need one image per view ({len(rig)}), got {len(images)}")
        views = _Views(rig, x) if method == "dlt" else None
        pair_err = ((views.pair_errors() if views is not None else _pair_errors(rig, x, method))
                    if len(rig) >= 3 and x.shape[1] else None)
        first = _triangulate_markers(rig, x, method, refine, 2.0, pair_err, views)
        r_exp = expected_radius_px(rig, first.points, bead_radius_m)
        if radii_px is not None:
            r_exp = np.where(np.isfinite(r_exp), r_exp, np.asarray(radii_px, float) + 0.7)
        r_exp = np.where(np.isfinite(r_exp), r_exp, 0.5 * sum(settings.radius_range) + 0.7)
        fill = bead_fill_views(images, np.where(seen[..., None], x, np.nan), r_exp)
        with np.errstate(invalid="ignore"):
            best = np.nanmax(np.where(seen, fill, -np.inf), axis=0)
            # whole: fill above min_fill, or (when the marker has a whole view at all) close to
            # its best view's fill (beads that look smaller or dimmer in every view)
            good = seen & ((fill >= settings.min_fill)
                           | ((fill >= settings.fill_ratio * best[None]) & (best[None] >= settings.min_fill)))
        enough = good.sum(axis=0) >= 2
        partial = seen & ~good & enough[None]
        x_used = np.where(partial[..., None], np.nan, x)
    tri = _triangulate_markers(rig, x_used, method, refine, settings.outlier_px, pair_err, views)
    points, used = tri.points.copy(), tri.used.copy()
    lost = ~np.all(np.isfinite(points), axis=1)
    if first is not None and lost.any():
        back = lost & np.all(np.isfinite(first.points), axis=1)
        points[back] = first.points[back]
        used[:, back] = first.used[:, back]
        partial[:, back] = False
    err = np.where(used, tri.errors_px, np.nan)
    if first is not None:
        err = np.where(used & ~np.isfinite(err), first.errors_px, err)
    sq = np.where(used, err, 0.0) ** 2
    k = used.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(k >= 2, np.sqrt(np.nansum(sq, axis=0) / k), np.nan)
    outlier = seen & ~used & ~partial
    return MarkerSolve(tuple(names), points, x, used, fill, partial, outlier, rms, tri, good)


def _replace_markers(solve: MarkerSolve, cols: np.ndarray, sub: MarkerSolve, observations) -> MarkerSolve:
    """``solve`` with the markers ``cols`` taken from ``sub`` (solved on their own) and the
    observations replaced."""
    def put(a, b, axis):
        a = np.array(a, copy=True)
        if axis == 0:
            a[cols] = b
        else:
            a[:, cols] = b
        return a

    t, ts = solve.triangulation, sub.triangulation
    tri = Triangulation(put(t.points, ts.points, 0), put(t.reproj_error_px, ts.reproj_error_px, 0),
                        put(t.errors_px, ts.errors_px, 1), put(t.used, ts.used, 1))
    whole = None if solve.whole is None or sub.whole is None else put(solve.whole, sub.whole, 1)
    return MarkerSolve(solve.names, put(solve.points, sub.points, 0), np.asarray(observations, float),
                       put(solve.used, sub.used, 1), put(solve.fill, sub.fill, 1), put(solve.partial, sub.partial, 1),
                       put(solve.outlier, sub.outlier, 1), put(solve.reproj_error_px, sub.reproj_error_px, 0), tri, whole)


# --- comparison with the truth ------------------------------------------------------------------
@dataclass
class PuppetComparison:
    """A result against the studio's truth (``truth.json``).

    Identification counts are over (view, marker) pairs: ``right`` = the marker was put within
    one bead radius of its own bead's true pixel (the bead at least partly visible), ``wrong`` =
    anywhere else; ``visible`` = beads whose centre the truth marks visible, ``right_visible``
    = those identified right. ``wrong_used`` =
    wrong identifications the triangulation still used. These are for the final identification
    (after :func:`reidentify`); ``raw_*`` count the colour-only identification the same way
    (equal to the final counts when no re-identification ran). 3D errors are over the recovered
    markers; ``seen_twice`` = markers the truth shows in 2+ views. Bone directions and joint
    positions are grouped by what the markers measure (:func:`frame_status`): ``full`` bones
    start at a fully measured joint frame, ``partial`` at one with a single bead (forearms,
    shins), ``none`` at one without (hands, feet); joints likewise by the least measured frame
    on their way from the root. ``bone_groups`` / ``joint_groups`` group by the marker set's
    design; ``measured_bone_groups`` / ``measured_joint_groups`` the same way but counting only
    the markers this result recovered (a forearm of ``puppet-20`` whose second bead was seen in
    fewer than two views is "partial" there).
    """

    visible: int
    identified: int
    right: int
    right_visible: int
    wrong: int
    wrong_used: int
    seen_twice: int
    recovered: int
    recovered_seen_twice: int
    missing_seen_twice: tuple
    marker_errors_m: np.ndarray
    bone_errors_deg: dict
    thesis_bone_errors_deg: dict
    joint_errors_m: np.ndarray
    thesis_joint_errors_m: np.ndarray
    bone_groups: dict
    joint_groups: dict
    raw_identified: int = 0
    raw_right_visible: int = 0
    raw_wrong: int = 0
    measured_bone_groups: dict = field(default_factory=dict)
    measured_joint_groups: dict = field(default_factory=dict)

    @property
    def raw_wrong_pct(self) -> float:
        """Wrong colour-only identifications (before :func:`reidentify`), % of them."""
        return 100.0 * self.raw_wrong / max(self.raw_identified, 1)

    @property
    def raw_right_pct(self) -> float:
        """Visible beads the colour-only identification named right, % of the visible beads."""
        return 100.0 * self.raw_right_visible / max(self.visible, 1)

    @property
    def right_pct(self) -> float:
        """Visible beads identified right, % of the visible beads."""
        return 100.0 * self.right_visible / max(self.visible, 1)

    @property
    def wrong_pct(self) -> float:
        """Wrong identifications, % of all identifications."""
        return 100.0 * self.wrong / max(self.identified, 1)

    def marker_rms_mm(self) -> float:
        e = self.marker_errors_m[np.isfinite(self.marker_errors_m)]
        return float(np.sqrt(np.mean(e ** 2)) * 1e3) if len(e) else float("nan")

    def marker_max_mm(self) -> float:
        e = self.marker_errors_m[np.isfinite(self.marker_errors_m)]
        return float(e.max() * 1e3) if len(e) else float("nan")

    def bone_stats(self, group: str = "full", thesis: bool = False, measured: bool = False) -> tuple[float, float]:
        """(RMS, max) bone direction error in degrees over a group of bones (of
        ``measured_bone_groups`` with ``measured``)."""
        errs = self.thesis_bone_errors_deg if thesis else self.bone_errors_deg
        groups = self.measured_bone_groups if measured else self.bone_groups
        e = np.array([errs[b] for b in groups.get(group, []) if np.isfinite(errs.get(b, np.nan))])
        return (float(np.sqrt(np.mean(e ** 2))), float(e.max())) if len(e) else (float("nan"), float("nan"))

    def joint_stats(self, group: str | None = None, thesis: bool = False) -> tuple[float, float]:
        """(RMS, max) joint position error in mm, over all joints or a group."""
        errs = self.thesis_joint_errors_m if thesis else self.joint_errors_m
        idx = self.joint_groups.get(group, []) if group else list(range(len(errs)))
        e = errs[idx]
        e = e[np.isfinite(e)]
        return (float(np.sqrt(np.mean(e ** 2)) * 1e3), float(e.max() * 1e3)) if len(e) else (float("nan"), float("nan"))

    def to_dict(self) -> dict:
        def stats(pair):
            return {"rms": _num(pair[0]), "max": _num(pair[1])}

        return {
            "identification": {"visible": self.visible, "identified": self.identified, "right": self.right,
                               "right_visible": self.right_visible, "wrong": self.wrong, "wrong_used": self.wrong_used,
                               "right_pct_of_visible": _num(self.right_pct), "wrong_pct_of_identified": _num(self.wrong_pct),
                               "colour_only": {"identified": self.raw_identified, "right_visible": self.raw_right_visible,
                                               "wrong": self.raw_wrong, "right_pct_of_visible": _num(self.raw_right_pct),
                                               "wrong_pct_of_identified": _num(self.raw_wrong_pct)}},
            "markers": {"seen_twice": self.seen_twice, "recovered": self.recovered,
                        "recovered_seen_twice": self.recovered_seen_twice,
                        "missing_seen_twice": list(self.missing_seen_twice),
                        "error_mm": {"rms": _num(self.marker_rms_mm()), "max": _num(self.marker_max_mm())},
                        "errors_mm": [_num(e * 1e3) for e in self.marker_errors_m]},
            "bone_direction_error_deg": {
                "fit": {g: stats(self.bone_stats(g)) for g in self.bone_groups},
                "thesis": {g: stats(self.bone_stats(g, True)) for g in self.bone_groups},
                "per_bone_fit": {b: _num(v) for b, v in self.bone_errors_deg.items()},
                "per_bone_thesis": {b: _num(v) for b, v in self.thesis_bone_errors_deg.items()},
                "groups": {g: list(v) for g, v in self.bone_groups.items()},
                "fit_measured": {g: stats(self.bone_stats(g, measured=True)) for g in self.measured_bone_groups},
                "groups_measured": {g: list(v) for g, v in self.measured_bone_groups.items()}},
            "joint_position_error_mm": {
                "fit": {"all": stats(self.joint_stats())} | {g: stats(self.joint_stats(g)) for g in self.joint_groups},
                "thesis": {"all": stats(self.joint_stats(thesis=True))}
                | {g: stats(self.joint_stats(g, True)) for g in self.joint_groups}},
        }


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


_ORDER = {"locked": 0, "full": 1, "partial": 2, "none": 3}


def _groups(skeleton: Skeleton, markerset: MarkerSet, recovered=None) -> tuple[dict, dict]:
    """Bones and joints grouped by what the markers measure (see :class:`PuppetComparison`);
    with ``recovered`` (bool, shape (n_markers,)) by what those markers alone measure."""
    if recovered is not None:
        markerset = MarkerSet(tuple(m for m, ok in zip(markerset.markers, recovered) if ok), (), markerset.name,
                              markerset.skeleton_name, markerset.source)
    status = frame_status(skeleton, markerset)
    bones: dict[str, list] = {"full": [], "partial": [], "none": []}
    for j, name in enumerate(skeleton.names):
        p = skeleton.parents[j]
        if p < 0 or skeleton.bone_lengths[j] <= 0:
            continue
        s = status[skeleton.names[p]]
        if s != "locked":  # bones of a locked joint (the pelvis) never move
            bones[s].append(name)
    joints: dict[str, list] = {"full": [], "partial": [], "none": []}
    for j in range(skeleton.n_joints):
        worst, k = "full", skeleton.parents[j]
        while k >= 0:
            s = status[skeleton.names[k]]
            if _ORDER[s] > _ORDER[worst]:
                worst = s
            k = skeleton.parents[k]
        joints[worst].append(j)
    return {k: v for k, v in bones.items() if v}, {k: v for k, v in joints.items() if v}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    a, b = normalised(a), normalised(b)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def compare_with_truth(result: PuppetResult, truth) -> PuppetComparison:
    """Compare a result with the truth of a synthetic capture.

    Parameters
    ----------
    result : PuppetResult
    truth : stillcap.studio.puppet.PuppetTruth
        Same views in the same order, same marker names.
    """
    if list(truth.marker_names) != list(result.names):
        raise ValueError("truth and result list different markers")
    obs = result.markers.observations
    nv = obs.shape[0]
    if truth.markers_px.shape[0] != nv:
        raise ValueError(f"truth has {truth.markers_px.shape[0]} views, the result {nv}")
    true_px = np.stack([cam.project(truth.marker_positions) for cam in result.rig])
    r_true = expected_radius_px(result.rig, truth.marker_positions, 0.5 * float(np.mean(truth.marker_diameter)))

    def score(o):
        found = np.isfinite(o[..., 0])
        d = np.linalg.norm(o - true_px, axis=2)
        with np.errstate(invalid="ignore"):
            right = found & (d <= np.maximum(r_true, 2.0)) & (truth.coverage > 0)
        return found, right, found & ~right

    found, right, wrong = score(obs)
    raw = result.raw_observations
    r_found, r_right, r_wrong = (found, right, wrong) if raw is None else score(np.asarray(raw, float))
    seen2 = truth.visible.sum(axis=0) >= 2
    ok = result.markers.ok
    err = np.linalg.norm(result.markers.points - truth.marker_positions, axis=1)
    sk = result.pose.skeleton
    tpose = truth.pose(sk)
    tb = tpose.bone_vectors()
    fb, thb = result.pose.bone_vectors(), result.thesis_pose.bone_vectors()
    bone_groups, joint_groups = _groups(sk, result.markerset)
    measured_bones, measured_joints = _groups(sk, result.markerset, ok)
    names = [b for g in bone_groups.values() for b in g]
    fit_e = {b: _angle_deg(fb[sk.index(b)], tb[sk.index(b)]) for b in names}
    th_e = {b: _angle_deg(thb[sk.index(b)], tb[sk.index(b)]) for b in names}
    je = np.linalg.norm(result.pose.positions - tpose.positions, axis=1)
    tje = np.linalg.norm(result.thesis_pose.positions - tpose.positions, axis=1)
    return PuppetComparison(int(truth.visible.sum()), int(found.sum()), int(right.sum()),
                            int((right & truth.visible).sum()), int(wrong.sum()),
                            int((wrong & result.markers.used).sum()), int(seen2.sum()), int(ok.sum()),
                            int((ok & seen2).sum()), tuple(n for n, s, o in zip(result.names, seen2, ok) if s and not o),
                            np.where(ok, err, np.nan), fit_e, th_e, je, tje, bone_groups, joint_groups,
                            int(r_found.sum()), int((r_right & truth.visible).sum()), int(r_wrong.sum()),
                            measured_bones, measured_joints)


# --- the result -------------------------------------------------------------------------------
@dataclass(eq=False)
class PuppetResult:
    """Everything the puppet pipeline found (see :meth:`to_dict` for the JSON form).

    Attributes
    ----------
    rig : Rig
        The camera of every view, in view order.
    view_names : list of str
    angles_deg : list of float or None
        Turn angle of every view, degrees (None for rig views).
    markerset : MarkerSet
    markers : MarkerSolve
        2D observations, 3D markers, which views were used.
    fit : PoseFit
        Fitted and thesis poses.
    settings : PuppetSettings
    views : list of ViewResult or None
        Detection per view (None when the markers came from a project's stored detections).
    source : dict
        Where the photos came from (``{"type": "capture"|"project", "path": ...}``).
    timings_s : dict
        Seconds per stage.
    comparison : PuppetComparison or None
        Against the truth, for synthetic captures.
    files : list of str or None
        The photo of every view.
    raw_observations : ndarray, shape (n_views, n_markers, 2), or None
        The colour-only identification, before :func:`reidentify` named the candidates after
        the 3D markers (None when it did not run); ``markers.observations`` is the final one.
    """

    rig: Rig
    view_names: list
    angles_deg: list
    markerset: MarkerSet
    markers: MarkerSolve
    fit: PoseFit
    settings: PuppetSettings = DEFAULT
    views: list | None = None
    source: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    comparison: PuppetComparison | None = None
    files: list | None = None
    raw_observations: np.ndarray | None = None

    @property
    def names(self) -> tuple:
        return self.markers.names

    @property
    def pose(self) -> Pose:
        """The result's pose: the fitted one, or the thesis's with ``settings.pose="thesis"``."""
        return self.fit.pose if self.settings.pose == "fit" else self.fit.thesis_pose

    @property
    def thesis_pose(self) -> Pose:
        return self.fit.thesis_pose

    @property
    def trajectories(self) -> MarkerTrajectories:
        """The 3D markers as one frame of :class:`MarkerTrajectories` (for :func:`stillcap.io.export.export`)."""
        return MarkerTrajectories.single(self.names, self.markers.points)

    @property
    def missing(self) -> tuple:
        return self.markers.missing

    def to_dict(self) -> dict:
        """JSON-ready dict; keys shared with ``truth.json`` (``markers[].name/position``,
        ``joints[].name/position/local_rotation``, ``root2world``, ``cameras``, ``angles_deg``,
        ``markers_px``) mean the same, in the same units (metres, pixels). See ``docs/puppet.md``."""
        m, pose = self.markers, self.pose
        sk = pose.skeleton

        def pts(a):
            return [None if not np.all(np.isfinite(p)) else [float(v) for v in p] for p in a]

        def joints(p: Pose):
            return [{"name": n, "position": [float(v) for v in x], "local_rotation": R.tolist()}
                    for n, x, R in zip(sk.names, p.positions, p.local_rotations)]

        vecs = normalised(pose.bone_vectors())
        d = {
            "format": RESULT_FORMAT, "version": 1, "kind": "puppet", "frame": self.rig.world,
            "units": {"length": "m", "pixels": "px (x, y), origin top-left pixel centre", "angle": "deg"},
            "source": dict(self.source),
            "settings": self.settings.to_dict(),
            "markers": [{"name": n, "position": p, "n_views": int(k), "whole_views": int(wv),
                         "identified_views": int(iv), "reproj_error_px": _num(e), "missing": p is None,
                         "fit_residual_m": _num(r)}
                        for n, p, k, wv, iv, e, r in zip(m.names, pts(m.points), m.n_views, m.whole_views,
                                                         m.identified_views, m.reproj_error_px, self.fit.residuals_m)],
            "missing": list(m.missing),
            "joints": joints(pose),
            "root2world": pose.root2world.tolist(),
            "bone_directions": {n: pts(vecs[j:j + 1])[0] for j, n in enumerate(sk.names) if sk.parents[j] >= 0
                                and sk.bone_lengths[j] > 0},
            "cameras": list(self.view_names),
            "angles_deg": [None if a is None else float(a) for a in self.angles_deg],
            "markers_px": [[[_num(c) for c in p] for p in v] for v in m.observations],  # as truth.json: [null, null]
            "markers_px_colour": None if self.raw_observations is None else
            [[[_num(c) for c in p] for p in v] for v in self.raw_observations],
            "used": m.used.astype(bool).tolist(),
            "partial": m.partial.astype(bool).tolist(),
            "outlier": m.outlier.astype(bool).tolist(),
            "fill": [[_num(f) for f in row] for row in m.fill],
            "views": [{"name": n, "file": f, "angle_deg": None if a is None else float(a),
                       "identified": int(np.isfinite(m.observations[v, :, 0]).sum()), "used": int(m.used[v].sum()),
                       **({"candidates": len(self.views[v].circles)} if self.views else {})}
                      for v, (n, f, a) in enumerate(zip(self.view_names, self.files or [None] * len(self.view_names),
                                                        self.angles_deg))],
            "pose_fit": {"method": self.settings.pose, "success": self.fit.success, "n_markers": self.fit.n_markers,
                         "rms_m": _num(self.fit.rms_m),
                         "frames": frame_status(sk, self.markerset)},
            "thesis": {"bone_directions": {b: pts(np.asarray(v)[None])[0] for b, v in self.fit.directions.items()},
                       "joints": joints(self.thesis_pose)},
            "skeleton": sk.to_dict("m"),
            "markerset": self.markerset.name,
            "camera_rig": self.rig.to_dict(),
            "timings_s": {k: float(v) for k, v in self.timings_s.items()},
        }
        if self.comparison is not None:
            d["comparison"] = self.comparison.to_dict()
        return d


# --- wiring -------------------------------------------------------------------------------------
@one_blas_thread
def reconstruct_puppet(rig: Rig, images=None, *, markerset: MarkerSet | None = None, palette: Palette | None = None,
                       observations=None, settings: PuppetSettings = DEFAULT, view_names=None, angles_deg=None,
                       root2world=None, progress: Callable[[int, int], None] | None = None, truth=None,
                       source: dict | None = None, files=None, skeleton: Skeleton | None = None,
                       detections: Sequence[ViewResult] | None = None) -> PuppetResult:
    """The whole pipeline on photos (or on already identified 2D markers).

    BLAS (NumPy's and SciPy's) runs on one thread during the call (``threadpoolctl``; the
    caller's setting is restored afterwards): the pipeline's matrices are small, and on a busy
    machine OpenBLAS's threads made the pose fit 15x slower.

    Parameters
    ----------
    rig : Rig, n_views cameras
        The camera of every view (puppet frame).
    images : sequence of n_views BGR images, optional
        The photos. Without ``observations`` they are detected and identified; with them only
        the fill test reads them.
    markerset : MarkerSet, optional
        Default :meth:`MarkerSet.puppet`.
    palette : Palette, optional
        Reference colours in marker-set order; default the marker set's colours.
    observations : array_like, shape (n_views, n_markers, 2), optional
        Identified pixels (e.g. a project's markers with the user's edits); skips detection.
    settings : PuppetSettings
    view_names, angles_deg : sequences, optional
        Per view; default the camera names and None.
    root2world : array_like, shape (4, 4), optional
        Pelvis frame; default the skeleton's rest frame (the puppet on the turntable axis).
    progress : callable(done, total), optional
        Called after each detected view.
    truth : PuppetTruth, optional
        Compare with it (:func:`compare_with_truth`).
    source : dict, optional
        Where the photos came from (kept in the result).
    files : sequence of str, optional
        The photo of every view (kept in the result).
    skeleton : Skeleton, optional
        Default :meth:`Skeleton.puppet`; the marker set's bones must be in it.
    detections : sequence of n_views ViewResult, optional
        The views already detected in ``images`` with this palette and ``settings``
        (:func:`detect_view`; :func:`run_capture` detects while it decodes); skips detection.
    """
    markerset = markerset or MarkerSet.puppet()
    settings = _settings_for(settings, markerset)
    skeleton = skeleton or _puppet_skeleton()
    markerset.check_skeleton(skeleton)
    if palette is None:
        palette = Palette.from_markerset(markerset)
    elif tuple(palette.names) != tuple(markerset.names):
        raise ValueError(f"palette names {list(palette.names)} differ from the marker set's {list(markerset.names)}")
    n = len(rig)
    if images is not None:
        images = list(images)
        if len(images) != n:
            raise ValueError(f"need one image per view ({n}), got {len(images)}")
        for cam, img in zip(rig, images):
            h, w = np.asarray(img).shape[:2]
            if (w, h) != tuple(cam.image_size):
                raise ValueError(f"view {cam.name!r}: image is {w}x{h} px, its camera is "
                                 f"{cam.image_size[0]}x{cam.image_size[1]} px")
    timings = {}
    views = None
    radii = None
    if observations is None:
        if images is None:
            raise ValueError("give images (to detect markers in) or observations")
        t0 = time.perf_counter()
        if detections is not None:
            views = list(detections)
            if len(views) != n:
                raise ValueError(f"need one detection per view ({n}), got {len(views)}")
        else:
            # candidates photo by photo, then all photos named by colour together (identify_views:
            # detect_view's identification, its small matrices computed for all photos at once)
            cands, t_det = [], []
            for k, img in enumerate(images):
                t1 = time.perf_counter()
                cands.append(find_bead_candidates(img, settings.detector, settings.radius_range, settings.n_circles,
                                                  settings.roi, settings.coarse))
                t_det.append(time.perf_counter() - t1)
                if progress is not None:
                    progress(k + 1, n)
            t1 = time.perf_counter()
            idents = identify_views(images, cands, palette, settings.identify)
            share = (time.perf_counter() - t1) / max(n, 1)
            views = [ViewResult(c, i, t + share) for c, i, t in zip(cands, idents, t_det)]
        obs = np.stack([v.identification.points for v in views]) if views else np.zeros((0, len(markerset), 2))
        radii = np.stack([v.identification.radii for v in views]) if views else None
        timings["detect_identify"] = (time.perf_counter() - t0 if detections is None
                                      else float(sum(v.time_s for v in views)))
    else:
        obs = np.asarray(observations, float)
    t0 = time.perf_counter()
    bead_r = 0.5 * float(np.mean([m.diameter for m in markerset.markers]))
    solve = solve_markers(rig, obs, markerset.names, images, settings, bead_radius_m=bead_r, radii_px=radii)
    raw_obs = None
    if views is not None and settings.reidentify:
        raw_obs = obs
        final = reidentify(rig, solve.points, views, bead_r, settings.reid_gate, settings.reid_colour)
        same = np.all((np.isnan(final) & np.isnan(obs)) | (final == obs), axis=(0, 2))
        if not same.all():
            # solve_markers treats every marker on its own (its views' consensus, fill test and
            # fallback look at that marker only), so only the re-identified markers are solved
            # again (with no detected radii, as a full second solve would use)
            cols = np.flatnonzero(~same)
            sub = solve_markers(rig, final[:, cols], [markerset.names[c] for c in cols], images, settings,
                                bead_radius_m=bead_r, radii_px=None)
            solve = _replace_markers(solve, cols, sub, final)
    timings["triangulate"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # markers without a 3D point (seen in one view, or their views disagree) still constrain the
    # pose: their final identification's rays, less sure the less of the bead shows (fill);
    # fit_pose rejects those its fit leaves > 5 sigma off
    from stillcap.body.puppet_pose import MarkerRays

    rays = MarkerRays.from_views(rig, solve.observations, ~solve.ok, fill=solve.fill)
    fit = fit_pose(skeleton, markerset, solve.points, root2world, marker_sigma_m=settings.marker_sigma_m,
                   rays=rays if len(rays) else None)
    timings["pose"] = time.perf_counter() - t0
    result = PuppetResult(rig, list(view_names) if view_names is not None else list(rig.names),
                          list(angles_deg) if angles_deg is not None else [None] * n, markerset, solve, fit,
                          settings, views, dict(source or {}), timings, None, list(files) if files else None, raw_obs)
    if truth is not None:
        result.comparison = compare_with_truth(result, truth)
    return result


def capture_markerset(folder, cap=None) -> MarkerSet:
    """The marker set a puppet capture shows: its ``markerset`` entry (the whole marker set, as
    ``stillcap studio puppet`` writes it, or a built-in name); captures without one show the
    thesis's 16 beads. ``cap``: the capture already loaded from ``folder``."""
    if cap is None:
        from stillcap.io.capture import Capture

        cap = Capture.load(folder)
    entry = (cap.meta or {}).get("markerset", "puppet-16")
    if not isinstance(entry, (str, dict)):
        raise ValueError(f"capture {folder}: 'markerset' must be a built-in name or a marker set, got {entry!r}")
    try:
        markerset = MarkerSet.resolve(entry) if isinstance(entry, dict) or entry in BUILTIN_MARKERSETS else None
    except ValueError as e:
        raise ValueError(f"capture {folder}: {e}") from None
    if markerset is None:
        raise ValueError(f"capture {folder}: unknown marker set {entry!r} (built-in: {', '.join(BUILTIN_MARKERSETS)})")
    return markerset


def _settings_for(settings: PuppetSettings, markerset: MarkerSet) -> PuppetSettings:
    """``settings`` with at least one candidate circle per bead of ``markerset``: the thesis's
    "N best circles" has N = its 16 beads, and puppet-20 with 16 candidates lost its four dimmest
    beads in 10-20 % of the photos."""
    if settings.n_circles < len(markerset):
        return replace(settings, n_circles=len(markerset))
    return settings


def _capture_inputs(folder: Path):
    """A puppet capture's pieces: ``(capture, rig, view names, angles, files, truth, markerset)``
    (the marker set: :func:`capture_markerset`)."""
    from stillcap.io.capture import Capture
    from stillcap.studio.puppet import PuppetTruth

    cap = Capture.load(folder)
    if cap.kind != "puppet":
        raise ValueError(f"capture {folder} is of kind {cap.kind!r}, not 'puppet' (make one with stillcap studio puppet)")
    if not cap.images:
        raise ValueError(f"capture {folder} has no images")
    cams, names, angles, files = [], [], [], []
    for im in cap.images:
        c = cap.rig[im.camera]
        cams.append(c)
        names.append(c.name)
        a = (im.meta or {}).get("angle_deg")
        angles.append(None if a is None else float(a))
        files.append(im.file)
    rig = Rig(cams, cap.rig.world)
    markerset = capture_markerset(folder, cap)
    truth = None
    if cap.truth and cap.truth.get("kind") == "puppet":
        truth = PuppetTruth.from_dict(cap.truth)
        if list(truth.cameras) != names or list(truth.marker_names) != list(markerset.names):
            truth = None  # views or markers differ from the truth's: no comparison
    return cap, rig, names, angles, files, truth, markerset


@one_blas_thread
def run_capture(folder, settings: PuppetSettings = DEFAULT, palette: Palette | None = None,
                progress: Callable[[int, int], None] | None = None, compare: bool = True,
                workers: int = 2) -> tuple[PuppetResult, list]:
    """Run the pipeline on a capture folder of kind ``puppet`` (``stillcap studio puppet``).

    With ``workers`` >= 2 a second thread decodes the photos and makes each one's photo-wide
    detection inputs (:func:`~stillcap.detect.beads.prepare_view`: bright region, grey image,
    half-resolution contrast map; OpenCV calls and large NumPy operations, which release the
    GIL) while this one finds the candidates of each photo as soon as it is ready, so that work
    hides behind the detection when a second core is free; then every photo's candidates are
    named by colour together (:func:`~stillcap.detect.beads.identify_views`). The result is the
    same as with ``workers=1`` (decode all, then :func:`detect_view` each). Detecting whole photos
    on two threads was measured slower on the benchmark's two shared cores (the candidate
    search is mostly small NumPy calls that hold the GIL).
    Timings: ``read`` is the capture's loading plus the time spent waiting for decoded photos.
    BLAS runs on one thread during the call (see :func:`reconstruct_puppet`).

    Returns
    -------
    result : PuppetResult
        Compared with ``truth.json`` when the folder has one (and ``compare``).
    images : list of ndarray
        The decoded photos (for overlays).
    """
    folder = Path(folder)
    t0 = time.perf_counter()
    cap, rig, names, angles, files, truth, markerset = _capture_inputs(folder)
    settings = _settings_for(settings, markerset)
    detections = None
    if workers <= 1 or len(cap.images) <= 1:
        images = [cap.read_image(im) for im in cap.images]
        t_read = time.perf_counter() - t0
    else:
        t_read = time.perf_counter() - t0
        if palette is None:  # reconstruct_puppet's default: the marker set's reference colours
            palette = Palette.from_markerset(markerset)
        images, detections = [], []

        def read(entry):  # the second thread: decode, and the photo-wide part of the detection
            img = cap.read_image(entry)
            return img, _prepare(img, settings)

        candidates, t_det, idents = [], [], []

        def name(upto):  # the photos found so far but not yet named, named by colour together
            if upto > len(idents):
                t = time.perf_counter()
                new = identify_views(images[len(idents):upto], candidates[len(idents):upto], palette,
                                     settings.identify)
                share = (time.perf_counter() - t) / len(new)
                for j in range(len(idents), upto):
                    t_det[j] += share
                idents.extend(new)

        with ThreadPoolExecutor(max_workers=1) as pool:
            pending = [pool.submit(read, im) for im in cap.images]
            stolen = {}
            try:
                for k, fut in enumerate(pending):
                    if not fut.done():
                        name(k)  # while the other thread still decodes: name what was found
                    t1 = time.perf_counter()
                    # still waiting: decode a photo the other thread has not started (the last
                    # one), here, so that both threads decode while this one has nothing to detect
                    while k not in stolen and not fut.done():
                        j = next((j for j in range(len(pending) - 1, k, -1)
                                  if j not in stolen and pending[j].cancel()), None)
                        if j is None:
                            break
                        stolen[j] = read(cap.images[j])
                    img, prepared = stolen.pop(k) if k in stolen else fut.result()
                    t2 = time.perf_counter()
                    t_read += t2 - t1
                    images.append(img)
                    candidates.append(find_bead_candidates(img, settings.detector, settings.radius_range,
                                                           settings.n_circles, settings.roi, settings.coarse,
                                                           prepared=prepared))
                    t_det.append(time.perf_counter() - t2)
                    if progress is not None:
                        progress(k + 1, len(pending))
            finally:
                for fut in pending:
                    fut.cancel()
        # every photo's candidates named by colour (identify_views: the same identification as
        # detect_view's per photo; the photos named together share its small-matrix calls)
        name(len(images))
        detections = [ViewResult(c, i, t) for c, i, t in zip(candidates, idents, t_det)]
    res = reconstruct_puppet(rig, images, markerset=markerset, palette=palette, settings=settings, view_names=names, angles_deg=angles,
                             progress=None if detections is not None else progress,
                             truth=truth if compare else None, source={"type": "capture", "path": str(folder)},
                             files=files, detections=detections)
    res.timings_s = {"read": t_read, **res.timings_s}
    return res, images


def run_project(project, settings: PuppetSettings = DEFAULT, palette: Palette | None = None, redetect: bool = False,
                progress: Callable[[int, int], None] | None = None, save: bool = True) -> tuple[PuppetResult, list]:
    """Detect markers in a project's photos, store them, and reconstruct.

    Views without detections (all views with ``redetect``) are detected and identified; their
    detections replace the stored ones (the user's edits stay and still apply) and the project
    is saved (``save``). The 3D markers come from every view's effective markers (detections
    with edits), as :meth:`Project.reconstruct` would, plus the fill test.

    Parameters
    ----------
    project : Project or path
    """
    from stillcap.io.project import Project

    if not isinstance(project, Project):
        project = Project.load(project)
    if not project.views:
        raise ValueError(f"project {project.root} has no views yet (add photos with stillcap puppet add)")
    pal = palette or Palette.from_markerset(project.markerset)
    settings = _settings_for(settings, project.markerset)
    t0 = time.perf_counter()
    images = [project.read_image(v) for v in project.views]
    t_read = time.perf_counter() - t0
    todo = [k for k, v in enumerate(project.views) if redetect or not v.detected]
    t0 = time.perf_counter()
    views: list = [None] * len(images)
    for i, k in enumerate(todo):
        vr = detect_view(images[k], pal, settings)
        views[k] = vr
        project.set_detections(k, vr.identification.as_dict())
        if progress is not None:
            progress(i + 1, len(todo))
    t_det = time.perf_counter() - t0
    if todo and save:
        project.save()
    res = reconstruct_project(project, settings, images=images)
    res.views = views if all(v is not None for v in views) else None
    res.timings_s = {"read": t_read, "detect_identify": t_det, **{k: v for k, v in res.timings_s.items()}}
    return res, images


def reconstruct_project(project, settings: PuppetSettings = DEFAULT, images=None) -> PuppetResult:
    """3D markers and pose from a project's stored markers (detections with the user's edits).

    ``images`` (the decoded photos, view order) enable the fill test; default: read them.
    """
    from stillcap.io.project import Project

    if not isinstance(project, Project):
        project = Project.load(project)
    names, pts, rig = project.observations()
    if images is None:
        images = [project.read_image(v) for v in project.views]
    return reconstruct_puppet(rig, images, markerset=project.markerset, observations=pts, settings=settings,
                              view_names=[v.name for v in project.views],
                              angles_deg=[v.angle_deg for v in project.views],
                              source={"type": "project", "path": str(project.root)},
                              files=[v.image for v in project.views])


def run_folder(folder, settings: PuppetSettings = DEFAULT, palette: Palette | None = None, redetect: bool = False,
               progress: Callable[[int, int], None] | None = None) -> tuple[PuppetResult, list]:
    """:func:`run_capture` or :func:`run_project`, whichever ``folder`` is."""
    folder = Path(folder)
    if not folder.exists():
        raise ValueError(f"folder {folder} does not exist")
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder (give a capture folder or a stillcap project)")
    if (folder / "project.json").is_file():
        return run_project(folder, settings, palette, redetect, progress)
    if (folder / "capture.json").is_file():
        return run_capture(folder, settings, palette, progress)
    raise ValueError(f"{folder} is neither a capture folder (capture.json) nor a stillcap project (project.json)")


# --- reading a result back ---------------------------------------------------------------------
@dataclass(eq=False)
class LoadedResult:
    """A pipeline result read back from its JSON (:func:`load_result`): what exports need.

    Attributes
    ----------
    pose : Pose
    markers : MarkerTrajectories
        One frame of 3D markers (NaN = missing).
    data : dict
        The whole JSON.
    """

    pose: Pose
    markers: MarkerTrajectories
    data: dict


def load_result(path_or_dict) -> LoadedResult:
    """Read a result written by ``stillcap puppet run --out`` (``result.json``) or ``--json``.

    Raises
    ------
    ValueError
        Naming the file when it is not a puppet result or lacks the skeleton or pose.
    """
    from stillcap.files.jsonable import from_jsonable

    if isinstance(path_or_dict, dict):
        d, where = path_or_dict, "<result>"
    else:
        p = Path(path_or_dict)
        if not p.is_file():
            raise ValueError(f"result file {p} does not exist")
        d = read_json(p)
        where = str(p)
    if not isinstance(d, dict) or d.get("format") != RESULT_FORMAT:
        raise ValueError(f"{where} is not a stillcap puppet result (expected \"format\": \"{RESULT_FORMAT}\")")
    if d.get("version", 0) > 1:
        raise ValueError(f"{where}: result version {d.get('version')} is newer than this stillcap reads (1)")
    try:
        sk = Skeleton.from_dict(d["skeleton"], source=where)
        by = {j["name"]: np.asarray(j["local_rotation"], float) for j in d["joints"]}
        local = np.stack([by[n] for n in sk.names])
        pose = Pose(sk, np.asarray(d["root2world"], float), local)
        names = [m["name"] for m in d["markers"]]
        pts = from_jsonable([m["position"] if m["position"] is not None else [None] * 3 for m in d["markers"]])
        markers = MarkerTrajectories.single(names, np.asarray(pts, float).reshape(len(names), 3))
    except (KeyError, TypeError) as e:
        raise ValueError(f"{where}: incomplete puppet result (missing {e})") from None
    return LoadedResult(pose, markers, d)


def with_settings(settings: PuppetSettings = DEFAULT, **changes) -> PuppetSettings:
    """A copy of ``settings`` with some fields changed (validated)."""
    return replace(settings, **changes)
