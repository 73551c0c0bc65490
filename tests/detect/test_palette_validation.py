"""Palette files (`puppet run --palette`, `palette --keep`) and marker-ball palettes (`markers
--palette`): one line naming the file and the key path."""

import pytest

import fuzzing
from stillcap.detect.palette import Palette, read_bgr_palette



def _write(tmp_path, d, name="pal.json"):
    path = tmp_path / name
    path.write_text(fuzzing.dumps(d))
    return path


def test_seeds_load(tmp_path):
    assert len(Palette.load(_write(tmp_path, fuzzing.seed_palette()))) == 16
    assert read_bgr_palette(_write(tmp_path, fuzzing.seed_bgr_palette()))["red"] == (30, 30, 220)


@pytest.mark.parametrize("data, message", [
    ({"colors": [{"name": "a", "rgb": [0, 0, 1.5]}]},
     r"pal.json: colors\.0\.rgb\.2: input should be less than or equal to 1"),
    ({"colors": [{"name": "a", "rgb": [0, float("nan"), 1]}]},
     r"pal.json: colors\.0\.rgb\.1: input should be a finite number"),
    ({"colors": [{"name": "", "rgb": [0, 0, 1]}]},
     r"pal.json: colors\.0\.name: string should have at least 1 character"),
    ({"colors": [{"name": "a", "rgb": [0, 0, 1]}, {"name": "a", "rgb": [1, 0, 1]}]},
     r"pal.json: colors\.1\.name: colour 'a' is listed twice"),
    ({"colors": []}, r"pal.json: colors: list should have at least 1 item"),
    ([1, 2], r"pal.json: \(the whole file\): input should be a valid dictionary"),
])
def test_bad_palettes_get_one_line(tmp_path, data, message):
    with pytest.raises(ValueError, match=message):
        Palette.load(_write(tmp_path, data))


@pytest.mark.parametrize("data, message", [
    ({"red": [0, 0, 256]}, r"balls.json: red\.2: input should be less than or equal to 255"),
    ({"red": [0, 0]}, r"balls.json: red\.2: field required"),
    ({"red": "#ff0000"}, r"balls.json: red: input should be a valid tuple"),
    ({}, r"balls.json: \(the whole file\): dictionary should have at least 1 item"),
])
def test_bad_ball_palettes_get_one_line(tmp_path, data, message):
    with pytest.raises(ValueError, match=message):
        read_bgr_palette(_write(tmp_path, data, "balls.json"))


@pytest.mark.parametrize("name", ["palette", "bgr-palette"])
def test_any_file_loads_or_is_refused_in_one_line(tmp_path, name):
    fuzzing.check_any_file(tmp_path, name)
