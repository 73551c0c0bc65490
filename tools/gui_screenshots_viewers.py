"""Screenshots of the GUI's pitch and hand screens for docs/gui.md (docs/img/gui-pitch-*.png,
docs/img/gui-hand-*.png), made from studio captures rendered here (same seeds, same pictures up
to the renderer's and SwiftShader's own differences).

    PYTHONPATH=src python tools/gui_screenshots_viewers.py [--out docs/img] [--work /tmp/gui-shots]

Needs /usr/bin/chromium (Playwright drives it; WebGL through SwiftShader).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "gui"))
import viewers_support as vs  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "img")
    ap.add_argument("--work", type=Path, default=None, help="where the studio captures are rendered")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    work = args.work or Path(tempfile.mkdtemp(prefix="stillcap-gui-shots-"))
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch

    session = work / "session"
    for name, preset, seed in (("4seam", "seed-4seam", 1), ("curveball", "seed-curveball", 3), ("slider", "seed-slider", 5)):
        vs.render_pitch(session / name, seed=seed, preset=preset)
    rep = session / "4seam-report"
    rep.mkdir(exist_ok=True)
    (rep / "pitch.json").write_text(json.dumps(analyse_pitch(Capture.load(session / "4seam")).to_dict(), allow_nan=False))
    hand = vs.render_hand(work / "hand", seed=2)
    shots = []
    with vs.browser() as b:
        with vs.serve(session) as (base, ctx):
            page = vs.open_page(b, f"{base}/pitch.html?token={vs.TOKEN}&item=4seam-report/pitch.json", size=(1400, 1000))
            page.wait_for_selector("#metrics-table tbody tr[data-key]", timeout=240_000)
            vs.wait_until(page, "document.getElementById('zoom-img').complete")
            page.screenshot(path=str(args.out / "gui-pitch-result.png"))
            shots.append("gui-pitch-result.png")
            page.locator("#plate-svg").scroll_into_view_if_needed()
            page.screenshot(path=str(args.out / "gui-pitch-plate-checks.png"))
            shots.append("gui-pitch-plate-checks.png")
            # a capture analysed in the page, its photo zoomed on a ball with its markers
            page.goto(f"{base}/pitch.html?item=4seam")
            page.wait_for_selector("#analyse:not([hidden])", timeout=240_000)
            page.click("#analyse")
            page.wait_for_selector("#metrics-table tbody tr[data-key]", timeout=240_000)
            ball = ctx.state["pitch"]["results"]["4seam"]["result"]["pairs"][0]["centers_px"][0][4]
            page.evaluate(f"() => window.stillcapPitchPage.zoomTo({ball[0]}, {ball[1]}, 6)")
            page.wait_for_timeout(1500)
            page.locator("#zoom").scroll_into_view_if_needed()
            page.screenshot(path=str(args.out / "gui-pitch-photo-zoom.png"))
            shots.append("gui-pitch-photo-zoom.png")
            # the session compared (the others analysed in one background job)
            page.goto(f"{base}/pitch.html?session=1")
            page.wait_for_selector("#session-table tbody tr", timeout=240_000)
            page.click("#analyse-all")
            vs.wait_until(page, "[...document.querySelectorAll('#session-table td[data-key]')].filter((td) => td.textContent).length >= 32", 600)
            page.wait_for_timeout(500)
            page.screenshot(path=str(args.out / "gui-pitch-session.png"))
            shots.append("gui-pitch-session.png")
        with vs.serve(hand) as (base, ctx):
            page = vs.open_page(b, f"{base}/hand.html?token={vs.TOKEN}", size=(1400, 1000))
            page.wait_for_selector("#points-table tbody tr", timeout=240_000)
            view = ctx.state["hand"]["results"][""]["view"]
            k = next(f["flash"] for f in view["flashes"] if f["reconstructed"])
            page.select_option("#flash", str(k))
            page.select_option("#points-table select[data-index='0']", "delete")
            page.wait_for_timeout(500)
            page.screenshot(path=str(args.out / "gui-hand-relabel.png"))
            shots.append("gui-hand-relabel.png")
            page.click("#show-all-flashes")
            page.evaluate("() => { const v = window.stillcapHand.state.view; window.stillcapHand.setTime(v.release.t0_s + 0.004); }")
            page.wait_for_timeout(500)
            page.screenshot(path=str(args.out / "gui-hand-release.png"))
            shots.append("gui-hand-release.png")
    for s in shots:
        print(f"wrote {args.out / s}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
