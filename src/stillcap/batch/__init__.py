"""Batches of captures on a Dask cluster (``stillcap batch``, ``docs/batch.md``).

- :mod:`~stillcap.batch.inputs`: the captures (kind, name, pitch type) and the content hash of
  their inputs; :func:`read_inputs`, :func:`read_capture_list`.
- :mod:`~stillcap.batch.tasks`: one capture's work on a worker (:func:`analyse_capture`): the
  kind's own pipeline, its JSON text and its table row.
- :mod:`~stillcap.batch.run`: :func:`run_batch`: skip what is done, submit, collect, write.
- :mod:`~stillcap.batch.table`: the Parquet table; :mod:`~stillcap.batch.summary`: the session
  summary; :mod:`~stillcap.batch.cluster`: a ``LocalCluster`` or a running scheduler.

The package sits beside ``gui`` in the stack: it imports pipelines, report, io and below, never
the studio (a comparison with a studio truth is passed in by the CLI as ``finish``).
"""

from stillcap.batch.cluster import connect
from stillcap.batch.inputs import KINDS, BatchInput, content_hash, read_capture_list, read_inputs
from stillcap.batch.run import OUTPUT_NAMES, BatchRun, run_batch
from stillcap.batch.table import TABLE_FILE, read_rows, write_rows
from stillcap.batch.tasks import JSON_FILES, analyse_capture, metrics_row

__all__ = ["JSON_FILES", "KINDS", "OUTPUT_NAMES", "TABLE_FILE", "BatchInput", "BatchRun", "analyse_capture",
           "connect", "content_hash", "metrics_row", "read_capture_list", "read_inputs", "read_rows", "run_batch",
           "write_rows"]
