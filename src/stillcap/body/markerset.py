"""Marker sets (markers attached to bones, their colours, bone-direction rules) and marker
trajectories (labelled 3D markers over frames).

A marker is rigidly attached to a bone. Its offset is given in the *bone frame*: origin at the
bone's start joint (the parent of the joint that names the bone), axes of that joint's frame,
which moves the bone. At rest all joint frames are parallel to the skeleton frame, so offsets
read like puppet-frame vectors from the bone's start joint. See ``docs/skeleton.md``.

Bone rules say how the direction of a bone is measured (SPEC J3, thesis section 6.3):

- ``{"bone": B, "from": m1, "to": m2}``: direction of ``m2 - m1``;
- ``{"bone": B, "copy": C}``: the direction of bone C (fingers copy the lower arm);
- ``{"bone": B, "cross": C, "axis": v}``: ``normalised(direction(C) x v)`` with ``v`` in the
  root frame (toes: lower leg x (1, 0, 0); shoulders: upper back x (0, 0, +-1)).
"""

from __future__ import annotations

import colorsys
import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Literal, Sequence

import numpy as np
from pydantic import Field

from stillcap._checks import as_array
from stillcap.body.skeleton import LENGTH_UNITS, Animation, Pose, Skeleton
from stillcap.files.atomic import write_text
from stillcap.files.jsonfile import read_json, read_package_json
from stillcap.files.schema import Coordinate, Fraction, Model, Name, PositiveCount, Vec3, validate

__all__ = ["BUILTIN_MARKERSETS", "PUPPET_MARKERSETS", "BoneRule", "Marker", "MarkerSet", "MarkerTrajectories"]

_FORMAT = "stillcap-markerset"

#: The puppet's marker sets shipped with stillcap: name -> file in ``stillcap/data``.
PUPPET_MARKERSETS = {"puppet-16": "puppet_markers.json", "puppet-20": "puppet_markers_20.json"}
#: Marker sets shipped with stillcap that :meth:`MarkerSet.builtin` loads by name (the hand's
#: glove markers come with their own colour groups: :func:`stillcap.body.hand.hand_markers`).
BUILTIN_MARKERSETS = dict(PUPPET_MARKERSETS)


class MarkerEntry(Model):
    """One entry of a marker-set file's ``markers`` (``docs/skeleton.md``)."""

    name: Name
    bone: Name
    offset: Vec3
    hsb: tuple[Fraction, Fraction, Fraction] = (0.0, 0.0, 1.0)
    rgb: tuple[Fraction, Fraction, Fraction] | None = None
    diameter: Coordinate | None = Field(None, gt=0)


class BoneRuleEntry(Model):
    """One entry of a marker-set file's ``bone_rules``."""

    bone: Name
    from_: Name | None = Field(None, alias="from")
    to: Name | None = None
    copy_: Name | None = Field(None, alias="copy")
    cross: Name | None = None
    axis: Vec3 | None = None
    primary: bool = Field(False, strict=True)


class MarkerSetFile(Model):
    """A marker-set file (``stillcap-markerset``): the schema checked on load."""

    format: Literal["stillcap-markerset"] = _FORMAT
    version: PositiveCount = 1
    name: str = "markers"
    skeleton: str | None = None
    length_unit: Literal["m", "cm", "mm"] = "m"
    markers: list[MarkerEntry] = []
    bone_rules: list[BoneRuleEntry] = []


@dataclass(frozen=True, eq=False)
class Marker:
    """One marker.

    Parameters
    ----------
    name : str
    bone : str
        Name of the bone (= the joint at its end) the marker is attached to.
    offset : array_like, shape (3,)
        Marker centre in the bone frame, metres.
    hsb : array_like, shape (3,)
        Reference colour, hue / saturation / brightness in [0, 1] (hue in turns).
    diameter : float
        Bead diameter, metres.
    """

    name: str
    bone: str
    offset: np.ndarray
    hsb: tuple[float, float, float] = (0.0, 0.0, 1.0)
    diameter: float = 0.006

    def __post_init__(self):
        object.__setattr__(self, "offset", as_array(self.offset, (3,), f"offset of marker {self.name!r}"))
        hsb = as_array(self.hsb, (3,), f"hsb of marker {self.name!r}")
        if (hsb < 0).any() or (hsb > 1).any():
            raise ValueError(f"hsb of marker {self.name!r} must lie in [0, 1], got {hsb.tolist()}")
        object.__setattr__(self, "hsb", tuple(float(v) for v in hsb))
        if not float(self.diameter) > 0:
            raise ValueError(f"diameter of marker {self.name!r} must be > 0, got {self.diameter}")

    @property
    def rgb(self) -> tuple[float, float, float]:
        """The reference colour as sRGB in [0, 1]."""
        return colorsys.hsv_to_rgb(*self.hsb)

    @property
    def rgb8(self) -> tuple[int, int, int]:
        """The reference colour as 8-bit sRGB."""
        return tuple(int(round(255 * v)) for v in self.rgb)


@dataclass(frozen=True)
class BoneRule:
    """How the direction of one bone follows from markers (see the module docstring).

    Exactly one of (``start``, ``end``), ``copy`` or (``cross``, ``axis``) is set. A
    ``primary`` rule is matched exactly when several bones start at one joint (the puppet's
    shoulder line, so that the head only nods about it).
    """

    bone: str
    start: str | None = None
    end: str | None = None
    copy: str | None = None
    cross: str | None = None
    axis: tuple[float, float, float] | None = None
    primary: bool = False

    def __post_init__(self):
        kinds = [self.start is not None and self.end is not None, self.copy is not None, self.cross is not None]
        if sum(kinds) != 1:
            raise ValueError(f"bone rule for {self.bone!r} needs exactly one of from/to, copy, cross+axis")
        if self.cross is not None:
            if self.axis is None:
                raise ValueError(f"bone rule for {self.bone!r}: 'cross' needs an 'axis'")
            object.__setattr__(self, "axis", tuple(float(v) for v in as_array(self.axis, (3,), "axis")))

    @property
    def kind(self) -> str:
        return "markers" if self.start is not None else "copy" if self.copy is not None else "cross"

    def to_dict(self) -> dict:
        if self.kind == "markers":
            d = {"bone": self.bone, "from": self.start, "to": self.end}
        elif self.kind == "copy":
            d = {"bone": self.bone, "copy": self.copy}
        else:
            d = {"bone": self.bone, "cross": self.cross, "axis": list(self.axis)}
        if self.primary:
            d["primary"] = True
        return d


@dataclass(frozen=True, eq=False)
class MarkerSet:
    """Markers on a skeleton plus the rules that turn them into bone directions.

    Parameters
    ----------
    markers : sequence of Marker
    rules : sequence of BoneRule
        In an order where every ``copy``/``cross`` source comes before its use.
    name : str
    skeleton_name : str
        Name of the skeleton the bones refer to (informational).
    source : str
        Where it came from, for error messages.
    """

    markers: tuple[Marker, ...]
    rules: tuple[BoneRule, ...] = ()
    name: str = "markers"
    skeleton_name: str | None = None
    source: str = field(default="<markerset>", compare=False)

    def __post_init__(self):
        object.__setattr__(self, "markers", tuple(self.markers))
        object.__setattr__(self, "rules", tuple(self.rules))
        where = f" in {self.source}"
        seen: set[str] = set()
        for m in self.markers:
            if m.name in seen:
                raise ValueError(f"duplicate marker name {m.name!r}{where}")
            seen.add(m.name)
        bones: set[str] = set()
        for r in self.rules:
            if r.bone in bones:
                raise ValueError(f"two bone rules for bone {r.bone!r}{where}")
            for ref in (r.start, r.end):
                if ref is not None and ref not in seen:
                    raise ValueError(f"bone rule for {r.bone!r} names unknown marker {ref!r}{where}")
            src = r.copy or r.cross
            if src is not None and src not in bones:
                raise ValueError(f"bone rule for {r.bone!r} uses bone {src!r} before a rule defines it{where}")
            bones.add(r.bone)

    @cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.markers)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown marker {name!r}; known: {', '.join(self.names)}") from None

    def __len__(self) -> int:
        return len(self.markers)

    @property
    def offsets(self) -> np.ndarray:
        """Marker offsets in their bone frames, shape (n_markers, 3), metres."""
        return np.array([m.offset for m in self.markers])

    @property
    def rgb(self) -> np.ndarray:
        """Reference colours as sRGB in [0, 1], shape (n_markers, 3)."""
        return np.array([m.rgb for m in self.markers])

    @property
    def hsb(self) -> np.ndarray:
        """Reference colours as HSB in [0, 1], shape (n_markers, 3)."""
        return np.array([m.hsb for m in self.markers])

    def check_skeleton(self, skeleton: Skeleton) -> None:
        """ValueError if a marker or rule names a bone the skeleton lacks (or its root)."""
        def bones() -> str:
            return ", ".join(n for n in skeleton.names if n != skeleton.names[skeleton.root])

        for k, m in enumerate(self.markers):
            if m.bone not in skeleton or skeleton.index(m.bone) == skeleton.root:
                raise ValueError(f"{self.source}: markers.{k}.bone: marker {m.name!r} is on bone {m.bone!r}, which "
                                 f"skeleton {skeleton.name!r} lacks (bones: {bones()})")
        for k, r in enumerate(self.rules):
            for key, b in (("bone", r.bone), ("copy", r.copy), ("cross", r.cross)):
                if b is not None and (b not in skeleton or skeleton.index(b) == skeleton.root):
                    raise ValueError(f"{self.source}: bone_rules.{k}.{key}: bone rule names bone {b!r}, which "
                                     f"skeleton {skeleton.name!r} lacks (bones: {bones()})")

    def bone_frames(self, skeleton: Skeleton) -> np.ndarray:
        """Index of the joint whose frame carries each marker (its bone's start joint), shape (n_markers,).

        Kept for the last skeleton asked about (both are immutable; the puppet's pose fit and
        its checks ask ~10 times per capture, ~0.1 ms each): a new array each call."""
        last = self.__dict__.get("_bone_frames")
        if last is None or last[0] is not skeleton:
            self.check_skeleton(skeleton)
            last = (skeleton, np.array([skeleton.parents[skeleton.index(m.bone)] for m in self.markers], dtype=int))
            self.__dict__["_bone_frames"] = last
        return last[1].copy()

    def positions(self, pose: Pose | Animation) -> np.ndarray:
        """World positions of the markers in a pose or animation.

        Returns
        -------
        ndarray, shape (n_markers, 3) for a Pose or (n_frames, n_markers, 3) for an Animation, metres.
        """
        frames = self.bone_frames(pose.skeleton)
        j2w = pose.joint2world[..., frames, :, :]
        return np.einsum("...mij,mj->...mi", j2w[..., :3, :3], self.offsets) + j2w[..., :3, 3]

    def trajectories(self, animation: Animation) -> "MarkerTrajectories":
        """Marker trajectories of an animation with uniform times (for synthetic data)."""
        rate = animation.frame_rate
        if rate is None:
            raise ValueError("trajectories need an animation with uniformly spaced times (a frame rate)")
        return MarkerTrajectories(self.names, self.positions(animation), rate, start_time=float(animation.times[0]))

    # -- files -----------------------------------------------------------------------------
    def to_dict(self, length_unit: str = "m") -> dict:
        """A JSON-ready dict (see ``docs/skeleton.md``), lengths in ``length_unit``."""
        if length_unit not in LENGTH_UNITS:
            raise ValueError(f"length_unit must be one of {sorted(LENGTH_UNITS)}, got {length_unit!r}")
        s = LENGTH_UNITS[length_unit]
        markers = [
            {
                "name": m.name,
                "bone": m.bone,
                "offset": [float(f"{v / s:.10g}") for v in m.offset],
                "diameter": float(f"{m.diameter / s:.10g}"),
                "hsb": list(m.hsb),
                "rgb": [round(v, 4) for v in m.rgb],
            }
            for m in self.markers
        ]
        out = {"format": _FORMAT, "version": 1, "name": self.name}
        if self.skeleton_name is not None:
            out["skeleton"] = self.skeleton_name
        out.update(length_unit=length_unit, markers=markers, bone_rules=[r.to_dict() for r in self.rules])
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "<dict>", prefix: tuple = ()) -> "MarkerSet":
        """Build a marker set from :meth:`to_dict` output; ValueError naming ``source`` and the
        key path on bad data (``prefix``: the key path of ``data`` inside its file)."""
        if not isinstance(data, dict) or data.get("format", _FORMAT) != _FORMAT:
            raise ValueError(f"{source}: {'.'.join(map(str, prefix)) or '(the whole file)'}: not a marker-set "
                             f"file (expected format {_FORMAT!r})")
        f = validate(MarkerSetFile, data, source, prefix)
        s = LENGTH_UNITS[f.length_unit]

        def at(*keys) -> str:
            return f"{source}: {'.'.join(str(k) for k in (*prefix, *keys))}"

        markers = []
        for k, d in enumerate(f.markers):
            diameter = 0.006 if d.diameter is None else d.diameter * s
            m = Marker(name=d.name, bone=d.bone, offset=np.asarray(d.offset, float) * s, hsb=d.hsb, diameter=diameter)
            if d.rgb is not None and np.abs(np.asarray(d.rgb, float) - m.rgb).max() > 0.01:
                raise ValueError(f"{at('markers', k, 'rgb')}: marker {d.name!r}: rgb {list(d.rgb)} disagrees with "
                                 f"hsb {list(m.hsb)} (as rgb {[round(v, 4) for v in m.rgb]})")
            if d.name in (x.name for x in markers):
                raise ValueError(f"{at('markers', k, 'name')}: duplicate marker name {d.name!r}")
            markers.append(m)
        names = {m.name for m in markers}
        rules, defined = [], set()
        for k, d in enumerate(f.bone_rules):
            kinds = [d.from_ is not None and d.to is not None, d.copy_ is not None, d.cross is not None]
            if sum(kinds) != 1 or (d.from_ is None) != (d.to is None):
                raise ValueError(f"{at('bone_rules', k)}: bone rule for {d.bone!r} needs exactly one of from/to, "
                                 "copy, cross+axis")
            if d.bone in defined:
                raise ValueError(f"{at('bone_rules', k, 'bone')}: two bone rules for bone {d.bone!r}")
            for key, ref in (("from", d.from_), ("to", d.to)):
                if ref is not None and ref not in names:
                    raise ValueError(f"{at('bone_rules', k, key)}: bone rule for {d.bone!r} names unknown marker "
                                     f"{ref!r}")
            for key, src in (("copy", d.copy_), ("cross", d.cross)):
                if src is not None and src not in defined:
                    raise ValueError(f"{at('bone_rules', k, key)}: bone rule for {d.bone!r} uses bone {src!r} "
                                     "before a rule defines it")
            if d.cross is not None and (d.axis is None or not any(d.axis)):
                raise ValueError(f"{at('bone_rules', k, 'axis')}: bone rule for {d.bone!r}: 'cross' needs a "
                                 f"non-zero 'axis' [x, y, z] (got {d.axis})")
            defined.add(d.bone)
            rules.append(BoneRule(d.bone, d.from_, d.to, d.copy_, d.cross, d.axis, d.primary))
        return cls(tuple(markers), tuple(rules), f.name, f.skeleton, source)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "MarkerSet":
        """Read a marker-set JSON file."""
        return cls.from_dict(read_json(path), source=str(path))

    def save(self, path: str | os.PathLike, length_unit: str = "m") -> Path:
        """Write the marker set as JSON (atomically); return the path."""
        return write_text(path, json.dumps(self.to_dict(length_unit), indent=1) + "\n")

    @classmethod
    def puppet(cls, name: str = "puppet-16") -> "MarkerSet":
        """A bead marker set of :meth:`Skeleton.puppet` shipped with stillcap.

        Parameters
        ----------
        name : {"puppet-16", "puppet-20"}
            ``"puppet-16"`` (default): the thesis's 16 beads (``data/puppet_markers.json``);
            ``"puppet-20"``: those 16 plus a second bead on each forearm and shin
            (``data/puppet_markers_20.json``), so that every joint frame with a bead carries
            two and its twist is measured (``docs/puppet.md``).
        """
        if name not in PUPPET_MARKERSETS:
            raise ValueError(f"unknown puppet marker set {name!r}; built-in: {', '.join(PUPPET_MARKERSETS)}")
        return cls.builtin(name)

    @classmethod
    def builtin(cls, name: str) -> "MarkerSet":
        """A marker set shipped with stillcap, by name (:data:`BUILTIN_MARKERSETS`)."""
        if name not in BUILTIN_MARKERSETS:
            raise ValueError(f"unknown built-in marker set {name!r}; built-in: {', '.join(BUILTIN_MARKERSETS)}")
        data, source = read_package_json(BUILTIN_MARKERSETS[name])
        return cls.from_dict(data, source=source)

    @classmethod
    def resolve(cls, spec: "MarkerSet | str | os.PathLike | dict | None", default: str = "puppet-16") -> "MarkerSet":
        """A marker set from whatever names one: a :class:`MarkerSet` (returned as is), a built-in
        name (``"puppet-16"``, ``"puppet-20"``), the path of a marker-set JSON file,
        a :meth:`to_dict` dict, or None for ``default``.

        A string is a built-in name if it is one, else a file path; ValueError if neither.
        """
        if spec is None:
            spec = default
        if isinstance(spec, MarkerSet):
            return spec
        if isinstance(spec, dict):
            return cls.from_dict(spec, source="<embedded marker set>")
        if isinstance(spec, str) and spec in BUILTIN_MARKERSETS:
            return cls.builtin(spec)
        if isinstance(spec, (str, os.PathLike)):
            path = Path(spec)
            if not path.is_file():
                raise ValueError(f"marker set {str(spec)!r} is neither a built-in ({', '.join(BUILTIN_MARKERSETS)}) "
                                 "nor an existing file")
            return cls.load(path)
        raise ValueError(f"a marker set must be a MarkerSet, a built-in name, a file or a dict, got {type(spec).__name__}")

    def builtin_name(self) -> str | None:
        """The name of the built-in marker set this one equals (same content), or None."""
        d = self.to_dict()
        for name in BUILTIN_MARKERSETS:
            if name == self.name and MarkerSet.builtin(name).to_dict() == d:
                return name
        return None


@dataclass(eq=False)
class MarkerTrajectories:
    """Labelled 3D marker positions over frames.

    Parameters
    ----------
    names : sequence of str, length n_markers
    points : array_like, shape (n_frames, n_markers, 3)
        World positions, metres; NaN where a marker was not seen.
    frame_rate : float
        Frames per second.
    start_time : float
        Time of frame 0, seconds.
    residuals : array_like, shape (n_frames, n_markers), optional
        Reconstruction residual per point, metres (e.g. RMS distance to the rays); NaN where unseen.
    """

    names: tuple[str, ...]
    points: np.ndarray
    frame_rate: float
    start_time: float = 0.0
    residuals: np.ndarray | None = None

    def __post_init__(self):
        self.names = tuple(str(n) for n in self.names)
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"marker names must be unique, got {list(self.names)}")
        self.points = as_array(self.points, (None, len(self.names), 3), "points")
        if not (np.isfinite(self.frame_rate) and self.frame_rate > 0):
            raise ValueError(f"frame_rate must be > 0 (Hz), got {self.frame_rate}")
        self.frame_rate = float(self.frame_rate)
        if self.residuals is not None:
            self.residuals = as_array(self.residuals, self.points.shape[:2], "residuals")

    @classmethod
    def single(cls, names: Sequence[str], points, frame_rate: float = 1.0) -> "MarkerTrajectories":
        """One frame of markers, ``points`` shape (n_markers, 3), metres."""
        pts = as_array(points, (len(names), 3), "points")
        return cls(tuple(names), pts[None], frame_rate)

    @property
    def n_frames(self) -> int:
        return self.points.shape[0]

    @property
    def n_markers(self) -> int:
        return self.points.shape[1]

    @property
    def times(self) -> np.ndarray:
        """Frame times, shape (n_frames,), seconds."""
        return self.start_time + np.arange(self.n_frames) / self.frame_rate

    @property
    def seen(self) -> np.ndarray:
        """Whether each marker was seen, shape (n_frames, n_markers)."""
        return np.all(np.isfinite(self.points), axis=-1)
