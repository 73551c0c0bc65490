"""C3D export: read back with ezc3d and with the independent `c3d` package (labels, rate, mm, NaN)."""

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from stillcap.body import MarkerTrajectories
from stillcap.io.export import export

sys.path.insert(0, str(Path(__file__).parent))  # the shared test helper beside this file
from stillcap_external_tools import puppet_motion, python_module  # noqa: E402


@pytest.fixture(scope="module")
def motion():
    return puppet_motion()


@pytest.fixture(scope="module")
def c3d_file(tmp_path_factory, motion):
    python_module("ezc3d")
    _, markers, _ = motion
    return export(tmp_path_factory.mktemp("c3d") / "markers.c3d", markers)


def test_ezc3d_reads_labels_rate_units_and_values(c3d_file, motion):
    ezc3d = python_module("ezc3d")
    _, markers, _ = motion
    c = ezc3d.c3d(str(c3d_file))
    p = c["parameters"]["POINT"]
    assert list(p["LABELS"]["value"]) == list(markers.names)
    assert p["RATE"]["value"][0] == pytest.approx(markers.frame_rate)
    assert list(p["UNITS"]["value"]) == ["mm"]
    pts = np.transpose(c["data"]["points"][:3], (2, 1, 0))  # (frames, markers, 3), mm
    np.testing.assert_array_equal(np.isnan(pts), np.isnan(markers.points))
    np.testing.assert_allclose(pts, markers.points * 1000, atol=1e-3, equal_nan=True)
    res = c["data"]["meta_points"]["residuals"][0].T
    assert np.all(res[~markers.seen] < 0)
    np.testing.assert_array_equal(res[markers.seen], 0.0)


def test_c3d_package_reads_the_same(c3d_file, motion):
    c3d = python_module("c3d")
    _, markers, _ = motion
    with open(c3d_file, "rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "no analog data"
        reader = c3d.Reader(f)
        assert [s.strip() for s in reader.point_labels] == list(markers.names)
        assert reader.point_rate == pytest.approx(markers.frame_rate)
        frames = [points for _, points, _ in reader.read_frames()]
    data = np.array(frames)  # (frames, markers, 5): x, y, z, residual, camera mask
    seen = data[..., 3] >= 0
    np.testing.assert_array_equal(seen, markers.seen)
    np.testing.assert_allclose(data[..., :3][seen], markers.points[markers.seen] * 1000, atol=1e-3)
    np.testing.assert_array_equal(data[..., 3][seen], 0.0)


def test_joint_positions_when_no_markers(tmp_path, motion):
    ezc3d = python_module("ezc3d")
    anim, markers, pose = motion
    c = ezc3d.c3d(str(export(tmp_path / "j.c3d", anim)))
    assert list(c["parameters"]["POINT"]["LABELS"]["value"]) == list(anim.skeleton.names)
    np.testing.assert_allclose(np.transpose(c["data"]["points"][:3], (2, 1, 0)), anim.positions * 1000, atol=1e-3)
    c = ezc3d.c3d(str(export(tmp_path / "both.c3d", (anim, markers), points="both")))
    assert len(c["parameters"]["POINT"]["LABELS"]["value"]) == markers.n_markers + anim.skeleton.n_joints
    with pytest.raises(ValueError, match="needs marker trajectories"):
        export(tmp_path / "x.c3d", pose, points="markers")


def test_single_frame_markers(tmp_path):
    ezc3d = python_module("ezc3d")
    traj = MarkerTrajectories.single(["a", "b"], [[0.1, 0.2, 0.3], [np.nan] * 3], frame_rate=1)
    c = ezc3d.c3d(str(export(tmp_path / "one.c3d", traj)))
    np.testing.assert_allclose(c["data"]["points"][:3, 0, 0], [100, 200, 300], atol=1e-3)
    assert np.isnan(c["data"]["points"][:3, 1, 0]).all()
