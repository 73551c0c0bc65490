"""A puppet capture folder (``stillcap studio puppet``) opened in the GUI, in Chromium: imported as a
project from the page (its rig, its photos, the beads detected), 3D computed from it; then a bead
selected by a click and deleted, and another selected and relabelled, both saved as project
edits."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gui_support import canvas_click, run_server, wait_until


@pytest.fixture(scope="module")
def puppet_capture(tmp_path_factory):
    """A studio puppet capture as ``stillcap studio puppet`` writes it (12 turntable views, JPEG),
    with its truth."""
    from stillcap.calibrate.turntable import turntable_rig
    from stillcap.studio.puppet import puppet_scene, webcam_sensor

    root = tmp_path_factory.mktemp("puppet-capture")
    res = puppet_scene(turntable_rig(12, 30.0), "random", rng=3, sensor=webcam_sensor(jpeg_quality=None), supersample=1)
    cap, images = res.to_capture(".jpg")
    cap.save(root / "jj", images, jpeg_quality=85)
    return root / "jj", res


def _status(page):
    return page.inner_text("#status")


def _project(folder):
    return json.loads((folder / "project.json").read_text())


def test_capture_imported_edited_by_clicks_and_computed(puppet_capture, new_page):
    capture, scene = puppet_capture
    with run_server(capture) as srv:
        page = new_page(srv.page_url("puppet.html"))
        # the opened folder is a capture, not a project: the page offers to import it
        wait_until(page, "() => !document.getElementById('import-row').hidden")
        assert page.inner_text("#project-name") == "no project open"
        page.click("#import-btn")
        wait_until(page, "() => /imported|error/.test(document.getElementById('status').className + "
                         "document.getElementById('status').textContent)")
        assert _status(page).startswith("capture imported into the project folder “project” (12 views)"), _status(page)
        proj = capture / "project"
        d = _project(proj)
        assert len(d["views"]) == 12 and {v["camera"] for v in d["views"]} == {c.name for c in scene.rig}
        assert page.locator("#angles button[data-view]").count() == 12
        assert page.is_hidden("#import-row")  # imported: offered no more

        # the beads detected on import are where the truth says (the first view shown)
        names = list(scene.truth.marker_names)
        view = page.evaluate("() => window.stillcapPuppet.view")
        k = [c.name for c in scene.rig].index(view["name"])
        err = [np.hypot(*(np.array(m["xy"]) - scene.truth.markers_px[k, names.index(m["name"])]))
               for m in view["markers"] if scene.truth.visible[k, names.index(m["name"])]]
        assert len(err) >= 8 and np.median(err) < 2.0, err

        # select a bead by a click on it, then Delete
        def select(name):
            m = next(m for m in page.evaluate("() => window.stillcapPuppet.view.markers") if m["name"] == name)
            canvas_click(page, "#photo", m["xy"][0], m["xy"][1])
            wait_until(page, "(n) => !document.getElementById('selected-panel').hidden && "
                             "document.getElementById('selected-name').textContent.startsWith(n + ' ')", name)
            return m

        victim, other = view["markers"][0]["name"], view["markers"][1]["name"]
        select(victim)
        page.click("#delete-btn")
        wait_until(page, "(s) => document.getElementById('status').textContent === s", f"{victim} deleted")
        assert not any(m["name"] == victim for m in page.evaluate("() => window.stillcapPuppet.view.markers"))
        assert page.is_hidden("#selected-panel")  # the deleted bead is no longer selected
        edits = next(v for v in _project(proj)["views"] if v["name"] == view["name"])["edits"]
        assert edits == [{"op": "delete", "marker": victim}]

        # select another bead, relabel it as the deleted one's name
        m = select(other)
        page.select_option("#relabel-select", victim)
        page.click("#relabel-btn")
        wait_until(page, "(s) => document.getElementById('status').textContent === s", f"{other} relabelled as {victim}")
        now = {b["name"]: b for b in page.evaluate("() => window.stillcapPuppet.view.markers")}
        assert other not in now and now[victim]["xy"] == m["xy"] and now[victim]["source"] == "edited"
        assert page.inner_text("#selected-name").startswith(victim + " ")  # still selected, by its new name
        edits = next(v for v in _project(proj)["views"] if v["name"] == view["name"])["edits"]
        assert edits[-1]["op"] == "relabel" and edits[-1]["marker"] == other and edits[-1]["to"] == victim

        # a bead clicked at once after another view is chosen stays selected once that view's
        # photo has arrived (the first shift's session test lost such selections: the page
        # cleared the selection when the photo came, after the view's name had changed)
        for tile in page.evaluate("() => [...document.querySelectorAll('#angles button[data-view]')]"
                                  ".map((b) => b.dataset.view)")[1:5]:
            page.click(f"#angles button[data-view='{tile}']")
            wait_until(page, "(n) => window.stillcapPuppet.view.name === n", tile)
            name = page.evaluate("() => window.stillcapPuppet.view.markers[0].name")
            select(name)
            page.wait_for_load_state("networkidle")  # the photo fetched and drawn
            page.evaluate("() => new Promise((r) => requestAnimationFrame(() => r()))")
            assert page.is_visible("#selected-panel") and page.inner_text("#selected-name").startswith(name + " "), tile

        # 3D from the imported project
        page.click("#compute-btn")
        wait_until(page, "() => /^3D:/.test(document.getElementById('status').textContent) || "
                         "document.getElementById('status').classList.contains('error')")
        assert _status(page).startswith("3D:"), _status(page)
        n3d = page.evaluate("""() => window.stillcapPuppet.scene3d.scene.children.flatMap((c) => c.children || [])
                                 .filter((o) => o.userData && o.userData.kind === 'marker').length""")
        assert n3d >= 12
        assert page.errors == []
