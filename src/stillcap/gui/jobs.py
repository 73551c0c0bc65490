"""Background jobs shared by every GUI module: long work (detection, 3D, spin) runs in a thread
pool so that the event loop keeps answering, and the page follows its progress.

A route submits ``fn(progress, *args)``; ``progress(done, total, label=None)`` has the signature of
the callbacks the pipelines already take (:func:`stillcap._progress.report_progress`), so a
pipeline's ``progress=`` argument is given the job's callback as it is. The page polls
``GET /api/jobs/{id}`` or follows ``GET /api/jobs/{id}/events`` (server-sent events), and may
cancel with ``DELETE /api/jobs/{id}`` (the next progress report then stops the work).

Threads rather than processes: the work is numpy and OpenCV, which release the GIL, the results
stay in memory for the routes to save, and the progress callback is a plain call.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

from starlette.requests import Request
from starlette.responses import JSONResponse, StreamingResponse
from starlette.routing import Route

__all__ = ["Job", "JobCancelled", "JobManager", "job_manager", "routes"]


class JobCancelled(Exception):
    """Raised inside a job's progress callback once the job was cancelled."""


@dataclass
class Job:
    """One piece of background work and what the page may know of it."""

    id: str
    label: str
    status: str = "queued"  # queued | running | done | failed | cancelled
    done: float = 0.0
    total: float = 0.0
    step: str = ""
    result: Any = None
    error: str | None = None
    started: float = field(default_factory=time.time)
    finished: float | None = None
    cancel: threading.Event = field(default_factory=threading.Event, repr=False)

    def as_json(self) -> dict:
        """What ``GET /api/jobs/{id}`` answers (the result only once done)."""
        frac = (self.done / self.total) if self.total else (1.0 if self.status == "done" else 0.0)
        return {"id": self.id, "label": self.label, "status": self.status, "done": self.done,
                "total": self.total, "fraction": max(0.0, min(1.0, frac)), "step": self.step,
                "error": self.error, "result": self.result if self.status == "done" else None}


class JobManager:
    """A thread pool running :class:`Job`\\ s, and their records (the last ``keep`` are kept)."""

    def __init__(self, workers: int = 2, keep: int = 100):
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="stillcap-gui-job")
        self._jobs: dict[str, Job] = {}
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._keep = keep

    def submit(self, fn: Callable[..., Any], *args, label: str = "", **kwargs) -> Job:
        """Run ``fn(progress, *args, **kwargs)`` in the pool; its return value (JSON-able) becomes
        the job's ``result``. A ``ValueError`` (bad input the user can fix) becomes the job's
        ``error`` as it is; any other exception is a bug, reported with its type."""
        job = Job(id=f"j{next(self._ids)}", label=label)
        with self._lock:
            self._jobs[job.id] = job
            for old in list(self._jobs)[:-self._keep]:
                if self._jobs[old].status in ("done", "failed", "cancelled"):
                    del self._jobs[old]

        def progress(done, total, step=None):
            if job.cancel.is_set():
                raise JobCancelled
            job.done, job.total = float(done), float(total)
            if step is not None:
                job.step = str(step)

        def run():
            if job.cancel.is_set():
                job.status, job.finished = "cancelled", time.time()
                return
            job.status = "running"
            try:
                job.result = fn(progress, *args, **kwargs)
                job.status = "done"
                if job.total:
                    job.done = job.total
            except JobCancelled:
                job.status = "cancelled"
            except (ValueError, FileNotFoundError) as e:
                job.status, job.error = "failed", str(e)
            except Exception as e:  # a bug: say so, with the place, rather than hiding it
                job.status = "failed"
                job.error = f"internal error ({type(e).__name__}: {e})"
                traceback.print_exc()
            job.finished = time.time()

        self._pool.submit(run)
        return job

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    def all(self) -> list[Job]:
        with self._lock:
            return list(self._jobs.values())

    def wait(self, job_id: str, timeout: float = 60.0) -> Job:
        """Block until the job ends (for tests and scripts; the page polls instead)."""
        end = time.monotonic() + timeout
        job = self.get(job_id)
        while job is not None and job.status in ("queued", "running") and time.monotonic() < end:
            time.sleep(0.02)
        return job

    def shutdown(self) -> None:
        for job in self.all():
            job.cancel.set()
        self._pool.shutdown(wait=False, cancel_futures=True)


def job_manager(ctx) -> JobManager:
    """The server's one :class:`JobManager`, kept in ``ctx.state["jobs"]``."""
    jm = ctx.state.get("jobs")
    if jm is None:
        jm = ctx.state["jobs"] = JobManager()
    return jm


def job_response(job: Job, status_code: int = 202) -> JSONResponse:
    """The answer of a route that started a job: its record, 202 Accepted."""
    return JSONResponse(job.as_json(), status_code=status_code)


def routes(ctx) -> list[Route]:
    """``/api/jobs``: list, status, server-sent events and cancel."""
    jm = job_manager(ctx)

    def _job(request: Request) -> Job:
        job = jm.get(request.path_params["job_id"])
        if job is None:
            raise _NotFound(request.path_params["job_id"])
        return job

    async def list_jobs(request: Request):
        return JSONResponse([j.as_json() for j in jm.all()])

    async def status(request: Request):
        try:
            return JSONResponse(_job(request).as_json())
        except _NotFound as e:
            return JSONResponse({"error": f"no job {e.args[0]!r}"}, status_code=404)

    async def cancel(request: Request):
        try:
            job = _job(request)
        except _NotFound as e:
            return JSONResponse({"error": f"no job {e.args[0]!r}"}, status_code=404)
        job.cancel.set()
        return JSONResponse(job.as_json())

    async def events(request: Request):
        try:
            job = _job(request)
        except _NotFound as e:
            return JSONResponse({"error": f"no job {e.args[0]!r}"}, status_code=404)

        async def stream():
            last = None
            while True:
                state = json.dumps(job.as_json())
                if state != last:
                    yield f"data: {state}\n\n"
                    last = state
                if job.status not in ("queued", "running") or await request.is_disconnected():
                    return
                await asyncio.sleep(0.1)

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store"})

    return [Route("/", list_jobs, methods=["GET"]),
            Route("/{job_id}", status, methods=["GET"]),
            Route("/{job_id}", cancel, methods=["DELETE"]),
            Route("/{job_id}/events", events, methods=["GET"])]


class _NotFound(Exception):
    pass
