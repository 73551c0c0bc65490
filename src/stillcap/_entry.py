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

``STILLCAP_SERVER=off`` never uses a server; ``STILLCAP_SERVER=verbose`` says on stderr which
way each run went (and why not through the server). ``STILLCAP_SOCKET`` names the socket.
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


def forwardable(argv: list[str]) -> bool:
    """Whether ``stillcap ARGV`` may go to the server."""
    if "--help" in argv:
        return False
    return bool(argv) and (argv[0] in ("pitch", "hand", "markers") or argv[:2] == ["puppet", "run"])


def _say(verbose: bool, text: str) -> None:
    if verbose:
        sys.stderr.write(f"stillcap: {text}\n")
        sys.stderr.flush()


def forward(argv: list[str], verbose: bool = False):
    """Run ``stillcap ARGV`` through the server: the exit status, ``-SIGNAL`` for a run a signal
    ended, or None when no server took it (nothing was run: run it here)."""
    from stillcap import _server_link as link

    path = link.socket_path()
    try:
        link.check_private_dir(os.path.dirname(path), create=False)
        st = os.lstat(path)
        if st.st_uid != os.getuid():
            raise ValueError(f"{path} belongs to uid {st.st_uid}")
        for fd in (0, 1, 2):
            os.fstat(fd)  # a closed stdin, stdout or stderr cannot be handed over
    except FileNotFoundError:
        _say(verbose, f"in-process (no server at {path})")
        return None
    except (OSError, ValueError) as e:
        _say(verbose, f"in-process ({e})")
        return None
    sock = None
    try:
        sock = link.connect(path, ACCEPT_TIMEOUT_S)
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
    mode = os.environ.get("STILLCAP_SERVER", "auto").strip().lower()
    if forwardable(argv) and mode not in ("off", "0", "no", "false"):
        code = forward(argv, verbose=mode == "verbose")
        if code is not None:
            if code < 0:  # ended by a signal: end this process by it too (the shell sees 128 + N)
                signal.signal(-code, signal.SIG_DFL)
                os.kill(os.getpid(), -code)
                time.sleep(1)  # (a signal that does not end a process by default: status 128 + N)
                code = 128 - code
            sys.exit(code)
    from stillcap.cli import run as run_here

    run_here()
