"""Bad calibration input: one line naming the problem, exit status 2, never a traceback."""

import cv2
import numpy as np
import pytest

from stillcap.calibrate import CharucoTarget, Chessboard, calibrate_intrinsics, calibrate_stereo, parse_pattern
from support import run_cli


def one_line(capsys, args, match):
    code, _, err = run_cli(args, capsys)
    lines = [s for s in err.splitlines() if s.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("error: ") and match in " ".join(err.split()), err
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    (d / "text.jpg").write_text("not an image")
    (d / "empty.png").write_bytes(b"")
    cv2.imwrite(str(d / "blank.png"), np.full((480, 640), 200, np.uint8))
    cv2.imwrite(str(d / "small.png"), np.full((240, 320), 200, np.uint8))
    return d


def test_not_an_image(capsys, stereo_dir, files):
    left = sorted(stereo_dir.glob("left0*.jpg"))
    one_line(capsys, ["calibrate", "intrinsics", *left, files / "text.jpg"], "text.jpg is not an image")
    one_line(capsys, ["calibrate", "intrinsics", *left, files / "empty.png"], "empty.png is empty")
    one_line(capsys, ["calibrate", "intrinsics", *left, files], f"{files} is a folder, not an image file")
    one_line(capsys, ["calibrate", "intrinsics", *left, files / "none.jpg"], "none.jpg does not exist")


def test_board_not_found_anywhere(capsys, files):
    blank = files / "blank.png"
    one_line(capsys, ["calibrate", "intrinsics", blank, blank, blank],
             "target not found in any of the 3 images: blank.png (9x6 chessboard not found)")


def test_too_few_views(capsys, stereo_dir, files):
    two = [stereo_dir / "left01.jpg", stereo_dir / "left03.jpg"]
    line = one_line(capsys, ["calibrate", "intrinsics", *two], "target found in only 2 images (left01.jpg, left03.jpg)")
    assert line.endswith("need 3")  # nothing skipped: no empty "skipped:" list
    one_line(capsys, ["calibrate", "intrinsics", *two, files / "blank.png"],
             "need 3; skipped: blank.png (9x6 chessboard not found)")
    pairs = [stereo_dir / f"{s}0{i}.jpg" for i in (1, 3) for s in ("left", "right")]
    one_line(capsys, ["calibrate", "stereo", *pairs], "camera 'left': target found in only 2 images")


def test_images_of_different_sizes(capsys, stereo_dir, files, tmp_path):
    left = sorted(stereo_dir.glob("left0*.jpg"))
    one_line(capsys, ["calibrate", "intrinsics", *left, files / "small.png"],
             "camera 'cam0': images differ in size: left01.jpg is 640x480 px, small.png is 320x240 px")
    right = sorted(stereo_dir.glob("right0*.jpg"))
    (tmp_path / "left99.png").symlink_to(files / "small.png")
    (tmp_path / "right99.png").symlink_to(files / "blank.png")
    one_line(capsys, ["calibrate", "stereo", *left, *right, tmp_path / "left99.png", tmp_path / "right99.png"],
             "camera 'left': images differ in size")
    for cam, imgs in (("a", ["left01.jpg", "left03.jpg"]), ("b", ["right01.jpg", "right03.jpg"])):
        (tmp_path / "rig" / cam).mkdir(parents=True)
        for k, name in enumerate(imgs):
            (tmp_path / "rig" / cam / f"{k}.jpg").symlink_to(stereo_dir / name)
    (tmp_path / "rig" / "b" / "2.png").symlink_to(files / "small.png")
    one_line(capsys, ["calibrate", "rig", tmp_path / "rig"], "camera 'b': 2.png is 320x240 px, earlier images are 640x480 px")


def test_rig_too_few_views_names_the_camera(capsys, stereo_dir, tmp_path):
    for cam, imgs in (("a", ["left01.jpg", "left03.jpg"]), ("b", ["right01.jpg", "right03.jpg"])):
        (tmp_path / cam).mkdir()
        for k, name in enumerate(imgs):
            (tmp_path / cam / f"{k}.jpg").symlink_to(stereo_dir / name)
    one_line(capsys, ["calibrate", "rig", tmp_path], "camera 'a': intrinsic calibration needs at least 3 views, got 2")


def test_stereo_pairs_that_do_not_pair(capsys, stereo_dir, files):
    left = sorted(stereo_dir.glob("left0*.jpg"))
    one_line(capsys, ["calibrate", "stereo", *left, *sorted(stereo_dir.glob("right1*.jpg"))],
             "stereo pairs do not match: no partner for left01.jpg")
    one_line(capsys, ["calibrate", "stereo", *left], "got 9 'left' and 0 'right' images")
    one_line(capsys, ["calibrate", "stereo", *sorted(stereo_dir.glob("*.jpg")), files / "blank.png"],
             "cannot tell left from right for blank.png")


@pytest.mark.parametrize("args, match", [
    (["--pattern", "9y6"], "pattern must look like 9x6 (inner corners), got '9y6'"),
    (["--pattern", "9x6x2"], "pattern must look like 9x6"),
    (["--pattern", "1x6"], "at least 2x2 inner corners"),
    (["--pattern", "99999999x6"], "at most 100 inner corners per side, got '99999999x6'"),
    (["--square", "nan"], "--square must be a positive length in metres, got nan"),
    (["--square", "inf"], "--square must be a positive length in metres, got inf"),
    (["--square", "-1"], "--square must be a positive length"),
    (["--charuco", "--squares", "7y5"], "--squares must look like 7x5, got '7y5'"),
    (["--charuco", "--squares", "1x1"], "--squares must be from 2x2 to 100x100, got '1x1'"),
    (["--charuco", "--squares", "40x40"], "a 40x40 ChArUco board needs 800 markers from id 0, but its dictionary holds 250"),
    (["--charuco", "--dict", "DICT_FOO"], "unknown ArUco dictionary 'DICT_FOO'"),
    (["--charuco", "--marker", "inf"], "--marker must be between 0 and --square (0.025), got inf"),
])
def test_target_options(capsys, stereo_dir, args, match):
    one_line(capsys, ["calibrate", "intrinsics", stereo_dir / "left01.jpg", *args], match)


def test_library_targets_check_their_numbers():
    assert parse_pattern("9X6") == (9, 6)
    with pytest.raises(ValueError, match="chessboard inner corners along x"):
        Chessboard(1, 6)
    with pytest.raises(ValueError, match="whole number from 2 to 100, got 9.5"):
        Chessboard(9.5, 6)
    with pytest.raises(ValueError, match="chessboard square must be a positive finite length \\(metres\\), got nan"):
        Chessboard(9, 6, float("nan"))
    with pytest.raises(ValueError, match="ChArUco marker must be between 0 and 0.04 "):
        CharucoTarget(7, 5, 0.04, 0.05)
    with pytest.raises(ValueError, match="needs 17 markers from id 240"):
        CharucoTarget(7, 5, first_id=240)


def test_library_boundaries(stereo_dir, files):
    board = Chessboard(9, 6, 1.0)
    with pytest.raises(ValueError, match="text.jpg is not an image"):
        calibrate_intrinsics([stereo_dir / "left01.jpg", files / "text.jpg"], board)
    with pytest.raises(ValueError, match="no partner for left01.jpg"):
        calibrate_stereo([stereo_dir / "left01.jpg"], [stereo_dir / "right02.jpg"], board)
