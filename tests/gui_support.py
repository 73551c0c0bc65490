"""Helpers of the GUI tests (``tests/gui``) and of the screenshot script
(``tools/gui-screenshots/shoot.py``): a real server in a thread, the application in a test client,
Debian's Chromium through Playwright, the one CSP-safe poll of a page, and small studio captures.

The fixtures built on these live in ``tests/gui/conftest.py`` (the one place for fixtures).

``CHROMIUM`` is ``/usr/bin/chromium`` or ``$STILLCAP_CHROMIUM``; ``CHROMIUM_ARGS`` the switches of a
headless run in a container (as root in CI: no sandbox) with WebGL through SwiftShader (the
software rasteriser is not disabled).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

CHROMIUM = os.environ.get("STILLCAP_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist", "--disable-dev-shm-usage"]
#: Waits in the tests only stop a hung test on a loaded machine: nothing is timed.
WAIT_S = 240.0
WAIT_MS = int(WAIT_S * 1000)
STUDIO_SIZE = (1280, 960)  # half the studio's resolution: same field of view, 4x cheaper


def have_chromium() -> bool:
    return Path(CHROMIUM).is_file() and os.access(CHROMIUM, os.X_OK)


# --------------------------------------------------------------------------------------------
# the server
# --------------------------------------------------------------------------------------------
@dataclass
class Server:
    """A running GUI server: its URL, token, context (``ctx.root`` is the opened folder)."""

    url: str
    port: int
    token: str
    ctx: object
    app: object

    def page_url(self, page: str = "", query: str = "") -> str:
        """The URL a user opens (the printed one): the page with the session token, and ``query``
        (``"item=x&y=z"``) after it."""
        return f"{self.url}/{page}?token={self.token}" + (f"&{query}" if query else "")

    @property
    def headers(self) -> dict:
        """The API header a page sends."""
        return {"X-Stillcap-Token": self.token}


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
    end = time.monotonic() + 60
    while not server.started and thread.is_alive() and time.monotonic() < end:
        time.sleep(0.02)
    if not server.started:
        raise RuntimeError("the GUI server did not start")
    try:
        yield Server(f"http://127.0.0.1:{port}", port, token, ctx, app)
    finally:
        server.should_exit = True
        thread.join(timeout=30)
        sock.close()


TEST_TOKEN = "test-token-0123456789"


def client(root: Path):
    """A Starlette test client of the whole application on ``root``, sending the token
    (:data:`TEST_TOKEN`); ``client.ctx`` is its context."""
    from starlette.testclient import TestClient

    from stillcap.gui.app import create_app
    from stillcap.gui.context import GuiContext

    ctx = GuiContext(Path(root).resolve(), TEST_TOKEN)
    c = TestClient(create_app(ctx), base_url="http://127.0.0.1", headers={"X-Stillcap-Token": TEST_TOKEN})
    c.ctx = ctx
    return c


def wait_job(c, job: dict, timeout: float = 300.0) -> dict:
    """Poll ``/api/jobs/{id}`` (``c``: a test client or an httpx client) until the job ends; its
    last record. (The timeout only stops a hung test: nothing is timed.)"""
    end = time.monotonic() + timeout
    while job["status"] in ("queued", "running") and time.monotonic() < end:
        time.sleep(0.1)
        job = c.get(f"/api/jobs/{job['id']}").json()
    return job


# --------------------------------------------------------------------------------------------
# the browser
# --------------------------------------------------------------------------------------------
def launch_chromium(playwright, extra_args=()):
    """Debian's Chromium, headless, with :data:`CHROMIUM_ARGS` and ``extra_args``."""
    return playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=[*CHROMIUM_ARGS, *extra_args])


def watch_errors(page):
    """Collect the page's script errors, console errors and failed requests in ``page.errors``."""
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(f"page error: {e}"))
    page.on("console", lambda m: page.errors.append(f"console {m.type}: {m.text}")
            if m.type == "error" and not m.text.startswith("Failed to load resource") else None)  # those: below, with the URL
    page.on("response", lambda r: page.errors.append(f"HTTP {r.status} {r.url}")
            if r.status >= 400 and not r.url.endswith("/favicon.ico") else None)
    return page


def open_page(browser, url: str | None = None, size=(1500, 950), **context_kw):
    """A page in a new context of ``browser`` (close ``page.context`` when done), watching its
    errors (:func:`watch_errors`), at ``url`` when given."""
    ctx = browser.new_context(viewport={"width": size[0], "height": size[1]}, **context_kw)
    page = watch_errors(ctx.new_page())
    if url:
        page.goto(url)
    return page


def canvas_click(page, selector: str, x: float, y: float, modifiers=()):
    """Click image pixel (x, y) of a canvas drawn at its image's size and scaled by CSS."""
    box = page.locator(selector).bounding_box()
    size = page.evaluate("(s) => [document.querySelector(s).width, document.querySelector(s).height]", selector)
    at = box["x"] + (x + 0.5) * box["width"] / size[0], box["y"] + (y + 0.5) * box["height"] / size[1]
    for m in modifiers:
        page.keyboard.down(m)
    page.mouse.click(*at)
    for m in modifiers:
        page.keyboard.up(m)


def wait_until(page, js: str, arg=None, timeout_s: float = WAIT_S):
    """Poll ``js`` in the page until it is truthy; its value.

    ``js`` is an expression or a function (``"(a) => ..."``, called with ``arg``), evaluated
    through the debugger protocol (``page.evaluate``). The one wait of every GUI test:
    ``page.wait_for_function`` polls inside the page by ``eval``, which the pages'
    Content-Security-Policy (no ``unsafe-eval``) may refuse. On time-out the error says what
    the page's status line shows. The timeout only stops a hung test: nothing is timed.
    """
    end = time.monotonic() + timeout_s
    while True:
        try:
            value = page.evaluate(js, arg)
        except Exception as e:  # the page navigated meanwhile (the token's redirect): ask the new one
            if "context was destroyed" not in str(e) and "navigat" not in str(e):
                raise
            value = None
        if value:
            return value
        if time.monotonic() > end:
            said = page.evaluate("() => document.getElementById('status')?.textContent ?? null")
            raise TimeoutError(f"still false after {timeout_s} s: {js} ({arg!r}); the page's status line: "
                               f"{said!r}; errors: {getattr(page, 'errors', None)}")
        time.sleep(0.1)


# --------------------------------------------------------------------------------------------
# studio captures
# --------------------------------------------------------------------------------------------
def render_pitch(folder: Path, seed: int = 1, preset: str = "seed-4seam", **kw) -> Path:
    """A studio pitch capture (true rig, small photos) written to ``folder`` (kept if there)."""
    from stillcap.studio.pitch import pitch_capture

    if not (folder / "capture.json").is_file():
        pc = pitch_capture(preset, seed, calibrate=False, image_size=STUDIO_SIZE, **kw)
        cap, images = pc.to_capture()
        cap.save(folder, images)
    return folder


def render_hand(folder: Path, seed: int = 2) -> Path:
    """A studio hand capture (small JPEG photos) written to ``folder`` (kept if there)."""
    from stillcap.studio.hand import hand_capture

    if not (folder / "capture.json").is_file():
        hc = hand_capture(seed, image_size=STUDIO_SIZE)
        cap, images = hc.to_capture(".jpg")
        cap.save(folder, images, jpeg_quality=92)
    return folder


def copy_tree(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, dirs_exist_ok=True)
    return dst
