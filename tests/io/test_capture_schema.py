"""capture.json checked by its schema (io/_capture_schema.py) and Capture.load: the bad inputs
of issue 15 give one ValueError naming the file and the key path, and exit status 2 with one
line from the CLI."""

import json
import struct
import zlib

import numpy as np
import pytest

from stillcap.camera import Camera, Rig
from stillcap.io.capture import Capture, CaptureImage
from support import run_cli


def _rig():
    return Rig([Camera.from_intrinsics(n, 100.0, 100.0, 31.5, 23.5, (64, 48)) for n in ("cam_a", "cam_b")])


@pytest.fixture
def cap(tmp_path):
    imgs = [CaptureImage(f"images/{n}.png", n, strobe_hz=80.0, shutter_s=1.0, first_flash_s=0.05, n_flashes=8,
                         meta={"pair": "front"}) for n in ("cam_a", "cam_b")]
    pixels = {f"images/{n}.png": np.full((48, 64, 3), 30, np.uint8) for n in ("cam_a", "cam_b")}
    meta = {"pairs": {"front": ["cam_a", "cam_b"]}, "strobe_position_m": [0.0, 1.0, 2.0], "synthetic": True}
    Capture("pitch", _rig(), imgs, {"kind": "pitch"}, meta).save(tmp_path / "cap", pixels)
    return tmp_path / "cap"


def _edit(root, path, value, file="capture.json"):
    d = json.loads((root / file).read_text())
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    (root / file).write_text(json.dumps(d))


DELETE = object()


@pytest.mark.parametrize("path, value, message", [
    (("version",), -1, r"capture.json: version: must be a capture file version this stillcap reads \(1\) \(got -1\)"),
    (("version",), 0, r"capture.json: version: must be a capture file version this stillcap reads \(1\) \(got 0\)"),
    (("version",), True, r"capture.json: version: input should be a valid integer \(got True\)"),
    (("version",), DELETE, r"capture.json: version: field required"),
    (("kind",), "pitchh", r"capture.json: kind: input should be 'chessboard', .* or 'puppet' \(got 'pitchh'\)"),
    (("format",), "stillcap-rig", r"capture.json: format: not a stillcap capture \(expected \"format\": \"stillcap-capture\", got 'stillcap-rig'\)"),
    (("units", "time"), "ms", r"capture.json: units.time: input should be 's' \(got 'ms'\)"),
    (("images", 0, "strobe_hz"), "80", r"capture.json: images.0.strobe_hz: input should be a valid number \(got '80'\)"),
    (("images", 0, "strobe_hz"), True, r"capture.json: images.0.strobe_hz: input should be a valid number \(got True\)"),
    (("images", 0, "strobe_hz"), None, r"capture.json: images.0.strobe_hz: input should be a valid number \(got None\)"),
    (("images", 0, "strobe_hz"), 0, r"capture.json: images.0.strobe_hz: input should be greater than 0 \(got 0\)"),
    (("images", 0, "strobe_hz"), float("nan"), r"capture.json: images.0.strobe_hz: input should be a finite number"),
    (("images", 1, "shutter_s"), {"s": 1}, r"capture.json: images.1.shutter_s: input should be a valid number \(got \{'s': 1\}\)"),
    (("images", 1, "first_flash_s"), -0.1, r"capture.json: images.1.first_flash_s: input should be greater than or equal to 0"),
    (("images", 0, "n_flashes"), 1000000000, r"capture.json: images.0.n_flashes: input should be less than or equal to 100000 \(got 1000000000\)"),
    (("images", 0, "n_flashes"), 1e9, r"capture.json: images.0.n_flashes: input should be a valid integer \(got 1000000000.0\)"),
    (("images", 0, "n_flashes"), 2.5, r"capture.json: images.0.n_flashes: input should be a valid integer"),
    (("images", 0, "meta"), True, r"capture.json: images.0.meta: input should be a valid dictionary \(got True\)"),
    (("images", 0, "meta"), 3, r"capture.json: images.0.meta: input should be a valid dictionary \(got 3\)"),
    (("images", 0, "meta", "pair"), 7, r"capture.json: images.0.meta.pair: input should be a valid string \(got 7\)"),
    (("images", 0, "meta", "angle_deg"), "abc", r"capture.json: images.0.meta.angle_deg: input should be a valid number"),
    (("images", 0, "strobe"), 80, r"capture.json: images.0.strobe: image entry has unknown keys \['strobe'\] \(timing keys carry their unit"),
    (("images", 0, "camera"), DELETE, r"capture.json: images.0.camera: field required"),
    (("images", 0, "camera"), "cam_c", r"capture.json: images.0.camera: camera 'cam_c' is not in the rig rig.json \(cameras: \['cam_a', 'cam_b'\]\)"),
    (("images", 1, "file"), "images/cam_a.png", r"capture.json: images.1.file: image 'images/cam_a.png' is listed twice \(also images.0\)"),
    (("images", 0, "file"), "../x.png", r"capture.json: images.0.file: path '../x.png' leaves the capture folder"),
    (("images", 0, "file"), "images/nope.png", r"capture.json: images.0.file: image file .*nope.png does not exist"),
    (("images", 0), "images/cam_a.png", r"capture.json: images.0: input should be a valid dictionary"),
    (("images",), {"a": 1}, r"capture.json: images: input should be a valid list"),
    (("meta",), False, r"capture.json: meta: input should be a valid dictionary \(got False\)"),
    (("pairs", "front"), ["cam_a"], r"capture.json: pairs.front.1: field required"),
    (("pairs", "front", 1), "cam_z", r"capture.json: pairs.front.1: camera 'cam_z' is not in the rig"),
    (("pairs", "front", 1), "cam_a", r"capture.json: pairs.front.1: camera 'cam_a' is already in the pair 'front'"),
    (("strobe_position_m",), [0, 1], r"capture.json: strobe_position_m.2: field required"),
    (("strobe_position_m", 0), float("inf"), r"capture.json: strobe_position_m.0: input should be a finite number"),
    (("synthetic",), "yes", r"capture.json: synthetic: input should be a valid boolean \(got 'yes'\)"),
    (("markerset",), 5, r"capture.json: markerset: must be a built-in name \(a string\) or an object \(got 5\)"),
    (("truth",), 5, r"capture.json: truth: input should be a valid string"),
    (("rig",), "/etc/rig.json", r"capture.json: rig: path '/etc/rig.json' is absolute"),
    (("calibration",), {"board2world": {"front": [[[1, 0, 0, 0]] * 3]}}, r"capture.json: calibration.board2world.front.0.3: field required"),
    (("calibration",), {"cameras": {"cam_a": {"spots_used": [0, "x"]}}}, r"capture.json: calibration.cameras.cam_a.spots_used.1: input should be a valid integer"),
])
def test_bad_values_name_the_file_and_the_key(cap, path, value, message):
    _edit(cap, path, value)
    with pytest.raises(ValueError, match=message) as e:
        Capture.load(cap)
    assert str(e.value).startswith(str(cap / "capture.json") + ": ") and "\n" not in str(e.value)


def test_the_embedded_rig_keys_are_named(cap):
    _edit(cap, ("cameras", 1, "K", 0, 0), -5.0, "rig.json")
    with pytest.raises(ValueError, match=r"rig.json: camera 'cam_b': cameras.1.K.0.0: input should be greater than 0 \(got -5.0\)$"):
        Capture.load(cap)


def test_truth_must_be_an_object(cap):
    (cap / "truth.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"truth.json: \(the whole file\): a truth file must be an object, got a JSON list$"):
        Capture.load(cap)


def _png_claiming(w, h):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 10)) + chunk(b"IEND", b""))


def test_photos_are_checked_at_load_without_decoding(cap):
    (cap / "images" / "cam_b.png").write_bytes(_png_claiming(60000, 60000))
    with pytest.raises(ValueError, match=r"cam_b.png: its header claims 60000x60000 px \(3600 megapixels\)"):
        Capture.load(cap)
    (cap / "images" / "cam_b.png").write_bytes(_png_claiming(32, 24))
    with pytest.raises(ValueError, match=r"cam_b.png is 32x24 px but camera 'cam_b' is 64x48 px"):
        Capture.load(cap)


def test_valid_captures_keep_their_meta(cap):
    c = Capture.load(cap)
    assert c.meta["pairs"] == {"front": ["cam_a", "cam_b"]} and c.meta["strobe_position_m"] == [0.0, 1.0, 2.0]
    assert c.images[0].strobe_hz == 80.0 and c.images[0].n_flashes == 8 and c.truth == {"kind": "pitch"}


def test_python_api_refuses_bad_types_with_value_errors():
    with pytest.raises(ValueError, match=r"image 'a.png': shutter_s must be a number, got \{'s': 1\}"):
        CaptureImage("a.png", "cam_a", shutter_s={"s": 1})
    with pytest.raises(ValueError, match=r"n_flashes must be a whole number from 0 to 100000, got inf"):
        CaptureImage("a.png", "cam_a", n_flashes=float("inf"))
    with pytest.raises(ValueError, match=r"meta must be a dict, got True"):
        CaptureImage("a.png", "cam_a", meta=True)
    with pytest.raises(ValueError, match=r"strobe_hz must be a number, got '80'"):
        CaptureImage("a.png", "cam_a", strobe_hz="80")


@pytest.mark.parametrize("command", [["pitch"], ["hand"], ["markers"], ["puppet", "run"]])
def test_cli_gives_exit_2_and_one_line(cap, capsys, command):
    _edit(cap, ("images", 0, "strobe_hz"), "fast")
    code, out, err = run_cli([*command, cap], capsys)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "capture.json: images.0.strobe_hz: input should be a valid number (got 'fast')" in lines[0]


def test_cli_truncated_photo_exit_2(cap, capsys):
    p = cap / "images" / "cam_a.png"
    p.write_bytes(p.read_bytes()[:-20])
    code, _, err = run_cli(["pitch", cap], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "cam_a.png is truncated" in err


def test_cli_prints_square_brackets_as_they_are(cap, capsys):
    _edit(cap, ("cameras", 0, "K", 1, 0), 3.0, "rig.json")
    code, _, err = run_cli(["pitch", cap], capsys)
    assert code == 2 and "cameras.0.K.1.0: must be 0 (K is [[fx, s, cx], [0, fy, cy], [0, 0, 1]]) (got 3.0)" in err
