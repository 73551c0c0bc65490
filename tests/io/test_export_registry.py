"""The export registry, input normalisation, atomic writes, lazy optional imports, CSV/JSON."""

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from stillcap.body import MarkerTrajectories, Skeleton
from stillcap.io import export as ex

sys.path.insert(0, str(Path(__file__).parent))  # the shared test helper beside this file
from stillcap_external_tools import puppet_motion  # noqa: E402


@pytest.fixture(scope="module")
def motion():
    return puppet_motion()


def test_registry_knows_every_format():
    assert set(ex.EXPORTERS) >= {".dae", ".bvh", ".gltf", ".glb", ".c3d", ".csv", ".json"}
    assert ex.known_extensions() == sorted(ex.EXPORTERS)


def test_unknown_extension_lists_the_known_ones(tmp_path):
    pose = Skeleton.puppet().rest_pose()
    with pytest.raises(ValueError, match=r"unknown extension '\.fbx'; known: \.bvh, \.c3d, \.csv, \.dae"):
        ex.export(tmp_path / "x.fbx", pose)
    with pytest.raises(ValueError, match=r"unknown extension '\(none\)'"):
        ex.export(tmp_path / "x", pose)


def test_register_adds_a_writer(tmp_path, monkeypatch):
    monkeypatch.setitem(ex.EXPORTERS, ".xyz", None)  # removed again after the test
    seen = {}

    @ex.register("XYZ")
    def write_xyz(path, data, **options):
        seen.update(data=data, options=options)
        return path

    assert ".xyz" in ex.EXPORTERS
    ex.export(tmp_path / "a.XYZ", Skeleton.puppet().rest_pose(), flag=1)
    assert seen["options"] == {"flag": 1} and seen["data"].single_pose


def test_inputs_are_normalised(motion):
    anim, markers, pose = motion
    d = ex.as_export_data(pose)
    assert d.single_pose and d.animation.n_frames == 1 and d.markers is None
    d = ex.as_export_data((anim, markers))
    assert d.animation is anim and d.markers is markers and not d.single_pose

    class Result:  # a pipeline result with attributes
        def __init__(self):
            self.pose, self.markers = pose, markers

    d = ex.as_export_data(Result())
    assert d.single_pose and d.markers is markers
    with pytest.raises(ValueError, match="cannot export an object of type int"):
        ex.as_export_data(3)
    with pytest.raises(ValueError, match="two skeleton motions"):
        ex.as_export_data((anim, pose))


def test_formats_that_need_motion_say_so(tmp_path, motion):
    _, markers, _ = motion
    for ext in (".dae", ".bvh", ".gltf"):
        with pytest.raises(ValueError, match="needs a Pose or an Animation"):
            ex.export(tmp_path / f"m{ext}", markers)


def test_missing_optional_dependency_gives_an_install_hint(tmp_path, monkeypatch, motion):
    monkeypatch.setitem(sys.modules, "pygltflib", None)  # makes "import pygltflib" fail
    with pytest.raises(ImportError, match="pip install pygltflib"):
        ex.export(tmp_path / "a.glb", motion[2])
    monkeypatch.setitem(sys.modules, "ezc3d", None)
    with pytest.raises(ImportError, match="pip install ezc3d"):
        ex.export(tmp_path / "a.c3d", motion[1])


def test_atomic_writes_keep_the_old_file_on_error(tmp_path, motion):
    anim, _, _ = motion
    target = tmp_path / "keep.bvh"
    target.write_text("old")
    nonuniform = type(anim)(anim.skeleton, anim.times ** 1.5 + anim.times, anim.root2world, anim.local_rotations)
    with pytest.raises(ValueError, match="uniformly spaced"):
        ex.export(target, nonuniform)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.bvh"]


def test_csv_has_units_in_the_header_and_blank_unseen(tmp_path, motion):
    anim, markers, _ = motion
    path = ex.export(tmp_path / "t.csv", (anim, markers), length_unit="mm")
    rows = list(csv.DictReader(path.open()))
    assert list(rows[0]) == ["frame", "time_s", "kind", "name", "x_mm", "y_mm", "z_mm"]
    n_m, n_j = markers.n_markers * markers.n_frames, anim.skeleton.n_joints * anim.n_frames
    assert len(rows) == n_m + n_j
    joints = [r for r in rows if r["kind"] == "joint"]
    got = np.array([[float(r[k]) for k in ("x_mm", "y_mm", "z_mm")] for r in joints]).reshape(anim.positions.shape)
    np.testing.assert_allclose(got / 1000, anim.positions, atol=1e-12)
    unseen = [r for r in rows if r["kind"] == "marker" and r["frame"] == "2" and r["name"] == markers.names[0]]
    assert unseen[0]["x_mm"] == "" and float(unseen[0]["time_s"]) == pytest.approx(2 / 24)


def test_json_round_trips_positions_and_rotations(tmp_path, motion):
    anim, markers, _ = motion
    doc = json.loads(ex.export(tmp_path / "t.json", (anim, markers)).read_text())
    assert doc["length_unit"] == "m"
    pts = np.array([[[np.nan] * 3 if p is None else p for p in f] for f in doc["markers"]["positions_m"]], float)
    np.testing.assert_allclose(pts, markers.points, atol=1e-12)
    assert doc["markers"]["positions_m"][2][0] is None
    m = doc["motion"]
    skel = Skeleton.from_dict(m["skeleton"])
    from scipy.spatial.transform import Rotation

    local = Rotation.from_quat(np.reshape(m["local_rotations_xyzw"], (-1, 4))).as_matrix().reshape(anim.local_rotations.shape)
    rebuilt = type(anim)(skel, m["times_s"], m["root2world_m"], local)
    np.testing.assert_allclose(rebuilt.positions, anim.positions, atol=1e-9)
    np.testing.assert_allclose(m["positions_m"], anim.positions, atol=1e-9)


def test_markers_only_json_and_csv(tmp_path):
    traj = MarkerTrajectories.single(["a", "b"], [[0, 0, 0], [np.nan, 1, 2]])
    doc = json.loads(ex.export(tmp_path / "m.json", traj).read_text())
    assert "motion" not in doc and doc["markers"]["positions_m"][0][1] is None
    assert ex.export(tmp_path / "m.csv", traj).read_text().count("\n") == 3


@pytest.mark.parametrize("ext, signed", [(".dae", True), (".gltf", True), (".glb", True), (".json", True),
                                         (".bvh", False), (".csv", False), (".c3d", False)])
def test_exports_are_recognised_as_stillcap_outputs(motion, tmp_path, ext, signed):
    """COLLADA, glTF, GLB and JSON say in their first bytes that stillcap wrote them; the others
    are recognised by the manifest the CLI records them in (stillcap.files.outputs)."""
    from stillcap.files.outputs import is_stillcap_output, record_outputs

    if ext == ".c3d":
        pytest.importorskip("ezc3d")
    anim, markers, _ = motion
    path = ex.export(tmp_path / f"motion{ext}", [anim, markers] if ext in (".json", ".csv", ".c3d") else anim)
    assert is_stillcap_output(path) == signed
    record_outputs([path])
    assert is_stillcap_output(path)
