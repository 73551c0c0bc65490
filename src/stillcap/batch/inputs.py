"""The captures of a batch: what each one is (kind, name, pitch type) and the hash of its inputs.

Everything here runs on the client before any task is sent: a capture that is missing, has no
readable ``capture.json`` or is of a kind the batch does not analyse is bad input (a
``ValueError`` naming it; nothing runs). Whether its photos decode, its rig loads and so on is
the analysis's business, on a worker, where a failure is isolated to its capture.

The content hash covers every file the analysis reads (``capture.json``, the rig file, every
photo listed, ``truth.json`` when there is one: the per-capture JSON compares with it) and the
options, so a capture whose files or options changed is analysed again, and one that only moved
or was renamed is not.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from stillcap.files.jsonfile import read_json
from stillcap.files.paths import resolve_inside

__all__ = ["KINDS", "BatchInput", "content_hash", "read_capture_list", "read_inputs"]

#: The kinds of capture a batch analyses (``capture.json`` ``"kind"``) and the command that
#: analyses one of them alone.
KINDS = {"pitch": "stillcap pitch", "hand": "stillcap hand", "puppet": "stillcap puppet run",
         "markers": "stillcap markers"}
_CHUNK = 1 << 20


@dataclass(frozen=True)
class BatchInput:
    """One capture of a batch.

    Parameters
    ----------
    path : str
        The capture folder, absolute (what the worker reads: its files never travel).
    kind : str
        One of :data:`KINDS`.
    name : str
        The folder's name (the per-capture results go under ``captures/NAME``; made unique).
    pitch_type : str
        ``capture.json``'s ``"pitch_type"`` for pitches when given, else ``"unknown"``; ``""``
        for other kinds.
    files : tuple of str
        The files the analysis reads, relative to ``path`` (for the content hash).
    """

    path: str
    kind: str
    name: str
    pitch_type: str
    files: tuple


def read_capture_list(path) -> list[Path]:
    """The capture folders listed in a text file (``--from``): one a line; blank lines and lines
    starting with ``#`` are skipped; relative paths are relative to the list's folder."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"--from {path}: the list file does not exist")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"--from {path}: not a UTF-8 text file ({e.reason} at byte {e.start})") from None
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            p = Path(line).expanduser()
            out.append(p if p.is_absolute() else path.parent / p)
    return out


def _describe(folder: Path) -> tuple[str, str, tuple]:
    """``(kind, pitch_type, files)`` of a capture folder from its ``capture.json`` alone."""
    if not folder.is_dir():
        raise ValueError(f"capture folder {folder} does not exist")
    cfile = folder / "capture.json"
    if not cfile.is_file():
        raise ValueError(f"{cfile} does not exist: {folder} is not a capture folder")
    d = read_json(cfile)
    if not isinstance(d, dict):
        raise ValueError(f"{cfile}: (the whole file): a capture file must be an object")
    kind = d.get("kind")
    if kind not in KINDS:
        raise ValueError(f"{cfile}: kind: {kind!r} is not a kind the batch analyses ({', '.join(KINDS)})")
    files = ["capture.json"]
    for key in ("rig", "truth"):
        v = d.get(key, "rig.json" if key == "rig" else None)
        if isinstance(v, str):
            files.append(v)
    for im in d.get("images") or []:
        if isinstance(im, dict) and isinstance(im.get("file"), str):
            files.append(im["file"])
    pitch_type = ""
    if kind == "pitch":
        pt = d.get("pitch_type")
        pitch_type = pt.strip() if isinstance(pt, str) and pt.strip() else "unknown"
    return kind, pitch_type, tuple(files)


def read_inputs(captures) -> list[BatchInput]:
    """The :class:`BatchInput` of every capture folder, in the order given (a folder given twice
    is kept once). ``ValueError`` naming the first bad one (and how many more there are)."""
    out, seen, problems = [], set(), []
    names: dict[str, int] = {}
    for c in captures:
        folder = Path(c).expanduser()
        if folder.name == "capture.json":
            folder = folder.parent
        folder = folder.absolute()
        if str(folder) in seen:
            continue
        seen.add(str(folder))
        try:
            kind, pitch_type, files = _describe(folder)
        except ValueError as e:
            problems.append(str(e))
            continue
        base = folder.name or "capture"
        names[base] = names.get(base, 0) + 1
        name = base if names[base] == 1 else f"{base}-{names[base]}"
        out.append(BatchInput(str(folder), kind, name, pitch_type, files))
    if problems:
        more = f" (and {len(problems) - 1} more bad capture(s))" if len(problems) > 1 else ""
        raise ValueError(problems[0] + more)
    if not out:
        raise ValueError("no captures given (CAPTURES... or --from LIST)")
    return out


def content_hash(inp: BatchInput, options: dict) -> str:
    """SHA-256 (hex) of the capture's input files (their names and bytes) and of ``options``
    (JSON with sorted keys). A listed file that is missing or outside the folder counts by its
    name alone: the analysis will name the problem."""
    h = hashlib.sha256()
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    root = Path(inp.path)
    for rel in inp.files:
        h.update(b"\x00file\x00" + rel.encode("utf-8", "surrogateescape") + b"\x00")
        try:
            p = resolve_inside(root, rel, "capture file", "capture folder")
            with open(p, "rb") as f:
                while chunk := f.read(_CHUNK):
                    h.update(chunk)
        except (OSError, ValueError):
            h.update(b"\x00missing\x00")
    return h.hexdigest()
