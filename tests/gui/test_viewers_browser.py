"""The pitch and hand pages in a real browser (Debian's Chromium through Playwright, WebGL through
SwiftShader): a pitch result and a pitch capture opened, the 3D view not blank and holding one
mesh per measured position, the metrics table showing the result's numbers; a hand relabel made
in the page, saved to the overrides file, read back, and applied by the hand pipeline."""

import json
from pathlib import Path

import gui_support as vs
import numpy as np
import pytest
from gui_support import WAIT_MS


@pytest.fixture(scope="module")
def pitch_root(tmp_path_factory):
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch

    root = tmp_path_factory.mktemp("browser-pitch")
    cap = vs.render_pitch(root / "pitch-b", seed=3, preset="seed-curveball")
    (root / "report-b").mkdir()
    (root / "report-b" / "pitch.json").write_text(json.dumps(analyse_pitch(Capture.load(cap)).to_dict(),
                                                            allow_nan=False))
    return root


def _scene(page, name="stillcapPitch"):
    return page.evaluate(f"""() => ({{
        positions: window.{name}.objectsOfKind('position').length,
        ellipsoids: window.{name}.objectsOfKind('ellipsoid').length,
        trajectories: window.{name}.objectsOfKind('trajectory').length,
        cameras: window.{name}.objectsOfKind('camera').length,
        stats: window.{name}.frameStatistics()}})""")


def test_pitch_result_page(pitch_root, new_page):
    d = json.loads((pitch_root / "report-b" / "pitch.json").read_text())
    n_pos = sum(len(p["positions"]) for p in d["pairs"])
    with vs.run_server(pitch_root) as srv:
        ctx = srv.ctx
        page = new_page(srv.page_url("pitch.html", "item=report-b/pitch.json"))
        page.wait_for_selector("#metrics-table tbody tr[data-key]", timeout=WAIT_MS)
        vs.wait_until(page, "window.stillcapPitch && window.stillcapPitch.objectsOfKind('position').length > 0")
        s = _scene(page)
        assert s["positions"] == n_pos and s["ellipsoids"] == n_pos and s["trajectories"] == 1 and s["cameras"] == 4
        # not blank: a cleared canvas has one colour and no variance
        assert s["stats"]["variance"] > 20 and s["stats"]["colours"] > 10, s["stats"]
        # the view without its content is blank by the same measure (the check can fail)
        blank = page.evaluate("""() => { const v = window.stillcapPitch.view; v.content.visible = false; v.render();
            const s = window.stillcapPitch.frameStatistics(); v.content.visible = true; v.render(); return s; }""")
        assert blank["variance"] < 1e-6 and blank["colours"] == 1
        # the metrics table shows the result's numbers
        cells = page.eval_on_selector_all("#metrics-table tbody tr[data-key]",
                                          "rows => rows.map(r => [r.dataset.key, r.cells[1].textContent])")
        shown = dict(cells)
        for k in ("release_speed_mph", "spin_rate_rpm", "induced_vertical_break_in", "plate_x_ft", "spin_efficiency"):
            assert shown[k] == f"{d['metrics'][k]:.3f}"
        assert shown["spin_tilt"] == d["metrics"]["spin_tilt"]
        # the photos: one overlay circle per detected ball, its flash number beside it
        page.wait_for_selector("#thumbs figure", timeout=WAIT_MS)
        cam = page.eval_on_selector("#thumbs figure.here", "f => f.dataset.file")
        pair = next(p for p in d["pairs"] if Path(cam).stem in p["cameras"])
        i = pair["cameras"].index(Path(cam).stem)
        n_balls = sum(1 for c in pair["centers_px"][i] if c[0] is not None)
        assert page.locator("#zoom-svg circle.ball").count() == n_balls
        assert page.locator("#zoom-svg text.flash").count() == n_balls
        vs.wait_until(page, "document.getElementById('zoom-img').complete && document.getElementById('zoom-img').naturalWidth > 0")
        # the plate view: the zone and the crossing
        assert page.locator("#plate-svg rect.zone").count() == 1 and page.locator("#plate-svg circle.crossing").count() == 1
        assert page.errors == []


def test_pitch_capture_analysed_in_the_page(pitch_root, new_page):
    with vs.run_server(pitch_root) as srv:
        ctx = srv.ctx
        page = new_page(srv.page_url("pitch.html", "item=pitch-b"))
        page.wait_for_selector("#analyse:not([hidden])", timeout=WAIT_MS)
        assert page.locator("#metrics-table tbody tr[data-key]").count() == 0
        page.click("#analyse")
        page.wait_for_selector("#metrics-table tbody tr[data-key]", timeout=WAIT_MS)
        vs.wait_until(page, "window.stillcapPitch.objectsOfKind('position').length > 0")
        v = ctx.state["pitch"]["results"]["pitch-b"]["result"]
        s = _scene(page)
        assert s["positions"] == sum(len(p["positions"]) for p in v["pairs"]) > 10
        assert s["stats"]["variance"] > 20
        assert page.locator("#zoom-svg path.marker").count() > 0  # the painted markers found
        # the session: both pitches compared, their flights overlaid
        page.click("#show-session")
        page.wait_for_selector("#session-table tbody tr[data-path='pitch-b'] td[data-key]", timeout=WAIT_MS)
        vs.wait_until(page, "window.stillcapSession && window.stillcapSession.objectsOfKind('trajectory').length == 2")
        assert _scene(page, "stillcapSession")["stats"]["variance"] > 5
        speed = page.inner_text("#session-table tbody tr[data-path='pitch-b'] td[data-key='release_speed_mph']")
        assert speed.startswith(f"{v['metrics']['release_speed_mph']:.2f} ±")
        assert page.errors == []


def test_hand_relabel_saved_and_applied(tmp_path, new_page):
    from stillcap.body.hand_label import read_label_overrides
    from stillcap.pipelines.hand import HandOptions, analyse_hand

    root = vs.render_hand(tmp_path / "hand", seed=2)
    with vs.run_server(root) as srv:
        ctx = srv.ctx
        page = new_page(srv.page_url("hand.html"))
        page.wait_for_selector("#points-table tbody tr", timeout=WAIT_MS)  # analysed on opening
        view = ctx.state["hand"]["results"][""]["view"]
        k = next(f["flash"] for f in view["flashes"] if f["reconstructed"])
        page.select_option("#flash", str(k))
        assert vs.wait_until(page, "window.stillcapHand.objectsOfKind('skeleton').length == 1")
        s = page.evaluate("() => window.stillcapHand.frameStatistics()")
        assert s["variance"] > 5 and s["colours"] > 10, s
        rows = page.locator("#points-table tbody tr")
        i = next(j for j in range(rows.count())
                 if rows.nth(j).get_attribute("data-label") not in ("", "back.1", "back.2", "back.3"))
        old = rows.nth(i).get_attribute("data-label")
        new = "little.nail" if old != "little.nail" else "ring.nail"
        page.select_option(f"#points-table select[data-index='{i}']", new)
        page.click("#save")
        page.wait_for_selector("#save:disabled", timeout=WAIT_MS)
        point = view["flashes"][k]["points"][i]
        assert page.errors == []
    # the file the page wrote, read back by the hand pipeline's reader
    path = root / "label-overrides.json"
    raw = json.loads(path.read_text())
    assert raw["format"] == "stillcap-label-overrides" and len(raw["overrides"]) == 1
    read = read_label_overrides(path)
    assert read[0].flash == k and read[0].label == new
    np.testing.assert_allclose(read[0].position, point["position"], atol=1e-6)
    # the hand pipeline run with it gives the point its new label (and without it, the old one)
    def label_of(res):
        lab = res.labels
        p = int(np.argmin(np.linalg.norm(lab.points - np.asarray(point["position"]), axis=1)))
        j = np.flatnonzero(lab.point_index[k] == p)
        return lab.marker_names[int(j[0])] if len(j) else None
    assert label_of(analyse_hand(root, HandOptions())) == old
    assert label_of(analyse_hand(root, HandOptions(overrides=path))) == new


@pytest.fixture(scope="module")
def checks_root(tmp_path_factory):
    """Two results: a clean studio four-seamer (seed 1, the one whose checks all pass in
    tests/pipelines/test_pitch_checks.py), and a pitch flown with the Nathan model analysed with
    the seed's physics (the wrong one: ``flight_chi2`` fails)."""
    from stillcap.pipelines.pitch import analyse_pitch
    from stillcap.studio.pitch import pitch_capture

    root = tmp_path_factory.mktemp("browser-checks")
    (root / "clean").mkdir()
    (root / "clean" / "pitch.json").write_text(json.dumps(
        analyse_pitch(vs.render_pitch(root / "clean-capture", seed=1)).to_dict(), allow_nan=False))
    pc = pitch_capture("mlb-4seam", rng=2, calibrate=False, image_size=vs.STUDIO_SIZE, model="nathan")
    cap, photos = pc.to_capture()
    folder = cap.save(root / "nathan", photos)
    (root / "wrong").mkdir()
    (root / "wrong" / "pitch.json").write_text(json.dumps(analyse_pitch(folder, physics="seed").to_dict(),
                                                          allow_nan=False))
    return root


def _check_rows(page):
    return page.eval_on_selector_all("#checks-table tbody tr[data-name]", """rows => rows.map(r => ({
        cls: r.className, mark: r.cells[0].textContent, name: r.cells[1].textContent,
        subject: r.cells[2].textContent, message: r.cells[5].textContent}))""")


def test_pitch_self_checks_shown(checks_root, new_page):
    clean = json.loads((checks_root / "clean" / "pitch.json").read_text())["self_checks"]
    wrong = json.loads((checks_root / "wrong" / "pitch.json").read_text())["self_checks"]
    assert clean and all(c["passed"] for c in clean)  # the premise: a clean studio pitch passes
    failed = [c for c in wrong if not c["passed"]]
    assert "flight_chi2" in {c["name"] for c in failed}  # the premise: the wrong physics is caught
    with vs.run_server(checks_root) as srv:
        page = new_page(srv.page_url("pitch.html", "item=wrong/pitch.json"))
        vs.wait_until(page, "document.querySelectorAll('#checks-table tbody tr[data-name]').length > 0")
        rows = _check_rows(page)
        assert len(rows) == len(wrong)
        shown_failed = [(r["name"], r["subject"], r["message"]) for r in rows if r["cls"] == "failed"]
        assert shown_failed == [(c["name"], c.get("subject") or "", c["message"]) for c in failed]
        assert all(r["mark"] == "✗" for r in rows if r["cls"] == "failed")
        chi2 = next(r for r in rows if r["name"] == "flight_chi2" and r["cls"] == "failed")
        assert chi2["message"]  # says what went wrong, not only that it did
        # the clean result: every check listed, all passed
        page.goto(srv.page_url("pitch.html", "item=clean/pitch.json"))
        vs.wait_until(page, "(n) => document.querySelectorAll('#checks-table tbody tr[data-name]').length === n", len(clean))
        rows = _check_rows(page)
        assert [r["name"] for r in rows] == [c["name"] for c in clean]
        assert all(r["cls"] == "passed" and r["mark"] == "✓" for r in rows)
        assert page.errors == []


def test_a_running_job_is_cancelled_from_the_page(pitch_root, new_page, monkeypatch):
    """The Cancel button beside the progress bar stops the job (DELETE /api/jobs/{id}: the work
    stops at its next progress report). The analysis is replaced by one that reports progress
    until it is cancelled, so the test does not race a real analysis's end."""
    import time

    import stillcap.gui.pitch as gui_pitch

    calls = []

    def endless(ctx, rel, progress=None):
        calls.append(rel)
        for i in range(10**6):  # ends by the cancel (JobCancelled raised by progress), or the test's timeout
            progress(i, 10**6, "waiting to be cancelled")
            time.sleep(0.05)
        raise AssertionError("never cancelled")

    monkeypatch.setattr(gui_pitch, "analyse_capture", endless)
    with vs.run_server(pitch_root) as srv:
        page = new_page(srv.page_url("pitch.html", "item=pitch-b"))
        page.wait_for_selector("#analyse:not([hidden])", timeout=WAIT_MS)
        assert page.is_hidden("#cancel-job")
        page.click("#analyse")
        page.wait_for_selector("#cancel-job:not([hidden])", timeout=WAIT_MS)
        vs.wait_until(page, "() => /waiting to be cancelled/.test(document.getElementById('progress-text').textContent)")
        page.click("#cancel-job")
        vs.wait_until(page, "() => document.getElementById('status').textContent === 'cancelled'")
        assert page.is_hidden("#cancel-job")
        assert calls == ["pitch-b"]
        assert "pitch-b" not in srv.ctx.state.get("pitch", {}).get("results", {})
        from stillcap.gui.jobs import job_manager

        assert [j.status for j in job_manager(srv.ctx)._jobs.values()] == ["cancelled"]
        assert page.errors == []


_HAND_SPAN = """(k) => { const h = window.stillcapHand, v = h.state.view, T = h.view.THREE, cam = h.view.camera;
    cam.updateMatrixWorld();
    const ps = v.flashes[k].points.filter((p) => p.label).map((p) => new T.Vector3(...p.position).project(cam));
    const xs = ps.map((p) => p.x), ys = ps.map((p) => p.y);
    return { span: Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys)),
             inside: ps.every((p) => Math.abs(p.x) <= 1 && Math.abs(p.y) <= 1) }; }"""


def test_hand_view_framed_on_the_hand(tmp_path, new_page):
    """The 3D view frames the shown flash's hand (its labelled markers span a good part of the view,
    all inside it); with "all flashes" it frames the whole take, where that hand is smaller."""
    root = vs.render_hand(tmp_path / "hand", seed=2)
    with vs.run_server(root) as srv:
        page = new_page(srv.page_url("hand.html"))
        page.wait_for_selector("#points-table tbody tr", timeout=WAIT_MS)
        view = srv.ctx.state["hand"]["results"][""]["view"]
        k = next(f["flash"] for f in view["flashes"] if f["reconstructed"])
        page.select_option("#flash", str(k))
        page.click("#frame-hand")
        hand = page.evaluate(_HAND_SPAN, k)
        assert hand["inside"] and hand["span"] > 0.5, hand
        page.check("#show-all-flashes")
        take = page.evaluate(_HAND_SPAN, k)
        assert take["inside"] and take["span"] < 0.8 * hand["span"], (hand, take)
        assert page.errors == []
