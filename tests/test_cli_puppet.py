"""`stillcap puppet ...`, `stillcap export`, `stillcap palette`: commands run, files load in real readers,
bad input exits 2 with a message naming it."""

import json
import shutil

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from stillcap.cli import app, main

from support import run_cli as run
from stillcap.io.capture import Capture
from stillcap.files.jsonable import from_jsonable
from stillcap.io.project import Project
from stillcap.studio.puppet import PuppetTruth


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A rendered T-pose, 6 turntable views 60 degrees apart (every bead seen 4-5 times)."""
    out = tmp_path_factory.mktemp("cli") / "cap"
    main(["studio", "puppet", "--out", str(out), "--pose", "tpose", "--seed", "2", "--views", "6", "--step-deg", "60"])
    return out


@pytest.fixture(scope="module")
def result_json(capture, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    main(["puppet", "run", str(capture), "--out", str(out)])
    return out / "result.json"


def test_puppet_run_json_and_outputs(capture, result_json, capsys):
    code, out, _ = run(["puppet", "run", capture, "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    truth = json.loads((capture / "truth.json").read_text())
    assert res["format"] == "stillcap-puppet-result" and res["missing"] == []
    # keys shared with the truth, in metres
    assert [m["name"] for m in res["markers"]] == [m["name"] for m in truth["markers"]]
    p = np.array([m["position"] for m in res["markers"]], float)
    t = np.array([m["position"] for m in truth["markers"]], float)
    assert np.abs(p - t).max() < 0.5e-3
    assert from_jsonable(res["markers_px"]).shape == (6, 16, 2)
    assert res["comparison"]["identification"]["wrong_used"] == 0
    # --out wrote the same result, overlays and plots
    folder = result_json.parent
    assert json.loads(result_json.read_text())["markers"] == res["markers"]
    assert len(list((folder / "overlays").glob("*.png"))) == 6
    for f in ("markers_3d.png", "skeleton_3d.png"):
        assert cv2.imread(str(folder / f)) is not None
    # and report.html, linking the plots and every overlay
    page = (folder / "report.html").read_text(encoding="utf-8")
    for f in ["markers_3d.png", "skeleton_3d.png"] + [f"overlays/{p.name}" for p in (folder / "overlays").glob("*.png")]:
        assert f"src='{f}'" in page, f
    # the table
    code, out, _ = run(["puppet", "run", capture, "--identify", "thesis"], capsys)
    assert code == 0 and "markers from 6 views" in out and "Compared with the truth" in out


def test_json_with_out_keeps_stdout_json(capture, tmp_path, capsys):
    """--json --out: stdout is the JSON alone; the "wrote ..." line goes to stderr."""
    code, out, err = run(["puppet", "run", capture, "--json", "--out", tmp_path / "o"], capsys)
    assert code == 0 and json.loads(out)["format"] == "stillcap-puppet-result"
    assert "wrote result.json" in err and (tmp_path / "o" / "result.json").is_file()


def test_run_out_files_are_known_and_recorded(result_json):
    """Every file ``puppet run --out`` writes is one the check before the analysis knows, and is
    recorded as stillcap's (a second run needs no --force)."""
    from pathlib import Path

    from stillcap.cli.puppet import OUT_FILES
    from stillcap.files.outputs import MANIFEST, check_writable, is_stillcap_output

    out = result_json.parent
    written = [p for p in out.rglob("*") if p.is_file() and p.name != MANIFEST]
    assert all(any(Path(p.relative_to(out).as_posix()).match(pat) for pat in OUT_FILES) for p in written), written
    assert all(is_stillcap_output(p) for p in written)
    check_writable(out, "folder", option="--out", names=OUT_FILES)


def test_export_to_every_format(result_json, tmp_path, capsys):
    files = [tmp_path / n for n in ("pose.dae", "pose.bvh", "pose.gltf", "pose.glb", "markers.c3d", "m.csv", "m.json")]
    code, out, err = run(["export", result_json, *sum((["--to", f] for f in files), [])], capsys)
    assert code == 0, err
    assert all(f.is_file() and f.stat().st_size > 0 for f in files)
    res = json.loads(result_json.read_text())
    joints = {j["name"]: np.array(j["position"]) for j in res["joints"]}
    collada = pytest.importorskip("collada")
    dae = collada.Collada(str(files[0]))
    assert dae.assetInfo.upaxis == "Y_UP" and len(dae.scenes) == 1
    from stillcap.io.bvh_read import read_bvh

    anim = read_bvh(files[1])
    np.testing.assert_allclose(anim[0].positions[anim.skeleton.index("l-elbow")], joints["l-elbow"], atol=1e-6)
    pygltflib = pytest.importorskip("pygltflib")
    for f in files[2:4]:
        g = pygltflib.GLTF2().load(str(f))
        assert {n.name for n in g.nodes} >= set(joints)
    ezc3d = pytest.importorskip("ezc3d")
    c = ezc3d.c3d(str(files[4]))
    assert c["parameters"]["POINT"]["LABELS"]["value"][:16] == [m["name"] for m in res["markers"]]
    pts = c["data"]["points"][:3, :16, 0].T
    np.testing.assert_allclose(pts, np.array([m["position"] for m in res["markers"]]) * 1000, atol=1e-3)
    assert "kind,name" in files[5].read_text().splitlines()[0].replace("frame,time_s,", "")
    assert json.loads(files[6].read_text())["format"] == "stillcap-export"
    # a project folder exports too; a bad extension names itself
    code, _, err = run(["export", result_json, "--to", tmp_path / "x.fbx"], capsys)
    assert code == 2 and "x.fbx" in err


def test_palette(capsys):
    code, out, _ = run(["palette", "5", "--json", "--restarts", "2"], capsys)
    assert code == 0
    d = json.loads(out)
    assert len(d["colors"]) == 5 and d["min_distance"] > 20 and all(c["hex"].startswith("#") for c in d["colors"])
    code, out, _ = run(["palette", "3", "--restarts", "1"], capsys)
    assert code == 0 and "3 marker colours" in out
    code, _, err = run(["palette", "0"], capsys)
    assert code == 2 and "N must be a positive" in err


def _angles(capture):
    cap = Capture.load(capture)
    return [(capture / im.file, im.meta["angle_deg"]) for im in cap.images]


def test_project_new_add_edit_show_reconstruct(capture, tmp_path, capsys):
    proj = tmp_path / "proj"
    assert run(["puppet", "new", proj], capsys)[0] == 0
    for photo, angle in _angles(capture):
        code, out, err = run(["puppet", "add", proj, photo, "--angle", angle], capsys)
        assert code == 0, err
        assert "markers identified" in out
    p = Project.load(proj)
    assert len(p.views) == 6 and all(len(v.detected) >= 8 for v in p.views)
    code, out, _ = run(["puppet", "edit", proj, "60", "--delete", "head.1"], capsys)
    assert code == 0 and "1 edits" in out
    code, out, _ = run(["puppet", "edit", proj, "#2", "--move", "head.2", "300", "200"], capsys)
    assert code == 0
    code, out, _ = run(["puppet", "edit", proj, "turn_120.0deg", "--clear"], capsys)
    assert code == 0 and "0 edits" in out
    code, out, _ = run(["puppet", "show", proj, "--json"], capsys)
    d = json.loads(out)
    assert len(d["views"]) == 6 and d["views"][1]["edits"] == 1 and d["seen_fewer_than_twice"] == []
    code, out, _ = run(["puppet", "show", proj], capsys)
    assert code == 0 and "views per marker" in out
    code, out, _ = run(["puppet", "reconstruct", proj, "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    truth = PuppetTruth.from_dict(json.loads((capture / "truth.json").read_text()))
    p3 = np.array([m["position"] for m in res["markers"]], float)
    np.testing.assert_allclose(p3, truth.marker_positions, atol=0.5e-3)
    # project folders export directly
    code, _, err = run(["export", proj, "--to", tmp_path / "p.bvh"], capsys)
    assert code == 0 and (tmp_path / "p.bvh").is_file(), err
    # unknown view and a bad edit name themselves
    code, _, err = run(["puppet", "edit", proj, "45", "--delete", "head.1"], capsys)
    assert code == 2 and "no view at 45 deg" in err
    code, _, err = run(["puppet", "edit", proj, "0", "--delete", "nose"], capsys)
    assert code == 2 and "'nose'" in err


def test_capture_from_a_video_file(capture, tmp_path):
    frames = [cv2.imread(str(f)) for f, _ in _angles(capture)[:3]]
    video = tmp_path / "turn.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 5, (640, 480))
    assert w.isOpened()
    for f in frames:
        w.write(f)
    w.release()
    proj = tmp_path / "proj"
    Project.create(proj)
    runner = CliRunner()
    # Enter takes 0 deg, s skips 30, Enter takes 60, q stops before 90
    r = runner.invoke(app, ["puppet", "capture", str(proj), "--source", str(video), "--angles", "4x30"],
                      input="\ns\n\nq\n")
    assert r.exit_code == 0, r.output
    assert "took 2 photos" in r.output and "skipped 30 deg" in r.output and "(stopped)" in r.output
    p = Project.load(proj)
    assert p.angles_deg == [0.0, 60.0]
    assert all(len(v.detected) >= 8 for v in p.views)  # detected as they were taken
    img = p.read_image(0)
    assert img.shape == (480, 640, 3) and np.abs(img.astype(float) - frames[0]).mean() < 3  # MJPG is lossy


def test_jumpingjack_round_trip(capture, tmp_path, capsys):
    proj = tmp_path / "proj"
    run(["puppet", "new", proj], capsys)
    for photo, angle in _angles(capture)[:3]:
        run(["puppet", "add", proj, photo, "--angle", angle], capsys)
    code, _, err = run(["puppet", "export-jj", proj, tmp_path / "jj" / "take.juja"], capsys)
    assert code == 0, err
    assert (tmp_path / "jj" / "take.juja").is_file() and len(list((tmp_path / "jj").glob("take_*"))) == 3
    code, _, err = run(["puppet", "import-jj", tmp_path / "jj" / "take.juja", tmp_path / "back"], capsys)
    assert code == 0, err
    a, b = Project.load(proj), Project.load(tmp_path / "back")
    assert [v.angle_deg for v in a.views] == [v.angle_deg for v in b.views]
    for va, vb in zip(a.views, b.views):
        assert va.markers.keys() == vb.markers.keys()
        for k in va.markers:
            np.testing.assert_allclose(va.markers[k], vb.markers[k], atol=1e-6)


def test_bad_input_exits_2_with_a_message(capture, tmp_path, capsys):
    code, _, err = run(["puppet", "run", tmp_path / "missing"], capsys)
    assert code == 2 and "missing" in err and "does not exist" in err
    main(["studio", "markers", "--out", str(tmp_path / "balls"), "--balls", "2", "--cameras", "2",
          "--size", "160x120"])
    code, _, err = run(["puppet", "run", tmp_path / "balls"], capsys)
    assert code == 2 and "kind 'markers'" in err and "'puppet'" in err
    code, _, err = run(["puppet", "run", capture, "--detector", "sift"], capsys)
    assert code == 2 and "unknown detector 'sift'" in err
    code, _, err = run(["puppet", "run", capture, "--identify", "magic"], capsys)
    assert code == 2 and "unknown identification 'magic'" in err
    code, _, err = run(["export", tmp_path / "nothing.json", "--to", tmp_path / "a.bvh"], capsys)
    assert code == 2 and "nothing.json" in err
    (tmp_path / "bad.json").write_text("{}")
    code, _, err = run(["export", tmp_path / "bad.json", "--to", tmp_path / "a.bvh"], capsys)
    assert code == 2 and "not a stillcap puppet result" in err
    code, _, err = run(["puppet", "capture", tmp_path / "noproject", "--source", "0"], capsys)
    assert code == 2 and "noproject" in err
    Project.create(tmp_path / "p2")
    code, _, err = run(["puppet", "capture", tmp_path / "p2", "--source", tmp_path / "no.avi"], capsys)
    assert code == 2 and "no.avi" in err
    shutil.rmtree(tmp_path / "p2")


def test_puppet_demo_and_its_summary(tmp_path, capsys):
    from stillcap.cli.demo import puppet_summary
    from stillcap.cli.demo_puppet import EXPORTS, puppet_demo

    res = puppet_demo(tmp_path / "demo", 0)
    for name in EXPORTS + ("result.json",):
        assert (tmp_path / "demo" / name).stat().st_size > 100, name
    assert (tmp_path / "demo" / "report.html").stat().st_size > 1000
    rows = {r.quantity: r for r in puppet_summary(res)}
    wrong = rows["identifications wrong (of all, per view and bead)"]
    assert wrong.measured == f"0 of {res.comparison.identified}" and wrong.met is True
    assert float(rows["marker 3D error, RMS"].measured.split()[0]) < 0.3
    assert float(rows["bone direction error, RMS (bones the beads fix)"].measured.split()[0]) < 0.5
    # forearms and shins carry one bead of puppet-16 (twist open): scored without a goal over those
    # whose bead was recovered; seed 0 hides arm.L3 in every view, so its forearm is listed as unfixed
    one_bead = rows["bone direction error, RMS (forearms, shins: one recovered bead, twist open)"]
    assert float(one_bead.measured.split()[0]) < 3 and one_bead.met is None
    unfixed = rows["forearms, shins without a recovered bead (not fixed, not scored)"]
    assert unfixed.measured == "l-hand" and unfixed.met is None and "arm.L3" in res.missing
