"""stillcap.calibrate.edge_response: the camera response from the symmetry of a chessboard's
blurred edges; calibration writes it into the rig (``--response``)."""

import json

import cv2
import numpy as np
import pytest

from stillcap.calibrate import Chessboard
from stillcap.calibrate.detect import find_chessboard, read_gray
from stillcap.calibrate.edge_response import board_response, edge_response, image_edge_gamma, rig_responses
from stillcap.camera import Camera, Rig
from stillcap.cli import main
from stillcap.response import Response
from stillcap.studio.scenes import chessboard_set
from stillcap.studio.sensor import Sensor

BOARD = Chessboard(9, 6, 0.025)


@pytest.fixture(scope="module")
def boards():
    """Four studio photos of a board per response (the studio's blur, noise and anti-aliasing)."""
    out = {}
    for name, sensor in [("linear", Sensor(gamma=1.0)), ("srgb", Sensor()), ("gamma:1.8", Sensor(gamma=1.8)),
                         ("gamma:2.6", Sensor(gamma=2.6)), ("tone", Sensor(tone=True))]:
        s = chessboard_set(n_views=4, target=BOARD, rng=11, sensor=sensor)
        grays = [read_gray(im) for im in s.images]
        out[name] = (sensor.response, grays, [find_chessboard(g, BOARD) for g in grays])
    return out


@pytest.mark.parametrize("name", ["linear", "srgb", "gamma:1.8", "gamma:2.6", "tone"])
def test_recovers_the_class_and_the_effective_gamma(boards, name):
    true, grays, corners = boards[name]
    e = edge_response(grays, corners, BOARD.pattern_size)
    assert e.ok and e.response_class == true.response_class, e.evidence
    assert e.gamma == pytest.approx(true.effective_gamma, rel=0.1)
    assert e.n_photos == 4 and e.spread < 0.1
    assert e.response() == (Response.linear() if name == "linear" else Response.power(round(e.gamma, 2)))


def test_the_orientation_of_the_photo_does_not_matter(boards):
    """Mirrored photos (every edge's dark side on the other hand) give the same gamma."""
    _true, grays, corners = boards["srgb"]
    g = image_edge_gamma(grays[0], corners[0], BOARD.pattern_size)
    flipped = grays[0][:, ::-1].copy()
    c = find_chessboard(flipped, BOARD)
    gf = image_edge_gamma(flipped, c, BOARD.pattern_size)
    assert gf["gamma"] == pytest.approx(g["gamma"], rel=0.03)


def test_clipped_squares_cannot_tell(boards):
    """Over-exposed photos (white squares at 255): the plateau is not the radiance."""
    _true, grays, corners = boards["linear"]
    bright = [np.clip(g.astype(float) * 2.2, 0, 255).astype(np.uint8) for g in grays]
    e = edge_response(bright, corners, BOARD.pattern_size)
    assert not e.ok and e.response() is None and "clipped" in e.evidence and e.clipped > 0.05


def test_edges_without_a_profile_cannot_tell(boards):
    """A thresholded photo has no blurred edge to measure."""
    _true, grays, corners = boards["srgb"]
    binary = [np.where(g > 128, 230, 20).astype(np.uint8) for g in grays]
    e = edge_response(binary, corners, BOARD.pattern_size)
    assert not e.ok and "too sharp" in e.evidence


def test_too_few_photos_and_a_charuco_board_say_so(boards):
    _true, grays, corners = boards["linear"]
    e = edge_response(grays[:2], corners[:2], BOARD.pattern_size)
    assert not e.ok and "only 2 photo" in e.evidence
    from stillcap.calibrate import CharucoTarget

    e = board_response(grays, CharucoTarget(7, 5, 0.04, 0.03))
    assert not e.ok and "chessboard" in e.evidence


def test_real_photos_of_a_consumer_camera_are_not_called_linear(stereo_dir):
    """OpenCV's sample photos (a consumer camera): the estimate must not claim a linear camera.
    Measured: their photos disagree (gammas 0.7-2.2, white squares between 195 and 250), so it
    cannot tell and writes nothing."""
    for side in ("left", "right"):
        e = board_response(sorted(stereo_dir.glob(f"{side}*.jpg")), Chessboard(9, 6, 1.0))
        assert e.response_class != "linear", e.evidence
        assert e.n_photos >= 10


def test_rig_responses_stated_wins_and_estimated_is_written(boards, tmp_path):
    _true, grays, _c = boards["linear"]
    files = []
    for i, g in enumerate(grays):
        f = tmp_path / f"v{i}.png"
        cv2.imwrite(str(f), g)
        files.append(f)
    rig = Rig([Camera.from_intrinsics("cam0", 800, 800, 320, 240, (grays[0].shape[1], grays[0].shape[0]))])
    out, rep = rig_responses(rig, {"cam0": files}, BOARD)
    assert rep["source"] == "estimated" and rep["written"] == {"cam0": True}
    assert out["cam0"].response == Response.linear() and "wrote linear" in rep["messages"][0]
    out, rep = rig_responses(rig, {"cam0": files}, BOARD, Response.power(2.2))
    assert rep["source"] == "stated" and out["cam0"].response == Response.power(2.2)


def test_cli_writes_the_response_into_the_rig(tmp_path, capsys):
    folder = tmp_path / "board"
    main(["studio", "chessboard", "--out", str(folder), "--views", "5", "--camera-response", "linear"])
    capsys.readouterr()
    assert json.loads((folder / "truth.json").read_text())["response"] == "linear"
    photos = sorted((folder / "images").glob("*.png"))
    out = tmp_path / "rig.json"
    main(["calibrate", "intrinsics", *map(str, photos), "--square", "0.025", "--out", str(out)])
    text = capsys.readouterr().out
    assert "response of cam0: linear" in text
    assert json.loads(out.read_text())["cameras"][0]["response"] == "linear"
    out2 = tmp_path / "rig2.json"
    main(["calibrate", "intrinsics", *map(str, photos), "--square", "0.025", "--out", str(out2),
          "--response", "gamma:2.4", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert d["response"]["source"] == "stated" and d["response"]["cameras"] == {"cam0": {"gamma": 2.4}}
    assert Rig.load(out2)["cam0"].response == Response.power(2.4)


def test_cli_bad_response_is_one_line_exit_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["calibrate", "intrinsics", str(tmp_path / "x.png"), "--response", "gamma:x"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--response 'gamma:x'" in err and len(err.strip().splitlines()) == 1
