"""files/atomic: an interrupted write leaves the target as it was and no temporary file; a killed
one's temporary file goes at the next save into the folder."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from stillcap.files import atomic
from stillcap.files.atomic import TEMP_TAG, atomic_path, remove_stale_temp_files, write_text

REPO = Path(__file__).resolve().parents[2]


def _temps(folder):
    return [p for p in Path(folder).iterdir() if TEMP_TAG in p.name]


def test_temp_name_is_recognisable(tmp_path):
    with atomic_path(tmp_path / "plot.png") as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".png"
        assert tmp.name.startswith(f".plot.png{TEMP_TAG}{os.getpid()}-")
        assert atomic._TEMP_NAME.match(tmp.name)
        tmp.write_bytes(b"x")
    assert _temps(tmp_path) == [] and (tmp_path / "plot.png").read_bytes() == b"x"


@pytest.mark.parametrize("error", [KeyboardInterrupt, OSError, ValueError])
def test_interrupted_write_leaves_target_and_no_temp(tmp_path, error):
    """Ctrl-C (KeyboardInterrupt) or an error half-way: the old file stays whole, the temp goes."""
    target = tmp_path / "project.json"
    target.write_text('{"old": true}\n')
    with pytest.raises(error):
        with atomic_path(target) as tmp:
            with open(tmp, "w") as f:
                f.write('{"new": ')  # half written
                f.flush()
                raise error("interrupted")
    assert target.read_text() == '{"old": true}\n'
    assert _temps(tmp_path) == []


def test_writer_raising_keyboard_interrupt_midway(tmp_path, monkeypatch):
    """A writer of the library (write_text) interrupted after writing part of its bytes."""
    target = tmp_path / "rig.json"
    write_text(target, "old\n")
    real = Path.write_bytes

    def half_then_ctrl_c(self, data):
        real(self, data[: len(data) // 2])
        raise KeyboardInterrupt

    monkeypatch.setattr(Path, "write_bytes", half_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        write_text(target, "new content, long enough to be cut in half\n")
    monkeypatch.undo()
    assert target.read_text() == "old\n" and _temps(tmp_path) == []


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temp_files_are_removed_at_the_next_save(tmp_path):
    dead = tmp_path / f".project.json{TEMP_TAG}{_dead_pid()}-abcd1234.json"
    dead.write_text("half")
    live = tmp_path / f".other.json{TEMP_TAG}{os.getpid()}-efgh5678.json"  # a write of this process, going on
    live.write_text("half")
    old = tmp_path / f".old.png{TEMP_TAG}{os.getpid()}-ijkl9012.png"  # older than STALE_AFTER_S: the pid is reused
    old.write_text("half")
    t = time.time() - atomic.STALE_AFTER_S - 10
    os.utime(old, (t, t))
    user = tmp_path / ".project.json.backup"  # not ours: never touched
    user.write_text("mine")
    write_text(tmp_path / "project.json", "{}\n")
    assert not dead.exists() and not old.exists()
    assert live.exists() and user.exists()
    assert remove_stale_temp_files(tmp_path) == []


_SAVER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from stillcap.io.project import Project

    p = Project.load(sys.argv[1])
    p.name = "renamed"
    real = Path.write_bytes

    def slow(self, data):  # half the bytes, then wait to be killed
        real(self, data[: len(data) // 2])
        print("writing", flush=True)
        time.sleep(60)

    Path.write_bytes = slow
    p.save()
""")


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="no SIGKILL on this system")
def test_sigkill_during_project_save_then_save_again(tmp_path):
    """The issue's leftover: a project save killed half-way leaves its temp file and the old
    project.json; the next save into the folder removes the temp file."""
    from stillcap.io.project import Project

    folder = tmp_path / "proj"
    Project.create(folder, name="before")
    before = (folder / "project.json").read_text()
    env = dict(os.environ, PYTHONPATH=str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", _SAVER, str(folder)], stdout=subprocess.PIPE, env=env, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
        proc.stdout.close()
    stray = _temps(folder)
    assert len(stray) == 1 and stray[0].name.startswith(f".project.json{TEMP_TAG}{proc.pid}-")
    assert (folder / "project.json").read_text() == before  # the old file is whole
    p = Project.load(folder)
    p.name = "after"
    p.save()
    assert _temps(folder) == []
    assert Project.load(folder).name == "after"
