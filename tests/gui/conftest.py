"""Fixtures of the GUI tests: a real server (uvicorn in a thread on a free port of 127.0.0.1) and
Playwright driving Debian's Chromium (``/usr/bin/chromium``, or ``$STILLCAP_CHROMIUM``).

Browser tests are skipped, with the reason, only when that Chromium is absent; ``.ci/run``
installs it, so in CI they run. WebGL runs through SwiftShader (no GPU; the software rasteriser
is not disabled).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from gui_support import CHROMIUM, have_chromium, launch_chromium, open_page, run_server


@pytest.fixture
def gui_server(tmp_path):
    """A server on an empty folder (``tmp_path / "work"``); tests open other folders with :func:`run_server`."""
    root = tmp_path / "work"
    root.mkdir()
    with run_server(root) as s:
        yield s


def _need_chromium():
    if not have_chromium():
        pytest.skip(f"Debian's Chromium is not installed at {CHROMIUM} (apt-get install chromium; .ci/run does)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e .[test])")


@pytest.fixture(scope="session")
def playwright_instance():
    _need_chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


@pytest.fixture(scope="session")
def browser(playwright_instance):
    """A headless Chromium (no camera)."""
    b = launch_chromium(playwright_instance)
    yield b
    b.close()


@pytest.fixture(scope="session")
def puppet_video(tmp_path_factory):
    """A y4m video of the studio's puppet turning on the turntable (:mod:`gui_video`)."""
    from gui_video import write_turntable_video

    return write_turntable_video(tmp_path_factory.mktemp("video") / "turntable.y4m")


@pytest.fixture(scope="session")
def camera_browser(playwright_instance, puppet_video):
    """A headless Chromium whose camera is the fake device playing :func:`puppet_video`."""
    b = launch_chromium(playwright_instance, ["--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream",
                                              f"--use-file-for-fake-video-capture={puppet_video.path}"])
    yield b
    b.close()


@pytest.fixture
def new_page(browser):
    """``new_page(url=None, size=(1500, 950), browser=None, **context_kw)``: a page in a fresh
    context, its errors collected in ``page.errors`` (:func:`gui_support.open_page`); closed at
    the test's end."""
    pages = []

    def make(url=None, size=(1500, 950), browser_=None, **kw):
        pages.append(open_page(browser_ or browser, url, size, **kw))
        return pages[-1]

    yield make
    for p in pages:
        p.context.close()


@pytest.fixture
def page(new_page):
    """A fresh browser page (its errors in ``page.errors``)."""
    return new_page()


def has_ffmpeg() -> bool:
    try:
        import imageio_ffmpeg

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).is_file()
    except Exception:
        return shutil.which("ffmpeg") is not None
