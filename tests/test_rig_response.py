"""The rig file's per-camera ``response`` key (docs/rig-format.md, docs/camera-response.md)."""

import json

import pytest

from stillcap.camera import Camera, Rig
from stillcap.response import Response
from support import ring_rig


def _rig_dict():
    return json.loads(json.dumps(ring_rig(2).to_dict()))


def test_written_read_and_kept(tmp_path):
    rig = ring_rig(2).with_responses({"cam_0": Response.linear(), "cam_1": Response.power(1.8)})
    path = rig.save(tmp_path / "rig.json")
    d = json.loads(path.read_text())
    assert [c["response"] for c in d["cameras"]] == ["linear", {"gamma": 1.8}]
    back = Rig.load(path)
    assert [c.response for c in back] == [Response.linear(), Response.power(1.8)]
    # the cameras made from a camera keep its response
    c = back["cam_1"]
    assert c.with_pose(c.world2cam).response == Response.power(1.8)
    assert back.subset(["cam_1"])[0].response == Response.power(1.8)


def test_old_rigs_read_as_srgb(tmp_path):
    d = _rig_dict()
    for c in d["cameras"]:
        c.pop("response")
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(d))
    assert all(c.response == Response.srgb() for c in Rig.load(path))
    assert Camera.from_intrinsics("a", 100, 100, 50, 50, (100, 100)).response == Response.srgb()


def test_lookup_table_round_trip(tmp_path):
    lut = [(v / 255) ** 2.0 for v in range(256)]
    rig = ring_rig(1).with_responses(Response.table(lut))
    back = Rig.load(rig.save(tmp_path / "rig.json"))
    assert back[0].response.kind == "lut" and back[0].response.effective_gamma == pytest.approx(2.0, abs=0.01)


@pytest.mark.parametrize("value, message", [
    ("lin", r"camera 'cam_1': cameras\.1\.response: must be \"srgb\", \"linear\", \{\"gamma\": G\} or "
            r"\{\"lut\": \[256 numbers\]\} \(got 'lin'\)$"),
    ({"gamma": -1}, r"camera 'cam_1': cameras\.1\.response: response gamma must be a number from 0\.2 to 5\.0 "
                    r"\(got \{'gamma': -1\}\)$"),
    ({"lut": [0, 1]}, r"camera 'cam_1': cameras\.1\.response: response lookup table must have 256 numbers"),
    (None, r"camera 'cam_1': cameras\.1\.response: must be"),
])
def test_bad_response_is_one_line_naming_file_camera_and_key(tmp_path, value, message):
    d = _rig_dict()
    d["cameras"][1]["response"] = value
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=message) as e:
        Rig.load(path)
    text = str(e.value)
    assert text.startswith(f"{path}: camera 'cam_1'") and "\n" not in text


def test_camera_checks_its_response():
    with pytest.raises(ValueError, match="camera 'x': response: must be"):
        Camera.from_intrinsics("x", 100, 100, 50, 50, (100, 100), response="lin")
