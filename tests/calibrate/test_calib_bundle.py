"""N-camera rigs: spanning-tree initialisation + bundle adjustment on a synthetic 4-camera rig."""

import numpy as np
import pytest

from stillcap.calibrate import calibrate_rig, calibrate_rig_from_points, rig_images_from_folder
from stillcap.camera import Camera


def _center_errors(rig, truth):
    """Distances (m) between calibrated centres and true centres expressed in rig camera 0's frame."""
    W0 = truth[rig.names[0]].world2cam
    return np.array([np.linalg.norm(c.center - (W0[:3, :3] @ truth[c.name].center + W0[:3, 3])) for c in rig])


@pytest.fixture(scope="module")
def rig4(synth):
    return synth.synthetic_rig(n_cams=4, n_instants=14, noise_px=0.3, rng=0)


def test_bundle_adjustment_recovers_centers_and_beats_initialisation(rig4):
    truth = {c.name: c for c in rig4.cameras}
    res = calibrate_rig_from_points(rig4.views, cameras=truth)
    assert res.success and res.rig.names == ["cam0", "cam1", "cam2", "cam3"]
    np.testing.assert_allclose(res.rig[0].world2cam, np.eye(4), atol=1e-12)
    err, err0 = _center_errors(res.rig, truth), _center_errors(res.initial_rig, truth)
    assert err.max() < 0.003  # metres, cameras 2.2 m from the board
    assert err.sum() < 0.6 * err0.sum()
    assert res.rms_px < res.initial_rms_px and 0.35 < res.rms_px < 0.5  # 0.3 px noise per axis
    assert set(res.per_camera_rms_px) == set(truth) and len(res.instants_used) == 14
    # board poses come out in the world (camera 0) frame
    W0 = truth["cam0"].world2cam
    for k, name in enumerate(res.instants_used):
        true_b2w = W0 @ rig4.board2world[int(name[1:])]
        assert np.linalg.norm(res.board2world[name][:3, 3] - true_b2w[:3, 3]) < 0.005


def test_camera_order_is_kept_and_first_is_world(rig4):
    truth = {c.name: c for c in rig4.cameras}
    order = ["cam2", "cam0", "cam3", "cam1"]
    res = calibrate_rig_from_points({k: rig4.views[k] for k in order}, cameras=truth)
    assert res.rig.names == order
    np.testing.assert_allclose(res.rig["cam2"].world2cam, np.eye(4), atol=1e-12)
    assert _center_errors(res.rig, truth).max() < 0.003
    # relative geometry does not depend on the order
    ref = calibrate_rig_from_points(rig4.views, cameras=truth).rig
    rel = res.rig["cam3"].world2cam @ np.linalg.inv(res.rig["cam1"].world2cam)
    rel_ref = ref["cam3"].world2cam @ np.linalg.inv(ref["cam1"].world2cam)
    np.testing.assert_allclose(rel, rel_ref, atol=1e-3)


def test_names_that_sort_differently_keep_their_order(synth):
    names = ["cam_10", "cam_2", "cam_1", "cam_20"]
    s = synth.synthetic_rig(n_instants=10, names=names, rng=1)
    res = calibrate_rig_from_points(s.views, cameras={c.name: c for c in s.cameras})
    assert res.rig.names == names and list(res.per_camera_rms_px) == names


def test_refine_intrinsics_from_a_poor_start(synth):
    s = synth.synthetic_rig(n_instants=10, rng=2)
    poor = {}
    for c in s.cameras:
        K = c.K.copy()
        K[0, 0] *= 1.02
        K[1, 1] *= 1.02
        K[0, 2] += 4
        poor[c.name] = Camera(c.name, K, c.dist * 0.8, np.eye(4), c.image_size)
    fixed = calibrate_rig_from_points(s.views, cameras=poor)
    res = calibrate_rig_from_points(s.views, cameras=poor, refine_intrinsics=True)
    # measured: RMS 0.433 -> 0.418 px, worst centre 68 -> 7 mm, fx within 0.4 % (started 2 % off)
    assert res.rms_px < fixed.rms_px - 0.01
    for c, t in zip(res.rig, s.cameras):
        assert abs(c.K[0, 0] / t.K[0, 0] - 1) < 0.006
    truth = {c.name: c for c in s.cameras}
    assert _center_errors(res.rig, truth).max() < 0.015 < _center_errors(fixed.rig, truth).max()


def test_robust_to_a_few_gross_outliers(rig4):
    rng = np.random.default_rng(3)
    views = {}
    for k, vs in rig4.views.items():
        views[k] = []
        for v in vs:
            if v is not None:
                px = v[1].copy()
                bad = rng.random(len(px)) < 0.02
                px[bad] += rng.normal(0, 15, (bad.sum(), 2))
                v = (v[0], px)
            views[k].append(v)
    truth = {c.name: c for c in rig4.cameras}
    res = calibrate_rig_from_points(views, cameras=truth)
    assert _center_errors(res.rig, truth).max() < 0.005


def test_rig_bad_input(rig4):
    truth = {c.name: c for c in rig4.cameras}
    views = {k: list(v) for k, v in rig4.views.items()}
    with pytest.raises(ValueError, match="at least 2 cameras, got 1"):
        calibrate_rig_from_points({"cam0": views["cam0"]}, cameras=truth)
    with pytest.raises(ValueError, match="different numbers of instants: cam0: 14, cam1: 13"):
        calibrate_rig_from_points({"cam0": views["cam0"], "cam1": views["cam1"][:-1]}, cameras=truth)
    with pytest.raises(ValueError, match="camera 'cam1': no intrinsics given and no image_size"):
        calibrate_rig_from_points(views, cameras={"cam0": truth["cam0"]})
    # cam3 sees the board only when nobody else does
    lonely = {k: list(v) for k, v in views.items()}
    first = next(i for i, v in enumerate(lonely["cam3"]) if v is not None)
    for k in ("cam0", "cam1", "cam2"):
        lonely[k][first] = None
    lonely["cam3"] = [v if i == first else None for i, v in enumerate(lonely["cam3"])]
    with pytest.raises(ValueError, match="cam3 share no target view with camera 'cam0'"):
        calibrate_rig_from_points(lonely, cameras=truth)
    with pytest.raises(ValueError, match="different numbers of images.*a: 2, b: 1"):
        calibrate_rig({"a": [np.zeros((4, 4))] * 2, "b": [np.zeros((4, 4))]}, None)
    with pytest.raises(ValueError, match="camera 'b': no images given"):
        calibrate_rig({"a": [np.zeros((4, 4))], "b": [None]}, None)


def test_rig_folder_layout(tmp_path):
    for cam, files in {"cam10": ["001.png", "002.png"], "cam2": ["001.png", "010.png"], "cam1": ["002.png"]}.items():
        (tmp_path / cam).mkdir()
        for f in files:
            (tmp_path / cam / f).write_bytes(b"")
    (tmp_path / "cam1" / "notes.txt").write_text("ignored")
    images, instants = rig_images_from_folder(tmp_path)
    assert list(images) == ["cam1", "cam2", "cam10"]  # natural order, not "cam10" < "cam2"
    assert instants == ["001", "002", "010"]
    assert [p and p.name for p in images["cam2"]] == ["001.png", None, "010.png"]
    with pytest.raises(ValueError, match="does not exist"):
        rig_images_from_folder(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty holds no images"):
        rig_images_from_folder(tmp_path)
