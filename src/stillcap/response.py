"""A camera's response: how its 8-bit pixel values relate to the light that reached the sensor.

Every detector that works in linear light (the ball's known-radius Hough transform, the painted
markers' palette, bead and colour-marker detection) undoes the response first. It is a property
of each camera (``Camera.response``, the rig file's ``response`` key, ``docs/camera-response.md``),
never a constant inside a detector:

- ``"srgb"`` (the default): the IEC 61966-2-1 curve, what most cameras' JPEGs carry;
- ``"linear"``: pixel value proportional to radiance (a machine-vision camera with gamma off,
  raw data scaled to 8 bits);
- ``{"gamma": g}``: ``value = 255 * radiance ** (1 / g)``;
- ``{"lut": [256 numbers]}``: the linear radiance (0-1) of every 8-bit code, non-decreasing
  (a measured curve, a consumer camera's tone curve).

A response's *class* is what a photo can tell reliably: ``"linear"`` (effective gamma below
:data:`LINEAR_LIMIT`) or ``"gamma"`` (an encoded response: sRGB, a power law, a tone curve).
``--response auto`` estimates it from the photos themselves (:mod:`stillcap.detect.response`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Response", "EstimatedResponse", "CLASSES", "LINEAR_LIMIT", "parse_response_spec", "check_response_option",
           "effective_gamma_of_lut"]

#: The response classes (:attr:`Response.response_class`).
CLASSES = ("linear", "gamma")
#: Effective gammas below this are the "linear" class: halfway (geometrically) between a linear
#: camera (1.0) and the flattest encoding the studio varies (1.8).
LINEAR_LIMIT = 1.35
_KINDS = ("srgb", "linear", "gamma", "lut")
_MIN_GAMMA, _MAX_GAMMA = 0.2, 5.0


def _srgb_decode(c: np.ndarray) -> np.ndarray:
    # IEC 61966-2-1. Written out (9 lines) rather than taken from skimage/colour: those decode
    # float images only, and the LUT below must match the studio's encoder exactly.
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _srgb_encode(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0) ** (1 / 2.4) - 0.055)


def effective_gamma_of_lut(lut) -> float:
    """The power ``g`` of ``(v / 255) ** g`` closest (least squares in log radiance) to a
    code -> radiance table over the mid-tones (codes 32-240, where an encoding's shape shows and
    toe and shoulder do not dominate)."""
    lut = np.asarray(lut, float)
    v = np.arange(32, 241)
    y = lut[v]
    ok = y > 0
    if ok.sum() < 10:
        return float("nan")
    x = np.log(v[ok] / 255.0)
    ly = np.log(y[ok] / max(lut[-1], 1e-12))
    return float(np.sum(x * ly) / np.sum(x * x))


@dataclass(frozen=True)
class Response:
    """A camera's response (module docstring). Build with :meth:`srgb`, :meth:`linear`,
    :meth:`power`, :meth:`table`, :meth:`from_json` or :func:`parse_response_spec`.

    Attributes
    ----------
    kind : {"srgb", "linear", "gamma", "lut"}
    gamma : float or None
        The power of a ``"gamma"`` response.
    lut : tuple of 256 floats or None
        Code -> linear radiance of a ``"lut"`` response.
    """

    kind: str = "srgb"
    gamma: float | None = None
    lut: tuple | None = field(default=None, repr=False)

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ValueError(f"response kind must be one of {', '.join(_KINDS)}, got {self.kind!r}")
        if self.kind == "gamma":
            g = self.gamma
            if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(g) \
                    or not _MIN_GAMMA <= g <= _MAX_GAMMA:
                raise ValueError(f"response gamma must be a number from {_MIN_GAMMA} to {_MAX_GAMMA}, got {g!r}")
            object.__setattr__(self, "gamma", float(g))
        elif self.gamma is not None:
            raise ValueError(f"a {self.kind!r} response takes no gamma")
        if self.kind == "lut":
            object.__setattr__(self, "lut", _check_lut(self.lut))
        elif self.lut is not None:
            raise ValueError(f"a {self.kind!r} response takes no lookup table")

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def srgb(cls) -> Response:
        return cls("srgb")

    @classmethod
    def linear(cls) -> Response:
        return cls("linear")

    @classmethod
    def power(cls, gamma: float) -> Response:
        """``value = 255 * radiance ** (1 / gamma)`` (gamma 1 is :meth:`linear`)."""
        return cls("gamma", gamma=gamma)

    @classmethod
    def estimated(cls, response_class: str, gamma: float) -> Response:
        """The response an estimate names: linear for the ``"linear"`` class, else the power law
        of the estimated ``gamma`` (kept within 1.4-3.2, the encodings cameras use)."""
        if response_class == "linear":
            return cls.linear()
        return cls.power(round(float(np.clip(gamma, 1.4, 3.2)), 2))

    @classmethod
    def table(cls, values) -> Response:
        """A measured curve: ``values[code]`` = linear radiance (0-1) of each 8-bit code."""
        return cls("lut", lut=values)

    # --- the curve ----------------------------------------------------------------------
    def to_linear_lut(self) -> np.ndarray:
        """8-bit code -> linear radiance (0-1), float32 shape (256,), read-only (cached)."""
        return _linear_lut(self)

    def linearize(self, values) -> np.ndarray:
        """Pixel values (8-bit scale, any shape; uint8 through the table, floats interpolated,
        clipped to 0-255) -> linear radiance 0-1, float32."""
        a = np.asarray(values)
        lut = _linear_lut(self)
        if a.dtype == np.uint8:
            return lut[a]
        c = np.clip(a.astype(np.float32), 0, 255)
        if self.kind == "linear":
            return c / np.float32(255.0)
        if self.kind == "gamma":
            return (c / np.float32(255.0)) ** np.float32(self.gamma)
        if self.kind == "srgb":
            return _srgb_decode(c / 255.0).astype(np.float32)
        return np.interp(c, np.arange(256), lut).astype(np.float32)

    def encode(self, linear) -> np.ndarray:
        """Linear radiance (0-1, clipped) -> pixel values on the 8-bit scale (float, unrounded)."""
        x = np.clip(np.asarray(linear, float), 0.0, 1.0)
        if self.kind == "linear":
            return 255.0 * x
        if self.kind == "gamma":
            return 255.0 * x ** (1.0 / self.gamma)
        if self.kind == "srgb":
            return 255.0 * _srgb_encode(x)
        lut = np.asarray(self.lut, float)
        # the inverse of a non-decreasing table: flat runs give their first code
        keep = np.concatenate([[True], np.diff(lut) > 0])
        return np.interp(x, lut[keep], np.arange(256.0)[keep])

    def as_srgb(self, image) -> np.ndarray:
        """An 8-bit photo of this response re-encoded as the sRGB camera would have written it
        (uint8, same shape; the photo itself for sRGB): for detectors whose colours are sRGB
        references (bead and marker palettes)."""
        a = np.asarray(image)
        if self.kind == "srgb":
            return a
        if a.dtype != np.uint8:
            a = np.clip(np.round(a), 0, 255).astype(np.uint8)
        return _srgb_table(self)[a]

    @property
    def effective_gamma(self) -> float:
        """The power law closest to the curve (:func:`effective_gamma_of_lut`): 1 for linear,
        ``gamma`` for a power law, about 2.2 for sRGB."""
        if self.kind == "linear":
            return 1.0
        if self.kind == "gamma":
            return self.gamma
        return effective_gamma_of_lut(_linear_lut(self))

    @property
    def response_class(self) -> str:
        """``"linear"`` or ``"gamma"`` (:data:`CLASSES`): what a photo can tell."""
        return "linear" if self.effective_gamma < LINEAR_LIMIT else "gamma"

    # --- files and text -----------------------------------------------------------------
    def to_json(self):
        """The rig file's form: ``"srgb"``, ``"linear"``, ``{"gamma": g}`` or ``{"lut": [...]}``."""
        if self.kind in ("srgb", "linear"):
            return self.kind
        if self.kind == "gamma":
            return {"gamma": self.gamma}
        return {"lut": [float(v) for v in self.lut]}

    @classmethod
    def from_json(cls, value, where: str = "response") -> Response:
        """A response from its rig-file form; ``ValueError`` ``WHERE: ...`` naming what came."""
        if isinstance(value, Response):
            return value
        if isinstance(value, str):
            if value in ("srgb", "linear"):
                return cls(value)
            raise ValueError(f"{where}: must be \"srgb\", \"linear\", {{\"gamma\": G}} or {{\"lut\": [256 numbers]}}, "
                             f"got {value!r}")
        if isinstance(value, dict) and len(value) == 1 and ("gamma" in value or "lut" in value):
            try:
                if "gamma" in value:
                    return cls.power(value["gamma"])
                return cls.table(value["lut"])
            except ValueError as e:
                raise ValueError(f"{where}: {e}") from None
        got = repr(value)
        got = got if len(got) <= 40 else got[:37] + "..."
        raise ValueError(f"{where}: must be \"srgb\", \"linear\", {{\"gamma\": G}} or {{\"lut\": [256 numbers]}}, "
                         f"got {got}")

    def __str__(self) -> str:
        if self.kind == "gamma":
            return f"gamma {self.gamma:g}"
        if self.kind == "lut":
            return f"lookup table (effective gamma {self.effective_gamma:.2f})"
        return self.kind

    def spec(self) -> str:
        """The command-line form (``srgb``, ``linear``, ``gamma:2.2``; a table has none: ``lut``)."""
        return f"gamma:{self.gamma:g}" if self.kind == "gamma" else self.kind


def _check_lut(values) -> tuple:
    try:
        a = np.asarray(values, float)
    except (TypeError, ValueError):
        raise ValueError("response lookup table must be 256 numbers") from None
    if a.shape != (256,):
        raise ValueError(f"response lookup table must have 256 numbers (one per 8-bit code), got shape {a.shape}")
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.max() > 1:
        raise ValueError("response lookup table values must be linear radiances from 0 to 1")
    if np.any(np.diff(a) < 0):
        i = int(np.flatnonzero(np.diff(a) < 0)[0])
        raise ValueError(f"response lookup table must not decrease (code {i + 1} is darker than code {i})")
    if not a[-1] > a[0]:
        raise ValueError("response lookup table is flat (code 255 is no brighter than code 0)")
    return tuple(float(v) for v in a)


@functools.lru_cache(maxsize=32)
def _linear_lut(r: Response) -> np.ndarray:
    c = np.arange(256, dtype=np.float64) / 255.0
    if r.kind == "linear":
        y = c
    elif r.kind == "gamma":
        y = c ** r.gamma
    elif r.kind == "srgb":
        y = _srgb_decode(c)
    else:
        y = np.asarray(r.lut, float)
    lut = y.astype(np.float32)
    lut.flags.writeable = False
    return lut


@functools.lru_cache(maxsize=32)
def _srgb_table(r: Response) -> np.ndarray:
    t = np.clip(np.round(255.0 * _srgb_encode(_linear_lut(r).astype(float))), 0, 255).astype(np.uint8)
    t.flags.writeable = False
    return t


def parse_response_spec(text: str, option: str = "--response") -> Response | str:
    """A ``--response`` value: ``auto`` (returned as the string ``"auto"``), ``srgb``, ``linear``
    or ``gamma:G``; ``ValueError`` naming the bad spec (and ``option``)."""
    s = str(text).strip().lower()
    if s in ("auto", "srgb", "linear"):
        return s if s == "auto" else Response(s)
    if s.startswith("gamma:"):
        try:
            g = float(s.split(":", 1)[1])
        except ValueError:
            g = None
        if g is not None and math.isfinite(g) and _MIN_GAMMA <= g <= _MAX_GAMMA:
            return Response.power(g)
        raise ValueError(f"{option} {text!r}: gamma:G needs a number G from {_MIN_GAMMA} to {_MAX_GAMMA} "
                         "(e.g. gamma:2.2)")
    raise ValueError(f"{option} {text!r}: expected auto, srgb, linear or gamma:G (e.g. gamma:2.2)")


def check_response_option(response):
    """A pipeline's ``response`` option: ``None`` (each camera's own), ``"auto"`` or a
    :class:`Response` (given as one, as its rig-file form, or as a ``--response`` spec string);
    ``ValueError`` naming a bad value."""
    if response is None or isinstance(response, Response):
        return response
    if isinstance(response, str):
        return parse_response_spec(response)
    return Response.from_json(response, "response option")


class EstimatedResponse:
    """What every response estimate shares (the balls' shading, a board's edges): a class or
    None when it cannot tell (``response_class``), and the fitted ``gamma``."""

    response_class: str | None
    gamma: float

    @property
    def ok(self) -> bool:
        return self.response_class is not None

    def response(self) -> Response | None:
        """The response it names (:meth:`Response.estimated`); None when it cannot tell."""
        return Response.estimated(self.response_class, self.gamma) if self.ok else None
