"""project.json and JumpingJack files: typed validation with one line naming the file and the key
path (or element); arbitrary JSON, mutated projects and mutated XML load or are refused so."""

import json
import shutil

import pytest
from hypothesis import given

import fuzzing
from stillcap.io.jumpingjack import export_jumpingjack, import_jumpingjack, read_jumpingjack
from stillcap.io.project import Project

CI = fuzzing.CI  # the suite's bound on examples


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    root = tmp_path_factory.mktemp("seed")
    p = fuzzing.make_project(root / "proj")
    juja = export_jumpingjack(p, root / "jj" / "thesis.juja")
    return p.root, juja


def _project_with(made, tmp_path, fn):
    root = tmp_path / "p"
    shutil.copytree(made[0], root)
    d = json.loads((root / "project.json").read_text())
    fn(d)
    (root / "project.json").write_text(fuzzing.dumps(d))
    return root


@pytest.mark.parametrize("change, message", [
    (lambda d: d["views"][1].__setitem__("angle_deg", float("nan")),
     r"project.json: views\.1\.angle_deg: input should be a finite number \(got nan\)$"),
    (lambda d: d["views"][1].__setitem__("angle_deg", 1e308),
     r"project.json: views\.1\.angle_deg: input should be less than or equal to 1000000"),
    (lambda d: d["views"][1].__setitem__("angle_deg", "30"),
     r"project.json: views\.1\.angle_deg: input should be a valid number \(got '30'\)$"),
    (lambda d: d["views"][0]["detected"].__setitem__("head.1", [1, 2, 3]),
     r"project.json: views\.0\.detected\.head\.1: tuple should have at most 2 items"),
    (lambda d: d["views"][0]["detected"].__setitem__("head.1", [1, "abc"]),
     r"project.json: views\.0\.detected\.head\.1\.1: input should be a valid number \(got 'abc'\)$"),
    (lambda d: d["views"][0]["edits"][0].__setitem__("op", "rotate"),
     r"project.json: views\.0\.edits\.0\.op: input should be 'delete', 'relabel' or 'move' \(got 'rotate'\)$"),
    (lambda d: d["views"][0]["edits"][0].__setitem__("xy", [1, float("inf")]),
     r"project.json: views\.0\.edits\.0\.xy\.1: input should be a finite number"),
    (lambda d: d["views"][0]["edits"][0].pop("xy"),
     r"project.json: views\.0 \(view 'turn_000.0deg'\): edits\.0: move edit of 'leg.L1': 'xy' is for move edits only "
     r"and required there$"),
    (lambda d: d["views"][0]["detected"].__setitem__("head.1", [1e9, 2]),
     r"project.json: view 'turn_000.0deg': detections: marker 'head.1': position \(1e\+09, 2\) px is outside"),
    (lambda d: d["views"][0].__setitem__("image", "../../etc/passwd"),
     r"project.json: view 'turn_000.0deg': image: path '../../etc/passwd' leaves the project folder"),
    (lambda d: d["views"].__setitem__(0, [1, 2]), r"project.json: views\.0: input should be a valid dictionary"),
    (lambda d: d.__setitem__("version", 0),
     r"project.json: version: input should be greater than or equal to 1 \(got 0\)"),
    (lambda d: d.__setitem__("version", True), r"project.json: version: input should be a valid integer \(got True\)"),
    (lambda d: d["turntable"].__setitem__("distance_m", -0.4),
     r"project.json: turntable\.distance_m: input should be greater than 0 \(got -0.4\)"),
    (lambda d: d.__setitem__("markerset", {"file": "../m.json"}),
     r"project.json: markerset file: path '../m.json' leaves the project folder"),
    (lambda d: d.__setitem__("markerset", dict(fuzzing.seed_markerset(), bone_rules=[],
                                               markers=[{"name": "a", "bone": "tail", "offset": [0, 0, 0]}])),
     r"project.json: markers\.0\.bone: marker 'a' is on bone 'tail', which skeleton 'puppet-210mm' lacks"),
    (lambda d: d.__setitem__("markerset", dict(fuzzing.seed_markerset(), length_unit="in")),
     r"project.json: markerset\.length_unit: input should be 'm', 'cm' or 'mm'"),
    (lambda d: d.__setitem__("meta", [1]), r"project.json: meta: input should be a valid dictionary"),
])
def test_bad_projects_get_one_line(made, tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        Project.load(_project_with(made, tmp_path, change))


def test_the_seed_project_loads(made):
    p = Project.load(made[0])
    assert len(p.views) == 3 and "leg.L1" in p.views[0].markers and "arm.R1" in p.views[2].markers


def test_any_project_file_loads_or_is_refused_in_one_line(made, tmp_path):
    seed = json.loads((made[0] / "project.json").read_text())

    @CI
    @given(fuzzing.json_files(seed, fuzzing.PROJECT_FROZEN))
    def prop(doc):
        root = tmp_path / "p"
        if not root.exists():
            shutil.copytree(made[0], root)
        (root / "project.json").write_text(fuzzing.dumps(doc))
        fuzzing.outcome(lambda path: fuzzing.read_project(path.parent), root / "project.json")

    prop()


@pytest.mark.parametrize("xml, message", [
    ('<JJProject><image name="0" normal_src="thesis_0.png"><marker name="head.1" x="nan" y="2"/></image></JJProject>',
     r"t.juja: image #0 \('0'\): marker 'head.1' x must be finite, got 'nan'"),
    ('<JJProject><image name="0" normal_src="thesis_0.png"><marker name="head.1" y="2"/></image></JJProject>',
     r"t.juja: image #0 \('0'\): marker 'head.1' x must be a number, got None"),
    ('<JJProject><image name="0"/></JJProject>', r"t.juja: image #0 \('0'\): missing the normal_src attribute"),
    ('<JJProject><image normal_src="thesis_0.png"/></JJProject>', r"t.juja: image #0: missing the name attribute"),
    ('<JJProject><image name="0" normal_src="/etc/passwd"/></JJProject>',
     r"t.juja: image #0 \('0'\): normal_src: path '/etc/passwd' is absolute"),
    ('<JJProject><image name="1e300" normal_src="thesis_0.png"/></JJProject>',
     r"t.juja: image #0 \('1e300'\): name '1e300': the turn angle must be finite and within \+-1e\+06 degrees$"),
    ('<JJProject><image name="0" normal_src="thesis_0.png"><marker name="head.1" x="1e308" y="2"/></image></JJProject>',
     r"t.juja: image #0 \('0'\): view at 0 deg: detections: marker 'head.1': position \(1e\+308, 2\) px is outside"),
])
def test_bad_jumpingjack_files_get_one_line(made, tmp_path, xml, message):
    folder = tmp_path / "jj"
    shutil.copytree(made[1].parent, folder)
    (folder / "t.juja").write_text(xml)
    with pytest.raises(ValueError, match=message):
        import_jumpingjack(folder / "t.juja", tmp_path / "new")


def test_any_jumpingjack_file_imports_or_is_refused_in_one_line(made, tmp_path):
    text = made[1].read_text()
    folder = tmp_path / "jj"
    shutil.copytree(made[1].parent, folder)
    runs = iter(range(10 ** 6))

    def read(path):
        read_jumpingjack(path)
        return import_jumpingjack(path, tmp_path / f"new{next(runs)}")

    @CI
    @given(fuzzing.xml_mutations(text))
    def prop(xml):
        (folder / "t.juja").write_text(xml)
        fuzzing.outcome(read, folder / "t.juja")

    prop()
