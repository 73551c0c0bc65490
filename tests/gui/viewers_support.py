"""Helpers of the pitch and hand viewer tests (``tests/gui/test_viewers_*.py``) and of
``tools/gui_screenshots_viewers.py``: small studio captures, the application in a test client or
a real server on a free port, and Chromium through Playwright."""

from __future__ import annotations

import contextlib
import shutil
import socket
import threading
import time
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
#: Chromium's flags: no sandbox (containers), WebGL through SwiftShader (no GPU here).
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
SIZE = (1280, 960)  # half the studio's resolution: same field of view, 4x cheaper
TOKEN = "test-token-0123456789"


def render_pitch(folder: Path, seed: int = 1, preset: str = "seed-4seam", **kw) -> Path:
    """A studio pitch capture (true rig, small photos) written to ``folder``."""
    from stillcap.studio.pitch import pitch_capture

    if not (folder / "capture.json").is_file():
        pc = pitch_capture(preset, seed, calibrate=False, image_size=SIZE, **kw)
        cap, images = pc.to_capture()
        cap.save(folder, images)
    return folder


def render_hand(folder: Path, seed: int = 2) -> Path:
    """A studio hand capture (small JPEG photos) written to ``folder``."""
    from stillcap.studio.hand import hand_capture

    if not (folder / "capture.json").is_file():
        hc = hand_capture(seed, image_size=SIZE)
        cap, images = hc.to_capture(".jpg")
        cap.save(folder, images, jpeg_quality=92)
    return folder


def copy_tree(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, dirs_exist_ok=True)
    return dst


def context(root: Path):
    from stillcap.gui.context import GuiContext

    return GuiContext(Path(root).resolve(), TOKEN)


def client(root: Path):
    """A Starlette test client of the whole application on ``root``, sending the token."""
    from starlette.testclient import TestClient

    from stillcap.gui.app import create_app

    ctx = context(root)
    c = TestClient(create_app(ctx), base_url="http://127.0.0.1", headers={"X-Stillcap-Token": TOKEN})
    c.ctx = ctx
    return c


def wait_job(c, job: dict, timeout: float = 300.0) -> dict:
    """Poll ``/api/jobs/{id}`` until the job ends; its last record. (A generous timeout that
    only stops a hung test: the machine is shared, nothing is timed.)"""
    end = time.monotonic() + timeout
    while job["status"] in ("queued", "running") and time.monotonic() < end:
        time.sleep(0.1)
        job = c.get(f"/api/jobs/{job['id']}").json()
    return job


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(root: Path):
    """The application on ``root`` served by uvicorn on 127.0.0.1 (a thread); yields
    ``(base_url, ctx)``. The page URL to open is ``base_url + "/pitch.html?token=" + TOKEN``."""
    import uvicorn

    from stillcap.gui.app import create_app

    ctx = context(root)
    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(ctx, port=port), host="127.0.0.1", port=port,
                                           log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    end = time.monotonic() + 60
    while not server.started and thread.is_alive() and time.monotonic() < end:
        time.sleep(0.05)
    if not server.started:
        raise RuntimeError("the GUI server did not start")
    try:
        yield f"http://127.0.0.1:{port}", ctx
    finally:
        server.should_exit = True
        thread.join(timeout=30)


@contextlib.contextmanager
def browser():
    """Chromium (Debian's, /usr/bin/chromium) through Playwright; yields a new page factory."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


def open_page(b, url: str, size=(1400, 1000)):
    """A page of ``b`` at ``url`` whose console errors and failed requests are collected in
    ``page.errors``."""
    page = b.new_page(viewport={"width": size[0], "height": size[1]})
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(f"page error: {e}"))
    page.on("console", lambda m: page.errors.append(f"console {m.type}: {m.text}") if m.type == "error" and not m.text.startswith("Failed to load resource") else None)  # those: below, with the URL
    page.on("response", lambda r: page.errors.append(f"HTTP {r.status} {r.url}")
            if r.status >= 400 and not r.url.endswith("/favicon.ico") else None)
    page.goto(url)
    return page


def wait_until(page, expression: str, timeout_s: float = 240.0):
    """Poll ``expression`` (JavaScript, evaluated by the debugger protocol) until it is truthy;
    its value. (``page.wait_for_function`` polls through ``eval``, which the pages' CSP refuses.)
    The timeout only stops a hung test: nothing is timed."""
    end = time.monotonic() + timeout_s
    while True:
        value = page.evaluate(expression)
        if value:
            return value
        if time.monotonic() > end:
            raise TimeoutError(f"still false after {timeout_s} s: {expression}")
        time.sleep(0.1)
