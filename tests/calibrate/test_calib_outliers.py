"""Outlier views: flagged by per-view RMS against the median (stillcap.calibrate.outliers)."""

import json

import cv2
import numpy as np
import pytest

from stillcap.calibrate import Chessboard, calibrate_intrinsics, calibrate_rig, calibrate_stereo
from stillcap.calibrate.outliers import FLOOR_PX, outlier_threshold, outlier_views
from support import run_cli

BOARD = Chessboard(9, 6, 1.0)


def test_rule():
    # the real set's left camera (per-image RMS, px): left02 only
    left = {"01": 0.193, "02": 1.220, "03": 0.175, "04": 0.194, "05": 0.159, "06": 0.183, "07": 0.238,
            "08": 0.243, "09": 0.301, "11": 0.168, "12": 0.202, "13": 0.462, "14": 0.175}
    assert outlier_views(left) == ["02"]
    # the right camera: right05 (2.9x the median) and right13 (2.5x) stay, right02 (5.5x) goes
    right = {"01": 0.454, "02": 1.203, "03": 0.184, "04": 0.219, "05": 0.626, "06": 0.199, "07": 0.293,
             "08": 0.200, "09": 0.222, "11": 0.150, "12": 0.219, "13": 0.548, "14": 0.144}
    assert outlier_views(right) == ["02"]
    # a clean rendered set: 4.7x the median, but under the floor of half a pixel
    assert outlier_views({str(i): 0.05 for i in range(10)} | {"x": 0.24}) == []
    assert outlier_views({str(i): 0.05 for i in range(10)} | {"x": FLOOR_PX + 0.01}) == ["x"]
    # a widely spread set: 3x the median is inside the spread (median + 3 MAD-sigma rules)
    spread = {str(i): e for i, e in enumerate([0.2, 0.3, 0.5, 0.7, 0.9, 1.1, 1.3])}
    assert outlier_views(spread | {"x": 2.2}) == [] and outlier_views(spread | {"x": 3.5}) == ["x"]
    # too few views to judge
    assert outlier_views({"a": 0.1, "b": 0.1, "c": 5.0}) == [] and outlier_threshold([0.1, 0.1, 5.0]) == np.inf


@pytest.fixture(scope="module")
def photos(stereo_dir):
    return sorted(stereo_dir.glob("left*.jpg")), sorted(stereo_dir.glob("right*.jpg"))


def test_real_set_flags_pair_02_only(photos):
    res = calibrate_stereo(*photos, BOARD)
    assert res.left.outlier_views == ["left02.jpg"] and res.right.outlier_views == ["right02.jpg"]
    assert res.outlier_pairs == ["02"] and res.pair_images["02"] == ("left02.jpg", "right02.jpg")
    # without them: OpenCV's tutorial numbers for the left camera (fx 534.07 with 7x6 corners)
    wl = res.left.without_outliers
    assert wl.images_used == [p.name for p in photos[0] if p.name != "left02.jpg"] and not wl.outlier_views
    assert wl.rms_px < 0.25 < res.left.rms_px and abs(wl.camera.K[0, 0] - 534.1) < 0.1
    assert res.right.without_outliers.rms_px < 0.33 < res.right.rms_px
    w = res.without_outliers
    assert "02" not in w.pairs_used and len(w.pairs_used) == 12 and w.rms_px < 0.31 < res.rms_px
    assert abs(w.baseline - res.baseline) < 0.01


def test_real_set_rig_flags_02_in_both_cameras(stereo_dir, tmp_path):
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for p in stereo_dir.glob(f"{side}*.jpg"):
            (tmp_path / side / p.name.replace(side, "")).symlink_to(p)
    from stillcap.calibrate import rig_images_from_folder

    images, instants = rig_images_from_folder(tmp_path)
    res = calibrate_rig(images, BOARD, instants=instants)
    assert {c: list(v) for c, v in res.outlier_views.items()} == {"left": ["02.jpg"], "right": ["02.jpg"]}
    assert "intrinsic calibration, 6.3x the median" in res.outlier_views["left"]["02.jpg"]
    assert set(res.per_view_rms_px["left"]) == {f"{i:02d}.jpg" for i in (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14)}
    assert res.without_outliers.rms_px < res.rms_px


def test_cli_marks_outliers_and_suggests_dropping_them(capsys, stereo_dir):
    photos = sorted(stereo_dir.glob("*.jpg"))
    code, out, err = run_cli(["calibrate", "stereo", *photos, "--square", "1"], capsys)
    assert code == 0, err
    text = " ".join(out.split())  # rich wraps long lines
    assert "left02.jpg │ 1.220 outlier" in text and "right02.jpg │ 1.203 outlier" in text
    assert "left13.jpg │ 0.462 │" in text and "right05.jpg │ 0.626 │" in text  # not flagged
    assert "outlier view: left02.jpg (1.220 px, 6.3x the median 0.194 px)" in text
    assert "without it: RMS 0.409 -> 0.234 px, fx 536.07 -> 534.13" in text
    assert "outlier pair: 02 (left02.jpg, right02.jpg; RMS 1.230 / 1.214 px)" in text
    assert "stereo RMS 0.448 -> 0.302 px" in text and "consider dropping left02.jpg, right02.jpg" in text

    code, out, err = run_cli(["calibrate", "stereo", *photos, "--square", "1", "--json"], capsys)
    d = json.loads(out)
    assert d["left"]["outlier_views"] == ["left02.jpg"] and d["right"]["outlier_views"] == ["right02.jpg"]
    assert d["left"]["without_outliers"]["rms_px"] < 0.25 and len(d["left"]["without_outliers"]["images_used"]) == 12
    assert d["outlier_pairs"] == ["02"] and d["outlier_files"] == ["left02.jpg", "right02.jpg"]
    assert d["without_outliers"]["rms_px"] < 0.31 and "02" not in d["without_outliers"]["pairs_used"]

    left = sorted(stereo_dir.glob("left*.jpg"))
    code, out, err = run_cli(["calibrate", "intrinsics", *left, "--square", "1"], capsys)
    assert "consider dropping it and calibrating again" in " ".join(out.split())


def _bend(image, amp_px):
    """The photo warped by a smooth wave of ``amp_px`` (a board that is not flat)."""
    h, w = image.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return cv2.remap(image, xx + amp_px * np.sin(yy / 25), yy + amp_px * np.cos(xx / 31), cv2.INTER_LINEAR)


def test_rendered_boards_flag_nothing_and_a_spoiled_view_is_flagged():
    from stillcap.studio.scenes import chessboard_set, default_camera

    boards = chessboard_set(default_camera(), 10, Chessboard(9, 6, 0.025), rng=1)
    clean = calibrate_intrinsics(boards.images, boards.target)
    assert clean.outlier_views == [] and clean.without_outliers is None and clean.summary()["outlier_views"] == []
    images = list(boards.images)
    images[4] = _bend(images[4], 1.5)
    spoiled = calibrate_intrinsics(images, boards.target)
    assert spoiled.outlier_views == ["#4"] and spoiled.per_image_rms_px["#4"] > 0.5
    assert spoiled.without_outliers.rms_px == pytest.approx(calibrate_intrinsics(
        [im for i, im in enumerate(boards.images) if i != 4], boards.target).rms_px, rel=1e-6)
