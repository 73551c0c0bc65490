"""Property-based tests of the rig and capture parsers: whatever JSON a file holds, they either
load it or raise one ValueError naming the file, never another exception."""

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from stillcap.camera import Camera, Rig
from stillcap.io.capture import Capture, CaptureImage

SETTINGS = settings(max_examples=75, deadline=None, suppress_health_check=[HealthCheck.too_slow])

#: Any JSON value (with the NaN and Infinity Python's json reads and writes).
scalars = st.none() | st.booleans() | st.integers(-10 ** 20, 10 ** 20) | st.floats() | \
    st.sampled_from([0, 1, -1, 2, 1e308, -1e308, 0.5, 640, 1280, 100001]) | st.text(max_size=12) | \
    st.sampled_from(["m", "mm", "pitch", "stillcap-rig", "stillcap-capture", "rig.json", "cam_0", "../x", "/etc"])
json_values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=5)
                           | st.dictionaries(st.text(max_size=8) | st.sampled_from(["name", "K", "file", "camera", "meta"]),
                                             inner, max_size=5), max_leaves=20)


def _rig():
    cams = [Camera.from_intrinsics(n, 100.0, 100.0, 31.5, 23.5, (64, 48)) for n in ("cam_0", "cam_1")]
    return Rig(cams)


def _paths(d, prefix=()):
    """Every key path of a JSON value."""
    yield prefix
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _paths(v, (*prefix, i))


def _replace(d, path, value):
    d = json.loads(json.dumps(d))
    if not path:
        return value
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return d


RIG = _rig().to_dict()
RIG_PATHS = list(_paths(RIG))


def _rig_loads_or_names_the_file(content):
    try:
        Rig.from_dict(content, "rig.json: ")
    except ValueError as e:
        assert str(e).startswith("rig.json: ") and "\n" not in str(e), str(e)


@SETTINGS
@given(json_values)
def test_rig_from_any_json(value):
    _rig_loads_or_names_the_file(value)


@SETTINGS
@given(st.sampled_from(RIG_PATHS), json_values)
def test_rig_with_any_value_anywhere(path, value):
    _rig_loads_or_names_the_file(_replace(RIG, path, value))


@SETTINGS
@given(json_values)
def test_camera_entry_and_image_entry_from_any_json(value):
    for parse, where in ((Camera.from_dict, "rig.json: "), (CaptureImage.from_dict, "capture.json: ")):
        try:
            parse(value, where)
        except ValueError as e:
            assert str(e).startswith(where) and "\n" not in str(e), str(e)


@pytest.fixture(scope="module")
def folder():
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "cap"
        imgs = [CaptureImage(f"images/{n}.png", n, strobe_hz=80.0, shutter_s=1.0, first_flash_s=0.0, n_flashes=4,
                             meta={"pair": "front"}) for n in ("cam_0", "cam_1")]
        pixels = {f"images/{n}.png": np.zeros((48, 64, 3), np.uint8) for n in ("cam_0", "cam_1")}
        Capture("pitch", _rig(), imgs, {"kind": "pitch"}, {"pairs": {"front": ["cam_0", "cam_1"]}}).save(root, pixels)
        yield root


def _capture_loads_or_names_a_file(root, content):
    (root / "capture.json").write_text(json.dumps(content))
    try:
        Capture.load(root)
    except ValueError as e:
        assert str(root) in str(e) and "\n" not in str(e), str(e)


@SETTINGS
@given(json_values)
def test_capture_from_any_json(folder, value):
    _capture_loads_or_names_a_file(folder, value)


@SETTINGS
@given(st.data(), json_values)
def test_capture_with_any_value_anywhere(folder, data, value):
    path = data.draw(st.sampled_from(list(_paths(CAPTURE))))
    _capture_loads_or_names_a_file(folder, _replace(CAPTURE, path, value))


CAPTURE = {"format": "stillcap-capture", "version": 1, "kind": "pitch",
           "units": {"length": "m", "time": "s", "frequency": "Hz", "angle": "rad"}, "rig": "rig.json",
           "truth": "truth.json", "pairs": {"front": ["cam_0", "cam_1"]}, "strobe_position_m": [0.0, 1.0, 2.0],
           "images": [{"file": f"images/{n}.png", "camera": n, "strobe_hz": 80.0, "shutter_s": 1.0,
                       "first_flash_s": 0.0, "n_flashes": 4, "meta": {"pair": "front", "angle_deg": 0.0}}
                      for n in ("cam_0", "cam_1")]}


def test_the_base_capture_loads(folder):
    (folder / "capture.json").write_text(json.dumps(CAPTURE))
    cap = Capture.load(folder)
    assert cap.images[1].n_flashes == 4 and math.isclose(cap.meta["strobe_position_m"][2], 2.0)


def test_unknown_key_with_a_line_break_is_quoted():
    """Found by the property test above: an unknown image-entry key holding a line break broke the
    one-line message; the key path quotes it as the validator's paths do."""
    with pytest.raises(ValueError) as e:
        CaptureImage.from_dict({"\n": 0}, "capture.json: ")
    assert "\n" not in str(e.value) and "'\\n'" in str(e.value)
