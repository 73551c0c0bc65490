"""The schema of ``capture.json`` (``docs/capture-folder.md``): pydantic models of the file's top
level, its image entries and the capture-wide keys stillcap reads, checked through
:func:`stillcap.files.schema.validate` so that every problem is one line
``capture.json: KEY.PATH: what was expected (got VALUE)``.

What the schema cannot see alone (an image's camera is in the rig, paths stay inside the folder,
the photos' headers) :meth:`stillcap.io.capture.Capture.load` checks after it.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, StrictBool, StrictInt, StrictStr
from pydantic_core import PydanticCustomError

from stillcap.files.schema import Model, describe, key_step, validate

CAPTURE_FORMAT = "stillcap-capture"
CAPTURE_VERSION = 1
#: What a capture folder may hold (``kind``).
KINDS = ("chessboard", "charuco", "calibration-object", "rig-boards", "markers", "pitch", "hand", "puppet")
UNITS = {"length": "m", "time": "s", "frequency": "Hz", "angle": "rad"}
TIMING = ("strobe_hz", "shutter_s", "first_flash_s", "n_flashes")
#: Limits of the numbers of ``capture.json``.
MAX_STROBE_HZ = 1e6
MAX_SECONDS = 3600.0  # shutter_s, first_flash_s
MAX_FLASHES = 100_000  # n_flashes
MAX_INDEX = 1_000_000  # images[].meta.view, .instant; calibration spots
MAX_DEGREES = 1e4  # images[].meta.angle_deg
MAX_METRES = 1e6  # strobe_position_m, calibration board2world

_Hz = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=MAX_STROBE_HZ)]
_Shutter = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=MAX_SECONDS)]
_Seconds = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0, le=MAX_SECONDS)]
_Flashes = Annotated[StrictInt, Field(ge=0, le=MAX_FLASHES)]
_Index = Annotated[StrictInt, Field(ge=0, le=MAX_INDEX)]
_Degrees = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_DEGREES, le=MAX_DEGREES)]
_Metres = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_METRES, le=MAX_METRES)]
_Name = Annotated[StrictStr, Field(min_length=1)]
_Row4 = tuple[_Metres, _Metres, _Metres, _Metres]


def _version(v: int) -> int:
    if not 1 <= v <= CAPTURE_VERSION:
        raise PydanticCustomError("version", "must be a capture file version this stillcap reads ({versions})",
                                  {"versions": "1" if CAPTURE_VERSION == 1 else f"1 to {CAPTURE_VERSION}"})
    return v


def _name_or_object(v: Any) -> Any:
    if not (isinstance(v, str) and v) and not isinstance(v, dict):
        raise PydanticCustomError("name_or_object", "must be a built-in name (a string) or an object")
    return v


class Units(Model):
    """``units``: fixed (lengths in metres, times in seconds, frequencies in hertz, angles in radians)."""

    length: Literal["m"] = "m"
    time: Literal["s"] = "s"
    frequency: Literal["Hz"] = "Hz"
    angle: Literal["rad"] = "rad"


class CaptureFile(Model):
    """``capture.json``'s top level; the capture-wide keys stillcap reads are typed when present
    (other keys are kept as they are, in ``Capture.meta``)."""

    format: Literal["stillcap-capture"]
    version: Annotated[StrictInt, AfterValidator(_version)]
    kind: Literal[KINDS]
    units: Units = Units()
    rig: StrictStr = "rig.json"
    truth: StrictStr | None = None
    images: list[dict[str, Any]]
    meta: dict[str, Any] = None
    description: StrictStr = None
    synthetic: StrictBool = None
    rig_calibrated: StrictBool = None
    pairs: dict[str, tuple[_Name, _Name]] = None
    strobe_position_m: tuple[_Metres, _Metres, _Metres] = None
    markerset: Annotated[Any, AfterValidator(_name_or_object)] = None
    skeleton: Annotated[Any, AfterValidator(_name_or_object)] = None
    ball: Annotated[Any, AfterValidator(_name_or_object)] = None
    target: dict[str, Any] = None
    calibration: dict[str, Any] = None


class CalibrationRecord(Model):
    """The parts of ``calibration`` (the record of how the rig was calibrated) the pitch
    uncertainties read: the board poses and the spots each camera used."""

    extrinsics_target: dict[str, Any] = None
    board2world: dict[str, list[tuple[_Row4, _Row4, _Row4, _Row4]]] = None
    cameras: dict[str, dict[str, Any]] = None


class CalibrationCamera(Model):
    spots_used: list[_Index] = None


class ImageEntry(Model):
    """One entry of ``images``: the file, its camera, its timing, its ``meta``."""

    file: StrictStr
    camera: _Name
    strobe_hz: _Hz = None
    shutter_s: _Shutter = None
    first_flash_s: _Seconds = None
    n_flashes: _Flashes = None
    meta: dict[str, Any] = None


class ImageMeta(Model):
    """The keys of ``images[].meta`` stillcap reads (others are kept as they are)."""

    pair: _Name = None
    angle_deg: _Degrees = None
    view: _Index = None
    instant: _Index = None


def check_image_entry(d: Any, source: str, prefix: tuple = ()) -> ImageEntry:
    """An image entry checked: no unknown key (timing keys carry their unit), then
    :class:`ImageEntry` and :class:`ImageMeta`; ``ValueError`` ``SOURCE: KEY.PATH: ...``."""
    if isinstance(d, dict):
        unknown = sorted(set(d) - {"file", "camera", "meta", *TIMING}, key=str)
        if unknown:
            path = ".".join(map(key_step, (*prefix, unknown[0])))
            raise ValueError(f"{source}: {path}: image entry has unknown keys {unknown} "
                             f"(timing keys carry their unit: {', '.join(TIMING)})")
    e = validate(ImageEntry, d, source, prefix)
    if e.meta is not None:
        validate(ImageMeta, e.meta, source, (*prefix, "meta"))
    return e


def check_capture_file(d: Any, source: str) -> CaptureFile:
    """``capture.json``'s content checked (its image entries: only that they are objects; see
    :func:`check_image_entry`); ``ValueError`` ``SOURCE: KEY.PATH: ...`` for the first problem."""
    if not isinstance(d, dict) or d.get("format") != CAPTURE_FORMAT:
        got = describe(d.get("format")) if isinstance(d, dict) else f"a JSON {type(d).__name__}"
        raise ValueError(f"{source}: format: not a stillcap capture (expected \"format\": \"{CAPTURE_FORMAT}\", "
                         f"got {got})")
    c = validate(CaptureFile, d, source)
    if c.calibration is not None:
        rec = validate(CalibrationRecord, c.calibration, source, ("calibration",))
        for name, cam in (rec.cameras or {}).items():
            validate(CalibrationCamera, cam, source, ("calibration", "cameras", name))
    return c
