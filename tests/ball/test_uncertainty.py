"""Uncertainty parts of the ball stages (issue 3, coverage of the reported 95 % intervals):
the cluster-robust spin covariance with few flashes, the reference fit's response to a measured
spin whose error covariance is not the diagonal one it was weighted with."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.ball.fit import FitPriors, fit_reference_trajectory
from stillcap.ball.metrics import FT, spin_vector
from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation import MarkerObservations, fit_spin, simulate_observations
from stillcap.ball.orientation._global import _cluster_robust, _pose_clusters
from stillcap.ball.physics import FlightModel, cross_plane, simulate


# ----------------------------------------------------------------------------------------------
# cluster-robust (CR2) covariance of a fit whose residuals are correlated within a flash
# ----------------------------------------------------------------------------------------------
def _spin_like_design(rng, n_flash, per_flash):
    """A design like the spin fit's: per flash ``per_flash`` observations x 2 components, 3
    orientation parameters and 3 spin parameters whose effect grows with the flash's time
    (``t`` from -1 to 1), so the first and last flashes have the largest leverage."""
    flash = np.repeat(np.arange(n_flash), per_flash)
    t = np.linspace(-1.0, 1.0, n_flash)[np.concatenate([flash, flash])]
    A = rng.normal(0.0, 1.0, (2 * len(flash), 3))
    return np.concatenate([A, A * t[:, None]], axis=1), flash


def _clustered_errors(rng, flash, shared=1.0, own=0.5):
    """A shared error per flash and component (the ball-centre error) plus marker noise."""
    n = flash.max() + 1
    e = np.concatenate([rng.normal(0, shared, n)[flash], rng.normal(0, shared, n)[flash]])
    return e + own * rng.normal(0.0, 1.0, len(e))


def test_cluster_robust_cr2_is_calibrated_with_few_flashes():
    """Over many data sets (same design, new errors) the CR2 variance matches the estimator's
    actual variance; the CR1 sandwich it replaced was ~10-25 % low with 12 flashes and 6
    parameters. And it only ever widens the model-based covariance."""
    rng = np.random.default_rng(3)
    n_flash, p = 12, 6
    J, flash = _spin_like_design(rng, n_flash, 5)
    fl2 = np.concatenate([flash, flash])
    bread = np.linalg.inv(J.T @ J)
    est, var_cr2, var_cr1 = [], [], []
    for _ in range(1000):
        y = _clustered_errors(rng, flash)  # truth: parameters 0
        x = bread @ J.T @ y
        r = y - J @ x
        cov = float(r @ r) / (len(r) - p) * bread
        assert np.all(np.linalg.eigvalsh(_cluster_robust(cov, bread, J, r, flash) - cov) > -1e-12)
        # the bare sandwich: with a zero model covariance _cluster_robust returns it
        var_cr2.append(np.diag(_cluster_robust(np.zeros((p, p)), bread, J, r, flash)))
        g = np.zeros((n_flash, p))
        np.add.at(g, fl2, J * r[:, None])
        cr1 = bread @ (g.T @ g) @ bread * (n_flash / (n_flash - 1) * (len(r) - 1) / (len(r) - p))
        var_cr1.append(np.diag(cr1))
        est.append(x)
    ratio = np.mean(var_cr2, axis=0) / np.var(est, axis=0)
    ratio1 = np.mean(var_cr1, axis=0) / np.var(est, axis=0)
    print("mean variance / actual variance per parameter: CR2", np.round(ratio, 2), "CR1", np.round(ratio1, 2))
    # the Monte Carlo's own error on 1000 variances is ~4.5 % per parameter
    assert np.all(ratio > 0.85) and np.all(ratio < 1.2), ratio
    assert np.mean(ratio1) < np.mean(ratio) - 0.05


def test_pose_clusters_group_the_flashes_that_repeat_a_pose():
    """A third of a turn per flash: flashes 0, 3, 6, ... show one pose (within the tolerance,
    until the drift of an off-resonance spin carries them past it); other clock groups never
    join a cluster."""
    f = 80.0
    axis = np.array([0.0, 0.6, 0.8])
    times = np.arange(9) / f
    for rpm, expect in ((1600.0, [0, 1, 2, 0, 1, 2, 0, 1, 2]),  # exactly 120 deg per flash
                        (1632.0, [0, 1, 2, 0, 1, 2, 6, 7, 8])):  # 7.2 deg of drift per 3 flashes
        w = axis * rpm * 2 * np.pi / 60
        R = Rotation.from_rotvec(np.outer(times, w)).as_matrix()
        np.testing.assert_array_equal(_pose_clusters(R, np.radians(9.2)), expect)
    R = Rotation.from_rotvec(np.outer(times, axis * 1600.0 * 2 * np.pi / 60)).as_matrix()
    groups = np.array([0, 0, 0, 1, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(_pose_clusters(R, np.radians(9.2), groups), [0, 1, 2, 3, 4, 5, 0, 1, 2])


def test_spin_sigma_counts_a_repeated_pose_once():
    """Issue 12, "everything varied" #18: 1,600 rpm at 80 Hz turns the ball a third of a turn per
    flash, so every third flash shows each marker where it was, and a marker's pose-bound
    centroid error (cut by the terminator, seen on its lit side only) repeats. Simulated: 2 deg
    per component of such an error per pose and marker, 0.2 deg of independent noise, 16 spins.
    Counted as independent errors the axis's 95 % cone (2.45 sigma) covered 7 of 16; with the
    flashes of one pose as one cluster 12 of 16 (CR2 from three clusters is itself low)."""
    layout = BallLayout.seed()
    f, rpm = 80.0, 1600.0
    times = np.arange(12) / f
    z = []
    for seed in range(16):
        rng = np.random.default_rng(seed)
        axis = rng.normal(size=3)
        w = axis / np.linalg.norm(axis) * rpm * 2 * np.pi / 60
        R0 = Rotation.random(random_state=seed).as_matrix()
        obs = simulate_observations(times, R0, w, [[1, 0, 0], [0, 1, 0]], noise_deg=0.2, rng=seed)
        Rk = Rotation.from_rotvec(np.outer(times, w)).as_matrix() @ R0
        model = np.einsum("mab,jb->mja", Rk[obs.flash], layout.directions)
        cos = np.where(layout.types[None, :] == obs.types[:, None], np.einsum("ma,mja->mj", obs.directions, model), -2)
        bias = rng.normal(0.0, np.radians(2.0), (3, len(layout.directions), 3))  # per pose and marker
        u = obs.directions + bias[obs.flash % 3, cos.argmax(1)]
        res = fit_spin(times, MarkerObservations(obs.flash, obs.types, u / np.linalg.norm(u, axis=1, keepdims=True)),
                       layout, strobe_hz=f)
        z.append(res.angle_errors_deg(w)[1] / res.sigma_axis_deg)
    cover = float(np.mean(np.array(z) <= 2.45))
    print("axis cone coverage", cover, "z RMS", float(np.sqrt(np.mean(np.square(z)))))
    assert cover >= 0.65, z


def test_cluster_robust_needs_three_flashes():
    rng = np.random.default_rng(0)
    J, flash = _spin_like_design(rng, 2, 8)
    bread = np.linalg.inv(J.T @ J)
    r = _clustered_errors(rng, flash)
    cov = np.eye(6)
    assert _cluster_robust(cov, bread, J, r, flash) is cov


# ----------------------------------------------------------------------------------------------
# the reference fit and a measured spin with a correlated error
# ----------------------------------------------------------------------------------------------
P0 = np.array([-0.5, 54.5 * FT, 1.8])
V0 = np.array([0.3, -42.0, -0.5])  # 94 mph
SPIN = spin_vector(2400.0, 210.0, V0, efficiency=0.95)


def _capture(model):
    t_plate = cross_plane(P0, V0, SPIN, model).time
    times = np.concatenate([np.arange(0.0, 0.07, 1 / 80), np.arange(t_plate - 0.2, t_plate, 1 / 50)])
    return times, simulate(P0, V0, SPIN, times, model).positions


def test_prior_gain_is_the_fits_response_to_the_measured_spin():
    """``prior_gain`` predicts how the fitted state moves when the measured spin moves."""
    model = FlightModel(kind="seed")
    times, truth = _capture(model)
    rng = np.random.default_rng(1)
    meas = truth + rng.normal(0, 0.0005, truth.shape)
    priors = FitPriors(spin_axial_sigma=1.0, spin_transverse_sigma=0.8)
    kw = dict(model=model, position_sigma=0.0005, priors=priors)
    fit = fit_reference_trajectory(times, meas, P0, V0, SPIN, **kw)
    assert fit.prior_gain.shape == (9, 9)
    assert np.allclose(fit.prior_sigma[6:9], [1.0, 0.8, 0.8])
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1.0  # rad/s along e_v, e_1, e_2
        moved = fit_reference_trajectory(times, meas, P0, V0, SPIN + fit.spin_basis @ d, **kw)
        dth = moved.params - fit.params
        pred = fit.prior_gain[:9, 6 + k]
        scale = np.abs(fit.param_sigma) + 1e-12
        assert np.all(np.abs(dth - pred) / scale < 0.05), (k, dth / scale, pred / scale)


def test_spin_prior_covariance_term_covers_a_correlated_spin_error():
    """Monte Carlo: the measured spin's error has a correlated covariance ``C`` (transverse
    sigmas 5 and 0.5 rad/s along tilted axes, the fit weighted with their RMS, 3.5 rad/s, on
    both); along the velocity directions the two transverse spin axes move the fit to, the
    fitted velocity's error variance is the corrected one, not the model one."""
    model = FlightModel(kind="seed")
    times, truth = _capture(model)
    B = fit_reference_trajectory(times, truth, P0, V0, SPIN, model=model, position_sigma=0.002).spin_basis
    c, s = np.cos(0.6), np.sin(0.6)
    Rt = np.array([[c, -s], [s, c]])
    Ct = Rt @ np.diag([5.0 ** 2, 0.5 ** 2]) @ Rt.T
    Cs = np.zeros((3, 3))
    Cs[0, 0] = 1.0
    Cs[1:, 1:] = Ct
    C = B @ Cs @ B.T  # world frame
    priors = FitPriors(spin_axial_sigma=1.0, spin_transverse_sigma=float(np.sqrt(np.trace(Ct) / 2)))
    rng = np.random.default_rng(7)
    L = np.linalg.cholesky(C)
    errs, fit = [], None
    for _ in range(150):
        meas = truth + rng.normal(0, 0.002, truth.shape)  # the seed's 2 mm: the spin prior matters
        wm = SPIN + L @ rng.normal(0, 1, 3)
        fit = fit_reference_trajectory(times, meas, P0, V0, wm, model=model, position_sigma=0.002,
                                       priors=priors)
        errs.append(fit.v0 - V0)
    errs = np.array(errs)
    corrected = fit.with_extra_covariance(fit.spin_prior_covariance_term(C))
    miss_model = miss_corrected = 0.0
    for k, name in enumerate(("major", "minor")):
        d = fit.prior_gain[3:6, 7:9] @ Rt[:, k]
        d /= np.linalg.norm(d)
        emp = np.var(errs @ d)
        mod = d @ fit.covariance[3:6, 3:6] @ d
        cor = d @ corrected.covariance[3:6, 3:6] @ d
        print(f"{name}: velocity error variance / model {emp / mod:.2f}, / corrected {emp / cor:.2f}")
        # 150 draws: the empirical variance is good to ~12 % (1 sigma); 250 draws gave 0.97
        # and 0.87 corrected, 1.17 and 0.67 with the model covariance
        assert 0.7 < emp / cor < 1.35
        miss_model += abs(np.log(emp / mod))
        miss_corrected += abs(np.log(emp / cor))
    assert miss_corrected < miss_model
    # with the covariance the fit was weighted with, no correction
    Cdiag = B @ np.diag(fit.prior_sigma[6:9] ** 2) @ B.T
    assert np.allclose(fit.spin_prior_covariance_term(Cdiag), 0.0, atol=1e-12 * np.abs(fit.covariance).max())


def test_spin_prior_covariance_term_without_spin_prior_is_zero():
    model = FlightModel(kind="seed")
    times, truth = _capture(model)
    fit = fit_reference_trajectory(times, truth, P0, V0, None, model=model, position_sigma=0.0005)
    assert np.all(fit.spin_prior_covariance_term(np.eye(3)) == 0.0)
    try:
        fit.spin_prior_covariance_term(np.eye(2))
    except ValueError as e:
        assert "(3, 3)" in str(e)
    else:
        raise AssertionError("no ValueError for a (2, 2) covariance")


# ----------------------------------------------------------------------------------------------
# the ball-centre bias that remains after the detector's shading correction
# ----------------------------------------------------------------------------------------------
def test_shading_model_offset_is_the_lit_limb_bias():
    """The model the correction subtracts: no offset for a ball lit from the camera (symmetric
    shading), toward the light and growing with the phase angle for a side-lit half moon
    (``_shading_bias``: about +0.1 px at 90 deg, +0.25 px at 110 deg for a 20 px ball)."""
    from stillcap.ball.uncertainty import shading_model_offset_px

    assert abs(shading_model_offset_px(0.0, 20.0)) < 0.01
    o90, o110 = shading_model_offset_px(np.radians(90), 20.0), shading_model_offset_px(np.radians(110), 20.0)
    assert 0.05 < o90 < 0.2 and 0.15 < o110 < 0.35 and o110 > o90
    # more blur moves the lit limb's gradient peak further out
    assert shading_model_offset_px(np.radians(100), 20.0, psf_px=0.8) > shading_model_offset_px(np.radians(100), 20.0, psf_px=0.3)


def test_shading_residual_is_the_models_spread_and_the_table_holds_it():
    """Corrected: the spread under the blur and phase variations, far below the offset the
    correction removed; not corrected: the offset itself is left. The run-time table is the
    function on its grid (a few entries recomputed)."""
    from stillcap.ball import _uncertainty_shading as U

    a = np.radians(100.0)
    corr, raw = U.shading_residual_px(a, 20.0, True), U.shading_residual_px(a, 20.0, False)
    assert 0.0 < corr < 0.5 * U.shading_model_offset_px(a, 20.0) < raw
    for i, j in ((0, 0), (2, 18), (3, 20), (4, 24)):
        r, ph = U._TABLE_RADII[i], np.radians(U._TABLE_PHASE_DEG[j])
        assert abs(U._RESIDUAL_CORRECTED[i, j] - U.shading_residual_px(ph, r, True)) < 1e-3
        assert abs(U._RESIDUAL_UNCORRECTED[i, j] - U.shading_residual_px(ph, r, False)) < 1e-3
    got = U.shading_residual_lookup(np.radians([90.0, 90.0, 0.0]), [20.0, 20.0, 30.0], [True, False, False])
    assert np.allclose(got, [U._RESIDUAL_CORRECTED[2, 18], U._RESIDUAL_UNCORRECTED[2, 18], U._RESIDUAL_UNCORRECTED[3, 0]])
    # between grid radii it lies between the rows
    mid = U.shading_residual_lookup(np.radians([90.0]), [25.0], [True])[0]
    lo, hi = sorted((U._RESIDUAL_CORRECTED[2, 18], U._RESIDUAL_CORRECTED[3, 18]))
    assert lo <= mid <= hi
    try:
        U.shading_residual_lookup([0.1, 0.2], [20.0], True)
    except ValueError as e:
        assert "shape" in str(e)
    else:
        raise AssertionError("shape mismatch accepted")


def test_lit_phase_from_the_detected_silhouette():
    """A rendered lambertian ball, found by ``detect_balls``: its silhouette's area gives the
    phase angle within the dim terminator the threshold loses (<= 15 deg) for half moons."""
    import cv2

    from stillcap.ball.uncertainty import lit_phase_from_area
    from stillcap.detect.ball import detect_balls
    from stillcap.detect.ball._shading import _lit_sphere_image

    rng = np.random.default_rng(3)
    r = 20.0
    for deg in (60, 80, 100, 120):
        a = np.radians(deg)
        img = _lit_sphere_image((100, 100), np.array([50.3, 49.6]), np.eye(2) * r, (np.sin(a), 0.0, np.cos(a)))
        img = cv2.GaussianBlur(img, (0, 0), 0.5)
        im8 = np.clip(255 * (0.8 * img) ** (1 / 2.2) + rng.normal(0, 1.5, img.shape) + 3, 0, 255).astype(np.uint8)
        d = detect_balls(np.dstack([im8] * 3), min_area=20)
        k = int(np.argmax(d.areas))
        assert abs(np.degrees(lit_phase_from_area(d.areas[k], r)) - deg) < 15, deg


def test_lit_bias_modes_shift_along_the_lit_direction():
    """Corrected images move along their lit direction only, full discs along both axes; each
    mode is the re-triangulated shift of one camera's centres."""
    from stillcap.geometry.triangulate import triangulate
    from stillcap.ball.uncertainty import lit_bias_modes
    from stillcap.studio.pitch import pitch_rig

    rig = pitch_rig(image_size=(640, 480)).rig
    cams = [rig["back_left"], rig["back_right"]]
    X = np.array([[0.0, 5.5 - 0.3 * k, 1.4 - 0.03 * k] for k in range(6)])
    x = np.stack([c.project(X) for c in cams])
    ang = np.linspace(0.3, 0.9, 6)
    u = np.stack([np.stack([np.cos(ang), np.sin(ang)], 1), np.stack([-np.cos(ang), np.sin(ang)], 1)])
    s = np.full((2, 6), 0.05)
    corr = np.array([True, True, True, False, False, False])
    m = lit_bias_modes(cams, x, u, s, corr)
    assert m.shape == (12, 6, 3)
    X0 = triangulate(cams, x).points
    xs = x.copy()
    xs[1, :3] += 0.05 * u[1, :3]
    assert np.allclose(m[6], triangulate(cams, xs).points - X0, atol=1e-12)
    assert np.all(np.abs(m[6, 3:]) < 1e-12) and np.all(np.abs(m[2:6, :3]) < 1e-12)  # u on corrected, axes on the rest
    assert np.all(np.linalg.norm(m[0, :3], axis=1) > 0) and np.all(np.linalg.norm(m[2, 3:], axis=1) > 0)
    # the trend runs from -1 to +1 times the constant shift along the flight (linspace over 6)
    assert np.allclose(m[1, 0], -m[0, 0], rtol=1e-3, atol=1e-12) and np.allclose(m[1, 2], -0.2 * m[0, 2], rtol=1e-3, atol=1e-12)
    assert np.allclose(m[4, 5], m[2, 5], rtol=1e-3, atol=1e-12) and np.allclose(m[4, 3], 0.2 * m[2, 3], rtol=1e-3, atol=1e-12)
    try:
        lit_bias_modes(cams, x, u[:, :5], s, corr)
    except ValueError as e:
        assert "(2, K, 2)" in str(e)
    else:
        raise AssertionError("shape mismatch accepted")


def test_bad_inputs_of_the_uncertainty_parts_are_named():
    """Each uncertainty helper refuses bad input with a message that names it."""
    import pytest

    from stillcap.ball.uncertainty import shading_model_offset_px
    from stillcap.ball.uncertainty import lit_geometry

    with pytest.raises(ValueError, match="radius_px must be > 2"):
        shading_model_offset_px(0.5, 1.5)
    with pytest.raises(ValueError, match="psf_px must be >= 0"):
        shading_model_offset_px(0.5, 20.0, psf_px=-0.1)
    model = FlightModel(kind="seed")
    times, truth = _capture(model)
    fit = fit_reference_trajectory(times, truth, P0, V0, None, model=model, position_sigma=0.0005)
    with pytest.raises(ValueError, match=rf"modes must have shape \(n_modes, {len(times)}, 3\)"):
        fit.position_covariance_term(np.zeros((2, len(times) - 1, 3)))
    from dataclasses import replace

    with pytest.raises(ValueError, match="no position_gain"):
        replace(fit, position_gain=None).position_covariance_term(np.zeros((1, len(times), 3)))
    with pytest.raises(ValueError, match=r"centers_px must have shape \(2, K, 2\)"):
        lit_geometry(None, np.zeros((3, 4, 2)), np.zeros(4, int), np.ones((2, 4)))


# ----------------------------------------------------------------------------------------------
# per-image position covariance (a stereo pair's thin depth ellipsoids)
# ----------------------------------------------------------------------------------------------
def _depth_shapes(rng, K):
    """Covariance shapes like a stereo pair's: 4-10x longer along a line of sight that turns
    slowly along the flight, the level growing toward the pair's last images."""
    S = np.empty((K, 3, 3))
    for k in range(K):
        a = 0.3 * k / K
        los = np.array([np.cos(a), np.sin(a), 0.1])
        los /= np.linalg.norm(los)
        Q, _ = np.linalg.qr(np.column_stack([los, rng.normal(size=(3, 2))]))
        sd = np.array([4.0 + 6.0 * k / K, 1.0, 1.2]) * (1.0 + k / K)
        S[k] = (Q * sd ** 2) @ Q.T
    return S * 1e-8


def test_position_covariances_cover_a_depth_ellipsoid_where_one_sigma_cannot():
    """Errors drawn from per-image thin ellipsoids plus a shared shift: the per-image covariance
    (level from the residuals of a fitted offset, with the fit's degrees of freedom, plus the
    shared mode) passes the chi2_3 95 % test 95 % of the time; one isotropic sigma per pair (RMS
    per coordinate of the residuals, the shared shift in quadrature) covers only ~89 %."""
    from stillcap.ball.uncertainty import position_covariances

    rng = np.random.default_rng(3)
    K, n_trials, scale, q = 12, 400, 1.7, 7.815
    S = _depth_shapes(rng, K)
    L = np.linalg.cholesky(S)
    mode = np.tile([[0.0, 4e-5, 1e-5]], (1, K, 1))  # (1, K, 3) a calibration-like shift
    Winv = np.linalg.inv(S)
    inside, inside_iso, s2s, s2s_raw = 0, 0, [], []
    for _ in range(n_trials):
        noise = scale * np.einsum("kij,kj->ki", L, rng.normal(size=(K, 3)))
        err = noise + rng.normal() * mode[0]
        # the fit: a constant offset (3 parameters, generalised least squares) absorbs part of the noise
        c = np.linalg.solve(Winv.sum(0), np.einsum("kij,kj->i", Winv, noise))
        resid = noise - c
        cov, s2 = position_covariances(resid, S, mode, dof_ratio=3 * K / (3 * K - 3))
        _, s2_raw = position_covariances(resid, S)
        s2s.append(s2)
        s2s_raw.append(s2_raw)
        m2 = np.einsum("ki,ki->k", err, np.linalg.solve(cov, err[:, :, None])[:, :, 0])
        inside += np.sum(m2 <= q)
        sig2 = np.mean(resid ** 2) + np.sum(mode ** 2) / (3 * K)
        inside_iso += np.sum(np.sum(err ** 2, 1) / sig2 <= q)
    n = n_trials * K
    assert abs(np.mean(s2s) / scale ** 2 - 1.0) < 0.03  # unbiased level with the fit's dof
    assert np.mean(s2s_raw) / scale ** 2 < 0.94  # without: short by 3 / (3 K)
    assert 0.93 <= inside / n <= 0.97
    assert inside_iso / n < 0.91


def test_position_covariances_edge_cases_and_bad_inputs():
    import pytest

    from stillcap.ball.uncertainty import position_covariances

    S = np.broadcast_to(np.diag([4.0, 1.0, 1.0]), (3, 3, 3)).copy()
    r = np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [np.nan, 0.0, 0.0]])
    cov, s2 = position_covariances(r, S)
    assert s2 == pytest.approx(1.0 / 3.0)  # (1 + 1) / 2 rows / 3 coordinates; the NaN row skipped
    np.testing.assert_allclose(cov, S / 3.0)
    assert position_covariances(r[1:], S[1:]) == (None, pytest.approx(float("nan"), nan_ok=True))
    with pytest.raises(ValueError, match="shape_covariance"):
        position_covariances(r, S[:2])
    with pytest.raises(ValueError, match="dof_ratio must be >= 1"):
        position_covariances(r, S, dof_ratio=0.5)
    with pytest.raises(ValueError, match=r"shared_modes must have shape \(M, 3, 3\)"):
        position_covariances(r, S, np.zeros((2, 4, 3)))


def test_remaining_bias_grows_with_the_shading_correction_made():
    """Where the stereo step corrected the ball images' shading (``StereoBalls.shading_px``),
    every image counts as corrected and its remaining-bias sigma is the model's own error and
    ``model_error`` times the correction in quadrature: the modes grow with both, and a
    ``model_error`` of 0 leaves the model's own."""
    from detect.test_ball import FLIGHT, R_BALL, draw_balls_camera, front_pair
    from stillcap.ball.stereo import ball_centers_stereo
    from stillcap.ball.uncertainty import remaining_bias_modes

    a, b = front_pair()
    light = (1.0, 0.0, 0.3)  # half moons: a correction of ~0.1-0.2 px
    st = ball_centers_stereo(a, draw_balls_camera(a, FLIGHT, R_BALL, light_world=light, rng=11),
                             b, draw_balls_camera(b, FLIGHT, R_BALL, light_world=light, rng=12), R_BALL)
    assert st.shading_px.shape == (len(st), 2) and np.all(st.shading_px > 0.02)
    x = np.stack([st.centers_a, st.centers_b])
    flags = np.zeros(len(st), int)  # not PARTIAL: the corrections alone make them corrected
    m0 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.0)
    m1 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5)
    m2 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 1.0)
    size = [float(np.sqrt(np.sum(m ** 2))) for m in (m0, m1, m2)]
    assert 0 < size[0] < size[1] < size[2]
    # corrected images move along their lit direction only: the per-axis full-disc modes are empty
    assert np.all(m1[[2, 3, 4, 5, 8, 9, 10, 11]] == 0)
    # a stereo result without the record (an older one) keeps the former sizing
    st.shading_px = None
    np.testing.assert_array_equal(remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5),
                                  remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.0))


def _side_lit_pair():
    from detect.test_ball import FLIGHT, R_BALL, draw_balls_camera, front_pair
    from stillcap.ball.stereo import ball_centers_stereo

    a, b = front_pair()
    light = (1.0, 0.0, 0.3)  # half moons: a correction of ~0.1-0.2 px
    st = ball_centers_stereo(a, draw_balls_camera(a, FLIGHT, R_BALL, light_world=light, rng=11),
                             b, draw_balls_camera(b, FLIGHT, R_BALL, light_world=light, rng=12), R_BALL)
    return a, b, st


def _side_lit_centres(sigma_px, seed):
    """:func:`_side_lit_pair`, the images' lit directions, a stated sigma ``sigma_px`` per image
    and camera, and the true centres with 0.01 px of random centre noise."""
    from stillcap.ball.uncertainty import lit_geometry

    a, b, st = _side_lit_pair()
    x = np.stack([st.centers_a, st.centers_b])
    u, _, _ = lit_geometry(st, x, np.zeros(len(st), int), st.radius_px.T)
    rng = np.random.default_rng(seed)
    xt = np.stack([a.project(st.points_3d), b.project(st.points_3d)]) + rng.normal(0.0, 0.01, x.shape)
    return a, b, st, u, np.full((2, len(st)), sigma_px), xt


def test_share_correlation_reads_the_cameras_own_shares_from_the_epipolar_residuals():
    """A bias both cameras share (each centre moved by the same share of its own size along its
    lit direction) keeps the pair on its epipolar lines: the correlation comes out near 1. The
    same bias in one camera only moves the centres off them: near 0, the former independent
    model. With too few images the capture cannot tell: 0."""
    from stillcap.ball.uncertainty import share_correlation

    # the true centres with a little random centre noise, then a bias of 1.5 sigma
    a, b, st, u, s, xt = _side_lit_centres(0.2, 5)
    shared = xt + 1.5 * s[:, :, None] * u
    own = xt.copy()
    own[0] += 1.5 * s[0][:, None] * u[0]
    rho_shared = share_correlation([a, b], shared, u, s)
    rho_own = share_correlation([a, b], own, u, s)
    assert rho_shared.shape == (2,)
    assert rho_shared[0] > 0.8
    assert rho_own[0] < 0.2
    np.testing.assert_array_equal(share_correlation([a, b], shared[:, :3], u[:, :3], s[:, :3]), [0.0, 0.0])


def test_epipolar_bias_scale_widens_only_where_the_cameras_own_bias_is_larger_than_stated():
    """One camera's centres biased by 4 stated sigmas along their lit direction move the pair
    off its epipolar lines by more than two independent unit shares explain: the constant mode's
    variance factor comes out near 4^2 / 2 = 8. A bias within the stated one (0.5 sigma), or one
    both cameras share (it keeps the epipolar lines), leaves the factor at 1, and so do too few
    images."""
    from stillcap.ball.uncertainty import epipolar_bias_scale, remaining_bias_modes

    a, b, st, u, s, xt = _side_lit_centres(0.05, 7)
    x = np.stack([st.centers_a, st.centers_b])

    def biased(k0, k1):
        xb = xt.copy()
        xb[0] += k0 * s[0][:, None] * u[0]
        xb[1] += k1 * s[1][:, None] * u[1]
        return xb

    lam_own = epipolar_bias_scale([a, b], biased(4.0, 0.0), u, s)
    assert lam_own.shape == (2,)
    assert 4.0 < lam_own[0] < 12.0
    np.testing.assert_array_equal(epipolar_bias_scale([a, b], biased(0.5, 0.0), u, s)[0], 1.0)
    assert epipolar_bias_scale([a, b], biased(4.0, 4.0), u, s)[0] < 1.5
    np.testing.assert_array_equal(epipolar_bias_scale([a, b], biased(4.0, 0.0)[:, :3], u[:, :3], s[:, :3]),
                                  [1.0, 1.0])
    # in the modes: each camera's own along-u modes grow by sqrt(lambda); nothing else moves
    flags = np.zeros(len(st), int)
    m0 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.1)
    m1 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.1, epipolar_scale=True)
    np.testing.assert_allclose(m1[[2, 3, 4, 5, 8, 9, 10, 11, 12, 13]], m0[[2, 3, 4, 5, 8, 9, 10, 11, 12, 13]])
    assert np.all(np.linalg.norm(m1[[0, 1, 6, 7]], axis=(1, 2)) >= np.linalg.norm(m0[[0, 1, 6, 7]], axis=(1, 2)) - 1e-15)


def test_remaining_bias_keeps_each_cameras_variance_and_shares_part_of_it():
    """``correlation`` moves part of each camera's along-u variance into two modes that move both
    cameras at once; each camera's own variance (per image, along u) stays the same, and with a
    correlation of 0 the shared modes are empty (the former model)."""
    from stillcap.ball.uncertainty import remaining_bias_modes

    a, b, st = _side_lit_pair()
    x = np.stack([st.centers_a, st.centers_b])
    flags = np.zeros(len(st), int)
    m0 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5)
    m1 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5, correlation=1.0)
    mh = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5, correlation=0.5)
    assert m0.shape == (14, len(st), 3) and np.all(m0[12:] == 0)
    assert np.all(m1[[0, 1, 6, 7]] == 0) and np.any(m1[12:])
    # a shared shift moves the triangulated point less in depth than two independent ones: the
    # total position variance falls as the correlation grows
    var = [float(np.sum(m ** 2)) for m in (m0, mh, m1)]
    assert var[0] > var[1] > var[2] > 0
    with pytest.raises(ValueError, match="correlation"):
        remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5, correlation=1.5)
    with pytest.raises(ValueError, match="correlation"):
        remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5, correlation="guess")
    rho = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5, correlation="epipolar")
    assert rho.shape == (14, len(st), 3)


def test_remaining_bias_takes_a_share_per_camera():
    """``model_error`` one per camera (as an estimate per camera would give it): each camera's
    modes grow with its own share only, and a negative share is refused."""
    from detect.test_ball import FLIGHT, R_BALL, draw_balls_camera, front_pair
    from stillcap.ball.stereo import ball_centers_stereo
    from stillcap.ball.uncertainty import remaining_bias_modes

    a, b = front_pair()
    light = (1.0, 0.0, 0.3)
    st = ball_centers_stereo(a, draw_balls_camera(a, FLIGHT, R_BALL, light_world=light, rng=11),
                             b, draw_balls_camera(b, FLIGHT, R_BALL, light_world=light, rng=12), R_BALL)
    x = np.stack([st.centers_a, st.centers_b])
    flags = np.zeros(len(st), int)
    m0 = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.0)
    m = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, [0.5, 0.0])
    both = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.5)
    assert m.shape == m0.shape == (14, len(st), 3)
    # camera 0's modes (0-5) grew, camera 1's (6-11) are the model's own error alone
    np.testing.assert_array_equal(m[6:], m0[6:])
    assert np.sum(m[:6] ** 2) > np.sum(m0[:6] ** 2)
    np.testing.assert_array_equal(m[:6], both[:6])
    with pytest.raises(ValueError, match="model_error must be >= 0"):
        remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, [0.5, -1.0])


def test_offset_slope_is_the_models_slope_and_the_table_holds_it():
    """The run-time table of the shading model's offset is the function on its grid (a few
    entries recomputed), and its slope with the phase angle is the function's own slope."""
    from stillcap.ball import _uncertainty_shading as U

    for p, i, j in ((0, 0, 0), (1, 2, 18), (2, 3, 20), (4, 4, 24)):
        got = U.shading_model_offset_px(np.radians(U._TABLE_PHASE_DEG[j]), U._TABLE_RADII[i], U._OFFSET_PSF[p])
        assert abs(U._OFFSET[p, i, j] - got) < 1e-3
    for deg, r, psf in ((100.0, 20.0, 0.5), (120.0, 15.0, 1.0)):
        h = np.radians(5.0)
        want = (U.shading_model_offset_px(np.radians(deg) + h, r, psf)
                - U.shading_model_offset_px(np.radians(deg) - h, r, psf)) / (2 * h)
        got = U.shading_offset_slope_lookup(np.radians([deg]), np.array([r]), psf)[0]
        assert abs(got - want) < 0.15 * abs(want) + 0.02, (deg, got, want)
    # radii beyond the table scale with the ball
    s10, s5 = U.shading_offset_slope_lookup(np.radians([100.0, 100.0]), np.array([10.0, 5.0]), 0.5)
    assert s5 == pytest.approx(0.5 * s10)
    with pytest.raises(ValueError, match="one shape"):
        U.shading_offset_slope_lookup([0.1, 0.2], [20.0], 0.5)
    with pytest.raises(ValueError, match="psf_px"):
        U.shading_offset_slope_lookup([0.1], [20.0], -1.0)


def _reported_stereo(K: int, made, misfit_px, phase_sd_rad=np.nan, psf=(0.5, 0.5)):
    """A stand-in for ``StereoBalls`` with what the shading correction reports."""
    from types import SimpleNamespace

    centers = np.stack([np.arange(K) * 30.0 + 100.0, np.full(K, 200.0)], axis=1)
    return SimpleNamespace(centers_a=centers, centers_b=centers + 5.0, shading_px=np.asarray(made, float),
                           shading_misfit_px=np.asarray(misfit_px, float), psf_px=np.asarray(psf, float),
                           shading_phase_sd_rad=np.full((K, 2), phase_sd_rad)), np.stack([centers, centers + 5.0])


def test_misfit_share_reads_a_cameras_share_from_its_misfit_shifts():
    """Shifts along the lit direction that are ``alpha + beta t`` times the correction made give
    the share ``sqrt((alpha^2 + beta^2) / 2)`` per camera; a camera with fewer than four reported
    images, or shifts across the lit direction only, states none."""
    from stillcap.ball.uncertainty import misfit_share

    K = 8
    t = np.linspace(-1, 1, K)
    made = np.stack([np.linspace(0.2, 0.4, K), np.linspace(0.1, 0.3, K)], axis=1)  # (K, 2)
    u = np.zeros((2, K, 2))
    u[..., 0] = 1.0
    d = np.zeros((K, 2, 2))
    d[:, 0, 0] = (0.3 + 0.1 * t) * made[:, 0]
    d[:, 1, 1] = 0.5 * made[:, 1]  # across the lit direction
    st, x = _reported_stereo(K, made, d)
    got = misfit_share(st, x, u)
    assert got[0] == pytest.approx(np.sqrt((0.3 ** 2 + 0.1 ** 2) / 2))
    assert got[1] == pytest.approx(0.0, abs=1e-12)
    d[3:, 0, 0] = np.nan  # three reported images left in camera 0
    st, x = _reported_stereo(K, made, d)
    assert misfit_share(st, x, u)[0] == 0.0


def test_phase_error_is_the_split_half_sigma_through_the_models_slope():
    """Each corrected image's centre error from its camera's phase sigma (the RMS of the
    reported split-half sigmas) times the model's slope at its phase, radius and blur; none
    without a report."""
    from stillcap.ball.uncertainty import phase_error_px, shading_offset_slope_lookup

    K = 5
    made = np.full((K, 2), 0.2)
    st, x = _reported_stereo(K, made, np.full((K, 2, 2), np.nan), phase_sd_rad=np.radians(2.0), psf=(0.5, 1.0))
    phase = np.radians(np.stack([np.linspace(80, 120, K), np.linspace(60, 100, K)]))
    radius = np.full((2, K), 15.0)
    got = phase_error_px(st, x, phase, radius)
    for c, psf in ((0, 0.5), (1, 1.0)):
        np.testing.assert_allclose(got[c], np.abs(shading_offset_slope_lookup(phase[c], radius[c], psf)) * np.radians(2.0))
    st.shading_phase_sd_rad = None
    assert np.all(phase_error_px(st, x, phase, radius) == 0)


def test_lit_geometry_takes_the_corrections_phase_and_the_modes_grow_with_the_measured_share():
    """The phase the uncertainty reads is the one the correction used where it reported one
    (the silhouette's area elsewhere), and ``remaining_bias_modes(measured=True)`` adds the
    share the misfit states: the modes grow with it, and ``measured=False`` is the stated share
    alone."""
    from stillcap.ball.uncertainty import lit_geometry, remaining_bias_modes

    a, b, st = _side_lit_pair()
    x = np.stack([st.centers_a, st.centers_b])
    flags = np.zeros(len(st), int)
    _, phase, _ = lit_geometry(st, x, flags, st.radius_px.T)
    np.testing.assert_allclose(phase, st.shading_phase_rad.T)
    st.shading_phase_rad = np.full_like(st.shading_phase_rad, np.nan)
    _, area, _ = lit_geometry(st, x, flags, st.radius_px.T)
    assert np.all(np.isfinite(area)) and not np.allclose(area, phase)
    plain = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.1, measured=False)
    meas = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.1)
    assert np.sum(meas ** 2) >= np.sum(plain ** 2)
    u = np.zeros((2, len(st), 2))
    u[..., 0] = 1.0
    st.shading_misfit_px = np.zeros((len(st), 2, 2))
    st.shading_misfit_px[:, :, 0] = 0.5 * st.shading_px  # a large share: half the correction
    big = remaining_bias_modes([a, b], st, x, flags, st.radius_px.T, 0.1)
    assert np.sum(big ** 2) > 1.5 * np.sum(plain ** 2)
