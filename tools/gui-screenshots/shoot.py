"""Screenshots of every screen of the GUI for docs/gui.md (docs/img/gui-*.png), reproducibly.

    PYTHONPATH=src python tools/gui-screenshots/shoot.py [--out docs/img] [--work DIR] [--only puppet,pitch,hand]

Renders its studio captures first (the puppet of the browser tests, seed 7; a puppet capture,
seed 3; three pitches, seeds 1, 3, 5; a hand, seed 2: same seeds, same pictures up to the
renderer's and SwiftShader's own differences), serves the GUI on them (uvicorn in a thread on
127.0.0.1), and drives Debian's Chromium (/usr/bin/chromium or $STILLCAP_CHROMIUM; WebGL through
SwiftShader) with Chromium's fake camera playing the turning puppet. The helpers are the browser
tests' own (tests/gui_support.py, tests/gui_video.py).

Screens: the start page; the puppet page with the live camera, the processed view with a bead
selected, the 3D view, a puppet capture offered for import; the pitch result (3D, metrics), its
plate and self-checks, a photo zoomed on a ball, a session compared; the hand relabel and the
take just after release.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import cv2
import httpx

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests"))

import gui_support as gs  # noqa: E402
from gui_video import write_turntable_video  # noqa: E402

WIDTH = 1200  # the PNGs are scaled down to this width: smaller files


def shoot_puppet(b, work: Path, out: Path, playwright) -> list[str]:
    video = write_turntable_video(work / "turntable.y4m")
    root = work / "jumpingjack"
    shutil.rmtree(root, ignore_errors=True)  # made anew: the project of an earlier run would be refused
    root.mkdir()
    cam = gs.launch_chromium(playwright, ["--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream",
                                          f"--use-file-for-fake-video-capture={video.path}"])
    shots = []
    with gs.run_server(root) as srv:
        page = gs.open_page(cam, srv.page_url("index.html", "stay=1"), size=(1500, 1000))
        gs.wait_until(page, "() => (document.getElementById('opened')?.textContent ?? '').startsWith('Opened')")
        page.screenshot(path=str(out / "gui-start.png"))
        shots.append("gui-start.png")
        # the project: 11 photos through the API (as the camera would), the 12th left for the camera
        h = srv.headers
        httpx.post(f"{srv.url}/api/puppet/new", json={"path": "."}, headers=h).raise_for_status()
        for k, (img, a) in enumerate(zip(video.scene.images, video.scene.truth.angles_deg)):
            if k == 4:
                continue  # left missing: the overview shows it
            png = cv2.imencode(".png", img)[1].tobytes()
            httpx.post(f"{srv.url}/api/puppet/photo?angle={round(a) % 360}", files={"file": ("p.png", png)},
                       headers=h, timeout=120).raise_for_status()
        page.goto(srv.page_url("puppet.html"))
        page.click("#camera-btn")
        gs.wait_until(page, "() => document.getElementById('live').videoWidth > 0")
        page.select_option("#angle-select", "120")
        page.wait_for_timeout(800)
        page.screenshot(path=str(out / "gui-puppet-camera.png"))
        shots.append("gui-puppet-camera.png")
        page.click("#angles button[data-angle='60']")
        gs.wait_until(page, "() => window.stillcapPuppet.view && window.stillcapPuppet.view.name === 'turn_060.0deg'")
        m = page.evaluate("() => window.stillcapPuppet.view.markers[0]")
        gs.canvas_click(page, "#photo", m["xy"][0], m["xy"][1])
        gs.wait_until(page, "() => !document.getElementById('selected-panel').hidden")
        page.locator("main").screenshot(path=str(out / "gui-puppet-view.png"))
        shots.append("gui-puppet-view.png")
        page.click("#compute-btn")
        gs.wait_until(page, "() => document.getElementById('status').textContent.startsWith('3D:')")
        page.wait_for_timeout(500)
        page.screenshot(path=str(out / "gui-puppet-3d.png"), full_page=True)
        shots.append("gui-puppet-3d.png")
        page.context.close()
    cam.close()
    # a puppet capture folder (stillcap studio puppet) opened: the page offers to import it
    from stillcap.calibrate.turntable import turntable_rig
    from stillcap.studio.puppet import puppet_scene, webcam_sensor

    capture = work / "puppet-capture"
    if not (capture / "capture.json").is_file():
        res = puppet_scene(turntable_rig(12, 30.0), "random", rng=3, sensor=webcam_sensor(jpeg_quality=None),
                           supersample=1)
        c, images = res.to_capture(".jpg")
        c.save(capture, images, jpeg_quality=85)
    shutil.rmtree(capture / "project", ignore_errors=True)  # imported anew
    with gs.run_server(capture) as srv:
        page = gs.open_page(b, srv.page_url("puppet.html"), size=(1500, 1000))
        gs.wait_until(page, "() => !document.getElementById('import-row').hidden")
        page.click("#import-btn")
        gs.wait_until(page, "() => document.getElementById('status').textContent.startsWith('capture imported')")
        page.wait_for_timeout(300)
        page.screenshot(path=str(out / "gui-puppet-import.png"))
        shots.append("gui-puppet-import.png")
        page.context.close()
    return shots


def shoot_pitch(b, work: Path, out: Path) -> list[str]:
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch

    session = work / "session"
    for name, preset, seed in (("4seam", "seed-4seam", 1), ("curveball", "seed-curveball", 3), ("slider", "seed-slider", 5)):
        gs.render_pitch(session / name, seed=seed, preset=preset)
    rep = session / "4seam-report"
    rep.mkdir(exist_ok=True)
    (rep / "pitch.json").write_text(json.dumps(analyse_pitch(Capture.load(session / "4seam")).to_dict(), allow_nan=False))
    shots = []
    with gs.run_server(session) as srv:
        page = gs.open_page(b, srv.page_url("pitch.html", "item=4seam-report/pitch.json"), size=(1400, 1000))
        page.wait_for_selector("#metrics-table tbody tr[data-key]", timeout=gs.WAIT_MS)
        gs.wait_until(page, "document.getElementById('zoom-img').complete")
        page.screenshot(path=str(out / "gui-pitch-result.png"))
        shots.append("gui-pitch-result.png")
        page.evaluate("() => document.getElementById('plate-svg').scrollIntoView({ block: 'start' })")  # the plate and the checks below it
        page.wait_for_timeout(300)
        page.screenshot(path=str(out / "gui-pitch-plate-checks.png"))
        shots.append("gui-pitch-plate-checks.png")
        # a capture analysed in the page, its photo zoomed on a ball with its markers
        page.goto(srv.page_url("pitch.html", "item=4seam"))
        page.wait_for_selector("#analyse:not([hidden])", timeout=gs.WAIT_MS)
        page.click("#analyse")
        page.wait_for_selector("#metrics-table tbody tr[data-key]", timeout=gs.WAIT_MS)
        ball = srv.ctx.state["pitch"]["results"]["4seam"]["result"]["pairs"][0]["centers_px"][0][4]
        page.evaluate(f"() => window.stillcapPitchPage.zoomTo({ball[0]}, {ball[1]}, 6)")
        page.wait_for_timeout(1500)
        page.locator("#zoom").scroll_into_view_if_needed()
        page.screenshot(path=str(out / "gui-pitch-photo-zoom.png"))
        shots.append("gui-pitch-photo-zoom.png")
        # the session compared (the others analysed in one background job)
        page.goto(srv.page_url("pitch.html", "session=1"))
        page.wait_for_selector("#session-table tbody tr", timeout=gs.WAIT_MS)
        page.click("#analyse-all")
        gs.wait_until(page, "[...document.querySelectorAll('#session-table td[data-key]')].filter((td) => td.textContent).length >= 32", timeout_s=600)
        page.wait_for_timeout(500)
        page.screenshot(path=str(out / "gui-pitch-session.png"))
        shots.append("gui-pitch-session.png")
        page.context.close()
    return shots


def shoot_hand(b, work: Path, out: Path) -> list[str]:
    hand = gs.render_hand(work / "hand", seed=2)
    shots = []
    with gs.run_server(hand) as srv:
        page = gs.open_page(b, srv.page_url("hand.html"), size=(1400, 1000))
        page.wait_for_selector("#points-table tbody tr", timeout=gs.WAIT_MS)
        view = srv.ctx.state["hand"]["results"][""]["view"]
        k = next(f["flash"] for f in view["flashes"] if f["reconstructed"])
        page.select_option("#flash", str(k))
        page.click("#frame-hand")
        page.select_option("#points-table select[data-index='0']", "delete")
        page.wait_for_timeout(500)
        page.screenshot(path=str(out / "gui-hand-relabel.png"))
        shots.append("gui-hand-relabel.png")
        page.check("#show-all-flashes")
        page.evaluate("() => { const v = window.stillcapHand.state.view; window.stillcapHand.setTime(v.release.t0_s + 0.004); }")
        page.wait_for_timeout(500)
        page.screenshot(path=str(out / "gui-hand-release.png"))
        shots.append("gui-hand-release.png")
        page.context.close()
    return shots


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "img")
    ap.add_argument("--work", type=Path, default=None, help="where the studio captures are rendered (kept)")
    ap.add_argument("--only", default="puppet,pitch,hand", help="which pages (comma-separated)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    work = args.work or Path(tempfile.mkdtemp(prefix="stillcap-gui-shots-"))
    work.mkdir(parents=True, exist_ok=True)
    only = set(args.only.split(","))
    from playwright.sync_api import sync_playwright

    shots = []
    with sync_playwright() as p:
        b = gs.launch_chromium(p)
        try:
            if "puppet" in only:
                shots += shoot_puppet(b, work, args.out, p)
            if "pitch" in only:
                shots += shoot_pitch(b, work, args.out)
            if "hand" in only:
                shots += shoot_hand(b, work, args.out)
        finally:
            b.close()
    for s in shots:
        f = args.out / s
        img = cv2.imread(str(f))
        if img.shape[1] > WIDTH:
            img = cv2.resize(img, (WIDTH, round(img.shape[0] * WIDTH / img.shape[1])), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(f), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        print(f"wrote {f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
