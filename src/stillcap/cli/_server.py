"""The warm server behind ``stillcap serve``: imports the pipelines once, then forks one process
per run a client sends (docs/serve.md; the client is :mod:`stillcap._entry`, the socket and the
messages :mod:`stillcap._server_link`).

Written on the standard library's sockets, ``selectors`` and ``os.fork``/``os.pidfd_open``: the
pattern of mypy's dmypy and nailgun (a resident process that runs each command in a fresh
fork), for which no maintained library exists that hands a client's own file descriptors to
the command; Python's ``multiprocessing.forkserver`` is the same idea but its forks report to
the parent process, not to an unrelated client.

Each run is its own process, forked from the server: it takes the client's stdin, stdout and
stderr (``dup2`` onto 0, 1, 2), working directory, environment, umask and arguments, and runs
``stillcap.cli.main`` in a fresh process group; the server reports its exit status (or the
signal that ended it) to the client and passes the client's signals on to the group. Runs never
share a process, so two at once cannot disturb each other; the server itself runs no analysis
(its memory stays as the imports left it, and no thread pool is forked half-used).
"""

from __future__ import annotations

import fcntl
import gc
import importlib
import importlib.abc
import importlib.machinery
import io
import json
import os
import selectors
import signal
import socket
import sys
import threading
import time
import traceback

from stillcap import _server_link as link

__all__ = ["PRELOAD", "WARM", "Server", "exit_as_python", "preload", "run_command"]

#: What the server imports once: the four forwarded commands' modules and what their runs import
#: later (found by listing ``sys.modules`` after a run of each, on captures with and without a
#: truth). A module that fails to import is left to the run.
PRELOAD = ("stillcap.cli.pitch", "stillcap.cli.hand", "stillcap.cli.puppet", "stillcap.cli.markers",
           "stillcap.pipelines.pitch", "stillcap.pipelines.hand", "stillcap.pipelines.puppet",
           "stillcap.pipelines.markers", "stillcap.pipelines.pitch.checks", "stillcap.io.capture",
           "stillcap.io.export", "stillcap.io.project", "stillcap.files.outputs", "stillcap.ball.alias",
           "stillcap.body.retarget", "stillcap.calibrate", "stillcap.studio.compare.pitch",
           "stillcap.studio.compare.hand", "stillcap.studio.compare.puppet", "pydantic.type_adapter",
           "scipy.sparse.csgraph", "xml.etree.ElementTree", "rich.markup")
#: Computed once in the server as well: cached functions without arguments that every run of a
#: kind calls (tables and models built on first use). Pure NumPy or file reads: no thread is
#: started in the server, and each run gets the value it would compute itself.
WARM = ("stillcap._blas:_blas_controller", "stillcap.detect.ball._shading:_centroid_table",
        "stillcap.pipelines.puppet.analyse:_puppet_skeleton", "stillcap.body.hand:hand_skeleton",
        "stillcap.body.hand:hand_markerset")
#: Imported for their imports, then forgotten, so that each run executes them afresh: the CLI's
#: modules make rich consoles when imported, which fix their colours and terminal from the
#: process's stdout and environment of that moment; typer's rich_utils reads the environment.
FORGET = ("stillcap.cli.", "typer.rich_utils")
KEEP = ("stillcap.cli._server", "stillcap.cli.serve")


def _log(text: str) -> None:
    sys.stderr.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} stillcap serve[{os.getpid()}]: {text}\n")
    sys.stderr.flush()


def preload() -> tuple[float, int]:
    """Import :data:`PRELOAD`, compute :data:`WARM`, forget :data:`FORGET`, freeze the objects left out of the garbage
    collector (the forks then neither scan nor copy them). Seconds taken and modules loaded."""
    t = time.perf_counter()
    for name in PRELOAD:
        try:
            importlib.import_module(name)
        except Exception as e:  # noqa: BLE001  (an optional module: the run will say what is wrong)
            _log(f"preloading {name} failed ({type(e).__name__}: {e}); runs import it themselves")
    for name in WARM:
        module, func = name.split(":")
        try:
            getattr(importlib.import_module(module), func)()
        except Exception as e:  # noqa: BLE001  (the run computes it then)
            _log(f"computing {name} failed ({type(e).__name__}: {e}); runs compute it themselves")
    cli = sys.modules["stillcap.cli"]
    codes = {}
    for name in list(sys.modules):
        if name.startswith(FORGET) and name not in KEEP:
            codes[name] = _code_of(sys.modules[name])
            del sys.modules[name]
            if name.startswith("stillcap.cli.") and "." not in name[len("stillcap.cli."):]:
                cli.__dict__.pop(name.rsplit(".", 1)[1], None)
    _KeptCode.install({name: code for name, code in codes.items() if code is not None})
    gc.collect()
    gc.freeze()
    return time.perf_counter() - t, len(sys.modules)


def _code_of(module):
    """The compiled code of a module imported from a ``.py`` file (and the file), or None."""
    spec = getattr(module, "__spec__", None)
    loader = getattr(spec, "loader", None)
    if not isinstance(loader, importlib.machinery.SourceFileLoader) or not spec.origin:
        return None
    try:
        return spec.origin, loader.get_code(spec.name)
    except (ImportError, OSError, SyntaxError):
        return None


class _KeptCode(importlib.abc.MetaPathFinder):
    """Imports the forgotten modules (:data:`FORGET`) again, in each run, from the code compiled
    once in the server: with ``PYTHONDONTWRITEBYTECODE`` (or a source folder that cannot be
    written) no ``.pyc`` exists, and every run compiled the CLI's modules afresh (a pitch's six:
    3 ms of CPU, best of 5, of the ~25 ms its command line costs around the analysis). The
    code is that of the file the run would read:
    a run is only started for a client whose fingerprint (the size and time of every ``.py``
    file of stillcap) is the server's, and the file's path must be the one found now."""

    def __init__(self, codes: dict):
        self.codes = codes

    @classmethod
    def install(cls, codes: dict) -> None:
        sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, cls)]
        sys.meta_path.insert(0, cls(codes))

    def find_spec(self, name, path=None, target=None):
        kept = self.codes.get(name)
        if kept is None:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.origin != kept[0] or not isinstance(spec.loader, importlib.machinery.SourceFileLoader):
            return None
        spec.loader = _KeptCodeLoader(name, spec.origin, kept[1])
        return spec


class _KeptCodeLoader(importlib.machinery.SourceFileLoader):
    """A source file's loader that gives the code compiled once (:class:`_KeptCode`)."""

    def __init__(self, fullname, path, code):
        super().__init__(fullname, path)
        self.code = code

    def get_code(self, fullname):
        return self.code if fullname == self.name else super().get_code(fullname)


def run_command(argv: list[str]):
    """``stillcap ARGV`` as :func:`stillcap.cli.run` runs it in a fresh process: the exit status
    (SystemExit's code as Python reads it at exit); a KeyboardInterrupt ends the process by
    SIGINT after its traceback, as Python does."""
    from stillcap.cli import main

    try:
        main(argv)
        return 0
    except SystemExit as e:
        return e.code
    except KeyboardInterrupt:
        traceback.print_exc()
        sys.stderr.flush()
        import atexit

        atexit._run_exitfuncs()
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)
        return 130
    except BaseException:  # noqa: BLE001  (a bug: its traceback and status 1, as Python gives)
        traceback.print_exc()
        return 1
    finally:
        gc.freeze()


def exit_as_python(code) -> None:
    """End the run's process as the interpreter ends one whose ``main`` raised ``SystemExit(code)``:
    the status (None: 0; not an int: printed on stderr, 1), non-daemon threads joined, atexit
    handlers run (worker pools shut down, temporary folders removed), stdout and stderr flushed
    (status 120 when that fails and it was 0); then ``os._exit``, without the teardown of the
    1200 modules the server imported (it changes nothing the run left, and takes ~0.1 s)."""
    import atexit

    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:
        sys.stderr.write(f"{code}\n")
        status = 1
    try:
        threading._shutdown()  # (private: the interpreter's own exit calls it first, to join threads)
    except BaseException:  # noqa: BLE001
        traceback.print_exc()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001  (a closed pipe: Python's exit status then is 120)
            status = status or 120
    os._exit(status & 0xFF)


def _reopen_stdio() -> None:
    """New ``sys.stdin``, ``sys.stdout`` and ``sys.stderr`` on descriptors 0, 1, 2 (now the
    client's), buffered as Python's start-up buffers them: stdout line by line on a terminal,
    stderr always line by line; encoding and error handler as the server's (the client's are
    the same: the locale, PYTHONIOENCODING and PYTHONUNBUFFERED are in the fingerprint)."""
    unbuffered = bool(getattr(sys.stdout, "write_through", False))  # python -u, PYTHONUNBUFFERED
    for name, fd, mode in (("stdin", 0, "r"), ("stdout", 1, "w"), ("stderr", 2, "w")):
        old = getattr(sys, name)
        encoding = getattr(old, "encoding", None) or "utf-8"
        errors = getattr(old, "errors", None) or ("backslashreplace" if fd == 2 else "strict")
        if mode == "r":
            buf = open(fd, "rb", closefd=False)  # noqa: SIM115
        else:
            buf = open(fd, "wb", buffering=0 if unbuffered else -1, closefd=False)  # noqa: SIM115
        new = io.TextIOWrapper(buf, encoding=encoding, errors=errors, newline="\n",
                               line_buffering=mode == "w" and not unbuffered and (fd == 2 or os.isatty(fd)),
                               write_through=unbuffered)
        setattr(sys, name, new)
        setattr(sys, f"__{name}__", new)


class Server:
    """One server on one socket: :meth:`start` (lock, imports, bind), then :meth:`loop`."""

    def __init__(self, path: str, idle_timeout_s: float, held_lock_fd: int | None = None):
        self.path, self.idle_timeout_s = path, float(idle_timeout_s)
        self.held_lock_fd = held_lock_fd  # the lock file as the ``stillcap`` command that started it took it
        self.pid = os.getpid()
        self.lock_fd = self.listener = self.sel = None
        self.runs: dict[int, dict] = {}  # pid -> {"conn", "pidfd"}
        self.stopping = False
        self.served = 0
        self.started = time.time()
        self.fingerprint = ""
        self.env_before: dict = {}
        self.env_changes: dict = {}
        self.env_removed: list = []
        self.preload_s = 0.0
        self.last_active = time.monotonic()

    # -- start and stop ------------------------------------------------------------------------
    def lock(self) -> None:
        """Take the socket's lock file (one server per socket), or ValueError naming the socket.
        A server the ``stillcap`` command started (``_entry.start_server``) adopts the lock that
        command took for it, so that no other run starts one meanwhile."""
        if len(os.fsencode(self.path)) > 107:
            raise ValueError(f"{self.path}: a socket path may have at most 107 bytes; give a shorter --socket")
        link.check_private_dir(os.path.dirname(self.path), create=True)
        if self.held_lock_fd is not None:
            held, own = os.fstat(self.held_lock_fd), os.stat(self.path + ".lock")
            if (held.st_dev, held.st_ino) != (own.st_dev, own.st_ino):
                raise ValueError(f"--lock-fd {self.held_lock_fd} is not {self.path}.lock")
            os.set_inheritable(self.held_lock_fd, False)
            self.lock_fd = self.held_lock_fd
        else:
            self.lock_fd = os.open(self.path + ".lock", os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(self.lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self.lock_fd)
            self.lock_fd = None
            raise ValueError(f"{self.path}: a server is already running on this socket "
                             f"(stillcap serve --stop ends it)") from None

    def start(self) -> None:
        """Lock, import, then listen (so that a socket that answers is a warm server)."""
        if self.lock_fd is None:
            self.lock()
        before = dict(os.environ)
        self.fingerprint = link.fingerprint(before)
        self.preload_s, n = preload()
        # what the imports did to the environment (OpenCV sets LD_LIBRARY_PATH, ...): each run's
        # environment, the client's, gets the same changes, as a process of its own would have them
        self.env_before = before
        self.env_changes = {k: v for k, v in os.environ.items() if before.get(k) != v}
        self.env_removed = [k for k in before if k not in os.environ]
        if threading.active_count() > 1:
            _log(f"{threading.active_count()} threads run after the imports: forked runs may hang")
        try:
            os.unlink(self.path)  # a stale socket (the lock is ours: no server holds it)
        except FileNotFoundError:
            pass
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)  # the socket is made 0600, never readable by others for a moment
        try:
            self.listener.bind(self.path)
        finally:
            os.umask(old)
        os.chmod(self.path, 0o600)
        self.listener.listen(64)
        self.sel = selectors.DefaultSelector()
        self.sel.register(self.listener, selectors.EVENT_READ, ("listen", None))
        _log(f"listening on {self.path}: {n} modules imported in {self.preload_s:.2f} s; "
             f"idle timeout {self._idle_text()}")

    def _idle_text(self) -> str:
        return "none" if self.idle_timeout_s <= 0 else f"{self.idle_timeout_s:g} s"

    def close(self) -> None:
        """Stop listening (the socket file removed if still this server's), release the lock."""
        if os.getpid() != self.pid:
            return  # a run's process unwinding through the server's frames
        self.close_listener()

    # -- the loop ------------------------------------------------------------------------------
    def loop(self) -> None:
        """Serve until stopped (``--stop``, SIGTERM, Ctrl-C) or idle for the idle timeout."""
        signal.signal(signal.SIGTERM, _terminate)
        try:
            while True:
                if self.stopping and not self.runs:
                    _log("stopped")
                    return
                timeout = None
                if not self.runs and self.idle_timeout_s > 0:
                    timeout = self.last_active + self.idle_timeout_s - time.monotonic()
                    if timeout <= 0:
                        _log(f"idle for {self._idle_text()}: exiting")
                        return
                for key, _ in self.sel.select(timeout):
                    kind, pid = key.data
                    if kind == "listen" and self.listener is not None:
                        self._accept()
                    elif kind == "conn":
                        self._from_client(pid)
                    elif kind == "run":
                        self._reap(pid)
        finally:
            self.close()

    def _accept(self) -> None:
        conn, _ = self.listener.accept()
        fds: list[int] = []
        try:
            conn.settimeout(5.0)
            peer, uid = link.peer_uid(conn)
            if uid != os.getuid():
                _log(f"refused process {peer} of uid {uid}")
                conn.close()
                return
            request, fds = link.recv_request(conn)
            kind = request.get("kind")
            if kind == "status":
                link.send_message(conn, self.status())
            elif kind == "stop":
                link.send_message(conn, {"ok": True, "pid": self.pid, "running": len(self.runs)})
                _log(f"stop asked by process {peer}" + (f"; waiting for {len(self.runs)} runs" if self.runs else ""))
                self.stopping = True
                self.close_listener()
            elif kind == "run":
                given, fds = fds, []
                self._start_run(conn, request, given)  # closes them (in a run's process: never returns)
                return
            conn.close()
        except (OSError, ValueError) as e:
            _log(f"a connection failed: {e}")
            conn.close()
        finally:
            if os.getpid() == self.pid:
                for fd in fds:
                    os.close(fd)

    def close_listener(self) -> None:
        """No more connections: the socket file goes (new runs stay in their own process) and
        the lock with it, so that a new server may start while this one waits for its runs.
        (The lock is still this server's: no other server can have bound the path meanwhile.)"""
        if self.listener is not None:
            if self.sel is not None:
                try:
                    self.sel.unregister(self.listener)
                except (KeyError, ValueError):
                    pass
            try:
                os.unlink(self.path)
            except OSError:
                pass
            self.listener.close()
            self.listener = None
        if self.lock_fd is not None:
            os.close(self.lock_fd)
            self.lock_fd = None

    def status(self) -> dict:
        return {"ok": True, "pid": self.pid, "socket": self.path, "fingerprint": self.fingerprint,
                "version": _version(), "source": os.path.dirname(os.path.realpath(link.__file__)),
                "python": sys.executable, "uptime_s": round(time.time() - self.started, 1),
                "idle_timeout_s": self.idle_timeout_s, "running": len(self.runs), "served": self.served,
                "preload_s": round(self.preload_s, 3), "modules": len(sys.modules)}

    def _start_run(self, conn: socket.socket, request: dict, fds: list[int]) -> None:
        try:
            why = self._refusal(request, fds)
            if why:
                link.send_message(conn, {"ok": False, "reason": why})
                conn.close()
                return
            link.send_message(conn, {"ok": True})
            messages = link.Messages(conn)
            go = messages.next()  # the client may have given up waiting: then nothing runs
            if not (go and go.get("go")):
                conn.close()
                return
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                self._child(conn, request, fds)  # never returns (os._exit)
            try:
                os.setpgid(pid, pid)
            except OSError:
                pass  # the run already set it (or has ended)
            conn.settimeout(None)
            pidfd = os.pidfd_open(pid)
            self.runs[pid] = {"conn": conn, "pidfd": pidfd, "messages": messages, "t0": time.monotonic(),
                              "what": " ".join(request["argv"][:2])}
            self.sel.register(conn, selectors.EVENT_READ, ("conn", pid))
            self.sel.register(pidfd, selectors.EVENT_READ, ("run", pid))
            link.send_message(conn, {"pid": pid})
        except OSError as e:
            _log(f"a run could not start: {e}")
            conn.close()
        finally:
            if os.getpid() == self.pid:  # (never in a run's process; kept as a guard)
                for fd in fds:
                    os.close(fd)

    def _refusal(self, request: dict, fds: list[int]) -> str | None:
        """Why this server does not take the run (the client then runs it itself), or None."""
        if self.stopping:
            return "the server is stopping"
        if len(fds) != 3:
            return "stdin, stdout and stderr did not arrive"
        if request.get("fingerprint") != self.fingerprint:
            if link.fingerprint(self.env_before) != self.fingerprint:  # its own source changed: useless now
                _log("stillcap's source or the environment changed since the start: stopping")
                self.stopping = True
                self.close_listener()
                return "the server's code is out of date (it is stopping)"
            return "the server runs other code (another stillcap, Python or environment)"
        return None

    def _from_client(self, pid: int) -> None:
        run = self.runs[pid]
        try:
            message = run["messages"].next()
        except (OSError, ValueError):
            message = None
        if message is None:  # the client is gone (killed): so is the run, as it would have been
            self.sel.unregister(run["conn"])
            self._signal(pid, signal.SIGTERM)
            return
        if "signal" in message:
            self._signal(pid, int(message["signal"]))

    @staticmethod
    def _signal(pid: int, signum: int) -> None:
        try:
            os.killpg(pid, signum)  # the run and the worker processes it started, as a terminal does
        except OSError:
            try:
                os.kill(pid, signum)
            except OSError:
                pass

    def _reap(self, pid: int) -> None:
        run = self.runs.pop(pid)
        self.sel.unregister(run["pidfd"])
        os.close(run["pidfd"])
        _, status, usage = os.wait4(pid, 0)
        end = {"signal": os.WTERMSIG(status)} if os.WIFSIGNALED(status) else {"exit": os.waitstatus_to_exitcode(status)}
        _log(f"run {pid} (stillcap {run['what']} ...): {next(iter(end))} {next(iter(end.values()))} "
             f"after {time.monotonic() - run['t0']:.3f} s; CPU {usage.ru_utime + usage.ru_stime:.3f} s, "
             f"{usage.ru_minflt} page faults")
        conn = run["conn"]
        try:
            self.sel.unregister(conn)
        except (KeyError, ValueError):
            pass
        try:
            link.send_message(conn, end)
        except OSError:
            pass
        conn.close()
        self.served += 1
        self.last_active = time.monotonic()

    # -- the run's own process -----------------------------------------------------------------
    def _child(self, conn: socket.socket, request: dict, fds: list[int]) -> None:
        """In the forked process: become the client's process, run the command, end as Python
        ends a process (:func:`exit_as_python`). Never returns."""
        try:
            os.setpgid(0, 0)
            signal.signal(signal.SIGINT, signal.default_int_handler)
            for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGCHLD):
                signal.signal(s, signal.SIG_DFL)
            for s in request.get("ignored", ()):  # as the client ignores them (nohup, a background job)
                signal.signal(int(s), signal.SIG_IGN)
            self.sel.close()
            for run in self.runs.values():
                run["conn"].close()
                os.close(run["pidfd"])
            self.runs = {}
            if self.listener is not None:
                self.listener.close()
            if self.lock_fd is not None:
                os.close(self.lock_fd)
            conn.close()
            for i, fd in enumerate(fds):
                os.dup2(fd, i)
            for fd in fds:
                if fd > 2:
                    os.close(fd)
            os.chdir(request["cwd"])
            os.environ.clear()
            os.environ.update(request["env"])
            os.environ.update(self.env_changes)
            for k in self.env_removed:
                os.environ.pop(k, None)
            time.tzset()
            os.umask(int(request["umask"]))
            sys.argv = [request.get("argv0") or "stillcap", *request["argv"]]
            _reopen_stdio()
            if "numpy" in sys.modules:  # NumPy's global generator would repeat the server's sequence
                sys.modules["numpy"].random.seed()
            _keep_freed_memory()
        except BaseException as e:  # noqa: BLE001
            os.write(2, f"stillcap: the server could not start the run: {e}\n".encode())
            os._exit(2)
        exit_as_python(run_command(request["argv"]))


#: glibc's ``mallopt`` settings of a run's process (``M_TRIM_THRESHOLD``, ``M_TOP_PAD``,
#: ``M_MMAP_THRESHOLD``: parameter numbers of glibc's malloc.h, and their values in bytes).
MALLOPT = ((-1, 512 << 20), (-2, 64 << 20), (-3, 32 << 20))


def _keep_freed_memory() -> None:
    """A run's process keeps the memory it frees for its next allocations (glibc's malloc: no
    trimming below 512 MiB, the heap grown 64 MiB at a time, blocks up to 32 MiB from the heap
    rather than from their own ``mmap``), instead of returning it to the system and faulting
    fresh pages in again. A process forked from the server starts with no memory of its own:
    every page it writes is a page fault (copy-on-write or new), ~24 000 in a pitch against
    ~10 000 in a warm process's second run; these settings cut them to ~20 000 and the analysis's
    CPU in the fork by ~0.015 s (medians of 7 and of 12 forks of a preloaded process, with and
    without, on the loaded 2-core machine; ``benchmarks/bench_serve.py`` times the fork's first
    run). Runs are short-lived processes: what they keep goes when they end. Nothing where the C
    library is not glibc."""
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"):
            return
        import ctypes

        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, ValueError, AttributeError):  # not glibc
        return
    for param, value in MALLOPT:
        mallopt(param, value)


def _terminate(signum, _frame):
    _log("SIGTERM: stopped")
    raise SystemExit(0)


def _version() -> str:
    return sys.modules["stillcap"].__version__


def query(path: str, kind: str, timeout_s: float = 5.0) -> dict | None:
    """Ask the server on ``path`` for its status or to stop: its reply, or None when no server
    answers there."""
    sock = None
    try:
        link.check_private_dir(os.path.dirname(path), create=False)
        sock = link.connect(path, timeout_s)
        if link.peer_uid(sock)[1] != os.getuid():
            return None
        link.send_request(sock, {"kind": kind})
        return link.Messages(sock).next()
    except (OSError, ValueError):
        return None
    finally:
        if sock is not None:
            sock.close()


def status_text(reply: dict) -> str:
    same = reply.get("fingerprint") == link.fingerprint()
    return (f"stillcap server pid {reply['pid']} on {reply['socket']}: stillcap {reply['version']} from "
            f"{reply['source']}; up {reply['uptime_s']:g} s, {reply['served']} runs served, {reply['running']} running; "
            f"idle timeout {'none' if reply['idle_timeout_s'] <= 0 else format(reply['idle_timeout_s'], 'g') + ' s'}; "
            f"imports took {reply['preload_s']:g} s\n"
            + ("this stillcap's runs of pitch, hand, puppet run and markers go through it" if same else
               "this stillcap differs from the server's (code, Python or environment): its runs stay in-process"))


def as_json(reply: dict) -> str:
    return json.dumps(dict(reply, same_code=reply.get("fingerprint") == link.fingerprint()), indent=2)
