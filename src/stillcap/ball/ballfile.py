"""Ball files (``stillcap-ball``, ``docs/ball-format.md``): a ball's size, mass, flight
coefficients and painted markers, and the built-in balls (``stillcap/data/balls/*.json``).

A :class:`Ball` is what the pitch (and hand) pipelines need to know about the ball in the photos:
its radius (ball detection, triangulated centres), its mass and aerodynamics (the flight fit),
and its marker layout (:class:`~stillcap.ball.layout.BallLayout`: marker directions, types,
colours, shapes and sizes for the marker detector and the orientation fit). Nothing about a
baseball is assumed: the seed's 12-marker baseball is the built-in ball ``baseball``, read from
its file like any other.

The file's units are in its key names: ``radius_m``, ``mass_kg``, ``azimuth_deg``,
``polar_deg``, ``size_deg`` or ``size_mm``; colours as ``color_linear`` (linear RGB, 0-1) or
``color_srgb`` (``"#rrggbb"``, IEC 61966-2-1 sRGB). Every problem is one line naming the file
and the key path (:func:`stillcap.files.schema.validate`).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, Field, StrictInt, StrictStr, model_validator
from pydantic_core import PydanticCustomError

from stillcap.ball.layout import BallLayout, sphere_direction
from stillcap.ball.markers import marker_types
from stillcap.ball.physics import BALLS, BallModel, BallProperties, flight_model
from stillcap.detect.ball_markers import SHAPES, marker_color_class
from stillcap.files.atomic import write_text
from stillcap.files.jsonfile import read_json
from stillcap.files.schema import ClosedModel, Finite, Fraction, Name, Positive, describe, validate

__all__ = ["BALL_FORMAT", "BALL_VERSION", "Ball", "builtin_ball_names", "builtin_ball", "load_ball", "resolve_ball",
           "srgb_to_linear", "linear_to_srgb_hex"]

BALL_FORMAT = "stillcap-ball"
BALL_VERSION = 1
#: Largest ball radius a file may give, m (a typing error beyond: mm written as m).
MAX_RADIUS_M = 1.0
#: Largest mass, kg.
MAX_MASS_KG = 100.0
#: Chromatic marker types whose hues differ by less than this (deg, 0-360) but are not the same
#: colour would both claim the same pixels (:func:`stillcap.detect.ball_markers.detect_ball_markers`
#: accepts hues within 30 deg of a type's).
MIN_HUE_GAP_DEG = 30.0


# ----------------------------------------------------------------------------------------------
# colours
# ----------------------------------------------------------------------------------------------
def srgb_to_linear(hex_color: str) -> tuple:
    """``"#rrggbb"`` (sRGB, IEC 61966-2-1) as linear RGB in 0..1."""
    c = np.array([int(hex_color[i:i + 2], 16) for i in (1, 3, 5)], float) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return tuple(float(v) for v in lin)


def linear_to_srgb_hex(rgb) -> str:
    """Linear RGB (0..1) as ``"#rrggbb"`` sRGB (rounded to 8 bits)."""
    c = np.clip(np.asarray(rgb, float), 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    return "#" + "".join(f"{int(round(v * 255)):02x}" for v in s)


def _hex(v: str) -> str:
    if not re.fullmatch(r"#[0-9a-fA-F]{6}", v):
        raise PydanticCustomError("hex", "must be an sRGB colour written \"#rrggbb\"")
    return v.lower()


# ----------------------------------------------------------------------------------------------
# the schema
# ----------------------------------------------------------------------------------------------
def _version(v: int) -> int:
    if not 1 <= v <= BALL_VERSION:
        raise PydanticCustomError("version", "must be a ball file version this stillcap reads (1)")
    return v


class TypeEntry(ClosedModel):
    """One marker type: name, shape, colour (linear or sRGB) and size (angular or metric)."""

    name: Name
    shape: Literal[SHAPES]
    color_linear: tuple[Fraction, Fraction, Fraction] = None
    color_srgb: Annotated[StrictStr, AfterValidator(_hex)] = None
    size_deg: Annotated[float, Field(strict=True, gt=0, lt=90, allow_inf_nan=False)] = None
    size_mm: Positive = None

    @model_validator(mode="after")
    def _one_each(self):
        if (self.color_linear is None) == (self.color_srgb is None):
            raise PydanticCustomError("color", "give exactly one of color_linear (linear RGB 0-1) and color_srgb "
                                      "(\"#rrggbb\")")
        if self.size_deg is not None and self.size_mm is not None:
            raise PydanticCustomError("size", "give at most one of size_deg and size_mm")
        return self


class MarkerEntry(ClosedModel):
    """One painted marker: its type and its direction (a vector, or azimuth and polar angle)."""

    type: Name
    name: Name = None
    direction: tuple[Finite, Finite, Finite] = None
    azimuth_deg: Finite = None
    polar_deg: Annotated[float, Field(strict=True, ge=0, le=180, allow_inf_nan=False)] = None

    @model_validator(mode="after")
    def _one_direction(self):
        angles = (self.azimuth_deg is not None, self.polar_deg is not None)
        if self.direction is not None:
            if any(angles):
                raise PydanticCustomError("direction", "give either direction or azimuth_deg and polar_deg, not both")
            if not math.fsum(v * v for v in self.direction) > 1e-12:
                raise PydanticCustomError("direction", "direction must be a non-zero vector")
        elif not all(angles):
            raise PydanticCustomError("direction", "give direction (a vector in the ball frame) or both azimuth_deg "
                                      "and polar_deg")
        return self


class FlightCoefficients(ClosedModel):
    """Own aerodynamic coefficients (:class:`stillcap.ball.physics.BallModel`'s)."""

    cd_table: list[tuple[Positive, Annotated[float, Field(strict=True, ge=0, le=5, allow_inf_nan=False)]]] = \
        Field(min_length=1)
    cd_spin: Finite = 0.0
    cl0: Positive = 1.0
    cl1: Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False)] = 0.0
    cl2: Finite = 1.0
    source: StrictStr = ""

    @model_validator(mode="after")
    def _increasing(self):
        re_ = [r for r, _ in self.cd_table]
        if any(b <= a for a, b in zip(re_, re_[1:])):
            raise PydanticCustomError("cd_table", "cd_table must list (Re, C_D) pairs with increasing Re")
        return self


def _preset(v: Any) -> Any:
    if isinstance(v, str) and v.strip().lower().replace("_", "-") not in BALLS:
        raise PydanticCustomError("preset", "must be a flight preset ({names}) or an object of coefficients",
                                  {"names": ", ".join(BALLS)})
    return v


class BallFile(ClosedModel):
    """A ball file's top level."""

    format: Literal["stillcap-ball"]
    version: Annotated[StrictInt, AfterValidator(_version)]
    name: Name
    description: StrictStr = ""
    radius_m: Annotated[float, Field(strict=True, gt=0, le=MAX_RADIUS_M, allow_inf_nan=False)]
    mass_kg: Annotated[float, Field(strict=True, gt=0, le=MAX_MASS_KG, allow_inf_nan=False)]
    flight: Annotated[StrictStr | FlightCoefficients, AfterValidator(_preset)] = "baseball"
    types: list[TypeEntry] = Field(min_length=1)
    markers: list[MarkerEntry] = Field(min_length=2)


# ----------------------------------------------------------------------------------------------
# the ball
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Ball:
    """A ball: name, mass, flight coefficients and painted markers (:class:`BallLayout`, which
    also holds the radius).

    Attributes
    ----------
    layout : BallLayout
    mass : float
        kg.
    flight : str or dict
        A key of :data:`stillcap.ball.physics.BALLS` (the preset's drag and lift, with this
        ball's mass and size), or own coefficients (``cd_table``, ``cd_spin``, ``cl0``, ``cl1``,
        ``cl2``: :class:`~stillcap.ball.physics.BallModel`).
    description : str
    source : str
        Where it was read from (a file, ``stillcap/data/balls/NAME.json``), or "".
    """

    layout: BallLayout
    mass: float
    flight: Any = "baseball"
    description: str = ""
    source: str = ""
    marker_names: tuple = field(default=())

    @property
    def name(self) -> str:
        return self.layout.name

    @property
    def radius(self) -> float:
        return self.layout.radius

    @property
    def flight_preset(self) -> str | None:
        """The flight preset's key, or None for own coefficients."""
        return self.flight.strip().lower().replace("_", "-") if isinstance(self.flight, str) else None

    def flight_model(self, physics: str = "seed", gravity=None):
        """The flight model of this ball.

        A ball flying as a baseball (``flight: "baseball"``) uses the pitch pipeline's baseball
        models (``physics``: ``"seed"`` or ``"nathan"``, :data:`~stillcap.ball.physics.FLIGHT_MODELS`)
        with this ball's mass and diameter; any other preset, or own coefficients, a
        :class:`~stillcap.ball.physics.BallModel` with this ball's mass and diameter
        (``physics`` is then not used).
        """
        diameter = 2.0 * self.radius
        if self.flight_preset == "baseball":
            model = flight_model(physics)
            if (model.ball.mass, model.ball.diameter) != (self.mass, diameter):
                model = replace(model, ball=BallProperties(self.mass, diameter))
            return model
        if self.flight_preset is not None:
            base = BALLS[self.flight_preset]()
        else:
            c = self.flight
            base = BallModel(self.name, self.mass, diameter, tuple(tuple(p) for p in c["cd_table"]),
                             cd_spin=c.get("cd_spin", 0.0), cl0=c.get("cl0", 1.0), cl1=c.get("cl1", 0.0),
                             cl2=c.get("cl2", 1.0), source=c.get("source", ""))
        kw = {"mass": self.mass, "diameter": diameter}
        if gravity is not None:
            kw["gravity"] = tuple(float(g) for g in gravity)
        return replace(base, **kw)

    @property
    def flight_name(self) -> str:
        """How the flight is modelled, for results: the preset's key or ``"own coefficients"``."""
        return self.flight_preset or "own coefficients"

    # -- files -----------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: Any, source: str = "ball file") -> "Ball":
        """A ball from a ball file's content; ``ValueError`` ``SOURCE: KEY.PATH: ...``."""
        if not isinstance(d, dict) or d.get("format") != BALL_FORMAT:
            got = describe(d.get("format")) if isinstance(d, dict) else f"a JSON {type(d).__name__}"
            raise ValueError(f"{source}: format: not a stillcap ball file (expected \"format\": \"{BALL_FORMAT}\", "
                             f"got {got})")
        f = validate(BallFile, d, source)
        type_names = [t.name for t in f.types]
        for i, t in enumerate(type_names):
            if t in type_names[:i]:
                raise ValueError(f"{source}: types.{i}.name: type {t!r} is listed twice")
        index = {n: i for i, n in enumerate(type_names)}
        palette, sizes = {}, []
        for i, t in enumerate(f.types):
            palette[t.name] = t.color_linear if t.color_linear is not None else srgb_to_linear(t.color_srgb)
            size = (math.radians(t.size_deg) if t.size_deg is not None
                    else t.size_mm * 1e-3 / f.radius_m if t.size_mm is not None else None)
            if size is None:
                raise ValueError(f"{source}: types.{i}: give the marker size as size_deg (angle from the marker's "
                                 "centre to its edge) or size_mm (that distance on the ball's surface)")
            if not 0 < size < math.pi / 4:
                raise ValueError(f"{source}: types.{i}: the marker size is {math.degrees(size):.1f} deg, more than "
                                 "45 deg from its centre to its edge (size_mm is measured on the ball's surface)")
            sizes.append(size)
        dirs, types, names = [], [], []
        for j, m in enumerate(f.markers):
            if m.type not in index:
                raise ValueError(f"{source}: markers.{j}.type: unknown marker type {m.type!r} "
                                 f"(types: {', '.join(type_names)})")
            types.append(index[m.type])
            if m.direction is not None:
                v = np.asarray(m.direction, float)
                dirs.append(v / np.linalg.norm(v))
            else:
                dirs.append(sphere_direction(m.azimuth_deg, m.polar_deg))
            names.append(m.name)
        unused = [n for i, n in enumerate(type_names) if i not in types]
        if unused:
            raise ValueError(f"{source}: types: type {unused[0]!r} has no marker")
        given = [n for n in names if n is not None]
        if given and len(given) != len(names):
            j = names.index(None)
            raise ValueError(f"{source}: markers.{j}.name: name every marker or none")
        if len(set(given)) != len(given):
            dup = next(n for i, n in enumerate(given) if n in given[:i])
            raise ValueError(f"{source}: markers: marker name {dup!r} is used twice")
        d_arr = np.array(dirs)
        close = np.clip(d_arr @ d_arr.T, -1, 1)
        np.fill_diagonal(close, -1)
        a, b = np.unravel_index(np.argmax(close), close.shape)
        size_of = np.array(sizes)[types]
        gap = math.degrees(math.acos(close[a, b]))
        if gap < math.degrees(size_of[a] + size_of[b]):
            raise ValueError(f"{source}: markers.{max(a, b)}: marker overlaps markers.{min(a, b)} (centres "
                             f"{gap:.1f} deg apart, sizes {math.degrees(size_of[a]):.1f} and "
                             f"{math.degrees(size_of[b]):.1f} deg)")
        same_sizes = len(set(sizes)) == 1
        try:
            layout = BallLayout(d_arr, np.array(types), tuple(type_names), tuple(t.shape for t in f.types), palette,
                                tuple(given), sizes[0] if same_sizes else max(sizes), f.radius_m,
                                () if same_sizes else tuple(sizes), f.name)
        except ValueError as e:
            raise ValueError(f"{source}: {e}") from None
        _check_colors(layout, source)
        flight = f.flight if isinstance(f.flight, str) else f.flight.model_dump()
        return cls(layout, f.mass_kg, flight, f.description, source, tuple(given))

    def to_dict(self) -> dict:
        """The ball file's content (colours as ``color_linear``, directions as vectors, sizes in
        degrees): :meth:`from_dict` gives the same ball back."""
        lay = self.layout
        types = [{"name": n, "shape": s, "color_linear": [float(c) for c in lay.palette[n]],
                  "size_deg": math.degrees(float(z))}
                 for n, s, z in zip(lay.type_names, lay.type_shapes, lay.sizes_of_types)]
        markers = []
        for j, (d, t) in enumerate(zip(lay.directions, lay.types)):
            m = {"type": lay.type_names[t], "direction": [float(v) for v in d]}
            if self.marker_names:
                m["name"] = lay.names[j]
            markers.append(m)
        return {"format": BALL_FORMAT, "version": BALL_VERSION, "name": self.name, "description": self.description,
                "radius_m": float(self.radius), "mass_kg": float(self.mass),
                "flight": self.flight if isinstance(self.flight, str) else dict(self.flight),
                "types": types, "markers": markers}

    @classmethod
    def load(cls, path) -> "Ball":
        """A ball file; ``ValueError`` naming the file (and the key path) otherwise."""
        path = Path(path)
        return cls.from_dict(read_json(path, "ball file"), str(path))

    def save(self, path) -> Path:
        """Write the ball file atomically."""
        return write_text(Path(path), json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")

    def summary(self) -> dict:
        """Name, radius, mass, flight, markers and types (``stillcap balls``)."""
        lay = self.layout
        counts = np.bincount(lay.types, minlength=lay.n_types)
        return {"name": self.name, "radius_mm": 1e3 * self.radius, "mass_g": 1e3 * self.mass,
                "flight": self.flight_name, "markers": len(lay),
                "types": [{"name": n, "shape": s, "color_srgb": linear_to_srgb_hex(lay.palette[n]),
                           "size_deg": math.degrees(float(z)), "markers": int(c)}
                          for n, s, z, c in zip(lay.type_names, lay.type_shapes, lay.sizes_of_types, counts)],
                "description": self.description, "source": self.source}


def _check_colors(layout: BallLayout, source: str) -> None:
    """Every type's paint can be told from a white ball and from the other types."""
    mts = marker_types(layout)
    hues = []
    for i, mt in enumerate(mts):
        kind, hue = marker_color_class(mt.color_bgr)
        if kind is None:
            raise ValueError(f"{source}: types.{i}: the colour {linear_to_srgb_hex(layout.palette[mt.name])} is neither "
                             "saturated nor dark: it cannot be told from a white ball")
        hues.append((kind, hue))
    for i in range(len(mts)):
        for j in range(i):
            (ki, hi), (kj, hj) = hues[i], hues[j]
            same_color = ki == kj and (ki == "dark" or abs((hi - hj + 180) % 360 - 180) < 1.0)
            if same_color and mts[i].shape == mts[j].shape:
                raise ValueError(f"{source}: types.{i}: same colour and shape as types.{j} ({mts[j].name!r}): the "
                                 "detector cannot tell them apart")
            if ki == kj == "chromatic" and not same_color and abs((hi - hj + 180) % 360 - 180) < MIN_HUE_GAP_DEG:
                raise ValueError(f"{source}: types.{i}: hue {hi:.0f} deg is within {MIN_HUE_GAP_DEG:.0f} deg of "
                                 f"types.{j}'s ({hj:.0f} deg): the detector would take one for the other")


# ----------------------------------------------------------------------------------------------
# built-in balls and how a ball is named
# ----------------------------------------------------------------------------------------------
def builtin_ball_names() -> tuple:
    """Names of the balls shipped in ``stillcap/data/balls``."""
    files = resources.files("stillcap").joinpath("data", "balls")
    return tuple(sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".json")))


def builtin_ball(name: str) -> Ball:
    """A built-in ball by name (:func:`builtin_ball_names`)."""
    names = builtin_ball_names()
    if name not in names:
        raise ValueError(f"unknown ball {name!r}; built-in balls: {', '.join(names)} (or give a ball file)")
    text = resources.files("stillcap").joinpath("data", "balls", f"{name}.json").read_text(encoding="utf-8")
    return Ball.from_dict(json.loads(text), f"stillcap/data/balls/{name}.json")


def load_ball(spec: str | Path, what: str = "--ball") -> Ball:
    """A ball from a built-in name or a ball file's path (a path that exists, or ends in
    ``.json``, is a file)."""
    s = str(spec)
    p = Path(s)
    if p.is_file() or s.endswith(".json") or "/" in s or "\\" in s:
        if not p.is_file():
            raise ValueError(f"{what}: ball file {p} does not exist")
        return Ball.load(p)
    if s in builtin_ball_names():
        return builtin_ball(s)
    raise ValueError(f"{what}: {s!r} is neither a built-in ball ({', '.join(builtin_ball_names())}) nor a ball file")


def resolve_ball(spec, folder=None, what: str = "ball") -> Ball:
    """A ball from a capture's ``ball`` value: a built-in name, a path inside ``folder`` (kept
    inside it: :func:`stillcap.files.paths.resolve_inside`), or an embedded ball file object."""
    from stillcap.files.paths import resolve_inside

    if isinstance(spec, Ball):
        return spec
    if isinstance(spec, dict):
        return Ball.from_dict(spec, what)
    s = str(spec)
    if s in builtin_ball_names() and not s.endswith(".json"):
        return builtin_ball(s)
    if folder is None:
        return load_ball(s, what)
    p = resolve_inside(folder, s, what, "capture folder")
    if not p.is_file():
        raise ValueError(f"{what}: {s!r} is neither a built-in ball ({', '.join(builtin_ball_names())}) nor a "
                         f"ball file in the capture folder")
    return Ball.load(p)
