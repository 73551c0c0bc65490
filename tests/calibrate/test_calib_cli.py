"""`stillcap calibrate ...` end to end on the real photos, through stillcap.cli.main."""

import json

import numpy as np
import pytest

from stillcap.camera import Rig
from stillcap.cli import main


def run(capsys, *args):
    main(list(map(str, args)))
    return capsys.readouterr().out


def fail(capsys, *args):
    with pytest.raises(SystemExit) as e:
        main(list(map(str, args)))
    return e.value.code, capsys.readouterr().err


def test_intrinsics_json(capsys, stereo_dir, tmp_path):
    left = sorted(stereo_dir.glob("left*.jpg"))
    out = tmp_path / "left.json"
    d = json.loads(run(capsys, "calibrate", "intrinsics", *left, "--pattern", "9x6", "--square", "1",
                       "--name", "left", "--json", "--out", out))
    assert set(d) == {"rms_px", "fx", "fy", "cx", "cy", "dist", "image_size", "images_used", "images_skipped",
                      "per_image_rms_px", "outlier_views", "without_outliers", "response"}
    assert d["rms_px"] <= 0.409 and abs(d["fx"] - 536.07) < 0.02 and len(d["dist"]) == 5
    assert d["image_size"] == [640, 480] and len(d["images_used"]) == 13 and d["images_skipped"] == {}
    assert Rig.load(out).names == ["left"]


def test_intrinsics_human_output_lists_skipped_images(capsys, stereo_dir, tmp_path):
    blank = tmp_path / "blank.png"
    import cv2

    cv2.imwrite(str(blank), np.full((480, 640), 200, np.uint8))
    text = run(capsys, "calibrate", "intrinsics", *sorted(stereo_dir.glob("right0*.jpg")), blank, "--square", "1")
    assert "right01.jpg" in text and "blank.png" in text and "9x6 chessboard not found" in text
    assert "fx 543.06" in text and "RMS" in text  # 9 of the 13 right images


def test_stereo_json_and_rig_file(capsys, stereo_dir, tmp_path):
    out = tmp_path / "stereo.json"
    d = json.loads(run(capsys, "calibrate", "stereo", *sorted(stereo_dir.glob("*.jpg")), "--square", "1",
                       "--json", "--out", out))
    assert d["rms_px"] <= 0.448 and abs(d["baseline"] - 3.345) < 0.0335
    assert np.asarray(d["R"]).shape == (3, 3) and len(d["T"]) == 3
    assert d["left"]["rms_px"] <= 0.409 and d["right"]["rms_px"] <= 0.459
    rig = Rig.load(out)
    assert rig.names == ["left", "right"] and abs(np.linalg.norm(rig["right"].center) - 3.345) < 0.0335


def test_rig_folder_json(capsys, stereo_dir, tmp_path):
    for side in ("left", "right"):
        (tmp_path / "rig" / side).mkdir(parents=True)
        for p in stereo_dir.glob(f"{side}*.jpg"):
            (tmp_path / "rig" / side / p.name.replace(side, "")).symlink_to(p)
    known = tmp_path / "stereo.json"
    run(capsys, "calibrate", "stereo", *sorted(stereo_dir.glob("*.jpg")), "--square", "1", "--out", known)
    out = tmp_path / "rig.json"
    d = json.loads(run(capsys, "calibrate", "rig", tmp_path / "rig", "--square", "1", "--intrinsics", known,
                       "--json", "--out", out))
    assert [c["name"] for c in d["cameras"]] == ["left", "right"] and d["success"]
    assert d["rms_px"] < 0.5 and len(d["instants_used"]) == 13
    assert abs(np.linalg.norm(d["cameras"][1]["center"]) - 3.345) < 0.0335
    assert Rig.load(out).names == ["left", "right"]
    text = run(capsys, "calibrate", "rig", tmp_path / "rig", "--square", "1", "--intrinsics", known)
    assert "bundle adjustment" in text


def test_cli_errors_exit_2(capsys, tmp_path, stereo_dir):
    code, err = fail(capsys, "calibrate", "intrinsics", tmp_path / "missing.jpg")
    assert code == 2 and "missing.jpg" in err and "does not exist" in err
    code, err = fail(capsys, "calibrate", "stereo", stereo_dir / "left01.jpg", stereo_dir / "right02.jpg")
    assert code == 2 and "no partner for left01.jpg, right02.jpg" in err
    code, err = fail(capsys, "calibrate", "intrinsics", stereo_dir / "left01.jpg", "--charuco", "--dict", "NOPE")
    assert code == 2 and "unknown ArUco dictionary" in err
    code, err = fail(capsys, "calibrate", "intrinsics", stereo_dir / "left01.jpg", "--pattern", "9by6")
    assert code == 2 and "pattern must look like 9x6" in err
    code, err = fail(capsys, "calibrate", "rig", tmp_path / "nothing")
    assert code == 2 and "does not exist" in err


def test_charuco_intrinsics_from_rendered_photos(capsys, tmp_path, synth):
    import cv2

    from stillcap.calibrate import CharucoTarget

    board = CharucoTarget(7, 5, 0.03, 0.022)
    cam = synth.make_camera(dist=(0, 0, 0, 0, 0))
    paths = []
    for i, T in enumerate(synth.board_poses(cam, board.object_points(), 6, np.random.default_rng(9),
                                            depth=(0.3, 0.5), margin=50)):
        paths.append(tmp_path / f"view{i}.png")
        cv2.imwrite(str(paths[-1]), synth.render_plane(board.texture(64), board.extent, T, cam))
    d = json.loads(run(capsys, "calibrate", "intrinsics", *paths, "--charuco", "--squares", "7x5",
                       "--square", "0.03", "--marker", "0.022", "--json"))
    assert len(d["images_used"]) == 6 and d["rms_px"] < 0.2
    assert abs(d["fx"] / 800 - 1) < 0.01 and abs(d["fy"] / 805 - 1) < 0.01
