"""Every command that reads a user's file, handed arbitrary and mutated files: it succeeds (exit 0)
or exits 2 with exactly one line on stderr, never a traceback.

Commands: `export`, `puppet show|edit|reconstruct|run --palette|export-jj|import-jj`,
`hand --overrides`, `markers --palette`, `palette --keep`. tools/fuzz_files.py runs longer campaigns.
"""

import json
import shutil

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fuzzing
from support import run_cli


def settings_for(n):
    return settings(max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck))


def check(args, capsys):
    """Run the command; the property: exit 0, or exit 2 and one line on stderr."""
    code, _, err = run_cli(args, capsys)
    assert code in (0, 2), f"exit {code}: {err}"
    if code == 2:
        assert len(err.strip().splitlines()) == 1, f"not one line: {err!r}"
        assert err.startswith("error: "), err
    return code, err


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    return fuzzing.make_project(tmp_path_factory.mktemp("cli-seed") / "proj").root


def _fresh_project(project, tmp_path, doc):
    root = tmp_path / "p"
    if root.exists():
        shutil.rmtree(root)
    shutil.copytree(project, root)
    (root / "project.json").write_text(fuzzing.dumps(doc))
    return root


def test_export_of_bad_results(tmp_path, capsys):
    d = fuzzing.seed_result()
    d["markers"][0]["position"] = [1e308, 0, 0]
    (tmp_path / "r.json").write_text(json.dumps(d))
    code, err = check(["export", tmp_path / "r.json", "--to", tmp_path / "o.c3d"], capsys)
    assert code == 2 and "r.json: markers.0.position.0: input should be less than or equal to 1000000" in err
    d = fuzzing.seed_result()
    d["joints"][4]["position"] = "abc"
    (tmp_path / "r.json").write_text(json.dumps(d))
    code, err = check(["export", tmp_path / "r.json", "--to", tmp_path / "o.c3d"], capsys)
    assert code == 2 and "r.json: joints.4.position: input should be a valid tuple (got 'abc')" in err
    assert not (tmp_path / "o.c3d").exists()


def test_export_reads_any_file(tmp_path, capsys):
    seed = fuzzing.seed_result()

    @settings_for(25)
    @given(fuzzing.json_files(seed))
    def prop(doc):
        (tmp_path / "r.json").write_text(fuzzing.dumps(doc))
        check(["export", tmp_path / "r.json", "--to", tmp_path / "o.c3d", "--to", tmp_path / "o.bvh",
               "--to", tmp_path / "o.json"], capsys)

    prop()


@pytest.mark.parametrize("command", [
    ["puppet", "show", "{p}"],
    ["puppet", "edit", "{p}", "0", "--delete", "head.1"],
    ["puppet", "reconstruct", "{p}"],
    ["puppet", "export-jj", "{p}", "{tmp}/jj/out.juja"],
    ["puppet", "run", "{p}", "--palette", "{tmp}/pal.json"],
])
def test_puppet_commands_read_any_project(project, tmp_path, capsys, command):
    seed = json.loads((project / "project.json").read_text())
    (tmp_path / "pal.json").write_text(json.dumps(fuzzing.seed_palette()))
    n = 6 if command[1] in ("reconstruct", "run") else 15

    @settings_for(n)
    @given(fuzzing.json_files(seed, fuzzing.PROJECT_FROZEN))
    def prop(doc):
        root = _fresh_project(project, tmp_path, doc)
        check([a.format(p=root, tmp=tmp_path) for a in command], capsys)

    prop()


def test_puppet_run_reads_any_palette(project, tmp_path, capsys):
    @settings_for(6)
    @given(fuzzing.json_files(fuzzing.seed_palette()))
    def prop(doc):
        (tmp_path / "pal.json").write_text(fuzzing.dumps(doc))
        check(["puppet", "run", project, "--palette", tmp_path / "pal.json"], capsys)

    prop()


def test_import_jj_reads_any_file(project, tmp_path, capsys):
    code, _ = check(["puppet", "export-jj", project, tmp_path / "jj" / "t.juja"], capsys)
    assert code == 0
    text = (tmp_path / "jj" / "t.juja").read_text()
    runs = iter(range(10 ** 6))

    @settings_for(15)
    @given(fuzzing.xml_mutations(text))
    def prop(xml):
        (tmp_path / "jj" / "t.juja").write_text(xml)
        check(["puppet", "import-jj", tmp_path / "jj" / "t.juja", tmp_path / f"new{next(runs)}"], capsys)

    prop()


def test_palette_keep_reads_any_file(tmp_path, capsys):
    seeds = [fuzzing.seed_palette(), fuzzing.seed_markerset()]

    @settings_for(15)
    @given(st.sampled_from(seeds).flatmap(fuzzing.json_files))
    def prop(doc):
        (tmp_path / "keep.json").write_text(fuzzing.dumps(doc))
        check(["palette", "2", "--keep", tmp_path / "keep.json", "--restarts", "1"], capsys)

    prop()


@pytest.fixture(scope="module")
def marker_capture(tmp_path_factory):
    from stillcap.cli import main

    root = tmp_path_factory.mktemp("cli-markers") / "cap"

    main(["studio", "markers", "--out", str(root), "--seed", "3", "--balls", "4"])
    return root


def test_markers_reads_any_palette(marker_capture, tmp_path, capsys):
    capsys.readouterr()

    @settings_for(8)
    @given(fuzzing.json_files(fuzzing.seed_bgr_palette()))
    def prop(doc):
        (tmp_path / "balls.json").write_text(fuzzing.dumps(doc))
        check(["markers", marker_capture, "--palette", tmp_path / "balls.json", "--json"], capsys)

    prop()


@pytest.fixture(scope="module")
def hand_capture_folder(tmp_path_factory):
    from stillcap.studio.hand import hand_capture

    root = tmp_path_factory.mktemp("cli-hand") / "cap"
    hc = hand_capture(2, image_size=(1280, 960))
    cap, images = hc.to_capture(".jpg")
    cap.save(root, images, jpeg_quality=92)
    return root


def test_hand_reads_any_overrides(hand_capture_folder, tmp_path, capsys):
    bad = fuzzing.seed_overrides()
    bad["overrides"][0]["position_m"] = [0, "abc", 0]
    (tmp_path / "ov.json").write_text(json.dumps(bad))
    code, err = check(["hand", hand_capture_folder, "--overrides", tmp_path / "ov.json"], capsys)
    assert code == 2 and "ov.json: overrides.0.position_m.1: input should be a valid number (got 'abc')" in err

    @settings_for(6)
    @given(fuzzing.json_files(fuzzing.seed_overrides()))
    def prop(doc):
        (tmp_path / "ov.json").write_text(fuzzing.dumps(doc))
        check(["hand", hand_capture_folder, "--overrides", tmp_path / "ov.json", "--json"], capsys)

    prop()


def test_names_from_files_are_not_rich_markup(tmp_path, capsys):
    d = fuzzing.seed_overrides()
    d["overrides"][0]["[/x]"] = 1
    (tmp_path / "ov.json").write_text(json.dumps(d))
    code, err = check(["hand", tmp_path / "missing-capture", "--overrides", tmp_path / "ov.json"], capsys)
    assert code == 2 and "overrides.0.[/x]: unknown key" in err
