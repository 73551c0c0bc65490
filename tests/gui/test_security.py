"""The GUI's security: another origin, no token, a wrong host, a path outside the opened folder
and an oversized or forged upload are refused; pages carry their security headers; the server
answers on 127.0.0.1 only."""

from __future__ import annotations

import json
import socket

import cv2
import httpx
import numpy as np
import pytest
from starlette.testclient import TestClient

from stillcap.gui.app import create_app
from stillcap.gui.context import GuiContext

PORT = 8391
TOKEN = "s3cret-token"


@pytest.fixture
def client(tmp_path):
    root = tmp_path / "work"
    root.mkdir()
    (tmp_path / "secret.txt").write_text("outside")
    app = create_app(GuiContext(root, TOKEN), port=PORT, max_upload_bytes=200_000)
    with TestClient(app, base_url=f"http://127.0.0.1:{PORT}") as c:
        yield c


H = {"X-Stillcap-Token": TOKEN}


def test_api_needs_the_token(client):
    assert client.get("/api/info").status_code == 403
    assert client.get("/api/info", headers={"X-Stillcap-Token": "wrong"}).status_code == 403
    assert client.get("/api/info", headers=H).status_code == 200
    assert client.post("/api/puppet/new", json={"path": "p"}).status_code == 403
    assert client.get("/api/puppet/state", headers=H).json()["project"] is None  # nothing was made


def test_pages_need_the_token_then_keep_it_in_an_httponly_cookie(client):
    assert client.get("/puppet.html").status_code == 403
    assert client.get("/vendor/three/three.module.min.js").status_code == 403
    assert client.get("/puppet.html?token=wrong", follow_redirects=False).status_code == 403
    r = client.get("/puppet.html?token=" + TOKEN, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/puppet.html"  # the token leaves the address bar
    r = client.get(f"/index.html?token={TOKEN}&stay&item=a/b.json", follow_redirects=False)
    assert r.headers["location"] == "/index.html?stay=&item=a%2Fb.json"  # the rest of the query kept, blank ones too
    cookie = r.headers["set-cookie"].lower()
    assert "httponly" in cookie and "samesite=strict" in cookie
    page = client.get("/puppet.html")
    assert page.status_code == 200
    csp = page.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in csp and "script-src 'self' 'nonce-" in csp
    assert page.headers["x-content-type-options"] == "nosniff"
    assert client.get("/vendor/three/three.module.min.js").status_code == 200
    # the cookie authorises reading, never changing: a POST needs the header
    assert client.get("/api/info").status_code == 200
    assert client.post("/api/puppet/new", json={"path": "p"}).status_code == 403


def test_another_origin_is_refused(client):
    for headers in ({"Origin": "http://evil.example"}, {"Origin": "http://localhost:1234"},
                    {"Sec-Fetch-Site": "cross-site"}, {"Sec-Fetch-Site": "same-site"}):
        r = client.post("/api/puppet/new", json={"path": "p"}, headers={**H, **headers})
        assert r.status_code == 403, headers
    assert client.get("/api/info", headers={**H, "Origin": f"http://127.0.0.1:{PORT}",
                                            "Sec-Fetch-Site": "same-origin"}).status_code == 200


@pytest.mark.parametrize("host", ["evil.example", f"evil.example:{PORT}", "127.0.0.1:9", f"192.168.1.5:{PORT}",
                                  f"localhost.evil.example:{PORT}"])
def test_another_host_is_refused_dns_rebinding(client, host):
    assert client.get("/api/info", headers={**H, "Host": host}).status_code == 403


def test_localhost_by_name_is_served(client):
    assert client.get("/api/info", headers={**H, "Host": f"localhost:{PORT}"}).status_code == 200


@pytest.mark.parametrize("path", ["../outside", "/etc", "a/../../x", "..", "sub/../../secret.txt"])
def test_a_path_outside_the_opened_folder_is_refused(client, path):
    for route in ("/api/puppet/new", "/api/puppet/open"):
        r = client.post(route, json={"path": path}, headers=H)
        assert r.status_code == 400, (route, path, r.text)
        assert "error" in r.json()


def test_a_symlink_out_of_the_folder_is_refused(tmp_path):
    root = tmp_path / "work"
    root.mkdir()
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (root / "link").symlink_to(outside, target_is_directory=True)
    with TestClient(create_app(GuiContext(root, TOKEN), port=PORT), base_url=f"http://127.0.0.1:{PORT}") as c:
        r = c.post("/api/puppet/new", json={"path": "link/p"}, headers=H)
        assert r.status_code == 400 and "outside" in r.json()["error"]
    assert not (outside / "p").exists()


def test_static_files_stay_in_the_static_folder(client):
    client.get("/?token=" + TOKEN)
    for p in ("/../app.py", "/..%2fapp.py", "/vendor/../../app.py", "/%2e%2e/app.py"):
        r = client.get(p)
        assert r.status_code in (403, 404), p
        assert "create_app" not in r.text


def _png(w=640, h=480):
    return cv2.imencode(".png", np.zeros((h, w, 3), np.uint8))[1].tobytes()


def test_oversized_upload_is_refused(client):
    client.post("/api/puppet/new", json={"path": "."}, headers=H)
    big = b"\0" * 300_000
    r = client.post("/api/puppet/photo?angle=0", files={"file": ("x.png", big)}, headers=H)
    assert r.status_code == 413

    def chunks():  # no Content-Length: counted while read
        for _ in range(40):
            yield b"x" * 10_000

    r = client.post("/api/puppet/photo?angle=0", content=chunks(),
                    headers={**H, "Content-Type": "multipart/form-data; boundary=b"})
    assert r.status_code == 413
    assert client.get("/api/puppet/state", headers=H).json()["project"]["views"] == []


def test_uploads_are_decoded_safely(client):
    client.post("/api/puppet/new", json={"path": "."}, headers=H)
    # a PNG header claiming 60000 x 60000 pixels is refused before decoding
    png = bytearray(_png(8, 8))
    png[16:24] = (60000).to_bytes(4, "big") * 2
    r = client.post("/api/puppet/photo?angle=0", files={"file": ("huge.png", bytes(png))}, headers=H)
    assert r.status_code == 400 and "huge.png" in r.json()["error"]
    r = client.post("/api/puppet/photo?angle=0", files={"file": ("cut.png", _png()[:-30])}, headers=H)
    assert r.status_code == 400 and "cut.png" in r.json()["error"]
    r = client.post("/api/puppet/photo?angle=0", files={"file": ("a.png", b"<html>not an image</html>")}, headers=H)
    assert r.status_code == 400
    r = client.post("/api/puppet/photo?angle=0", files={"file": ("small.png", _png(320, 240))}, headers=H)
    assert r.status_code == 400 and "320" in r.json()["error"]  # not the camera's size
    assert client.get("/api/puppet/state", headers=H).json()["project"]["views"] == []
    r = client.post("/api/puppet/photo?angle=0", files={"file": ("ok.png", _png())}, headers=H)
    assert r.status_code == 200


def test_server_camera_takes_an_index_never_a_path(client):
    client.post("/api/puppet/new", json={"path": "."}, headers=H)
    for source in ("/etc/passwd", "../x.mp4", "-1", "1e3"):
        r = client.post(f"/api/puppet/server-camera?source={source}&angle=0", headers=H)
        assert r.status_code == 400 and "index" in r.json()["error"]


def test_the_cli_listens_on_127_0_0_1_only(tmp_path):
    """``stillcap gui --no-browser`` prints a 127.0.0.1 URL with the token and serves only there."""
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "stillcap", "gui", str(tmp_path), "--no-browser"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = ""
        for _ in range(20):
            line = proc.stdout.readline()
            if "http://" in line:
                break
        url = line[line.index("http://"):].split()[0]
        assert url.startswith("http://127.0.0.1:") and "token=" in url
        port = int(url.split(":")[2].split("/")[0])
        for _ in range(100):
            try:
                r = httpx.Client(follow_redirects=True).get(url)
                break
            except httpx.ConnectError:
                time.sleep(0.1)
        assert r.status_code == 200
        listening = [c for c in _listening(proc.pid) if c[1] == port]
        assert listening and all(addr == "127.0.0.1" for addr, _ in listening), listening
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _listening(pid):
    """``(address, port)`` of the TCP sockets in LISTEN state (from /proc/net/tcp)."""
    out = []
    try:
        lines = open("/proc/net/tcp").read().splitlines()[1:]
    except OSError:
        pytest.skip("no /proc/net/tcp on this system")
    for line in lines:
        parts = line.split()
        local, state = parts[1], parts[3]
        if state == "0A":
            ip_hex, port_hex = local.split(":")
            ip = socket.inet_ntoa(bytes.fromhex(ip_hex)[::-1])
            out.append((ip, int(port_hex, 16)))
    return out


def test_jobs_report_progress_and_errors(tmp_path):
    from stillcap.gui.jobs import JobManager

    jm = JobManager()

    def work(progress, n):
        for i in range(n):
            progress(i + 1, n, f"step {i}")
        return {"n": n}

    def bad(progress):
        raise ValueError("photo turn_030.0deg is unreadable")

    ok, fail = jm.submit(work, 3, label="w"), jm.submit(bad, label="b")
    assert jm.wait(ok.id).as_json()["result"] == {"n": 3} and ok.done == 3 and ok.step == "step 2"
    assert jm.wait(fail.id).status == "failed" and fail.error == "photo turn_030.0deg is unreadable"
    json.dumps([j.as_json() for j in jm.all()])
    jm.shutdown()
