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
