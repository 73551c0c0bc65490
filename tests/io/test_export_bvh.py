"""BVH export and the BVH reader: structure, units, round trips, real files."""

import sys
from pathlib import Path

import numpy as np
import pytest

from stillcap.body import Animation
from stillcap.io.bvh_read import read_bvh
from stillcap.io.export import export

sys.path.insert(0, str(Path(__file__).parent))  # the shared test helper beside this file
from stillcap_external_tools import puppet_motion, shared_data  # noqa: E402


@pytest.fixture(scope="module")
def motion():
    return puppet_motion()


def test_hierarchy_and_motion_lines(tmp_path, motion):
    anim, _, _ = motion
    text = export(tmp_path / "a.bvh", anim).read_text()
    lines = text.splitlines()
    assert lines[:4] == ["HIERARCHY", "ROOT root", "{", "  OFFSET 0.000000 0.000000 0.000000"]
    assert "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" in lines
    assert text.count("End Site") == 5  # toes x2, head, fingers x2
    i = lines.index("MOTION")
    assert lines[i + 1 : i + 3] == ["Frames: 5", "Frame Time: 0.0416666667"]
    values = np.array(lines[i + 3].split(), float)
    assert values.size == 6 + 3 * (anim.skeleton.n_joints - 1)
    np.testing.assert_allclose(values[:3], anim.root2world[0, :3, 3] * 100, atol=1e-6)  # centimetres


@pytest.mark.parametrize("unit,order", [("cm", "ZXY"), ("m", "ZYX"), ("mm", "XYZ")])
def test_round_trip_through_the_reader(tmp_path, motion, unit, order):
    anim, _, _ = motion
    path = export(tmp_path / "a.bvh", anim, length_unit=unit, rotation_order=order)
    back = read_bvh(path, length_unit=unit, end_sites=False)
    assert back.skeleton.names == anim.skeleton.names
    np.testing.assert_allclose(back.times, anim.times, atol=1e-9)
    tol = {"cm": 1e-7, "m": 1e-5, "mm": 1e-8}[unit]  # 6 decimals in the file's unit
    np.testing.assert_allclose(back.positions, anim.positions, atol=tol)


def test_single_pose_and_rate_rules(tmp_path, motion):
    anim, _, pose = motion
    text = export(tmp_path / "p.bvh", pose).read_text()
    assert "Frames: 1" in text and "Frame Time: 0.0333333333" in text
    np.testing.assert_allclose(read_bvh(tmp_path / "p.bvh", end_sites=False).positions[0], pose.positions, atol=1e-7)
    odd = Animation(anim.skeleton, [0, 0.1, 0.3, 0.35, 0.5], anim.root2world, anim.local_rotations)
    with pytest.raises(ValueError, match="uniformly spaced"):
        export(tmp_path / "odd.bvh", odd)
    with pytest.raises(ValueError, match="permutation"):
        export(tmp_path / "x.bvh", pose, rotation_order="XXY")


def test_reader_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n0 0 0\n")
    with pytest.raises(ValueError, match=r"bad\.bvh: expected 2 frames x 3 channels = 6 values, got 3"):
        read_bvh(bad)
    bad.write_text("HIERARCHY\nROOT a\n{\n OFFSET 0 0\n")
    with pytest.raises(ValueError, match=r"bad\.bvh"):
        read_bvh(bad)
    bad.write_text(
        "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n JOINT b\n {\n OFFSET 0 1 0\n"
        " CHANNELS 3 Xposition Yposition Zposition\n End Site\n {\n OFFSET 0 1 0\n }\n }\n}\nMOTION\nFrames: 1\n"
        "Frame Time: 0.1\n0 0 0 0 5 0\n"
    )
    with pytest.raises(ValueError, match="joint 'b' has moving position channels"):
        read_bvh(bad)


@pytest.mark.parametrize("name,n_frames,fps", [("walk01", 101, 24), ("test_mocapbank", 455, 30)])
def test_real_bvh_files_read_and_round_trip(tmp_path, name, n_frames, fps):
    src = shared_data("bvh") / f"{name}.bvh"
    anim = read_bvh(src)
    assert anim.n_frames == n_frames and anim.frame_rate == pytest.approx(fps, rel=1e-4)
    assert anim.skeleton.n_joints == 19 + 5  # 19 joints and 5 end sites
    heights = anim.positions[..., 1]
    assert 1.3 < np.ptp(heights[0]) < 2.2  # a person in metres (the files are in centimetres)
    back = read_bvh(export(tmp_path / f"{name}.bvh", anim), end_sites=True)
    idx = [back.skeleton.index(n) for n in anim.skeleton.names]
    np.testing.assert_allclose(back.positions[:, idx], anim.positions, atol=2e-6)
