"""`stillcap serve`: a warm process that runs ``pitch``, ``hand``, ``puppet run`` and ``markers``
for the ``stillcap`` command without its start-up (docs/serve.md; the server is
:mod:`stillcap.cli._server`)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import typer

DEFAULT_IDLE_S = 1800.0


def serve(
    socket_path: Path = typer.Option(None, "--socket", help="The Unix socket (its folder must be this user's "
                                     "alone, mode 700; made if missing). Default: $XDG_RUNTIME_DIR/stillcap/"
                                     "server.sock, else /tmp/stillcap-$UID/server.sock. Clients find another "
                                     "socket through STILLCAP_SOCKET."),
    idle_timeout: float = typer.Option(DEFAULT_IDLE_S, "--idle-timeout", min=0,
                                       help="Exit after this many seconds without a run (0: never)."),
    detach: bool = typer.Option(False, "--detach", help="Run in the background (its log beside the socket, "
                                "SOCKET.log); return once it listens."),
    stop: bool = typer.Option(False, "--stop", help="Stop the running server (runs in progress finish)."),
    status: bool = typer.Option(False, "--status", help="Say whether a server runs, and whether this stillcap's "
                                "runs go through it (exit status 1 when none answers)."),
    as_json: bool = typer.Option(False, "--json", help="--status as JSON."),
    lock_fd: int = typer.Option(None, "--lock-fd", hidden=True, help="The socket's lock file, open and locked "
                                "by the stillcap command that starts this server (docs/serve.md)."),
):
    """Keep the pipelines imported in a background process and run `stillcap pitch`, `hand`,
    `puppet run` and `markers` in forks of it: the same output, files and exit status as a run
    of its own, without the ~0.6 s of start-up (docs/serve.md).

    A run goes through the server when one answers on the socket and has the same stillcap
    source, Python and import-time environment; otherwise it runs in its own process, silently
    (STILLCAP_SERVER=verbose says which way each run went, STILLCAP_SERVER=off never uses one).
    """
    from stillcap import _server_link as link
    from stillcap.cli import _server

    path = link.socket_path(None if socket_path is None else str(socket_path))
    if stop and status:
        raise ValueError("--stop and --status: give one")
    if status:
        reply = _server.query(path, "status")
        if reply is None:
            print(f"no stillcap server answers on {path}")
            raise typer.Exit(1)
        print(_server.as_json(reply) if as_json else _server.status_text(reply))
        return
    if stop:
        reply = _server.query(path, "stop")
        if reply is None:
            print(f"no stillcap server answers on {path}")
            return
        _wait_gone(int(reply["pid"]))
        print(f"stopped the stillcap server (pid {reply['pid']}) on {path}")
        return
    server = _server.Server(path, idle_timeout, lock_fd)
    if detach:
        _detach(server)
        return
    server.lock()
    server.start()
    try:
        server.loop()
    except KeyboardInterrupt:  # Ctrl-C in the server's own terminal: stop (its runs are in their own groups)
        _server._log("interrupted: stopped")


def _wait_gone(pid: int, timeout_s: float = 600.0) -> None:
    """Until process ``pid`` has ended (the server waits for the runs in progress)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)


def _detach(server) -> None:
    """Start ``server`` as a daemon (fork, new session, fork; stdio on /dev/null and the log) and
    return once it listens, or raise ValueError with the reason it did not start."""
    r, w = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    if os.fork() > 0:
        os.close(w)
        with os.fdopen(r, "rb") as f:
            said = f.read().decode(errors="replace")
        if not said.startswith("ready"):
            raise ValueError(said.strip() or f"{server.path}: the server did not start (see {server.path}.log)")
        print(f"stillcap server pid {said.split()[1]} listening on {server.path} (log: {server.path}.log)")
        return
    os.close(r)
    os.setsid()
    if os.fork() > 0:
        os._exit(0)
    server.pid = os.getpid()
    try:
        server.lock()
        log = os.open(server.path + ".log", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        null = os.open(os.devnull, os.O_RDWR)
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(null, 0)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(null)
        os.close(log)
        server.start()
    except BaseException as e:  # noqa: BLE001  (told to the waiting parent)
        os.write(w, f"{e}\n".encode())
        os._exit(2)
    os.write(w, f"ready {os.getpid()}\n".encode())
    os.close(w)
    os.chdir("/")  # a daemon holds no folder busy (each run moves to its client's)
    server.loop()
