"""stillcap: optical motion capture from still photographs taken with commodity cameras."""

from stillcap.camera import Camera, Rig

__all__ = ["Camera", "Rig"]
__version__ = "0.1.0"
