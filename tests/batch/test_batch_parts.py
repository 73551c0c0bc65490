"""The batch's parts without a cluster: inputs and their hash, the table, bad input; and one
small batch on the default local cluster."""

import json
import shutil

import pytest

from support import run_cli as run

pq = pytest.importorskip("pyarrow.parquet")


@pytest.fixture(scope="module")
def markers_capture(tmp_path_factory):
    from stillcap.cli import main

    root = tmp_path_factory.mktemp("batch-parts") / "scene"
    main(["studio", "markers", "--out", str(root), "--seed", "3", "--balls", "4"])
    return root


def test_content_hash_follows_the_inputs_not_the_place(markers_capture, tmp_path):
    from stillcap.batch import content_hash, read_inputs

    copy = tmp_path / "elsewhere"
    shutil.copytree(markers_capture, copy)
    a, b = read_inputs([markers_capture, copy])
    assert a.kind == "markers" and a.pitch_type == "" and "rig.json" in a.files and "truth.json" in a.files
    assert b.name == "elsewhere"
    h = content_hash(a, {"x": 1})
    assert content_hash(b, {"x": 1}) == h  # moved: same inputs
    assert content_hash(a, {"x": 2}) != h  # other options
    photo = copy / a.files[-1]
    data = bytearray(photo.read_bytes())
    data[len(data) // 2] ^= 1
    photo.write_bytes(bytes(data))
    assert content_hash(b, {"x": 1}) != h  # one bit of one photo


def test_same_folder_names_get_distinct_names(markers_capture, tmp_path):
    from stillcap.batch import read_inputs

    shutil.copytree(markers_capture, tmp_path / "a" / "scene")
    shutil.copytree(markers_capture, tmp_path / "b" / "scene")
    names = [i.name for i in read_inputs([tmp_path / "a" / "scene", tmp_path / "b" / "scene", tmp_path / "a" / "scene"])]
    assert names == ["scene", "scene-2"]


def test_capture_list_file(markers_capture, tmp_path):
    from stillcap.batch import read_capture_list

    lst = tmp_path / "list.txt"
    lst.write_text(f"# a session\n\n{markers_capture}\nrelative/cap\n")
    assert read_capture_list(lst) == [markers_capture, tmp_path / "relative" / "cap"]


def test_table_round_trip(tmp_path):
    from stillcap.batch import read_rows, write_rows

    rows = [{"capture": "/a", "name": "a", "kind": "pitch", "pitch_type": "FF", "status": "ok", "error": None,
             "content_hash": "0" * 64, "seconds": 1.5, "worker": "w", "json_file": "captures/a/pitch.json",
             "release_speed_mph": 90.5, "release_speed_mph_sigma": 0.1, "spin_tilt": "1:00", "ball_positions": 23},
            {"capture": "/b", "name": "b", "kind": "markers", "pitch_type": "", "status": "error", "error": "bad",
             "content_hash": "1" * 64, "seconds": 0.2, "worker": "w", "json_file": None, "markers": 3}]
    write_rows(tmp_path / "t.parquet", rows)
    t = pq.read_table(tmp_path / "t.parquet")
    assert str(t.schema.field("ball_positions").type) == "int64" and str(t.schema.field("seconds").type) == "double"
    back = read_rows(tmp_path / "t.parquet")
    assert back[0]["release_speed_mph"] == 90.5 and back[0]["markers"] is None and back[1]["spin_tilt"] is None
    (tmp_path / "x.parquet").write_text("not parquet")
    with pytest.raises(ValueError, match="x.parquet: not a readable Parquet file"):
        read_rows(tmp_path / "x.parquet")


@pytest.mark.parametrize("case, message", [
    ("missing", "capture folder .*missing does not exist"),
    ("not-a-capture", "capture.json does not exist"),
    ("chessboard", "kind: 'chessboard' is not a kind the batch analyses"),
    ("none", "no captures"),
])
def test_bad_input_exits_2_before_any_work(case, message, tmp_path, capsys):
    import re

    folder = tmp_path / case
    if case == "not-a-capture":
        folder.mkdir()
    if case == "chessboard":
        folder.mkdir()
        (folder / "capture.json").write_text(json.dumps({"kind": "chessboard", "images": []}))
    args = ["batch", "--out", tmp_path / "out"] + ([] if case == "none" else [folder])
    code, _, err = run(args, capsys)
    assert code == 2 and re.search(message, err), err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_unreachable_scheduler_exits_2(markers_capture, tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code, _, err = run(["batch", markers_capture, "--scheduler", f"tcp://127.0.0.1:{port}", "--out", tmp_path / "o"],
                       capsys)
    assert code == 2 and "cannot reach the Dask scheduler" in err and len(err.strip().splitlines()) == 1


def test_local_cluster_by_default(markers_capture, tmp_path, capsys):
    code, _, err = run(["batch", markers_capture, "--workers", "1", "--out", tmp_path / "out"], capsys)
    assert code == 0, err
    assert "on 1 Dask worker(s)" in err and "1 analysed" in err
    rows = pq.read_table(tmp_path / "out" / "results.parquet").to_pylist()
    assert [r["status"] for r in rows] == ["ok"]
    doc = json.loads((tmp_path / "out" / rows[0]["json_file"]).read_text())
    assert rows[0]["markers"] == len(doc["markers"]) >= 3
