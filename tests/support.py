"""Test helpers shared by all test folders (importable as ``support``; tests/ is on pythonpath)."""

from pathlib import Path

import numpy as np
import pytest

from stillcap.camera import Camera, Rig, look_at

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def ring_rig(n=4, radius=3.0, height=1.0, dist=(0.0, 0.0, 0.0, 0.0, 0.0), size=(1280, 960), f=1100.0):
    """``n`` cameras on a circle around the origin, looking at it."""
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = (radius * np.cos(a), radius * np.sin(a), height)
        cams.append(Camera.from_intrinsics(f"cam_{i}", f, f * 1.002, size[0] / 2 + 3, size[1] / 2 - 2,
                                           size, dist=dist, world2cam=look_at(eye, (0, 0, 0))))
    return Rig(cams)


def shared_data(sub: str) -> Path:
    """Path to a folder of ../shared/data, or skip the test with a message saying why."""
    p = SHARED_DATA / sub
    if not p.exists():
        pytest.skip(f"real data folder {p} is absent (see shared/data/README.md)")
    return p
