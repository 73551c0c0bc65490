"""``stillcap serve``: a warm server as a separate process on a socket in a temporary folder, the
``stillcap`` command (``python -m stillcap``, the console script's entry) sending runs to it.

What a run through the server must give is what the same run gives in its own process
(``STILLCAP_SERVER=off``): the same stdout, stderr and exit status, for a result and for bad
input; when no server can take it (none, a killed one's stale socket, other code) it runs in its
own process with the same result. No timings: the benchmark (benchmarks/bench_speed.py) times it.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
VIA = "stillcap: via the server at "
READY_WAIT_S = 300  # how long to wait for a server's imports on a loaded machine (not a timing test)


def _env(sock: Path, src: Path = SRC, **extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), STILLCAP_SOCKET=str(sock))
    env.pop("STILLCAP_SERVER", None)
    env.update(extra)
    return env


def stillcap(args, sock: Path, mode: str | None = None, src: Path = SRC, **extra) -> subprocess.CompletedProcess:
    """``python -m stillcap ARGS`` as a fresh process; ``mode``: STILLCAP_SERVER's value."""
    env = _env(sock, src, **extra)
    if mode is not None:
        env["STILLCAP_SERVER"] = mode
    return subprocess.run([sys.executable, "-m", "stillcap", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=600)


def start_server(sock: Path, src: Path = SRC, detach: bool = False):
    """A server on ``sock`` (its folder made private), once its status answers: its Popen (or
    None with ``detach``)."""
    sock.parent.mkdir(mode=0o700, exist_ok=True)
    args = [sys.executable, "-m", "stillcap", "serve", "--socket", str(sock), "--idle-timeout", "900"]
    if detach:
        r = subprocess.run([*args, "--detach"], capture_output=True, text=True, env=_env(sock, src), timeout=600)
        assert r.returncode == 0, r.stderr
        assert "listening on" in r.stdout
        return None
    proc = subprocess.Popen(args, env=_env(sock, src), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    end = time.monotonic() + READY_WAIT_S
    while stillcap(["serve", "--status"], sock, src=src).returncode != 0:
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < end, "the server did not start listening"
        time.sleep(0.5)
    return proc


def status(sock: Path, src: Path = SRC) -> dict | None:
    r = stillcap(["serve", "--status", "--json"], sock, src=src)
    return json.loads(r.stdout) if r.returncode == 0 else None


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    sock = tmp_path_factory.mktemp("serve") / "run" / "s.sock"
    proc = start_server(sock)
    yield sock, proc
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)


@pytest.fixture(scope="module")
def pitch_capture(tmp_path_factory):
    from support import studio_pitch

    return studio_pitch(tmp_path_factory, "fastball")


def _via(r: subprocess.CompletedProcess, sock: Path) -> str:
    """The run's stderr without the line saying it went through the server (which must be there)."""
    first, _, rest = r.stderr.partition("\n")
    assert first == VIA + str(sock), r.stderr
    return rest


def test_a_pitch_through_the_server_is_the_run_in_its_own_process(server, pitch_capture):
    from support import untimed

    sock, _ = server
    served = status(sock)["served"]
    warm = stillcap(["pitch", pitch_capture, "--json"], sock, "verbose")
    cold = stillcap(["pitch", pitch_capture, "--json"], sock, "off")
    assert (warm.returncode, cold.returncode) == (0, 0), (warm.stderr, cold.stderr)
    assert _via(warm, sock) == cold.stderr
    assert untimed(json.loads(warm.stdout)) == untimed(json.loads(cold.stdout))
    assert json.loads(warm.stdout)["self_checks"]  # a real result, with its self-checks
    assert status(sock)["served"] == served + 1  # the server ran it


@pytest.mark.parametrize("args", [["pitch", "{missing}", "--json"], ["pitch", "--no-such-option"],
                                  ["markers", "{missing}"], ["puppet", "run", "{missing}"]])
def test_bad_input_through_the_server_gives_the_same_line_and_status(server, tmp_path, args):
    sock, _ = server
    args = [a.replace("{missing}", str(tmp_path / "no-capture")) for a in args]
    warm = stillcap(args, sock, "verbose")
    cold = stillcap(args, sock, "off")
    assert warm.returncode == cold.returncode == 2
    assert _via(warm, sock) == cold.stderr
    assert warm.stdout == cold.stdout
    if args[0] == "pitch" and "--json" in args:
        assert cold.stderr == f"error: capture folder {args[1]} does not exist\n"


def test_the_client_imports_neither_numpy_nor_typer(server, pitch_capture):
    """The process of ``stillcap pitch`` run through the server loads only the standard library
    and stillcap's client modules (checked in that process after the run)."""
    sock, _ = server
    code = ("import sys\n"
            f"sys.argv = ['stillcap', 'pitch', {str(pitch_capture)!r}, '--json']\n"
            "from stillcap._entry import run\n"
            "try:\n    run()\nexcept SystemExit as e:\n    code = e.code\n"
            "heavy = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numpy', 'scipy', 'cv2', 'typer', 'click', 'rich', 'pydantic'))\n"
            "mine = sorted(m for m in sys.modules if m.startswith('stillcap'))\n"
            "sys.stderr.write(f'\\nCODE {code} HEAVY {heavy} STILLCAP {mine}\\n')\n")
    env = _env(sock, STILLCAP_SERVER="verbose")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert r.stderr.startswith(VIA), r.stderr
    assert "CODE 0 HEAVY [] STILLCAP ['stillcap', 'stillcap._entry', 'stillcap._server_link']" in r.stderr
    assert json.loads(r.stdout)["self_checks"]


def test_other_code_or_environment_runs_in_process(server, tmp_path):
    """A client whose import-time environment differs from the server's (here the BLAS thread
    count) runs the command itself, with the same result; STILLCAP_SERVER=off never asks."""
    sock, _ = server
    missing = tmp_path / "no-capture"
    # a value other than this process's (which the server inherited): Dask, imported by earlier
    # tests of the suite, sets OPENBLAS_NUM_THREADS=1 here
    other = "2" if os.environ.get("OPENBLAS_NUM_THREADS") == "1" else "1"
    r = stillcap(["pitch", missing], sock, "verbose", OPENBLAS_NUM_THREADS=other)
    assert r.returncode == 2
    assert r.stderr.splitlines()[0].startswith("stillcap: in-process (the server runs other code"), r.stderr
    assert r.stderr.splitlines()[1] == f"error: capture folder {missing} does not exist"
    served = status(sock)["served"]
    assert stillcap(["pitch", missing], sock, "off").returncode == 2
    assert status(sock)["served"] == served


def _sigint_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_reaches_the_run(server, pitch_capture):
    """SIGINT to the client reaches the run in the server's fork, which ends as an interrupted
    run in its own process ends: inside the command typer's exit status 130, before it Python's
    death by SIGINT; no result on stdout either way (without the forwarding the run would finish)."""
    sock, _ = server
    # The client starts as a terminal starts a command, SIGINT at its default, whatever the test
    # process's own disposition is: a process that inherits SIGINT ignored (nohup, a background
    # job) ignores it, and its run too (docs/serve.md), which is right, but is not this test.
    p = subprocess.Popen([sys.executable, "-m", "stillcap", "pitch", str(pitch_capture), "--json"],
                         env=_env(sock, STILLCAP_SERVER="verbose"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         preexec_fn=_sigint_default)
    while status(sock)["running"] == 0:  # until the run has started in the server's fork
        assert p.poll() is None
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=600)
    assert p.returncode in (130, -signal.SIGINT), err
    assert out == b""
    while status(sock)["running"]:  # the fork has ended (the server reaped it)
        time.sleep(0.1)


def test_the_server_exports_no_console_made_at_its_start():
    """The CLI's modules make rich consoles when imported (their colours and terminal fixed
    then): the server imports them for their imports and forgets them, so each run makes its own."""
    code = ("from stillcap.cli._server import preload\n"
            "preload()\n"
            "import sys, rich.console\n"
            "bad = [f'{n}.{a}' for n, m in list(sys.modules.items()) if m is not None\n"
            "       for a, v in list(vars(m).items()) if isinstance(v, rich.console.Console)]\n"
            "print(bad, 'stillcap.cli.pitch' in sys.modules, 'stillcap.pipelines.pitch' in sys.modules)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, PYTHONPATH=str(SRC)))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[] False True"


def test_stale_socket_stop_status_and_changed_source(tmp_path):
    """A killed server's socket: runs go in-process; a new server replaces the stale socket;
    --status and --stop; a server whose source changed stops itself."""
    src = tmp_path / "src"
    shutil.copytree(SRC, src, ignore=shutil.ignore_patterns("__pycache__", "static"))
    sock = tmp_path / "run" / "s.sock"
    missing = tmp_path / "no-capture"
    proc = start_server(sock, src)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    assert sock.exists()  # the stale socket is left behind
    r = stillcap(["pitch", missing], sock, "manual,verbose", src=src)  # (auto would start a server: below)
    assert r.returncode == 2
    assert r.stderr.startswith("stillcap: in-process (server at"), r.stderr
    assert r.stderr.splitlines()[1] == f"error: capture folder {missing} does not exist"
    assert stillcap(["serve", "--status"], sock, src=src).returncode == 1

    start_server(sock, src, detach=True)  # over the stale socket
    st = status(sock, src)
    assert st["same_code"] and st["running"] == 0
    again = stillcap(["serve", "--socket", sock], sock, src=src)  # a second server on the socket is refused
    assert again.returncode == 2 and "a server is already running on this socket" in again.stderr
    r = stillcap(["serve", "--stop"], sock, src=src)
    assert r.returncode == 0 and f"stopped the stillcap server (pid {st['pid']})" in r.stdout
    assert not sock.exists()
    assert stillcap(["serve", "--status"], sock, src=src).returncode == 1

    start_server(sock, src, detach=True)
    pid = status(sock, src)["pid"]
    os.utime(src / "stillcap" / "pipelines" / "markers.py")  # the code changed under the server
    r = stillcap(["pitch", missing], sock, "verbose", src=src)
    assert r.returncode == 2
    assert r.stderr.startswith("stillcap: in-process (the server's code is out of date"), r.stderr
    for _ in range(600):  # it stops itself
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("the out-of-date server did not stop")
    assert stillcap(["serve", "--status"], sock, src=src).returncode == 1


def test_the_socket_folder_must_be_private(tmp_path):
    folder = tmp_path / "open"
    folder.mkdir(mode=0o755)
    folder.chmod(0o755)
    r = stillcap(["serve", "--socket", folder / "s.sock"], folder / "s.sock")
    assert r.returncode == 2
    assert r.stderr == f"error: {folder}: the server's folder is open to others (mode 755, needs 700)\n"
    # a client does not hand its terminal to a socket in such a folder
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(folder / "s.sock"))
    s.listen(1)
    try:
        r = stillcap(["pitch", tmp_path / "missing"], folder / "s.sock", "verbose")
        assert r.returncode == 2
        assert r.stderr.startswith(f"stillcap: in-process ({folder}: the server's folder is open to others"), r.stderr
    finally:
        s.close()


def test_an_idle_server_exits(tmp_path):
    sock = tmp_path / "run" / "s.sock"
    sock.parent.mkdir(mode=0o700)
    r = subprocess.run([sys.executable, "-m", "stillcap", "serve", "--socket", str(sock), "--idle-timeout", "1",
                        "--detach"], capture_output=True, text=True, env=_env(sock), timeout=600)
    assert r.returncode == 0, r.stderr
    pid = int(r.stdout.split("pid ")[1].split()[0])
    end = time.monotonic() + READY_WAIT_S
    while _alive(pid):
        assert time.monotonic() < end, "the idle server did not exit"
        time.sleep(0.2)
    assert not sock.exists()
    assert "idle for 1 s: exiting" in (tmp_path / "run" / "s.sock.log").read_text()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat", "rb") as f:  # a zombie (not yet reaped by init) has ended
        return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"


def test_which_commands_go_to_the_server():
    from stillcap._entry import forwardable

    for argv in (["pitch", "CAP"], ["pitch", "A", "B", "--json"], ["hand", "CAP"], ["markers", "CAP"],
                 ["puppet", "run", "CAP"]):
        assert forwardable(argv), argv
    for argv in ([], ["serve"], ["gui"], ["batch", "A"], ["studio", "pitch"], ["puppet", "new", "P"],
                 ["pitch", "--help"], ["calibrate", "rig", "F"], ["demo"]):
        assert not forwardable(argv), argv


def test_a_linked_socket_folder_is_refused(tmp_path):
    from stillcap._server_link import check_private_dir

    real = tmp_path / "real"
    real.mkdir(mode=0o700)
    (tmp_path / "link").symlink_to(real)
    check_private_dir(str(real), create=False)
    with pytest.raises(ValueError, match="is not a directory"):
        check_private_dir(str(tmp_path / "link"), create=False)
    with pytest.raises(ValueError, match="does not exist"):
        check_private_dir(str(tmp_path / "none"), create=False)


def _gone(pid: int) -> None:
    end = time.monotonic() + READY_WAIT_S
    while _alive(pid):
        assert time.monotonic() < end, f"process {pid} did not end"
        time.sleep(0.1)


def test_a_run_without_a_server_starts_one_for_the_next_run(tmp_path):
    """No server: the run runs in its own process (the same status and error line as with
    STILLCAP_SERVER=off), then starts one, whose lock it took for it; a run while that server
    imports runs in its own process and starts no other; once it listens, runs go through it.
    The server runs in a session of its own from the root folder, with the idle timeout of a
    started server, until stopped."""
    from stillcap._entry import AUTO_IDLE_S

    sock = tmp_path / "run" / "s.sock"
    missing = tmp_path / "no-capture"
    off = stillcap(["pitch", missing], sock, "off")
    assert off.returncode == 2 and not sock.parent.exists()
    first = stillcap(["pitch", missing], sock, "verbose")
    lines = first.stderr.splitlines()
    assert lines[0] == f"stillcap: in-process (no server at {sock}; starting one after this run)", first.stderr
    assert lines[1:] == [off.stderr.strip(), f"stillcap: starting a server at {sock} for the next runs "
                                             "(STILLCAP_SERVER=manual: never)"], first.stderr
    assert first.returncode == 2 and first.stdout == off.stdout == ""
    second = stillcap(["pitch", missing], sock, "verbose")
    assert second.stderr.splitlines() in ([f"stillcap: in-process (server at {sock}: a server is starting there)",
                                           off.stderr.strip()], [VIA + str(sock), off.stderr.strip()]), second.stderr
    assert second.returncode == 2
    end = time.monotonic() + READY_WAIT_S
    while status(sock) is None:
        assert time.monotonic() < end, "the server started did not listen"
        time.sleep(0.5)
    served = status(sock)["served"]
    third = stillcap(["pitch", missing], sock, "verbose")
    assert third.stderr.splitlines() == [VIA + str(sock), off.stderr.strip()], third.stderr
    assert third.returncode == 2
    st = status(sock)
    assert st["served"] == served + 1
    assert st["same_code"]
    pid = st["pid"]
    assert os.readlink(f"/proc/{pid}/cwd") == "/"
    assert os.getsid(pid) != os.getsid(0)
    assert f"idle timeout {AUTO_IDLE_S} s" in (sock.parent / "s.sock.log").read_text()
    assert stillcap(["serve", "--stop"], sock).returncode == 0
    _gone(pid)


@pytest.mark.parametrize("mode", ["manual,verbose", "off"])
def test_manual_or_off_starts_no_server(tmp_path, mode):
    sock = tmp_path / "run" / "s.sock"
    r = stillcap(["pitch", tmp_path / "no-capture"], sock, mode)
    assert r.returncode == 2
    assert "starting" not in r.stderr
    assert not sock.parent.exists()


def test_a_run_with_interpreter_options_starts_no_server(tmp_path):
    """A server started as ``python -m stillcap serve`` would not have ``-X faulthandler``: its
    fingerprint could not match, so none is started."""
    sock = tmp_path / "run" / "s.sock"
    sock.parent.mkdir(mode=0o700)
    r = subprocess.run([sys.executable, "-X", "faulthandler", "-m", "stillcap", "pitch", str(tmp_path / "none")],
                       capture_output=True, text=True, env=_env(sock, STILLCAP_SERVER="verbose"), timeout=600)
    assert r.returncode == 2
    assert r.stderr.startswith(f"stillcap: in-process (no server at {sock})\n"), r.stderr
    assert sorted(sock.parent.iterdir()) == []


def test_the_lock_tells_a_starting_server_and_is_not_taken_twice(tmp_path, monkeypatch):
    """``_lock_held`` sees a lock another open file holds; ``start_server`` starts nothing while
    it is held."""
    import fcntl

    from stillcap import _entry

    sock = tmp_path / "run" / "s.sock"
    sock.parent.mkdir(mode=0o700)
    monkeypatch.setenv("STILLCAP_SOCKET", str(sock))
    assert not _entry._lock_held(str(sock))  # no lock file
    fd = os.open(str(sock) + ".lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        assert not _entry._lock_held(str(sock))
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert _entry._lock_held(str(sock))
        spawned = []
        monkeypatch.setattr(os, "posix_spawn", lambda *a, **k: spawned.append(a))
        _entry.start_server(dict(os.environ))
        assert spawned == []
        fcntl.flock(fd, fcntl.LOCK_UN)
        assert not _entry._lock_held(str(sock))
        _entry.start_server(dict(os.environ))
        assert len(spawned) == 1 and spawned[0][1][-2:] != ["--lock-fd", str(fd)]
        assert not _entry._lock_held(str(sock))  # (the spawn was not real: the lock went with its file)
    finally:
        os.close(fd)


def test_a_package_installed_changes_the_fingerprint(tmp_path, monkeypatch):
    """Installing, upgrading or removing a package changes its site-packages folder: a server
    whose dependencies changed is out of date, as one whose stillcap changed."""
    from stillcap._server_link import fingerprint

    folder = tmp_path / "site-packages"
    folder.mkdir()
    monkeypatch.setattr(sys, "path", [*sys.path, str(folder)])
    before = fingerprint()
    assert fingerprint() == before
    (folder / "numpy-9.9.dist-info").mkdir()
    assert fingerprint() != before


def test_the_server_started_keeps_no_descriptor_of_its_starter(tmp_path):
    """A descriptor the run inherited (here a pipe its caller reads to its end) is not handed to
    the server it starts: the caller sees the pipe close when the run ends."""
    sock = tmp_path / "run" / "s.sock"
    r, w = os.pipe()
    code = ("import os, sys\n"
            f"sys.argv = ['stillcap', 'pitch', {str(tmp_path / 'none')!r}]\n"
            f"sys.orig_argv = [sys.executable, '-m', 'stillcap']  # (as python -m stillcap)\n"
            "from stillcap._entry import run\n"
            "run()\n")
    p = subprocess.Popen([sys.executable, "-c", code], env=_env(sock), pass_fds=(w,), stderr=subprocess.PIPE)
    os.close(w)
    assert p.wait(timeout=600) == 2, p.stderr.read()
    end = time.monotonic() + READY_WAIT_S
    while status(sock) is None:
        assert time.monotonic() < end, "no server was started"
        time.sleep(0.5)
    try:
        with os.fdopen(r, "rb") as f:  # the run has ended and the server it started lives: EOF
            assert select.select([f], [], [], 0)[0] == [f], "the server holds the caller's pipe"
            assert f.read() == b""
    finally:
        assert stillcap(["serve", "--stop"], sock).returncode == 0
