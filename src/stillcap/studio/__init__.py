"""The synthetic studio: renders what each camera of a rig would photograph, with ground truth.

Scene model in :mod:`stillcap.studio.scene`, renderer in :mod:`stillcap.studio.renderer`, sensor
in :mod:`stillcap.studio.sensor`, ball marker sets in :mod:`stillcap.studio.markers` and ready-made
scenarios (chessboard sets, marker scenes) in :mod:`stillcap.studio.scenes`. Drawn (not ray-cast)
bead photos for the bead detector are in :mod:`stillcap.studio.beads`. See ``docs/studio.md``.
"""

import importlib

#: Where each name of the package lives: imported on first use (PEP 562), so that importing a
#: submodule (e.g. ``stillcap.studio.compare.pitch``, which the CLI imports for a capture with a
#: truth) does not load the renderer and the scenes (~80 modules, 0.08 s).
_WHERE = {"render": "renderer", "render_radiance": "renderer", "Sensor": "sensor",
          "baseball_markers": "markers", "chessboard_set": "scenes", "default_camera": "scenes",
          "marker_rig": "scenes", "marker_scene": "scenes",
          **{n: "scene" for n in ("Backdrop", "Capsule", "Exposure", "Flash", "PointLight", "Scene", "Sphere",
                                  "SphereMarker", "TexturedPlane", "target_planes")}}

__all__ = ["Backdrop", "Capsule", "Exposure", "Flash", "PointLight", "Scene", "Sensor", "Sphere",
           "SphereMarker", "TexturedPlane", "baseball_markers", "chessboard_set", "default_camera",
           "marker_rig", "marker_scene", "render", "render_radiance", "target_planes"]


def __getattr__(name: str):
    if name in _WHERE:
        value = getattr(importlib.import_module(f"stillcap.studio.{_WHERE[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'stillcap.studio' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
