"""The pitch pipeline's spin from flight on a studio capture with markers: both spins, their
agreement, and the added JSON keys (the existing ones unchanged)."""

import json

import numpy as np
import pytest

from stillcap.pipelines.pitch import analyse_pitch
from stillcap.studio.pitch import pitch_capture


@pytest.fixture(scope="module")
def kept(tmp_path_factory):
    """A four-seam pitch rendered at 1280x960 through the true rig, saved as a capture folder."""
    capture, photos = pitch_capture("seed-4seam", rng=0, calibrate=False, image_size=(1280, 960)).to_capture()
    return capture.save(tmp_path_factory.mktemp("studio") / "pitch", photos)


def test_marked_pitch_reports_both_spins_and_their_agreement(kept):
    res = analyse_pitch(kept, n_samples=0)
    d = res.to_dict()
    truth = json.loads((kept / "truth.json").read_text())
    assert d["spin_source"] == "markers" and d["spin_reported"]["source"] == "markers"
    f = d["spin_from_flight"]
    assert f["source"] == "flight" and f["transverse_only"] and f["lift_from"] == "total"  # the seed model
    assert f["spin_sigma_rpm"] > 0 and f["axis_sigma_deg"] > 0
    assert abs(f["spin_rpm"] - truth["spin_rpm"]) < max(4 * f["spin_sigma_rpm"], 10.0)
    c = d["spin_comparison"]
    assert c["agree"] and c["dof"] == 2 and c["axis_angle_deg"] < 2.0
    # the seed model's lift follows the total rate: no efficiency from the flight
    assert c["spin_efficiency"] is None
    assert d["spin"] == d["spin_reported"]["spin"] and np.isclose(d["spin_rpm"], truth["spin_rpm"], atol=5)
