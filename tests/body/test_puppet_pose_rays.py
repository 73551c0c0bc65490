"""Single-view rays in the pose fit (stillcap.body.puppet_pose.MarkerRays, fit_pose(rays=...)):
a puppet-20 forearm or shin bead seen in one view only still fixes the segment's twist; a
wrong ray is rejected; a triangulated marker is never counted twice."""

import numpy as np
import pytest

from stillcap.body import MarkerSet, Skeleton
from stillcap.body.puppet_pose import MarkerRays, fit_pose
from stillcap.calibrate.turntable import turntable_rig
from stillcap.studio.puppet import random_pose

SK, MS = Skeleton.puppet(), MarkerSet.puppet("puppet-20")
RIG = turntable_rig()
DROP = ("arm.L4", "leg.R4")  # the second bead of a forearm and of a shin
BONES = ("l-hand", "r-foot")  # the bones (named after their end joint) those beads orient


def _bone_err_deg(pose, truth, bones=BONES):
    a, b = pose.bone_vectors(), truth.bone_vectors()
    out = []
    for bn in bones:
        j = SK.index(bn)
        c = a[j] @ b[j] / np.linalg.norm(a[j]) / np.linalg.norm(b[j])
        out.append(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    return np.array(out)


def _case(seed, px_noise=0.3, mm_noise=0.15):
    rng = np.random.default_rng(seed)
    truth = random_pose(SK, seed, MS)
    X = MS.positions(truth)
    obs = np.stack([c.project(X) for c in RIG]) + rng.normal(0, px_noise, (len(RIG), len(MS), 2))
    pts = X + rng.normal(0, mm_noise * 1e-3, X.shape)
    drop = [MS.index(n) for n in DROP]
    pts[drop] = np.nan
    one = np.full_like(obs, np.nan)
    one[seed % len(RIG), drop] = obs[seed % len(RIG), drop]  # each dropped bead seen in one view
    return truth, pts, one


def test_a_bead_seen_in_one_view_fixes_its_segment():
    without, with_rays = [], []
    for seed in range(8):
        truth, pts, one = _case(seed)
        rays = MarkerRays.from_views(RIG, one, ~np.all(np.isfinite(pts), axis=1))
        assert len(rays) == 2 and set(rays.marker) == {MS.index(n) for n in DROP}
        f0 = fit_pose(SK, MS, pts, truth.root2world)
        f1 = fit_pose(SK, MS, pts, truth.root2world, rays=rays)
        assert f1.success and f1.ray_used.all() and np.all(f1.ray_residuals_px < 2.0)
        assert sorted(f1.ray_markers) == sorted(MS.index(n) for n in DROP)
        # the model bead is on its ray to a few tenths of a millimetre
        assert np.all(rays.distances(MS.positions(f1.pose)) < 0.5e-3)
        without.append(_bone_err_deg(f0.pose, truth))
        with_rays.append(_bone_err_deg(f1.pose, truth))
    without, with_rays = np.concatenate(without), np.concatenate(with_rays)
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))
    assert rms(with_rays) < 1.0 and rms(with_rays) < 0.6 * rms(without)
    assert with_rays.max() < 2.0


def test_a_wrong_ray_is_rejected_and_leaves_the_pose_alone():
    truth, pts, one = _case(3)
    v = 3
    i = MS.index("arm.L4")
    bad = one.copy()
    bad[v, i] += [60.0, -45.0]  # another bead's pixel: 75 px off
    rays = MarkerRays.from_views(RIG, bad, ~np.all(np.isfinite(pts), axis=1))
    fit = fit_pose(SK, MS, pts, truth.root2world, rays=rays)
    wrong = rays.marker == i
    assert not fit.ray_used[wrong].any() and fit.ray_used[~wrong].all()
    assert fit.ray_residuals_px[wrong][0] > 10.0
    ref = fit_pose(SK, MS, pts, truth.root2world, rays=rays.subset(~wrong))
    np.testing.assert_allclose(fit.pose.positions, ref.pose.positions, atol=2e-5)
    assert np.all(fit.rms_m < 0.5e-3)


def test_rays_of_triangulated_markers_are_ignored():
    truth, pts, _ = _case(1)
    X = MS.positions(truth)
    full = np.stack([c.project(X) for c in RIG])
    rays = MarkerRays.from_views(RIG, full)
    fit = fit_pose(SK, MS, pts, truth.root2world, rays=rays)
    seen = np.all(np.isfinite(pts), axis=1)
    assert not fit.ray_used[seen[rays.marker]].any() and fit.ray_used[~seen[rays.marker]].all()
    assert np.all(np.isnan(fit.ray_residuals_px[seen[rays.marker]]))
    # with only triangulated markers' rays, the fit is the plain one
    only = rays.subset(seen[rays.marker])
    np.testing.assert_allclose(fit_pose(SK, MS, pts, truth.root2world, rays=only).pose.positions,
                               fit_pose(SK, MS, pts, truth.root2world).pose.positions, atol=1e-12)


def _spy_least_squares(monkeypatch) -> list:
    """Record ``(fun, jac, x0)`` of every ``least_squares`` call the pose fit makes."""
    import stillcap.body.puppet_pose as pp

    calls = []
    real = pp.least_squares

    def spy(fun, x0, **kw):
        calls.append((fun, kw["jac"], np.array(x0)))
        return real(fun, x0, **kw)

    monkeypatch.setattr(pp, "least_squares", spy)
    return calls


def test_the_ray_jacobian_is_the_residuals_derivative(monkeypatch):
    calls = _spy_least_squares(monkeypatch)
    truth, pts, one = _case(5)
    rays = MarkerRays.from_views(RIG, one, ~np.all(np.isfinite(pts), axis=1))
    fit_pose(SK, MS, pts, truth.root2world, rays=rays)
    fun, jac, x0 = calls[0]
    J = jac(x0)
    h = 1e-6
    num = np.stack([(fun(x0 + h * e) - fun(x0 - h * e)) / (2 * h) for e in np.eye(len(x0))], axis=1)
    assert J.shape == num.shape == (3 * 18 + 2 * 2 + len(x0), len(x0))
    np.testing.assert_allclose(J, num, atol=1e-4 * np.abs(num).max())


def test_fill_sets_the_ray_sigma_and_bad_input_is_refused():
    P = np.zeros((len(MS), 3))
    P[16], P[17] = [0.01, 0.12, 0.02], [-0.03, 0.08, 0.0]
    x = np.full((len(RIG), len(MS), 2), np.nan)
    x[0, 16] = RIG[0].project(P[16])
    x[1, 17] = RIG[1].project(P[17])
    fill = np.full(x.shape[:2], np.nan)
    fill[0, 16] = 0.3
    rays = MarkerRays.from_views(RIG, x, fill=fill)
    np.testing.assert_allclose(rays.sigma_px, [6.5 * 0.5, 1.0])
    np.testing.assert_allclose(np.linalg.norm(rays.direction, axis=1), 1.0)
    # each ray leaves its camera's centre and passes through the point whose pixel it is
    np.testing.assert_allclose(rays.origin, [RIG[0].center, RIG[1].center])
    np.testing.assert_array_equal(rays.view, [0, 1])
    assert np.all(rays.distances(P) < 1e-9) and np.all(rays.depths(P) > 0.1)
    with pytest.raises(ValueError, match=r"observations must have shape \(12, n_markers, 2\), got \(3, 20, 2\)"):
        MarkerRays.from_views(RIG, x[:3])
    with pytest.raises(ValueError, match=r"fill must have shape \(12, 20\), got \(12, 19\)"):
        MarkerRays.from_views(RIG, x, fill=fill[:, :19])
    with pytest.raises(ValueError, match="ray markers must index the 16 markers"):
        fit_pose(SK, MarkerSet.puppet(), MarkerSet.puppet().positions(SK.rest_pose()), rays=rays)
    with pytest.raises(ValueError, match="rays must be a MarkerRays"):
        fit_pose(SK, MS, MS.positions(SK.rest_pose()), rays=[(16, 0, 0)])


def test_the_start_is_the_same_level_by_level_as_joint_by_joint(monkeypatch):
    """_start_angles solves the joints of one depth together (one Euler conversion per level):
    the same angles as one joint at a time, with rays and without, on both marker sets."""
    import stillcap.body.puppet_pose as pp

    levels = pp._levels(SK)
    order = np.concatenate(levels)
    assert sorted(order) == list(range(SK.n_joints))  # every joint once
    depth = {int(j): d for d, lv in enumerate(levels) for j in lv}
    assert all(SK.parents[j] < 0 or depth[SK.parents[j]] == depth[j] - 1 for j in range(SK.n_joints))
    starts = []
    real_start = pp._start_angles

    def spy(*args, **kwargs):
        starts.append(real_start(*args, **kwargs))
        return starts[-1]

    monkeypatch.setattr(pp, "_start_angles", spy)
    for ms, seed in ((MS, 3), (MarkerSet.puppet("puppet-16"), 4)):
        truth = random_pose(SK, seed, ms)
        pts = ms.positions(truth) + np.random.default_rng(seed).normal(0, 0.3e-3, (len(ms), 3))
        obs = np.stack([c.project(ms.positions(truth)) for c in RIG])
        drop = [ms.index(n) for n in (("arm.L4", "leg.R4") if ms is MS else ("arm.L3",))]
        pts[drop] = np.nan
        obs[1:] = np.nan  # the dropped beads seen in the first view only
        rays = MarkerRays.from_views(RIG, obs, ~np.all(np.isfinite(pts), axis=1)) if ms is MS else None
        for rr in (None, rays):
            starts.clear()
            fit_pose(SK, ms, pts, truth.root2world, rays=rr)
            batched = starts[0]
            monkeypatch.setattr(pp, "_levels", lambda sk: [np.array([j]) for j in sk.depth_first])
            starts.clear()
            fit_pose(SK, ms, pts, truth.root2world, rays=rr)
            monkeypatch.undo()
            monkeypatch.setattr(pp, "_start_angles", spy)
            np.testing.assert_array_equal(batched, starts[0])


def test_the_jacobian_is_of_the_parameters_asked_whatever_came_before(monkeypatch):
    """The residuals' frames are reused for the Jacobian at the same parameters only."""
    calls = _spy_least_squares(monkeypatch)
    truth, pts, one = _case(6)
    fit_pose(SK, MS, pts, truth.root2world, rays=MarkerRays.from_views(RIG, one, ~np.all(np.isfinite(pts), axis=1)))
    fun, jac, x0 = calls[0]
    J0, f0 = jac(x0).copy(), fun(x0).copy()
    x = x0.copy()
    fun(x)
    x += 0.5  # the same array, other values
    J1 = jac(x)
    assert not np.allclose(J1, J0)
    np.testing.assert_array_equal(J1, jac(x0 + 0.5))
    np.testing.assert_array_equal(fun(x0), f0)
    np.testing.assert_array_equal(jac(x0), J0)
