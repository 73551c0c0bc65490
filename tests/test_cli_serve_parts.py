"""Pieces of the warm server (``stillcap serve``) tested on their own, without a server: the
messages between client and server, what the client imports, and the CLI modules each run
imports again from the code the server compiled once (tests/test_cli_serve.py runs the whole)."""

from __future__ import annotations

import importlib
import importlib.machinery
import os
import socket
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from stillcap import _server_link as link

SRC = Path(__file__).resolve().parents[1] / "src"


def test_a_request_carries_its_file_descriptors_and_the_messages_follow(tmp_path):
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    files = [open(tmp_path / f"f{i}", "w") for i in range(3)]  # noqa: SIM115
    try:
        request = {"kind": "run", "argv": ["pitch", "é/π"], "env": {"A": "1"}, "umask": 0o22, "ignored": []}
        link.send_request(a, request, [f.fileno() for f in files])
        got, fds = link.recv_request(b)
        assert got == request
        assert [os.fstat(fd).st_ino for fd in fds] == [os.fstat(f.fileno()).st_ino for f in files]
        for fd in fds:
            os.close(fd)
        link.send_message(a, {"go": True})
        link.send_message(a, {"signal": 2})
        messages = link.Messages(b)
        assert messages.next() == {"go": True}
        assert messages.next() == {"signal": 2}
        a.close()
        assert messages.next() is None  # the other end closed
    finally:
        for f in files:
            f.close()
        a.close()
        b.close()


@pytest.mark.parametrize("raw, why", [
    (b"JUNK" + struct.pack(">I", 2) + b"{}", "not a stillcap request"),
    (b"SCAP" + struct.pack(">I", link.MAX_BYTES + 1), "a request of"),
    (b"SCAP" + struct.pack(">I", 4) + b"\xff\xff\xff\xff", "does not decode"),
    (b"SCAP" + struct.pack(">I", 5) + b"\xe9\x03\x00\x00\x00", "not a dict"),  # marshal of the int 3
    (b"SCAP" + struct.pack(">I", 100) + b"short", "closed inside the request"),
])
def test_a_bad_request_is_refused_and_its_descriptors_closed(tmp_path, raw, why):
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    f = open(tmp_path / "f", "w")  # noqa: SIM115
    try:
        socket.send_fds(a, [raw[:8]], [f.fileno()])
        a.sendall(raw[8:])
        a.close()
        before = len(os.listdir("/proc/self/fd"))
        with pytest.raises(ValueError, match=why):
            link.recv_request(b)
        assert len(os.listdir("/proc/self/fd")) == before  # the descriptor received was closed
    finally:
        f.close()
        a.close()
        b.close()


def test_a_message_too_long_or_cut_short_is_refused():
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        a.sendall(struct.pack(">I", link.MAX_BYTES + 1))
        with pytest.raises(ValueError, match="a message of"):
            link.Messages(b).next()
        a.sendall(struct.pack(">I", 10) + b"abc")
        a.close()
        with pytest.raises(ValueError, match="closed inside a message"):
            link.Messages(b).next()
    finally:
        a.close()
        b.close()


def test_the_client_imports_only_what_the_interpreter_has_built_in():
    """The client's imports (``_entry`` and ``_server_link``, the fingerprint computed) add to a
    bare interpreter's modules only stillcap's three and built-in or tiny ones: none of
    ``socket``, ``signal``, ``hashlib``, ``json``, ``enum`` or ``re``, which cost more than the
    rest of the client (docs in stillcap._server_link)."""
    listing = "import sys; print(' '.join(sorted(sys.modules)))"
    env = dict(os.environ, PYTHONPATH=str(SRC))
    bare = set(subprocess.run([sys.executable, "-c", listing], capture_output=True, text=True, env=env,
                              check=True, timeout=120).stdout.split())
    code = "import stillcap._entry, stillcap._server_link as l; l.fingerprint(); " + listing
    client = set(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                                check=True, timeout=120).stdout.split())
    allowed = {"stillcap", "stillcap._entry", "stillcap._server_link", "__future__", "_socket", "_signal",
               "marshal", "struct", "_struct", "stat", "_stat", "_sha256", "_sha2"}
    assert client - bare <= allowed, sorted(client - bare - allowed)
    assert "stillcap._entry" in client


def _module_file(folder: Path, name: str, text: str) -> Path:
    path = folder / f"{name}.py"
    path.write_text(text)
    return path


def test_forgotten_modules_are_imported_again_from_the_code_compiled_once(tmp_path, monkeypatch):
    """A run imports the CLI's modules again (the server forgot them) from the code the server
    compiled: nothing is compiled, the module is as a fresh import makes it; a module found at
    another path than the one compiled is compiled and imported as usual."""
    from stillcap.cli._server import _code_of, _KeptCode

    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "meta_path", list(sys.meta_path))
    importlib.invalidate_caches()
    path = _module_file(tmp_path, "kept_code_mod", "X = [1, 2]\nWHERE = __file__\n")
    first = importlib.import_module("kept_code_mod")
    kept = _code_of(first)
    assert kept is not None and kept[0] == str(path)
    del sys.modules["kept_code_mod"]
    other = tmp_path / "elsewhere"
    other.mkdir()
    _module_file(tmp_path, "kept_code_other", "Y = 3\n")
    _KeptCode.install({"kept_code_mod": kept, "kept_code_other": (str(other / "kept_code_other.py"), kept[1])})
    _KeptCode.install({"kept_code_mod": kept, "kept_code_other": (str(other / "kept_code_other.py"), kept[1])})
    assert sum(isinstance(f, _KeptCode) for f in sys.meta_path) == 1  # installed once

    compiled = []
    real = importlib.machinery.SourceFileLoader.source_to_code
    monkeypatch.setattr(importlib.machinery.SourceFileLoader, "source_to_code",
                        lambda self, data, path, **kw: compiled.append(path) or real(self, data, path, **kw))
    try:
        again = importlib.import_module("kept_code_mod")
        assert again is not first and again.X == [1, 2] and again.X is not first.X  # executed afresh
        assert again.WHERE == str(path) and again.__spec__.origin == str(path)
        assert compiled == []
        other_mod = importlib.import_module("kept_code_other")  # its path is not the kept code's
        assert other_mod.Y == 3 and not hasattr(other_mod, "X")
        assert compiled == [str(tmp_path / "kept_code_other.py")]
    finally:
        sys.modules.pop("kept_code_mod", None)
        sys.modules.pop("kept_code_other", None)


FREED_AGAIN = r"""
import ctypes, resource, sys
if sys.argv[1] == "on":
    from stillcap.cli._server import _keep_freed_memory
    _keep_freed_memory()
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
n = 24 << 20

def faults():
    p = libc.malloc(n)
    f = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    ctypes.memset(p, 1, n)
    f = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f
    libc.free(p)
    return f

print(faults(), faults())
"""


@pytest.mark.skipif(not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"), reason="glibc's mallopt")
def test_a_runs_process_keeps_the_memory_it_frees():
    """In a run's process (the server's settings), 24 MiB written, freed and asked for again come
    back without page faults; with glibc's defaults (the control) they are faulted in again."""
    pages = (24 << 20) // os.sysconf("SC_PAGE_SIZE")
    env = dict(os.environ, PYTHONPATH=str(SRC))
    got = {}
    for mode in ("on", "off"):
        out = subprocess.run([sys.executable, "-c", FREED_AGAIN, mode], capture_output=True, text=True, env=env,
                             check=True, timeout=120).stdout
        got[mode] = [int(x) for x in out.split()]
    assert got["on"][0] > pages // 2 and got["off"][0] > pages // 2  # the first time: fresh pages
    assert got["on"][1] < pages // 10, got
    assert got["off"][1] > pages // 2, got  # the control: without the settings they come back faulted
