"""Weighted marker directions (issue 12, spin under blur): how precisely a centroid fixes a
direction, the weighted global fit and its estimated centroid noise, noise classes, the blur
correction of marker centroids and the ``spin_noise`` self-check."""

import cv2
import numpy as np
import pytest

from stillcap.ball.layout import BallLayout
from stillcap.ball.orientation import (RPM_PER_RAD_S, MarkerObservations, direction_information, fit_spin,
                                       rays_to_directions, simulate_observations)
from stillcap.camera import Camera, look_at
from stillcap.detect.ball_markers import MarkerType, detect_ball_markers, shading_blur_shift
from stillcap.pipelines.pitch.spin import spin_noise_check

LAYOUT = BallLayout.seed()
VIEW = np.array([1.0, 0.1, 0.25]) / np.linalg.norm([1.0, 0.1, 0.25])


def _camera(ball_center, distance=4.0, f=1400.0):
    eye = ball_center + distance * VIEW
    return Camera.from_intrinsics("c", f, f, 640.0, 480.0, (1280, 960), world2cam=look_at(eye, ball_center))


def test_direction_information_matches_a_pixel_shift_through_a_real_camera():
    """A centroid moved by e px moves the ray-sphere direction by du with du^T I du = e^2, both
    across the line of sight and toward it (where the sphere is foreshortened by cos theta)."""
    c = np.array([0.0, 10.0, 1.5])
    cam = _camera(c)
    r = 0.0366
    r_px = cam.K[0, 0] * r / np.linalg.norm(cam.center - c)
    view = (cam.center - c) / np.linalg.norm(cam.center - c)
    rng = np.random.default_rng(3)
    for _ in range(20):
        # a direction on the visible hemisphere, 0-70 deg from the line of sight
        u = view + rng.uniform(-1.2, 1.2, 3) * 0.8
        u -= min(0.0, u @ view) * view
        u /= np.linalg.norm(u)
        if np.degrees(np.arccos(u @ view)) > 70:
            continue
        px = cam.project((c + r * u)[None])[0]
        info = direction_information(u[None], view[None], r_px)[0]
        for e in (np.array([0.05, 0.0]), np.array([0.0, 0.05]), np.array([0.035, -0.035])):
            o, d = cam.rays((px + e)[None])
            v, hit = rays_to_directions(o, d, c[None], r)
            assert hit[0]
            du = v[0] - u
            # perspective: the pixel scale varies by the ball's depth across its radius (~1 %)
            assert du @ info @ du == pytest.approx(e @ e, rel=0.05)


def test_direction_information_without_radial_keeps_only_the_direction_around_the_line_of_sight():
    u = np.array([[0.6, 0.8, 0.0]])
    view = np.array([[1.0, 0.0, 0.0]])
    full = direction_information(u, view, 10.0)[0]
    cut = direction_information(u, view, 10.0, radial=[False])[0]
    around = np.array([0.0, 0.0, 1.0])
    toward = np.array([0.8, -0.6, 0.0])  # the tangent direction toward the line of sight
    assert around @ full @ around == pytest.approx(100.0)
    assert toward @ full @ toward == pytest.approx(100.0 * 0.36)
    assert around @ cut @ around == pytest.approx(100.0)
    assert toward @ cut @ toward == pytest.approx(0.0, abs=1e-9)


def _pixel_noise_observations(seed, noise_px, r_px=15.0, noise_edge_px=None):
    """Exact observations, then each direction moved as a centroid with ``noise_px`` of
    isotropic noise would move it (across the line of sight e/r, toward it e/(r cos theta));
    markers beyond 60 deg from the view are class 1 with ``noise_edge_px`` when given."""
    rng = np.random.default_rng(seed)
    rpm = rng.uniform(1200, 2400)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    w = axis * rpm / RPM_PER_RAD_S
    from scipy.spatial.transform import Rotation

    R0 = Rotation.random(random_state=rng).as_matrix()
    times = 0.01 + np.arange(12) / 80.0
    obs = simulate_observations(times, R0, w, VIEW, LAYOUT, noise_deg=0.0, margin_deg=5.0, rng=rng)
    u = obs.directions
    c = u @ VIEW
    toward = VIEW[None] - c[:, None] * u
    toward /= np.linalg.norm(toward, axis=1, keepdims=True)
    around = np.cross(u, toward)
    cls = (c < np.cos(np.radians(60.0))).astype(int) if noise_edge_px is not None else np.zeros(len(u), int)
    s = np.where(cls == 1, noise_edge_px or noise_px, noise_px)
    e = rng.normal(size=(len(u), 2)) * s[:, None]
    v = u + (e[:, :1] * around + e[:, 1:] * toward / np.maximum(c, 0.1)[:, None]) / r_px
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    info = direction_information(v, np.broadcast_to(VIEW, v.shape), r_px)
    return times, MarkerObservations(obs.flash, obs.types, v, None, info, cls), w


def test_weighted_fit_is_more_accurate_estimates_the_pixel_noise_and_its_intervals_cover():
    err_w, err_u, z, noise = [], [], [], []
    for seed in range(24):
        times, obs, w = _pixel_noise_observations(seed, 0.3)
        weighted = fit_spin(times, obs, LAYOUT, spin_init=w)
        plain = fit_spin(times, MarkerObservations(obs.flash, obs.types, obs.directions), LAYOUT, spin_init=w)
        rate = np.linalg.norm(w) * RPM_PER_RAD_S
        err_w.append(weighted.spin_rpm - rate)
        err_u.append(plain.spin_rpm - rate)
        z.append(err_w[-1] / weighted.sigma_rpm)
        noise.append(weighted.noise_px)
        assert np.isnan(plain.noise_px)
    assert np.mean(np.abs(err_w)) < 0.8 * np.mean(np.abs(err_u))
    assert 0.25 < np.median(noise) < 0.35
    assert np.mean(np.abs(z) <= 1.96) >= 0.8


def test_noise_classes_get_their_own_scale():
    """Markers near the limb 3x noisier than the others: the fit finds their scale (about 3)
    and the estimated noise of the others stays theirs."""
    ratios, noise = [], []
    for seed in range(12):
        times, obs, w = _pixel_noise_observations(seed, 0.1, noise_edge_px=0.3)
        if np.count_nonzero(obs.noise_class == 1) < 6 or np.count_nonzero(obs.noise_class == 0) < 6:
            continue
        res = fit_spin(times, obs, LAYOUT, spin_init=w)
        noise.append(res.noise_px)
        from stillcap.ball.orientation._global import _GlobalProblem  # the scales it used

        prob = _GlobalProblem(times, obs, LAYOUT, times[0])
        x = np.concatenate([np.zeros(3), res.spin])
        j, _ = prob.assign(res.ball2world_t0, res.spin)
        ratios.append(prob.estimate_class_noise(x, res.ball2world_t0, j, res.inliers)[1])
    assert len(ratios) >= 6
    assert 2.0 < np.median(ratios) < 4.0
    assert 0.07 < np.median(noise) < 0.13


def test_concatenate_keeps_information_only_when_every_part_has_it():
    a = MarkerObservations([0], [0], [[1.0, 0, 0]], None, np.eye(3)[None], [1])
    b = MarkerObservations([1], [1], [[0, 1.0, 0]])
    both = MarkerObservations.concatenate([a, a.with_flash([3])])
    assert both.information.shape == (2, 3, 3) and both.flash.tolist() == [0, 3] and both.noise_class.tolist() == [1, 1]
    assert MarkerObservations.concatenate([a, b]).information is None
    with pytest.raises(ValueError, match="information"):
        MarkerObservations([0], [0], [[1.0, 0, 0]], None, np.eye(3))


def _shaded_ball_photo(blur_px, marker_at=(0.5, 0.0), r=30.0, marker_r=4.0, size=120):
    """A matte ball lit from the camera (S = n_z, linear), a dark disc drawn flat in the image at
    ``marker_at`` (fractions of the radius from the centre), blurred (Gaussian), sRGB encoded."""
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    c = size / 2.0
    nx, ny = (xx - c) / r, (yy - c) / r
    rho2 = nx * nx + ny * ny
    S = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0)) * 0.8
    mx, my = c + marker_at[0] * r, c + marker_at[1] * r
    # the disc anti-aliased by supersampling, so its true centroid is (mx, my)
    k = 8
    sub = (np.arange(k) + 0.5) / k - 0.5
    cover = np.zeros_like(S)
    for dy in sub:
        for dx in sub:
            cover += ((xx + dx - mx) ** 2 + (yy + dy - my) ** 2 <= marker_r ** 2)
    cover /= k * k
    albedo = 1.0 - 0.97 * cover
    lin = S * albedo
    if blur_px > 0:
        lin = cv2.GaussianBlur(lin, (0, 0), blur_px)
    enc = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.clip(lin, 0, None) ** (1 / 2.4) - 0.055)
    img = np.repeat((np.clip(enc, 0, 1) * 255.0)[:, :, None], 3, axis=2).astype(np.float32)
    return img, np.array([c, c]), r, np.array([mx, my])


def test_shading_model_and_blur_correction_remove_the_outward_pull_of_shading():
    """On a shaded ball a dark marker's centroid is pulled outward (down the shading): by the
    closing that estimates the local white (it fills the marker from its brighter side), and by
    blur spread before the division by the white. The fitted shading model removes the first,
    the stated blur most of the second; a sharp photo has neither."""
    types = (MarkerType("black", (43, 43, 43), "disc"),)
    img, c, r, truth = _shaded_ball_photo(1.5)
    radial = (truth - c) / np.linalg.norm(truth - c)

    def bias(**kw):
        m = detect_ball_markers(img, c[None], r, types, **kw)
        assert len(m) == 1
        return float((m.centers[0] - truth) @ radial)

    closing, model, fixed = bias(shading_model=False), bias(), bias(blur_px=1.5)
    assert closing > 0.2  # outward, as measured on the studio's photos
    assert 0 < model < 0.6 * closing
    assert abs(fixed) < 0.75 * model
    img0, *_ = _shaded_ball_photo(0.0)
    sharp = detect_ball_markers(img0, c[None], r, types)
    assert abs(float((sharp.centers[0] - truth) @ radial)) < 0.02


def test_shading_blur_shift_points_up_the_shading_and_grows_with_blur():
    model = (0.0, 0.0, 0.8, 0.0, 60.0, 60.0, 30.0)  # lit from the camera: brightest at the centre
    s1 = shading_blur_shift(model, np.array([75.0, 60.0]), 1.0)
    s2 = shading_blur_shift(model, np.array([75.0, 60.0]), 1.5)
    assert s1[0] < 0 and abs(s1[1]) < 1e-12  # toward the centre (up the shading)
    assert s2[0] == pytest.approx(2.25 * s1[0])
    # beyond the terminator (no shading) nothing is corrected
    side = (0.8, 0.0, 0.0, 0.0, 60.0, 60.0, 30.0)  # lit from +x: dark at x < 60
    assert np.all(shading_blur_shift(side, np.array([40.0, 60.0]), 1.5) == 0)


def test_spin_noise_check_fires_when_the_residuals_exceed_the_stated_noise():
    times, obs, w = _pixel_noise_observations(5, 0.3)
    res = fit_spin(times, obs, LAYOUT, spin_init=w)
    ok = spin_noise_check(res, stated_px=0.5)
    assert ok.passed and ok.name == "spin_noise" and ok.unit == "px"
    bad = spin_noise_check(res, stated_px=0.1)
    assert not bad.passed and "do not follow one spin" in bad.message
    plain = fit_spin(times, MarkerObservations(obs.flash, obs.types, obs.directions), LAYOUT, spin_init=w)
    assert spin_noise_check(plain) is None


def test_center_shift_cov_covers_the_error_of_a_centre_offset_shared_by_all_flashes():
    """Every flash's directions measured from a centre moved by the same offset (lateral, in
    ball radii): the spin moves; with that offset's covariance stated the spin's covariance
    grows so that the move is within its chi-square(3) 99 % bound in nearly every case, and
    without it the move is beyond the stated intervals in many."""
    from scipy.stats import chi2

    lateral = np.eye(3) - np.outer(VIEW, VIEW)
    sigma = 0.02  # radii: 0.3 px on a 15 px ball
    inside, outside_plain = 0, 0
    n = 16
    for seed in range(n):
        times, obs, w = _pixel_noise_observations(seed, 0.1)
        base = fit_spin(times, obs, LAYOUT, spin_init=w)
        rng = np.random.default_rng(100 + seed)
        delta = lateral @ rng.normal(size=3) * sigma
        u = obs.directions
        moved = u - (delta[None, :] - (u @ delta)[:, None] * u)
        moved /= np.linalg.norm(moved, axis=1, keepdims=True)
        shifted = MarkerObservations(obs.flash, obs.types, moved, None, obs.information, obs.noise_class)
        plain = fit_spin(times, shifted, LAYOUT, spin_init=w)
        wide = fit_spin(times, shifted, LAYOUT, spin_init=w, center_shift_cov=[(None, sigma ** 2 * lateral)])
        assert np.allclose(wide.spin, plain.spin)  # the estimate is the same, only its covariance grows
        assert np.trace(wide.spin_covariance) > np.trace(plain.spin_covariance)
        d = plain.spin - base.spin
        inside += d @ np.linalg.solve(wide.spin_covariance, d) <= chi2.ppf(0.99, 3)
        outside_plain += d @ np.linalg.solve(plain.spin_covariance, d) > chi2.ppf(0.99, 3)
    assert inside >= n - 2  # (linearised: the part of the move outside the offset's span is the plain fit's)
    assert outside_plain >= n // 2


def test_center_shift_of_ray_directions_follows_the_ray_not_the_point():
    """Directions from pixel rays (``views`` given): a centre offset along the line of sight
    moves none of them, so it adds nothing to the spin's covariance; a lateral offset moves
    them as the ray met with the moved sphere does (``u - (e - v (e.u)/(v.u))``), and the
    covariance then covers that move."""
    from scipy.stats import chi2

    lateral = np.eye(3) - np.outer(VIEW, VIEW)
    sigma = 0.005  # radii: 0.08 px on a 15 px ball, the size measured on the studio's pitches (0.07-0.15 px)
    inside, n = 0, 12
    for seed in range(n):
        times, obs, w = _pixel_noise_observations(seed, 0.1)
        views = np.repeat(VIEW[None, :], len(obs), axis=0)
        rays = MarkerObservations(obs.flash, obs.types, obs.directions, np.ones(len(obs), bool), obs.information,
                                  obs.noise_class, views)
        base = fit_spin(times, rays, LAYOUT, spin_init=w)
        along = fit_spin(times, rays, LAYOUT, spin_init=w, center_shift_cov=[(None, sigma ** 2 * np.outer(VIEW, VIEW))])
        lat = fit_spin(times, rays, LAYOUT, spin_init=w, center_shift_cov=[(None, sigma ** 2 * lateral)])
        added_along = np.trace(along.spin_covariance) - np.trace(base.spin_covariance)
        added_lateral = np.trace(lat.spin_covariance) - np.trace(base.spin_covariance)
        # (not exactly 0: near the limb v.u is kept above 0.1)
        assert abs(added_along) < 0.01 * added_lateral
        rng = np.random.default_rng(200 + seed)
        e = lateral @ rng.normal(size=3) * sigma
        u = rays.directions
        vu = np.maximum(u @ VIEW, 0.1)
        moved = u - (e[None, :] - VIEW[None, :] * ((u @ e) / vu)[:, None])
        moved /= np.linalg.norm(moved, axis=1, keepdims=True)
        shifted = MarkerObservations(obs.flash, obs.types, moved, np.ones(len(obs), bool), obs.information,
                                     obs.noise_class, views)
        plain = fit_spin(times, shifted, LAYOUT, spin_init=w)
        wide = fit_spin(times, shifted, LAYOUT, spin_init=w, center_shift_cov=[(None, sigma ** 2 * lateral)])
        assert np.trace(wide.spin_covariance) > 1.02 * np.trace(plain.spin_covariance)
        d = plain.spin - base.spin
        inside += d @ np.linalg.solve(wide.spin_covariance, d) <= chi2.ppf(0.99, 3)
    assert inside >= n - 2


def test_a_per_observation_centre_shift_mode_equals_the_same_shift_given_as_a_covariance():
    """``center_shift_cov`` takes a mode as each observation's centre shift (M, 3) as well as a
    (mask, 3x3 covariance): a shift that is the same for the masked observations gives the same
    spin covariance either way, and a mode that moves only one flash's centre adds less than one
    that moves every flash's."""
    times, obs, w = _pixel_noise_observations(3, 0.1)
    views = np.repeat(VIEW[None, :], len(obs), axis=0)
    rays = MarkerObservations(obs.flash, obs.types, obs.directions, np.ones(len(obs), bool), obs.information,
                              obs.noise_class, views)
    e = np.cross(VIEW, [0.0, 0.0, 1.0])
    e /= np.linalg.norm(e)
    sigma = 0.01
    mask = obs.flash >= 2
    base = fit_spin(times, rays, LAYOUT, spin_init=w)
    as_cov = fit_spin(times, rays, LAYOUT, spin_init=w, center_shift_cov=[(mask, sigma ** 2 * np.outer(e, e))])
    as_shift = fit_spin(times, rays, LAYOUT, spin_init=w, center_shift_cov=[np.where(mask[:, None], sigma * e, 0.0)])
    assert np.allclose(as_shift.spin, as_cov.spin)
    assert np.allclose(as_shift.spin_covariance, as_cov.spin_covariance, rtol=1e-6, atol=1e-12)
    added = np.trace(as_shift.spin_covariance) - np.trace(base.spin_covariance)
    one = fit_spin(times, rays, LAYOUT, spin_init=w,
                   center_shift_cov=[np.where((obs.flash == 2)[:, None], sigma * e, 0.0)])
    assert 0 < np.trace(one.spin_covariance) - np.trace(base.spin_covariance) < added
    with pytest.raises(ValueError, match="shape"):
        fit_spin(times, rays, LAYOUT, spin_init=w, center_shift_cov=[np.zeros((len(obs) + 1, 3)) + e])


def test_the_spins_centre_modes_are_the_pairs_position_modes_at_each_observations_flash():
    """The pitch pipeline's spin takes each pair's shared position modes (metres, per ball image)
    as the centre shift of every observation of that image, in ball radii, and leaves the other
    pairs' observations unmoved."""
    from types import SimpleNamespace

    from stillcap.pipelines.pitch.spin import _center_shift_modes

    class Part(SimpleNamespace):  # a pair: its observations and its number of ball images
        def __len__(self):
            return self.k

    def rays(flash):
        n = len(flash)
        return MarkerObservations(np.asarray(flash), np.zeros(n, int), np.tile([0.0, 0.0, 1.0], (n, 1)), None, None,
                                  None, np.tile(VIEW, (n, 1)))

    a = Part(observations=rays([0, 0, 1, 2]), k=3)
    b = Part(observations=rays([1, 1, 0]), k=2)
    D = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3) * 1e-4  # 2 modes, 3 ball images
    D[1] = 0.0  # an all-zero mode (e.g. full-disc modes of a pair whose images are all corrected) adds nothing
    modes = _center_shift_modes([a, b], [D, None], 0.037)
    assert len(modes) == 1
    m = modes[0]
    assert m.shape == (7, 3)
    assert np.allclose(m[:4], D[0][[0, 0, 1, 2]] / 0.037)
    assert np.all(m[4:] == 0)
    assert _center_shift_modes([a, b], [D, None], None) == []
    # directions not from rays (no views): a shared centre error was not modelled for them before either
    a_plain = Part(observations=MarkerObservations(np.array([0, 1]), np.zeros(2, int), np.tile([0.0, 0.0, 1.0], (2, 1))),
                   k=3)
    assert _center_shift_modes([a_plain], [D], 0.037) == []


def test_blur_error_bounds_the_first_order_corrections_error_on_a_side_lit_ball():
    """A point marker's blurred weight ``P(z) S(x0) / S(x0 + z)`` integrated on a fine grid gives
    the true pull; the first-order correction misses it by at most twice
    ``shading_blur_error`` from a face-on marker to the terminator (``s |grad log S|`` 0.07-1),
    and the error is a small part of the correction face-on."""
    from stillcap.detect._blur_shift import shading_blur_error

    model = (1.0, 0.0, 0.35, 0.0, 100.0, 100.0, 15.0)  # lit from +x, terminator at x ~ 95
    a, b, c, d, cx, cy, r = model
    s = 1.5
    z = np.arange(-6 * s, 6 * s, 0.02)
    for x0, face_on in ((110.0, True), (104.0, True), (100.0, False), (98.0, False), (97.0, False)):
        c0 = np.array([x0, 103.0])
        X, Y = np.meshgrid(c0[0] + z, c0[1] + z)
        nx, ny = (X - cx) / r, (Y - cy) / r
        S = a * nx + b * ny + c * np.sqrt(np.clip(1 - nx * nx - ny * ny, 0, 1)) + d
        w = np.where(S > 1e-3, np.exp(-((X - c0[0]) ** 2 + (Y - c0[1]) ** 2) / (2 * s * s)) / np.maximum(S, 1e-3), 0)
        pull = np.array([(w * X).sum(), (w * Y).sum()]) / w.sum() - c0
        applied = shading_blur_shift(model, c0, s)
        err = shading_blur_error(model, c0, s)
        assert np.linalg.norm(applied + pull) <= 2.0 * np.linalg.norm(err)
        assert float(err @ applied) > 0
        if face_on:
            assert np.linalg.norm(err) < 0.2 * np.linalg.norm(applied)
    # beyond the capped length the correction is as uncertain as itself
    edge = np.array([96.6, 103.0])
    np.testing.assert_allclose(shading_blur_error(model, edge, s), shading_blur_shift(model, edge, s))


def test_detected_markers_carry_their_blur_error():
    types = (MarkerType("black", (43, 43, 43), "disc"),)
    from stillcap.detect._blur_shift import shading_blur_error

    img, c, r, truth = _shaded_ball_photo(1.5, marker_at=(0.8, 0.0))
    fixed = detect_ball_markers(img, c[None], r, types, blur_px=1.5)
    plain = detect_ball_markers(img, c[None], r, types)
    assert len(fixed) == len(plain) == 1 and np.all(plain.blur_error_px == 0)
    applied = fixed.centers[0] - plain.centers[0]
    assert np.linalg.norm(fixed.blur_error_px[0]) > 0 and float(fixed.blur_error_px[0] @ applied) > 0
    assert fixed.select([0]).blur_error_px.shape == (1, 2)


def test_blur_mode_moves_each_direction_by_its_centroids_blur_error(monkeypatch):
    """``pair_marker_observations`` turns each centroid's blur error into how far its direction
    moves (a pair's matched marker through both rays combined, a single ray through its own),
    and the pitch pipeline adds it to the spin fit as one error mode."""
    import stillcap.ball.markers as markers
    from stillcap.ball.markers import pair_marker_observations
    from stillcap.detect.ball_markers import BallMarkers
    from stillcap.pipelines.pitch.spin import _center_shift_modes

    c, radius = np.array([0.0, 10.0, 1.5]), 0.0366
    cam_a = _camera(c)
    eye_b = c + 4.0 * np.array([0.95, -0.2, 0.25]) / np.linalg.norm([0.95, -0.2, 0.25])
    cam_b = Camera.from_intrinsics("b", 1400.0, 1400.0, 640.0, 480.0, (1280, 960), world2cam=look_at(eye_b, c))
    depth = LAYOUT.centroid_depth[LAYOUT.type_index(["red"])][0]
    on = c + radius * (1 - depth) * np.array([[0.9, 0.1, 0.3], [0.8, -0.5, 0.2]]) / np.linalg.norm(
        [[0.9, 0.1, 0.3], [0.8, -0.5, 0.2]], axis=1)[:, None]
    err = {"a": np.array([[0.6, -0.2], [0.3, 0.4]]), "b": np.array([[0.5, -0.1]])}
    det = {"a": cam_a.project(on), "b": cam_b.project(on[:1])}

    def fake_detect(img, centers, radii, types, blur_px=None, **kw):
        xy = det[img] + (err[img] if blur_px else 0.0)  # the corrected centroids
        n = len(xy)
        return BallMarkers(xy, np.array(["red"] * n, object), np.array(["disc"] * n, object), np.full(n, 30.0),
                           np.ones(n), np.ones(n), np.zeros(n, int), np.zeros(n, int),
                           err[img] if blur_px else None)

    monkeypatch.setattr(markers, "detect_ball_markers", fake_detect)
    obs0, *_ = pair_marker_observations(cam_a, "a", cam_b, "b", None, None, None, None, c[None], max_px=5.0)
    obs, *_ = pair_marker_observations(cam_a, "a", cam_b, "b", None, None, None, None, c[None], max_px=5.0,
                                       blur_px=1.5)
    assert len(obs) == len(obs0) == 2 and not np.any(obs0.blur_mode)
    # the corrected centroids sit the error away from the sharp ones: blur_mode is the move of
    # their directions (to first order: within 20 % at these 0.3-0.6 px on a 13 px ball)
    moved = obs.directions - obs0.directions
    assert np.all(np.linalg.norm(moved - obs.blur_mode, axis=1) < 0.2 * np.linalg.norm(obs.blur_mode, axis=1))
    np.testing.assert_allclose(np.einsum("ij,ij->i", obs.blur_mode, obs.directions), 0.0, atol=1e-12)
    assert np.all(np.degrees(np.linalg.norm(obs.blur_mode, axis=1)) > 0.5)

    class Part:
        observations = obs

    modes = _center_shift_modes([Part()], [None], radius)
    assert len(modes) == 1
    np.testing.assert_allclose(modes[0], -obs.blur_mode)
    assert _center_shift_modes([type("P", (), {"observations": obs0})()], [None], radius) == []


def _limb_cut_observations(seed, noise_px=0.3, r_px=15.0, cut_deg=45.0, n_flashes=8, per_flash=2):
    """Few markers a flash, most of them cut by the limb (beyond ``cut_deg`` from the view):
    a cut marker's centroid fixes only its direction around the line of sight (``radial``
    False), its error toward the line of sight is as large as a whole one's but carries no
    information. Isotropic centroid noise ``noise_px`` otherwise, one noise class."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    w = axis / np.linalg.norm(axis) * rng.uniform(1200, 2400) / RPM_PER_RAD_S
    R0 = Rotation.random(random_state=rng).as_matrix()
    times = 0.01 + np.arange(n_flashes) / 80.0
    obs = simulate_observations(times, R0, w, VIEW, LAYOUT, noise_deg=0.0, margin_deg=5.0,
                                max_per_flash=np.full(n_flashes, per_flash), rng=rng)
    u = obs.directions
    c = u @ VIEW
    toward = VIEW[None] - c[:, None] * u
    toward /= np.linalg.norm(toward, axis=1, keepdims=True)
    around = np.cross(u, toward)
    whole = c > np.cos(np.radians(cut_deg))
    e = rng.normal(size=(len(u), 2)) * noise_px
    v = u + (e[:, :1] * around + e[:, 1:] * toward / np.maximum(c, 0.1)[:, None]) / r_px
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    info = direction_information(v, np.broadcast_to(VIEW, v.shape), r_px, radial=whole)
    return times, MarkerObservations(obs.flash, obs.types, v, None, info), w, whole


def test_noise_and_intervals_count_only_the_informative_components_of_limb_cut_markers():
    """Two thirds of the markers cut by the limb, known centroid noise 0.3 px, no outliers
    (``outlier_deg`` past every residual, so only the noise scale is tested): the estimated
    noise (the scale of the spin's model covariance) is the true one when a cut marker counts
    as one degree of freedom (counted as two: 0.23 px, 25 % low), and the rate and axis errors
    stay about 1 of their stated sigmas (z RMS 0.92; 1.03 counted as two: the cluster-robust
    sandwich, which only widens, had made up most of the low scale here)."""
    noise, z, cut = [], [], []
    for seed in range(40):
        times, obs, w, whole = _limb_cut_observations(seed)
        res = fit_spin(times, obs, LAYOUT, spin_init=w, outlier_deg=90.0)
        assert res.success and res.n_inliers == len(obs)
        assert np.array_equal(res.residual_ranks, np.where(whole, 2, 1))
        assert res.dof == int(res.residual_ranks.sum()) - 6
        noise.append(res.noise_px)
        rate_err, axis_err = res.angle_errors_deg(w)
        # the axis error is the length of a 2-vector: its square over sigma^2 has mean 2
        z += [rate_err / res.sigma_rpm, axis_err / res.sigma_axis_deg / np.sqrt(2.0)]
        cut.append(np.mean(~whole))
    assert np.mean(cut) > 0.6
    assert 0.27 < np.median(noise) < 0.33
    assert 0.8 < np.sqrt(np.mean(np.square(z))) < 1.2
