"""Exporters keyed by file extension (one module per format), in the style of trimesh's
``exchange`` package.

>>> from stillcap.body import Skeleton
>>> from stillcap.io.export import export
>>> export("pose.dae", Skeleton.puppet().rest_pose())   # doctest: +SKIP

Inputs (anything :func:`as_export_data` accepts): a :class:`~stillcap.body.Pose`, an
:class:`~stillcap.body.Animation`, :class:`~stillcap.body.MarkerTrajectories`, an
:class:`ExportData`, a tuple of these, or a result object with ``pose`` / ``animation`` /
``markers`` attributes. Every writer writes atomically (``stillcap.files.atomic``) and returns the
path. Heavy optional dependencies (pycollada is not needed; pygltflib, ezc3d) are imported only
inside the writer that needs them, with an install hint when missing.

Formats and units: see ``docs/exports.md``.
"""

from stillcap.io.export._base import (EXPORTERS, ExportData, as_export_data, export, known_extensions, register,
                                      require, stick_mesh)

# Register the writers (each imports its heavy dependency lazily, inside the writer).
from stillcap.io.export import bvh, c3d, collada, gltf, table  # noqa: E402,F401

__all__ = ["EXPORTERS", "ExportData", "as_export_data", "export", "register", "known_extensions", "require", "stick_mesh"]
