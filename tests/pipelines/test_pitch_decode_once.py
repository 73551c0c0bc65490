"""Each photo of a pitch is decoded once per analysis (issue 16): the response self-check works on
the photos the pair step decoded, with threads; serial (workers=1) gives the same result."""

import pytest

from stillcap.io.capture import Capture
from stillcap.pipelines.pitch import PitchOptions, analyse_pitch

from support import studio_pitch


@pytest.fixture(scope="module")
def fastball(tmp_path_factory):
    return studio_pitch(tmp_path_factory, "fastball")


def test_each_photo_decoded_once(fastball, monkeypatch):
    cap = Capture.load(fastball)
    decoded = []
    read = Capture.read_image

    def counting(self, image, *args, **kwargs):
        decoded.append(self._entry(image).file)
        return read(self, image, *args, **kwargs)

    monkeypatch.setattr(Capture, "read_image", counting)
    res = analyse_pitch(cap, PitchOptions(n_samples=50))
    assert sorted(decoded) == sorted(im.file for im in cap.images)  # once each, none twice
    checks = [c for c in res.self_checks if c.name == "response"]
    assert {c.subject for c in checks} == set(cap.rig.names)  # the check still ran on every camera
    decoded.clear()
    serial = analyse_pitch(cap, PitchOptions(n_samples=50, workers=1))
    assert sorted(decoded) == sorted(im.file for im in cap.images)
    assert [(c.subject, c.value) for c in serial.self_checks if c.name == "response"] == \
        [(c.subject, c.value) for c in checks]
    assert serial.metrics.to_dict() == res.metrics.to_dict()
