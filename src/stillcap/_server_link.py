"""What the ``stillcap`` client and the warm server (``stillcap serve``) share: where the socket
is, how each side checks the other, the fingerprint of the code and the messages (docs/serve.md).

The client imports this before anything else, so it imports only what the interpreter has
built in (no module that is a ``.py`` file of the standard library): ``_socket`` rather than
``socket``, ``_sha256`` rather than ``hashlib``, ``marshal`` rather than ``json``. ``socket``,
``hashlib``, ``signal`` and ``json`` build enums, load OpenSSL or compile regular expressions
when imported (CPU time of a fresh interpreter, best of 15, on the loaded 2-core machine:
``python -c pass`` 8.6 ms, ``import json, socket, hashlib, struct, stat`` 20.7 ms; the client's
two modules imported 25.1 ms with those, 13.7 ms without).

The socket lives in a private directory: ``$XDG_RUNTIME_DIR/stillcap`` (when that directory is
the user's own) or ``/tmp/stillcap-$UID``, mode 0700, the socket itself 0600, or wherever
``STILLCAP_SOCKET`` (the client) and ``stillcap serve --socket`` (the server) say. Each side also
asks the kernel who is at the other end (``SO_PEERCRED``) and talks only to its own user: the
client hands the server its terminal and its environment, the server runs what the client asks.

Messages: each is a 4-byte big-endian length and that many bytes of :mod:`marshal` data (a dict
of strings, numbers, lists and dicts; read only from a process of this same user, who could
run anything as themselves anyway, and at most 4 MiB). The client's first one carries its
stdin, stdout and stderr file descriptors (``SCM_RIGHTS``) and starts with ``SCAP``.
"""

from __future__ import annotations

import _socket
import marshal
import os
import stat
import struct
import sys

try:  # (hashlib's own fallbacks: the builtin SHA-256, without loading OpenSSL)
    from _sha256 import sha256 as _sha256
except ImportError:  # Python 3.12 renamed it; a build without it
    try:
        from _sha2 import sha256 as _sha256
    except ImportError:
        from hashlib import sha256 as _sha256

__all__ = ["MAGIC", "MAX_BYTES", "IMPORT_ENV_PREFIXES", "Messages", "check_private_dir", "connect",
           "default_socket", "fingerprint", "import_env", "peer_uid", "recv_request", "send_message",
           "send_request", "socket_path"]

MAGIC = b"SCAP"
MAX_BYTES = 1 << 22
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


def connect(path: str, timeout_s: float):
    """A Unix stream socket connected to ``path`` (``_socket.socket``: its methods are those of
    ``socket.socket``, without the ``socket`` module's import)."""
    sock = _socket.socket(_socket.AF_UNIX, _socket.SOCK_STREAM)
    try:
        sock.settimeout(timeout_s)
        sock.connect(path)
    except BaseException:
        sock.close()
        raise
    return sock


def peer_uid(sock) -> tuple[int, int]:
    """(pid, uid) of the process at the other end of a Unix socket (``SO_PEERCRED``)."""
    creds = sock.getsockopt(_socket.SOL_SOCKET, _socket.SO_PEERCRED, struct.calcsize("3i"))
    pid, uid, _gid = struct.unpack("3i", creds)
    return pid, uid


def fingerprint(env=None) -> str:
    """A cheap fingerprint of the code a command would run: stillcap's version and source folder
    with the size and time of every ``.py`` file in it, the interpreter (its path, version, flags,
    warning and ``-X`` options, module path after the script's own folder) and the environment
    variables read at import (:func:`import_env`), and the time each folder of the module path was
    last changed (installing, upgrading or removing a package in ``site-packages`` changes it).
    Equal fingerprints: the server's forked process runs the code a fresh process would."""
    package = sys.modules[__package__]  # stillcap (imported before any of its modules; not imported
    root = os.path.dirname(os.path.realpath(__file__))  # here: it is above every layer of the stack)
    h = _sha256()
    h.update(repr((package.__version__, root, os.path.realpath(sys.executable), sys.version, tuple(sys.flags),
                   sys.warnoptions, sorted(sys._xoptions.items()), sys.path[1:],
                   sorted(import_env(env).items()), [_changed_ns(p) for p in sys.path[1:]])).encode())
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "static"))
        for name in sorted(files):
            if name.endswith(".py"):
                st = os.stat(os.path.join(folder, name))
                h.update(f"{folder[len(root):]}/{name} {st.st_size} {st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:32]


def _changed_ns(folder: str):
    """The last change of ``folder`` (ns), or None where there is none (a zip file's path missing)."""
    try:
        return os.stat(folder).st_mtime_ns
    except OSError:
        return None


def _frame(message: dict) -> bytes:
    body = marshal.dumps(message)
    return struct.pack(">I", len(body)) + body


def send_request(sock, request: dict, fds=()) -> None:
    """The first message: ``SCAP``, its length and the file descriptors in one ``sendmsg`` (as
    ``socket.send_fds`` sends them), then the rest of it."""
    frame = _frame(request)
    ancillary = [(_socket.SOL_SOCKET, _socket.SCM_RIGHTS, struct.pack(f"{len(fds)}i", *fds))] if fds else []
    sent = sock.sendmsg([MAGIC + frame[:4]], ancillary)
    if sent != 8:
        raise OSError("the request's header was cut short")
    sock.sendall(frame[4:])


def _recv_exactly(sock, n: int, what: str) -> bytes:
    data = bytearray()
    while len(data) < n:
        more = sock.recv(min(1 << 16, n - len(data)))
        if not more:
            raise ValueError(f"the connection closed inside {what}")
        data += more
    return bytes(data)


def _decode(body: bytes) -> dict:
    try:
        message = marshal.loads(body)
    except (EOFError, ValueError, TypeError) as e:
        raise ValueError(f"a message that does not decode ({e})") from None
    if not isinstance(message, dict):
        raise ValueError(f"a message that is a {type(message).__name__}, not a dict")  # noqa: TRY004  (bad input)
    return message


def recv_request(sock, max_bytes: int = MAX_BYTES) -> tuple[dict, list[int]]:
    """The first message (:func:`send_request`): the request and the file descriptors received
    (the caller closes them). Raises ValueError for anything else."""
    import socket  # (the server's side: it has the module imported anyway)

    head, fds, _flags, _addr = socket.recv_fds(sock, 8, 3)
    try:
        if len(head) < 8:
            head += _recv_exactly(sock, 8 - len(head), "the header")
        if head[:4] != MAGIC:
            raise ValueError("not a stillcap request")
        (n,) = struct.unpack(">I", head[4:])
        if n > max_bytes:
            raise ValueError(f"a request of {n} bytes")
        return _decode(_recv_exactly(sock, n, "the request")), fds
    except BaseException:
        for fd in fds:
            os.close(fd)
        raise


def send_message(sock, message: dict) -> None:
    """One message (a dict) after the first."""
    sock.sendall(_frame(message))


class Messages:
    """The messages that arrive on a socket after the first: :meth:`next` gives the next one, or
    None when the other end has closed. Raises ValueError for one that is not a message."""

    def __init__(self, sock, max_bytes: int = MAX_BYTES):
        self.sock, self.max_bytes = sock, max_bytes

    def next(self) -> dict | None:
        head = self.sock.recv(4)
        if not head:
            return None
        if len(head) < 4:
            head += _recv_exactly(self.sock, 4 - len(head), "a message's length")
        (n,) = struct.unpack(">I", head)
        if n > self.max_bytes:
            raise ValueError(f"a message of {n} bytes")
        return _decode(_recv_exactly(self.sock, n, "a message"))
