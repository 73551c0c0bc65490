"""Typed validation of the files a user gives: one pydantic model per file format, and one way to
turn a validation error into one line that names the file, the key path and what was expected.

The models live beside the code that reads each format (``camera.py`` for rigs,
``io/capture.py`` for captures, ...); this module only holds the shared number types and
:func:`validate`. Numbers are finite, counts are integers (``true`` is not a number), and every
message reads ``FILE: KEY.PATH: what was expected (got VALUE)``.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError

__all__ = ["Finite", "Positive", "NonNegative", "Count", "PositiveCount", "Name", "Fraction", "Coordinate",
           "MAX_COORDINATE", "Vec3", "Model", "ClosedModel", "validate", "describe"]

#: A finite number (JSON integers are taken as floats; ``true``, ``NaN``, ``Infinity`` are not).
Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]
#: A finite number > 0.
Positive = Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False)]
#: A finite number >= 0.
NonNegative = Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False)]
#: A whole number >= 0 (``1.0`` and ``true`` are not).
Count = Annotated[StrictInt, Field(ge=0)]
#: A whole number >= 1.
PositiveCount = Annotated[StrictInt, Field(ge=1)]
#: A non-empty string (a joint, marker, view or colour name).
Name = Annotated[StrictStr, Field(min_length=1)]
#: A finite number in [0, 1] (colour channels, hue in turns).
Fraction = Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]
#: Largest magnitude of a coordinate or length in a file, in the file's own unit: larger values
#: are typing errors, and would overflow when converted (a C3D file holds float32 millimetres).
MAX_COORDINATE = 1e6
#: A finite coordinate or length with ``|v| <= MAX_COORDINATE``.
Coordinate = Annotated[float, Field(strict=True, ge=-MAX_COORDINATE, le=MAX_COORDINATE, allow_inf_nan=False)]
#: A 3D point or vector of :data:`Coordinate`.
Vec3 = tuple[Coordinate, Coordinate, Coordinate]


class Model(BaseModel):
    """Base of the file models: unknown keys are kept (files may carry notes), booleans are not
    numbers, numbers are not strings."""

    model_config = ConfigDict(extra="allow", strict=False, allow_inf_nan=False)


class ClosedModel(Model):
    """A file model whose unknown keys are refused (formats where a misspelt key would be lost,
    e.g. ``angle`` for ``angle_deg``)."""

    model_config = ConfigDict(extra="forbid")


def describe(value: Any, limit: int = 40) -> str:
    """A short printable form of a bad value for a message."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def key_step(key: Any) -> str:
    """One step of a key path: as written when it is a plain printable name, else quoted (a key
    from a file may be empty or hold line breaks)."""
    text = str(key)
    return text if text and text.isprintable() and text == text.strip() else repr(text)


def validate(model: type[BaseModel], data: Any, source: str, prefix: tuple = ()) -> Any:
    """``model`` validated from ``data`` (parsed JSON), or ``ValueError`` in one line:
    ``SOURCE: KEY.PATH: MESSAGE (got VALUE)`` for the first error (``prefix``: the key path of
    ``data`` inside its file)."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        first = e.errors(include_url=False)[0]
        path = ".".join(key_step(p) for p in (*prefix, *first["loc"])) or "(the whole file)"
        message = first["msg"][0].lower() + first["msg"][1:] if first["msg"] else "invalid"
        if first["type"] == "extra_forbidden":
            message = "unknown key (not part of the format; check its spelling)"
        got = f" (got {describe(first['input'])})" if first["type"] != "missing" else ""
        more = f"; {e.error_count() - 1} more problem(s)" if e.error_count() > 1 else ""
        raise ValueError(f"{source}: {path}: {message}{got}{more}") from None
