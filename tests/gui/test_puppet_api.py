"""The puppet API without a browser: photos in, hand edits kept across re-detection, 3D with the
markers seen fewer than twice flagged, exports that real readers open."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from starlette.testclient import TestClient

from stillcap.gui.app import create_app
from stillcap.gui.context import GuiContext
from stillcap.gui.jobs import job_manager

H = {"X-Stillcap-Token": "t"}


@pytest.fixture(scope="module")
def scene():
    from stillcap.studio.puppet import puppet_scene

    return puppet_scene(rng=11, supersample=1)


def _client(root):
    ctx = GuiContext(root, "t")
    return ctx, TestClient(create_app(ctx, port=1), base_url="http://127.0.0.1:1", headers=H)


def _add(c, img, angle):
    r = c.post(f"/api/puppet/photo?angle={angle}", files={"file": ("p.png", cv2.imencode(".png", img)[1].tobytes())})
    assert r.status_code == 200, r.text
    return r.json()


def test_edits_survive_redetection_and_3d_flags_markers_seen_once(scene, tmp_path):
    ctx, c = _client(tmp_path)
    assert c.post("/api/puppet/new", json={"path": "jj"}).status_code == 200
    views = [_add(c, img, round(a) % 360) for img, a in zip(scene.images[:3], scene.truth.angles_deg[:3])]
    v = views[0]
    names = [m["name"] for m in v["markers"]]
    assert all(0 <= m["confidence"] <= 1 for m in v["markers"])
    a, b = names[0], names[1]
    # delete one, relabel another to the deleted name, move a third: three edits
    for body in ({"op": "delete", "marker": a}, {"op": "relabel", "marker": b, "to": a},
                 {"op": "move", "marker": names[2], "xy": [100.0, 120.0]}):
        r = c.post(f"/api/puppet/view/{v['name']}/edit", json=body)
        assert r.status_code == 200, r.text
    after = {m["name"]: m for m in r.json()["markers"]}
    assert b not in after and after[a]["source"] == "edited" and after[names[2]]["xy"] == [100.0, 120.0]
    r = c.post(f"/api/puppet/view/{v['name']}/redetect")
    again = {m["name"]: m for m in r.json()["markers"]}
    assert again[names[2]]["xy"] == [100.0, 120.0] and b not in again  # the edits still apply
    stored = json.loads((tmp_path / "jj" / "project.json").read_text())
    assert len(stored["views"][0]["edits"]) == 3
    # a bad edit is refused with its reason
    r = c.post(f"/api/puppet/view/{v['name']}/edit", json={"op": "relabel", "marker": "nope", "to": a})
    assert r.status_code == 400 and "nope" in r.json()["error"]
    # overview: 3 taken, 9 missing; one marked to retake
    c.post(f"/api/puppet/view/{views[1]['name']}/retake")
    st = c.get("/api/puppet/state").json()["project"]
    assert [x["status"] for x in st["angles"]].count("missing") == 9
    assert [x["status"] for x in st["angles"]].count("retake") >= 1
    # 3D from three views: a marker identified in only one view is flagged
    only_once = names[3]
    for w in views[1:]:
        if any(m["name"] == only_once for m in c.get(f"/api/puppet/view/{w['name']}").json()["markers"]):
            c.post(f"/api/puppet/view/{w['name']}/edit", json={"op": "delete", "marker": only_once})
    job = c.post("/api/puppet/reconstruct").json()
    job_manager(ctx).wait(job["id"], timeout=120)
    res = c.get(f"/api/jobs/{job['id']}").json()
    assert res["status"] == "done", res
    scene3d = res["result"]
    assert only_once in scene3d["missing"]
    flagged = next(m for m in scene3d["markers"] if m["name"] == only_once)
    assert flagged["missing"] and flagged["position"] is None
    assert len(scene3d["cameras"]) == 3 and len(scene3d["joints"]) > 10
    assert all(len(j["angles_deg"]) == 3 for j in scene3d["joints"])


def test_export_needs_3d_and_writes_inside_the_project(scene, tmp_path):
    ctx, c = _client(tmp_path)
    c.post("/api/puppet/new", json={"path": "."})
    r = c.get("/api/puppet/export/dae")
    assert r.status_code == 400 and "3D" in r.json()["error"]
    for img, a in zip(scene.images, scene.truth.angles_deg):
        _add(c, img, round(a) % 360)
    job = c.post("/api/puppet/reconstruct").json()
    job_manager(ctx).wait(job["id"], timeout=120)
    assert c.get(f"/api/jobs/{job['id']}").json()["status"] == "done"
    assert c.get("/api/puppet/export/exe").status_code == 400
    r = c.get("/api/puppet/export/glb")
    assert r.status_code == 200 and r.headers["content-disposition"].endswith('"pose.glb"')
    assert (tmp_path / "exports" / "pose.glb").read_bytes() == r.content
    import pygltflib

    g = pygltflib.GLTF2().load(str(tmp_path / "exports" / "pose.glb"))
    assert g.skins and len(g.skins[0].joints) > 10


def test_capture_import_refusals_and_reopening(tmp_path):
    """Import: paths leading out refused at once (400), a capture of another kind or a folder
    with no capture fails its job with one line naming it; an existing project is opened."""
    from gui_support import wait_job

    (tmp_path / "pitchcap").mkdir()
    (tmp_path / "pitchcap" / "capture.json").write_text(json.dumps(
        {"format": "stillcap-capture", "version": 1, "kind": "pitch", "images": []}))
    (tmp_path / "empty").mkdir()
    ctx, c = _client(tmp_path)
    for body in ({"capture": "../x"}, {"capture": "/etc"}, {"capture": "empty", "project": "../out"}):
        r = c.post("/api/puppet/import", json=body)
        assert r.status_code == 400 and "error" in r.json(), (body, r.text)
    job = wait_job(c, c.post("/api/puppet/import", json={"capture": "empty"}).json())
    assert job["status"] == "failed" and "'empty' holds no capture" in job["error"]
    job = wait_job(c, c.post("/api/puppet/import", json={"capture": "pitchcap"}).json())
    assert job["status"] == "failed" and "pitchcap" in job["error"] and "not a puppet capture" in job["error"], job["error"]
    assert c.get("/api/puppet/state").json()["captures"] == []  # a pitch capture is not offered
    assert c.post("/api/puppet/new", json={"path": "proj"}).status_code == 200
    job = wait_job(c, c.post("/api/puppet/import", json={"capture": "empty", "project": "proj"}).json())
    assert job["status"] == "done" and job["result"] == {"project": "proj", "imported": False}
