"""Puppet projects (SPEC J3 "Files"): photos, their turn angles or cameras, identified markers.

- :mod:`~stillcap.io.project._project`: :class:`Project` (create, load, save, views, edits,
  observations and 3D markers) and how a project file is read;
- :mod:`~stillcap.io.project._records`: the file's constants and records (:class:`TurntableSetup`,
  :class:`Edit`, :class:`View`, :class:`Markers3D`), :data:`BUILTIN_MARKERSETS` and
  :func:`dumps_json` (the file's layout for people).

The folder layout and the rules (paths stay inside the folder, atomic writes) are described in
:mod:`~stillcap.io.project._project` and ``docs/project-format.md``.
"""

from stillcap.files.paths import resolve_inside, safe_relpath
from stillcap.io.project._project import Project
from stillcap.io.project._records import (BUILTIN_MARKERSETS, PHOTOS_DIR, PROJECT_FILE, PROJECT_FORMAT, PROJECT_VERSION,
                                          Edit, Markers3D, TurntableSetup, View, dumps_json)

__all__ = ["PROJECT_FORMAT", "PROJECT_VERSION", "PROJECT_FILE", "PHOTOS_DIR", "dumps_json", "TurntableSetup", "Edit",
           "View", "Markers3D", "Project", "safe_relpath", "resolve_inside", "BUILTIN_MARKERSETS"]
