"""Capture.start_decoding: photos decoded ahead on a background thread are the ones on disk,
handed out once, with the errors read_image gives without it."""

import pickle
from dataclasses import replace

import cv2
import numpy as np
import pytest

from stillcap.camera import Camera, Rig
from stillcap.io.capture import Capture, CaptureImage

NAMES = ("cam_2", "cam_10", "cam_3")


def _capture(tmp_path) -> Capture:
    """Three cameras, a JPEG, a PNG and a JPEG of noise (not one value: a mix-up would show)."""
    rng = np.random.default_rng(7)
    rig = Rig([Camera.from_intrinsics(n, 100.0, 100.0, 63.5, 47.5, (128, 96)) for n in NAMES])
    files = [f"images/{n}.{ext}" for n, ext in zip(NAMES, ("jpg", "png", "jpeg"))]
    pixels = {f: rng.integers(0, 256, (96, 128, 3), np.uint8) for f in files}
    Capture("pitch", rig, [CaptureImage(f, n) for f, n in zip(files, NAMES)]).save(tmp_path / "cap", pixels)
    return Capture.load(tmp_path / "cap")


def test_photos_decoded_ahead_are_the_files_on_disk(tmp_path):
    cap = _capture(tmp_path)
    cap.start_decoding()
    for im in reversed(cap.images):  # not in the order they were decoded
        img = cap.read_image(im)
        assert np.array_equal(img, cv2.imread(str(cap.path_of(im)), cv2.IMREAD_COLOR)), im.file
    assert cap._decoding == {}  # every photo handed out


def test_a_photo_is_handed_out_once_then_read_again(tmp_path):
    cap = _capture(tmp_path)
    cap.start_decoding(cap.images[:1])
    assert list(cap._decoding) == [cap.images[0].file]
    first = cap.read_image(0)
    first[:] = 0  # the caller owns it: a later read decodes the file again
    again = cap.read_image(0)
    assert again is not first and np.array_equal(again, cv2.imread(str(cap.path_of(0))))


def test_other_flags_do_not_take_the_colour_decoding(tmp_path):
    cap = _capture(tmp_path)
    cap.start_decoding()
    gray = cap.read_image(1, cv2.IMREAD_GRAYSCALE)
    assert gray.ndim == 2 and np.array_equal(gray, cv2.imread(str(cap.path_of(1)), cv2.IMREAD_GRAYSCALE))
    assert cap.images[1].file in cap._decoding  # still there for the colour read
    assert cap.read_image(1).shape == (96, 128, 3)


def test_a_bad_photo_gives_the_same_error_at_its_read(tmp_path):
    cap = _capture(tmp_path)
    path = cap.path_of(0)
    path.write_bytes(path.read_bytes()[:-200])  # cut short after Capture.load checked it
    with pytest.raises(ValueError) as plain:
        cap.read_image(0)
    cap.start_decoding()
    with pytest.raises(ValueError) as ahead:
        cap.read_image(0)
    assert str(ahead.value) == str(plain.value) and str(path) in str(ahead.value)
    assert np.array_equal(cap.read_image(2), cv2.imread(str(cap.path_of(2))))  # the others are fine


def test_the_size_check_applies_to_a_photo_decoded_ahead(tmp_path):
    cap = _capture(tmp_path)
    cv2.imwrite(str(cap.path_of(1)), np.zeros((48, 64, 3), np.uint8))  # replaced after loading
    cap.start_decoding()
    with pytest.raises(ValueError, match=r"is 64x48 px but camera 'cam_10' is 128x96 px"):
        cap.read_image(1)


def test_copies_share_the_decoding_and_pickles_leave_it(tmp_path):
    cap = _capture(tmp_path)
    cap.start_decoding()
    other = replace(cap, rig=cap.rig.with_responses({}))  # as the pipelines' response option does
    assert np.array_equal(other.read_image(0), cv2.imread(str(cap.path_of(0))))
    assert cap.images[0].file not in cap._decoding  # handed out through the copy
    sent = pickle.loads(pickle.dumps(cap))  # as to a worker process
    assert sent._decoding == {} and sent.images == cap.images and sent.root == cap.root
    assert np.array_equal(sent.read_image(2), cv2.imread(str(cap.path_of(2))))
