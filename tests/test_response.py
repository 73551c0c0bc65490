"""stillcap.response: the camera response value type, its rig-file forms and its CLI spec."""

import numpy as np
import pytest

from stillcap.response import LINEAR_LIMIT, Response, check_response_option, parse_response_spec
from stillcap.studio.sensor import Sensor, consumer_tone_curve


@pytest.mark.parametrize("r", [Response.srgb(), Response.linear(), Response.power(1.8), Response.power(2.6),
                               consumer_tone_curve()])
def test_json_round_trip_and_curve_inverse(r):
    back = Response.from_json(r.to_json())
    assert back == r
    lut = r.to_linear_lut()
    assert lut.dtype == np.float32 and lut.shape == (256,) and not lut.flags.writeable
    assert np.all(np.diff(lut) >= 0) and lut[0] == 0 and lut[-1] == pytest.approx(1)
    # encode inverts the table (to a fraction of a code where the curve is not flat)
    codes = np.arange(20, 256, 7)
    np.testing.assert_allclose(r.encode(lut[codes]), codes, atol=0.05)
    np.testing.assert_allclose(r.linearize(codes.astype(float)), lut[codes], atol=1e-6)
    np.testing.assert_array_equal(r.linearize(codes.astype(np.uint8)), lut[codes])


def test_the_studio_sensor_encodes_with_the_same_curve():
    """The studio's encoding and Response's decoding agree (the studio's truth is the rig's)."""
    x = np.linspace(0.02, 1, 50)
    rad = np.repeat(x[None, :, None], 3, axis=2)
    for r in (Response.srgb(), Response.linear(), Response.power(2.6), consumer_tone_curve()):
        img = Sensor.ideal(gamma=r).expose(rad)
        back = r.linearize(img[0, :, 0])
        slope = np.gradient(r.to_linear_lut())[img[0, :, 0]]  # one code's radiance step
        assert np.all(np.abs(back - x) <= slope * 0.51 + 1e-6)
        assert Sensor(gamma=r).response == r
    assert Sensor(gamma=1.0).response == Response.linear()
    assert Sensor(gamma=2.2).response == Response.power(2.2)


def test_classes_and_effective_gamma():
    assert Response.linear().response_class == "linear"
    assert Response.srgb().response_class == "gamma"
    assert 2.0 < Response.srgb().effective_gamma < 2.3
    assert Response.power(1.8).response_class == "gamma" and Response.power(1.2).response_class == "linear"
    assert consumer_tone_curve().response_class == "gamma"
    assert Response.table(np.linspace(0, 1, 256)).effective_gamma == pytest.approx(1.0, abs=0.01)
    assert LINEAR_LIMIT < 1.8


def test_as_srgb_re_encodes():
    img = np.arange(256, dtype=np.uint8).reshape(16, 16)
    assert Response.srgb().as_srgb(img) is img
    out = Response.linear().as_srgb(img)
    assert out.dtype == np.uint8 and out[8, 0] > 128  # linear 0.5 is sRGB ~188


@pytest.mark.parametrize("spec, want", [("auto", "auto"), ("srgb", Response.srgb()), ("LINEAR", Response.linear()),
                                        ("gamma:2.2", Response.power(2.2)), (" gamma:1.8 ", Response.power(1.8))])
def test_cli_spec(spec, want):
    assert parse_response_spec(spec) == want
    assert check_response_option(spec) == want


@pytest.mark.parametrize("spec", ["gamma", "gamma:", "gamma:x", "gamma:0", "gamma:nan", "gamma:9", "lin", "", "2.2"])
def test_bad_cli_spec_names_it(spec):
    with pytest.raises(ValueError, match=r"--response '.*'"):
        parse_response_spec(spec)


@pytest.mark.parametrize("value, match", [
    ("lin", "must be \"srgb\""), (3, "must be \"srgb\""), ({"gamma": 0}, "gamma must be"),
    ({"gamma": True}, "gamma must be"), ({"lut": [0.5] * 256}, "flat"), ({"lut": [0, 1]}, "256 numbers"),
    ({"lut": list(np.linspace(1, 0, 256))}, "must not decrease"), ({"lut": [2.0] * 256}, "from 0 to 1"),
    ({"gamma": 2.2, "lut": [0]}, "must be"),
])
def test_bad_rig_forms(value, match):
    with pytest.raises(ValueError, match=match):
        Response.from_json(value, "rig.json: camera 'a': response")
