"""What the ``stillcap`` client and the warm server (``stillcap serve``) share: where the socket
is, how each side checks the other, the fingerprint of the code and the messages (stdlib only:
the client imports this before any of NumPy, typer or rich; docs/serve.md).

The socket lives in a private directory: ``$XDG_RUNTIME_DIR/stillcap`` (when that directory is
the user's own) or ``/tmp/stillcap-$UID``, mode 0700, the socket itself 0600, or wherever
``STILLCAP_SOCKET`` (the client) and ``stillcap serve --socket`` (the server) say. Each side also
asks the kernel who is at the other end (``SO_PEERCRED``) and talks only to its own user: the
client hands the server its terminal and its environment, the server runs what the client asks.

Messages: the client's first one carries its stdin, stdout and stderr file descriptors
(``SCM_RIGHTS``, :func:`socket.send_fds`) with an 8-byte header (``SCAP`` and the length of the
JSON request that follows). After it each side writes one JSON object per line.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import stat
import struct
import sys

__all__ = ["MAGIC", "Lines", "IMPORT_ENV_PREFIXES", "check_private_dir", "default_socket", "fingerprint",
           "import_env", "peer_uid", "recv_request", "send_line", "send_request", "socket_path"]

MAGIC = b"SCAP"
#: Environment variables read when modules are imported (the BLAS thread count, the locale and the
#: stdio encoding, Python's own, colours forced by typer): a server started with other values
#: would not run a command as a fresh process does, so the client then runs it itself.
IMPORT_ENV_PREFIXES = ("PYTHON", "OMP_", "OPENBLAS_", "GOTO", "MKL_", "BLIS_", "KMP_", "NUMEXPR_", "NUMBA_",
                       "OPENCV_", "MPL", "NUMPY_", "SCIPY_", "LANG", "LC_", "LD_", "FORCE_COLOR", "NO_COLOR",
                       "PY_COLORS", "TERMINAL_WIDTH", "GITHUB_ACTIONS", "TYPER_", "_TYPER", "HOME",
                       "XDG_CONFIG_HOME", "XDG_CACHE_HOME", "STILLCAP_")
#: ... except these, which only choose and describe the server.
NOT_IMPORT_ENV = ("STILLCAP_SERVER", "STILLCAP_SOCKET")


def import_env(env=None) -> dict:
    """The environment variables of :data:`IMPORT_ENV_PREFIXES` (``os.environ`` by default)."""
    env = os.environ if env is None else env
    return {k: v for k, v in env.items() if k.startswith(IMPORT_ENV_PREFIXES) and k not in NOT_IMPORT_ENV}


def default_socket() -> str:
    """``$XDG_RUNTIME_DIR/stillcap/server.sock`` when XDG_RUNTIME_DIR is a directory of this user,
    else ``/tmp/stillcap-$UID/server.sock``."""
    run = os.environ.get("XDG_RUNTIME_DIR")
    if run:
        try:
            st = os.stat(run)
            if stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid():
                return os.path.join(run, "stillcap", "server.sock")
        except OSError:
            pass
    return os.path.join("/tmp", f"stillcap-{os.getuid()}", "server.sock")


def socket_path(given: str | None = None) -> str:
    """The socket: ``given``, else ``STILLCAP_SOCKET``, else :func:`default_socket` (absolute)."""
    path = given or os.environ.get("STILLCAP_SOCKET") or default_socket()
    return os.path.abspath(os.path.expanduser(path))


def check_private_dir(folder: str, create: bool) -> None:
    """``folder`` is a real directory (not a link) of this user that nobody else may enter, made
    (mode 0700) when ``create``. Raises ValueError naming the folder and what is wrong (someone
    else could otherwise put a socket there that the client would hand its terminal to)."""
    if create:
        try:
            os.mkdir(folder, 0o700)
        except FileExistsError:
            pass
        except OSError as e:
            raise ValueError(f"{folder}: cannot make the server's folder ({e.strerror})") from None
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        raise ValueError(f"{folder}: the server's folder does not exist") from None
    if not stat.S_ISDIR(st.st_mode):
        raise ValueError(f"{folder}: the server's folder is not a directory (a link or a file)")
    if st.st_uid != os.getuid():
        raise ValueError(f"{folder}: the server's folder belongs to uid {st.st_uid}, not to this user")
    if st.st_mode & 0o077:
        raise ValueError(f"{folder}: the server's folder is open to others (mode {st.st_mode & 0o777:o}, "
                         f"needs 700)")


def peer_uid(sock: socket.socket) -> tuple[int, int]:
    """(pid, uid) of the process at the other end of a Unix socket (``SO_PEERCRED``)."""
    creds = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    pid, uid, _gid = struct.unpack("3i", creds)
    return pid, uid


def fingerprint(env=None) -> str:
    """A cheap fingerprint of the code a command would run: stillcap's version and source folder
    with the size and time of every ``.py`` file in it, the interpreter (its path, version, flags,
    warning and ``-X`` options, module path after the script's own folder) and the environment
    variables read at import (:func:`import_env`). Equal fingerprints: the server's forked process
    runs the code a fresh process would. Not covered: a dependency (NumPy, ...) upgraded in place."""
    package = sys.modules[__package__]  # stillcap (imported before any of its modules; not imported
    root = os.path.dirname(os.path.realpath(__file__))  # here: it is above every layer of the stack)
    h = hashlib.sha256()
    h.update(repr((package.__version__, root, os.path.realpath(sys.executable), sys.version, tuple(sys.flags),
                   sys.warnoptions, sorted(sys._xoptions.items()), sys.path[1:],
                   sorted(import_env(env).items()))).encode())
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "static"))
        for name in sorted(files):
            if name.endswith(".py"):
                st = os.stat(os.path.join(folder, name))
                h.update(f"{folder[len(root):]}/{name} {st.st_size} {st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:32]


def send_request(sock: socket.socket, request: dict, fds=()) -> None:
    """The first message: header and file descriptors in one ``sendmsg``, then the JSON."""
    body = json.dumps(request).encode()
    socket.send_fds(sock, [MAGIC + struct.pack(">I", len(body))], list(fds))
    sock.sendall(body)


def recv_request(sock: socket.socket, max_bytes: int = 1 << 22) -> tuple[dict, list[int]]:
    """The first message (:func:`send_request`): the request and the file descriptors received
    (the caller closes them). Raises ValueError for anything else."""
    head, fds, _flags, _addr = socket.recv_fds(sock, 8, 3)
    try:
        while len(head) < 8:
            more = sock.recv(8 - len(head))
            if not more:
                raise ValueError("the connection closed inside the header")
            head += more
        if head[:4] != MAGIC:
            raise ValueError("not a stillcap request")
        (n,) = struct.unpack(">I", head[4:])
        if n > max_bytes:
            raise ValueError(f"a request of {n} bytes")
        body = bytearray()
        while len(body) < n:
            more = sock.recv(min(1 << 16, n - len(body)))
            if not more:
                raise ValueError("the connection closed inside the request")
            body += more
        return json.loads(body), fds
    except BaseException:
        for fd in fds:
            os.close(fd)
        raise


def send_line(sock: socket.socket, message: dict) -> None:
    """One JSON object and a newline."""
    sock.sendall(json.dumps(message).encode() + b"\n")


class Lines:
    """The JSON objects, one a line, that arrive on a socket: :meth:`next` gives the next one or
    None when the other end has closed."""

    def __init__(self, sock: socket.socket):
        self.sock, self.buffer = sock, b""

    def next(self) -> dict | None:
        while b"\n" not in self.buffer:
            more = self.sock.recv(4096)
            if not more:
                return None
            self.buffer += more
        line, self.buffer = self.buffer.split(b"\n", 1)
        return json.loads(line)
