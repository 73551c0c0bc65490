"""The cluster a batch runs on: a ``LocalCluster`` of worker processes, or a running scheduler.

A running cluster is Dask's business: start it with ``dask scheduler`` and ``dask worker`` (or
dask-jobqueue, dask-kubernetes, dask-cloudprovider, ...) and give its address; its workers need
stillcap installed and must see the capture folders at the same paths (a shared filesystem).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager

__all__ = ["connect"]


@contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, threads: int = 1, timeout_s: float = 10.0):
    """A :class:`distributed.Client`: on a new ``LocalCluster`` of ``workers`` processes with
    ``threads`` threads each (``workers`` None: one per core), or on the running scheduler at
    ``scheduler`` (``tcp://host:8786``). Closed on exit.

    Raises
    ------
    ValueError
        When the scheduler cannot be reached within ``timeout_s`` (one line naming it), or for
        a bad number of workers or threads.
    """
    from distributed import Client, LocalCluster

    if threads < 1:
        raise ValueError(f"--threads must be at least 1, got {threads}")
    if scheduler is not None:
        if workers is not None:
            raise ValueError("--workers starts a local cluster; a running cluster (--scheduler) has its own workers")
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError, ValueError, TypeError) as e:
            why = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ValueError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({why})") from None
        try:
            yield client
        finally:
            client.close()
        return
    if workers is not None and workers < 1:
        raise ValueError(f"--workers must be at least 1, got {workers}")
    import os

    n = workers if workers is not None else (os.cpu_count() or 1)
    cluster = LocalCluster(n_workers=n, threads_per_worker=threads, processes=True, silence_logs=logging.ERROR,
                           dashboard_address=":8787")
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()
