"""The command line: commands run, bad input exits 2 with a message naming the problem."""

import json
import subprocess
import sys


from support import run_cli as run


def test_studio_markers_then_markers_json(tmp_path, capsys):
    code, _, _ = run(["studio", "markers", "--out", str(tmp_path / "cap"), "--seed", "3", "--balls", "6"], capsys)
    assert code == 0
    code, out, _ = run(["markers", str(tmp_path / "cap"), "--json", "--out", str(tmp_path / "m.json")], capsys)
    assert code == 0
    res = json.loads(out)
    assert res == json.loads((tmp_path / "m.json").read_text())
    assert len(res["markers"]) >= 3
    assert all(m["error_mm"] < 1.5 and m["label"] in m["true_ball"] for m in res["markers"])


def test_bad_input_exits_2_with_a_message(tmp_path, capsys):
    code, _, err = run(["markers", str(tmp_path / "missing")], capsys)
    assert code == 2 and "missing" in err and "does not exist" in err
    code, _, err = run(["demo", "nothing"], capsys)
    assert code == 2 and "unknown demo 'nothing'" in err
    code, _, err = run(["calibrate", "intrinsics", "--bogus"], capsys)
    assert code == 2 and "--bogus" in err


def test_unknown_marker_set_exits_2_and_writes_nothing(tmp_path, capsys):
    code, _, err = run(["studio", "puppet", "--out", str(tmp_path / "cap"), "--seed", "1", "--markers", "nosuch"], capsys)
    assert code == 2 and "marker set 'nosuch' is neither a built-in" in err
    assert not (tmp_path / "cap").exists()
    code, _, err = run(["palette", "2", "--keep", "nosuch"], capsys)
    assert code == 2 and "--keep 'nosuch' is neither" in err


def test_python_dash_m_entry_point():
    r = subprocess.run([sys.executable, "-m", "stillcap", "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "calibrate" in r.stdout and "demo" in r.stdout
