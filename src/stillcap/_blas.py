"""BLAS on one thread for the small-matrix stages (one controller for the process).

The puppet pipeline's matrix products and the pose fit's SVDs are on small matrices (at most a
few hundred rows), where OpenBLAS's threads only cost: on the benchmark's busy 2-core machine they
spin, and the dense pose fit took 225-240 ms instead of 15 ms, a 3 x 3 ``@`` 20x longer than
``np.einsum``. ``threadpoolctl`` sets the limit for the call only and restores the caller's
setting afterwards (it is process-wide meanwhile: BLAS has no per-thread setting).
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading

import threadpoolctl
from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread", "single_blas_thread"]


class _BlasDepth(threading.local):
    """Per thread: how many limited sections are running (nested ones leave the limit to the
    outermost)."""

    depth = 0


_blas_limited = _BlasDepth()


@functools.lru_cache(maxsize=1)
def _blas_controller() -> ThreadpoolController:
    """One :class:`threadpoolctl.ThreadpoolController` for the process: ``threadpool_limits``
    looks up the loaded BLAS libraries again at every call (~1.1 ms); the controller does it
    once. SciPy's linear algebra is imported first so that its OpenBLAS (which NumPy's does not
    cover) is among the libraries found. Where it can (:class:`_NamedLibrariesController`),
    only the libraries whose file names threadpoolctl would match are looked at."""
    import scipy.linalg  # noqa: F401  (loads SciPy's BLAS)

    try:
        return _NamedLibrariesController()
    except (AttributeError, TypeError, OSError):  # threadpoolctl's internals changed: its own full search
        return ThreadpoolController()


class _NamedLibrariesController(ThreadpoolController):
    """A :class:`~threadpoolctl.ThreadpoolController` that hands threadpoolctl only the loaded
    libraries whose file names start with one of its known prefixes (``libopenblas``,
    ``libscipy_openblas``, ``libmkl``, ``libgomp``, ...), the names it matches them by.

    Hand-written over threadpoolctl's own Linux search (``/proc/self/maps``) because that search
    resolves every one of the process's ~140 shared libraries' paths (``os.path.realpath``)
    before it looks at their names: 3.4-3.7 ms CPU of the puppet's first call in a fresh
    process, against ~1.5 ms here. The paths ``/proc/self/maps`` lists are those the kernel
    mapped, already resolved, so filtering their names first finds the same libraries (a test
    compares the two controllers' ``info()``). Elsewhere (no ``/proc``, or a threadpoolctl
    whose internals differ) threadpoolctl's own search runs."""

    def _find_libraries_with_linux(self):
        prefixes = tuple(p.lower() for p in threadpoolctl._ALL_PREFIXES)
        with open("/proc/self/maps", "rb") as f:
            maps = f.read()
        for path in set(self._PATH_RE.findall(maps)):
            path = path.decode("utf-8")
            if os.path.basename(path).lower().startswith(prefixes):
                self._make_controller_from_path(path)


@contextlib.contextmanager
def single_blas_thread():
    """BLAS limited to one thread inside the ``with`` block (a no-op inside another one)."""
    if _blas_limited.depth:
        yield
        return
    _blas_limited.depth += 1
    try:
        with _blas_controller().limit(limits=1, user_api="blas"):
            yield
    finally:
        _blas_limited.depth -= 1


def one_blas_thread(func):
    """Decorator: run ``func`` inside :func:`single_blas_thread`."""
    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with single_blas_thread():
            return func(*args, **kwargs)
    return wrapper
