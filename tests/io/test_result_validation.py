"""Puppet result files (what `stillcap export` reads) and the data every exporter receives:
finite, bounded numbers, or one line naming the file and the key path."""

import numpy as np
import pytest

import fuzzing
from stillcap.body import Skeleton
from stillcap.body.markerset import MarkerTrajectories
from stillcap.io.export import as_export_data, export
from stillcap.io.puppet_result import load_result



def _result_with(tmp_path, fn):
    return fuzzing.written(tmp_path, fuzzing.seed_result(), fn, "result.json")


def test_the_seed_result_loads_and_exports(tmp_path):
    res = load_result(_result_with(tmp_path, lambda d: None))
    assert np.isnan(res.markers.points[0, 3]).all() and np.isfinite(res.markers.points[0, 4]).all()
    for ext in (".c3d", ".bvh", ".json"):
        assert export(tmp_path / f"out{ext}", res).is_file()


@pytest.mark.parametrize("change, message", [
    (lambda d: d["markers"][0].__setitem__("position", [1e308, 0, 0]),
     r"result.json: markers\.0\.position\.0: input should be less than or equal to 1000000 \(got 1e\+308\)$"),
    (lambda d: d["joints"][2].__setitem__("position", "abc"),
     r"result.json: joints\.2\.position: input should be a valid tuple \(got 'abc'\)$"),
    (lambda d: d["joints"][2].__setitem__("position", [0, 0, 0]),
     r"result.json: joints\.2\.position: joint 'l-knee' is at \[0.0, 0.0, 0.0\] but the skeleton, root2world and local "
     r"rotations put it at"),
    (lambda d: d["joints"][1].__setitem__("local_rotation", [[1, 0, 0], [0, 1, 0], [0, 0, 2]]),
     r"result.json: joints\.1\.local_rotation: must be a rotation matrix"),
    (lambda d: d["joints"][1].__setitem__("local_rotation", [[1, 0, 0], [0, 1, 0], [0, 0, float("nan")]]),
     r"result.json: joints\.1\.local_rotation\.2\.2: input should be a finite number"),
    (lambda d: d["joints"].pop(), r"result.json: joints: no entry for the skeleton's joints \['r-finger'\]"),
    (lambda d: d["joints"].append(dict(d["joints"][0])),
     r"result.json: joints\.20\.name: joint 'root' is listed twice"),
    (lambda d: d["root2world"][3].__setitem__(3, 2), r"result.json: root2world: root2world must be rigid"),
    (lambda d: d["root2world"].pop(), r"result.json: root2world\.3: field required"),
    (lambda d: d["skeleton"]["joints"][3].__setitem__("offset", [0, "x", 0]),
     r"result.json: skeleton\.joints\.3\.offset\.1: input should be a valid number \(got 'x'\)"),
    (lambda d: d["markers"].append(dict(d["markers"][0])),
     r"result.json: markers\.16\.name: marker 'head.1' is listed twice"),
    (lambda d: d.__setitem__("version", 2), r"result.json: result version 2 is newer"),
    (lambda d: d.__setitem__("format", "x"), r"result.json is not a stillcap puppet result"),
])
def test_bad_results_get_one_line(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        load_result(_result_with(tmp_path, change))


def test_exporters_get_no_infinite_or_huge_positions(tmp_path):
    traj = MarkerTrajectories.single(["a", "b"], [[0, 0, 0], [1e308, 1, 2]])
    with pytest.raises(ValueError,
        match=r"cannot export: marker 'b' \(frame 0\) is at \[1e\+308, 1.0, 2.0\] m; positions "
                                         r"must be finite and within 1e\+06 m"):
        export(tmp_path / "m.c3d", traj)
    assert not (tmp_path / "m.c3d").exists()
    traj = MarkerTrajectories.single(["a"], [[np.inf, 0, 0]])
    with pytest.raises(ValueError, match="marker 'a'"):
        as_export_data(traj)
    as_export_data(MarkerTrajectories.single(["a"], [[np.nan, 0, 0]]))  # NaN: not seen, kept as before
    sk = Skeleton.puppet()
    far = sk.rest_pose()
    far.root2world[:3, 3] = [2e6, 0, 0]
    with pytest.raises(ValueError, match=r"cannot export: joint 'root' \(frame 0\) is at \[2000000.0"):
        export(tmp_path / "p.bvh", far)


def test_any_result_loads_or_is_refused_in_one_line(tmp_path):
    fuzzing.check_any_file(tmp_path, "result")
