"""The synthetic studio: renders what each camera of a rig would photograph, with ground truth.

Scene model in :mod:`stillcap.studio.scene`, renderer in :mod:`stillcap.studio.renderer`, sensor
in :mod:`stillcap.studio.sensor`, ball marker sets in :mod:`stillcap.studio.markers` and ready-made
scenarios (chessboard sets, marker scenes) in :mod:`stillcap.studio.scenes`. Drawn (not ray-cast)
bead photos for the bead detector are in :mod:`stillcap.studio.beads`. See ``docs/studio.md``.
"""

from stillcap.studio.renderer import render, render_radiance
from stillcap.studio.scene import (Backdrop, Capsule, Exposure, Flash, PointLight, Scene, Sphere,
                                   SphereMarker, TexturedPlane, target_planes)
from stillcap.studio.sensor import Sensor
from stillcap.studio.markers import baseball_markers
from stillcap.studio.scenes import chessboard_set, default_camera, marker_rig, marker_scene

__all__ = ["Backdrop", "Capsule", "Exposure", "Flash", "PointLight", "Scene", "Sensor", "Sphere",
           "SphereMarker", "TexturedPlane", "baseball_markers", "chessboard_set", "default_camera",
           "marker_rig", "marker_scene", "render", "render_radiance", "target_planes"]
