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


def run_cli(args, capsys):
    """Run ``stillcap ARGS`` in-process: ``(exit code, stdout, stderr)``."""
    from stillcap.cli import main

    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


PITCH_SIZE = (1280, 960)  # half the seed's resolution keeps the field of view; 4x cheaper to render and detect


def studio_pitch(factory, name, **kw):
    """Render a studio pitch (true rig) into the session's temp folder once; its folder."""
    from stillcap.studio.pitch import pitch_capture

    root = factory.getbasetemp() / f"pitch-{name}"
    if not (root / "capture.json").is_file():
        pc = pitch_capture(kw.pop("preset", "seed-4seam"), kw.pop("seed", 1), calibrate=False,
                           image_size=PITCH_SIZE, **kw)
        cap, images = pc.to_capture()
        cap.save(root, images)
    return root


def assert_same_reconstruction(one, two):
    """Two puppet results with the same circles, identifications, 2D and 3D markers and pose."""
    import numpy as np

    for a, b in zip(one.views, two.views):
        np.testing.assert_array_equal(a.circles.centers, b.circles.centers)
        np.testing.assert_array_equal(a.identification.cost, b.identification.cost)
    np.testing.assert_array_equal(one.markers.observations, two.markers.observations)
    np.testing.assert_array_equal(one.markers.points, two.markers.points)
    np.testing.assert_array_equal(one.pose.positions, two.pose.positions)


def untimed(x):
    """A result's JSON without its timings (they differ from run to run)."""
    if isinstance(x, dict):
        return {k: untimed(v) for k, v in x.items() if k not in ("timings_s", "fit_time_s")}
    if isinstance(x, list):
        return [untimed(v) for v in x]
    return x
