"""The pitch detectors' fast paths (issue 16, speed of one capture) give the numbers of the plain
NumPy they replace, bit for bit: the lit-sphere model's limb supersampling (in place), the
lens-blur fit's centred models (one array operation for all 17 blurs), the ball white balance
on 8-bit values, the markers' noise ceilings (medians without ``np.median``) and the circle
fit's Newton Jacobian (filled in place). Each reference below is the expression the fast path
replaced, on inputs none of the studio's captures used (random ellipses, lights, crops)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stillcap.detect.ball._shading import (_BLUR_GRID, _lit_frame, _lit_sphere_image, limb_blur_px,
                                          supersample_depth_px)
from stillcap.detect.ball_markers import _robust_ceiling, ball_white_balance
from stillcap.detect.circle_fit import _soft_l1_newton


def _reference_band(shape, center, A, light, band_px, q, ss=3):
    """``_lit_sphere_image``'s band path as it was: ``rad_of`` of the samples with temporaries."""
    o = (np.arange(ss) + 0.5) / ss - 0.5
    Ai = np.linalg.inv(A)
    lx, ly, lz = light

    def rad_of(qx, qy, r2=None):
        if r2 is None:
            r2 = qx * qx + qy * qy
        qz = np.sqrt(np.maximum(1.0 - r2, 0.0))
        return np.where(r2 < 1.0, np.maximum(qx * lx + qy * ly + qz * lz, 0.0), 0.0)

    sv = np.linalg.svd(A, compute_uv=False)
    r2 = q[0] ** 2 + q[1] ** 2
    r_in = max(1.0 - (band_px + 1.0) / sv[0], 0.0)
    r_out = 1.0 + 1.5 / sv[-1]
    out = rad_of(q[0], q[1], r2)
    band = (r2 > r_in * r_in) & (r2 < r_out * r_out)
    qxb, qyb = q[0][band], q[1][band]
    dqx = Ai[0, 0] * o[None, :] + Ai[0, 1] * o[:, None]
    dqy = Ai[1, 0] * o[None, :] + Ai[1, 1] * o[:, None]
    out[band] = rad_of(qxb[:, None, None] + dqx[None], qyb[:, None, None] + dqy[None]).mean(axis=(1, 2))
    return out.astype(np.float32)


def _ellipse(rng, r):
    M = np.eye(2) + rng.normal(0.0, 0.15, (2, 2))
    ev, V = np.linalg.eigh(0.5 * (M + M.T))
    return (V * np.abs(ev)) @ V.T * r


def _random_ball(rng, r, n, z=None):
    """A sharp lit ball of radius ``r`` in an ``n`` x ``n`` crop: centre near the middle, a random
    ellipse, light from a random direction (its z through ``z`` when given). Returns
    ``(c, A, light, image)``; the draws are in the order the tests made them."""
    c = np.array([n / 2, n / 2]) + rng.normal(0.0, 1.0, 2)
    A = _ellipse(rng, r)
    light = rng.normal(size=3)
    if z is not None:
        light[2] = z(light[2])
    light /= np.linalg.norm(light)
    return c, A, light, _lit_sphere_image((n, n), c, A, tuple(light))


@pytest.mark.parametrize("seed", range(4))
def test_lit_sphere_band_in_place_is_bit_identical(seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        r = rng.uniform(4.0, 40.0)
        h, w = int(2 * r + rng.integers(10, 30)), int(2 * r + rng.integers(10, 30))
        A = _ellipse(rng, r)
        c = np.array([w / 2, h / 2]) + rng.normal(0.0, 2.0, 2)
        light = rng.normal(size=3)
        light /= np.linalg.norm(light)  # lit from anywhere, behind included
        band = float(rng.choice([2.0, 7.6, 16.0]))
        yy, xx = np.mgrid[0:h, 0:w]
        q = np.einsum("ij,jhw->ihw", np.linalg.inv(A), np.stack([xx - c[0], yy - c[1]]).astype(float))
        got = _lit_sphere_image((h, w), c, A, tuple(light), band_px=band, q=q)
        want = _reference_band((h, w), c, A, tuple(light), band, q)
        assert got.dtype == want.dtype and np.array_equal(got, want)


def _reference_blur_sse(lin, center, off):
    """``limb_blur_px``'s misfit per blur sigma as it was: one blur, centring and dot at a time."""
    mid, A, q, light = _lit_frame(lin, np.asarray(center, float), off)
    r2 = q[0] ** 2 + q[1] ** 2
    band = (r2 > 0.6 ** 2) & (r2 < 1.4 ** 2)
    band_px = supersample_depth_px(float(np.linalg.svd(A, compute_uv=False)[-1]))
    model0 = _lit_sphere_image(lin.shape, mid, A, light, band_px=band_px, q=q)
    y = lin[band].astype(float)
    y = y - y.mean()
    yy = float(y @ y)
    sse = np.empty(len(_BLUR_GRID))
    for k, s in enumerate(_BLUR_GRID):
        m = cv2.GaussianBlur(model0, (0, 0), float(s))[band].astype(float)
        m = m - m.mean()
        mm = float(m @ m)
        sse[k] = yy - (float(m @ y) ** 2 / mm if mm > 0 else 0.0)
    k = int(np.argmin(sse))
    if k == 0 or k == len(_BLUR_GRID) - 1:
        return float("nan")
    x0, x1, x2 = _BLUR_GRID[k - 1:k + 2]
    c2, c1, _ = np.polyfit([x0, x1, x2], sse[k - 1:k + 2], 2)
    return float(np.clip(-c1 / (2.0 * c2), x0, x2)) if c2 > 0 else float(x1)


@pytest.mark.parametrize("seed", range(3))
def test_limb_blur_centred_at_once_is_bit_identical(seed):
    """Balls of 8-30 px lit from any side (crescents included), blurred 0.3-2.5 px, noisy:
    the blur read from the limb is the same number as the one-sigma-at-a-time fit's."""
    rng = np.random.default_rng(100 + seed)
    found = 0
    for _ in range(12):
        r = rng.uniform(8.0, 30.0)
        n = int(2 * r + 24)
        c, A, light, img = _random_ball(rng, r, n, lambda z: -abs(z) if rng.random() < 0.3 else abs(z))
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.3, 2.5)))
        img = np.clip(0.8 * img + 0.02 + rng.normal(0.0, 0.01, img.shape), 0, 1).astype(np.float32)
        th = np.linspace(0, 2 * np.pi, 96, endpoint=False)
        off = np.stack([np.cos(th), np.sin(th)], axis=1) @ A.T
        got, want = limb_blur_px(img, c, off), _reference_blur_sse(img, c, off)
        assert got == want or (np.isnan(got) and np.isnan(want))
        found += np.isfinite(got)
    assert found >= 6  # most balls give a blur (the comparison is not of NaNs only)


def test_white_balance_of_8_bit_photo_equals_float_path():
    """A cast photo with dark markers and clipped pixels: the 8-bit fast path (brightest channel
    on the codes, converted after) gives the gains of the float path, bit for bit."""
    rng = np.random.default_rng(7)
    H, W = 200, 300
    img = rng.integers(0, 30, (H, W, 3)).astype(np.uint8)
    centers, radii = [], []
    yy, xx = np.mgrid[0:H, 0:W]
    for cx, cy, r in ((60, 60, 25), (160, 100, 30), (250, 150, 18), (295, 10, 20)):  # the last cut by the edge
        d = np.hypot(xx - cx, yy - cy) / r
        ball = d < 1.0
        shade = np.clip(1.1 - d, 0.2, 1.0)[..., None] * np.array([200.0, 235.0, 260.0])  # BGR cast, clipping
        img[ball] = np.clip(shade[ball] + rng.normal(0, 3, (ball.sum(), 3)), 0, 255).astype(np.uint8)
        img[ball & (rng.random((H, W)) < 0.05)] = (20, 20, 20)  # dark paint
        centers.append((cx, cy))
        radii.append(r)
    fast = ball_white_balance(img, centers, radii)
    plain = ball_white_balance(img.astype(np.float32), centers, radii)
    assert np.array_equal(fast, plain)
    assert fast[0] < 0.95  # a cast was measured (the comparison is not of (1, 1, 1) only)


@pytest.mark.parametrize("n", [1, 2, 7, 200, 201, 5000])
def test_robust_ceiling_equals_np_median_formula(n):
    x = np.random.default_rng(n).normal(0.05, 0.02, n).astype(np.float32)
    med = float(np.median(x))
    want = med + 6.0 * max(1.4826 * float(np.median(np.abs(x - med))), 2.0 / 255.0)
    assert _robust_ceiling(x) == want


def _reference_newton(points, x0, f_scale, tol=1e-8, max_iter=50):
    """``_soft_l1_newton`` as it was: the Jacobian stacked anew every step."""
    x = np.array(x0, float)
    px, py = points[:, 0], points[:, 1]

    def at(x):
        dx, dy = px - x[0], py - x[1]
        dist = np.hypot(dx, dy)
        e = dist - x[2]
        return dx, dy, dist, e, float(np.sum(np.sqrt(1.0 + (e / f_scale) ** 2)))
    dx, dy, dist, e, cost = at(x)
    for _ in range(max_iter):
        z = (e / f_scale) ** 2
        rho1 = 1.0 / np.sqrt(1.0 + z)
        h = np.maximum(rho1 - z * rho1 ** 3, 0.1 * rho1)
        inv = 1.0 / np.maximum(dist, 1e-12)
        J = np.stack([-dx * inv, -dy * inv, -np.ones_like(dx)], 1)
        step = np.linalg.solve((J * h[:, None]).T @ J, -(J.T @ (rho1 * e)))
        for _h in range(30):
            got = at(x + step)
            if got[4] <= cost * (1 + 1e-15):
                break
            step = 0.5 * step
        x = x + step
        dx, dy, dist, e, cost = got
        if float(np.max(np.abs(step))) < tol * (1.0 + float(np.max(np.abs(x)))):
            return x
    return None


@pytest.mark.parametrize("seed", range(5))
def test_newton_jacobian_in_place_is_bit_identical(seed):
    """Short and long arcs with outliers (a notch): the same iterates as the stacked Jacobian."""
    rng = np.random.default_rng(seed)
    for _ in range(10):
        r = rng.uniform(5.0, 60.0)
        span = rng.uniform(0.5, 2 * np.pi)
        th = rng.uniform(0.0, span, int(rng.integers(12, 200)))
        pts = np.stack([r * np.cos(th), r * np.sin(th)], 1) + 500.0 + rng.normal(0.0, 0.3, (len(th), 2))
        pts[: len(pts) // 10] *= 0.98  # a few points well inside
        x0 = np.array([500.0 + rng.normal(0, 2), 500.0 + rng.normal(0, 2), r * rng.uniform(0.8, 1.2)])
        got, want = _soft_l1_newton(pts, x0, 0.5), _reference_newton(pts, x0, 0.5)
        assert (got is None and want is None) or np.array_equal(got, want)


@pytest.mark.parametrize("n", [1, 7, 1600])
def test_sample_mean_rows_equal_numpy_mean_of_nine(n):
    """The lit-sphere band's per-pixel mean of its 3 x 3 samples, added row by row on the
    sample-major array, is ``mean(axis=(1, 2))`` of the pixel-major one bit for bit (values with
    zeros, tiny and large magnitudes: the order of the additions decides the rounding); other
    sample counts take NumPy's own mean."""
    from stillcap.detect.ball._shading import _sample_mean
    rng = np.random.default_rng(n)
    for ss in (3, 2, 4):
        v = rng.random((n, ss, ss)) * np.where(rng.random((n, ss, ss)) < 0.3, 0.0, 1.0)
        v[rng.random((n, ss, ss)) < 0.05] = 1e-300
        v[rng.random((n, ss, ss)) < 0.05] *= 1e12
        want = v.mean(axis=(1, 2))
        got = _sample_mean(np.ascontiguousarray(v.reshape(n, ss * ss).T))
        assert np.array_equal(got, want)


def test_lit_frame_with_outline_geometry_given_is_the_same():
    """``_lit_frame`` with the outline's geometry computed once (``_outline_geometry``, as
    ``_shading_bias`` passes it to every frame) gives the numbers it computes itself."""
    from stillcap.detect.ball._shading import _outline_geometry
    rng = np.random.default_rng(7)
    for _ in range(6):
        r = rng.uniform(8.0, 30.0)
        n = int(2 * r + 24)
        c, A, light, img = _random_ball(rng, r, n, abs)
        img = cv2.GaussianBlur(img, (0, 0), 0.8)
        th = np.linspace(0, 2 * np.pi, 96, endpoint=False)
        off = np.stack([np.cos(th), np.sin(th)], axis=1) @ A.T
        geom = _outline_geometry(off)
        for shift in (0.0, 0.3):
            a = _lit_frame(img, c + shift, off)
            b = _lit_frame(img, c + shift, off, geom=geom)
            assert all(np.array_equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("signed", [False, True])
def test_window_centroid_equals_masked_crop_sums(signed):
    """The radiance centroid summed over the window's gathered pixels is the masked crop's
    (``np.where`` over the whole crop, as it was) to float rounding: float64 images (the model's
    sums in the same precision) to 1e-12, float32 photos (the old sums accumulated the weights in
    float32) to 1e-6 of a radius; faint noisy balls, lit from any side."""
    from stillcap.detect.ball._shading import _centroid_window, _radiance_centroid
    from stillcap._numeric import median
    rng = np.random.default_rng(11 if signed else 12)
    checked = 0
    for _ in range(10):
        r = rng.uniform(6.0, 40.0)
        n = int(2.6 * r + 12)
        c, A, light, img = _random_ball(rng, r, n)
        img = cv2.GaussianBlur(img, (0, 0), 1.0)
        img = np.clip(0.3 * img + 0.05 + rng.normal(0.0, 0.02, img.shape), 0, 1)
        yy, xx = np.mgrid[0:n, 0:n]
        q = np.einsum("ij,jhw->ihw", np.linalg.inv(A), np.stack([xx - c[0], yy - c[1]]).astype(float))
        inside, ring = q[0] ** 2 + q[1] ** 2 < 1.15 ** 2, q[0] ** 2 + q[1] ** 2 > 1.3 ** 2
        for im, tol in ((img.astype(np.float64), 1e-12), (img.astype(np.float32), 1e-6)):
            if signed:
                level = float(im[ring].mean())
                wgt = np.where(inside, im - level, 0.0)
            else:
                level = median(im[ring])
                wgt = np.where(inside, np.maximum(im - level, 0.0), 0.0)
            tot = float(wgt.sum())
            got = _radiance_centroid(im, q, signed, _centroid_window(q))
            if not tot > 0:
                assert got is None
                continue
            want = np.array([(wgt * q[0]).sum(), (wgt * q[1]).sum()]) / tot
            assert np.abs(got - want).max() < tol, (got, want)
            checked += 1
    assert checked >= 12


@pytest.mark.parametrize("r", [6.0, 10.0, 14.0, 20.0, 30.0, 45.0])
def test_supersampled_depth_keeps_every_pixel_within_its_error(r):
    """The limb blur's model is supersampled only ``supersample_depth_px`` deep (where one sample
    at a pixel's centre misses its mean by more than ``SUPERSAMPLE_ERROR``): lit from the camera
    (the most curved radiance, no terminator inside the disc), every pixel is within 1.5x that
    error of the ball supersampled all over (3 x 3 samples, not the exact mean; an ellipse bends
    more along its short axis), at any sub-pixel placement; a third of that depth misses by more."""
    from stillcap.detect.ball._shading import SUPERSAMPLE_ERROR, supersample_depth_px
    rng = np.random.default_rng(int(r))
    for _ in range(3):
        n = int(2 * r + 14)
        c = np.array([n / 2, n / 2]) + rng.uniform(-0.5, 0.5, 2)
        A = _ellipse(rng, r)
        yy, xx = np.mgrid[0:n, 0:n]
        q = np.einsum("ij,jhw->ihw", np.linalg.inv(A), np.stack([xx - c[0], yy - c[1]]).astype(float))
        full = _lit_sphere_image((n, n), c, A, (0.0, 0.0, 1.0))
        depth = supersample_depth_px(float(np.linalg.svd(A, compute_uv=False)[-1]))
        got = _lit_sphere_image((n, n), c, A, (0.0, 0.0, 1.0), band_px=depth, q=q)
        assert np.abs(got - full).max() <= 1.5 * SUPERSAMPLE_ERROR
    if depth < r:  # balls whose middle bends less than the error: a shallower band misses
        less = _lit_sphere_image((n, n), c, A, (0.0, 0.0, 1.0), band_px=depth / 3.0, q=q)
        assert np.abs(less - full).max() > 1.5 * SUPERSAMPLE_ERROR


def test_report_over_the_window_equals_the_whole_crop():
    """The correction's report over the window's gathered pixels: the misfit shift is the whole
    crop's ``np.gradient`` fit bit for bit (window inside the crop, and one touching its border),
    the split-half phase sigma the masked crop's to float32 rounding of its halves' sums."""
    from stillcap._numeric import median
    from stillcap.detect.ball._shading import _centroid_window, _misfit_shift, _phase_split_sd
    rng = np.random.default_rng(21)
    for k in range(8):
        r = rng.uniform(8.0, 30.0)
        n = int(2 * r + 24) if k % 2 else int(2 * r + 2)  # odd k: the 1.3-radius window leaves the crop
        c, A, light, img = _random_ball(rng, r, n)
        img = np.clip(0.6 * cv2.GaussianBlur(img, (0, 0), 0.9) + 0.03 + rng.normal(0.0, 0.01, img.shape), 0, 1)
        img = img.astype(np.float32)
        model = cv2.GaussianBlur(_lit_sphere_image((n, n), c + 0.2, A, tuple(light)), (0, 0), 0.9)
        yy, xx = np.mgrid[0:n, 0:n]
        q = np.einsum("ij,jhw->ihw", np.linalg.inv(A), np.stack([xx - c[0], yy - c[1]]).astype(float))
        win = _centroid_window(q)
        r2 = win[2]
        sel = r2 < 1.3 ** 2
        gy, gx = np.gradient(model.astype(np.float64))
        J = np.stack([gx[sel], gy[sel], model[sel].astype(np.float64), np.ones(np.count_nonzero(sel))], axis=1)
        coef = np.linalg.solve(J.T @ J, J.T @ img[sel].astype(np.float64))
        assert np.array_equal(_misfit_shift(img, model, r2), -coef[:2] / coef[2])
        inside, ring = win[0], win[1]
        nl = float(np.hypot(light[0], light[1]))
        ax, ay = light[0] / nl, light[1] / nl
        w = np.where(inside, np.maximum(img - median(img[ring]), 0.0), 0.0)
        s, side = q[0] * ax + q[1] * ay, q[1] * ax - q[0] * ay > 0
        m = [float((w[h] * s[h]).sum()) / float(w[h].sum()) for h in (side, ~side)]
        got = _phase_split_sd(img, q, win, tuple(light), False, 0.5)
        assert abs(got - min(0.5 * abs(m[0] - m[1]) / 0.5, np.pi / 2)) <= 1e-6


def test_crescent_limb_circle_warm_started_is_the_cold_fit():
    """The crescent's limb circle, each round's fit started from the round before's circle (not
    the Kasa circle of its points), ends on the same circle to 1e-5 px: noisy drawn crescents'
    outer contours with the terminator's points among them."""
    import stillcap.detect.ball._arcs as arcs
    from stillcap.detect.circle_fit import fit_circle
    rng = np.random.default_rng(5)
    real = arcs.fit_circle
    for _ in range(10):
        r = rng.uniform(8.0, 30.0)
        c = rng.uniform(40.0, 60.0, 2)
        t = np.linspace(-1.2, 1.2, int(3 * r))  # the lit limb, ~140 deg
        phi = rng.uniform(0, 2 * np.pi)
        limb = c + r * np.stack([np.cos(t + phi), np.sin(t + phi)], 1)
        term = c + 0.5 * r * np.stack([np.cos(t + phi), np.sin(t + phi)], 1) * np.abs(np.cos(t))[:, None]
        pts = np.concatenate([limb, term]) + rng.normal(0.0, 0.3, (2 * len(t), 2))
        warm = arcs._limb_circle(pts, 0.5, None, 60.0, 1.0, 0.06)
        try:  # every round from the Kasa circle of its points, as before
            arcs.fit_circle = lambda p, radius=None, start=None, **k: fit_circle(p, radius=radius, **k)
            cold = arcs._limb_circle(pts, 0.5, None, 60.0, 1.0, 0.06)
        finally:
            arcs.fit_circle = real
        assert (warm is None) == (cold is None)
        if warm is not None:
            assert np.abs(warm[0] - cold[0]).max() < 1e-5 and abs(warm[1] - cold[1]) < 1e-5


@pytest.mark.parametrize("radius_px", [2.7, 3.2, 38.7, 39.2])
def test_supersample_depth_is_quiet_where_its_grid_reaches_the_centre(radius_px):
    """Radii whose 0.05 px depth grid lands on the ball's centre (R = 0) divided 0 by 0 there: a
    RuntimeWarning in the demo's output; the depth is that of the grid without the centre."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        depth = supersample_depth_px(radius_px)
    assert 0.0 < depth < radius_px or depth == float("inf")
