"""Skeletons and marker sets named in capture folders and projects (``docs/skeleton.md``).

A ``capture.json`` or ``project.json`` names its puppet's skeleton and marker set under the keys
``skeleton`` and ``markerset``, each as a built-in name, ``{"file": PATH}`` (a file inside the
folder; a path that leads outside is refused) or the whole file embedded.
"""
from __future__ import annotations

from stillcap.body.markerset import BUILTIN_MARKERSETS, MarkerSet
from stillcap.body.skeleton import BUILTIN_SKELETONS, Skeleton

__all__ = ["body_entry", "body_entry_dict"]


def body_entry(entry, kind: str, root, where: str, source: str, key: str):
    """A marker set (``kind="markerset"``) or skeleton (``kind="skeleton"``) from a capture's or
    project's entry: a built-in name, ``{"file": PATH}`` (a file inside the folder ``root``:
    :func:`~stillcap.files.paths.resolve_inside`) or the whole file embedded.

    ``where`` starts the messages (``"capture FOLDER"``), ``source`` names the JSON file that
    holds an embedded one, ``key`` the entry's key; ValueError on a bad entry.
    """
    from stillcap.files.paths import resolve_inside

    cls, builtin = ((MarkerSet, BUILTIN_MARKERSETS) if kind == "markerset" else (Skeleton, BUILTIN_SKELETONS))
    word = "marker set" if kind == "markerset" else "skeleton"
    if isinstance(entry, str):
        if entry not in builtin:
            raise ValueError(f"{where}: unknown {word} {entry!r} (built-in: {', '.join(builtin)}; a file: "
                             f"{{\"file\": \"{kind}.json\"}})")
        return cls.builtin(entry)
    if isinstance(entry, dict) and set(entry) == {"file"}:
        path = resolve_inside(root, entry["file"], f"{where}: {key} file", "folder")
        if not path.is_file():
            raise ValueError(f"{where}: {key}: {word} file {path} does not exist")
        return cls.load(path)
    if isinstance(entry, dict):
        return cls.from_dict(entry, source=source, prefix=(key,))
    raise ValueError(f"{where}: '{key}' must be a built-in name or a {word} ({{\"file\": PATH}} or the file "
                     f"embedded), got {entry!r}")


def body_entry_dict(obj: MarkerSet | Skeleton) -> str | dict:
    """The entry that names ``obj`` in a project file: its built-in name if it equals a built-in,
    else the whole file (millimetres)."""
    if isinstance(obj, MarkerSet):
        d = obj.to_dict()
        for name in BUILTIN_MARKERSETS:
            if MarkerSet.builtin(name).to_dict() == d:
                return name
        return obj.to_dict("mm")
    d = obj.to_dict()
    for name in BUILTIN_SKELETONS:
        if Skeleton.builtin(name).to_dict() == d:
            return name
    return obj.to_dict("mm")
