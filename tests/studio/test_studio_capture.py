"""Capture folders: round trip and every way a folder can be wrong."""

import json

import numpy as np
import pytest

from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard
from stillcap.camera import Camera, Rig
from stillcap.io.capture import Capture, CaptureImage, target_from_dict, target_to_dict
from stillcap.files.jsonable import from_jsonable, to_jsonable


def small_rig():
    return Rig([Camera.from_intrinsics(n, 100.0, 100.0, 31.5, 23.5, (64, 48)) for n in ("cam_2", "cam_10")])


def images():
    rng = np.random.default_rng(0)
    return {f"images/{n}.png": rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for n in ("cam_2", "cam_10")}


def make_capture(tmp_path):
    imgs = [CaptureImage("images/cam_2.png", "cam_2", strobe_hz=80.0, shutter_s=1.0, first_flash_s=0.05, n_flashes=8,
                         meta={"pair": "front"}),
            CaptureImage("images/cam_10.png", "cam_10")]
    truth = {"ball_centers_px": np.array([[1.0, np.nan], [2.0, 3.0]])}
    cap = Capture("pitch", small_rig(), imgs, truth, {"description": "test"})
    cap.save(tmp_path / "cap", images())
    return tmp_path / "cap"


def test_round_trip(tmp_path):
    root = make_capture(tmp_path)
    cap = Capture.load(root)
    assert cap.kind == "pitch" and cap.rig.names == ["cam_2", "cam_10"]  # order kept, not sorted
    im = cap.images[0]
    assert (im.strobe_hz, im.shutter_s, im.first_flash_s, im.n_flashes) == (80.0, 1.0, 0.05, 8)
    assert np.allclose(im.flash_times, 0.05 + np.arange(8) / 80)
    assert im.meta == {"pair": "front"} and cap.images[1].flash_times is None
    assert cap.meta["description"] == "test"
    got = from_jsonable(cap.truth["ball_centers_px"])
    assert np.isnan(got[0, 1]) and got[1, 1] == 3.0
    assert np.array_equal(cap.read_image("images/cam_10.png"), images()["images/cam_10.png"])
    assert [i.file for i in cap.images_of("cam_10")] == ["images/cam_10.png"]
    cap.verify()
    d = json.loads((root / "capture.json").read_text())
    assert d["format"] == "stillcap-capture" and d["units"]["time"] == "s"
    assert d["images"][0]["strobe_hz"] == 80.0


def test_load_accepts_the_json_path(tmp_path):
    root = make_capture(tmp_path)
    assert Capture.load(root / "capture.json").root == root


def _edit(root, fn):
    d = json.loads((root / "capture.json").read_text())
    fn(d)
    (root / "capture.json").write_text(json.dumps(d))


def test_missing_folder_and_files_are_named(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        Capture.load(tmp_path / "nope")
    with pytest.raises(ValueError, match="capture.json does not exist"):
        Capture.load(tmp_path)
    root = make_capture(tmp_path)
    (root / "images" / "cam_10.png").unlink()
    with pytest.raises(ValueError, match="cam_10.png does not exist"):
        Capture.load(root)


def test_missing_rig_is_named(tmp_path):
    root = make_capture(tmp_path)
    (root / "rig.json").unlink()
    with pytest.raises(ValueError, match="rig.json does not exist"):
        Capture.load(root)


def test_unknown_camera_is_named(tmp_path):
    root = make_capture(tmp_path)
    _edit(root, lambda d: d["images"][1].update(camera="cam_3"))
    with pytest.raises(ValueError, match="camera 'cam_3' is not in the rig"):
        Capture.load(root)


@pytest.mark.parametrize("bad, msg", [("../outside.png", "leaves the capture folder"),
                                      ("images/../../x.png", "leaves the capture folder"),
                                      ("/etc/passwd", "absolute"),
                                      ("C:/x.png", "absolute")])
def test_paths_must_stay_inside(tmp_path, bad, msg):
    root = make_capture(tmp_path)
    _edit(root, lambda d: d["images"][0].update(file=bad))
    with pytest.raises(ValueError, match=msg):
        Capture.load(root)


def test_undecodable_image_is_named(tmp_path):
    root = make_capture(tmp_path)
    (root / "images" / "cam_2.png").write_bytes(b"not an image at all")
    with pytest.raises(ValueError, match="cam_2.png"):
        Capture.load(root).read_image(0)


def test_truncated_image_fails_on_read(tmp_path):
    root = make_capture(tmp_path)
    p = root / "images" / "cam_2.png"
    p.write_bytes(p.read_bytes()[:40])
    with pytest.raises(ValueError, match="cam_2.png"):
        Capture.load(root).verify()


def test_image_size_must_match_camera(tmp_path):
    root = make_capture(tmp_path)
    import cv2

    cv2.imwrite(str(root / "images" / "cam_2.png"), np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match=r"cam_2.png is 10x10 px but camera 'cam_2' is 64x48"):
        Capture.load(root).read_image("images/cam_2.png")


def test_format_version_units_and_keys_are_checked(tmp_path):
    root = make_capture(tmp_path)
    _edit(root, lambda d: d.update(version=99))
    with pytest.raises(ValueError, match=r"capture.json: version: must be a capture file version this stillcap reads \(1\) \(got 99\)"):
        Capture.load(root)
    _edit(root, lambda d: d.update(version=1, format="other"))
    with pytest.raises(ValueError, match="not a stillcap capture"):
        Capture.load(root)
    _edit(root, lambda d: d.update(format="stillcap-capture", units={"length": "mm"}))
    with pytest.raises(ValueError, match="units"):
        Capture.load(root)
    _edit(root, lambda d: (d.pop("units"), d["images"][0].update(strobe=80)))
    with pytest.raises(ValueError, match="unknown keys \\['strobe'\\]"):
        Capture.load(root)
    (root / "capture.json").write_text("{ not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        Capture.load(root)


def test_bad_entries_fail_at_construction(tmp_path):
    with pytest.raises(ValueError, match="strobe_hz"):
        CaptureImage("a.png", "cam_2", strobe_hz=0)
    with pytest.raises(ValueError, match="n_flashes"):
        CaptureImage("a.png", "cam_2", n_flashes=2.5)
    with pytest.raises(ValueError, match="listed twice"):
        Capture("x", small_rig(), [CaptureImage("a.png", "cam_2"), CaptureImage("a.png", "cam_10")])
    with pytest.raises(ValueError, match="reserved"):
        Capture("x", small_rig(), [], meta={"images": 1})
    cap = Capture("x", small_rig(), [CaptureImage("images/a.png", "cam_2")])
    with pytest.raises(ValueError, match="missing"):
        cap.save(tmp_path / "c")  # the listed image was neither given nor present
    with pytest.raises(ValueError, match="not listed"):
        cap.save(tmp_path / "c", {"images/b.png": np.zeros((48, 64, 3), np.uint8)})


def test_jpeg_images_and_nan_truth(tmp_path):
    cap = Capture("markers", small_rig(), [CaptureImage("images/a.jpg", "cam_2")], {"x": [np.nan, 1.0]})
    cap.save(tmp_path / "c", {"images/a.jpg": np.full((48, 64, 3), 100, np.uint8)}, jpeg_quality=90)
    back = Capture.load(tmp_path / "c")
    assert back.truth == {"x": [None, 1.0]}
    assert abs(int(back.read_image(0).mean()) - 100) <= 1


def test_target_descriptions_round_trip():
    for t in (Chessboard(7, 5, 0.03), CharucoTarget(5, 4, 0.05, 0.035, first_id=4), CalibrationObject.charuco_box()):
        d = json.loads(json.dumps(to_jsonable(target_to_dict(t))))
        back = target_from_dict(d)
        assert type(back) is type(t)
        assert np.allclose(np.concatenate(back.object_points()) if isinstance(t, CalibrationObject) else back.object_points(),
                           np.concatenate(t.object_points()) if isinstance(t, CalibrationObject) else t.object_points())
    with pytest.raises(ValueError, match="unknown calibration target type 'circles'"):
        target_from_dict({"type": "circles"})
