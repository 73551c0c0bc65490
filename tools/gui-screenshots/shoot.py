"""Screenshots of every screen of the GUI for docs/gui.md (docs/img/gui-*.png), reproducibly.

    PYTHONPATH=src python tools/gui-screenshots/shoot.py [--out docs/img]

Renders the studio's puppet (seed 7, as the browser tests), serves the GUI on a temporary folder
(uvicorn in a thread on 127.0.0.1), drives Debian's Chromium (/usr/bin/chromium or
$STILLCAP_CHROMIUM) with Chromium's fake camera playing the turning puppet, and shoots: the
start page, the puppet page with the live camera, the processed view with a bead selected, the
3D view after Compute 3D. Pitch and hand pages are shot when their viewer modules exist
(``stillcap.gui.pitch`` / ``.hand``), on kept studio captures given with --pitch / --hand.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import cv2
import httpx

HERE = Path(__file__).resolve()
sys.path.insert(0, str(HERE.parents[2] / "tests"))

from gui_support import launch_chromium, run_server  # noqa: E402
from gui_video import write_turntable_video  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE.parents[2] / "docs" / "img")
    ap.add_argument("--pitch", type=Path, help="a pitch capture folder to shoot the pitch viewer on")
    ap.add_argument("--hand", type=Path, help="a hand capture folder to shoot the hand viewer on")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        video = write_turntable_video(tmp / "turntable.y4m")
        root = tmp / "jumpingjack"
        root.mkdir()
        with sync_playwright() as p, run_server(root) as srv:
            b = launch_chromium(p, ["--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream",
                                    f"--use-file-for-fake-video-capture={video.path}"])
            page = b.new_page(viewport={"width": 1500, "height": 1000})
            page.goto(srv.page_url("index.html") + "&stay")
            page.wait_for_timeout(500)
            page.screenshot(path=str(args.out / "gui-start.png"))
            # the project: 11 photos through the API (as the camera would), the 12th from the camera
            h = {"X-Stillcap-Token": srv.token}
            httpx.post(f"{srv.url}/api/puppet/new", json={"path": "."}, headers=h)
            for k, (img, a) in enumerate(zip(video.scene.images, video.scene.truth.angles_deg)):
                if k == 4:
                    continue  # left missing: the overview shows it
                png = cv2.imencode(".png", img)[1].tobytes()
                httpx.post(f"{srv.url}/api/puppet/photo?angle={round(a) % 360}", files={"file": ("p.png", png)}, headers=h)
            page.goto(srv.page_url("puppet.html"))
            page.click("#camera-btn")
            page.wait_for_function("() => document.getElementById('live').videoWidth > 0")
            page.select_option("#angle-select", "120")
            page.wait_for_timeout(800)
            page.screenshot(path=str(args.out / "gui-puppet-camera.png"))
            page.click("#angles button[data-angle='60']")
            page.wait_for_function("() => window.stillcapPuppet.view && window.stillcapPuppet.view.name === 'turn_060.0deg'")
            page.wait_for_timeout(300)
            m = page.evaluate("() => window.stillcapPuppet.view.markers[0]")
            box = page.locator("#photo").bounding_box()
            page.mouse.click(box["x"] + (m["xy"][0] + 0.5) * box["width"] / 640, box["y"] + (m["xy"][1] + 0.5) * box["height"] / 480)
            page.wait_for_timeout(300)
            page.locator("main").screenshot(path=str(args.out / "gui-puppet-view.png"))
            page.click("#compute-btn")
            page.wait_for_function("() => document.getElementById('status').textContent.startsWith('3D:')", timeout=120_000)
            page.wait_for_timeout(500)
            page.screenshot(path=str(args.out / "gui-puppet-3d.png"), full_page=True)
            b.close()
        for kind, folder in (("pitch", args.pitch), ("hand", args.hand)):
            if folder is None:
                continue
            work = tmp / kind
            shutil.copytree(folder, work)
            with sync_playwright() as p, run_server(work) as srv:
                b = launch_chromium(p)
                page = b.new_page(viewport={"width": 1500, "height": 1000})
                page.goto(srv.page_url(f"{kind}.html"))
                page.wait_for_timeout(4000)
                page.screenshot(path=str(args.out / f"gui-{kind}.png"), full_page=True)
                b.close()
    for f in sorted(args.out.glob("gui-*.png")):  # 1200 px wide, 8-bit palette-free PNG: smaller files
        img = cv2.imread(str(f))
        if img.shape[1] > 1200:
            img = cv2.resize(img, (1200, round(img.shape[0] * 1200 / img.shape[1])), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(f), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        print(f)


if __name__ == "__main__":
    main()
