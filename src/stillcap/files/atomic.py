"""Atomic file writes: write to a temporary file in the target folder, then rename.

A crash or an error half-way never leaves a user's file truncated: the old file stays until the
new one is complete (``os.replace`` is atomic on POSIX and Windows within one filesystem). An
exception, ``KeyboardInterrupt`` (Ctrl-C) included, removes the temporary file and leaves the
target as it was.

The temporary file is named ``.NAME.stillcap-tmp-PID-XXXXXXXX.EXT`` beside the target (``PID``:
the writing process, ``EXT``: the target's extension, which writers such as ``cv2.imwrite`` read).
A process killed during a write (SIGKILL, power loss) cannot remove its temporary file; the next
atomic write into the same folder removes such stale files: those whose writing process is gone
(on this machine), and any older than :data:`STALE_AFTER_S` (a process id used again).
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_bytes", "write_text", "remove_stale_temp_files", "TEMP_TAG", "STALE_AFTER_S"]

#: What every temporary file of :func:`atomic_path` holds in its name.
TEMP_TAG = ".stillcap-tmp-"
#: A temporary file older than this (seconds) is stale even when its process id is in use.
STALE_AFTER_S = 600.0
_TEMP_NAME = re.compile(r"^\..*\.stillcap-tmp-(\d+)-[^.]*(\.[^.]*)?$")


def _process_gone(pid: int) -> bool:
    """Whether no process ``pid`` runs on this machine (a zombie counts as gone)."""
    if pid == os.getpid():
        return False
    if sys.platform == "win32":  # os.kill(pid, 0) would end the process there: rely on the age
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's process
        return False
    except OSError:
        return False
    try:  # Linux: a killed child its parent has not reaped yet is a zombie ("Z")
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat[stat.rindex(")") + 2:].startswith("Z")
    except (OSError, ValueError):
        return False


def remove_stale_temp_files(folder, now: float | None = None) -> list[Path]:
    """Remove the stale temporary files of :func:`atomic_path` in ``folder`` (not recursive):
    those whose writing process is gone, and those older than :data:`STALE_AFTER_S`.
    Returns the files removed; errors (a file gone meanwhile, no permission) are ignored."""
    now = time.time() if now is None else now
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        if TEMP_TAG not in e.name:
            continue
        m = _TEMP_NAME.match(e.name)
        if m is None:
            continue
        try:
            if not e.is_file(follow_symlinks=False):
                continue
            old = now - e.stat(follow_symlinks=False).st_mtime > STALE_AFTER_S
            if old or _process_gone(int(m.group(1))):
                os.unlink(e.path)
                removed.append(Path(e.path))
        except OSError:
            continue
    return removed


@contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; on success it replaces ``path``.

    Use for writers that want a file name (``cv2.imwrite``, ``matplotlib.savefig``)::

        with atomic_path("out.png") as tmp:
            cv2.imwrite(str(tmp), image)

    On any exception (``KeyboardInterrupt`` too) the temporary file is removed and ``path`` is
    left as it was. Stale temporary files of killed processes in the folder are removed first.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temp_files(path.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TEMP_TAG}{os.getpid()}-", suffix=path.suffix or ".tmp",
                               dir=path.parent)
    try:
        os.close(fd)
        # mkstemp creates 0600; give the file the mode a plain open() would (or keep the old file's)
        try:
            mode = path.stat().st_mode & 0o777
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; return the path."""
    return write_bytes(path, text.encode("utf-8"))
