"""Each photo of a pitch is decoded once per analysis (issue 16): the response self-check's
estimates are made by each pair's job on the photos it decoded (threads, serial, and worker
processes), with the same values in all three."""

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


def test_response_estimates_in_worker_processes(fastball):
    """With worker processes the estimates come from the workers (which hold the photos): the
    same checks as on threads, digit for digit."""
    cap = Capture.load(fastball)
    threads = analyse_pitch(cap, PitchOptions(n_samples=50))
    procs = analyse_pitch(cap, PitchOptions(n_samples=50, processes=2))
    assert [(c.subject, c.value, c.passed) for c in procs.self_checks if c.name == "response"] == \
        [(c.subject, c.value, c.passed) for c in threads.self_checks if c.name == "response"]
    assert procs.response["shading"] == threads.response["shading"]
