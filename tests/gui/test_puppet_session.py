"""A whole puppet session in Chromium, as a person does it: a new project, the camera (Chromium's
fake camera playing the studio's turning puppet), a photo per turntable angle, one bead corrected
by hand, 3D computed, looked at and picked, exported, and the exports opened with real readers."""

from __future__ import annotations

import json

import cv2
import numpy as np
from gui_support import canvas_click, wait_until
from gui_video import read_code


def _video_code(page) -> int | None:
    """The angle index the live video shows now (read as the test's eyes, from a canvas)."""
    v = page.evaluate("""() => {
        const v = document.getElementById('live');
        if (!v.videoWidth) return null;
        const c = document.createElement('canvas'); c.width = 16; c.height = 16;
        const g = c.getContext('2d'); g.drawImage(v, 0, 0, 16, 16, 0, 0, 16, 16);
        const d = g.getImageData(0, 0, 16, 16).data; let s = 0, n = 0;
        for (let y = 2; y < 14; y++) for (let x = 2; x < 14; x++) { const i = 4 * (16 * y + x); s += (d[i] + d[i+1] + d[i+2]) / 3; n++; }
        return s / n; }""")
    return None if v is None else read_code(np.full((16, 16), v))


def _stored_photo(root, view_name):
    project = json.loads((root / "project.json").read_text())
    view = next(v for v in project["views"] if v["name"] == view_name)
    return cv2.imread(str(root / view["image"]))


def _wait(page, js, arg, errors):
    """:func:`gui_support.wait_until` that also keeps a screenshot of the page when it times out."""
    try:
        return wait_until(page, js, arg)
    except TimeoutError as e:
        page.screenshot(path="/tmp/gui_fail.png")
        raise AssertionError(f"{e}; view {page.evaluate('() => window.stillcapPuppet.view?.name')!r}, "
                             f"errors {errors}") from None


def _three_shot(page) -> np.ndarray:
    png = page.locator("#three-wrap canvas").screenshot()
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).astype(int)


def test_puppet_session(camera_browser, puppet_video, tmp_path):
    from gui_support import run_server

    root = tmp_path / "jumpingjack"
    root.mkdir()
    scene = puppet_video.scene
    with run_server(root) as server:
        ctx = camera_browser.new_context(viewport={"width": 1500, "height": 950}, accept_downloads=True)
        page = ctx.new_page()
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(server.page_url("puppet.html"))
        assert "token=" not in page.url  # the token went into the cookie, out of the address bar

        # a new project in the opened folder
        page.click("#new-project summary")
        page.click("#new-btn")
        wait_until(page, "() => document.getElementById('project-name').textContent.includes('0 photos')")
        assert (root / "project.json").is_file()

        # the camera, and a photo per angle: read the angle the turntable shows, choose it, take
        page.click("#camera-btn")
        wait_until(page, "() => document.getElementById('live').videoWidth > 0")
        verified: dict[int, str] = {}
        changes, last = 0, None  # bounded by turns of the turntable, not by the clock
        while len(verified) < 12:
            k = _video_code(page)
            if k != last:
                changes, last = changes + 1, k
            assert changes < 12 * 5, f"five turns and the 12 angles are not taken (verified {sorted(verified)})"
            if k is None or k in verified:
                page.wait_for_timeout(200)
                continue
            angle = round(puppet_video.angles_deg[k]) % 360  # read off the turntable's dial
            page.select_option("#angle-select", value=str(angle))
            page.evaluate("() => { document.getElementById('status').textContent = ''; }")
            page.click("#take-btn")
            _wait(page, "(a) => document.getElementById('status').textContent.startsWith('photo at')"
                        " && window.stillcapPuppet.view.angle_deg === a && !document.getElementById('take-btn').disabled",
                  angle, errors)
            name = page.evaluate("() => window.stillcapPuppet.view.name")
            if read_code(_stored_photo(root, name)) == k:  # the turntable did not move during the shot
                verified[k] = name
            # else: the photo shows another angle: it is retaken on the next pass (replace)
        tiles = page.locator("#angles button")
        assert tiles.count() == 12
        statuses = [tiles.nth(i).get_attribute("data-status") for i in range(12)]
        assert "missing" not in statuses, statuses

        # correct one bead: a marker the detection missed in a view where the truth says it is
        # visible, put at its true pixel by a click on the processed view
        project = json.loads((root / "project.json").read_text())
        names = list(scene.truth.marker_names)
        fix = None
        for k, vname in sorted(verified.items()):
            view = next(v for v in project["views"] if v["name"] == vname)
            others = np.array(list(view["detected"].values()) or [[1e9, 1e9]], float)
            for j, n in enumerate(names):
                xy = scene.truth.markers_px[k, j]
                if (n not in view["detected"] and scene.truth.visible[k, j]
                        and np.hypot(*(others - xy).T).min() > 20):  # a free spot: a click there places, not selects
                    fix = (k, vname, n, scene.truth.markers_px[k, j])
                    break
            if fix:
                break
        if fix is None:  # every visible bead found: move the one farthest from its true pixel there
            worst = max(((np.hypot(*(np.array(v["detected"][n]) - scene.truth.markers_px[k, names.index(n)])), k, v["name"], n)
                         for k, vname in verified.items() for v in project["views"] if v["name"] == vname
                         for n in v["detected"]), key=lambda t: t[0])
            _, k, vname, n = worst
            fix = (k, vname, n, scene.truth.markers_px[k, names.index(n)])
        k, vname, marker, xy = fix
        page.click(f"#angles button[data-angle='{round(puppet_video.angles_deg[k]) % 360}']")
        _wait(page, "(n) => window.stillcapPuppet.view && window.stillcapPuppet.view.name === n", vname, errors)
        page.select_option("#place-select", marker)
        canvas_click(page, "#photo", float(xy[0]), float(xy[1]), ["Shift"])  # placed even beside another bead
        _wait(page, "(m) => window.stillcapPuppet.view.markers.some(b => b.name === m && b.source === 'edited')"
                    " || document.getElementById('status').classList.contains('error')", marker, errors)
        assert "error" not in (page.get_attribute("#status", "class") or ""), page.inner_text("#status")
        view = next(v for v in json.loads((root / "project.json").read_text())["views"] if v["name"] == vname)
        edit = view["edits"][-1]
        assert edit["op"] == "move" and edit["marker"] == marker
        assert np.hypot(*(np.array(edit["xy"]) - xy)) < 1.5  # the click landed on the pixel meant
        page.click("#redetect-btn")  # the edit survives detection run again
        wait_until(page, "() => document.getElementById('status').textContent.startsWith('detected again')")
        view = next(v for v in json.loads((root / "project.json").read_text())["views"] if v["name"] == vname)
        assert view["edits"] and view["edits"][-1]["marker"] == marker

        # compute 3D in the background, with a progress bar; then look at it
        blank = _three_shot(page)
        page.click("#compute-btn")
        wait_until(page, "() => document.getElementById('status').textContent.startsWith('3D:')")
        assert page.evaluate("() => document.getElementById('progress').value") == 1
        shot = _three_shot(page)
        changed = np.abs(shot - blank).sum(axis=2) > 30
        assert changed.mean() > 0.002, f"the 3D view did not change after computing 3D ({changed.mean():.4%} of pixels)"
        assert shot.std() > 5
        import httpx

        result = httpx.get(f"{server.url}/api/puppet/result", headers={"X-Stillcap-Token": server.token}).json()
        assert page.locator("#angles-table tr").count() == 1 + len(result["joints"])  # the joint-angle table
        flags = page.locator("#flags").inner_text()
        for n in result["missing"]:  # markers seen fewer than twice are flagged on the page
            assert n in flags

        # pick a marker: click where three.js draws it
        target = page.evaluate("""() => {
            const s = window.stillcapPuppet.scene3d; const r = s.renderer.domElement.getBoundingClientRect();
            const m = s.scene.children.flatMap(c => c.children || []).find(o => o.userData && o.userData.kind === 'marker');
            const p = m.position.clone().project(s.camera);
            return {x: r.left + (p.x + 1) / 2 * r.width, y: r.top + (1 - p.y) / 2 * r.height, name: m.userData.name}; }""")
        page.mouse.click(target["x"], target["y"])
        wait_until(page, "(n) => document.getElementById('pick-info').textContent.startsWith('marker ')")

        # export, downloaded, opened by real readers
        files = {}
        for fmt in ("dae", "c3d", "gltf", "bvh"):
            with page.expect_download() as d:
                page.click(f"#exports button[data-format='{fmt}']")
            path = tmp_path / f"download.{fmt}"
            d.value.save_as(path)
            files[fmt] = path
        assert not errors, errors
        ctx.close()

    import collada
    import ezc3d
    import pygltflib

    dae = collada.Collada(str(files["dae"]))
    assert dae.scene is not None and len(list(dae.scene.objects("controller")) + list(dae.scene.nodes)) > 0
    c3d = ezc3d.c3d(str(files["c3d"]))
    labels = c3d["parameters"]["POINT"]["LABELS"]["value"]
    assert set(labels) == set(names)
    pts = c3d["data"]["points"][:3, :, 0]
    assert np.isfinite(pts[:, [labels.index(n) for n in names if n != "__none__"]]).sum() >= 3 * 10
    gltf = pygltflib.GLTF2().load(str(files["gltf"]))
    assert gltf.nodes and gltf.skins
    from stillcap.io.bvh_read import read_bvh

    bvh = read_bvh(files["bvh"])
    assert bvh is not None
