"""analyse_puppet's two threads: photos decoded and prepared on either thread (the detecting one
takes over photos the other has not started while it waits) give the serial result."""

import threading
import time

import numpy as np
import pytest

from stillcap.io.capture import Capture
from stillcap.pipelines.puppet import analyse_puppet
from stillcap.studio.puppet import puppet_scene
from support import assert_same_reconstruction


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    sc = puppet_scene(pose="random:5", rng=5, supersample=1)
    cap, images = sc.to_capture(".jpg")
    folder = tmp_path_factory.mktemp("cap") / "cap"
    cap.save(folder, images, jpeg_quality=85)
    return folder


def test_photos_decoded_on_both_threads_give_the_serial_result(monkeypatch, capture):
    one, _ = analyse_puppet(capture, workers=1)
    real = Capture.read_image
    readers = []

    def slow_read(self, entry):  # the decoding thread is slow: the detecting one helps out
        if threading.current_thread() is not threading.main_thread():
            time.sleep(0.05)
        readers.append(threading.current_thread() is threading.main_thread())
        return real(self, entry)

    monkeypatch.setattr(Capture, "read_image", slow_read)
    seen = []
    two, images = analyse_puppet(capture, workers=2, progress=lambda d, n: seen.append((d, n)))
    assert any(readers) and not all(readers)  # both threads decoded photos
    assert seen == [(k, 12) for k in range(1, 13)]
    assert len(images) == 12
    assert_same_reconstruction(one, two)
    assert np.isfinite(two.markers.points).all(axis=1).sum() >= 14


def test_decoding_starts_before_the_marker_set_is_read(monkeypatch, capture):
    """The decoding thread starts as soon as capture.json is loaded: the rest of the set-up (marker
    set, skeleton, BLAS limit: one-off costs of a first call) overlaps it."""
    import stillcap.pipelines.puppet.analyse as analyse

    started = threading.Event()
    real_read, real_markerset = Capture.read_image, analyse.capture_markerset

    def read(self, entry):
        started.set()
        return real_read(self, entry)

    order = []

    def markerset(folder, cap=None):
        # waits for the first decode (a safeguard, not a timing: set at once when it has begun)
        order.append(started.wait(timeout=30))
        return real_markerset(folder, cap)

    monkeypatch.setattr(Capture, "read_image", read)
    monkeypatch.setattr(analyse, "capture_markerset", markerset)
    res, _ = analyse_puppet(capture, workers=2)
    assert order == [True]
    assert len(res.names) == 16


def test_a_bad_marker_set_stops_the_decoding_thread(tmp_path, capture):
    """An error in the set-up made while the photos decode is the usual one line, and the decoding
    thread ends with it (no photos decoded in the background afterwards)."""
    import json
    import shutil

    folder = tmp_path / "cap"
    shutil.copytree(capture, folder)
    meta = json.loads((folder / "capture.json").read_text())
    meta["markerset"] = {"file": "beads-missing.json"}
    (folder / "capture.json").write_text(json.dumps(meta))
    before = set(threading.enumerate())
    with pytest.raises(ValueError, match="beads-missing.json"):
        analyse_puppet(folder, workers=2)
    assert set(threading.enumerate()) <= before
