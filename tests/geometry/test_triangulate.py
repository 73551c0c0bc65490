import numpy as np
import pytest

from stillcap.geometry.triangulate import reprojection_errors, triangulate

from support import ring_rig


def scene(rig, n=500, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-0.5, 0.5, (n, 3))
    x = rig.project(X) + rng.normal(0, noise, (len(rig), n, 2)) if noise else rig.project(X)
    return X, x


@pytest.mark.parametrize("method", ["dlt", "midpoint"])
def test_exact_points_recovered(rig4, method):
    X, x = scene(rig4)
    tri = triangulate(rig4, x, method=method, refine=False)
    np.testing.assert_allclose(tri.points, X, atol=1e-9)
    assert np.all(tri.n_views == 4) and tri.reproj_error_px.max() < 1e-6


def test_noise_error_matches_theory_and_refine_helps(rig4):
    X, x = scene(rig4, 2000, noise=0.5, seed=1)
    lin = triangulate(rig4, x, refine=False)
    ref = triangulate(rig4, x, refine=True)
    e_lin = np.linalg.norm(lin.points - X, axis=1)
    e_ref = np.linalg.norm(ref.points - X, axis=1)
    # ~0.5 px at f=1100 and 3 m: 1.4 mm per view; 4 views -> about 1 mm 3D RMS
    assert 0.3e-3 < np.sqrt(np.mean(e_ref**2)) < 2e-3
    assert np.mean(ref.reproj_error_px) <= np.mean(lin.reproj_error_px) + 1e-12
    assert np.sqrt(np.mean(e_ref**2)) <= np.sqrt(np.mean(e_lin**2)) * 1.02
    # the reported reprojection RMS is the one recomputed independently
    err = reprojection_errors(rig4, ref.points, x)
    np.testing.assert_allclose(np.sqrt(np.mean(err**2, axis=0)), ref.reproj_error_px, rtol=1e-9)


def test_unseen_views_and_too_few_views(rig4):
    X, x = scene(rig4, 6)
    x[0, 0] = np.nan            # point 0 seen by 3
    x[:3, 1] = np.nan           # point 1 seen by 1 -> NaN
    x[:, 2] = np.nan            # point 2 unseen
    x[1:3, 3] = np.nan          # point 3 seen by 2
    tri = triangulate(rig4, x)
    assert list(tri.n_views) == [3, 0, 0, 2, 4, 4]
    assert np.all(np.isnan(tri.points[1:3]))
    np.testing.assert_allclose(tri.points[[0, 3, 4, 5]], X[[0, 3, 4, 5]], atol=1e-8)
    assert np.isnan(tri.errors_px[0, 0]) and np.isnan(tri.reproj_error_px[1])


def test_outlier_view_rejected():
    rig = ring_rig(5, dist=(-0.1, 0.02, 0, 0, 0))
    X, x = scene(rig, 300, noise=0.3, seed=3)
    bad_cam = np.random.default_rng(4).integers(0, 5, 300)
    x[bad_cam, np.arange(300)] += 25.0  # one gross mismatch per point
    plain = triangulate(rig, x)
    robust = triangulate(rig, x, outlier_px=3.0)
    assert np.median(np.linalg.norm(plain.points - X, axis=1)) > 5e-3
    e = np.linalg.norm(robust.points - X, axis=1)
    assert e.max() < 3e-3
    assert not np.any(robust.used[bad_cam, np.arange(300)])
    assert np.all(robust.n_views == 4)


def test_camera_order_and_rig_rotation_do_not_change_the_points(rig4):
    X, x = scene(rig4, 50, noise=0.2, seed=5)
    tri = triangulate(rig4, x)
    perm = [2, 0, 3, 1]
    tri2 = triangulate([rig4[i] for i in perm], x[perm])
    np.testing.assert_allclose(tri.points, tri2.points, atol=1e-9)
    # rotate and move the whole world: the points move with it
    from scipy.spatial.transform import Rotation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()
    T[:3, 3] = [0.3, -1, 2]
    moved = [c.with_pose(c.world2cam @ np.linalg.inv(T)) for c in rig4]
    tri3 = triangulate(moved, x)
    np.testing.assert_allclose(tri3.points, tri.points @ T[:3, :3].T + T[:3, 3], atol=1e-8)


def test_bad_input(rig4):
    with pytest.raises(ValueError, match=r"points_2d must have shape \(4, N, 2\), got \(3, 5, 2\)"):
        triangulate(rig4, np.zeros((3, 5, 2)))
    with pytest.raises(ValueError, match="method must be"):
        triangulate(rig4, np.zeros((4, 5, 2)), method="magic")
    with pytest.raises(ValueError, match="Rig or a sequence of Camera"):
        triangulate(["a", "b"], np.zeros((2, 5, 2)))


def _cramer_written_out(a, b, damping=0.0):
    """Cramer's rule on the six unique entries, each cofactor written out (the solve before issue 16)."""
    a00, a01, a02, a11, a12, a22 = a
    if damping:
        a00, a11, a22 = a00 + damping, a11 + damping, a22 + damping
    b0, b1, b2 = b
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = 1.0 / np.where(np.abs(det) > 1e-300, det, np.nan)
        return np.stack([(c00 * b0 + c01 * b1 + c02 * b2) * inv, (c01 * b0 + c11 * b1 + c12 * b2) * inv,
                         (c02 * b0 + c12 * b1 + c22 * b2) * inv], axis=1)


@pytest.mark.parametrize("damping", [0.0, 1e-12])
def test_normal_equations_solve_is_cramers_rule_to_the_bit(damping):
    """_Normal3.solve gathers the cofactors in one set of products (fewer NumPy calls, issue 16):
    the same numbers, bit for bit, as each cofactor written out, singular systems NaN."""
    from stillcap.geometry.triangulate import StackedViews, _Normal3

    rng = np.random.default_rng(11)
    for n in (1, 16, 3000):
        eq = _Normal3(n)
        J = rng.normal(size=(3, 8, n)) * rng.uniform(1e-3, 1e3, (1, 1, n))
        r = rng.normal(size=(8, n))
        for k in range(8):
            eq.add_rows(J[:, k], r[k])
        eq.a[:, 0] = 0.0  # singular
        got = eq.solve(damping)
        np.testing.assert_array_equal(got, _cramer_written_out(eq.a, eq.b, damping))
        assert np.isnan(got[0]).all() == (damping == 0.0)
    # the stacked views' normal equations (two einsums): the sums of the products, bit for bit
    J, r = rng.normal(size=(2, 12, 16, 3)), rng.normal(size=(2, 12, 16))
    eq = StackedViews._normal(J, r, (0, 1))
    j0, j1, j2 = J[..., 0], J[..., 1], J[..., 2]
    want = np.stack([(p * q).sum((0, 1)) for p, q in ((j0, j0), (j0, j1), (j0, j2), (j1, j1), (j1, j2), (j2, j2))])
    np.testing.assert_array_equal(eq.a, want)
    np.testing.assert_array_equal(eq.b, np.stack([(j * r).sum((0, 1)) for j in (j0, j1, j2)]))


def test_stacked_views_normalise_as_each_camera_does_to_the_bit():
    """StackedViews' normalised observations (the pinhole cameras' closed form for all views at
    once) are each camera's own pixels_to_normalized, bit for bit: skewed and distorted lenses,
    NaN observations."""
    from stillcap.camera import Camera, Rig, look_at
    from stillcap.geometry.triangulate import StackedViews

    rng = np.random.default_rng(8)
    cams = []
    for v in range(6):
        c = Camera.from_intrinsics(f"c{v}", rng.uniform(400, 2000), rng.uniform(400, 2000), 320.5, 241.0, (640, 480),
                                   dist=(-0.2, 0.05, 0.001, -0.001, 0.0) if v == 2 else None,
                                   world2cam=look_at(rng.normal(0, 2, 3), (0, 0, 0)))
        if v == 4:  # skew
            K = c.K.copy()
            K[0, 1] = 1.3
            c = Camera(c.name, K, c.dist, c.world2cam, (640, 480))
        cams.append(c)
    x = rng.uniform(0, 640, (6, 25, 2))
    x[rng.random((6, 25)) < 0.2] = np.nan
    sv = StackedViews(Rig(cams), x)
    want = np.stack([c.pixels_to_normalized(xi) for c, xi in zip(cams, x)])
    assert np.isnan(want).any() and np.isfinite(want).sum() > 150
    np.testing.assert_array_equal(sv.xn, want)
    np.testing.assert_array_equal(sv.seen, np.isfinite(want).all(axis=-1))
