"""The places stillcap writes to: checked before the work starts, recognised as stillcap's after.

:func:`check_writable` is called by every command right after parsing, for every file or folder
it will write: a location that cannot be written (a read-only folder, a parent that is a file, a
file where a folder belongs or the reverse) gives one ``ValueError`` naming the path and the
problem before any analysis, and so does an existing file that stillcap did not write, unless
``force``.

A file is a **stillcap output** (and may be overwritten without ``--force``) when

- it is empty, or
- it says so itself: JSON whose ``"format"`` starts with ``stillcap-`` (rigs, results, projects,
  exports, ...), COLLADA whose ``authoring_tool`` is stillcap, glTF/GLB whose generator is
  stillcap, or
- the manifest ``.stillcap-output.json`` of its folder (or of a folder up to two levels above)
  lists it: stillcap records there every file it writes into a folder a user named (report
  folders, ``--out`` folders, the folder of a CSV, BVH or C3D file, ...). A report's folder
  lists its file names (glob patterns such as ``overlays/*.png``) before they are written, so
  that a report cut short (a full disk) is still recognised as stillcap's.

:func:`record_outputs` writes the manifests; :func:`save_fallback` keeps a result whose output
could not be written (a temporary folder).
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
import tempfile
from pathlib import Path, PurePosixPath

from stillcap.files.atomic import write_text

__all__ = ["MANIFEST", "check_writable", "is_stillcap_output", "mark_folder", "record_outputs", "save_fallback"]

#: The manifest stillcap writes into the folders it writes outputs into.
MANIFEST = ".stillcap-output.json"
_MANIFEST_FORMAT = "stillcap-output"
#: Bytes at the start of a file that mark it as stillcap's.
_SIGNATURES = (re.compile(rb'"format"\s*:\s*"stillcap-'), re.compile(rb"<authoring_tool>\s*stillcap\s*<"),
               re.compile(rb'"generator"\s*:\s*"stillcap"'))
_HEAD_BYTES = 65536
_GLOB = re.compile(r"[*?\[]")
_LEVELS = 3  # a manifest lists files of its folder and of sub-folders up to two levels down


def _name(option: str, path: Path) -> str:
    return f"{option} {path}" if option else str(path)


def _nearest_existing(path: Path) -> Path:
    p = path
    while not os.path.lexists(p):
        if p.parent == p:
            break
        p = p.parent
    return p


def _probe(folder: Path) -> str | None:
    """Why nothing can be written in ``folder`` (None: a file could be made and removed there).

    A real file is made, as ``os.access`` says yes to root in a read-only folder and knows
    nothing of read-only filesystems or full disks' quotas."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".stillcap-probe-", dir=folder)
    except OSError as e:
        return e.strerror or type(e).__name__
    os.close(fd)
    try:
        os.unlink(tmp)
    except OSError:
        pass
    return None


def _manifest(folder: Path) -> dict | None:
    try:
        d = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(d, dict) or d.get("format") != _MANIFEST_FORMAT or not isinstance(d.get("files"), list):
        return None
    return d


def _listed(path: Path) -> bool:
    path = Path(os.path.abspath(path))
    for level, folder in enumerate(path.parents):
        if level >= _LEVELS:
            break
        m = _manifest(folder)
        if m is None:
            continue
        rel = path.relative_to(folder).as_posix()
        if any(rel == f or (_GLOB.search(f) and fnmatch.fnmatchcase(rel, f)) for f in m["files"] if isinstance(f, str)):
            return True
    return False


def _signed(path: Path) -> bool:
    """Whether the first bytes of the file ``path`` say stillcap wrote it."""
    try:
        with open(path, "rb") as f:
            head = f.read(_HEAD_BYTES)
    except OSError:
        return False
    return any(s.search(head) for s in _SIGNATURES)


def is_stillcap_output(path) -> bool:
    """Whether the file ``path`` is absent, empty, or written by stillcap (see the module's
    description: a signature in its first bytes, or listed in a manifest)."""
    path = Path(path)
    try:
        if not path.exists() or (path.is_file() and path.stat().st_size == 0):
            return True
    except OSError:
        return False
    return path.is_file() and (_signed(path) or _listed(path))


def _check_file(path: Path, option: str, force: bool) -> None:
    where = _name(option, path)
    if path.is_dir():
        raise ValueError(f"{where} is a folder; give a file name")
    base = _nearest_existing(path.parent)
    if not base.is_dir():
        raise ValueError(f"{where}: {base} is a file, not a folder")
    why = _probe(base)
    if why is not None:
        raise ValueError(f"{where}: cannot write in the folder {base} ({why})")
    if path.exists() and not path.is_file():
        raise ValueError(f"{where} is not a regular file (a device, a pipe?); give a file name")
    if path.exists() and not force and not is_stillcap_output(path):
        raise ValueError(f"{where} exists and was not written by stillcap; pass --force to overwrite it")


def _check_folder(path: Path, option: str, force: bool, names) -> None:
    where = _name(option, path)
    base = _nearest_existing(path)
    if not base.is_dir():
        raise ValueError(f"{where} is a file, not a folder" if base == path else
                         f"{where}: {base} is a file, not a folder")
    why = _probe(base)
    if why is not None:
        raise ValueError(f"{where}: cannot write in the folder {base} ({why})")
    if base != path or force:
        return
    if names is None:  # the files it will write are not known: a folder stillcap made, or an empty one
        if _manifest(path) is None and any(e.name != MANIFEST for e in os.scandir(path)):
            raise ValueError(f"{where} holds files stillcap did not write; pass --force to write into it")
        return
    for pattern in names:
        glob = bool(_GLOB.search(pattern))
        for p in sorted(path.glob(pattern)) if glob else [path / pattern]:
            if p.is_dir() and not glob:
                raise ValueError(f"{where}: {p} is a folder where a file is written; remove or rename it")
            if p.is_file() and not is_stillcap_output(p):
                raise ValueError(f"{where}: {p.relative_to(path).as_posix()} exists and was not written by "
                                 "stillcap; pass --force to overwrite it")


def check_writable(path, kind: str = "file", *, option: str = "", force: bool = False, names=None) -> Path:
    """Check that stillcap can write ``path`` before the work starts; return it as a Path.

    Parameters
    ----------
    path : path
        The file or folder to write (need not exist).
    kind : {"file", "folder"}
    option : str
        The command-line option or argument that named it (``"--report"``), for the message.
    force : bool
        Allow overwriting files stillcap did not write (``--force``).
    names : iterable of str, optional
        Folders: the files that will be written in it (relative paths, glob patterns allowed);
        an existing one must be a stillcap output. Without ``names`` an existing folder must
        be empty or hold stillcap's manifest.

    Raises
    ------
    ValueError
        One line naming the path and the problem: a folder given for a file or a file for a
        folder, a parent that is a file, a folder where nothing can be written (read-only,
        missing permission, a read-only filesystem), or an existing file stillcap did not
        write (without ``force``).
    """
    if kind not in ("file", "folder"):
        raise ValueError(f"kind must be 'file' or 'folder', got {kind!r}")
    path = Path(path)
    if str(path) == "" or "\x00" in str(path):
        raise ValueError(f"{_name(option, path)}: not a path")
    if kind == "file":
        _check_file(path, option, force)
    else:
        _check_folder(path, option, force, names)
    return path


def record_outputs(paths, root=None) -> None:
    """Record ``paths`` (files just written) as stillcap outputs in the manifest of ``root``
    (paths relative to it) or, without ``root``, of each file's folder.

    Without ``root``, files that carry a signature (JSON ``"format": "stillcap-..."``, ...) are
    not recorded: they need no manifest. Nothing is raised when a manifest cannot be written: the outputs
    are written, only a later overwrite will ask for ``--force``."""
    groups: dict[Path, set] = {}
    for p in paths:
        p = Path(os.path.abspath(p))
        if root is None and _signed(p):
            continue
        folder = Path(os.path.abspath(root)) if root is not None else p.parent
        try:
            rel = PurePosixPath(p.relative_to(folder).as_posix())
        except ValueError:
            folder, rel = p.parent, PurePosixPath(p.name)
        groups.setdefault(folder, set()).add(str(rel))
    for folder, files in groups.items():
        old = _manifest(folder)
        listed = set(old["files"]) if old else set()
        if old is None or not files <= listed:
            _write_manifest(folder, listed | files)


def _write_manifest(folder: Path, files) -> None:
    data = {"format": _MANIFEST_FORMAT, "version": 1,
            "about": "files stillcap wrote here; stillcap overwrites them without --force (docs/errors.md)",
            "files": sorted(files)}
    try:
        write_text(folder / MANIFEST, json.dumps(data, indent=1) + "\n")
    except OSError:
        pass


def mark_folder(folder) -> None:
    """Make ``folder`` (created if needed) a stillcap output folder: an empty manifest, so that
    stillcap writes into it again without ``--force``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if _manifest(folder) is None:
        _write_manifest(folder, ())


def save_fallback(text: str, name: str) -> Path | None:
    """Write ``text`` as ``name`` in a new temporary folder (``stillcap-unsaved-*``): the place a
    result goes when its output could not be written. None when even that fails."""
    try:
        folder = Path(tempfile.mkdtemp(prefix="stillcap-unsaved-"))
        return write_text(folder / name, text)
    except OSError:
        return None
