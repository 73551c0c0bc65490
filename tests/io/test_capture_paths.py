"""Capture folders: an image symlinked out of the folder is refused; a symlinked folder itself loads."""

import os

import numpy as np
import pytest

from stillcap.camera import Camera, Rig
from stillcap.io.capture import Capture, CaptureImage


def _capture(tmp_path):
    rig = Rig([Camera.from_intrinsics(n, 100.0, 100.0, 31.5, 23.5, (64, 48)) for n in ("cam_2", "cam_10")])
    imgs = [CaptureImage(f"images/{n}.png", n) for n in ("cam_2", "cam_10")]
    pixels = {f"images/{n}.png": np.zeros((48, 64, 3), np.uint8) for n in ("cam_2", "cam_10")}
    Capture("pitch", rig, imgs).save(tmp_path / "cap", pixels)
    return tmp_path / "cap"


def test_image_symlinked_out_of_the_folder_is_refused(tmp_path):
    root = _capture(tmp_path)
    outside = tmp_path / "outside.png"
    os.replace(root / "images" / "cam_10.png", outside)
    os.symlink(outside, root / "images" / "cam_10.png")
    with pytest.raises(ValueError, match=r"'images/cam_10.png' leads outside the capture folder \(symlink\)"):
        Capture.load(root)


def test_symlinked_capture_folder_loads(tmp_path):
    root = _capture(tmp_path)
    link = tmp_path / "link"
    os.symlink(root, link)
    cap = Capture.load(link)
    assert [im.file for im in cap.images] == ["images/cam_2.png", "images/cam_10.png"]


def test_images_folder_symlinked_out_of_the_folder_is_refused(tmp_path):
    # the photos' folder is resolved once for all its files (resolve_inside's real_dirs): a
    # symlink there still leads outside
    root = _capture(tmp_path)
    os.replace(root / "images", tmp_path / "elsewhere")
    os.symlink(tmp_path / "elsewhere", root / "images")
    with pytest.raises(ValueError, match=r"'images/cam_2.png' leads outside the capture folder \(symlink\)"):
        Capture.load(root)


def test_images_folder_symlinked_inside_loads(tmp_path):
    root = _capture(tmp_path)
    os.replace(root / "images", root / "photos")
    os.symlink(root / "photos", root / "images")
    assert [im.file for im in Capture.load(root).images] == ["images/cam_2.png", "images/cam_10.png"]


def test_truth_left_unread_on_request(tmp_path):
    root = _capture(tmp_path)
    cap = Capture.load(root)
    cap.truth = {"kind": "pitch"}
    cap.save(root)
    assert Capture.load(root).truth == {"kind": "pitch"}
    assert Capture.load(root, truth=False).truth is None
    (root / "truth.json").write_text("[1, 2]")  # not an object: found only when read
    with pytest.raises(ValueError, match="a truth file must be an object"):
        Capture.load(root)
    assert Capture.load(root, truth=False).truth is None
    (root / "truth.json").unlink()  # its path is checked either way
    with pytest.raises(ValueError, match="truth file .* does not exist"):
        Capture.load(root, truth=False)
