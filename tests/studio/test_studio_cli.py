"""`stillcap studio ...` writes valid capture folders."""

import pytest

from stillcap.cli import main
from stillcap.io.capture import Capture


def test_chessboard_command_writes_a_capture(tmp_path):
    out = tmp_path / "cb"
    main(["studio", "chessboard", "--out", str(out), "--seed", "3", "--views", "2", "--pattern", "7x5",
          "--size", "640x480"])
    cap = Capture.load(out)
    assert cap.kind == "chessboard" and len(cap.images) == 2 and cap.rig[0].image_size == (640, 480)
    assert cap.meta["target"] == {"type": "chessboard", "cols": 7, "rows": 5, "square": 0.025, "margin": 1.0}
    assert len(cap.truth["views"]) == 2 and len(cap.truth["views"][0]["corners_px"]) == 35
    cap.verify()


def test_charuco_and_jpeg(tmp_path):
    out = tmp_path / "ch"
    main(["studio", "chessboard", "--out", str(out), "--seed", "1", "--views", "1", "--charuco", "--jpeg", "90"])
    cap = Capture.load(out)
    assert cap.kind == "charuco" and cap.images[0].file.endswith(".jpg")
    assert cap.read_image(0).shape == (960, 1280, 3)


def test_markers_command_is_reproducible(tmp_path):
    for name in ("a", "b"):
        main(["studio", "markers", "--out", str(tmp_path / name), "--seed", "4", "--cameras", "2", "--balls", "3",
              "--size", "640x480"])
    a, b = Capture.load(tmp_path / "a"), Capture.load(tmp_path / "b")
    assert a.kind == "markers" and a.rig.names == ["cam0", "cam1"]
    assert a.truth == b.truth
    assert (a.read_image(1) == b.read_image(1)).all()


def test_bad_size_is_a_user_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["studio", "markers", "--out", str(tmp_path / "y"), "--size", "big"])
    assert e.value.code == 2 and "--size" in capsys.readouterr().err


def test_refuses_to_overwrite(tmp_path, capsys):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep.txt").write_text("mine")
    with pytest.raises(SystemExit) as e:
        main(["studio", "markers", "--out", str(tmp_path / "x"), "--balls", "1", "--cameras", "1"])
    assert e.value.code == 2
    assert "not empty" in capsys.readouterr().err
