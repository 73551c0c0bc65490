"""Outputs of every command: checked before the work starts (one line, exit 2), never lost when
writing fails afterwards, files stillcap did not write kept unless --force; a session of pitch
captures goes on past bad ones."""

import errno
import json
import os
import shutil
from pathlib import Path

import pytest

from stillcap.files.outputs import MANIFEST
from support import run_cli as run, studio_pitch


@pytest.fixture(scope="module")
def fastball(tmp_path_factory):
    return studio_pitch(tmp_path_factory, "fastball")


@pytest.fixture(autouse=True)
def own_temp_folder(tmp_path, monkeypatch):
    """Results saved because an output failed go to the test's own temporary folder."""
    import tempfile

    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


# Every command that writes where the user says, with the output under a plain file ("F/x"): the
# inputs may be dummies, as the outputs are checked before any input is read.
COMMANDS = [
    (["pitch", "CAP", "--report", "F/x"], "--report"),
    (["pitch", "CAP", "--csv", "F/x.csv"], "--csv"),
    (["pitch", "CAP", "CAP2", "--report", "F/x"], "--report"),
    (["hand", "CAP", "--report", "F/x"], "--report"),
    (["hand", "CAP", "--export", "F/x.bvh"], "--export"),
    (["puppet", "run", "CAP", "--out", "F/x"], "--out"),
    (["puppet", "reconstruct", "CAP", "--out", "F/x"], "--out"),
    (["puppet", "new", "F/x"], "PROJECT"),
    (["puppet", "import-jj", "CAP/a.juja", "F/x"], "PROJECT"),
    (["puppet", "export-jj", "PROJ", "F/x.juja"], "JUJA"),
    (["puppet", "calibrate-palette", "CAP", "--out", "F/x.json"], "--out"),
    (["export", "CAP/result.json", "--to", "F/x.csv"], "--to"),
    (["calibrate", "intrinsics", "CAP/a.jpg", "--out", "F/x.json"], "--out"),
    (["calibrate", "stereo", "CAP/left1.jpg", "CAP/right1.jpg", "--out", "F/x.json"], "--out"),
    (["calibrate", "rig", "CAP", "--out", "F/x.json"], "--out"),
    (["studio", "chessboard", "--out", "F/x"], "--out"),
    (["studio", "markers", "--out", "F/x"], "--out"),
    (["studio", "puppet", "--out", "F/x"], "--out"),
    (["studio", "pitch", "--out", "F/x"], "--out"),
    (["studio", "hand", "--out", "F/x"], "--out"),
    (["demo", "--out", "F/x"], "--out"),
    (["markers", "CAP", "--out", "F/x.json"], "--out"),
]


def _args(args, tmp_path):
    from stillcap.io.project import Project

    f = tmp_path / "F"
    f.write_text("a file, not a folder")
    if "PROJ" in args:
        Project.create(tmp_path / "proj")
    subs = {"F": str(f), "CAP": str(tmp_path / "cap"), "CAP2": str(tmp_path / "cap2"), "PROJ": str(tmp_path / "proj")}
    out = []
    for a in args:
        head, _, rest = a.partition("/")
        out.append(subs[head] + ("/" + rest if rest else "") if head in subs else a)
    return out, f


@pytest.mark.parametrize("args, option", COMMANDS, ids=[" ".join(a[:2]) + " " + o for a, o in COMMANDS])
def test_output_under_a_file_exits_2_before_the_work(args, option, tmp_path, capsys):
    """A parent that is a file (root cannot write there either): one line naming the path and the
    problem, exit 2, before any input is read."""
    argv, f = _args(args, tmp_path)
    code, out, err = run(argv, capsys)
    line = _one_line(err)
    assert code == 2, err
    assert line.startswith(f"error: {option} {f}/x") and line.endswith(f": {f} is a file, not a folder"), line
    assert f.read_text() == "a file, not a folder"


@pytest.mark.parametrize("args, message", [
    (["pitch", "CAP", "--csv", "DIR"], "--csv DIR is a folder; give a file name"),
    (["pitch", "CAP", "--report", "FILE"], "--report FILE is a file, not a folder"),
    (["export", "CAP/r.json", "--to", "DIR/"], None),  # no extension: the exporter's message
    (["calibrate", "intrinsics", "CAP/a.jpg", "--out", "DIR"], "--out DIR is a folder; give a file name"),
    (["puppet", "run", "CAP", "--out", "FILE"], "--out FILE is a file, not a folder"),
    (["markers", "CAP", "--out", "FILE"], "--out FILE exists and was not written by stillcap; pass --force"),
])
def test_file_for_folder_and_folder_for_file(args, message, tmp_path, capsys):
    (tmp_path / "DIR").mkdir()
    (tmp_path / "FILE").write_text("mine")
    argv = [a.replace("CAP", str(tmp_path / "cap")).replace("DIR", str(tmp_path / "DIR"))
            .replace("FILE", str(tmp_path / "FILE")) for a in args]
    code, _, err = run(argv, capsys)
    line = _one_line(err)
    assert code == 2
    if message is not None:
        expected = message.replace("DIR", str(tmp_path / "DIR")).replace("FILE", str(tmp_path / "FILE"))
        assert line.startswith("error: " + expected), line
    assert (tmp_path / "FILE").read_text() == "mine"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder; the next test covers it")
def test_read_only_folder_chmod(fastball, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, _, err = run(["pitch", fastball, "--report", ro / "rep"], capsys)
        assert code == 2 and _one_line(err) == f"error: --report {ro}/rep: cannot write in the folder {ro} " \
                                               "(Permission denied)"
    finally:
        ro.chmod(0o755)


def test_unwritable_folder_for_root_too(fastball, tmp_path, capsys, monkeypatch):
    """The check makes a real file in the folder: where that fails (here made to, as the tests may
    run as root), the command stops before the analysis with the system's reason."""
    from stillcap.files import outputs as outputs_mod
    import stillcap.pipelines.pitch as pitch_pipeline

    ro = tmp_path / "ro"
    ro.mkdir()
    real = outputs_mod.tempfile.mkstemp

    def mkstemp(*a, dir=None, **kw):
        if Path(dir) == ro:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))
        return real(*a, dir=dir, **kw)

    def no_analysis(*a, **k):
        raise AssertionError("the analysis ran before the outputs were checked")

    monkeypatch.setattr(outputs_mod.tempfile, "mkstemp", mkstemp)
    monkeypatch.setattr(pitch_pipeline, "analyse_pitch", no_analysis)
    code, _, err = run(["pitch", fastball, "--report", ro / "rep", "--csv", tmp_path / "ok.csv"], capsys)
    assert code == 2 and _one_line(err) == f"error: --report {ro}/rep: cannot write in the folder {ro} " \
                                           "(Permission denied)"
    code, _, err = run(["export", tmp_path / "r.json", "--to", ro / "x.bvh"], capsys)
    assert code == 2 and _one_line(err) == f"error: --to {ro}/x.bvh: cannot write in the folder {ro} " \
                                           "(Permission denied)"


def _enospc(*a, **k):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/full/disk/pitch.json")


def test_write_failing_after_the_analysis_keeps_the_result(fastball, tmp_path, capsys, monkeypatch):
    """Disk full while writing the report: the tables still print, the result is saved in a
    temporary folder, and the line names it; exit 2."""
    import stillcap.report.pitch as report

    monkeypatch.setattr(report, "write_report", _enospc)
    code, out, err = run(["pitch", fastball, "--report", tmp_path / "rep", "--csv", tmp_path / "pos.csv"], capsys)
    assert code == 2
    assert "Pitch metrics" in out  # the printed result
    line = _one_line(err)
    assert line.startswith(f"error: cannot write --report {tmp_path / 'rep'} (/full/disk/pitch.json: No space left "
                           "on device); the result is saved in "), line
    saved = Path(line.rsplit(" ", 1)[1])
    assert saved.parent.parent == tmp_path / "tmp" and saved.name == "pitch.json"
    d = json.loads(saved.read_text())
    assert d["format"] == "stillcap-pitch" and d["metrics"]["release_speed_mph"] > 50
    assert (tmp_path / "pos.csv").is_file()  # the other output was written


def test_report_cut_short_is_still_stillcaps(fastball, tmp_path, capsys, monkeypatch):
    """A report whose writing stopped half-way (disk full) is written again without --force."""
    import stillcap.report.pitch as report

    real = report.write_report

    def half(res, out):
        report.plot_pitch(res, out)  # the plots, then the disk is full
        _enospc()

    monkeypatch.setattr(report, "write_report", half)
    code, _, err = run(["pitch", fastball, "--report", tmp_path / "rep"], capsys)
    assert code == 2 and "No space left on device" in err and (tmp_path / "rep" / "side.png").is_file()
    monkeypatch.setattr(report, "write_report", real)
    code, _, err = run(["pitch", fastball, "--report", tmp_path / "rep"], capsys)
    assert code == 0, err


def test_write_failing_with_json_and_no_fallback(fastball, tmp_path, capsys, monkeypatch):
    """When even the temporary folder cannot be written, the result is the JSON on stdout."""
    import stillcap.report.pitch as report
    from stillcap.cli import _outputs

    monkeypatch.setattr(report, "write_positions_csv", _enospc)
    monkeypatch.setattr(_outputs, "save_fallback", lambda text, name: None)
    code, out, err = run(["pitch", fastball, "--csv", tmp_path / "pos.csv"], capsys)
    assert code == 2 and "the result is printed on stdout as JSON" in _one_line(err)
    assert json.loads(out[out.index("{"):])["format"] == "stillcap-pitch"
    code, out, err = run(["pitch", fastball, "--csv", tmp_path / "pos.csv", "--json"], capsys)
    assert code == 2 and _one_line(err).endswith("; the result is the JSON printed on stdout")
    assert json.loads(out)["format"] == "stillcap-pitch"


def test_force_and_stillcap_outputs(fastball, tmp_path, capsys):
    """A file stillcap did not write is kept unless --force; stillcap's own outputs are overwritten."""
    from stillcap.cli.pitch import REPORT_FILES

    mine = tmp_path / "mine.csv"
    mine.write_text("my data\n")
    code, _, err = run(["pitch", fastball, "--csv", mine], capsys)
    assert code == 2 and _one_line(err) == f"error: --csv {mine} exists and was not written by stillcap; pass " \
                                           "--force to overwrite it"
    assert mine.read_text() == "my data\n"
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "report.html").write_text("my page")
    (rep / "notes.txt").write_text("mine")
    code, _, err = run(["pitch", fastball, "--report", rep], capsys)
    assert code == 2 and "report.html exists and was not written by stillcap; pass --force" in _one_line(err)
    code, _, err = run(["pitch", fastball, "--report", rep, "--csv", mine, "--force"], capsys)
    assert code == 0, err
    assert mine.read_text().startswith("flash") or mine.read_text() != "my data\n"
    assert (rep / "notes.txt").read_text() == "mine"
    written = {p.relative_to(rep).as_posix() for p in rep.rglob("*") if p.is_file()} - {"notes.txt", MANIFEST}
    assert written <= set(json.loads((rep / MANIFEST).read_text())["files"])
    assert all(any(Path(w).match(pat) for pat in REPORT_FILES) for w in written), written  # the check knows them
    code, _, err = run(["pitch", fastball, "--report", rep, "--csv", mine], capsys)  # stillcap's now: no --force
    assert code == 0, err


def test_export_jj_force(tmp_path, capsys):
    from stillcap.io.project import Project

    Project.create(tmp_path / "proj")
    juja = tmp_path / "out.juja"
    juja.write_text("<my/>")
    code, _, err = run(["puppet", "export-jj", tmp_path / "proj", juja], capsys)
    assert code == 2 and _one_line(err) == f"error: JUJA {juja} exists and was not written by stillcap; pass " \
                                           "--force to overwrite it"
    assert juja.read_text() == "<my/>"
    code, _, err = run(["puppet", "export-jj", tmp_path / "proj", juja, "--force"], capsys)
    assert code == 0, err
    code, _, err = run(["puppet", "export-jj", tmp_path / "proj", juja], capsys)
    assert code == 0, err
    assert "out.juja" in json.loads((tmp_path / MANIFEST).read_text())["files"]


def _corrupt_copies(fastball, tmp_path):
    """Three copies of a good capture, each broken in one way, and a folder that does not exist."""
    no_photo = tmp_path / "no_photo"
    shutil.copytree(fastball, no_photo)
    first = sorted((no_photo / "images").iterdir())[0]
    first.unlink()
    bad_json = tmp_path / "bad_json"
    shutil.copytree(fastball, bad_json)
    (bad_json / "capture.json").write_text('{"format": "stillcap-capture", ')
    bad_photo = tmp_path / "bad_photo"
    shutil.copytree(fastball, bad_photo)
    sorted((bad_photo / "images").iterdir())[0].write_bytes(b"\x89PNG\r\n\x1a\n not really a PNG")
    return [no_photo, bad_json, bad_photo, tmp_path / "absent"], first.name


def test_session_goes_on_past_corrupted_captures(fastball, tmp_path, capsys):
    """A session with broken captures (worker processes): each failure named in one line with the
    capture's path, the good ones analysed and summed up, exit 2."""
    bad, missing = _corrupt_copies(fastball, tmp_path)
    good2 = tmp_path / "good2"
    shutil.copytree(fastball, good2)
    code, out, err = run(["pitch", fastball, *bad, good2, "--report", tmp_path / "rep"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 4, err
    for cap, line in zip(bad, lines):
        assert line.startswith(f"{cap}: "), line
    assert missing in lines[0]
    assert "capture.json" in lines[1]
    assert "bad_photo" in lines[2] and "images" in lines[2]
    assert "absent" in lines[3]
    assert "6 pitches (4 failed)" in out
    assert (tmp_path / "rep" / fastball.name / "report.html").is_file()
    assert (tmp_path / "rep" / "good2" / "report.html").is_file()
    for cap in bad:
        assert not (tmp_path / "rep" / cap.name).exists()


def test_session_names_any_failure_and_a_lost_report(fastball, tmp_path, capsys, monkeypatch):
    """An unexpected error in one capture (a bug, a worker lost) and a report that cannot be
    written: both named, the session goes on, the result of the second saved; exit 2."""
    import stillcap.pipelines.pitch as pitch_pipeline
    import stillcap.report.pitch as report

    crash, full, ok = (tmp_path / n for n in ("crash", "full", "ok"))
    for c in (crash, full, ok):
        shutil.copytree(fastball, c)
    real_analyse, real_report = pitch_pipeline.analyse_pitch, report.write_report

    def analyse(cap, opts):
        if cap.root.name == "crash":
            raise RuntimeError("a worker process died")
        return real_analyse(cap, opts)

    def write_report(res, out):
        if Path(out).name == "full":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(Path(out) / "side.png"))
        return real_report(res, out)

    monkeypatch.setattr(pitch_pipeline, "analyse_pitch", analyse)
    monkeypatch.setattr(report, "write_report", write_report)
    code, out, err = run(["pitch", crash, full, ok, "--processes", "0", "--report", tmp_path / "rep", "--json"],
                         capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 2, err
    assert lines[0] == f"{crash}: RuntimeError: a worker process died"
    assert lines[1].startswith(f"{full}: cannot write --report {tmp_path / 'rep' / 'full'} (")
    saved = Path(lines[1].rsplit(" ", 1)[1])
    assert json.loads(saved.read_text())["format"] == "stillcap-pitch" and saved.name == "full.pitch.json"
    assert saved.parent.parent == tmp_path / "tmp"
    d = json.loads(out)
    assert d[0]["error"] == "RuntimeError: a worker process died" and "metrics" in d[1] and "metrics" in d[2]
    assert (tmp_path / "rep" / "ok" / "report.html").is_file()


def test_session_help_says_exit_2():
    from typer.testing import CliRunner

    from stillcap.cli import app

    text = " ".join(CliRunner().invoke(app, ["pitch", "--help"], terminal_width=200).output.split())
    assert "exit status is 2 when any capture failed" in text
