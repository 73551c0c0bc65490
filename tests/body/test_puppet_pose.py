"""Pose stage of the puppet pipeline (stillcap.body.puppet_pose); its accuracy on rendered
poses is tested with the pipeline (tests/pipelines/test_puppet_pipeline.py)."""

import numpy as np
import pytest

from stillcap.body import MarkerSet, Skeleton
from stillcap.body.puppet_pose import fit_pose, frame_status


def test_rest_markers_give_the_rest_pose():
    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    rest = sk.rest_pose()
    pts = ms.positions(rest)
    fit = fit_pose(sk, ms, pts)
    assert fit.success and fit.n_markers == len(ms)
    assert fit.rms_m < 1e-6
    np.testing.assert_allclose(fit.pose.positions, rest.positions, atol=1e-6)
    assert frame_status(sk, ms)["lower-back"] == "full"
    with pytest.raises(ValueError, match=r"marker_positions must have shape \(16, 3\), got \(15, 3\)"):
        fit_pose(sk, ms, pts[:15])


def test_euler_matrices_are_scipys_elementary_rotations():
    """The fit's closed-form Rx, Ry, Rz are Rotation.from_euler's, and their product the
    intrinsic XYZ rotation the joint limits are written in."""
    from scipy.spatial.transform import Rotation

    from stillcap.body.puppet_pose import _euler_matrices

    a = np.random.default_rng(0).uniform(-180, 180, (25, 3))
    R = _euler_matrices(a)
    for k, ax in enumerate("xyz"):
        np.testing.assert_allclose(R[k], Rotation.from_euler(ax, a[:, k:k + 1], degrees=True).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(R[0] @ R[1] @ R[2], Rotation.from_euler("XYZ", a, degrees=True).as_matrix(), atol=1e-14)


def _blas_threads():
    from threadpoolctl import threadpool_info

    return sorted({d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"})


def test_fit_pose_runs_blas_on_one_thread_and_restores_the_callers_setting(monkeypatch):
    # the dense trust-region solve spins OpenBLAS's threads on a busy machine (15x slower)
    from threadpoolctl import threadpool_limits

    import stillcap.body.puppet_pose as pp

    inside = []
    real = pp.least_squares

    def spy(*args, **kwargs):
        inside.append((_blas_threads(), kwargs["tr_solver"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(pp, "least_squares", spy)
    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    with threadpool_limits(2, user_api="blas"):
        fit = fit_pose(sk, ms, ms.positions(sk.rest_pose()))
        assert _blas_threads() == [2]
    assert fit.success and inside and all(t == ([1], "exact") for t in inside)


def test_newton_start_reaches_the_soft_l1_optimum_and_never_raises_the_loss():
    """_newton_start's reweighted Gauss-Newton steps (each residual row scaled by the square root
    of the soft-L1 loss's slope) converge to the optimum least_squares finds for that loss, each
    step lowering it; clipped into the bounds."""
    from scipy.optimize import least_squares

    from stillcap.body.puppet_pose import _newton_start, _robust_cost

    rng = np.random.default_rng(1)
    A = rng.normal(size=(60, 4))
    y = A @ np.array([1.0, -2.0, 0.5, 3.0]) + rng.normal(0, 0.1, 60)
    y[:6] += rng.normal(0, 20.0, 6)  # outliers, which the loss weighs down

    def fun(x):
        return (A @ x - y) / 0.1

    def jac(x):
        return A / 0.1

    free = (np.full(4, -np.inf), np.full(4, np.inf))
    x, f, _ = _newton_start(fun, jac, np.zeros(4), free, 5.0, steps=200, rtol=0.0)
    want = least_squares(fun, np.zeros(4), jac=jac, loss="soft_l1", f_scale=5.0, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    np.testing.assert_allclose(x, want.x, atol=1e-6)
    np.testing.assert_allclose(f, fun(x))
    assert want.cost == pytest.approx(_robust_cost(f, 5.0), rel=1e-9)  # the same loss as least_squares'
    plain, _, done = _newton_start(fun, jac, np.zeros(4), free, None, steps=60)
    np.testing.assert_allclose(plain, np.linalg.lstsq(A, y, rcond=None)[0], atol=1e-9)  # squares: one step
    assert done
    assert np.linalg.norm(plain - want.x) > 1e-2  # the outliers matter: the loss is not ignored
    lo, hi = np.array([-np.inf, -1.0, -np.inf, -np.inf]), np.array([np.inf, np.inf, np.inf, 2.0])
    xb, _, _ = _newton_start(fun, jac, np.zeros(4), (lo, hi), 5.0, steps=200, rtol=0.0)
    want_b = least_squares(fun, np.zeros(4), jac=jac, bounds=(lo, hi), loss="soft_l1", f_scale=5.0, xtol=1e-14,
                           ftol=1e-14, gtol=1e-14)
    assert np.all((xb >= lo) & (xb <= hi)) and xb[1] == -1.0  # held on the bound it met
    np.testing.assert_allclose(xb, want_b.x, atol=1e-6)  # the bounded optimum
    step_costs = [_robust_cost(_newton_start(fun, jac, np.zeros(4), (lo, hi), 5.0, steps=k, rtol=0.0)[1], 5.0)
                  for k in range(6)]
    assert all(b <= a for a, b in zip(step_costs, step_costs[1:])) and step_costs[-1] < step_costs[0]


def test_the_newton_start_ends_at_the_trust_regions_own_fit(monkeypatch):
    """fit_pose from the Gauss-Newton start: the pose least_squares reaches from the joint-by-joint
    start alone (to its tolerances), in fewer of its iterations."""
    import stillcap.body.puppet_pose as pp
    from stillcap.studio.puppet import random_pose

    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    nfev = []
    real = pp.least_squares

    def spy(*args, **kwargs):
        r = real(*args, **kwargs)
        nfev.append(r.nfev)
        return r

    monkeypatch.setattr(pp, "least_squares", spy)
    for seed in (3, 5, 8):
        truth = random_pose(sk, seed, ms)
        pts = ms.positions(truth) + np.random.default_rng(seed).normal(0, 0.1e-3, (len(ms), 3))
        nfev.clear()
        fast = fit_pose(sk, ms, pts, truth.root2world)
        n_fast = sum(nfev)
        with monkeypatch.context() as m:
            m.setattr(pp, "_newton_start", lambda fun, jac, x, *a, **k: (x, fun(x), False))
            nfev.clear()
            slow = fit_pose(sk, ms, pts, truth.root2world)
        np.testing.assert_allclose(fast.pose.positions, slow.pose.positions, atol=2e-6)
        assert np.nansum(fast.residuals_m ** 2) <= np.nansum(slow.residuals_m ** 2) * (1 + 1e-6)
        assert n_fast < sum(nfev)


def test_euler_matrices_are_the_elementary_rotations_bit_for_bit():
    """fit_pose's Rx, Ry, Rz (filled in place): each row's elementary rotations written out
    from the same cos and sin, entry for entry (signed zeros included)."""
    from stillcap.body.puppet_pose import _euler_matrices

    rng = np.random.default_rng(4)
    a = rng.uniform(-400, 400, (25, 3))
    a[rng.random(a.shape) < 0.2] = 0.0
    Rx, Ry, Rz = _euler_matrices(a)
    c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
    for k in range(len(a)):
        (cx, cy, cz), (sx, sy, sz) = c[k], s[k]
        want = (np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]]),
                np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]]),
                np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]]))
        for got, w in zip((Rx[k], Ry[k], Rz[k]), want):
            np.testing.assert_array_equal(got, w)
            np.testing.assert_array_equal(np.signbit(got), np.signbit(w))
