"""Regression: `calibrate stereo --refine-intrinsics` showed the refined K next to the single-camera RMS.

``cv2.stereoCalibrateExtended`` writes the refined intrinsics into the K and dist arrays it is
given; it was given the arrays of ``StereoResult.left.camera`` / ``.right.camera`` (and of cameras
the caller passed), so the single-camera results silently changed to the stereo fit's values.
"""

import json

import numpy as np

from stillcap.calibrate import calibrate_from_detections, calibrate_stereo_from_detections
from support import run_cli


def test_refined_stereo_leaves_single_camera_results_alone(synth):
    _, _, pairs = synth.stereo_detections(np.random.default_rng(7), noise=0.3)
    alone_l = calibrate_from_detections([a for _, a, _ in pairs], "left")
    alone_r = calibrate_from_detections([b for _, _, b in pairs], "right")
    res = calibrate_stereo_from_detections(pairs, fix_intrinsics=False)
    # the single-camera results hold exactly what intrinsics calibration returned ...
    # (to 1e-6: OpenCV's calibrateCamera varies in the 8th digit from run to run)
    for got, alone in ((res.left, alone_l), (res.right, alone_r)):
        np.testing.assert_allclose(got.camera.K, alone.camera.K, rtol=1e-6)
        np.testing.assert_allclose(got.camera.dist, alone.camera.dist, rtol=1e-6, atol=1e-7)
        # ... and the refined K, far from it, appears only in the refined rig
        refined = res.rig[got.camera.name].K
        assert abs(refined[0, 0] - alone.camera.K[0, 0]) > 0.05, refined[0, 0] - alone.camera.K[0, 0]


def test_refined_stereo_leaves_given_cameras_alone(synth):
    left, right, pairs = synth.stereo_detections(np.random.default_rng(9), noise=0.3)
    K_l, d_l, K_r, d_r = left.K.copy(), left.dist.copy(), right.K.copy(), right.dist.copy()
    res = calibrate_stereo_from_detections(pairs, left, right, fix_intrinsics=False)
    np.testing.assert_array_equal(left.K, K_l)
    np.testing.assert_array_equal(left.dist, d_l)
    np.testing.assert_array_equal(right.K, K_r)
    np.testing.assert_array_equal(right.dist, d_r)
    assert not np.array_equal(res.rig["left"].K, K_l)


def test_cli_refine_intrinsics_prints_each_number_with_its_rms(capsys, stereo_dir):
    photos = sorted(stereo_dir.glob("*.jpg"))
    code, out, err = run_cli(["calibrate", "stereo", *photos, "--square", "1", "--refine-intrinsics"], capsys)
    assert code == 0, err
    lines = out.splitlines()
    # single-camera results: OpenCV's reference intrinsics (data README) beside their own RMS
    i = next(k for k, s in enumerate(lines) if s.startswith("camera left: RMS 0.409 px"))
    assert "fx 536.07  fy 536.02  cx 342.37  cy 235.54" in lines[i + 1]
    i = next(k for k, s in enumerate(lines) if s.startswith("camera right: RMS 0.459 px"))
    assert "fx 542.35  fy 541.62  cx 328.32  cy 246.95" in lines[i + 1]
    # the refined intrinsics appear once, under the stereo RMS
    i = next(k for k, s in enumerate(lines) if s.startswith("stereo: RMS"))
    refined = "\n".join(lines[i:])
    assert "intrinsics refined" in lines[i] and "left fx 535." in refined and "right fx 539." in refined
    assert "fx 536.07" not in refined and "fx 542.35" not in refined

    code, out, err = run_cli(["calibrate", "stereo", *photos, "--square", "1", "--refine-intrinsics", "--json"],
                             capsys)
    d = json.loads(out)
    assert abs(d["left"]["fx"] - 536.07) < 0.01 and abs(d["right"]["fx"] - 542.35) < 0.01
    assert abs(d["refined"]["left"]["fx"] - 536.07) > 0.1 and d["refined"]["rms_px"] == d["rms_px"]


def _arrays(cams):
    return [(c.K.copy(), c.dist.copy(), c.world2cam.copy()) for c in cams]


def _unchanged(cams, before):
    for c, (K, d, T) in zip(cams, before):
        np.testing.assert_array_equal(c.K, K)
        np.testing.assert_array_equal(c.dist, d)
        np.testing.assert_array_equal(c.world2cam, T)


def test_no_solver_writes_into_the_callers_arrays(synth):
    # Every OpenCV / SciPy solver call of calibrate/ gets arrays a result or the caller also holds:
    # PnP (+ LM refinement), calibrateCamera with a K guess, the rig's bundle adjustment with
    # intrinsics refined. None may change them.
    from stillcap.calibrate import calibrate_intrinsics_from_points, calibrate_rig_from_points, pose_from_points

    left, _, pairs = synth.stereo_detections(np.random.default_rng(3), noise=0.2)
    before = _arrays([left])
    pose_from_points(left, pairs[0][1].object_points, pairs[0][1].image_points)
    _unchanged([left], before)

    K_guess = left.K.copy() * [[1.05], [1.05], [1]]
    guess = K_guess.copy()
    calibrate_intrinsics_from_points([a.object_points for _, a, _ in pairs], [a.image_points for _, a, _ in pairs],
                                     left.image_size, K_guess=K_guess)
    np.testing.assert_array_equal(K_guess, guess)

    rig = synth.synthetic_rig(n_cams=3, n_instants=8, noise_px=0.3, rng=1)
    before = _arrays(rig.cameras)
    res = calibrate_rig_from_points(rig.views, cameras={c.name: c for c in rig.cameras}, refine_intrinsics=True)
    _unchanged(rig.cameras, before)
    assert not np.array_equal(res.rig[1].K, rig.cameras[1].K)  # the refined values live in the result only
