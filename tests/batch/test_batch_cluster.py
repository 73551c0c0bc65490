"""`stillcap batch` on a real cluster: a scheduler and two workers started as separate processes on
127.0.0.1 (Dask's own command-line tools), a batch of every kind of capture rendered here, the
Parquet table read back with pyarrow and checked against the per-capture JSON, resume, and a
broken capture isolated."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support import run_cli as run, studio_pitch, untimed

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
distributed = pytest.importorskip("distributed")


def _set_meta(folder: Path, **meta):
    d = json.loads((folder / "capture.json").read_text())
    d.update(meta)
    (folder / "capture.json").write_text(json.dumps(d, indent=2))


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Six studio captures, rendered here: two pitches (pitch types FF and CU), a hand, a puppet,
    and two marker scenes, the first photo of the second one cut short."""
    from stillcap.cli import main
    from stillcap.studio.hand import hand_capture

    root = tmp_path_factory.mktemp("batch-captures")
    ff = studio_pitch(tmp_path_factory, "batch-ff", preset="seed-4seam", seed=1)
    cu = studio_pitch(tmp_path_factory, "batch-cu", preset="seed-curveball", seed=2)
    out = {"ff": root / "ff", "cu": root / "cu"}
    shutil.copytree(ff, out["ff"])
    shutil.copytree(cu, out["cu"])
    _set_meta(out["ff"], pitch_type="FF")
    _set_meta(out["cu"], pitch_type="CU")
    hc = hand_capture(2, image_size=(1280, 960))
    cap, images = hc.to_capture(".jpg")
    cap.save(root / "hand", images, jpeg_quality=92)
    out["hand"] = root / "hand"
    main(["studio", "puppet", "--out", str(root / "puppet"), "--pose", "tpose", "--seed", "2", "--views", "6",
          "--step-deg", "60"])
    out["puppet"] = root / "puppet"
    main(["studio", "markers", "--out", str(root / "markers"), "--seed", "3", "--balls", "6"])
    out["markers"] = root / "markers"
    main(["studio", "markers", "--out", str(root / "broken"), "--seed", "4", "--balls", "5"])
    photo = sorted((root / "broken" / "images").iterdir())[0]
    out["broken_bytes"] = photo.read_bytes()
    photo.write_bytes(out["broken_bytes"][: len(out["broken_bytes"]) // 3])
    out["broken"] = root / "broken"
    out["broken_photo"] = photo
    return out


def _env():
    """The test's stillcap on the workers' path (the source tree when it is not installed)."""
    import stillcap

    src = str(Path(stillcap.__file__).resolve().parents[1])
    return dict(os.environ, PYTHONPATH=os.pathsep.join([src, os.environ.get("PYTHONPATH", "")]))


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """A scheduler and two single-thread workers, each its own process (``dask scheduler`` and
    ``dask worker`` of distributed's CLI), on 127.0.0.1; the scheduler's address."""
    folder = tmp_path_factory.mktemp("dask")
    sfile = folder / "scheduler.json"
    procs = []
    logs = []

    def start(*args):
        log = open(folder / f"log-{len(procs)}.txt", "w")
        logs.append(log)
        procs.append(subprocess.Popen([sys.executable, "-m", *args], cwd=folder, env=_env(), stdout=log,
                                      stderr=subprocess.STDOUT))

    try:
        start("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(sfile))
        deadline = time.monotonic() + 120
        while not sfile.is_file() and time.monotonic() < deadline:
            assert procs[0].poll() is None, (folder / "log-0.txt").read_text()
            time.sleep(0.2)
        for _ in range(2):
            start("distributed.cli.dask_worker", "--scheduler-file", str(sfile), "--nthreads", "1", "--nworkers", "1",
                  "--no-dashboard", "--host", "127.0.0.1", "--local-directory", str(folder))
        with distributed.Client(scheduler_file=str(sfile), timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
            address = c.scheduler.address
            # each worker its own process, not the scheduler's
            pids = c.run(os.getpid)
            assert len(set(pids.values())) == 2 and procs[0].pid not in pids.values()
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        for log in logs:
            log.close()


def _table(out: Path) -> dict:
    t = pq.read_table(out / "results.parquet")
    return {r["name"]: r for r in t.to_pylist()}


def test_batch_of_every_kind_on_a_cluster(captures, scheduler, tmp_path, capsys):
    out = tmp_path / "results"
    folders = [captures[k] for k in ("ff", "cu", "hand", "puppet", "markers", "broken")]
    code, stdout, err = run(["batch", *folders, "--scheduler", scheduler, "--out", out], capsys)
    assert code == 1, err  # one capture failed: after the batch, non-zero
    assert "5 analysed, 0 skipped (already done), 1 failed" in err
    assert "dashboard: " in err
    rows = _table(out)
    assert set(rows) == {"ff", "cu", "hand", "puppet", "markers", "broken"}
    # the failure is isolated and named: its row says why in one line, naming the photo
    bad = rows["broken"]
    assert bad["status"] == "error" and bad["json_file"] is None
    assert captures["broken_photo"].name in bad["error"] and "\n" not in bad["error"]
    assert captures["broken_photo"].name in err
    for name in ("ff", "cu", "hand", "puppet", "markers"):
        r = rows[name]
        assert r["status"] == "ok" and r["error"] is None, r
        assert len(r["content_hash"]) == 64 and r["seconds"] > 0 and r["worker"].startswith("tcp://127.0.0.1:")
    assert rows["ff"]["kind"] == "pitch" and rows["ff"]["pitch_type"] == "FF" and rows["cu"]["pitch_type"] == "CU"
    # the table against the per-capture JSON (read by json, not by the batch's code)
    for name in ("ff", "cu"):
        doc = json.loads((out / rows[name]["json_file"]).read_text())
        assert rows[name]["json_file"] == f"captures/{name}/pitch.json"
        for k in ("release_speed_mph", "spin_rate_rpm", "induced_vertical_break_in", "horizontal_break_in",
                  "release_extension_ft"):
            assert rows[name][k] == doc["metrics"][k]
            assert rows[name][f"{k}_sigma"] == doc["metrics_sigma"][k] and rows[name][f"{k}_sigma"] > 0
        assert rows[name]["spin_tilt"] == doc["metrics"]["spin_tilt"]
    hand = json.loads((out / rows["hand"]["json_file"]).read_text())
    assert rows["hand"]["release_speed_mph"] == hand["release"]["speed_mph"]
    assert rows["hand"]["release_speed_mph_sigma"] == hand["release"]["speed_sigma_mph"]
    assert rows["hand"]["poses"] == sum(hand["flashes"]["reconstructed"])
    puppet = json.loads((out / "captures/puppet/result.json").read_text())
    assert rows["puppet"]["markers"] == len(puppet["markers"]) and puppet["format"] == "stillcap-puppet-result"
    assert rows["puppet"]["pose_fit_rms_mm"] == pytest.approx(puppet["pose_fit"]["rms_m"] * 1e3, rel=1e-12)
    markers = json.loads((out / "captures/markers/markers.json").read_text())
    assert rows["markers"]["markers"] == len(markers["markers"]) >= 3
    # the units are in the column names, the schema is typed
    schema = pq.read_schema(out / "results.parquet")
    assert schema.field("release_speed_mph").type == pa.float64() and schema.field("spin_tilt").type == pa.string()
    # the per-capture JSON is what the kind's own command prints (wall-clock times aside), run as
    # a user runs it
    single = subprocess.run([sys.executable, "-m", "stillcap", "pitch", str(captures["ff"]), "--json"],
                            capture_output=True, text=True, env=_env())
    assert single.returncode == 0, single.stderr
    a, b = json.loads(single.stdout), json.loads((out / "captures/ff/pitch.json").read_text())
    assert untimed(a) == untimed(b)  # digit for digit
    # the session summary: per pitch type, with its plots
    summary = (out / "summary.md").read_text()
    assert "| FF | 1 |" in summary and "| CU | 1 |" in summary and "Failed captures" in summary
    import cv2

    for png in ("summary_movement.png", "summary_speed.png"):
        assert cv2.imread(str(out / png)) is not None

    # resume: what is done is skipped (same rows, same seconds); a changed capture and the
    # repaired one are analysed again
    before = rows
    _set_meta(captures["cu"], pitch_type="SL")
    captures["broken_photo"].write_bytes(captures["broken_bytes"])
    code, _, err = run(["batch", *folders, "--scheduler", scheduler, "--out", out], capsys)
    assert code == 0, err
    assert "2 analysed, 4 skipped (already done), 0 failed" in err
    rows = _table(out)
    for name in ("ff", "hand", "puppet", "markers"):
        assert rows[name] == before[name]
    assert rows["cu"]["pitch_type"] == "SL" and rows["cu"]["content_hash"] != before["cu"]["content_hash"]
    assert rows["cu"]["release_speed_mph"] == before["cu"]["release_speed_mph"]
    assert rows["broken"]["status"] == "ok" and rows["broken"]["json_file"] == "captures/broken/markers.json"
    assert "| SL | 1 |" in (out / "summary.md").read_text()
