"""The studio's scene model: bodies, lights, flashes and the dark room around them.

Everything is in SI units (metres, seconds) and linear RGB. Radiometry is deliberately simple
and relative: a :class:`PointLight` of ``intensity`` I gives a surface facing it at distance d
the irradiance ``I / d**2``; a lambertian surface of albedo a then has the (pixel-value)
radiance ``a * I / d**2``. The sensor's ``gain`` maps radiance to a fraction of full scale.

A photo integrates over the shutter. The strobe (or any light in :attr:`Scene.lights`) fires
once per :class:`Flash`; each flash has its own body poses, so one image can hold a ball at
K instants. Ambient light is weak and continuous: it lights every surface over the whole
shutter (radiance ``albedo * ambient``); a body that moves is sampled at the flash instants,
each sample carrying ``1/K`` of the ambient exposure (a discretised motion trail).

Bodies and their local frames:

- :class:`Sphere`: centre at the origin of the ball frame, painted :class:`SphereMarker` s.
- :class:`Capsule`: axis from ``(0, 0, 0)`` to ``(0, 0, length)``, for limbs.
- :class:`TexturedPlane`: the plane ``z = 0``, texture over ``extent`` (e.g. a calibration
  target, whose board frame is OpenCV's); ``extent=None`` is an infinite uniform plane.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from stillcap._checks import as_array, is_rotation
from stillcap.ball.layout import RING_INNER

SHAPES = ("disc", "ring", "square", "triangle")


def _rgb(value, name: str) -> np.ndarray:
    a = np.asarray(value, float)
    if a.ndim == 0:
        a = np.full(3, float(a))
    return as_array(a, (3,), name)


def _pose(T, name: str) -> np.ndarray:
    T = as_array(T, (4, 4), name)
    R = T[:3, :3]
    if not is_rotation(R, 1e-6):
        raise ValueError(f"{name}: the 3x3 block is not a proper rotation")
    return T


def tangent_frame(direction) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors ``(e1, e2)`` spanning the tangent plane of the unit sphere at ``direction``.

    ``e1 = normalize(z x direction)`` ("east") and ``e2 = direction x e1`` ("north"); near the
    poles (``|direction . z| > 0.9``) the x axis replaces z. A marker's ``angle`` turns its shape
    from ``e1`` towards ``e2``.
    """
    c = as_array(direction, (3,), "direction")
    ref = np.array([0.0, 0.0, 1.0]) if abs(c[2]) <= 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, c)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(c, e1)


@dataclass
class SphereMarker:
    """A painted patch on a sphere, defined in the ball frame.

    Parameters
    ----------
    direction : array_like, shape (3,)
        Centre of the marker as a direction from the ball centre (normalised here).
    shape : {"disc", "ring", "square", "triangle"}
    size : float
        Angular size in radians: disc/ring radius, square half-side, triangle circumradius
        (measured as great-circle distance from the centre, i.e. azimuthal-equidistant
        coordinates in the tangent plane).
    angle : float
        Rotation of the shape about ``direction`` in radians (see :func:`tangent_frame`); a
        triangle with ``angle=0`` points towards ``e2``.
    color : array_like, shape (3,)
        Linear RGB albedo.
    inner : float
        Ring only: inner radius as a fraction of ``size``.
    name : str
    """

    direction: np.ndarray
    shape: str = "disc"
    size: float = 0.15
    angle: float = 0.0
    color: np.ndarray = field(default_factory=lambda: np.array([0.8, 0.05, 0.04]))
    inner: float = RING_INNER
    name: str = ""

    def __post_init__(self):
        d = as_array(self.direction, (3,), "marker direction")
        if np.linalg.norm(d) == 0:
            raise ValueError("marker direction must not be zero")
        self.direction = d / np.linalg.norm(d)
        if self.shape not in SHAPES:
            raise ValueError(f"marker shape must be one of {SHAPES}, got {self.shape!r}")
        if not 0 < self.size < np.pi / 2:
            raise ValueError(f"marker size is an angle in radians in (0, pi/2), got {self.size}")
        self.color = _rgb(self.color, "marker color")


@dataclass
class Sphere:
    """A ball of ``radius`` metres, base ``albedo`` (linear RGB), painted ``markers``."""

    radius: float
    albedo: np.ndarray = field(default_factory=lambda: np.array([0.75, 0.75, 0.72]))
    markers: Sequence[SphereMarker] = ()
    name: str = ""

    def __post_init__(self):
        if not self.radius > 0:
            raise ValueError(f"sphere radius must be positive (metres), got {self.radius}")
        self.albedo = _rgb(self.albedo, "sphere albedo")
        self.markers = tuple(self.markers)


@dataclass
class Capsule:
    """A capsule (cylinder with hemispherical ends): axis from the origin to ``(0, 0, length)``."""

    length: float
    radius: float
    albedo: np.ndarray = field(default_factory=lambda: np.array([0.03, 0.03, 0.03]))
    name: str = ""

    def __post_init__(self):
        if not self.radius > 0 or not self.length >= 0:
            raise ValueError(f"capsule needs radius > 0 and length >= 0, got {self.radius}, {self.length}")
        self.albedo = _rgb(self.albedo, "capsule albedo")


@dataclass
class TexturedPlane:
    """The plane ``z = 0`` of its frame, painted with a texture over ``extent``.

    Parameters
    ----------
    extent : (xmin, ymin, xmax, ymax) in metres, or None for an infinite uniform plane.
    texture : array_like, shape (h, w) or (h, w, 3), optional
        Reflectance in [0, 1] (floats) or 0..255 (uint8), RGB. Texture pixel ``(u, v)`` sits at
        ``x = xmin + (u + 0.5) / w * (xmax - xmin)`` (the convention of
        :mod:`stillcap.calibrate.targets`); looked up bilinearly.
    albedo : array_like, shape (3,)
        Multiplies the texture (the plane's colour when there is no texture).
    name : str
    """

    extent: tuple | None = None
    texture: np.ndarray | None = None
    albedo: np.ndarray = field(default_factory=lambda: np.ones(3))
    name: str = ""

    def __post_init__(self):
        self.albedo = _rgb(self.albedo, "plane albedo")
        if self.extent is not None:
            e = tuple(float(v) for v in np.ravel(self.extent))
            if len(e) != 4 or not (e[2] > e[0] and e[3] > e[1]):
                raise ValueError(f"extent must be (xmin, ymin, xmax, ymax) with max > min, got {self.extent}")
            self.extent = e
        if self.texture is not None:
            if self.extent is None:
                raise ValueError("a textured plane needs a finite extent")
            t = np.asarray(self.texture)
            scale = 1 / 255 if t.dtype == np.uint8 else 1.0
            t = t.astype(np.float32) * np.float32(scale)
            if not (t.ndim == 2 or (t.ndim == 3 and t.shape[2] == 3)) or min(t.shape[:2]) < 1:
                raise ValueError(f"texture must have shape (h, w) or (h, w, 3), got {np.shape(self.texture)}")
            self.texture = np.ascontiguousarray(t)  # grey stays one channel (faster lookups)

    @classmethod
    def from_target(cls, target, px_per_square: int = 32, white: float = 0.8,
                    black: float = 0.04, name: str = "") -> TexturedPlane:
        """A printed calibration target (:class:`~stillcap.calibrate.targets.Chessboard` or
        :class:`~stillcap.calibrate.targets.CharucoTarget`) in its board frame.

        ``white`` and ``black`` are the reflectances of paper and ink.
        """
        tex = target.texture(int(px_per_square)).astype(np.float32) / 255.0
        return cls(target.extent, black + (white - black) * tex, np.ones(3), name)


def target_planes(target, target2world, px_per_square: int = 32, **kw) -> list[tuple[TexturedPlane, np.ndarray]]:
    """``(plane, plane2world)`` pairs for a planar target or every face of a
    :class:`~stillcap.calibrate.targets.CalibrationObject` placed at ``target2world`` (4, 4)."""
    T = _pose(target2world, "target2world")
    if hasattr(target, "faces"):
        return [(TexturedPlane.from_target(f, px_per_square, name=f"face{i}", **kw), T @ np.asarray(F, float))
                for i, (f, F) in enumerate(zip(target.faces, target.face2object))]
    return [(TexturedPlane.from_target(target, px_per_square, **kw), T)]


@dataclass
class PointLight:
    """A point light at ``position`` (world, metres) of ``intensity`` times RGB ``color``.

    A strobe beside a camera, a side strobe (half-moon silhouettes) and an LED ring around a
    lens (a light at the camera centre) are all point lights.
    """

    position: np.ndarray
    intensity: float = 1.0
    color: np.ndarray = field(default_factory=lambda: np.ones(3))

    def __post_init__(self):
        self.position = as_array(self.position, (3,), "light position")
        self.color = _rgb(self.color, "light color")
        if self.intensity < 0:
            raise ValueError(f"light intensity must be >= 0, got {self.intensity}")


@dataclass
class Flash:
    """One instant of the exposure: the pose of every body when the lights fire.

    Parameters
    ----------
    poses : sequence of array_like, shape (4, 4)
        ``body2world`` for each of :attr:`Scene.bodies`, in the same order.
    time : float
        Seconds from the shutter opening (informative; the renderer does not use it).
    strength : float
        Scales the lights of this flash (0 = a missed flash).
    lights : sequence of PointLight, optional
        Lights that fire at this flash instead of :attr:`Scene.lights` (two strobes at two rates).
    """

    poses: Sequence[np.ndarray]
    time: float = 0.0
    strength: float = 1.0
    lights: Sequence[PointLight] | None = None

    def __post_init__(self):
        self.poses = tuple(_pose(T, f"flash pose #{i}") for i, T in enumerate(self.poses))
        if self.lights is not None:
            self.lights = tuple(self.lights)


@dataclass
class Exposure:
    """What happens while the shutter is open: ``flashes`` and the weak ``ambient`` light.

    Parameters
    ----------
    flashes : sequence of Flash
    ambient : float
        Ambient irradiance integrated over the shutter, relative to the lights (a white surface
        gets the radiance ``ambient``); small but nonzero in a dark room.
    shutter_s, strobe_hz, first_flash_s : float, optional
        Timing, recorded for the capture folder (seconds, hertz).
    """

    flashes: Sequence[Flash] = ()
    ambient: float = 0.0
    shutter_s: float | None = None
    strobe_hz: float | None = None
    first_flash_s: float | None = None

    def __post_init__(self):
        self.flashes = tuple(self.flashes)
        if self.ambient < 0:
            raise ValueError(f"ambient must be >= 0, got {self.ambient}")

    @classmethod
    def single(cls, poses, ambient: float = 0.0, shutter_s: float | None = None) -> Exposure:
        """A still photo: one instant, lit by the scene lights."""
        return cls((Flash(poses),), ambient, shutter_s)

    @classmethod
    def strobe(cls, poses_at: Callable[[float], Sequence[np.ndarray]], strobe_hz: float,
               n_flashes: int, first_flash_s: float = 0.0, shutter_s: float | None = None,
               ambient: float = 0.0, missed: Sequence[int] = ()) -> Exposure:
        """A multi-exposure: flashes at ``first_flash_s + k / strobe_hz``, ``k < n_flashes``.

        ``poses_at(t)`` gives the ``body2world`` of every body at time ``t`` (s); flashes whose
        index is in ``missed`` do not fire (strength 0), as a strobe that skips.
        """
        if strobe_hz <= 0 or n_flashes < 0:
            raise ValueError(f"need strobe_hz > 0 and n_flashes >= 0, got {strobe_hz}, {n_flashes}")
        times = first_flash_s + np.arange(n_flashes) / strobe_hz
        if shutter_s is None:
            shutter_s = float(times[-1] + 0.5 / strobe_hz) if n_flashes else 0.0
        flashes = [Flash(poses_at(float(t)), float(t), 0.0 if k in missed else 1.0) for k, t in enumerate(times)]
        return cls(flashes, ambient, shutter_s, float(strobe_hz), float(first_flash_s))


@dataclass
class Backdrop:
    """The dark room behind every body: an image-space radiance (ambient-lit, whole shutter).

    Parameters
    ----------
    level : float or array_like, shape (3,)
        Linear radiance of the room (0 = black).
    contrast : float
        Relative amplitude of a smooth low-contrast noise texture (0 = uniform).
    scale_px : float
        Feature size of that texture in pixels.
    """

    level: float | np.ndarray = 0.0
    contrast: float = 0.0
    scale_px: float = 48.0

    def radiance(self, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
        """The backdrop as linear RGB ``(height, width, 3)`` float32."""
        import cv2

        level = _rgb(self.level, "backdrop level").astype(np.float32)
        if self.contrast > 0 and np.any(level > 0):
            gw, gh = max(2, int(np.ceil(width / self.scale_px)) + 1), max(2, int(np.ceil(height / self.scale_px)) + 1)
            grid = np.clip(1 + self.contrast * rng.standard_normal((gh, gw, 1)), 0, None) * level
            img = cv2.resize(grid.astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC)
            return np.maximum(img, 0, out=img)
        img = np.empty((height, width, 3), np.float32)
        img[:] = level
        return img


@dataclass
class Scene:
    """Everything a camera can photograph.

    Parameters
    ----------
    bodies : sequence of Sphere, Capsule or TexturedPlane
        Bodies that move during the exposure; their poses are in each :class:`Flash`.
    exposure : Exposure
    lights : sequence of PointLight
        Lights that fire at each flash (strobes, LED rings, lamps of a still photo).
    static : sequence of (body, body2world)
        Bodies that do not move (calibration targets, a background wall).
    backdrop : Backdrop
    """

    bodies: Sequence = ()
    exposure: Exposure = field(default_factory=Exposure)
    lights: Sequence[PointLight] = ()
    static: Sequence[tuple] = ()
    backdrop: Backdrop = field(default_factory=Backdrop)

    def __post_init__(self):
        self.bodies = tuple(self.bodies)
        self.lights = tuple(self.lights)
        self.static = tuple((b, _pose(T, f"static body #{i} pose")) for i, (b, T) in enumerate(self.static))
        for k, f in enumerate(self.exposure.flashes):
            if len(f.poses) != len(self.bodies):
                raise ValueError(f"flash #{k} has {len(f.poses)} poses for {len(self.bodies)} bodies")

    @classmethod
    def still(cls, placed: Sequence[tuple], lights: Sequence[PointLight] = (), ambient: float = 0.0,
              backdrop: Backdrop | None = None) -> Scene:
        """A still photo of ``(body, body2world)`` pairs (all static), lit once by ``lights``."""
        return cls((), Exposure((Flash(()),), ambient), lights, placed, backdrop or Backdrop())
