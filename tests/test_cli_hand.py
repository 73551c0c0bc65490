"""`stillcap hand` and the hand demo: outputs written, options honoured, bad input exits 2."""

import json

import pytest

from support import run_cli as run

SIZE = (1280, 960)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from stillcap.studio.hand import hand_capture

    root = tmp_path_factory.getbasetemp() / "cli-hand"
    hc = hand_capture(2, image_size=SIZE)
    cap, images = hc.to_capture(".jpg")
    cap.save(root, images, jpeg_quality=92)
    return root


def test_hand_json(capture, capsys):
    code, out, err = run(["hand", capture, "--json", "--interpolation", "slerp", "--frame-rate", "500"], capsys)
    assert code == 0, err
    d = json.loads(out)
    assert d["kind"] == "hand" and len(d["marker_names"]) == 18
    assert d["truth_comparison"]["labels_right_pct"] >= 99.0
    assert d["release"] is not None and d["release"]["success"]


def test_hand_tables_exports_and_report(capture, tmp_path, capsys):
    code, out, err = run(["hand", capture, "--export", tmp_path / "h.bvh", "--export", tmp_path / "h.glb",
                          "--export", tmp_path / "m.c3d", "--report", tmp_path / "rep"], capsys)
    assert code == 0, err
    assert "Compared with the truth" in out and "labels right" in out and "release:" in out
    for f in ("h.bvh", "h.glb", "m.c3d", "rep/report.html", "rep/hand.gif", "rep/joint_angles.png", "rep/hand.json"):
        assert (tmp_path / f).stat().st_size > 100, f
    # every file of the report is one the check before the analysis knows, and is recorded as stillcap's
    from pathlib import Path

    from stillcap.cli.hand import REPORT_FILES
    from stillcap.files.outputs import MANIFEST, is_stillcap_output

    written = {p.relative_to(tmp_path / "rep").as_posix() for p in (tmp_path / "rep").rglob("*")} - {MANIFEST}
    assert all(any(Path(w).match(pat) for pat in REPORT_FILES) for w in written), written
    assert all(is_stillcap_output(tmp_path / f) for f in ("h.bvh", "h.glb", "m.c3d", "rep/report.html"))


@pytest.mark.parametrize("args, message", [
    (["--personalise", "tall"], "is not one of best, joint"),
    (["--interpolation", "cubic"], "is not one of spline, slerp"),
    (["--strobe-position", "1,2"], "expected three numbers X,Y,Z"),
    (["--export", "hand.xyz"], "unknown extension '.xyz'"),
    (["--slow-motion", "0"], "must be a positive factor"),
])
def test_bad_options_exit_2(capture, capsys, args, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(["hand", capture, *args], capsys)
    assert code == 2 and message in err


def test_not_a_capture_folder(tmp_path, capsys):
    code, out, err = run(["hand", tmp_path / "nothing"], capsys)
    assert code == 2 and "nothing" in err


def test_hand_demo_small(tmp_path, capsys):
    from stillcap.cli.demo import hand_summary
    from stillcap.cli.demo_hand import hand_demo

    res = hand_demo(tmp_path / "demo", 3, image_size=SIZE)
    out = capsys.readouterr().out
    assert "Compared with the truth" in out
    for f in ("hand.json", "hand.bvh", "hand.glb", "markers.c3d", "report/report.html", "capture/truth.json"):
        assert (tmp_path / "demo" / f).is_file(), f
    rows = hand_summary(res)
    assert rows[0][1] == "labels right" and rows[0][2].endswith("%")


def test_slow_motion_stretches_exported_time(capture, tmp_path, capsys):
    code, out, err = run(["hand", capture, "--export", tmp_path / "real.bvh", "--json"], capsys)
    assert code == 0, err
    code, out, err = run(["hand", capture, "--export", tmp_path / "slow.bvh", "--slow-motion", "40", "--json"], capsys)
    assert code == 0, err

    def frame_time(p):
        line = next(x for x in p.read_text().splitlines() if x.startswith("Frame Time:"))
        return float(line.split(":")[1])

    assert frame_time(tmp_path / "slow.bvh") == pytest.approx(40 * frame_time(tmp_path / "real.bvh"))


def test_motion_export_without_animation_exits_2_and_writes_nothing(capture, tmp_path, capsys, monkeypatch):
    """A capture that gave fewer than two hand poses has no animation: a motion format cannot be
    written (a marker file still could), and the error names the file."""
    from dataclasses import replace

    import stillcap.pipelines.hand as hand_pipeline

    real = hand_pipeline.analyse_hand
    monkeypatch.setattr(hand_pipeline, "analyse_hand", lambda *a, **k: replace(real(*a, **k), animation=None))
    code, out, err = run(["hand", capture, "--export", tmp_path / "one.bvh"], capsys)
    assert code == 2 and "one.bvh" in err and "fewer than two hand poses" in err
    assert not (tmp_path / "one.bvh").exists()
