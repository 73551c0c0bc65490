"""Helpers of the GUI tests (tests/gui): a real server in a thread, Debian's Chromium.

``CHROMIUM`` is ``/usr/bin/chromium`` or ``$STILLCAP_CHROMIUM``; ``CHROMIUM_ARGS`` the switches of a
headless run in a container (as root in CI: no sandbox) with WebGL through SwiftShader.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

CHROMIUM = os.environ.get("STILLCAP_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist", "--disable-dev-shm-usage"]


@dataclass
class Server:
    """A running GUI server: its URL, token, context (``ctx.root`` is the opened folder)."""

    url: str
    port: int
    token: str
    ctx: object
    app: object

    def page_url(self, page: str = "") -> str:
        """The URL a user opens (the printed one): the page with the session token."""
        return f"{self.url}/{page}?token={self.token}"


@contextlib.contextmanager
def run_server(root: Path):
    """Serve the GUI on ``root`` (uvicorn in a thread, a free port on 127.0.0.1) until the block ends."""
    import uvicorn

    from stillcap.gui.app import create_app
    from stillcap.gui.context import GuiContext

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    token = secrets.token_urlsafe(16)
    ctx = GuiContext(Path(root).resolve(), token)
    app = create_app(ctx, port=port)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False, lifespan="on"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    for _ in range(500):
        if server.started:
            break
        time.sleep(0.02)
    else:
        raise RuntimeError("the GUI server did not start within 10 s")
    try:
        yield Server(f"http://127.0.0.1:{port}", port, token, ctx, app)
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()



def launch_chromium(playwright, extra_args=()):
    """Debian's Chromium, headless, with :data:`CHROMIUM_ARGS` and ``extra_args``."""
    return playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=[*CHROMIUM_ARGS, *extra_args])
