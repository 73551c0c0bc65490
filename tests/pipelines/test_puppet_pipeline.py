"""The puppet pipeline on rendered turntable photos: markers named, triangulated, skeleton posed."""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.body import MarkerSet, Pose, Skeleton
from stillcap.camera import Rig
from stillcap.io.project import Project
from stillcap.body.puppet_pose import fit_pose, frame_status
from stillcap.detect.beads import bead_fill, bright_region, reidentify
from stillcap.io.puppet_result import load_result
from stillcap.pipelines.puppet import (DEFAULT, THESIS_CHAIN, PuppetOptions, analyse_puppet, analyse_puppet_views,
                                       solve_markers)
from stillcap.geometry.triangulate import triangulate, triangulate_markers
from stillcap.studio.compare.puppet import compare_with_capture, compare_with_truth
from stillcap.studio.puppet import puppet_scene
from support import assert_same_reconstruction


# supersample=1 (edge rays not re-traced) halves the render time; the numbers below were
# measured on exactly these renders (fixed seeds).
@pytest.fixture(scope="module")
def tpose():
    return puppet_scene(pose="tpose", rng=1, supersample=1)


@pytest.fixture(scope="module")
def random3():
    return puppet_scene(pose="random:3", rng=3, supersample=1)


def _run(scene, options=DEFAULT):
    res = analyse_puppet_views(scene.rig, scene.images, options=options, angles_deg=list(scene.truth.angles_deg))
    res.comparison = compare_with_truth(res, scene.truth)
    return res


def test_tpose_every_marker_recovered_without_a_wrong_identification(tpose):
    res = _run(tpose)
    c = res.comparison
    assert c.recovered_seen_twice == c.seen_twice == 16 and not res.missing
    assert c.wrong == 0 and c.right_visible == c.visible  # measured: 150 of 150 visible beads, none wrong
    assert c.marker_rms_mm() < 0.15 and c.marker_max_mm() < 0.3  # measured 0.09 / 0.14 mm
    assert c.bone_stats("full")[1] < 0.5  # measured 0.17 deg
    assert c.bone_stats("partial")[1] < 0.5  # the prior's centre is the rest pose
    assert c.joint_stats("full")[1] < 0.3  # mm; measured 0.17
    # the reprojection of every used view is sub-pixel
    assert np.nanmax(res.markers.reproj_error_px) < 0.6  # px RMS; measured 0.41


def test_random_pose_recovers_every_marker_seen_twice(random3):
    res = _run(random3)
    c = res.comparison
    assert c.recovered_seen_twice == c.seen_twice
    assert c.wrong_used == 0  # wrong 2D identifications (a few partly hidden beads) never reach 3D
    assert c.wrong == 0  # the final identification follows the 3D markers (see the test below)
    assert c.marker_rms_mm() < 0.3 and c.marker_max_mm() < 1.0  # measured 0.09 / 0.21 mm
    assert c.bone_stats("full")[0] < 0.5 and c.bone_stats("full")[1] < 1.0  # measured 0.16 / 0.32 deg
    assert c.joint_stats("full")[1] < 0.6  # mm; measured 0.15
    assert c.bone_stats("partial")[1] < 5.0  # one bead per forearm / shin; measured 1.4 deg
    # the fit beats the thesis's bone directions on every measured bone group
    assert c.bone_stats("full")[0] < c.bone_stats("full", thesis=True)[0]
    # the result dict shares its keys with the truth and is strict JSON
    d = res.to_dict()
    truth = random3.truth.to_dict()
    for key in ("markers", "joints", "root2world", "cameras", "angles_deg", "markers_px"):
        assert key in d and key in truth
    assert [m["name"] for m in d["markers"]] == [m["name"] for m in truth["markers"]]
    assert [j["name"] for j in d["joints"]] == [j["name"] for j in truth["joints"]]
    np.testing.assert_allclose(np.array([m["position"] for m in d["markers"]], float),
                               np.array([m["position"] for m in truth["markers"]], float), atol=1e-3)
    text = json.dumps(d, allow_nan=False)
    back = load_result(json.loads(text))
    np.testing.assert_allclose(back.pose.positions, res.pose.positions, atol=1e-12)
    np.testing.assert_allclose(back.markers.points[0], res.markers.points, atol=1e-12)


def test_thesis_chain_runs(random3):
    # the thesis's detector finds few beads on these renders (IsoData picks a threshold in the
    # background noise, see docs/puppet.md) and is slow; two views show that the chain runs
    rig = Rig(list(random3.rig)[:2], random3.rig.world)
    res = analyse_puppet_views(rig, random3.images[:2], options=THESIS_CHAIN)
    assert res.options.pose == "thesis" and res.pose is res.thesis_pose
    assert res.views[0].circles.method == "thesis" and res.views[0].identification.method == "greedy"
    assert res.markers.observations.shape == (2, 16, 2)


def test_fit_pose_recovers_twist_the_thesis_cannot_see():
    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    local = np.tile(np.eye(3), (sk.n_joints, 1, 1))
    twist = {"l-shoulder": [50, -20, -30], "upper-back": [0, 35, 0], "l-hip": [-40, 25, 0], "lower-back": [10, 0, 5]}
    for j, a in twist.items():
        local[sk.index(j)] = Rotation.from_euler("XYZ", a, degrees=True).as_matrix()
    truth = Pose(sk, sk.rest_root2world(), local)
    fit = fit_pose(sk, ms, ms.positions(truth))
    for j in twist:  # within 0.2 deg: the weak prior (sd = half the range) pulls a little even here
        d = Rotation.from_matrix(fit.pose.local_rotations[sk.index(j)] @ local[sk.index(j)].T).magnitude()
        assert np.degrees(d) < 0.2, j
    assert np.nanmax(fit.residuals_m) < 0.02e-3
    # the thesis's rules see the torso's bone but not its twist about it: the shoulders are off
    th = fit.thesis_pose.bone_vectors()[sk.index("l-shoulder")]
    tv = truth.bone_vectors()[sk.index("l-shoulder")]
    assert np.degrees(np.arccos(th @ tv / np.linalg.norm(th) / np.linalg.norm(tv))) > 20
    assert not sk.limit_violations(fit.pose.local_rotations).any()


def test_frame_status_of_the_puppet():
    s = frame_status(Skeleton.puppet(), MarkerSet.puppet())
    assert s["root"] == "locked" and s["head"] == "locked"
    assert all(s[j] == "full" for j in ("lower-back", "upper-back", "l-shoulder", "r-shoulder", "l-hip", "r-hip"))
    assert all(s[j] == "partial" for j in ("l-elbow", "r-elbow", "l-knee", "r-knee"))
    assert all(s[j] == "none" for j in ("l-hand", "r-hand", "l-foot", "r-foot"))


def test_elbow_bent_150_degrees_is_within_its_limits():
    # named test for the fixed bug: limits read as XYZ Euler angles capped elbow bends at 90 deg
    sk = Skeleton.puppet()
    local = np.tile(np.eye(3), (sk.n_joints, 1, 1))
    e = sk.index("l-elbow")
    for bend, ok in ((-150, True), (-120, True), (-91, True), (-160, False), (10, False)):
        local[e] = Rotation.from_euler("y", bend, degrees=True).as_matrix()
        assert sk.limit_violations(local).any() != ok, bend
        assert sk.limit_angles_deg(local)[e, 1] == pytest.approx(bend)
    local[e] = Rotation.from_euler("XYZ", [60, -140, 5], degrees=True).as_matrix()
    np.testing.assert_allclose(sk.limit_angles_deg(local)[e], [60, -140, 5], atol=1e-9)
    assert not sk.limit_violations(local).any()


def test_bead_fill_tells_whole_from_half_hidden_beads():
    img = np.full((60, 60, 3), 20, np.uint8)
    cv2.circle(img, (15, 30), 6, (200, 180, 160), -1)
    cv2.circle(img, (45, 30), 6, (200, 180, 160), -1)
    img[:, 45:52] = 20  # a dark limb hides the right half of the second bead
    f = bead_fill(img, [[15, 30], [45, 30], [np.nan, 1]], [6.4, 6.4, 6.4])
    assert f[0] > 0.8 and 0.3 < f[1] < 0.6 and np.isnan(f[2])


def test_bright_region_holds_every_bead(tpose):
    for img, px in zip(tpose.images, tpose.truth.markers_px):
        x0, y0, x1, y1 = bright_region(img)
        p = px[np.isfinite(px[:, 0])]
        assert np.all((p[:, 0] >= x0 + 5) & (p[:, 0] < x1 - 5) & (p[:, 1] >= y0 + 5) & (p[:, 1] < y1 - 5))
    assert bright_region(np.zeros((40, 50, 3), np.uint8)) == (0, 0, 50, 40)


def test_markers_seen_once_are_missing(tpose):
    names = MarkerSet.puppet().names
    obs = np.full((len(tpose.rig), 16, 2), np.nan)
    obs[:] = tpose.truth.markers_px
    obs[1:, 0] = np.nan  # head.1 only in view 0
    s = solve_markers(tpose.rig, obs, names, options=PuppetOptions(use_fill=False))
    assert s.missing == ("head.1",) and np.all(np.isnan(s.points[0]))
    assert s.ok[1:].all() and np.nanmax(s.reproj_error_px) < 0.05
    with pytest.raises(ValueError, match=r"points_2d must have shape \(12, 16, 2\)"):
        solve_markers(tpose.rig, obs[:3], names)


def test_capture_folder_and_project(tmp_path, tpose):
    cap, images = tpose.to_capture(".png")
    cap.save(tmp_path / "cap", images)
    images = list(images.values())
    res, imgs = analyse_puppet(tmp_path / "cap")
    res.comparison = compare_with_capture(res, tmp_path / "cap")
    assert len(imgs) == 12 and res.comparison is not None and res.comparison.recovered == 16
    # the same photos in a project: detected, stored, reconstructed
    p = Project.create(tmp_path / "proj")
    for img, a in zip(images[:6], tpose.truth.angles_deg[:6]):
        p.add_view(img, angle_deg=float(a))
    p.save()
    res2, _ = analyse_puppet(tmp_path / "proj")
    p = Project.load(tmp_path / "proj")
    assert all(v.detected for v in p.views)
    assert res2.markers.ok.sum() == 16 and res2.source["type"] == "project"
    np.testing.assert_allclose(res2.markers.points, tpose.truth.marker_positions, atol=5e-4)
    # an edit (delete a marker in all but one view) makes it missing
    for v in p.views[1:]:
        if "head.1" in v.markers:
            p.edit(v, delete="head.1")
    p.save()
    res3, _ = analyse_puppet(tmp_path / "proj")
    assert "head.1" in res3.missing


def test_bad_input(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        analyse_puppet(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="neither a capture folder"):
        analyse_puppet(tmp_path / "empty")
    with pytest.raises(ValueError, match="unknown detector 'sift'"):
        PuppetOptions(detector="sift")
    with pytest.raises(ValueError, match="unknown identification 'magic'"):
        PuppetOptions(identify="magic")
    with pytest.raises(ValueError, match="not a stillcap puppet result"):
        load_result({"format": "something"})


def test_identification_consistent_with_3d_has_no_wrong_marker(random3):
    # issue 4 (a): colour alone named 4 beads wrong on this pose (partly hidden beads, limb
    # edges); naming the candidates after the triangulated markers leaves none wrong
    res = _run(random3)
    c = res.comparison
    assert res.raw_observations is not None
    assert c.raw_wrong >= 2  # measured 4 colour-only: the defect is there to fix
    assert c.wrong == 0 and c.wrong_used == 0
    assert c.right_visible >= c.raw_right_visible
    # every final 2D marker lies on the projection of its 3D marker (within the gate)
    proj = np.stack([cam.project(res.markers.points) for cam in res.rig])
    d = np.linalg.norm(res.markers.observations - proj, axis=2)
    found = np.isfinite(res.markers.observations[..., 0]) & res.markers.ok[None]
    assert np.all(d[found] < 4.0)  # px; gate 0.6 x the bead radius (5-7 px)
    assert res.to_dict()["comparison"]["identification"]["colour_only"]["wrong"] == c.raw_wrong
    # without re-identification the colour's own naming stays (what the raw numbers count)
    plain = _run(random3, PuppetOptions(reidentify=False))
    assert plain.raw_observations is None
    np.testing.assert_array_equal(plain.markers.observations, res.raw_observations)


def test_reidentify_leaves_a_marker_without_matching_candidate_unidentified(random3):
    res = _run(random3)
    pts = res.markers.points.copy()
    k = int(np.flatnonzero(res.markers.ok)[0])
    pts[k] += [0.02, 0.0, 0.0]  # 20 mm off: its projection lands on no candidate of its colour
    out = reidentify(res.rig, pts, res.views)
    assert out.shape == res.markers.observations.shape
    assert not np.isfinite(out[:, k, 0]).any()
    with pytest.raises(ValueError, match=r"points_3d must have shape \(n_markers, 3\), got \(16, 2\)"):
        reidentify(res.rig, pts[:, :2], res.views)


def test_triangulate_markers_is_the_shared_triangulation(random3):
    # the puppet's fast consensus (all view pairs in one call) gives the shared function's result
    res = _run(random3, PuppetOptions(reidentify=False))
    x = res.markers.observations.copy()
    rng = np.random.default_rng(5)
    bad = rng.random(x.shape[:2]) < 0.08
    x[bad] += rng.normal(0.0, 6.0, (int(bad.sum()), 2))  # wrong identifications
    for o in (1.0, 2.0):
        a, b = triangulate(res.rig, x, outlier_px=o), triangulate_markers(res.rig, x, outlier_px=o)
        np.testing.assert_array_equal(a.used, b.used)
        np.testing.assert_allclose(b.points, a.points, atol=1e-9)
    with pytest.raises(ValueError, match=r"points_2d must have shape \(12, N, 2\), got \(3, 16, 2\)"):
        triangulate_markers(res.rig, x[:3])


def test_the_final_names_are_solved_once_as_a_full_solve(random3, monkeypatch):
    """triangulate_beads renames the candidates after the first pass's 3D markers (solve_markers'
    2 px consensus of the colour names) and solves the final names once: the same 3D markers,
    views and fill as solve_markers on them from scratch; and the first pass's view-pair
    hypotheses reused for the final consensus give its own result."""
    import stillcap.pipelines.puppet.stages as stages

    seen, real = [], stages.one_name_per_bead
    monkeypatch.setattr(stages, "one_name_per_bead", lambda rig, pts, *a, **k: seen.append(pts) or real(rig, pts, *a, **k))
    res = _run(random3)
    first = triangulate_markers(res.rig, res.raw_observations, "dlt", False, 2.0)  # linear, 2 px consensus
    np.testing.assert_array_equal(seen[0], first.points)  # named after the first pass, before any fill test
    final = res.markers.observations
    names = res.markerset.names
    full = solve_markers(res.rig, final, names, random3.images, DEFAULT, bead_radius_m=0.003)
    changed = ~np.all((np.isnan(final) & np.isnan(res.raw_observations)) | (final == res.raw_observations),
                      axis=(0, 2))
    assert 0 < changed.sum() < len(names)  # some markers renamed, some not
    np.testing.assert_allclose(res.markers.points, full.points, atol=1e-9)
    for k in ("used", "partial", "outlier", "whole"):
        np.testing.assert_array_equal(getattr(res.markers, k), getattr(full, k))
    np.testing.assert_array_equal(res.markers.fill, full.fill)
    np.testing.assert_allclose(res.markers.reproj_error_px, full.reproj_error_px, atol=1e-9)
    assert res.markers.noise_px == full.noise_px  # measured on the final names' whole views
    # the final consensus on the views left after the fill test, from scratch
    x_used = np.where(full.partial[..., None], np.nan, final)
    own = triangulate_markers(res.rig, x_used, outlier_px=DEFAULT.outlier_px)
    np.testing.assert_array_equal(own.used, full.triangulation.used)
    np.testing.assert_allclose(own.points, full.triangulation.points, atol=1e-9)


def _fit_bone_errors(angles: dict) -> dict:
    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    local = np.tile(np.eye(3), (sk.n_joints, 1, 1))
    for j, a in angles.items():
        local[sk.index(j)] = Rotation.from_euler("XYZ", a, degrees=True).as_matrix()
    truth = Pose(sk, sk.rest_root2world(), local)
    fit = fit_pose(sk, ms, ms.positions(truth))
    f, t = fit.pose.bone_vectors(), truth.bone_vectors()
    return {b: float(np.degrees(np.arccos(np.clip(f[sk.index(b)] @ t[sk.index(b)] / np.linalg.norm(f[sk.index(b)])
                                                  / np.linalg.norm(t[sk.index(b)]), -1, 1))))
            for b in ("l-hand", "r-hand", "l-foot", "r-foot")}


def test_forearm_and_shin_directions_on_the_hinge_and_off_it():
    # issue 4 (b): one bead per forearm / shin fixes two of the three angles of the elbow (knee);
    # on the hinge (the off-hinge angles 0) the fit's prior picks the truth: the elbow bent
    # 120 degrees (past the +-90 the retargeting clips to) comes out within 0.5 degrees
    hinge = {"l-shoulder": [20, -30, 10], "l-hip": [-50, 10, 0], "l-elbow": [30, -120, 0], "r-elbow": [-40, 70, 0],
             "l-knee": [80, 0, 0], "r-knee": [40, 0, 0]}
    e = _fit_bone_errors(hinge)
    assert max(e.values()) < 0.5, e  # measured 0.03-0.09 deg
    # the limits allow +-10 degrees off the hinge, which the one bead cannot see: 8 degrees of
    # elbow Z or knee Y (twist of the shin about itself moves the bead, not the bone) is not
    # recovered (measured 0.6-1.5 degrees of bone error); this is the floor of the "partial" group
    off = dict(hinge, **{"l-elbow": [30, -120, 8], "l-knee": [80, 8, 0]})
    e2 = _fit_bone_errors(off)
    assert e2["l-hand"] > 0.5 and e2["l-foot"] > 0.5, e2


def test_threads_give_the_serial_result(tmp_path, random3):
    """Decoding and detecting the views on two threads changes nothing (order and values)."""
    cap, images = random3.to_capture(".jpg")
    cap.save(tmp_path / "cap", images, jpeg_quality=85)
    seen = []
    one, _ = analyse_puppet(tmp_path / "cap", workers=1)
    two, _ = analyse_puppet(tmp_path / "cap", workers=2, progress=lambda d, n: seen.append((d, n)))
    assert seen == [(k, 12) for k in range(1, 13)]
    assert_same_reconstruction(one, two)
    assert np.isfinite(two.markers.points).all(axis=1).sum() >= 14
    with pytest.raises(ValueError, match=r"need one detection per view \(12\), got 3"):
        analyse_puppet_views(random3.rig, random3.images, detections=one.views[:3])


def test_pipeline_runs_blas_on_one_thread_and_restores_the_callers_setting(monkeypatch, random3):
    from threadpoolctl import threadpool_info, threadpool_limits

    import stillcap.pipelines.puppet.stages as pipe

    def blas_threads():
        return sorted({d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"})

    inside = []
    real = pipe.solve_markers

    def spy(*args, **kwargs):
        inside.append(blas_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(pipe, "solve_markers", spy)
    obs = np.stack([v.identification.points for v in _run(random3).views])
    inside.clear()
    with threadpool_limits(2, user_api="blas"):
        res = analyse_puppet_views(random3.rig, observations=obs)
        assert blas_threads() == [2]
    assert np.isfinite(res.markers.points).all(axis=1).sum() >= 14
    assert inside == [[1]]


def test_threads_give_the_serial_result_for_cameras_that_are_not_srgb(tmp_path, random3):
    """The decoding thread re-encodes each photo through its camera's response (here a 2.6
    power law, not sRGB): the same circles, names, markers and pose as the serial path, which
    re-encodes them in analyse_puppet_views. The photos were made sRGB, so the stated response
    changes the colours the beads are named by: the path taken is not the all-sRGB one."""
    from dataclasses import replace

    from stillcap.response import Response

    cap, images = random3.to_capture(".jpg")
    cap = replace(cap, rig=cap.rig.with_responses(Response.power(2.6)))
    cap.save(tmp_path / "cap", images, jpeg_quality=85)
    one, _ = analyse_puppet(tmp_path / "cap", workers=1)
    two, _ = analyse_puppet(tmp_path / "cap", workers=2)
    assert_same_reconstruction(one, two)
    srgb, _ = analyse_puppet(tmp_path / "cap", workers=1, options=replace(DEFAULT, response=Response.srgb()))
    assert not np.array_equal(srgb.views[0].identification.cost, one.views[0].identification.cost)


def test_threads_keep_an_srgb_rig(tmp_path, random3):
    """Cameras that are all sRGB already: the threaded path passes the capture's rig on as it is
    (the same cameras and responses as the serial path's result)."""
    cap, images = random3.to_capture(".jpg")
    cap.save(tmp_path / "cap", images, jpeg_quality=85)
    assert all(c.response.kind == "srgb" for c in cap.rig)
    one, _ = analyse_puppet(tmp_path / "cap", workers=1)
    two, _ = analyse_puppet(tmp_path / "cap", workers=2)
    assert [c.response for c in two.rig] == [c.response for c in one.rig]
    assert [c.name for c in two.rig] == [c.name for c in one.rig]
    for a, b in zip(one.rig, two.rig):
        np.testing.assert_array_equal(a.world2cam, b.world2cam)


def test_capture_markerset_reads_the_entry_and_names_bad_ones():
    from types import SimpleNamespace

    from stillcap.pipelines.puppet import capture_markerset

    def cap(**meta):
        return SimpleNamespace(meta=meta)

    assert len(capture_markerset("c", cap())) == 16  # no entry: the thesis's 16 beads
    assert capture_markerset("c", cap(markerset="puppet-20")).names == MarkerSet.builtin("puppet-20").names
    ms = MarkerSet.puppet("puppet-20")
    assert capture_markerset("c", cap(markerset=ms.to_dict("mm"))).to_dict() == ms.to_dict()
    with pytest.raises(ValueError, match=r"capture c: unknown marker set 'puppet-99' \(built-in: puppet-16"):
        capture_markerset("c", cap(markerset="puppet-99"))
    with pytest.raises(ValueError, match="capture c: unknown marker set 'markers.json'"):
        capture_markerset("c", cap(markerset="markers.json"))  # a capture names no marker-set file
    with pytest.raises(ValueError, match=r"capture c: .markerset. must be a built-in name or a marker set \(.*\), got 20"):
        capture_markerset("c", cap(markerset=20))
    with pytest.raises(ValueError, match=r"c/capture\.json: markerset: not a marker-set file"):
        capture_markerset("c", cap(markerset={"format": "other"}))


def test_every_entry_point_searches_one_candidate_per_bead():
    from stillcap.pipelines.puppet.options import _options_for

    twenty = MarkerSet.puppet("puppet-20")
    assert _options_for(DEFAULT, twenty).n_circles == 20
    assert _options_for(DEFAULT, MarkerSet.puppet()) is DEFAULT  # 16 beads: the thesis's 16 circles
    assert _options_for(PuppetOptions(n_circles=30), twenty).n_circles == 30  # never fewer than asked
