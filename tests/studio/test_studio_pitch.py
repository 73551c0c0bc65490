"""The pitch scenario: the seed's strobed stereo rig, a marked ball in flight, consistent truth."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.ball.layout import BallLayout
from stillcap.ball.metrics import MPH, RPM_PER_RAD_S, spin_axis_deg, spin_efficiency, spin_vector
from stillcap.ball.physics import FlightModel, simulate
from stillcap.cli import main
from stillcap.io.capture import Capture
from stillcap.studio import Backdrop, Exposure, Scene, Sensor, Sphere, render_radiance
from stillcap.studio.pitch import (PRESETS, PitchTruth, ReleaseVariation, pitch_capture, pitch_rig,
                                   release_state)

FT = 0.3048
SIZE = (1280, 960)  # half the seed's size: same field of view, 4x fewer pixels


@pytest.fixture(scope="module")
def ideal():
    """A noise-free seed four-seamer, true rig."""
    return pitch_capture("seed-4seam", rng=3, calibrate=False, image_size=SIZE, sensor=Sensor.ideal())


@pytest.fixture(scope="module")
def calibrated():
    """The same kind of capture with the rig calibrated from rendered board photos."""
    return pitch_capture("seed-4seam", rng=7, calibrate=True, image_size=SIZE, calibration_views=4)


def _silhouettes(pc, camera):
    """Radiance of the pair's balls lit evenly (ambient only, no markers): 1 inside, 0 outside."""
    pair = pc.rig.pair_of(camera.name).name
    sc = pc.scenes[pair]
    flat = Scene([Sphere(sc.bodies[0].radius, albedo=1.0)], Exposure(sc.exposure.flashes, ambient=1.0), [],
                 backdrop=Backdrop(0.0))
    return render_radiance(camera, flat, supersample=5)[..., 0] * len(sc.exposure.flashes)


def _whole_balls(pc, camera):
    """``(k, centre_px, radius_px, window)`` of every ball wholly inside ``camera``'s image."""
    pair = pc.rig.pair_of(camera.name).name
    pt = pc.truth.pair(pair)
    ci = pt.cameras.index(camera.name)
    W, H = camera.image_size
    for k in np.flatnonzero(pt.visible[ci]):
        c, r = pt.centers_px[ci, k], pt.radius_px[ci, k]
        x0, y0, x1, y1 = int(c[0] - r - 3), int(c[1] - r - 3), int(c[0] + r + 4), int(c[1] + r + 4)
        if x0 >= 0 and y0 >= 0 and x1 <= W and y1 <= H:
            yield k, c, r, (slice(y0, y1), slice(x0, x1))


def _centroid(w, win):
    ys, xs = np.mgrid[win[0], win[1]]
    return np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()


# --- the rig ---------------------------------------------------------------------------------
def test_rig_is_the_seeds():
    pr = pitch_rig()
    assert pr.rig.names == ["front_top", "front_bottom", "back_left", "back_right"] and pr.rig.world == "field"
    assert all(c.image_size == (2560, 1920) for c in pr.rig)
    ft, fb, bl, br = (c.center for c in pr.rig)
    assert ft[2] - fb[2] == pytest.approx(0.8) and ft[:2] == pytest.approx(fb[:2])  # vertical baseline
    assert -0.5 - ft[0] == pytest.approx(3.5)                                        # 3.5 m from the path
    assert (bl[2], br[2]) == pytest.approx((2.8, 2.8)) and bl[0] - br[0] == pytest.approx(4.0)  # 2.8 m high, 4 m apart
    front, back = pr.pair("front"), pr.pair("back")
    assert (front.strobe_hz, front.shutter_s, back.strobe_hz, back.shutter_s) == (80, 1.0, 50, 1.3)
    assert pr.pair_of("back_right") is back
    # upright cameras: a point above the view centre is higher in the image, the flight goes left to right
    cam = pr.rig["front_top"]
    up = cam.project(np.array([[-0.5, 14.7, 1.6], [-0.5, 14.7, 2.0], [-0.5, 15.5, 1.6]]))
    assert up[1, 1] < up[0, 1] and up[2, 0] < up[0, 0]


def test_small_images_keep_the_field_of_view():
    big, small = pitch_rig(), pitch_rig(image_size=(640, 480))
    p = np.array([[-0.4, 15.0, 1.7], [0.1, 2.0, 0.8]])
    for b, s in zip(big.rig, small.rig):
        np.testing.assert_allclose(s.project(p) * 4 + 1.5, b.project(p), atol=1e-6)


# --- truth against the images ----------------------------------------------------------------
def test_true_centers_are_where_the_balls_are_rendered(ideal):
    checked = 0
    for cam in ideal.rig.rig:
        sil = _silhouettes(ideal, cam)
        photo = render_radiance(cam, ideal.scenes[ideal.rig.pair_of(cam.name).name]).max(axis=2)
        for _, c, _, win in _whole_balls(ideal, cam):
            # silhouette centroid = projected centre (+ the small perspective offset)
            assert np.linalg.norm(_centroid(sil[win], win) - c) < 0.15
            if cam.name.startswith("front"):  # full, evenly lit balls in the photo itself
                mask = (photo[win] > 0.03).astype(float)
                assert np.linalg.norm(_centroid(mask, win) - c) < 0.5
            checked += 1
    assert checked >= 40


def test_front_images_show_6_to_10_balls_at_80_hz():
    for preset in ("seed-changeup", "seed-4seam", "mlb-4seam"):
        pc = pitch_capture(preset, rng=11, calibrate=False, image_size=(640, 480), supersample=2)
        pt = pc.truth.pair("front")
        for ci, name in enumerate(pt.cameras):
            cam = pc.rig.rig[name]
            grey = cv2.cvtColor(pc.images[pc.rig.rig.names.index(name)], cv2.COLOR_BGR2GRAY)
            _, _, stats, cents = cv2.connectedComponentsWithStats((grey > 90).astype(np.uint8))
            big = stats[1:, cv2.CC_STAT_AREA] >= 10
            blobs = int(big.sum())
            assert 6 <= blobs <= 10, (preset, name, blobs)
            assert abs(blobs - pt.visible[ci].sum()) <= 1  # a ball cut by the image border may differ
            # every ball wholly inside the image is one of the blobs
            for _, c, _, _ in _whole_balls(pc, cam):
                assert np.min(np.linalg.norm(cents[1:][big] - c, axis=1)) < 1.0
        assert pt.strobe_hz == 80


def test_back_images_show_half_moons(ideal):
    for cam in ideal.rig.rig:
        sil = _silhouettes(ideal, cam)
        photo = render_radiance(cam, ideal.scenes[ideal.rig.pair_of(cam.name).name]).max(axis=2)
        lit_share, offset = [], []
        for _, _, r, win in _whole_balls(ideal, cam):
            inside = sil[win] > 0.5
            p = photo[win]
            lit = inside & (p > 0.2 * p[inside].max())
            lit_share.append(lit.sum() / inside.sum())
            offset.append(np.linalg.norm(_centroid(lit, win) - _centroid(inside, win)) / r)
        lit_share, offset = np.array(lit_share), np.array(offset)
        if cam.name.startswith("front"):
            assert lit_share.min() > 0.85 and offset.max() < 0.1
        else:  # lit from the side: part of every ball stays dark, off centre
            assert lit_share.max() < 0.9 and 0.2 < np.median(lit_share) < 0.7
            assert offset.min() > 0.1
    pt = ideal.truth.pair("back")
    ph = pt.phase_angle_deg[pt.visible]
    assert 60 < np.median(ph) < 120 and ideal.truth.pair("front").phase_angle_deg.max() < 20


def test_orientation_turns_with_the_constant_spin(ideal):
    tr = ideal.truth
    rel = tr.release
    for pt in tr.pairs:
        # positions follow the physics, orientations exp([w] (t - t0)) R0
        sim = simulate(rel.p0, rel.v0, rel.spin, pt.times, FlightModel.seed_model(), t0=rel.t0)
        np.testing.assert_allclose(pt.positions, sim.positions, atol=1e-9)
        for T, t in zip(pt.ball2world, pt.times):
            R = Rotation.from_rotvec(rel.spin * (t - rel.t0)).as_matrix() @ rel.ball2world[:3, :3]
            np.testing.assert_allclose(T[:3, :3], R, atol=1e-9)
        # between flashes the ball turns by |w| / f about w
        step = pt.ball2world[1:, :3, :3] @ pt.ball2world[:-1, :3, :3].transpose(0, 2, 1)
        np.testing.assert_allclose(step, np.tile(Rotation.from_rotvec(rel.spin / pt.strobe_hz).as_matrix(),
                                                 (len(step), 1, 1)), atol=1e-9)
        # a visible marker's pixel lies on its ball's disc
        d = np.linalg.norm(pt.markers_px - pt.centers_px[:, :, None], axis=-1)
        seen = np.isfinite(d)
        assert seen.sum() > 50 and np.all(d[seen] < 1.15 * pt.radius_px[:, :, None].repeat(12, 2)[seen])
    assert rel.spin_rpm == pytest.approx(np.linalg.norm(tr.spin) * RPM_PER_RAD_S)
    assert tr.to_dict()["spin_rpm"] == pytest.approx(tr.metrics["spin_rate_rpm"])


def test_ball_is_the_layout_with_a_palette():
    pc = pitch_capture("seed-slider", rng=1, calibrate=False, image_size=(256, 192), supersample=1,
                       palette={"blue": (0.1, 0.45, 1.0)})
    seed = BallLayout.seed()
    marks = pc.truth.ball["markers"]
    np.testing.assert_allclose([m["direction"] for m in marks], seed.directions)
    assert [m["type"] for m in marks] == [seed.type_names[t] for t in seed.types]
    assert pc.truth.ball["palette"]["blue"] == [0.1, 0.45, 1.0]
    ball = pc.scenes["front"].bodies[0]
    assert ball.radius == pytest.approx(0.0737 / 2)
    assert all(np.allclose(m.color, (0.1, 0.45, 1.0)) for m, mk in zip(ball.markers, marks) if mk["type"] == "blue")


# --- pitches -------------------------------------------------------------------------------
def test_presets_give_their_speeds_and_spin_rates():
    for name, p in PRESETS.items():
        pc = pitch_capture(name, rng=2, calibrate=False, variation=None, image_size=(256, 192), supersample=1)
        m = pc.truth.metrics
        assert m["release_speed_mph"] == pytest.approx(p.speed_mph, abs=0.1), name
        assert m["spin_rate_rpm"] == pytest.approx(p.spin_rpm, abs=0.5), name
        assert m["spin_axis_deg"] == pytest.approx(p.spin_axis_deg, abs=0.5), name
        assert m["spin_efficiency"] == pytest.approx(p.spin_efficiency, abs=0.005), name
        # aimed at its target at the front of the plate
        assert (m["plate_x_ft"] * FT, m["plate_z_ft"] * FT) == pytest.approx(p.target_m, abs=0.01), name
        np.testing.assert_allclose(pc.truth.release.p0, p.release_m)
    # backspin for fastballs and the change-up, topspin for the curveball, sidespin for the slider
    for name, lo, hi in (("seed-4seam", 180, 240), ("seed-2seam", 180, 240), ("seed-changeup", 180, 240),
                         ("seed-curveball", 0, 45), ("seed-slider", 60, 120)):
        assert lo <= PRESETS[name].spin_axis_deg <= hi
    assert PRESETS["mlb-high-spin"].spin_rpm / 60 > 80 / 2  # above the 80 Hz Nyquist limit
    assert PRESETS["mlb-gyro-slider"].spin_efficiency < 0.5


def test_release_variation_stays_within_its_bounds():
    nominal = release_state("seed-curveball", variation=None)
    var = ReleaseVariation()
    speeds, tilts = [], []
    for seed in range(12):
        r = release_state("seed-curveball", seed)
        assert np.all(np.abs(r.p0 - nominal.p0) <= var.position_m + 1e-12)
        assert abs(r.speed_mph - nominal.speed_mph) <= var.speed_mph + 1e-9
        cos = r.v0 @ nominal.v0 / np.linalg.norm(r.v0) / np.linalg.norm(nominal.v0)
        ang = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        assert ang <= var.direction_deg + 1e-9
        assert abs(r.spin_rpm - nominal.spin_rpm) <= var.spin_rpm + 1e-6
        ideal_spin = spin_vector(r.spin_rpm, PRESETS["seed-curveball"].spin_axis_deg, r.v0, 0.85)
        tilt = np.degrees(np.arccos(np.clip(r.spin @ ideal_spin / np.linalg.norm(r.spin) ** 2, -1, 1)))
        assert tilt <= var.axis_deg + 1e-6
        speeds.append(r.speed_mph)
        tilts.append(tilt)
    assert np.ptp(speeds) > 0.5 and max(tilts) > 1.0  # it does vary
    # explicit values are exact, the rest still varies
    r = release_state("mlb-4seam", 5, speed_mph=97.0, spin_rpm=2600, spin_axis_deg=200)
    assert r.speed_mph == pytest.approx(97.0) and r.spin_rpm == pytest.approx(2600)
    assert spin_axis_deg(r.spin, r.v0) == pytest.approx(200, abs=1e-6)
    assert spin_efficiency(r.spin, r.v0) == pytest.approx(0.95)


def test_nathan_model_decays_the_spin():
    kw = dict(rng=4, calibrate=False, variation=None, image_size=(256, 192), supersample=1)
    seed, nathan = (pitch_capture("seed-changeup", model=m, **kw) for m in ("seed", "nathan"))
    assert nathan.truth.model == "nathan" and seed.truth.model == "seed"
    assert seed.truth.metrics["pfx_z_in"] != pytest.approx(nathan.truth.metrics["pfx_z_in"], abs=0.5)
    for pc in (seed, nathan):
        pt, rel = pc.truth.pair("front"), pc.truth.release
        step = Rotation.from_matrix(pt.ball2world[1:, :3, :3] @ pt.ball2world[:-1, :3, :3].transpose(0, 2, 1))
        ratio = step.magnitude() / (np.linalg.norm(rel.spin) / pt.strobe_hz)
        axes = step.as_rotvec() / step.magnitude()[:, None]
        np.testing.assert_allclose(axes, np.tile(rel.spin / np.linalg.norm(rel.spin), (len(axes), 1)), atol=1e-9)
        if pc is seed:  # constant spin
            np.testing.assert_allclose(ratio, 1.0, atol=1e-9)
        else:  # the spin decays (tau ~ 50 s at 60 mph): slightly less turn per flash, less and less
            assert np.all((ratio > 0.98) & (ratio < 1.0)) and np.all(np.diff(ratio) < 0)


# --- timing ----------------------------------------------------------------------------------
def test_strobes_run_free_and_the_offset_is_in_the_truth(ideal):
    tr = ideal.truth
    for pt in tr.pairs:
        assert 0 <= pt.first_flash_s < 1 / pt.strobe_hz
        np.testing.assert_allclose(pt.times, pt.first_flash_s + pt.flash_index / pt.strobe_hz)
        assert pt.times[0] >= tr.release.t0 and pt.times[-1] <= tr.end_time_s
        assert pt.n_flashes == int(np.floor((pt.shutter_s - pt.first_flash_s) * pt.strobe_hz)) + 1
    assert tr.time_offset_s == pytest.approx(tr.pair("back").first_flash_s - tr.pair("front").first_flash_s)
    other = pitch_capture("seed-4seam", rng=4, calibrate=False, image_size=(256, 192), supersample=1)
    assert other.truth.time_offset_s != tr.time_offset_s
    # unknown to a pipeline unless asked for
    cap, _ = ideal.to_capture()
    assert all(im.first_flash_s is None and im.n_flashes is None and im.strobe_hz in (80, 50) for im in cap.images)
    known = pitch_capture("seed-4seam", rng=3, calibrate=False, image_size=(256, 192), supersample=1,
                          known_flash_times=True)
    im = known.to_capture()[0].images[0]
    front = known.truth.pair("front")
    np.testing.assert_allclose(im.flash_times[front.flash_index], front.times)


def test_same_seed_same_pitch_with_or_without_calibration(ideal, calibrated):
    again = pitch_capture("seed-4seam", rng=7, calibrate=False, image_size=SIZE)
    assert np.array_equal(again.truth.release.v0, calibrated.truth.release.v0)
    assert all(np.array_equal(a, b) for a, b in zip(again.images, calibrated.images))
    assert again.truth.pairs[1].first_flash_s == calibrated.truth.pairs[1].first_flash_s


# --- calibration -----------------------------------------------------------------------------
def test_calibrated_rig_reprojects_like_the_true_rig(calibrated):
    cal = calibrated.calibration
    assert cal.success and calibrated.capture_rig is cal.rig
    err = calibrated.truth.calibration_error
    assert set(err) == set(calibrated.rig.rig.names)
    for name, e in err.items():
        assert e["n_points"] > 100
        assert e["max_px"] < 0.6 and e["rms_px"] < 0.2, (name, e)  # at 1280 px: ~1 px at the seed's 2560
        assert e["center_error_mm"] < 10
    # the rig is measured, not copied from the truth
    for true, cam in zip(calibrated.rig.rig, calibrated.capture_rig):
        assert not np.allclose(true.K, cam.K) and not np.allclose(true.world2cam, cam.world2cam)
        # the balls' true 3D centres land within a pixel of their true pixels
        pt = calibrated.truth.pair(calibrated.rig.pair_of(cam.name).name)
        ci = pt.cameras.index(cam.name)
        v = pt.visible[ci]
        assert np.abs(cam.project(pt.positions[v]) - pt.centers_px[ci, v]).max() < 0.5
    meta = calibrated.to_capture()[0].meta
    assert meta["rig_calibrated"] is True and "calibrated" in meta["rig_source"]
    cams = meta["calibration"]["cameras"]
    assert all(c["extrinsics_rms_px"] < 0.5 and c["intrinsics_rms_px"] < 0.5 and c["spots_used"] == [0, 1, 2]
               for c in cams.values())


# --- files -----------------------------------------------------------------------------------
def test_capture_round_trip(ideal, tmp_path):
    cap, files = ideal.to_capture()
    cap.save(tmp_path, files)
    back = Capture.load(tmp_path)
    back.verify()
    assert back.kind == "pitch" and back.rig.names == ideal.rig.rig.names and back.rig.world == "field"
    assert back.meta["rig_calibrated"] is False and back.meta["rig_source"].startswith("true rig")
    for a, b in zip(back.rig, ideal.capture_rig):
        np.testing.assert_allclose(a.world2cam, b.world2cam)
    assert [im.meta["pair"] for im in back.images] == ["front", "front", "back", "back"]
    assert np.array_equal(back.read_image(2), ideal.images[2])
    tr = PitchTruth.from_dict(back.truth)
    for a, b in zip(tr.pairs, ideal.truth.pairs):
        for key in ("times", "ball2world", "visible", "flash_index"):
            np.testing.assert_allclose(getattr(a, key), getattr(b, key))
        np.testing.assert_allclose(a.centers_px, b.centers_px)  # NaN where not seen, both sides
        np.testing.assert_allclose(a.markers_px, b.markers_px)
    np.testing.assert_allclose(tr.release.spin, ideal.truth.release.spin)
    assert tr.metrics == back.truth["metrics"] and tr.metrics["release_speed_mph"] == pytest.approx(
        np.linalg.norm(ideal.truth.release.v0) / MPH)
    assert back.truth["time_offset_s"] == pytest.approx(ideal.truth.time_offset_s)


def test_cli_writes_a_capture_folder(tmp_path, capsys):
    out = tmp_path / "pitch"
    main(["studio", "pitch", "--out", str(out), "--seed", "5", "--preset", "seed-curveball", "--no-calibrate",
          "--size", "640x480", "--speed-mph", "62.5", "--front-hz", "70", "--jpeg", "92"])
    cap = Capture.load(out)
    cap.verify()
    assert cap.kind == "pitch" and cap.images[0].file.endswith(".jpg") and cap.images[0].strobe_hz == 70
    assert cap.truth["preset"]["name"] == "seed-curveball"
    assert cap.truth["metrics"]["release_speed_mph"] == pytest.approx(62.5)
    assert cap.meta["rig_calibrated"] is False
    main(["studio", "pitch", "--list-presets"])
    listed = capsys.readouterr().out
    assert all(name in listed for name in PRESETS)


def test_cli_bad_options_are_user_errors(tmp_path, capsys):
    for args, words in ((["--preset", "knuckler"], "knuckler"), (["--front-hz", "0"], "front_hz"),
                        (["--size", "1000x1000"], "4:3"), (["--size", "640x480"], "calibrate")):
        with pytest.raises(SystemExit) as e:
            main(["studio", "pitch", "--out", str(tmp_path / "x"), *args])
        assert e.value.code == 2 and words in capsys.readouterr().err, args
    with pytest.raises(SystemExit):
        main(["studio", "pitch"])
    assert "--out" in capsys.readouterr().err


@pytest.mark.parametrize("kwargs, match", [
    (dict(preset="knuckler"), "unknown pitch preset 'knuckler'"),
    (dict(speed_mph=150), "speed_mph must be between 20 and 110"),
    (dict(spin_rpm=-5), "spin_rpm must be between 0 and 6000"),
    (dict(spin_axis_deg=400), "spin_axis_deg is a Statcast axis"),
    (dict(spin_efficiency=1.5), r"spin_efficiency must be in \[0, 1\]"),
    (dict(release_m=(0, 16)), r"release_m must have shape \(3,\)"),
    (dict(release_m=(0, 30, 1.8)), "release_m must be a field-frame point"),
    (dict(target_m=(0, 9)), "target_m is"),
    (dict(front_hz=-80), "front_hz must be a strobe rate"),
    (dict(back_hz=5000), "back_hz must be a strobe rate"),
    (dict(palette={"purple": (1, 0, 1)}), "unknown marker types"),
    (dict(palette=[(1, 0, 0)]), "palette must be a dict"),
    (dict(model="newton"), "unknown flight model 'newton'; choose one of seed, nathan"),
    (dict(image_size=(640, 640)), "4:3 aspect ratio"),
    (dict(image_size=(640, 480), calibrate=True), "calibrate=True needs images at least 960 px"),
    (dict(release_time_s=2.0), "release_time_s must be within the shutter"),
    (dict(supersample=0), "supersample must be >= 1"),
    (dict(calibrate=True, image_size=(1280, 960), calibration_views=2), "at least 3 close-up views"),
    (dict(variation="small"), "variation must be a ReleaseVariation or None"),
])
def test_bad_options_raise_clear_errors(kwargs, match):
    kw = dict(rng=0, calibrate=False, image_size=(256, 192))
    kw.update(kwargs)
    preset = kw.pop("preset", "seed-4seam")
    with pytest.raises(ValueError, match=match):
        pitch_capture(preset, **kw)
    with pytest.raises(ValueError, match="spin_rpm must be a finite number >= 0"):
        ReleaseVariation(spin_rpm=-1)


def test_truth_of_an_older_capture_keeps_pitchfx_movement_under_its_new_keys():
    from stillcap.studio.compare.pitch import _current_metric_keys

    old = {"movement_axis_deg": 200.0, "pfx_x_in": -5.0, "pfx_z_in": 9.0, "induced_vertical_break_in": 9.0,
           "horizontal_break_in": -5.0, "plate_x_ft": 0.1}
    new = _current_metric_keys(old)
    assert new == {"pitchfx_spin_dir_deg": 200.0, "pitchfx_pfx_x_in": -5.0, "pitchfx_pfx_z_in": 9.0, "plate_x_ft": 0.1}
    current = {"pitchfx_pfx_x_in": 1.0, "pfx_x_in": 2.0, "movement_axis_deg": 3.0}
    assert _current_metric_keys(current) is current
