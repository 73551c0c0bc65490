"""The hand studio scenario: rig, motion, truth consistency with the rendered photos, capture
folder and CLI round trips."""

import json

import cv2
import numpy as np
import pytest

from stillcap.body.hand import hand_markerset, hand_skeleton, marker_colors
from stillcap.cli import main
from stillcap.io.capture import Capture
from stillcap.studio.hand import (CAMERA_NAMES, MARKER_RADIUS, WINDOW_S, HandTruth, hand_capture, hand_motion,
                                  hand_rig, lit_centroids)
from stillcap.studio.pitch import release_state
from stillcap.studio.sensor import Sensor


@pytest.fixture(scope="module")
def ideal():
    """A noise-free, linear, unsaturated 1280x960 capture."""
    return hand_capture(2, image_size=(1280, 960), sensor=Sensor.ideal(gain=0.5, gamma=1.0))


@pytest.fixture(scope="module")
def small():
    return hand_capture(7, image_size=(640, 480), supersample=1)


def test_rig_half_circle_behind_and_above():
    hr = hand_rig((640, 480))
    assert hr.rig.names == list(CAMERA_NAMES) and hr.rig.world == "field"
    assert hr.pairs == {"left": CAMERA_NAMES[:2], "right": CAMERA_NAMES[2:]}
    assert hr.strobe_hz == 75.0 and hr.shutter_s == 1.0
    for cam in hr.rig:
        c = cam.center - hr.aim
        assert c[1] > 0.5 and c[2] > 0.8  # behind the pitcher (toward second base) and above
        assert 2.0 < np.linalg.norm(c) < 3.0
        assert cam.project(hr.aim[None])[0] == pytest.approx([319.5, 239.5], abs=5)  # looks at the release region
    xs = [cam.center[0] - hr.aim[0] for cam in hr.rig]
    assert xs[0] > xs[1] > 0 > xs[2] > xs[3]  # two per side
    light = hr.light.position - hr.aim
    assert abs(light[0]) < 1e-9 and light[1] > 2  # directly behind


def test_motion_releases_the_pitch():
    rel = release_state("seed-4seam", 3, t0=0.25)
    mo = hand_motion(rel)
    # held before release, on the pitch's flight after: position and velocity continuous at release
    dt = 1e-5
    b = mo.ball2world([rel.t0 - dt, rel.t0, rel.t0 + dt])[:, :3, 3]
    assert np.allclose(b[1], rel.p0, atol=1e-6)
    assert np.allclose((b[1] - b[0]) / dt, rel.v0, atol=0.3) and np.allclose((b[2] - b[1]) / dt, rel.v0, atol=0.3)
    # the held ball stays at one place in the hand; the wrist path speeds up toward release
    for t in (rel.t0 - 0.04, rel.t0 - 0.02, rel.t0 - 0.001):
        r2w = mo.root2world(t)
        ball = mo.ball2world([t])[0, :3, 3]
        assert np.allclose(np.linalg.inv(r2w)[:3] @ np.append(ball, 1), mo.ball_in_hand, atol=1e-9)
    w = np.array([mo.root2world(rel.t0 + s)[:3, 3] for s in np.linspace(*WINDOW_S, 7)])
    step = np.linalg.norm(np.diff(w, axis=0), axis=1)
    assert 0.5 < step.sum() < 2.0 and step[2] > step[0]
    # joint angles stay within the hand's limits over the window
    sk = hand_skeleton()
    for s in np.linspace(*WINDOW_S, 9):
        assert not sk.limit_violations(mo.pose(rel.t0 + s).local_rotations).any()


def test_flashes_and_truth_shapes(small):
    tr = small.truth
    assert len(small.images) == 4 and all(im.shape == (480, 640, 3) for im in small.images)
    assert 4 <= tr.n <= 5  # 60 ms at 75 Hz
    assert np.allclose(tr.times, tr.first_flash_s + tr.flash_index / 75.0)
    assert np.all(tr.times >= tr.release.t0 + WINDOW_S[0] - 1e-9) and np.all(tr.times <= tr.release.t0 + WINDOW_S[1] + 1e-9)
    assert tr.held.any() and (~tr.held).any()  # the ball leaves the fingers during the window
    assert np.array_equal(tr.held, tr.times < tr.release.t0)
    assert tr.markers.shape == (tr.n, 18, 3) and tr.markers_px.shape == (4, tr.n, 18, 2)
    assert tr.marker_names == list(hand_markerset().names)
    assert tr.marker_colors == marker_colors(hand_markerset())
    # labelled markers = the marker set on the truth pose; angles = the local rotations
    sk, ms = hand_skeleton(), hand_markerset()
    from stillcap.body.skeleton import Pose

    for k in range(tr.n):
        pose = Pose(sk, tr.root2world[k], tr.local_rotations[k])
        assert np.allclose(ms.positions(pose), tr.markers[k]) and np.allclose(pose.positions, tr.joints[k])
        assert np.allclose(sk.limit_angles_deg(tr.local_rotations[k]), tr.angles_deg[k])
    # the back of the hand is seen by 2+ cameras in several flashes around release (seed: ~4)
    back = tr.markers_visible[:, :, :3].all(axis=2).sum(axis=0)
    assert (back >= 2).sum() >= 2
    # the ball is in view of every camera in most flashes, held then flying
    assert tr.ball_visible.sum() >= 0.6 * tr.ball_visible.size


def test_truth_pixels_are_projections(small):
    tr = small.truth
    for ci, cam in enumerate(small.rig.rig):
        vis = tr.markers_visible[ci]
        px = cam.project(tr.markers[vis])
        assert np.allclose(px, tr.markers_px[ci][vis])
        assert np.all(np.isnan(tr.markers_px[ci][~vis]))
        bv = tr.ball_visible[ci]
        assert np.allclose(cam.project(tr.ball2world[bv, :3, 3]), tr.ball_px[ci][bv])


def _blob_centroid(I, center, rho):
    """Chroma-weighted centroid of the connected blob under a marker in the chroma image ``I``."""
    h = int(np.ceil(rho)) + 4
    x0, y0 = int(round(center[0])) - h, int(round(center[1])) - h
    win = I[y0:y0 + 2 * h + 1, x0:x0 + 2 * h + 1]
    _, lab = cv2.connectedComponents((win >= 3).astype(np.uint8), connectivity=8)
    yy, xx = np.mgrid[y0:y0 + 2 * h + 1, x0:x0 + 2 * h + 1]
    disc = (xx - center[0]) ** 2 + (yy - center[1]) ** 2 <= rho ** 2
    ids, counts = np.unique(lab[disc & (lab > 0)], return_counts=True)
    w = np.where(lab == ids[np.argmax(counts)], win, 0)
    return np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()


def test_marker_blobs_match_the_truth(ideal):
    """Noise-free photo: every isolated, unobstructed marker's blob centroid is its lit-centroid
    truth pixel; the projected centre differs by the half-moon shift (strobe behind, cameras to
    the side)."""
    tr = ideal.truth
    errs, shifts = [], []
    for ci, (cam, img) in enumerate(zip(ideal.rig.rig, ideal.images)):
        chroma = img.max(axis=2).astype(float) - img.min(axis=2)  # grey glove and room drop out
        for k, m in zip(*np.nonzero(tr.markers_isolated[ci] & (tr.markers_coverage[ci] > 0.999))):
            rho = cam.K[0, 0] * MARKER_RADIUS / cam.world_to_cam(tr.markers[k, m][None])[0, 2]
            c = _blob_centroid(chroma, tr.markers_px[ci, k, m], rho)
            errs.append(np.linalg.norm(c - tr.markers_lit_px[ci, k, m]))
            shifts.append(np.linalg.norm(tr.markers_lit_px[ci, k, m] - tr.markers_px[ci, k, m]))
    errs = np.array(errs)
    assert len(errs) >= 60
    assert np.median(errs) < 0.05 and errs.max() < 0.15  # measured: median 0.015, max 0.05 px
    assert max(shifts) > 1.0  # the phase shift is real, so the lit centroid matters


def test_lit_centroid_of_a_lone_sphere():
    from stillcap.camera import Camera
    from stillcap.studio import Exposure, PointLight, Scene, Sphere, render_radiance
    from stillcap.studio.pitch import field_look_at

    cam = Camera.from_intrinsics("c", 1650, 1650, 639.5, 479.5, (1280, 960),
                                 world2cam=field_look_at([0, -3, 0], [0, 0, 0]))
    yy, xx = np.mgrid[:960, :1280]
    for a in (30, 90, 150):
        L = 3 * np.array([np.sin(np.radians(a)), -np.cos(np.radians(a)), 0.0])
        rad = render_radiance(cam, Scene([Sphere(0.005, 0.8)], Exposure.single([np.eye(4)]), [PointLight(L, 9.0)]))
        rad = rad.max(axis=2).astype(float)
        c = np.array([(rad * xx).sum(), (rad * yy).sum()]) / rad.sum()
        assert np.allclose(c, lit_centroids(cam, [[0, 0, 0]], 0.005, L)[0], atol=0.07)


def test_ball_in_the_photos(ideal):
    """The white ball shows inside its truth disc in most views (lit from behind and the side it
    is a half moon, and the hand may cover part of a held ball)."""
    tr = ideal.truth
    bright = []
    for ci, img in enumerate(ideal.images):
        grey = img.min(axis=2)  # white: bright in every channel; coloured markers and the glove are not
        for k in np.flatnonzero(tr.ball_visible[ci]):
            x, y = tr.ball_px[ci, k]
            r = 0.8 * tr.ball_radius_px[ci, k]
            yy, xx = np.mgrid[:grey.shape[0], :grey.shape[1]]
            bright.append(grey[(xx - x) ** 2 + (yy - y) ** 2 <= r * r].max() > 60)
    assert len(bright) >= 10 and np.mean(bright) > 0.8


def test_capture_round_trip(small, tmp_path):
    cap, images = small.to_capture()
    cap.save(tmp_path / "h", images)
    back = Capture.load(tmp_path / "h")
    assert back.kind == "hand" and back.rig.names == list(CAMERA_NAMES)
    assert back.meta["rig_calibrated"] is False and back.meta["pairs"]["left"] == list(CAMERA_NAMES[:2])
    assert all(im.strobe_hz == 75.0 and im.shutter_s == 1.0 and im.first_flash_s is None for im in back.images)
    assert [im.meta["pair"] for im in back.images] == ["left", "left", "right", "right"]
    tr = HandTruth.from_dict(back.truth)
    assert np.allclose(tr.markers, small.truth.markers) and np.array_equal(tr.markers_visible, small.truth.markers_visible)
    assert np.allclose(tr.release.v0, small.truth.release.v0)
    assert (back.read_image(2) == small.images[2]).all()


def test_same_seed_same_capture():
    a = hand_capture(11, image_size=(320, 240), supersample=1)
    b = hand_capture(11, image_size=(320, 240), supersample=1)
    assert np.array_equal(a.truth.markers, b.truth.markers) and (a.images[0] == b.images[0]).all()


def test_bad_options():
    with pytest.raises(ValueError, match="window_s"):
        hand_capture(0, image_size=(320, 240), window_s=(0.02, -0.02))
    with pytest.raises(ValueError, match="preset"):
        hand_capture(0, image_size=(320, 240), preset="knuckleball")
    with pytest.raises(ValueError, match="image_size"):
        hand_capture(0, image_size=(320, 100))


def test_cli(tmp_path, capsys):
    out = tmp_path / "cli"
    main(["studio", "hand", "--out", str(out), "--seed", "3", "--size", "640x480", "--jpeg", "90"])
    cap = Capture.load(out)
    assert cap.kind == "hand" and cap.images[0].file.endswith(".jpg") and cap.read_image(0).shape == (480, 640, 3)
    assert json.loads((out / "truth.json").read_text())["kind"] == "hand"
    assert "flashes" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["studio", "hand", "--out", str(out), "--seed", "3", "--size", "640x480"])  # not empty, no --force
    main(["studio", "hand", "--out", str(out), "--seed", "3", "--size", "640x480", "--force"])
    assert Capture.load(out).images[0].file.endswith(".png")
