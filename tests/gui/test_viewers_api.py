"""The pitch and hand viewers' API (``/api/pitch``, ``/api/hand``) through the whole application:
what each endpoint answers for studio captures and results, and the refusals (paths outside the
opened folder, bad input) with a clear message and a 4xx status."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

import gui_support as vs


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A session folder: a pitch capture, a result of it in a report folder, a hand capture."""
    from stillcap.io.capture import Capture
    from stillcap.pipelines.pitch import analyse_pitch

    root = tmp_path_factory.mktemp("viewers-session")
    cap_dir = vs.render_pitch(root / "pitch-a", seed=1)
    res = analyse_pitch(Capture.load(cap_dir))
    (root / "report-a").mkdir()
    (root / "report-a" / "pitch.json").write_text(json.dumps(res.to_dict(), allow_nan=False))
    vs.render_hand(root / "hand-a", seed=2)
    (root / "notes.json").write_text('{"something": "else"}')
    return root


@pytest.fixture(scope="module")
def client(session):
    return vs.client(session)


def _result(session):
    return json.loads((session / "report-a" / "pitch.json").read_text())


# --------------------------------------------------------------------------------------------
# pitch
# --------------------------------------------------------------------------------------------
def test_pitch_items(client):
    items = {i["path"]: i for i in client.get("/api/pitch/items").json()["items"]}
    assert items["pitch-a"]["kind"] == "capture"
    assert items["report-a/pitch.json"]["kind"] == "result"
    assert "hand-a" not in items and "notes.json" not in items


def test_pitch_view_of_a_result(client, session):
    d = _result(session)
    v = client.get("/api/pitch/view", params={"path": "report-a/pitch.json"}).json()
    assert v["analysed"] and v["capture"] == "pitch-a" and not v["notes"]
    rows = {r["key"]: r for r in v["metrics"]}
    for k, val in d["metrics"].items():
        if k in ("nine_parameter", "success", "message"):
            continue
        assert rows[k]["value"] == val
        if isinstance(val, float):
            assert rows[k]["sigma"] == d["metrics_sigma"][k]
    assert rows["release_speed_mph"]["unit"] == "mph" and rows["spin_rate_rpm"]["unit"] == "rpm"
    # positions and error ellipsoids: the axes' outer products give back the covariance
    for p, q in zip(v["pairs"], d["pairs"]):
        assert np.allclose(p["positions"], q["positions"])
        for axes, cov in zip(p["ellipsoid_axes_m"], q["position_covariance_mm2"]):
            a = np.asarray(axes)
            np.testing.assert_allclose(a.T @ a, np.asarray(cov) * 1e-6, rtol=1e-9, atol=1e-15)
    # the reference trajectory: through the fitted positions, and on to the front of the plate
    traj = np.asarray(v["trajectory"]["positions"])
    fitted = np.asarray(d["reference_fit"]["positions"])
    gaps = np.linalg.norm(fitted[:, None] - traj[None], axis=2).min(axis=1)
    step = np.linalg.norm(np.diff(traj, axis=0), axis=1).max()
    assert gaps.max() < step
    assert traj[:, 1].min() <= 17 / 12 * 0.3048 < traj[:, 1].max()
    # the spin axis is the result's spin, normalised
    w = np.asarray(d["spin_reported"]["spin"])
    np.testing.assert_allclose(v["spin"]["axis"], w / np.linalg.norm(w))
    # cameras from the capture's rig and the balls on each photo
    assert [c["name"] for c in v["cameras"]] == ["front_top", "front_bottom", "back_left", "back_right"]
    for c in v["cameras"]:
        assert np.linalg.norm(np.asarray(c["corners"]).mean(axis=0) - c["center"]) == pytest.approx(0.6, rel=0.2)
    per_cam = {}
    for q in d["pairs"]:
        for cam, centers in zip(q["cameras"], q["centers_px"]):
            per_cam[cam] = [(f, c) for f, c in zip(q["flash_index"], centers) if c[0] is not None]
    for ph in v["photos"]:
        want = per_cam[ph["camera"]]
        assert len(ph["balls"]) == len(want) > 5
        assert [b["flash"] for b in ph["balls"]] == [f for f, _ in want]
        np.testing.assert_allclose([[b["x"], b["y"]] for b in ph["balls"]], [c for _, c in want])
        assert ph["markers"] == []  # a result file does not keep the painted markers
    assert v["plate"]["values"]["plate_x_ft"] == d["metrics"]["plate_x_ft"]


def test_pitch_capture_analysed_in_a_job(client, session):
    v = client.get("/api/pitch/view", params={"path": "pitch-a"}).json()
    assert not v["analysed"] and v["notes"] == ["not analysed yet"] and len(v["photos"]) == 4
    assert all(ph["balls"] == [] for ph in v["photos"])
    job = client.post("/api/pitch/analyse", json={"path": "pitch-a"})
    assert job.status_code == 202
    job = vs.wait_job(client, job.json())
    assert job["status"] == "done", job["error"]
    assert job["result"]["n_positions"] > 10
    v = client.get("/api/pitch/view", params={"path": "pitch-a"}).json()
    assert v["analysed"] and len(v["metrics"]) > 20
    n_markers = sum(len(ph["markers"]) for ph in v["photos"])
    assert n_markers > 20  # the painted markers found on the photos (in memory only)
    flashes = {ph["camera"]: {b["flash"] for b in ph["balls"]} for ph in v["photos"]}
    for ph in v["photos"]:
        assert {m["flash"] for m in ph["markers"]} <= flashes[ph["camera"]]
    assert next(i for i in client.get("/api/pitch/items").json()["items"] if i["path"] == "pitch-a")["analysed"]


def test_pitch_session(client, session):
    d = _result(session)
    s = client.get("/api/pitch/session", params={"path": ""}).json()
    rows = {r["path"]: r for r in s["rows"]}
    r = rows["report-a/pitch.json"]
    assert r["analysed"] and r["metrics"]["release_speed_mph"]["value"] == d["metrics"]["release_speed_mph"]
    assert r["n_positions"] == sum(len(p["positions"]) for p in d["pairs"])
    assert len(r["trajectory"]["positions"]) > 10
    assert {c["key"] for c in s["columns"]} >= {"release_speed_mph", "spin_rate_rpm", "induced_vertical_break_in"}


def test_pitch_photo(client):
    r = client.get("/api/pitch/photo", params={"path": "pitch-a/images/front_top.png", "w": 320})
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (240, 320, 3) and img.std() > 1
    full = client.get("/api/pitch/photo", params={"path": "pitch-a/images/front_top.png"})
    assert cv2.imdecode(np.frombuffer(full.content, np.uint8), cv2.IMREAD_COLOR).shape == (960, 1280, 3)


@pytest.mark.parametrize("route, params, status, match", [
    ("photo", {"path": "../outside.png"}, 400, "outside|'..'|leaves|parent"),
    ("photo", {"path": "/etc/passwd"}, 400, "absolute|outside"),
    ("photo", {"path": "pitch-a/capture.json"}, 400, "not a photo"),
    ("photo", {"path": "pitch-a/images/none.png"}, 404, "no such"),
    ("photo", {"path": "pitch-a/images/front_top.png", "w": "5"}, 400, "width must be"),
    ("photo", {"path": "pitch-a/images/front_top.png", "w": "big"}, 400, "whole number"),
    ("photo", {}, 400, "'path' is missing"),
    ("view", {"path": "../.."}, 400, "outside|'..'|parent"),
    ("view", {"path": "pitch-a/rig.json"}, 400, "not a pitch result"),
    ("view", {"path": "hand-a"}, 400, "not a pitch capture"),
    ("view", {"path": "nothing-here"}, 404, "no such"),
    ("session", {"path": "../"}, 400, "outside|'..'|parent"),
    ("session", {"path": "notes.json"}, 400, "not a folder"),
])
def test_pitch_refusals(client, route, params, status, match):
    import re

    r = client.get(f"/api/pitch/{route}", params=params)
    assert r.status_code == status
    assert re.search(match, r.json()["error"]), r.json()


@pytest.mark.parametrize("body, match", [
    (b'{"path": "report-a/pitch.json"}', "not a pitch capture"),
    (b'{"path": "../x"}', "outside|'..'|parent"),
    (b'{"path": 3}', "must be a string"),
    (b"[1, 2]", "must be a JSON object"),
    (b"{nope", "not JSON"),
])
def test_pitch_analyse_refusals(client, body, match):
    import re

    r = client.post("/api/pitch/analyse", content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and re.search(match, r.json()["error"]), r.json()


def test_token_required(session):
    from starlette.testclient import TestClient

    from stillcap.gui.app import create_app

    from stillcap.gui.context import GuiContext

    bare = TestClient(create_app(GuiContext(session.resolve(), vs.TEST_TOKEN)), base_url="http://127.0.0.1")
    assert bare.get("/api/pitch/items").status_code == 403
    assert bare.get("/api/hand/items").status_code == 403


# --------------------------------------------------------------------------------------------
# hand
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def hand_view(client):
    job = vs.wait_job(client, client.post("/api/hand/analyse", json={"path": "hand-a"}).json())
    assert job["status"] == "done", job["error"]
    return client.get("/api/hand/view", params={"path": "hand-a"}).json()


def test_hand_items_and_view(client, hand_view):
    items = {i["path"]: i for i in client.get("/api/hand/items").json()["items"]}
    assert items["hand-a"]["kind"] == "capture" and items["hand-a"]["analysed"]
    v = hand_view
    assert len(v["marker_names"]) == 18 and len(v["parents"]) == len(v["joint_names"]) == 21
    posed = [f for f in v["flashes"] if f["reconstructed"]]
    assert len(posed) >= 2 and all(f["joints"] is not None and len(f["joints"]) == 21 for f in posed)
    full_back = 0
    for f in posed:
        labels = [p["label"] for p in f["points"] if p["label"]]
        assert len(labels) == len(set(labels)) >= 6
        full_back += {"back.1", "back.2", "back.3"} <= set(labels)
    assert full_back >= 2  # the others were posed from their other markers and a neighbour (issue 12)
    anim = v["animation"]
    assert len(anim["times_s"]) == len(anim["joints"]) > 10 and np.all(np.diff(anim["times_s"]) > 0)
    assert v["overrides_file"] == "hand-a/label-overrides.json" and len(v["cameras"]) == 4
    assert v["ball"] is not None and v["release"]["success"]


def _a_labelled_point(view):
    f = next(f for f in view["flashes"] if f["reconstructed"])
    p = next(p for p in f["points"] if p["label"] and not p["label"].startswith("back"))
    return f["flash"], p


def test_hand_overrides_written_checked_and_applied(client, session, hand_view):
    from stillcap.body.hand_label import read_label_overrides

    path = session / "hand-a" / "label-overrides.json"
    got = client.get("/api/hand/overrides", params={"path": "hand-a"}).json()
    assert got["exists"] is False and got["overrides"] == []
    k, p = _a_labelled_point(hand_view)
    new = "little.nail" if p["label"] != "little.nail" else "ring.nail"
    r = client.put("/api/hand/overrides", json={"path": "hand-a", "overrides": [
        {"flash": k, "position_m": p["position"], "label": new}]})
    assert r.status_code == 200, r.json()
    read = read_label_overrides(path)  # the hand pipeline's own reader
    assert len(read) == 1 and read[0].flash == k and read[0].label == new
    np.testing.assert_allclose(read[0].position, p["position"])
    # analysed again: the GUI's analysis applies the file, and the point has its new label
    job = vs.wait_job(client, client.post("/api/hand/analyse", json={"path": "hand-a"}).json())
    assert job["status"] == "done", job["error"]
    v = client.get("/api/hand/view", params={"path": "hand-a"}).json()
    assert v["overrides_applied"]
    moved = [q for q in v["flashes"][k]["points"] if np.allclose(q["position"], p["position"], atol=1e-6)]
    assert [q["label"] for q in moved] == [new]
    client.put("/api/hand/overrides", json={"path": "hand-a", "overrides": []})
    assert read_label_overrides(path) == []


@pytest.mark.parametrize("entries, match", [
    ([{"flash": 0, "position_m": [0, 0, 0], "label": "pinky.tip"}], r"overrides.0.label: unknown marker 'pinky.tip'"),
    ([{"flash": -1, "position_m": [0, 0, 0], "label": "back.1"}], r"overrides.0.flash"),
    ([{"flash": 0, "position_m": [0, 0], "label": "back.1"}], r"overrides.0.position_m"),
    ([{"flash": 0, "position_m": [0, 0, float("nan")], "label": "back.1"}], r"overrides.0.position_m"),
    ([{"flash": 0, "position_m": [0, 0, 0], "label": "back.1", "delete": True}], "not both"),
    ([{"flash": 0, "position_m": [0, 0, 0]}], "either a 'label'"),
    ([{"flash": 0, "position_m": [0, 0, 0], "label": "back.1", "colour": "red"}], "unknown keys"),
    ("all", "must be a list"),
])
def test_hand_overrides_refused(client, session, entries, match):
    import re

    path = session / "hand-a" / "label-overrides.json"
    before = path.read_bytes() if path.exists() else None
    r = client.put("/api/hand/overrides", content=json.dumps({"path": "hand-a", "overrides": entries}),
                   headers={"Content-Type": "application/json", "X-Stillcap-Token": vs.TEST_TOKEN})
    assert r.status_code == 400 and re.search(match, r.json()["error"]), r.json()
    assert (path.read_bytes() if path.exists() else None) == before  # nothing written


@pytest.mark.parametrize("method, url, kw, status", [
    ("put", "/api/hand/overrides", {"json": {"path": "../elsewhere", "overrides": []}}, 400),
    ("put", "/api/hand/overrides", {"json": {"path": "pitch-a", "overrides": []}}, 400),
    ("get", "/api/hand/overrides", {"params": {"path": "../../etc"}}, 400),
    ("get", "/api/hand/view", {"params": {"path": "report-a/pitch.json"}}, 400),
    ("get", "/api/hand/view", {"params": {"path": "../"}}, 400),
    ("post", "/api/hand/analyse", {"json": {"path": "pitch-a"}}, 400),
    ("get", "/api/hand/view", {"params": {"path": "gone"}}, 404),
])
def test_hand_refusals(client, session, method, url, kw, status):
    r = getattr(client, method)(url, **kw)
    assert r.status_code == status and r.json()["error"]
    assert not (session.parent / "elsewhere").exists()


def test_hand_result_file_view(client, session, hand_view, tmp_path):
    """A hand.json (what stillcap hand --report writes) opens too: its labelled markers."""
    from stillcap.pipelines.hand import HandOptions, analyse_hand

    res = analyse_hand(session / "hand-a", HandOptions())
    (session / "hand-report").mkdir(exist_ok=True)
    (session / "hand-report" / "hand.json").write_text(json.dumps(res.to_dict(), allow_nan=False))
    v = client.get("/api/hand/view", params={"path": "hand-report/hand.json"}).json()
    d = res.to_dict()
    assert len(v["flashes"]) == len(d["flashes"]["times_s"])
    for f, markers in zip(v["flashes"], d["flashes"]["markers"]):
        assert len(f["points"]) == sum(1 for m in markers if m[0] is not None)
    assert v["parents"] is not None and v["overrides_file"] == "hand-report/label-overrides.json"
    assert not math.isnan(v["release"]["t0_s"])
