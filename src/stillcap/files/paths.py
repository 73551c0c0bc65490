"""Paths stored inside stillcap files (capture folders, projects, JumpingJack projects).

Every such path is relative to its folder and must stay inside it: no absolute paths, no ``..``,
and no symlink that leads out (checked after resolving). ``\\`` is read as ``/``.
"""

from __future__ import annotations

import functools
import os
import re
from pathlib import Path, PurePosixPath

__all__ = ["safe_relpath", "resolve_inside"]


def _prefix(what: str) -> str:
    return f"{what}: " if what else ""


def safe_relpath(path, what: str, folder: str = "project folder") -> str:
    """``path`` as a normalised relative POSIX path that cannot leave its folder.

    Parameters
    ----------
    path : str
        A path relative to a folder (``\\`` is read as ``/``).
    what : str
        Names the entry in error messages (e.g. ``"view 'turn_030.0deg': image"``); may be empty.
    folder : str
        Names the folder in error messages (``"project folder"``, ``"capture folder"``).

    Raises
    ------
    ValueError
        Not a non-empty string, absolute (``/x``, ``C:\\x``, ``\\\\server``), or containing ``..``.
    """
    pre = _prefix(what)
    if not isinstance(path, str) or not path.strip() or "\x00" in path:
        raise ValueError(f"{pre}file name must be a non-empty string, got {path!r}")
    norm, problem = _normalised(path)
    if problem == "absolute":
        raise ValueError(f"{pre}path {path!r} is absolute; paths must be relative to the {folder}")
    if problem == "parent":
        raise ValueError(f"{pre}path {path!r} leaves the {folder} ('..' is not allowed)")
    if problem == "empty":
        raise ValueError(f"{pre}path {path!r} names no file")
    return norm


@functools.lru_cache(maxsize=4096)
def _normalised(path: str) -> tuple[str, str | None]:
    """:func:`safe_relpath`'s answer for a string ``path``: ``(normalised path, None)`` or
    ``("", problem)`` (``"absolute"``, ``"parent"``, ``"empty"``). Cached: a capture's photo
    paths are checked three times as it loads (its entry, :class:`CaptureImage`,
    :func:`resolve_inside`), and ``PurePosixPath`` costs ~20 us a time."""
    s = path.replace("\\", "/")
    p = PurePosixPath(s)
    if p.is_absolute() or s.startswith("/") or re.match(r"^[A-Za-z]:", s):
        return "", "absolute"
    if ".." in p.parts:
        return "", "parent"
    if str(p) in ("", "."):
        return "", "empty"
    return str(p), None


def resolve_inside(root, path, what: str, folder: str = "project folder", *, real_root: Path | None = None,
                   real_dirs: dict | None = None) -> Path:
    """``root / path`` after checking that ``path`` is safe and, symlinks resolved, stays in ``root``.

    ``real_root`` is ``Path(root).resolve()`` when the caller already has it (one resolve per folder
    rather than per file). ``real_dirs``: a dict the caller keeps over many files, folder ->
    its resolved path, so that files of one folder resolve it once (a file that is not itself a
    symlink resolves to its resolved folder / its name, as ``Path.resolve`` walks it; ~0.1 ms per
    file of a capture's photos).
    """
    rel = safe_relpath(path, what, folder)
    full = Path(root) / rel
    if real_dirs is None or os.path.islink(full):
        real = full.resolve()
    else:
        parent = real_dirs.get(full.parent)
        if parent is None:
            parent = real_dirs[full.parent] = full.parent.resolve()
        real = parent / full.name
    if not real.is_relative_to(Path(root).resolve() if real_root is None else real_root):
        raise ValueError(f"{_prefix(what)}path {path!r} leads outside the {folder} (symlink)")
    return full
