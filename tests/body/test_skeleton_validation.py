"""Skeleton and marker-set files: typed validation (files/schema) with one line naming the file and
the key path; arbitrary JSON and mutations of a valid file either load or are refused so."""

import json

import pytest

import fuzzing
from stillcap.body import Skeleton
from stillcap.body.markerset import MarkerSet



def _skeleton_with(tmp_path, fn):
    d = fuzzing.seed_skeleton()
    fn(d)
    path = tmp_path / "sk.json"
    path.write_text(fuzzing.dumps(d))
    return path


@pytest.mark.parametrize("change, message", [
    (lambda d: d["joints"][1].__setitem__("offset", [1, "abc", 0]),
     r"sk.json: joints\.1\.offset\.1: input should be a valid number \(got 'abc'\)$"),
    (lambda d: d["joints"][1].__setitem__("offset", [1, float("nan"), 0]),
     r"sk.json: joints\.1\.offset\.1: input should be a finite number \(got nan\)$"),
    (lambda d: d["joints"][1].__setitem__("offset", [1e308, 0, 0]),
     r"sk.json: joints\.1\.offset\.0: input should be less than or equal to 1000000"),
    (lambda d: d["joints"][1].__setitem__("offset", [1, 2]), r"sk.json: joints\.1\.offset\.2: field required$"),
    (lambda d: d["joints"][1].__setitem__("parent", "nobody"),
     r"sk.json: joints\.1\.parent: joint 'l-hip' has unknown parent 'nobody' \(joints: root, "),
    (lambda d: d["joints"][2].__setitem__("name", "l-hip"), r"sk.json: joints\.2\.name: duplicate joint name 'l-hip'$"),
    (lambda d: d["joints"][0].__setitem__("parent", "l-hip"),
     r"joint 'root' is in a cycle of parents .* in .*sk.json$"),
    (lambda d: d["joints"][1].__setitem__("parent", None),
     r"exactly one root joint, got \['root', 'l-hip'\] in .*sk.json"),
    (lambda d: d.__setitem__("length_unit", "km"),
     r"sk.json: length_unit: input should be 'm', 'cm' or 'mm' \(got 'km'\)"),
    (lambda d: d.__setitem__("joints", []), r"sk.json: joints: list should have at least 1 item"),
    (lambda d: d["joints"][1].__setitem__("limits_deg", [[0, 1], [5, -5], None]),
     r"sk.json: joints\.1: limits_deg\[y\] of joint 'l-hip' must have min <= max"),
    (lambda d: d["joints"][1].__setitem__("limits_deg", [[0, 1], ["a", 2], None]),
     r"sk.json: joints\.1\.limits_deg\.1\.0: input should be a valid number"),
    (lambda d: d.__setitem__("format", "stillcap-rig"), r"sk.json: format: not a skeleton file"),
])
def test_bad_skeleton_files_get_one_line(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        Skeleton.load(_skeleton_with(tmp_path, change))


def _markers_with(tmp_path, fn):
    d = fuzzing.seed_markerset()
    fn(d)
    path = tmp_path / "ms.json"
    path.write_text(fuzzing.dumps(d))
    return path


@pytest.mark.parametrize("change, message", [
    (lambda d: d["markers"][0].__setitem__("offset", [0, float("inf"), 0]),
     r"ms.json: markers\.0\.offset\.1: input should be a finite number \(got inf\)$"),
    (lambda d: d["markers"][0].__setitem__("hsb", [1.5, 0, 0]),
     r"ms.json: markers\.0\.hsb\.0: input should be less than or equal to 1 \(got 1.5\)$"),
    (lambda d: d["markers"][0].__setitem__("rgb", [0, 0, -1]),
     r"ms.json: markers\.0\.rgb\.2: input should be greater than or equal to 0"),
    (lambda d: d["markers"][0].__setitem__("diameter", 0),
     r"ms.json: markers\.0\.diameter: input should be greater than 0"),
    (lambda d: d["markers"][0].__setitem__("bone", 7),
     r"ms.json: markers\.0\.bone: input should be a valid string \(got 7\)"),
    (lambda d: d["markers"][0].pop("offset"), r"ms.json: markers\.0\.offset: field required$"),
    (lambda d: d["bone_rules"].append({"bone": "l-toes", "cross": "l-foot", "axis": [0, 0, 0]}),
     r"ms.json: bone_rules\.\d+\.bone: two bone rules for bone 'l-toes'"),
    (lambda d: d["bone_rules"].__setitem__(0, {"bone": "head", "copy": "nowhere"}),
     r"ms.json: bone_rules\.0\.copy: bone rule for 'head' uses bone 'nowhere' before a rule defines it"),
    (lambda d: d["bone_rules"].__setitem__(0, {"bone": "head", "from": "head.2"}),
     r"ms.json: bone_rules\.0: bone rule for 'head' needs exactly one of from/to, copy, cross\+axis"),
    (lambda d: d["bone_rules"][0].__setitem__("primary", "yes"),
     r"ms.json: bone_rules\.0\.primary: input should be a valid boolean"),
])
def test_bad_marker_set_files_get_one_line(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        MarkerSet.load(_markers_with(tmp_path, change))


def test_cross_rules_need_a_non_zero_axis(tmp_path):
    def zero_axis(d):
        rule = next(r for r in d["bone_rules"] if "cross" in r)
        rule["axis"] = [0, 0, 0]
    with pytest.raises(ValueError, match=r"ms.json: bone_rules\.\d+\.axis: .*'cross' needs a non-zero 'axis'"):
        MarkerSet.load(_markers_with(tmp_path, zero_axis))


def test_markers_on_bones_the_skeleton_lacks_are_named(tmp_path):
    ms = MarkerSet.load(_markers_with(tmp_path, lambda d: d["markers"][2].__setitem__("bone", "tail")))
    with pytest.raises(ValueError, match=r"ms.json: markers\.2\.bone: marker '.*' is on bone 'tail', which skeleton "
                                         r"'puppet-210mm' lacks \(bones: "):
        ms.check_skeleton(Skeleton.puppet())


def test_seeds_load():
    for name in ("skeleton", "markerset"):
        fuzzing.FORMATS[name].seed()
    assert len(Skeleton.from_dict(fuzzing.seed_skeleton())) == 20
    assert len(MarkerSet.from_dict(json.loads(json.dumps(fuzzing.seed_markerset())))) == 20


@pytest.mark.parametrize("name", ["skeleton", "markerset"])
def test_any_file_loads_or_is_refused_in_one_line(tmp_path, name):
    fuzzing.check_any_file(tmp_path, name)
