"""Label overrides files (`stillcap hand --overrides`): one line naming the file and the entry."""

import pytest

import fuzzing
from stillcap.body.hand_label import read_label_overrides



def _with(tmp_path, fn):
    return fuzzing.written(tmp_path, fuzzing.seed_overrides(), fn, "ov.json")


def test_the_seed_loads(tmp_path):
    ov = read_label_overrides(_with(tmp_path, lambda d: None))
    assert [o.label for o in ov] == ["index.nail", None] and ov[1].tolerance_m == pytest.approx(0.002)
    assert ov[0].entry.endswith("ov.json: overrides.0")


@pytest.mark.parametrize("change, message", [
    (lambda d: d["overrides"][0].__setitem__("flash", 1.0),
     r"ov.json: overrides\.0\.flash: input should be a valid integer"),
    (lambda d: d["overrides"][0].__setitem__("flash", -1),
     r"ov.json: overrides\.0\.flash: input should be greater than or "),
    (lambda d: d["overrides"][0].__setitem__("position_m", [0, float("nan"), 0]),
     r"ov.json: overrides\.0\.position_m\.1: input should be a finite number \(got nan\)$"),
    (lambda d: d["overrides"][0].__setitem__("label", 5),
     r"ov.json: overrides\.0\.label: input should be a valid string"),
    (lambda d: d["overrides"][1].__setitem__("delete", "yes"),
     r"ov.json: overrides\.1\.delete: input should be a valid boolean"),
    (lambda d: d["overrides"][1].__setitem__("delete", False), r"ov.json: overrides\.1: needs either a 'label' or"),
    (lambda d: d["overrides"][0].__setitem__("colour", "red"), r"ov.json: overrides\.0\.colour: unknown key"),
    (lambda d: d.__setitem__("tolerance_mm", 0), r"ov.json: tolerance_mm: input should be greater than 0"),
    (lambda d: d.__setitem__("tolerance_mm", 1e308),
     r"ov.json: tolerance_mm: input should be less than or equal to 1000"),
    (lambda d: d.pop("overrides"), r"ov.json: overrides: field required$"),
])
def test_bad_overrides_get_one_line(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        read_label_overrides(_with(tmp_path, change))


def test_a_folder_is_named(tmp_path):
    with pytest.raises(ValueError, match=rf"label overrides file {tmp_path} is a folder, not a JSON file"):
        read_label_overrides(tmp_path)


def test_any_file_loads_or_is_refused_in_one_line(tmp_path):
    fuzzing.check_any_file(tmp_path, "overrides")
