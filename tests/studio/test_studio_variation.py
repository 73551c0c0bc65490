"""The studio's variations of pitch photos (issue 12, part 6) produce what they say."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stillcap.studio.pitch import LIGHT_PLACEMENTS, pitch_capture, pitch_rig, place_lights
from stillcap.studio.sensor import Sensor, _encode, jpeg_roundtrip, tone_curve


def _flat(level):
    return np.full((8, 8, 3), level, np.float32)


@pytest.mark.parametrize("level", [0.05, 0.25, 0.8])
def test_linear_response_pixel_values_follow_the_linear_curve(level):
    img = Sensor.ideal(gamma=1.0).expose(_flat(level))
    assert np.all(img == round(level * 255))
    g = Sensor.ideal(gamma=2.2).expose(_flat(level))
    assert np.all(np.abs(g.astype(int) - round(255 * level ** (1 / 2.2))) <= 1)


def test_tone_curve_is_an_s_curve_and_its_lut_inverts_the_encoding():
    y = np.linspace(0, 1, 11)
    t = tone_curve(y)
    assert t[0] == pytest.approx(0) and t[5] == pytest.approx(0.5) and t[-1] == pytest.approx(1)
    assert t[2] < y[2] and t[8] > y[8]  # darker shadows, brighter highlights
    s = Sensor.ideal(gamma="srgb")
    s.tone = True
    lut = np.array(s.response_lut())
    assert lut.shape == (256,) and np.all(np.diff(lut) > 0)
    x = np.array([0.02, 0.1, 0.3, 0.7])
    codes = np.round(_encode(x, "srgb", True) * 255).astype(int)
    np.testing.assert_allclose(lut[codes], x, rtol=0.03)
    assert s.response.to_json()["lut"] == pytest.approx(list(lut))
    assert Sensor(gamma=1.0).response.to_json() == "linear" and Sensor().response.to_json() == "srgb"
    assert Sensor(gamma=2.4).response.to_json() == {"gamma": 2.4}


def test_white_balance_casts_the_channels():
    img = Sensor(full_well=None, read_noise=0.0, blur_px=0.0, white_balance=(1.2, 1.0, 0.8), gamma=1.0).expose(_flat(0.5))
    b, g, r = img[0, 0].astype(float)
    assert r / g == pytest.approx(1.2, abs=0.01) and b / g == pytest.approx(0.8, abs=0.01)
    with pytest.raises(ValueError, match="white_balance"):
        Sensor(white_balance=(1, 0, 1))


def test_jpeg_quality_changes_the_file_size():
    pc = pitch_capture("seed-4seam", rng=0, calibrate=False, image_size=(640, 480))
    img = pc.images[0]
    sizes = [len(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, q])[1]) for q in (70, 98)]
    assert sizes[1] > 1.5 * sizes[0]
    assert jpeg_roundtrip(img, 70).shape == img.shape


def test_light_placements_move_the_strobes_and_keep_the_irradiance():
    rig = pitch_rig(image_size=(640, 480))
    assert place_lights(rig, "default") is rig
    for where in LIGHT_PLACEMENTS[1:]:
        moved = place_lights(rig, where)
        for a, b in zip(rig.pairs, moved.pairs):
            assert not np.allclose(a.light.position, b.light.position)
    with pytest.raises(ValueError, match="light placement"):
        place_lights(rig, "above")


def test_truth_records_the_conditions_and_the_camera_response():
    s = Sensor(gamma=1.8, blur_px=1.2, white_balance=(1.1, 1.0, 0.9))
    pc = pitch_capture("seed-4seam", rng=0, calibrate=False, image_size=(640, 480), sensor=s, lights="near",
                       room_flash=0.0004, ball_radius_m=0.04)
    d = pc.truth.to_dict()
    assert d["camera_response"] == {c: {"gamma": 1.8} for c in d["cameras"]}
    st = d["studio"]
    assert st["lights"] == "near" and st["blur_px"] == 1.2 and st["ball_radius_m"] == 0.04
    assert st["white_balance"] == [1.1, 1.0, 0.9] and st["room_flash"] == 0.0004
    assert d["ball"]["radius"] == pytest.approx(0.04)
    # the room lit by every flash is brighter than the black room
    dark = pitch_capture("seed-4seam", rng=0, calibrate=False, image_size=(640, 480), sensor=s, lights="near")
    assert pc.images[0][:40, :40].mean() > dark.images[0][:40, :40].mean() + 5
    with pytest.raises(ValueError, match="ball_radius_m"):
        pitch_capture("seed-4seam", rng=0, calibrate=False, image_size=(640, 480), ball_radius_m=2.0)
