"""Scheduling of the pitch pipeline's per-pair work: a thread pool, or worker processes.

Scheduling only: which thread or process runs each pair's work, and where its photos are kept.
The work itself is the stages' (:func:`stillcap.ball.stereo.ball_centers_stereo`,
:func:`stillcap.pipelines.pitch.spin.pair_markers_and_spin`). :func:`pair_jobs` gives the
stages one of two schedulers with the same two calls (``find_balls`` for every pair,
``markers_and_spin`` for one pair):

- :class:`ThreadJobs` (``PitchOptions.processes == 0``, default): the photos decode on a pool of
  ``PitchOptions.workers`` threads (``imread`` releases the GIL) while the calling thread finds
  each pair's ball images as soon as its photos are in; the pairs' marker jobs run on the pool
  (``workers == 1``: everything on the calling thread, one core).
- :class:`ProcessJobs` (``processes > 0``): each pair in a worker process, as follows.

Most of a pair's work after decoding (ball detection and refinement, markers, the pair's own spin
fit) is many small NumPy/SciPy calls that hold the GIL, so two threads cannot overlap it. With
``processes > 0`` each stereo pair runs in a worker process instead:

1. :func:`pair_positions_job` decodes the pair's two photos and finds its ball images; the
   decoded photos stay in the worker (a cache keyed by a token), only the small
   :class:`~stillcap.ball.stereo.StereoBalls` goes back.
2. After the main process has ordered the flashes (which needs every pair's positions),
   :func:`pair_markers_job` finds the markers in the cached photos and fits the pair's own spin,
   while the main process runs the positions-only reference fit.

Both steps of one pair must reach the process holding its photos, so the pool is a list of
single-process executors (pair ``i`` goes to executor ``i % n``), created on first use, reused
by every later capture of the process and shut down at exit. The processes start with the
``forkserver`` method (never ``fork``: the caller may run threads), with this module preloaded;
like every spawned process they import the caller's ``__main__`` module, so scripts need an
``if __name__ == "__main__":`` guard. Workers receive file paths, never decoded photos.
"""
from __future__ import annotations

import atexit
import itertools
import multiprocessing
import os
import threading
from collections import OrderedDict
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from stillcap.ball.stereo import ball_centers_stereo
from stillcap.detect.response import estimate_responses
from stillcap.io.capture import Capture
from stillcap.pipelines._response import _blur_of
from stillcap.pipelines.pitch.spin import pair_markers_and_spin

__all__ = [
    "ProcessJobs",
    "ThreadJobs",
    "cached_tokens",
    "drop_job",
    "new_token",
    "pair_jobs",
    "pair_markers_job",
    "pair_positions_job",
    "shutdown_worker_pools",
    "worker_pools",
]

# -- worker side -------------------------------------------------------------------------------
# decoded photos of the pairs whose marker step has not run yet (token -> (cams, imgs)); a bound
# in case a caller's marker step never comes (the main process also sends drop_job then)
_PHOTOS: OrderedDict = OrderedDict()
_MAX_CACHED = 8


def pair_positions_job(capture: Capture, images: tuple, cameras: tuple, radius_m: float, token: str):
    """Decode a pair's 2 photos (``capture.read_image``: the same errors as in the main
    process), find and match its ball images, keep the photos under ``token``.

    Returns
    -------
    StereoBalls
    """
    cams = [capture.rig[c] for c in cameras]
    imgs = [capture.read_image(im) for im in images]
    st = ball_centers_stereo(cams[0], imgs[0], cams[1], imgs[1], radius_m)
    _PHOTOS[token] = (cams, imgs)
    while len(_PHOTOS) > _MAX_CACHED:
        _PHOTOS.popitem(last=False)
    return st


def _cached(token: str, pair, release: bool):
    try:
        return _PHOTOS.pop(token) if release else _PHOTOS[token]
    except KeyError:
        raise RuntimeError(f"pitch worker {os.getpid()}: the photos of pair {pair.name!r} are no longer cached") \
            from None


def pair_markers_job(token: str, pair, types, layout, radius_m: float, max_px: float, spin_method: str,
                     release: bool = True):
    """The marker step of the pitch pipeline on the photos cached under ``token`` (released
    here unless ``release`` is False: :func:`pair_response_job` follows); ``pair`` is the pair's
    ``PairResult`` without its photos. Returns what
    :func:`stillcap.pipelines.pitch.spin.pair_markers_and_spin` returns."""
    cams, imgs = _cached(token, pair, release)
    return pair_markers_and_spin(cams, imgs, pair, types, layout, radius_m, max_px, spin_method)


def pair_response_estimates(photos, pair) -> dict:
    """Each camera's :class:`~stillcap.detect.response.ResponseEstimate` from the pair's photos
    at its refined centres and projected radii: what the ``response`` self-check
    (:func:`stillcap.pipelines._response.pitch_response_checks`) computes, on the photos the
    pair step decoded, where they are."""
    found = estimate_responses([(photos[k], np.asarray(pair.centers_px[k]), np.asarray(pair.radius_px[k]),
                                 _blur_of(pair.stereo, k))
                                for k in range(len(pair.cameras))])  # both cameras in one batch
    return dict(zip(pair.cameras, found))


def pair_response_job(token: str, pair) -> dict:
    """:func:`pair_response_estimates` on the photos cached under ``token`` (released here)."""
    _cams, imgs = _cached(token, pair, True)
    return pair_response_estimates(imgs, pair)


def drop_job(token: str) -> None:
    """Forget the photos cached under ``token`` (a capture that stopped before its marker step)."""
    _PHOTOS.pop(token, None)


def cached_tokens() -> list:
    """The tokens whose photos this worker holds (diagnostics: empty between captures)."""
    return list(_PHOTOS)


def _ready() -> int:
    return os.getpid()


# -- main side -------------------------------------------------------------------------------
_POOLS: list = []
_LOCK = threading.Lock()
_TOKENS = itertools.count()


def new_token() -> str:
    """A key for one pair's cached photos, unique in this process."""
    return f"{os.getpid()}-{next(_TOKENS)}"


def worker_pools(n: int) -> list:
    """``n`` single-process executors (created on first use, started together, then reused).

    Parameters
    ----------
    n : int
        How many worker processes, >= 1.

    Returns
    -------
    list of ProcessPoolExecutor
    """
    if int(n) < 1:
        raise ValueError(f"need at least 1 worker process, got {n}")
    with _LOCK:
        for i, ex in enumerate(_POOLS):  # a worker that died (e.g. killed) breaks its executor: replace it
            if getattr(ex, "_broken", False):
                ex.shutdown(wait=False, cancel_futures=True)
                _POOLS[i] = None
        _POOLS[:] = [ex for ex in _POOLS if ex is not None]
        new = []
        while len(_POOLS) < int(n):
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload([__name__])
            ex = ProcessPoolExecutor(1, mp_context=ctx)
            _POOLS.append(ex)
            new.append(ex)
        # start the new processes together rather than one at the first job of each
        for f in [ex.submit(_ready) for ex in new]:
            f.result()
        return _POOLS[:int(n)]


def shutdown_worker_pools() -> None:
    """Stop the worker processes (also done at interpreter exit)."""
    with _LOCK:
        pools, _POOLS[:] = list(_POOLS), []
    for ex in pools:
        ex.shutdown(wait=True, cancel_futures=True)


atexit.register(shutdown_worker_pools)


# -- the two schedulers ----------------------------------------------------------------------
class _Inline:
    """An executor that runs each job at once on the calling thread (a finished Future): one
    thread in all. A pool of one thread beside the calling one let a capture use a second core
    (decoding, markers while the flight is fitted), so a batch worker meant to use one core used
    more, and one worker's time was not the one-core time its parallel efficiency divides by."""

    def submit(self, fn, *args, **kwargs) -> Future:
        fut = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as e:  # noqa: BLE001 - raised again by result(), as a pool's would be
            fut.set_exception(e)
        return fut

    def shutdown(self, wait: bool = True) -> None:
        pass


class ThreadJobs:
    """A pair's work on a pool of ``workers`` threads (a context manager: the pool shuts down on
    exit, waiting for its jobs); ``workers == 1``: on the calling thread only."""

    def __init__(self, capture: Capture, workers: int):
        self.capture = capture
        self.pool = _Inline() if int(workers) <= 1 else ThreadPoolExecutor(int(workers))
        self.images: dict = {}  # pair name -> its photos' entries
        self.responses: list = []  # (photo entries, Future of pair_response_estimates)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.pool.shutdown(wait=True)

    def find_balls(self, specs, radius_m: float) -> list:
        """Every pair's ``(cameras, photos, StereoBalls)``, in the order of ``specs``."""
        cap = self.capture
        # the photos decode on the pool in pair order (imread releases the GIL); each pair's ball
        # images are found on this thread as soon as its two photos are in, while the next pair's
        # photos decode (detection mostly holds the GIL: two pairs on threads overlapped less)
        decoding = [[self.pool.submit(cap.read_image, im) for im in sp.images] for sp in specs]
        found = []
        for sp, futs in zip(specs, decoding):
            cams = [cap.rig[c] for c in sp.cameras]
            imgs = [f.result() for f in futs]
            self.images[sp.name] = sp.images
            found.append((cams, imgs, ball_centers_stereo(cams[0], imgs[0], cams[1], imgs[1], radius_m)))
        return found

    def markers_and_spin(self, pair, cams, photos, *args):
        """:func:`pair_markers_and_spin` of one pair on the pool (a Future); ``args``: its
        arguments after the pair. The pair's response estimates go on the pool when its marker
        step is done (behind the other pairs' marker steps, which the main thread waits for
        first; :meth:`response_estimates`)."""
        fut = self.pool.submit(pair_markers_and_spin, cams, photos, pair, *args)
        out = Future()

        def start(_done):
            try:
                job = self.pool.submit(pair_response_estimates, photos, pair)
            except RuntimeError as e:  # the pool shut down: the capture stopped on an error
                out.set_exception(e)
                return
            job.add_done_callback(lambda j: out.set_exception(j.exception()) if j.exception() else
                                  out.set_result(j.result()))

        fut.add_done_callback(start)
        self.responses.append((self.images[pair.name], out))
        return fut

    def response_estimates(self) -> dict:
        """``{(camera, photo file): ResponseEstimate}`` of the pairs whose marker step ran
        (:func:`pair_response_estimates`; waits for them)."""
        return _collect(self.responses)


class ProcessJobs:
    """A pair's work in ``processes`` worker processes (:func:`worker_pools`): pair ``i`` on
    worker ``i % processes``, which keeps its photos under a token for the pair's marker step (a
    context manager: on exit the workers forget the photos of pairs whose marker step did not
    come)."""

    def __init__(self, capture: Capture, processes: int):
        if capture.root is None:
            raise ValueError("processes > 0 needs a capture loaded from or saved to a folder (the worker processes "
                             "read its photos): use processes=0")
        self.capture = capture
        self.executors = worker_pools(int(processes))
        self.cached: dict = {}  # token -> executor: a pair's photos held by a worker until its marker step
        self.images: dict = {}  # pair name -> its photos' entries
        self.responses: list = []  # (photo entries, Future of pair_response_job)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        for token, ex in self.cached.items():  # the capture stopped before these pairs' marker step
            ex.submit(drop_job, token)

    def find_balls(self, specs, radius_m: float) -> list:
        """Every pair's ``(cameras, token, StereoBalls)``, in the order of ``specs`` (the token
        names the pair's photos, kept by its worker)."""
        cap = self.capture
        light = Capture(cap.kind, cap.rig, cap.images, None, {}, cap.root)  # paths only, no truth
        futs = []
        for i, sp in enumerate(specs):
            token, ex = new_token(), self.executors[i % len(self.executors)]
            self.cached[token] = ex
            self.images[sp.name] = sp.images
            futs.append((token, ex.submit(pair_positions_job, light, sp.images, sp.cameras, radius_m, token)))
        return [([cap.rig[c] for c in sp.cameras], token, f.result()) for sp, (token, f) in zip(specs, futs)]

    def markers_and_spin(self, pair, cams, photos, *args):
        """:func:`pair_markers_job` of one pair on the worker holding its photos (``photos``:
        their token); a Future."""
        # the worker holding the photos; the pair goes without them and its StereoBalls; the
        # pair's response estimates follow on that worker, which then releases the photos
        # (of its StereoBalls only the lens blur measured on the limbs, which the marker step uses)
        ex = self.cached.pop(photos)
        light = replace(pair, stereo=None if pair.stereo is None else SimpleNamespace(psf_px=pair.stereo.psf_px))
        fut = ex.submit(pair_markers_job, photos, light, *args, release=False)
        self.responses.append((self.images[pair.name], ex.submit(pair_response_job, photos, light)))
        return fut

    def response_estimates(self) -> dict:
        """As :meth:`ThreadJobs.response_estimates`, from the worker processes."""
        return _collect(self.responses)


def _collect(responses: list) -> dict:
    out = {}
    for images, fut in responses:
        found = fut.result()
        out.update(((im.camera, im.file), found[im.camera]) for im in images)
    return out


def pair_jobs(capture: Capture, workers: int, processes: int):
    """The scheduler of one capture's per-pair work: :class:`ThreadJobs` with ``processes == 0``,
    else :class:`ProcessJobs` (the capture must come from a folder)."""
    if int(processes) == 0:
        return ThreadJobs(capture, workers)
    return ProcessJobs(capture, processes)
