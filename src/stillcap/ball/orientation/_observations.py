"""Marker observations of one ball over several flashes: directions from the ball centre with
their types (:class:`MarkerObservations`), pixel rays turned into directions
(:func:`rays_to_directions`), the fits' input checks and the strobe period."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout


def _default_layout(layout):
    return BallLayout.seed() if layout is None else layout


def _unit_rows(a, name):
    n = np.linalg.norm(a, axis=1)
    if np.any(~(n > 0)):
        bad = np.flatnonzero(~(n > 0))
        raise ValueError(f"{name} must be non-zero and finite, rows {bad.tolist()} are not")
    return a / n[:, None]


def direction_information(directions, view_directions, radius_px, min_cos: float = 0.1, radial=None):
    """How precisely a marker centroid seen in one photo fixes its direction from the ball centre.

    A centroid moved by ``e`` pixels moves the direction by ``e / r_px`` rad across the line of
    sight (around it) and by ``e / (r_px cos theta)`` rad toward or away from it (``theta`` the
    angle between the marker and the line of sight, ``r_px`` the ball's image radius): the sphere
    is foreshortened there. With isotropic centroid noise ``s`` (pixels) the direction's
    covariance is ``s^2`` times the inverse of ``r_px^2 (P_around + cos^2 theta P_toward)``,
    which is returned (``P`` the projectors on those two tangent directions). ``cos theta`` is
    kept above ``min_cos`` (a ray grazing the limb meets the sphere at its closest approach).

    Parameters
    ----------
    directions : array_like, shape (M, 3)
        Unit marker directions from the ball centre.
    view_directions : array_like, shape (M, 3)
        Unit vectors from the ball centre to the camera.
    radius_px : array_like, shape (M,) or scalar
        The ball's image radius in that camera, px.
    radial : array_like of bool, shape (M,), optional
        False where the centroid's position toward the ball's image centre is not measured (a
        marker cut by the limb): only the direction around the line of sight is informed.

    Returns
    -------
    ndarray, shape (M, 3, 3)
        Information in each direction's tangent plane, px^2 per rad^2 (``cov = s^2 pinv(I)``
        with ``s`` in pixels).
    """
    u = as_array(directions, (None, 3), "directions")
    v = as_array(view_directions, (len(u), 3), "view_directions")
    r = np.broadcast_to(np.asarray(radius_px, float), (len(u),))
    c = np.einsum("ma,ma->m", u, v)
    toward = v - c[:, None] * u  # the line of sight's direction in the tangent plane
    n = np.linalg.norm(toward, axis=1)
    face_on = n < 1e-9
    toward = np.where(face_on[:, None], 0.0, toward / np.where(face_on, 1.0, n)[:, None])
    tangent = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    P_toward = toward[:, :, None] * toward[:, None, :]
    cos2 = np.clip(c, min_cos, 1.0) ** 2
    if radial is not None:
        cos2 = np.where(np.broadcast_to(np.asarray(radial, bool), (len(u),)), cos2, 0.0)
    return (r * r)[:, None, None] * (tangent - (1.0 - cos2)[:, None, None] * P_toward)


def rays_to_directions(ray_origins, ray_directions, ball_centers, radius: float = BASEBALL_RADIUS):
    """Where pixel rays meet the ball sphere, as directions from the ball centre.

    Each ray ``o + s d`` (``s > 0``) is intersected with the sphere ``|X - c| = radius``; the
    nearer intersection is the marker on the visible hemisphere. A ray that misses the sphere
    (noise near the silhouette) gives the direction of its closest approach (a point on the
    limb).

    Parameters
    ----------
    ray_origins : array_like, shape (M, 3)
        Camera centres, world frame, m.
    ray_directions : array_like, shape (M, 3)
        Ray directions through the marker pixels (any length), world frame.
    ball_centers : array_like, shape (M, 3)
        Ball centre at each observation's flash, m.
    radius : float or array_like, shape (M,)
        Sphere radius, m (per ray: e.g. the depth of each marker's image centroid,
        :attr:`stillcap.ball.layout.BallLayout.centroid_depth`).

    Returns
    -------
    directions : ndarray, shape (M, 3)
        Unit vectors from the ball centre to the marker, world frame.
    hit : ndarray of bool, shape (M,)
        False where the ray missed the sphere (direction on the limb).
    """
    o = as_array(ray_origins, (None, 3), "ray_origins")
    d = _unit_rows(as_array(ray_directions, (len(o), 3), "ray_directions"), "ray_directions")
    c = as_array(ball_centers, (len(o), 3), "ball_centers")
    radius = np.asarray(radius, float)
    if radius.shape not in ((), (len(o),)) or not np.all(radius > 0):
        raise ValueError(f"radius must be positive, one value or one per ray, got {radius}")
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    disc = b * b - (np.einsum("ij,ij->i", oc, oc) - radius * radius)
    hit = disc >= 0
    s = np.where(hit, -b - np.sqrt(np.where(hit, disc, 0.0)), -b)
    p = oc + s[:, None] * d
    return _unit_rows(p, "ray-sphere points (ray through the ball centre?)"), hit


@dataclass
class MarkerObservations:
    """Marker observations of one ball over several flashes (flat arrays).

    Attributes
    ----------
    flash : ndarray of int, shape (M,)
        Flash index of each observation (into the ``times`` given to the fits).
    types : ndarray of int, shape (M,)
        Marker type index (into ``BallLayout.type_names``).
    directions : ndarray, shape (M, 3)
        Unit vectors from the ball centre to the marker, world frame.
    from_ray : ndarray of bool, shape (M,)
        True for observations converted from a single camera's pixel ray.
    information : ndarray, shape (M, 3, 3), optional
        How precisely each direction is known, relative to the others: the inverse of its
        covariance in its tangent plane up to one common factor, ``cov_m = s^2 pinv(I_m)``, with
        ``s`` the marker-centroid noise in pixels that the spin fit estimates from its residuals
        (:func:`direction_information`: a marker seen face-on in a large ball image is known
        better than one near the limb of a small one). None: every direction equally well, in
        every direction (the fits then weigh all residuals alike).
    noise_class : ndarray of int, shape (M,), optional
        Observations of one class share a centroid noise, which the global fit estimates per
        class from its residuals (with ``information``): e.g. 0 for markers seen whole, 1 for
        markers cut by the limb. Default all 0.
    views : ndarray, shape (M, 3), optional
        Unit vector from the ball centre to the camera(s) whose pixel rays gave each direction
        (the mean of the two for a pair's combined direction): a ball-centre error along it does
        not move such a direction (the ray meets the moved sphere at the moved point). None: the
        directions are taken as marker points seen in 3D (a centre error moves them all).
    blur_mode : ndarray, shape (M, 3), optional
        How far each direction moves (radians, tangent, world frame) with its centroid's blur
        correction error (:func:`stillcap.detect._blur_shift.shading_blur_correction`): one error
        mode shared by all observations, which the spin's covariance takes with variance 1.
        None: no such error.
    centroid_sigma_px : ndarray, shape (M,), optional
        Each observation's centroid standard error read from its own photo's noise, px
        (:attr:`BallMarkers.centroid_sigma_px <stillcap.detect.ball_markers.BallMarkers>`; for a
        marker seen by both cameras the combination of the two, ``1 / sqrt(mean(1 / s^2))``); NaN
        where unknown. The global fit weighs the observations by it as far as its residuals show
        (:func:`~stillcap.ball.orientation._photo_noise.photo_noise_factors`). None: all unknown.
    """

    flash: np.ndarray
    types: np.ndarray
    directions: np.ndarray
    from_ray: np.ndarray = None
    information: np.ndarray = None
    noise_class: np.ndarray = None
    views: np.ndarray = None
    blur_mode: np.ndarray = None
    centroid_sigma_px: np.ndarray = None

    def __post_init__(self):
        self.flash = np.asarray(self.flash)
        if self.flash.ndim != 1:
            raise ValueError(f"flash must have shape (M,), got {self.flash.shape}")
        m = len(self.flash)
        if m and not np.all(np.equal(np.mod(self.flash, 1), 0)):
            raise ValueError("flash indices must be integers")
        self.flash = self.flash.astype(int)
        if m and self.flash.min() < 0:
            raise ValueError(f"flash indices must be >= 0, got {self.flash.min()}")
        self.types = np.asarray(self.types)
        if self.types.shape != (m,):
            raise ValueError(f"types must have shape ({m},), got {self.types.shape}")
        self.types = self.types.astype(int)
        d = as_array(self.directions, (m, 3), "directions")
        self.directions = _unit_rows(d, "directions") if m else d.reshape(0, 3)
        self.from_ray = (np.zeros(m, bool) if self.from_ray is None
                         else as_array(self.from_ray, (m,), "from_ray", dtype=bool))
        if self.information is not None:
            info = as_array(self.information, (m, 3, 3), "information")
            if not np.all(np.isfinite(info)):
                raise ValueError("information must be finite")
            self.information = info
        self.noise_class = (np.zeros(m, int) if self.noise_class is None
                            else as_array(self.noise_class, (m,), "noise_class").astype(int))
        if self.views is not None:
            v = as_array(self.views, (m, 3), "views")
            self.views = _unit_rows(v, "views") if m else v.reshape(0, 3)
        if self.blur_mode is not None:
            self.blur_mode = as_array(self.blur_mode, (m, 3), "blur_mode")
        if self.centroid_sigma_px is not None:
            s = np.asarray(self.centroid_sigma_px, float)
            if s.shape != (m,):
                raise ValueError(f"centroid_sigma_px must have shape ({m},), got {s.shape}")
            self.centroid_sigma_px = np.where(s > 0, s, np.nan)  # (not positive: unknown)

    def __len__(self) -> int:
        return len(self.flash)

    @classmethod
    def from_directions(cls, flash, types, directions, layout: BallLayout | None = None):
        """From directions (stereo-triangulated markers minus the ball centre).

        Parameters
        ----------
        flash : array_like of int, shape (M,)
        types : array_like, shape (M,)
            Type names (``"red"``) or indices.
        directions : array_like, shape (M, 3)
            From the ball centre to the marker, world frame (normalised here).
        layout : BallLayout, optional
            To translate type names (default the seed layout).
        """
        layout = _default_layout(layout)
        flash = np.asarray(flash)
        return cls(flash, layout.type_index(types).reshape(flash.shape), directions)

    @classmethod
    def from_rays(cls, flash, types, ray_origins, ray_directions, ball_centers,
                  radius: float | None = None, layout: BallLayout | None = None):
        """From single-camera pixel rays (see :func:`rays_to_directions`).

        Parameters
        ----------
        flash : array_like of int, shape (M,)
        types : array_like, shape (M,)
        ray_origins, ray_directions : array_like, shape (M, 3)
            Camera centre and ray direction through the marker pixel, world frame.
        ball_centers : array_like, shape (M, 3) or (K, 3)
            Ball centre per observation, or per flash (indexed by ``flash``), m; with as many
            rows as observations it is taken per observation.
        radius : float, optional
            Ball radius (default ``layout.radius``).
        """
        layout = _default_layout(layout)
        flash = np.asarray(flash)
        m = len(flash)
        c = np.asarray(ball_centers, float)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"ball_centers must have shape (M, 3) or (K, 3), got {c.shape}")
        if c.shape[0] != m:
            if m and flash.max() >= len(c):
                raise ValueError(f"ball_centers has {len(c)} rows but flash indices reach {flash.max()}")
            c = c[flash.astype(int)]
        d, _ = rays_to_directions(ray_origins, ray_directions, c, layout.radius if radius is None else radius)
        return cls(flash, layout.type_index(types).reshape(flash.shape), d, np.ones(m, bool))

    @classmethod
    def from_per_flash(cls, per_flash, layout: BallLayout | None = None):
        """From a list with one ``(directions (n_k, 3), types (n_k,))`` pair per flash."""
        layout = _default_layout(layout)
        fl, ty, di = [], [], []
        for k, item in enumerate(per_flash):
            if len(item) != 2:
                raise ValueError(f"per_flash[{k}] must be a (directions, types) pair")
            d = np.asarray(item[0], float).reshape(-1, 3) if np.size(item[0]) else np.zeros((0, 3))
            t = layout.type_index(np.asarray(item[1], dtype=object).reshape(-1))
            if len(t) != len(d):
                raise ValueError(f"per_flash[{k}]: {len(d)} directions but {len(t)} types")
            fl.append(np.full(len(d), k))
            ty.append(t)
            di.append(d)
        if not fl:
            return cls(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        return cls(np.concatenate(fl), np.concatenate(ty), np.concatenate(di))

    @classmethod
    def concatenate(cls, parts):
        """Join several observation sets (e.g. stereo directions and single-camera rays). The
        result has ``information`` only when every part has it (the parts' weights are on one
        scale only then)."""
        parts = list(parts)
        if not parts:
            return cls(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)))
        info = views = blur = sig = None
        if any(p.centroid_sigma_px is not None for p in parts):  # a part without it: unknown there
            sig = np.concatenate([np.full(len(p), np.nan) if p.centroid_sigma_px is None else p.centroid_sigma_px
                                  for p in parts])
        if any(p.blur_mode is not None for p in parts):  # a part without it: no error there
            blur = np.concatenate([np.zeros((len(p), 3)) if p.blur_mode is None else p.blur_mode
                                   for p in parts]).reshape(-1, 3)
        if all(p.information is not None for p in parts):
            info = np.concatenate([p.information for p in parts]).reshape(-1, 3, 3)
        if all(p.views is not None for p in parts):
            views = np.concatenate([p.views for p in parts]).reshape(-1, 3)
        return cls(np.concatenate([p.flash for p in parts]), np.concatenate([p.types for p in parts]),
                   np.concatenate([p.directions for p in parts]),
                   np.concatenate([p.from_ray for p in parts]), info,
                   np.concatenate([p.noise_class for p in parts]), views, blur, sig)

    def with_flash(self, flash):
        """The same observations with other flash indices (e.g. on a joint clock)."""
        return MarkerObservations(np.asarray(flash), self.types, self.directions, self.from_ray, self.information,
                                  self.noise_class, self.views, self.blur_mode, self.centroid_sigma_px)

    def of_flash(self, k: int):
        """``(directions (n, 3), types (n,))`` of flash ``k``."""
        sel = self.flash == k
        return self.directions[sel], self.types[sel]

    def counts(self, n_flashes: int) -> np.ndarray:
        """Observations per flash, shape (n_flashes,)."""
        return np.bincount(self.flash, minlength=n_flashes)[:n_flashes]


def _check_inputs(times, observations, layout):
    times = as_array(times, (None,), "times")
    if len(times) < 2:
        raise ValueError(f"need at least 2 flash times, got {len(times)}")
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError("times must be finite and strictly increasing")
    if not isinstance(observations, MarkerObservations):
        observations = MarkerObservations.from_per_flash(observations, layout)
    if len(observations) and observations.flash.max() >= len(times):
        raise ValueError(f"observations refer to flash {observations.flash.max()} but times has "
                         f"shape {times.shape}")
    if len(observations) and observations.types.max() >= layout.n_types:
        raise ValueError(f"observation types must be < {layout.n_types}, got {observations.types.max()}")
    return times, observations


def strobe_period(times) -> float:
    """The flash interval: the smallest time step (a missed flash leaves a 2x step), s."""
    times = as_array(times, (None,), "times")
    if len(times) < 2:
        raise ValueError(f"need at least 2 times, got shape {times.shape}")
    return float(np.min(np.diff(times)))
