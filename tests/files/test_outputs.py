"""files/outputs: output locations checked before the work, stillcap outputs recognised, fallbacks."""

import errno
import json
import os
from pathlib import Path

import pytest

from stillcap.files import outputs as outputs_mod
from stillcap.files.outputs import (MANIFEST, check_writable, is_stillcap_output, mark_folder, record_outputs,
                                    save_fallback)

ROOT = os.geteuid() == 0 if hasattr(os, "geteuid") else False


def test_parent_that_is_a_file(tmp_path):
    """Works as root too: nothing can be made under a file."""
    f = tmp_path / "plain.txt"
    f.write_text("x")
    with pytest.raises(ValueError, match=rf"^--csv {f}/sub/out.csv: {f} is a file, not a folder$"):
        check_writable(f / "sub" / "out.csv", "file", option="--csv")
    with pytest.raises(ValueError, match=rf"^--report {f}/rep: {f} is a file, not a folder$"):
        check_writable(f / "rep", "folder", option="--report")


def test_file_output_that_is_a_folder_and_the_reverse(tmp_path):
    with pytest.raises(ValueError, match=rf"^--csv {tmp_path} is a folder; give a file name$"):
        check_writable(tmp_path, "file", option="--csv")
    f = tmp_path / "report"
    f.write_text("x")
    with pytest.raises(ValueError, match=rf"^--report {f} is a file, not a folder$"):
        check_writable(f, "folder", option="--report")


def test_device_is_not_replaced():
    """``/dev/null`` would be replaced by a regular file by an atomic write (as root)."""
    if not Path("/dev/null").exists():
        pytest.skip("no /dev/null on this system")
    with pytest.raises(ValueError, match="/dev/null is not a regular file"):
        check_writable("/dev/null", "file", option="--csv")


@pytest.mark.skipif(ROOT, reason="root writes into a read-only folder; test_unwritable_folder_as_root covers it")
def test_read_only_folder(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(ValueError, match=rf"^--report {ro}/rep: cannot write in the folder {ro} \(Permission "
                                             "denied\\)$"):
            check_writable(ro / "rep", "folder", option="--report")
        with pytest.raises(ValueError, match=rf"cannot write in the folder {ro}"):
            check_writable(ro / "x.csv", "file", option="--csv")
        with pytest.raises(ValueError, match=rf"cannot write in the folder {ro}"):
            check_writable(ro, "folder", option="--out")
    finally:
        ro.chmod(0o755)


def test_unwritable_folder_as_root(tmp_path, monkeypatch):
    """The check makes a real file (``os.access`` says yes to root): a folder where that fails,
    whoever runs the test, is refused with the system's reason."""
    ro = tmp_path / "ro"
    ro.mkdir()
    real = outputs_mod.tempfile.mkstemp

    def mkstemp(*a, dir=None, **kw):
        if Path(dir) == ro:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS))
        return real(*a, dir=dir, **kw)

    monkeypatch.setattr(outputs_mod.tempfile, "mkstemp", mkstemp)
    with pytest.raises(ValueError, match=rf"^--out {ro}/a/b: cannot write in the folder {ro} \(Read-only file "
                                         r"system\)$"):
        check_writable(ro / "a" / "b", "folder", option="--out")
    check_writable(tmp_path / "fine", "folder", option="--out")


def test_sysfs_is_refused_even_for_root():
    """A real location nobody may write files in, root included (Linux sysfs)."""
    sys_dir = Path("/sys/kernel")
    if not sys_dir.is_dir() or os.access(sys_dir, os.W_OK) and not ROOT:
        pytest.skip("no /sys/kernel here")
    try:
        check_writable(sys_dir / "stillcap-test", "folder", option="--out")
    except ValueError as e:
        assert str(e).startswith(f"--out {sys_dir}/stillcap-test: cannot write in the folder {sys_dir} (")
    else:
        pytest.skip("/sys/kernel accepts new files here")


def test_probe_leaves_nothing(tmp_path):
    check_writable(tmp_path / "x.csv", "file")
    check_writable(tmp_path, "folder")
    assert list(tmp_path.iterdir()) == []


def test_existing_file_not_written_by_stillcap_needs_force(tmp_path):
    f = tmp_path / "data.csv"
    f.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match=rf"^--csv {f} exists and was not written by stillcap; pass --force to "
                                         "overwrite it$"):
        check_writable(f, "file", option="--csv")
    check_writable(f, "file", option="--csv", force=True)
    record_outputs([f])  # now stillcap wrote it
    check_writable(f, "file", option="--csv")
    assert json.loads((tmp_path / MANIFEST).read_text())["files"] == ["data.csv"]


@pytest.mark.parametrize("name, content", [
    ("rig.json", '{\n  "format": "stillcap-rig",\n  "version": 1}'),
    ("result.json", '{"format":"stillcap-puppet-result"}'),
    ("pose.dae", "<COLLADA><asset><contributor><authoring_tool>stillcap</authoring_tool></contributor></asset>"),
    ("pose.gltf", '{"asset":{"generator":"stillcap","version":"2.0"}}'),
    ("empty.bvh", ""),
])
def test_stillcap_outputs_are_recognised(tmp_path, name, content):
    f = tmp_path / name
    f.write_text(content)
    assert is_stillcap_output(f)
    check_writable(f, "file", option="--out")
    assert not (tmp_path / MANIFEST).exists()
    record_outputs([f])  # signed files need no manifest (an empty one is listed)
    assert (tmp_path / MANIFEST).exists() == (content == "")


@pytest.mark.parametrize("content", ['{"format": "other-tool"}', "HIERARCHY\nROOT hips\n", "x,y\n"])
def test_other_files_are_not(tmp_path, content):
    f = tmp_path / "f.json"
    f.write_text(content)
    assert not is_stillcap_output(f)


def test_folder_with_named_files(tmp_path):
    """A folder output with known file names: only an existing one stillcap did not write is refused."""
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "notes.txt").write_text("mine")
    names = ("report.html", "pitch.json", "overlays/*.png")
    check_writable(rep, "folder", option="--report", names=names)
    (rep / "report.html").write_text("<html>mine</html>")
    with pytest.raises(ValueError, match=rf"^--report {rep}: report.html exists and was not written by stillcap; "
                                         "pass --force to overwrite it$"):
        check_writable(rep, "folder", option="--report", names=names)
    check_writable(rep, "folder", option="--report", names=names, force=True)
    record_outputs([rep / "report.html"], rep)
    check_writable(rep, "folder", option="--report", names=names)
    (rep / "overlays").mkdir()
    (rep / "overlays" / "00_a.png").write_bytes(b"\x89PNG")
    with pytest.raises(ValueError, match="overlays/00_a.png exists and was not written by stillcap"):
        check_writable(rep, "folder", option="--report", names=names)
    record_outputs([rep / "overlays" / "00_a.png"], rep)  # listed in the folder above: recognised
    check_writable(rep, "folder", option="--report", names=names)
    (rep / "pitch.json").mkdir()
    with pytest.raises(ValueError, match="pitch.json is a folder where a file is written"):
        check_writable(rep, "folder", option="--report", names=names)


def test_folder_without_names(tmp_path):
    """Without file names: empty, new, or marked by stillcap."""
    out = tmp_path / "demo"
    check_writable(out, "folder", option="--out")
    out.mkdir()
    check_writable(out, "folder", option="--out")
    (out / "mine.txt").write_text("x")
    with pytest.raises(ValueError, match=rf"^--out {out} holds files stillcap did not write; pass --force to "
                                         "write into it$"):
        check_writable(out, "folder", option="--out")
    check_writable(out, "folder", option="--out", force=True)
    mark_folder(out)
    check_writable(out, "folder", option="--out")


def test_bad_manifest_is_ignored(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("1")
    (tmp_path / MANIFEST).write_text("not json")
    assert not is_stillcap_output(f)
    record_outputs([f])  # a broken manifest is replaced
    assert is_stillcap_output(f)


def test_save_fallback(tmp_path, monkeypatch):
    monkeypatch.setattr(outputs_mod.tempfile, "tempdir", str(tmp_path))
    p = save_fallback('{"a": 1}\n', "pitch.json")
    assert p.parent.parent == tmp_path and p.parent.name.startswith("stillcap-unsaved-")
    assert json.loads(p.read_text()) == {"a": 1}
