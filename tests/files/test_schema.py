import pytest

from stillcap.files.schema import ClosedModel, Count, Finite, Model, Positive, PositiveCount, validate


class Cam(Model):
    fx: Positive
    k: Finite = 0.0
    n: Count = 0
    size: tuple[PositiveCount, PositiveCount] = (1, 1)


class Rig(Model):
    cameras: list[Cam]


def test_valid_values_pass_and_ints_are_numbers():
    rig = validate(Rig, {"cameras": [{"fx": 1, "k": -2.5, "n": 3, "size": [640, 480], "note": "kept"}]}, "rig.json")
    assert rig.cameras[0].fx == 1.0 and rig.cameras[0].size == (640, 480)


@pytest.mark.parametrize("camera, message", [
    ({"fx": float("nan")}, "rig.json: cameras.0.fx: input should be a finite number (got nan)"),
    ({"fx": -1}, "rig.json: cameras.0.fx: input should be greater than 0 (got -1)"),
    ({"fx": True}, "rig.json: cameras.0.fx: input should be a valid number (got True)"),
    ({"fx": "1.5"}, "rig.json: cameras.0.fx: input should be a valid number (got '1.5')"),
    ({"fx": 1, "n": 1.0}, "rig.json: cameras.0.n: input should be a valid integer (got 1.0)"),
    ({"fx": 1, "size": [3, 1e308]}, "rig.json: cameras.0.size.1: input should be a valid integer (got 1e+308)"),
    ({}, "rig.json: cameras.0.fx: field required"),
])
def test_one_line_naming_file_key_and_value(camera, message):
    with pytest.raises(ValueError) as e:
        validate(Rig, {"cameras": [camera]}, "rig.json")
    assert str(e.value) == message


def test_the_whole_file_and_more_problems():
    with pytest.raises(ValueError, match=r"^rig.json: \(the whole file\): input should be a valid dictionary"):
        validate(Rig, 5, "rig.json")
    with pytest.raises(ValueError, match=r"; 1 more problem\(s\)$"):
        validate(Rig, {"cameras": [{"fx": -1, "k": "x"}]}, "rig.json")


def test_keys_from_a_file_stay_on_one_line():
    class Open(Model):
        data: dict[str, Positive]

    with pytest.raises(ValueError) as e:
        validate(Open, {"data": {"a\nb": -1}}, "f.json")
    assert str(e.value) == "f.json: data.'a\\nb': input should be greater than 0 (got -1)"
    with pytest.raises(ValueError) as e:
        validate(Open, {"data": {"head.1": -1, "\x85": 1}}, "f.json")
    assert str(e.value) == "f.json: data.head.1: input should be greater than 0 (got -1)"


def test_unknown_keys_are_named():
    class Closed(ClosedModel):
        a: Count = 0

    with pytest.raises(ValueError, match=r"^f.json: b: unknown key \(not part of the format; check its spelling\) "
                                         r"\(got 1\)$"):
        validate(Closed, {"b": 1}, "f.json")
