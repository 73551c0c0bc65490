"""The batch table: one row per capture, written as Parquet (pyarrow), read back to resume.

Columns (``docs/batch.md``): first the fixed ones, :data:`FIXED`, then each kind's metrics
(:func:`stillcap.batch.tasks.metrics_row`: units in the names, a metric's 1-sigma in
``NAME_sigma``), in the order they first appear. A metric a row does not have is null.
"""

from __future__ import annotations

import io
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from stillcap.files.atomic import write_bytes

__all__ = ["FIXED", "TABLE_FILE", "read_rows", "write_rows"]

#: The results table's file name in the results folder.
TABLE_FILE = "results.parquet"
#: The columns every row has: (name, Arrow type).
FIXED = (("capture", pa.string()), ("name", pa.string()), ("kind", pa.string()), ("pitch_type", pa.string()),
         ("status", pa.string()), ("error", pa.string()), ("content_hash", pa.string()),
         ("seconds", pa.float64()), ("worker", pa.string()), ("json_file", pa.string()))
_FORMAT = b"stillcap-batch-results"


def _type_of(values) -> pa.DataType:
    """The Arrow type of a metric column from its non-null values (Python scalars)."""
    seen = [v for v in values if v is not None]
    if not seen:
        return pa.float64()
    if all(isinstance(v, bool) for v in seen):
        return pa.bool_()
    if all(isinstance(v, int) and not isinstance(v, bool) for v in seen):
        return pa.int64()
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in seen):
        return pa.float64()
    return pa.string()


def _cast(v, t: pa.DataType):
    if v is None:
        return None
    if t == pa.string():
        return v if isinstance(v, str) else str(v)
    if t == pa.float64():
        return float(v)
    return v


def to_table(rows: list[dict]) -> pa.Table:
    """The rows (dicts with the :data:`FIXED` keys and metric keys) as an Arrow table."""
    fixed = [n for n, _ in FIXED]
    extra: list[str] = []
    for r in rows:
        extra.extend(k for k in r if k not in fixed and k not in extra)
    fields = [pa.field(n, t) for n, t in FIXED]
    fields += [pa.field(k, _type_of(r.get(k) for r in rows)) for k in extra]
    schema = pa.schema(fields, metadata={b"format": _FORMAT, b"version": b"1"})
    cols = [pa.array([_cast(r.get(f.name), f.type) for r in rows], type=f.type) for f in schema]
    return pa.Table.from_arrays(cols, schema=schema)


def write_rows(path, rows: list[dict]) -> Path:
    """Write the rows as a Parquet file, atomically (:func:`stillcap.files.atomic.write_bytes`)."""
    buf = io.BytesIO()
    pq.write_table(to_table(rows), buf)
    return write_bytes(path, buf.getvalue())


def read_rows(path) -> list[dict]:
    """The rows of a results table written by :func:`write_rows` (``[]`` when there is none).
    ``ValueError`` naming the file when it is not one."""
    path = Path(path)
    if not path.is_file():
        return []
    try:
        t = pq.read_table(path)
    except (pa.ArrowException, OSError) as e:
        raise ValueError(f"{path}: not a readable Parquet file ({e}); move it away to start afresh") from None
    if (t.schema.metadata or {}).get(b"format") != _FORMAT or any(n not in t.column_names for n, _ in FIXED):
        raise ValueError(f"{path}: not a stillcap batch table (no format stillcap-batch-results)")
    return t.to_pylist()
