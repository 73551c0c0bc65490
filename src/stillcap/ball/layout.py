"""The painted 12-marker ball (SPEC J1 "Ball markers", seed section 4.1): single source of truth.

Geometry (ball frame, z = the pole of the equator, azimuth from x towards y):

- 8 markers on the equator in pairs 30 deg apart, the pairs 60 deg apart: azimuths 0, 30, 90,
  120, 180, 210, 270, 300 deg;
- 4 markers on the orthogonal great circle through azimuths 60 and 240 deg (the middle of two
  opposite gaps between pairs), 30 deg from each pole on both sides: (azimuth, polar angle) =
  (60, 30), (60, 150), (240, 30), (240, 150) deg.

Four marker types told apart by colour and shape, three markers each:

=====  ========  =========  ================================================
type   colour    shape      markers (azimuth / polar angle, deg)
=====  ========  =========  ================================================
0      red       square     eq 120, eq 270, (240, 30)
1      blue      ring       eq 90, (60, 30), (60, 150)
2      green     triangle   eq 30, eq 210, eq 300
3      black     disc       eq 0, eq 180, (240, 150)
=====  ========  =========  ================================================

How the assignment was chosen (all 15400 ways to split the 12 positions into 4 groups of 3 were
scored, see ``docs/spin.md``): a view direction sees the markers within ``90 deg - margin`` of
it. Required: (1) at least 3 types on every open hemisphere (the seed's claim; margin 0);
(2) the frame is determinable from every view, i.e. no rotation other than the identity maps
the visible markers onto markers of the same types (:func:`check_layout`), for margins up to
15 deg. Among those, this assignment has the largest *separation*, the smallest angle by which
the best wrong rotation misses a visible marker: 14.9 deg for every view at 10 and 15 deg
margins (the studio's earlier draft, same positions, was ambiguous from 1.6 % of the views at
a 10 deg margin and 7 % at 20 deg), and then the most views showing 3 or more types within
80 deg (96.6 %), 4 types on the open hemisphere (78.8 %) and the best robustness to one missed
marker. At a 20 deg margin one sampled view in 6000 is ambiguous.

A margin costs types: looking along a pole only the two markers 30 deg from it are inside the
limb (the equator lies on it), so no assignment shows 3 types there; with a 10 deg margin 3.4 %
of the views (around the poles, and a band slightly above the equator near azimuth 270 deg
that sees the red and green markers only) show 2 types, and the frame is still determined by
them.

The studio renders these markers (:mod:`stillcap.studio.markers` should build its
``SphereMarker`` list from :func:`seed_layout`), the orientation fit
(:mod:`stillcap.ball.orientation`) matches observations to them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache

import numpy as np

from stillcap._checks import as_array

BASEBALL_RADIUS = 0.0737 / 2  #: m (diameter 73.7 mm, :class:`stillcap.ball.physics.BallProperties`)

#: Type names, in type-index order.
TYPE_NAMES = ("red", "blue", "green", "black")
#: Shape of each type (names understood by :class:`stillcap.studio.scene.SphereMarker`).
TYPE_SHAPES = ("square", "ring", "triangle", "disc")
#: Default linear-RGB albedo of each type (configurable: the seed found more luminous colours
#: much easier to detect).
DEFAULT_PALETTE = {
    "red": (0.80, 0.04, 0.03),
    "blue": (0.03, 0.10, 0.80),
    "green": (0.05, 0.60, 0.06),
    "black": (0.02, 0.02, 0.02),
}
#: Angular size of a marker, rad (disc radius, square half-side, ...): 12 mm on a baseball.
DEFAULT_MARKER_SIZE = 0.16
#: Inner radius of a ring marker as a fraction of its outer radius (also the default of the
#: studio's :class:`~stillcap.studio.scene.SphereMarker`).
RING_INNER = 0.55
#: Mean squared angular distance of a marker's painted area from its centre, in units of
#: ``marker_size ** 2``, per shape (azimuthal-equidistant tangent coordinates: disc radius a:
#: a^2 / 2; ring a^2 (1 + q^2) / 2; square of half-side a: 2 a^2 / 3; equilateral triangle of
#: circumradius a: a^2 / 4).
_SHAPE_SECOND_MOMENT = {"disc": 0.5, "ring": 0.5 * (1 + RING_INNER ** 2), "square": 2.0 / 3.0, "triangle": 0.25}

# (azimuth deg, polar deg, type index) of the 12 markers, in order
_SEED_MARKERS = (
    (0, 90, 3), (30, 90, 2), (90, 90, 1), (120, 90, 0),
    (180, 90, 3), (210, 90, 2), (270, 90, 0), (300, 90, 2),
    (60, 30, 1), (60, 150, 1), (240, 30, 0), (240, 150, 3),
)


def sphere_direction(azimuth_deg, polar_deg) -> np.ndarray:
    """Unit vector(s) at ``azimuth`` (from x towards y) and ``polar`` angle (from +z), degrees.

    Parameters
    ----------
    azimuth_deg, polar_deg : float or array_like, shape (N,)

    Returns
    -------
    ndarray, shape (3,) or (N, 3)
    """
    a, p = np.radians(azimuth_deg), np.radians(polar_deg)
    return np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1)


@dataclass(frozen=True, eq=False)
class BallLayout:
    """Markers painted on a ball, in the ball frame.

    Attributes
    ----------
    directions : ndarray, shape (n, 3)
        Unit vectors from the ball centre to the marker centres, ball frame.
    types : ndarray of int, shape (n,)
        Type index of each marker (into ``type_names``).
    type_names : tuple of str, length n_types
        e.g. ``("red", "blue", "green", "black")``.
    type_shapes : tuple of str, length n_types
        Shape of each type (``"square"``, ``"ring"``, ``"triangle"``, ``"disc"``).
    palette : dict
        Linear-RGB colour (3 floats in 0..1) per type name.
    names : tuple of str, length n
        Marker names ``"<type>.<k>"`` (``"red.0"``, ...), k counting that type in order.
    marker_size : float
        Angular size of a marker, rad (disc radius, square half-side, triangle circumradius).
    radius : float
        Ball radius, m.
    type_sizes : tuple of float, length n_types, optional
        Angular size of each type's markers, rad; empty (default): every type ``marker_size``.
    name : str
        The ball's name (a ball file's ``name``; ``"baseball"`` for the seed's).
    """

    directions: np.ndarray
    types: np.ndarray
    type_names: tuple = TYPE_NAMES
    type_shapes: tuple = TYPE_SHAPES
    palette: dict = field(default_factory=lambda: dict(DEFAULT_PALETTE))
    names: tuple = ()
    marker_size: float = DEFAULT_MARKER_SIZE
    radius: float = BASEBALL_RADIUS
    type_sizes: tuple = ()
    name: str = "baseball"

    def __post_init__(self):
        d = np.asarray(self.directions, float)
        if d.ndim != 2 or d.shape[1] != 3 or len(d) < 2:
            raise ValueError(f"directions must have shape (n, 3) with n >= 2, got {d.shape}")
        norm = np.linalg.norm(d, axis=1)
        if not np.all(norm > 0):
            raise ValueError("marker directions must be non-zero")
        d = d / norm[:, None]
        t = np.asarray(self.types)
        if t.shape != (len(d),):
            raise ValueError(f"types must have shape ({len(d)},), got {t.shape}")
        t = t.astype(int)
        nt = len(self.type_names)
        if len(self.type_shapes) != nt:
            raise ValueError(f"type_shapes must have {nt} entries, got {len(self.type_shapes)}")
        unknown = [s for s in self.type_shapes if s not in _SHAPE_SECOND_MOMENT]
        if unknown:  # the detector tells these shapes apart, and centroid_depth models them
            raise ValueError(f"unknown marker shapes {unknown}: use {', '.join(TYPE_SHAPES)}")
        if t.min() < 0 or t.max() >= nt:
            raise ValueError(f"types must be in 0..{nt - 1}, got {sorted(set(t.tolist()))}")
        missing = [n for n in self.type_names if n not in self.palette]
        if missing:
            raise ValueError(f"palette has no colour for types {missing}")
        pal = {n: tuple(float(c) for c in as_array(self.palette[n], (3,), f"palette[{n!r}]"))
               for n in self.type_names}
        if not (0 < self.marker_size < np.pi / 2):
            raise ValueError(f"marker_size is an angle in radians in (0, pi/2), got {self.marker_size}")
        if not self.radius > 0:
            raise ValueError(f"radius must be positive, got {self.radius}")
        sizes = tuple(float(v) for v in self.type_sizes)
        if sizes and len(sizes) != nt:
            raise ValueError(f"type_sizes must have {nt} entries, got {len(sizes)}")
        if not all(0 < v < np.pi / 2 for v in sizes):
            raise ValueError(f"type_sizes are angles in radians in (0, pi/2), got {sizes}")
        names = tuple(self.names)
        if not names:
            count: dict[int, int] = {}
            out = []
            for k in t:
                out.append(f"{self.type_names[k]}.{count.get(int(k), 0)}")
                count[int(k)] = count.get(int(k), 0) + 1
            names = tuple(out)
        if len(names) != len(d):
            raise ValueError(f"names must have {len(d)} entries, got {len(names)}")
        d.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "directions", d)
        object.__setattr__(self, "types", t)
        object.__setattr__(self, "type_names", tuple(self.type_names))
        object.__setattr__(self, "type_shapes", tuple(self.type_shapes))
        object.__setattr__(self, "palette", pal)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "type_sizes", sizes)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def seed(cls, palette: dict | None = None, marker_size: float = DEFAULT_MARKER_SIZE,
             radius: float = BASEBALL_RADIUS) -> "BallLayout":
        """The seed's 12-marker baseball (module docstring); ``palette`` overrides colours."""
        az, pol, typ = (np.array(c, float) for c in zip(*_SEED_MARKERS))
        return cls(sphere_direction(az, pol), typ.astype(int),
                   palette={**DEFAULT_PALETTE, **(palette or {})},
                   marker_size=marker_size, radius=radius)

    def with_palette(self, palette: dict) -> "BallLayout":
        """A copy with some type colours replaced (``{"blue": (0.1, 0.5, 1.0)}``)."""
        return replace(self, palette={**self.palette, **palette})

    # -- per-marker properties -----------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.directions)

    @property
    def n_types(self) -> int:
        return len(self.type_names)

    @property
    def shapes(self) -> tuple:
        """Shape of each marker, length n."""
        return tuple(self.type_shapes[k] for k in self.types)

    @property
    def sizes_of_types(self) -> np.ndarray:
        """Angular size of each type's markers, rad, shape (n_types,)."""
        return np.array(self.type_sizes) if self.type_sizes else np.full(self.n_types, float(self.marker_size))

    @property
    def sizes(self) -> np.ndarray:
        """Angular size of each marker, rad, shape (n,)."""
        return self.sizes_of_types[self.types]

    @cached_property
    def centroid_depth(self) -> np.ndarray:
        """How far inside the ball a marker's image centroid lies, per type, as a fraction of the radius.

        A painted patch on the sphere, seen from any direction, has its image centroid (area
        weighted: each patch element by its projected area) at the image of the point
        ``(1 - k) radius u`` on the marker's axis ``u``, to first order in the marker's size,
        with ``k`` the mean squared angular distance of the painted area from the marker's centre
        (rad^2): the patch curves away from the viewer and its far side is foreshortened more than
        its near side. So a pixel ray through a centroid meets the sphere closer to the line of
        sight than the marker's centre (by ``k tan(angle from the line of sight)``, ~2 deg for
        the seed's markers 65 deg off it), while two views' centroids triangulate to that inner
        point along the right direction. Neglected: markers cut by the limb.

        Returns
        -------
        ndarray, shape (n_types,)
            ``k`` per type index (the seed's markers: 0.0064 (triangle) to 0.0171 (square)).
        """
        if not self.type_sizes:
            return np.array([_SHAPE_SECOND_MOMENT[s] for s in self.type_shapes]) * self.marker_size ** 2
        return np.array([_SHAPE_SECOND_MOMENT[s] for s in self.type_shapes]) * self.sizes_of_types ** 2

    @property
    def colors(self) -> np.ndarray:
        """Linear-RGB colour of each marker, shape (n, 3)."""
        return np.array([self.palette[self.type_names[k]] for k in self.types])

    def type_index(self, types) -> np.ndarray:
        """Type indices from names or indices.

        Parameters
        ----------
        types : str, int or array_like, shape (N,)
            Type names (``"red"``) or indices; mixed lists are accepted.

        Returns
        -------
        ndarray of int, shape (N,) (or () for a scalar)
        """
        arr = np.asarray(types, dtype=object)
        lookup = {n: i for i, n in enumerate(self.type_names)}
        out = np.empty(arr.shape, int)
        for idx, v in np.ndenumerate(arr):
            if isinstance(v, str):
                if v not in lookup:
                    raise ValueError(f"unknown marker type {v!r}; known: {self.type_names}")
                out[idx] = lookup[v]
            else:
                try:
                    iv = int(v)
                except (TypeError, ValueError):
                    raise ValueError(f"marker type must be a name or an index, got {v!r}") from None
                if iv != v or not 0 <= iv < self.n_types:
                    raise ValueError(f"marker type index must be in 0..{self.n_types - 1}, got {v!r}")
                out[idx] = iv
        return out

    def visible(self, view_dirs, margin_deg: float = 0.0) -> np.ndarray:
        """Which markers a viewer in direction ``view_dirs`` (ball frame) sees.

        A marker is visible when its angle to the view direction (from the ball centre toward
        the viewer) is below ``90 deg - margin_deg``.

        Parameters
        ----------
        view_dirs : array_like, shape (3,) or (V, 3)
        margin_deg : float

        Returns
        -------
        ndarray of bool, shape (n,) or (V, n)
        """
        v = np.asarray(view_dirs, float)
        one = v.ndim == 1
        v = np.atleast_2d(v)
        if v.shape[1:] != (3,):
            raise ValueError(f"view_dirs must have shape (3,) or (V, 3), got {np.shape(view_dirs)}")
        v = v / np.linalg.norm(v, axis=1, keepdims=True)
        vis = v @ self.directions.T > np.cos(np.radians(90.0 - margin_deg)) + 1e-12
        return vis[0] if one else vis

    # -- identifiability -----------------------------------------------------------------------
    @cached_property
    def _pair_rotations(self) -> tuple[np.ndarray, np.ndarray]:
        """Nontrivial rotations mapping an ordered marker pair onto another with equal angle
        (geometry only), and the angle from each rotated marker to the nearest marker of its
        own type: ``(Q (q, 3, 3), mismatch_deg (q, n))``."""
        qs = _pair_rotations_geometry(self.directions.tobytes(), len(self))
        d = self.directions
        img = np.einsum("qab,nb->qna", qs, d)
        cosang = np.clip(img @ d.T, -1.0, 1.0)  # (q, n, n)
        same = self.types[:, None] == self.types[None, :]
        mismatch = np.degrees(np.arccos(np.where(same[None], cosang, -1.0).max(-1)))
        return qs, mismatch

    def separation_deg(self, visible) -> np.ndarray:
        """How clearly a set of visible markers fixes the ball frame.

        For every nontrivial rotation that maps some pair of markers onto another pair of
        markers, the largest angle between a rotated visible marker and the nearest marker of
        its type; the minimum over those rotations. 0 means the frame is ambiguous (a rotation
        other than the identity explains the visible markers and their types); the larger, the
        more noise the identification tolerates. A set of fewer than 2 markers is ambiguous.
        (Rotations not mapping a pair exactly are not searched, so for near-ambiguities this is
        an upper bound.)

        Parameters
        ----------
        visible : array_like of bool, shape (n,) or (V, n)

        Returns
        -------
        ndarray, shape () or (V,)
        """
        vis = np.asarray(visible, bool)
        if vis.shape[-1:] != (len(self),) or vis.ndim > 2:
            raise ValueError(f"visible must have shape ({len(self)},) or (V, {len(self)}), got {vis.shape}")
        _, mis = self._pair_rotations
        worst = np.where(vis[..., None, :], mis, -np.inf).max(-1)  # (..., q)
        sep = worst.min(-1) if worst.shape[-1] else np.full(vis.shape[:-1], 180.0)
        return np.where(vis.sum(-1) >= 2, np.maximum(sep, 0.0), 0.0)


@dataclass(frozen=True, eq=False)
class LayoutCheck:
    """What a layout shows from sampled view directions (:func:`check_layout`).

    Attributes
    ----------
    margin_deg : float
        Markers within ``90 - margin_deg`` of the view count as visible.
    view_dirs : ndarray, shape (V, 3)
        Sampled view directions (ball frame).
    n_visible, n_types : ndarray of int, shape (V,)
        Visible markers and distinct visible types per view.
    separation_deg : ndarray, shape (V,)
        :meth:`BallLayout.separation_deg` per view (0 = frame ambiguous).
    symmetric : bool
        The typed layout itself has a nontrivial rotational symmetry (never identifiable).
    """

    margin_deg: float
    view_dirs: np.ndarray
    n_visible: np.ndarray
    n_types: np.ndarray
    separation_deg: np.ndarray
    symmetric: bool

    @property
    def min_types(self) -> int:
        return int(self.n_types.min())

    @property
    def share_3_types(self) -> float:
        """Share of views with at least 3 visible types."""
        return float(np.mean(self.n_types >= 3))

    @property
    def n_ambiguous(self) -> int:
        """Views from which the frame is not determinable."""
        return int(np.sum(self.separation_deg <= 1e-6))

    @property
    def min_separation_deg(self) -> float:
        return float(self.separation_deg.min())


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors (Fibonacci lattice), shape (n, 3)."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    th = np.pi * (1.0 + 5.0 ** 0.5) * i
    return np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], axis=1)


def check_layout(layout: BallLayout | None = None, margin_deg: float = 0.0, n_views: int = 2000,
                 view_dirs=None) -> LayoutCheck:
    """Sample view directions and report what the layout shows from each.

    Parameters
    ----------
    layout : BallLayout, optional
        Default :meth:`BallLayout.seed`.
    margin_deg : float
        Visibility margin: a marker counts when its angle to the view is below
        ``90 - margin_deg`` deg.
    n_views : int
        Number of Fibonacci-lattice view directions (ignored with ``view_dirs``).
    view_dirs : array_like, shape (V, 3), optional

    Returns
    -------
    LayoutCheck
    """
    layout = layout or BallLayout.seed()
    v = fibonacci_sphere(n_views) if view_dirs is None else as_array(view_dirs, (None, 3), "view_dirs")
    vis = layout.visible(v, margin_deg)
    onehot = np.eye(layout.n_types, dtype=int)[layout.types]
    n_types = ((vis.astype(int) @ onehot) > 0).sum(1)
    sep = layout.separation_deg(vis)
    symmetric = bool(layout.separation_deg(np.ones(len(layout), bool)) <= 1e-6)
    return LayoutCheck(float(margin_deg), v, vis.sum(1), n_types, sep, symmetric)


@lru_cache(maxsize=8)
def _pair_rotations_geometry(directions_bytes: bytes, n: int) -> np.ndarray:
    """Distinct rotations other than the identity that map some ordered pair of marker
    directions onto another pair with the same angle, shape (q, 3, 3) (cached per geometry)."""
    d = np.frombuffer(directions_bytes).reshape(n, 3)
    ang = np.arccos(np.clip(d @ d.T, -1.0, 1.0))
    i, j = (x.ravel() for x in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
    ok = (i != j) & (np.abs(np.einsum("ij,ij->i", d[i], d[j])) < 0.999)
    i, j = i[ok], j[ok]
    # pairs (i, j) -> (a, b) with equal angles
    same = np.abs(ang[i, j][:, None] - ang[i, j][None, :]) < 1e-9
    src, dst = np.nonzero(same)
    frames_src = _triad(d[i[src]], d[j[src]])
    frames_dst = _triad(d[i[dst]], d[j[dst]])
    qs = frames_dst @ np.swapaxes(frames_src, -1, -2)
    qs = qs[np.abs(qs - np.eye(3)).max(axis=(1, 2)) > 1e-6]
    if not len(qs):
        return np.zeros((0, 3, 3))
    _, first = np.unique(np.round(qs.reshape(len(qs), 9), 6), axis=0, return_index=True)
    return qs[np.sort(first)]


def _triad(p, q) -> np.ndarray:
    """Orthonormal frame(s) (columns) from non-parallel unit vectors, symmetric in p and q.

    ``p, q`` of shape (3,) or (H, 3) give (3, 3) or (H, 3, 3)."""
    e1 = p + q
    e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = p - q
    e2 = e2 / np.linalg.norm(e2, axis=-1, keepdims=True)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def seed_layout(palette: dict | None = None, marker_size: float = DEFAULT_MARKER_SIZE) -> BallLayout:
    """Shorthand for :meth:`BallLayout.seed`."""
    return BallLayout.seed(palette=palette, marker_size=marker_size)
