"""rig.json checked by its schema (camera.RigFile, camera.CameraEntry): every bad value gives one
ValueError naming the file, the key path and the camera."""

import json

import numpy as np
import pytest

from stillcap.camera import Camera, Rig
from support import ring_rig


def _rig_dict():
    return json.loads(json.dumps(ring_rig(2, dist=(0.1, -0.05, 0.001, 0.0, 0.0)).to_dict()))


def _load(tmp_path, d):
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(d))
    return Rig.load(path)


def _set(d, path, value):
    *head, last = path
    for k in head:
        d = d[k]
    if value is _DELETE:
        del d[last]
    else:
        d[last] = value


_DELETE = object()
NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("path, value, message", [
    (("cameras", 1, "K", 0, 0), NAN, r"camera 'cam_1': cameras.1.K.0.0: input should be a finite number \(got nan\)"),
    (("cameras", 1, "K", 0, 0), -1100.0, r"camera 'cam_1': cameras.1.K.0.0: input should be greater than 0 \(got -1100.0\)"),
    (("cameras", 0, "K", 1, 1), 0, r"camera 'cam_0': cameras.0.K.1.1: input should be greater than 0 \(got 0\)"),
    (("cameras", 0, "K", 0, 2), INF, r"cameras.0.K.0.2: input should be a finite number"),
    (("cameras", 0, "K", 0, 0), 1e300, r"cameras.0.K.0.0: input should be less than or equal to 1000000"),
    (("cameras", 0, "K", 0, 0), "1100", r"cameras.0.K.0.0: input should be a valid number \(got '1100'\)"),
    (("cameras", 0, "K", 0, 0), {"fx": 1}, r"cameras.0.K.0.0: input should be a valid number \(got \{'fx': 1\}\)"),
    (("cameras", 0, "K", 2, 2), 2.0, r"cameras.0.K.2.2: must be 1 \(K is \[\[fx, s, cx\], \[0, fy, cy\], \[0, 0, 1\]\]\)"),
    (("cameras", 0, "K", 1, 0), 5.0, r"cameras.0.K.1.0: must be 0"),
    (("cameras", 0, "K", 2), [0, 0], r"cameras.0.K.2.2: field required"),
    (("cameras", 0, "dist", 0), 1e308, r"camera 'cam_0': cameras.0.dist.0: input should be less than or equal to 1000 \(got 1e\+308\)"),
    (("cameras", 0, "dist", 1), NAN, r"cameras.0.dist.1: input should be a finite number"),
    (("cameras", 0, "dist"), [0.1] * 8, r"cameras.0.dist: only the 5-parameter distortion \(k1, k2, p1, p2, k3\) is supported; coefficient 5 is 0.1"),
    (("cameras", 0, "dist"), 0.1, r"cameras.0.dist: input should be a valid list"),
    (("cameras", 0, "image_size"), [1280, 1e308], r"cameras.0.image_size.1: input should be a valid integer \(got 1e\+308\)"),
    (("cameras", 0, "image_size"), [1280, 0], r"cameras.0.image_size.1: input should be greater than or equal to 1"),
    (("cameras", 0, "image_size"), [1280, 200000], r"cameras.0.image_size.1: input should be less than or equal to 100000"),
    (("cameras", 0, "image_size"), [1280.5, 960], r"cameras.0.image_size.0: input should be a valid integer"),
    (("cameras", 0, "image_size"), [True, 960], r"cameras.0.image_size.0: input should be a valid integer \(got True\)"),
    (("cameras", 0, "image_size"), [1280], r"cameras.0.image_size.1: field required"),
    (("cameras", 0, "world2cam", 0, 0), 2.0, r"cameras.0.world2cam: must be a rigid transform: its rotation part \(3x3\) is not a proper rotation \(R R\^T differs from I by [0-9.]+, det\(R\) = [0-9.-]+\)"),
    (("cameras", 0, "world2cam", 3), [0, 0, 1, 1], r"cameras.0.world2cam: must be a rigid transform: its last row must be \[0, 0, 0, 1\]"),
    (("cameras", 0, "world2cam", 1, 3), NAN, r"cameras.0.world2cam.1.3: input should be a finite number"),
    (("cameras", 0, "world2cam", 1, 3), 1e300, r"cameras.0.world2cam.1.3: input should be less than or equal to 1000000000"),
    (("cameras", 0, "world2cam"), [[1, 0, 0, 0]], r"cameras.0.world2cam: list should have at least 3 items"),
    (("cameras", 0, "name"), 7, r"rig.json: cameras.0.name: input should be a valid string \(got 7\)"),
    (("cameras", 0, "name"), "", r"rig.json: cameras.0.name: string should have at least 1 character"),
    (("cameras", 1, "name"), "cam_0", r"rig.json: cameras.1.name: camera name 'cam_0' is used twice \(also cameras.0\); names must be unique"),
    (("cameras", 0, "K"), _DELETE, r"camera 'cam_0': cameras.0.K: field required"),
    (("cameras", 1), "cam", r"rig.json: cameras.1: input should be a valid dictionary \(got 'cam'\)"),
    (("cameras",), [], r"rig.json: cameras: list should have at least 1 item"),
    (("cameras",), {"a": 1}, r"rig.json: cameras: input should be a valid list"),
    (("version",), 2, r"rig.json: version: must be a rig file version this stillcap reads \(1\) \(got 2\)"),
    (("version",), 0, r"rig.json: version: must be a rig file version this stillcap reads \(1\) \(got 0\)"),
    (("version",), "1", r"rig.json: version: input should be a valid integer"),
    (("units",), "inch", r"rig.json: units: input should be 'm', 'cm' or 'mm' \(got 'inch'\)"),
    (("world",), None, r"rig.json: world: input should be a valid string \(got None\)"),
    (("format",), "stillcap-capture", r"rig.json: format: not a stillcap rig file \(expected \"format\": \"stillcap-rig\", got 'stillcap-capture'\)"),
])
def test_bad_values_name_the_file_the_key_and_the_camera(tmp_path, path, value, message):
    d = _rig_dict()
    _set(d, path, value)
    with pytest.raises(ValueError, match=message) as e:
        _load(tmp_path, d)
    assert str(e.value).startswith(str(tmp_path / "rig.json") + ": ")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("content, message", [
    ([1, 2], r"rig.json: format: not a stillcap rig file \(expected \"format\": \"stillcap-rig\", got a JSON list\)"),
    (None, r"got a JSON NoneType"),
])
def test_not_a_rig(tmp_path, content, message):
    with pytest.raises(ValueError, match=message):
        _load(tmp_path, content)


def test_valid_variants_load(tmp_path):
    d = _rig_dict()
    d.pop("version")  # optional (1)
    d["cameras"][0].pop("dist")  # none
    d["cameras"][0]["world2cam"] = d["cameras"][0]["world2cam"][:3]  # 3x4
    d["cameras"][1]["dist"] = [0.1, -0.05, 0.001, 0.0]  # 4 coefficients, the rest zero
    d["cameras"][1]["note"] = "kept"  # extra keys are allowed
    rig = _load(tmp_path, d)
    np.testing.assert_array_equal(rig[0].world2cam, ring_rig(2)[0].world2cam)
    np.testing.assert_array_equal(rig[0].dist, np.zeros(5))
    np.testing.assert_allclose(rig[1].dist, [0.1, -0.05, 0.001, 0.0, 0.0])
    assert rig[0].image_size == (1280, 960) and isinstance(rig[0].image_size[0], int)


def test_saved_rigs_load_back_the_same(tmp_path):
    rig = ring_rig(3, dist=(0.1, -0.05, 0.001, 0.002, 0.01))
    rig.save(tmp_path / "rig.json")
    back = Rig.load(tmp_path / "rig.json")
    for a, b in zip(rig, back):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.dist, b.dist)
        np.testing.assert_array_equal(a.world2cam, b.world2cam)


def test_embedded_rig_and_camera_entries_take_a_prefix():
    d = _rig_dict()
    d["cameras"][1]["K"][0][0] = -1.0
    with pytest.raises(ValueError, match=r"^project.json: rig: camera 'cam_1': rig.cameras.1.K.0.0: input should be "
                                         r"greater than 0 \(got -1.0\)$"):
        Rig.from_dict(d, "project.json: rig: ", prefix=("rig",))
    with pytest.raises(ValueError, match=r"^project.json: camera 'cam_0': turntable.camera.image_size.0: "):
        Camera.from_dict({**d["cameras"][0], "image_size": [-1, 2]}, "project.json: ", prefix=("turntable", "camera"))


def test_python_api_checks_stay():
    with pytest.raises(ValueError, match=r"camera 'x': image_size must be two whole numbers \(width, height\), got \(inf, 1\)"):
        Camera("x", np.eye(3), image_size=(float("inf"), 1))
    with pytest.raises(ValueError, match="duplicate camera names"):
        Rig([ring_rig(1)[0], ring_rig(1)[0]])
