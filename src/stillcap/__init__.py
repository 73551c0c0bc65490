"""stillcap: optical motion capture from still photographs taken with commodity cameras.

``Camera`` and ``Rig`` (from :mod:`stillcap.camera`) are imported on first use (PEP 562), so
that ``import stillcap``, which every ``stillcap`` command runs first, does not load NumPy and
OpenCV: ``stillcap --help`` starts fast.
"""

__all__ = ["Camera", "Rig"]
__version__ = "0.1.0"


def __getattr__(name: str):
    if name in __all__:
        from stillcap import camera

        value = globals()[name] = getattr(camera, name)
        return value
    raise AttributeError(f"module 'stillcap' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
