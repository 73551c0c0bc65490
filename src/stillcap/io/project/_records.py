"""The records of a puppet project file: its constants, :class:`TurntableSetup`, :class:`Edit`,
:class:`View` and :class:`Markers3D`, and :func:`dumps_json` (the file's layout for people)."""

from __future__ import annotations

import functools
import json
import math
import re
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from stillcap.body.markerset import BUILTIN_MARKERSETS as _MARKERSET_NAMES
from stillcap.body.markerset import MarkerSet
from stillcap.calibrate.turntable import THESIS_CX, THESIS_CY, THESIS_FX, THESIS_FY, turntable_world2cam
from stillcap.camera import Camera
from stillcap.geometry.triangulate import Triangulation
from stillcap.files.paths import safe_relpath
from stillcap.files.schema import MAX_COORDINATE, ClosedModel, Finite, Name, PositiveCount, Positive

PROJECT_FORMAT = "stillcap-puppet-project"
PROJECT_VERSION = 1
PROJECT_FILE = "project.json"
PHOTOS_DIR = "photos"
UNITS = {"angle": "deg", "pixel": "px", "length": "m"}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

#: A turn angle in degrees (finite; beyond a million degrees is a typing error).
_Angle = Annotated[float, Field(strict=True, ge=-MAX_COORDINATE, le=MAX_COORDINATE, allow_inf_nan=False)]


class EditEntry(ClosedModel):
    """One entry of a view's ``edits``."""

    op: Literal["delete", "relabel", "move"]
    marker: Name
    to: Name | None = None
    xy: tuple[Finite, Finite] | None = None


class ViewEntry(ClosedModel):
    """One entry of ``views`` (paths and markers are checked against the project after this)."""

    name: Name
    image: str
    processed: str | None = None
    angle_deg: _Angle | None = None
    camera: Name | None = None
    detected: dict[str, tuple[Finite, Finite]] = {}
    edits: list[EditEntry] = []


class TurntableEntry(ClosedModel):
    """``turntable``: lengths carry their unit (the camera is read as a rig camera)."""

    distance_m: Positive
    height_m: Finite
    camera: dict[str, Any]


class ProjectFile(ClosedModel):
    """``project.json``: the schema checked on load, before the project's own rules (paths inside
    the folder, known markers and cameras, positions inside the photos)."""

    format: Literal["stillcap-puppet-project"]
    version: PositiveCount
    name: str | None = None
    units: dict[str, str] = {}
    markerset: Any = "puppet-16"
    skeleton: Any = None
    turntable: TurntableEntry | None = None
    rig: dict[str, Any] | None = None
    views: list[ViewEntry] = []
    meta: dict[str, Any] = {}

#: Marker sets shipped with stillcap, by the name a project file may use: name -> a function
#: making it (every :data:`stillcap.body.markerset.BUILTIN_MARKERSETS` entry, via :meth:`MarkerSet.builtin`).
BUILTIN_MARKERSETS = {name: functools.partial(MarkerSet.builtin, name) for name in _MARKERSET_NAMES}


def dumps_json(obj, indent: int = 0, step: int = 1) -> str:
    """Strict JSON (no NaN) laid out for people: flat objects and lists of numbers on one line.

    ``json.dumps(indent=...)`` puts every number of every pixel position on its own line,
    which makes project files hard to read and diff; the text parses to the same data.
    """
    def flat(v):
        if isinstance(v, dict):
            return False
        return not isinstance(v, list) or all(not isinstance(e, (dict, list)) for e in v)

    pad, inner = " " * indent, " " * (indent + step)
    if isinstance(obj, dict):
        if all(flat(v) for v in obj.values()) and len(obj) <= 4:
            return json.dumps(obj, allow_nan=False)
        body = ",\n".join(f"{inner}{json.dumps(str(k))}: {dumps_json(v, indent + step, step)}" for k, v in obj.items())
        return f"{{\n{body}\n{pad}}}"
    if isinstance(obj, list):
        if flat(obj):
            return json.dumps(obj, allow_nan=False)
        body = ",\n".join(f"{inner}{dumps_json(v, indent + step, step)}" for v in obj)
        return f"[\n{body}\n{pad}]"
    return json.dumps(obj, allow_nan=False)


def _format_angle(angle_deg: float) -> str:
    return f"turn_{angle_deg:05.1f}deg"


def _file_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._+-]", "_", name).strip(".") or "view"


def _same_angle(a: float, b: float) -> bool:
    d = (a - b) % 360.0
    return min(d, 360.0 - d) < 1e-9


def _check_xy(xy, size, what: str) -> tuple[float, float]:
    """A finite pixel ``(x, y)`` inside an image of ``size = (w, h)``."""
    try:
        a = np.asarray(xy, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: position must be [x, y] in pixels, got {xy!r}") from None
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: position must be two finite numbers [x, y] in pixels, got {xy!r}")
    w, h = size
    x, y = float(a[0]), float(a[1])
    if not (-0.5 <= x <= w - 0.5 and -0.5 <= y <= h - 0.5):
        raise ValueError(f"{what}: position ({x:g}, {y:g}) px is outside the {w}x{h} px image")
    return x, y


# --- turntable ----------------------------------------------------------------------------
@dataclass
class TurntableSetup:
    """One camera and a turntable (SPEC J3): the photo at turn angle ``a`` is a camera on a circle.

    Parameters
    ----------
    camera : Camera
        Intrinsics, distortion and image size (its pose is ignored).
    distance : float
        Camera centre to the turn axis, metres (thesis: 0.400).
    height : float
        Lens centre above the platform, metres (thesis: 0.080).
    """

    camera: Camera = field(default_factory=lambda: Camera.from_intrinsics(
        "webcam", THESIS_FX, THESIS_FY, THESIS_CX, THESIS_CY, (640, 480)))
    distance: float = 0.400
    height: float = 0.080

    def __post_init__(self):
        if not isinstance(self.camera, Camera):
            raise ValueError(f"turntable camera must be a Camera, got {type(self.camera).__name__}")
        for k in ("distance", "height"):
            v = float(getattr(self, k))
            if not math.isfinite(v) or (k == "distance" and v <= 0):
                raise ValueError(f"turntable {k} must be a finite number of metres"
                                 f"{' > 0' if k == 'distance' else ''}, got {v}")
            setattr(self, k, v)

    def camera_at(self, angle_deg: float, name: str | None = None) -> Camera:
        """The virtual camera of the photo taken at turn angle ``angle_deg`` (degrees)."""
        c = self.camera
        return Camera(name or _format_angle(angle_deg), c.K, c.dist,
                      turntable_world2cam(math.radians(angle_deg), self.distance, self.height), c.image_size,
                      c.response)

    def to_dict(self) -> dict:
        cam = self.camera.to_dict()
        cam.pop("world2cam")
        return {"distance_m": self.distance, "height_m": self.height, "camera": cam}

    @classmethod
    def from_dict(cls, d: dict, where: str = "") -> TurntableSetup:
        if not isinstance(d, dict):
            raise ValueError(f"{where}turntable must be an object, got {type(d).__name__}")
        unknown = set(d) - {"distance_m", "height_m", "camera"}
        if unknown:
            raise ValueError(f"{where}turntable has unknown keys {sorted(unknown)} "
                             "(lengths carry their unit: distance_m, height_m)")
        for k in ("distance_m", "height_m", "camera"):
            if k not in d:
                raise ValueError(f"{where}turntable is missing the key {k!r}")
        try:
            return cls(Camera.from_dict(d["camera"], f"{where}turntable camera: "), d["distance_m"], d["height_m"])
        except (TypeError, ValueError) as e:
            raise ValueError(f"{where}turntable: {e}") from None


# --- views and edits ----------------------------------------------------------------------
@dataclass
class Edit:
    """One manual correction of a view's markers.

    Parameters
    ----------
    op : {"delete", "relabel", "move"}
        ``delete``: remove ``marker``; ``relabel``: the point called ``marker`` is really ``to``
        (it replaces a point already called ``to``); ``move``: put ``marker`` at ``xy``
        (adds it if absent).
    marker : str
    to : str, optional
        New name (``relabel``).
    xy : (float, float), optional
        Pixel position (``move``).
    """

    op: str
    marker: str
    to: str | None = None
    xy: tuple[float, float] | None = None

    def __post_init__(self):
        if self.op not in ("delete", "relabel", "move"):
            raise ValueError(f"edit op must be 'delete', 'relabel' or 'move', got {self.op!r}")
        if not isinstance(self.marker, str) or not self.marker:
            raise ValueError(f"{self.op} edit needs a marker name, got {self.marker!r}")
        if (self.op == "relabel") != (self.to is not None):
            raise ValueError(f"{self.op} edit of {self.marker!r}: 'to' is for relabel edits only and required there")
        if (self.op == "move") != (self.xy is not None):
            raise ValueError(f"{self.op} edit of {self.marker!r}: 'xy' is for move edits only and required there")
        if self.xy is not None:
            a = np.asarray(self.xy, dtype=float)
            if a.shape != (2,) or not np.all(np.isfinite(a)):
                raise ValueError(f"move edit of {self.marker!r}: xy must be two finite numbers, got {self.xy!r}")
            self.xy = (float(a[0]), float(a[1]))

    def apply(self, markers: dict) -> None:
        """Apply the edit to ``{name: (x, y)}`` in place (an edit of an absent marker does nothing)."""
        if self.op == "delete":
            markers.pop(self.marker, None)
        elif self.op == "relabel":
            if self.marker in markers:
                markers[self.to] = markers.pop(self.marker)
        else:
            markers[self.marker] = self.xy

    def to_dict(self) -> dict:
        d = {"op": self.op, "marker": self.marker}
        if self.to is not None:
            d["to"] = self.to
        if self.xy is not None:
            d["xy"] = list(self.xy)
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "") -> Edit:
        if not isinstance(d, dict):
            raise ValueError(f"{where}edit must be an object, got {type(d).__name__}")
        unknown = set(d) - {"op", "marker", "to", "xy"}
        if unknown:
            raise ValueError(f"{where}edit has unknown keys {sorted(unknown)}")
        try:
            return cls(d.get("op"), d.get("marker"), d.get("to"), d.get("xy"))
        except (TypeError, ValueError) as e:
            raise ValueError(f"{where}{e}") from None


@dataclass
class View:
    """One photo of the project.

    Parameters
    ----------
    name : str
        Unique name; also the name of the view's camera in :meth:`Project.observations`.
    image : str
        Photo, relative to the project folder (POSIX separators).
    angle_deg : float, optional
        Turn angle in degrees (turntable projects).
    camera : str, optional
        Rig camera that took the photo (rig projects).
    detected : dict
        Automatic detections ``{marker: (x, y)}``, pixels.
    edits : list of Edit
        Manual corrections, applied in order on top of ``detected``.
    processed : str, optional
        Processed photo (thesis: the outlined image with the found circles), relative path.
    """

    name: str
    image: str
    angle_deg: float | None = None
    camera: str | None = None
    detected: dict = field(default_factory=dict)
    edits: list = field(default_factory=list)
    processed: str | None = None

    @property
    def markers(self) -> dict[str, tuple[float, float]]:
        """The effective markers: ``detected`` with ``edits`` applied, ``{name: (x, y)}`` in pixels."""
        out = dict(self.detected)
        for e in self.edits:
            e.apply(out)
        return out

    def to_dict(self) -> dict:
        d = {"name": self.name, "image": self.image}
        if self.processed is not None:
            d["processed"] = self.processed
        if self.angle_deg is not None:
            d["angle_deg"] = self.angle_deg
        if self.camera is not None:
            d["camera"] = self.camera
        d["detected"] = {k: [x, y] for k, (x, y) in self.detected.items()}
        d["edits"] = [e.to_dict() for e in self.edits]
        return d


@dataclass
class Markers3D:
    """3D markers of a project (:meth:`Project.reconstruct`).

    Attributes
    ----------
    names : tuple of str, length n_markers
        Marker-set order.
    points : ndarray, shape (n_markers, 3)
        Positions in the rig world (puppet frame for turntables), metres; NaN for missing markers.
    n_views : ndarray of int, shape (n_markers,)
        Views used per marker.
    reproj_error_px : ndarray, shape (n_markers,)
        RMS reprojection error, pixels; NaN for missing markers.
    missing : tuple of str
        Markers identified in fewer than two views (or not triangulable): no 3D position.
    triangulation : Triangulation
        The full result (per-view errors, views used).
    """

    names: tuple[str, ...]
    points: np.ndarray
    n_views: np.ndarray
    reproj_error_px: np.ndarray
    missing: tuple[str, ...]
    triangulation: Triangulation

    @property
    def points_mm(self) -> np.ndarray:
        """Positions in millimetres (the thesis's unit), shape (n_markers, 3)."""
        return self.points * 1000.0

    @property
    def ok(self) -> np.ndarray:
        """Markers with a 3D position, shape (n_markers,) bool."""
        return np.all(np.isfinite(self.points), axis=1)

    def as_dict(self) -> dict[str, tuple[float, float, float] | None]:
        """``{name: (x, y, z) in metres or None if missing}``."""
        return {n: (tuple(float(v) for v in p) if ok else None) for n, p, ok in zip(self.names, self.points, self.ok)}


def _view_from_entry(d: ViewEntry, where: str, i: int) -> View:
    """A :class:`View` from a validated ``views`` entry (its paths made safe)."""
    at = f"{where}views.{i} (view {d.name!r}): "
    image = safe_relpath(d.image, f"{where}view {d.name!r}: image")
    processed = safe_relpath(d.processed, f"{where}view {d.name!r}: processed") if d.processed is not None else None
    edits = []
    for k, e in enumerate(d.edits):
        try:
            edits.append(Edit(e.op, e.marker, e.to, e.xy))
        except ValueError as err:
            raise ValueError(f"{at}edits.{k}: {err}") from None
    detected = {k: (float(x), float(y)) for k, (x, y) in d.detected.items()}
    return View(d.name, image, d.angle_deg, d.camera, detected, edits, processed)
