"""Ball files (stillcap-ball): round trip, validation errors, built-in balls, flight models."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stillcap.ball.ballfile import Ball, builtin_ball, builtin_ball_names, linear_to_srgb_hex, load_ball, \
    resolve_ball, srgb_to_linear
from stillcap.ball.design import score_layout
from stillcap.ball.layout import BallLayout, check_layout
from stillcap.ball.physics import BallModel, FlightModel

REPAINTED = Path(__file__).resolve().parents[1] / "data" / "repainted-baseball.json"


def _base() -> dict:
    return builtin_ball("baseball").to_dict()


def test_builtin_baseball_is_the_seed_layout_exactly():
    b, s = builtin_ball("baseball"), BallLayout.seed()
    lay = b.layout
    assert np.array_equal(lay.directions, s.directions) and np.array_equal(lay.types, s.types)
    assert lay.palette == s.palette and lay.names == s.names and lay.type_shapes == s.type_shapes
    assert lay.marker_size == s.marker_size and lay.radius == s.radius
    assert np.array_equal(lay.centroid_depth, s.centroid_depth)
    m = b.flight_model("seed")
    assert m == FlightModel.seed_model()  # the same flight model as without a ball file


@pytest.mark.parametrize("name", ["baseball", "softball", "cricket", "tennis"])
def test_builtin_balls_load_and_are_well_conditioned(name):
    b = builtin_ball(name)
    assert name in builtin_ball_names() and b.name == name and len(b.layout) >= 12
    for margin in (0, 10):
        c = check_layout(b.layout, margin)
        assert not c.symmetric and c.n_ambiguous == 0, (name, margin)
        assert c.min_separation_deg > 5.0
        assert c.min_types >= 2 and c.share_3_types > 0.85
        assert score_layout(b.layout, margin).share_determined == 1.0
    # the flight: the preset of the same name, with the file's mass and size
    m = b.flight_model()
    assert m.mass == b.mass and m.diameter == 2 * b.radius if isinstance(m, BallModel) else m.ball.mass == b.mass


def test_round_trip_and_srgb_colours(tmp_path):
    b = Ball.load(REPAINTED)
    p = b.save(tmp_path / "ball.json")
    b2 = Ball.load(p)
    assert np.allclose(b2.layout.directions, b.layout.directions, atol=1e-15)
    assert np.array_equal(b2.layout.types, b.layout.types) and b2.layout.palette == b.layout.palette
    assert b2.radius == 0.0366 and b2.mass == b.mass and b2.layout.marker_size == b.layout.marker_size
    d = _base()
    d["types"][0].pop("color_linear")
    d["types"][0]["color_srgb"] = "#E63B34"
    d["types"][1]["size_mm"] = d["types"][1].pop("size_deg") * 0 + 6.0
    b3 = Ball.from_dict(d, "x.json")
    assert np.allclose(b3.layout.palette["red"], srgb_to_linear("#e63b34"))
    assert linear_to_srgb_hex(b3.layout.palette["red"]) == "#e63b34"
    assert b3.layout.sizes_of_types[1] == pytest.approx(6.0e-3 / b3.radius)
    assert Ball.from_dict(b3.to_dict(), "y").layout.type_sizes == b3.layout.type_sizes


def _bad(change) -> dict:
    d = _base()
    change(d)
    return d


@pytest.mark.parametrize("change, match", [
    (lambda d: d.pop("radius_m"), r"ball\.json: radius_m: field required"),
    (lambda d: d.update(radius_m=-1.0), r"ball\.json: radius_m: .*greater than 0"),
    (lambda d: d.update(mass_kg="heavy"), r"ball\.json: mass_kg: "),
    (lambda d: d.update(flight="curling"), r"ball\.json: flight: .*flight preset"),
    (lambda d: d.update(format="stillcap-rig"), r"ball\.json: format: not a stillcap ball file"),
    (lambda d: d.update(version=7), r"ball\.json: version: "),
    (lambda d: d["types"][2].update(shape="star"), r"ball\.json: types\.2\.shape: "),
    (lambda d: d["types"][0].update(color_srgb="#ff0000"), r"ball\.json: types\.0: .*exactly one of color_linear"),
    (lambda d: d["types"][0].update(color_linear=[0.8, 0.8, 0.8]), r"ball\.json: types\.0: .*neither saturated nor dark"),
    (lambda d: d["types"][2].update(color_linear=[0.8, 0.15, 0.03]), r"ball\.json: types\.2: hue .* within 30 deg"),
    (lambda d: d["types"][1].update(color_linear=[0.02, 0.02, 0.02], shape="disc"),
     r"ball\.json: types\.3: same colour and shape as types\.1"),
    (lambda d: d["markers"][3].update(type="purple"), r"ball\.json: markers\.3\.type: unknown marker type 'purple'"),
    (lambda d: d["markers"][4].update(azimuth_deg=10.0), r"ball\.json: markers\.4: .*either direction or"),
    (lambda d: d["markers"][4].pop("direction"), r"ball\.json: markers\.4: .*give direction"),
    (lambda d: d["markers"][5].update(direction=[-1, 0.05, 0]), r"ball\.json: markers\.5: marker overlaps markers\.4"),
    (lambda d: d["markers"][0].update(colour="red"), r"ball\.json: markers\.0\.colour: unknown key"),
    (lambda d: d["types"][0].pop("size_deg"), r"ball\.json: types\.0: give the marker size"),
])
def test_validation_errors_name_file_and_key(change, match):
    with pytest.raises(ValueError, match=match) as e:
        Ball.from_dict(_bad(change), "ball.json")
    assert "\n" not in str(e.value)


def test_load_and_resolve(tmp_path):
    (tmp_path / "b.json").write_text(json.dumps(Ball.load(REPAINTED).to_dict()))
    assert load_ball(tmp_path / "b.json").name == "repainted-baseball"
    assert load_ball("tennis").name == "tennis"
    with pytest.raises(ValueError, match="--ball: 'curling' is neither a built-in ball"):
        load_ball("curling")
    with pytest.raises(ValueError, match="ball file .*nope.json does not exist"):
        load_ball(tmp_path / "nope.json")
    assert resolve_ball("b.json", tmp_path, "capture.json: ball").name == "repainted-baseball"
    with pytest.raises(ValueError, match=r"capture.json: ball: path '\.\./b.json' leaves the capture folder"):
        resolve_ball("../b.json", tmp_path / "sub", "capture.json: ball")
    assert resolve_ball(Ball.load(REPAINTED).to_dict(), tmp_path).radius == 0.0366
