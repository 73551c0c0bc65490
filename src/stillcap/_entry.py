"""The ``stillcap`` process's entry point (the console script and ``python -m stillcap``): a run of
``pitch``, ``hand``, ``puppet run`` or ``markers`` goes to a warm ``stillcap serve`` when one is
running for this code; everything else, and every run when no server can take it, runs here
through :func:`stillcap.cli.run`. Standard library only until then: a forwarded run imports
neither NumPy nor typer in this process (docs/serve.md).

Forwarded: the analyses a user runs capture after capture, whose start-up (the interpreter,
NumPy, SciPy, OpenCV, pydantic, the pipelines: ~0.6 s of a ~1.2 s pitch) the server has paid
once. Not forwarded: ``serve`` itself; ``gui`` and ``batch`` (long-running, their own servers and
workers, start-up a small part); ``studio``, ``calibrate``, ``demo`` and the rest (occasional,
or cheap to start: they would only make the server hold more modules); ``--help``.

The server forks a process for the run, which takes this process's stdin, stdout and stderr
(the descriptors themselves), its working directory, environment, umask and arguments, and runs
``stillcap.cli.main`` as this process would have; its exit status (or the signal that ended it)
becomes this process's. Ctrl-C (and SIGTERM, SIGHUP, SIGQUIT) here is passed on to it.

When no server runs (no socket, or a killed one's), a forwardable run runs here and then starts
one in the background (``stillcap serve --detach``, idle timeout :data:`AUTO_IDLE_S`), so that
the next runs are warm: the pattern of Gradle's daemon. A run that finds a server starting (its
lock taken, its imports under way) runs here and starts no other.

``STILLCAP_SERVER`` holds words: ``off`` never uses a server; ``manual`` uses a running one but
never starts one; ``verbose`` says on stderr which way each run went (and why not through the
server), e.g. ``STILLCAP_SERVER=manual,verbose``. ``STILLCAP_SOCKET`` names the socket.
"""

from __future__ import annotations

import _signal as signal  # (not ``signal``, which builds its enums at import: ~4 ms of the client)
import os
import sys
import time

__all__ = ["forward", "forwardable", "run"]

#: How long the client waits for the server to take a run before running it itself (a stopped
#: server, SIGSTOP): no run is ever done twice, the server forks only after the client's "go".
ACCEPT_TIMEOUT_S = 5.0
FORWARDED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
#: The idle timeout of a server the ``stillcap`` command starts itself (``stillcap serve``: 1800 s).
AUTO_IDLE_S = 600
#: What :func:`forward` returns when no server runs and none is starting: run here, then start one.
ABSENT = "absent"


def forwardable(argv: list[str]) -> bool:
    """Whether ``stillcap ARGV`` may go to the server."""
    if "--help" in argv:
        return False
    return bool(argv) and (argv[0] in ("pitch", "hand", "markers") or argv[:2] == ["puppet", "run"])


def _say(verbose: bool, text: str) -> None:
    if verbose:
        sys.stderr.write(f"stillcap: {text}\n")
        sys.stderr.flush()


def forward(argv: list[str], verbose: bool = False, auto_start: bool = False):
    """Run ``stillcap ARGV`` through the server: the exit status, ``-SIGNAL`` for a run a signal
    ended, or None when no server took it (nothing was run: run it here). With ``auto_start``,
    :data:`ABSENT` when none runs or starts (run it here, then :func:`start_server`)."""
    from stillcap import _server_link as link

    path = link.socket_path()
    folder = os.path.dirname(path)
    try:
        for fd in (0, 1, 2):
            os.fstat(fd)  # a closed stdin, stdout or stderr cannot be handed over
        if auto_start and not os.path.lexists(folder):  # (a server makes it, private)
            _say(verbose, f"in-process (no server at {path}; starting one after this run)")
            return ABSENT
        link.check_private_dir(folder, create=False)
        st = os.lstat(path) if os.path.lexists(path) or not auto_start else None
        if st is not None and st.st_uid != os.getuid():
            raise ValueError(f"{path} belongs to uid {st.st_uid}")
    except FileNotFoundError:
        _say(verbose, f"in-process (no server at {path})")
        return None
    except (OSError, ValueError) as e:
        _say(verbose, f"in-process ({e})")
        return None
    sock = None
    try:
        sock = _connect(link, path, auto_start)
        if sock is ABSENT:
            _say(verbose, f"in-process (no server at {path}; starting one after this run)")
            return ABSENT
        _pid, uid = link.peer_uid(sock)
        if uid != os.getuid():
            sock.close()
            _say(verbose, f"in-process (the server on {path} runs as uid {uid})")
            return None
        request = {"kind": "run", "fingerprint": link.fingerprint(), "argv": list(argv),
                   "argv0": sys.argv[0], "cwd": os.getcwd(), "env": dict(os.environ), "umask": _umask(),
                   "ignored": _ignored()}
        link.send_request(sock, request, (0, 1, 2))
        messages = link.Messages(sock)
        reply = messages.next()
        if reply is None or not reply.get("ok"):
            sock.close()
            why = "the server closed the connection" if reply is None else reply.get("reason", "refused")
            _say(verbose, f"in-process ({why})")
            return None
        link.send_message(sock, {"go": True})
    except (OSError, ValueError) as e:  # refused (a stale socket), timed out, reset: nothing ran
        if sock is not None:
            sock.close()
        _say(verbose, f"in-process (server at {path}: {e})")
        return None
    _say(verbose, f"via the server at {path}")
    return _wait(sock, messages, link)


def _connect(link, path: str, auto_start: bool):
    """A socket connected to the server at ``path``; with ``auto_start``, :data:`ABSENT` when none
    listens there and nothing holds its lock (no socket, or a killed server's). A server that
    holds the lock but does not listen yet is importing: the run is not made to wait for it (it
    runs in its own process, measured faster: docs/serve.md) and starts no other."""
    try:
        return link.connect(path, ACCEPT_TIMEOUT_S)
    except (FileNotFoundError, ConnectionRefusedError):
        if not auto_start:
            raise
        if not _lock_held(path):
            return ABSENT
        raise OSError("a server is starting there") from None


def _lock_held(path: str) -> bool:
    """Whether a server holds the socket's lock file (``stillcap serve`` takes it before its
    imports and keeps it while it listens). The test takes a shared lock for a moment: a server
    trying to start in that moment is refused, harmlessly (the next run starts one)."""
    import fcntl  # (only here: a run that finds a server does not load it)

    try:
        fd = os.open(path + ".lock", os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)  # (releases the shared lock)
    return False


def plain_interpreter() -> bool:
    """Whether this process was started without interpreter options (``python -m stillcap`` or
    the console script): a server started as ``python -m stillcap serve`` then has this process's
    flags, so its fingerprint can match (``python -X importtime -m stillcap`` would not)."""
    orig = getattr(sys, "orig_argv", [])
    return len(orig) > 1 and (orig[1] == "-m" or orig[1] == sys.argv[0])


def start_server(env: dict, verbose: bool = False) -> None:
    """Start ``stillcap serve --detach`` on this run's socket in the background, not waited for:
    its own session (the terminal's Ctrl-C and hang-up do not reach it), stdin, stdout and stderr
    on ``/dev/null`` (it logs beside its socket), the environment ``env`` (this process's as it
    started, before imports changed it: the server's fingerprint is then this process's), idle
    timeout :data:`AUTO_IDLE_S`. This process takes the socket's lock and hands it to the server
    (``--lock-fd``), so that a run meanwhile sees a server starting and starts no other; when the
    lock is taken already, a server is starting. A failure to start changes nothing."""
    import fcntl

    from stillcap import _server_link as link

    path = link.socket_path()
    fd = None
    try:
        link.check_private_dir(os.path.dirname(path), create=True)
        fd = os.open(path + ".lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.set_inheritable(fd, True)
        argv = [sys.executable, "-m", "stillcap", "serve", "--detach", "--socket", path,
                "--idle-timeout", str(AUTO_IDLE_S), "--lock-fd", str(fd)]
        # stdio on /dev/null, and no other descriptor this process inherited (a pipe its caller
        # waits to see closed): only the lock goes to the server
        actions = [(os.POSIX_SPAWN_OPEN, i, os.devnull, os.O_RDWR, 0) for i in (0, 1, 2)]
        actions += [(os.POSIX_SPAWN_CLOSE, i) for i in _open_fds() if i > 2 and i != fd]
        os.posix_spawn(sys.executable, argv, env, file_actions=actions, setsid=True)
    except BlockingIOError:
        _say(verbose, f"a server is starting at {path} already")
        return
    except (OSError, ValueError) as e:
        _say(verbose, f"could not start a server ({e})")
        return
    finally:
        if fd is not None:
            os.close(fd)  # (the server holds the lock now, or nobody)
    _say(verbose, f"starting a server at {path} for the next runs (STILLCAP_SERVER=manual: never)")


def _open_fds() -> list[int]:
    """This process's open file descriptors that a process it starts would inherit (Linux)."""
    fds = []
    for name in os.listdir("/proc/self/fd"):
        try:
            if os.get_inheritable(int(name)):
                fds.append(int(name))
        except OSError:  # (the listing's own, closed by now)
            pass
    return fds


def _ignored() -> list[int]:
    """The forwarded signals this process ignores (``nohup``, a shell's background job): the
    run ignores them too, and they are not passed on."""
    return [int(s) for s in FORWARDED_SIGNALS if signal.getsignal(s) == signal.SIG_IGN]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _wait(sock, messages, link):
    """The run's end: its status from the server; signals received meanwhile are sent on."""
    def pass_on(signum, _frame):
        try:
            link.send_message(sock, {"signal": int(signum)})
        except OSError:
            pass

    ignored = _ignored()
    for s in FORWARDED_SIGNALS:
        if s not in ignored:
            signal.signal(s, pass_on)
    sock.settimeout(None)
    child = None  # the run's process id, which the server sends first
    end = None
    try:
        while (end := messages.next()) is not None and "pid" in end:
            child = int(end["pid"])
    except (OSError, ValueError):
        end = None
    finally:
        for s in FORWARDED_SIGNALS:
            if s not in ignored:
                signal.signal(s, signal.SIG_DFL if s != signal.SIGINT else signal.default_int_handler)
    sock.close()
    if end is not None and "exit" in end:
        return int(end["exit"])
    if end is not None and "signal" in end:
        return -int(end["signal"])
    # the server went away during the run (stopped, killed): the run's own process goes on
    # writing to our stdout and stderr; wait for it, but its status is lost
    while child is not None and _alive(child):
        time.sleep(0.05)
    sys.stderr.write("stillcap: the server stopped during the run; its exit status is unknown\n")
    return 1


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # a zombie child of the dead server (reaped by init soon) counts as ended
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except OSError:
        return False


def run() -> None:
    """The entry point: through the server when possible, else :func:`stillcap.cli.run`."""
    argv = sys.argv[1:]
    env = dict(os.environ)  # (before the imports change it: OpenCV sets LD_LIBRARY_PATH)
    words = set(os.environ.get("STILLCAP_SERVER", "auto").lower().replace(",", " ").split())
    verbose = "verbose" in words
    start = False
    if forwardable(argv) and not words & {"off", "0", "no", "false"}:
        code = forward(argv, verbose, auto_start="manual" not in words and plain_interpreter())
        start = code is ABSENT
        if code is not None and not start:
            if code < 0:  # ended by a signal: end this process by it too (the shell sees 128 + N)
                signal.signal(-code, signal.SIG_DFL)
                os.kill(os.getpid(), -code)
                time.sleep(1)  # (a signal that does not end a process by default: status 128 + N)
                code = 128 - code
            sys.exit(code)
    from stillcap.cli import run as run_here

    if not start:
        run_here()
        return
    try:  # after the run, so that the server's imports do not slow it down; not after Ctrl-C or a crash
        run_here()
    except SystemExit:
        start_server(env, verbose)
        raise
    start_server(env, verbose)
