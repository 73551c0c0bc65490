"""stillcap.detect.response: the response's effective gamma from the shading of lit spheres."""

import cv2
import numpy as np
import pytest

from stillcap.detect import response as response_module
from stillcap.detect.response import MIN_SPHERES, ball_shading_gamma, estimate_response, response_check
from stillcap.response import Response


def sphere_photo(gamma, light=(0.3, -0.2, -0.93), r=18.0, size=64, albedo=0.8, ambient=0.0, blur=0.6,
                 noise=0.0, rng=0, markers=True, n_markers=3, specular=0.0):
    """A lambertian sphere (centre at the image centre, radius r) lit from ``light`` (camera frame,
    z away from the camera), with ``n_markers`` dark marker spots and, with ``specular`` > 0, a
    highlight of that peak radiance where the surface mirrors the light toward the camera,
    encoded with ``gamma``."""
    rng = np.random.default_rng(rng)
    s = np.asarray(light, float) / np.linalg.norm(light)
    ss = 4  # supersampled
    y, x = (np.mgrid[0:size * ss, 0:size * ss] + 0.5) / ss - 0.5
    c = (size - 1) / 2
    nx, ny = (x - c) / r, (y - c) / r
    rho2 = nx * nx + ny * ny
    inside = rho2 < 1
    nz = -np.sqrt(np.clip(1 - rho2, 0, 1))
    shade = np.clip(nx * s[0] + ny * s[1] + nz * s[2], 0, None)
    a = np.full(shade.shape, albedo)
    if markers:
        for mx, my in rng.uniform(-0.5, 0.5, (n_markers, 2)):
            a[(nx - mx) ** 2 + (ny - my) ** 2 < 0.02] = 0.03
    rad = np.where(inside, a * shade + ambient, 0.0)
    if specular:
        h = s + np.array([0.0, 0.0, -1.0])  # the half vector between the light and the view
        h /= np.linalg.norm(h)
        rad = rad + np.where(inside, specular * np.clip(nx * h[0] + ny * h[1] + nz * h[2], 0, 1) ** 200, 0.0)
    rad = cv2.resize(rad, (size, size), interpolation=cv2.INTER_AREA)
    if blur:
        rad = cv2.GaussianBlur(rad, (0, 0), blur)
    rad = np.clip(rad + noise * rng.standard_normal(rad.shape), 0, 1)
    code = np.round(Response.from_json(gamma).encode(rad)).astype(np.uint8)
    return np.repeat(code[:, :, None], 3, axis=2), np.array([c, c]), r


@pytest.mark.parametrize("gamma, value", [("linear", 1.0), ({"gamma": 1.8}, 1.8), ("srgb", 2.14), ({"gamma": 2.6}, 2.6)])
@pytest.mark.parametrize("light", [(0, 0, -1), (0.5, -0.3, -0.81), (-0.9, 0.1, -0.42), (0.95, 0.2, 0.24)])
def test_recovers_the_effective_gamma(gamma, value, light):
    img, c, r = sphere_photo(gamma, light, noise=0.002)
    f = ball_shading_gamma(img, c, r)
    assert f is not None
    assert f["gamma"] == pytest.approx(value, rel=0.12)
    assert np.dot(f["light"], np.asarray(light) / np.linalg.norm(light)) > 0.95


def test_nothing_to_fit():
    img, c, r = sphere_photo("srgb")
    assert ball_shading_gamma(img, c, 2.5) is None  # too small
    assert ball_shading_gamma(img, (5.0, 30.0), r) is None  # cut by the border
    assert ball_shading_gamma(np.full((64, 64, 3), 120, np.uint8), c, r) is None  # flat: no shading


def test_estimate_combines_and_says_when_it_cannot_tell():
    photos = [sphere_photo("linear", light, rng=k) for k, light in
              enumerate([(0, 0, -1), (0.4, 0.1, -0.9), (-0.3, 0.5, -0.8), (0.7, -0.2, -0.68)])]
    e = estimate_response([p[0] for p in photos], [p[1][None] for p in photos], [p[2] for p in photos])
    assert e.ok and e.response_class == "linear" and e.n_spheres == 4
    assert e.response() == Response.linear()
    assert "linear" in e.evidence and e.to_json()["class"] == "linear"
    few = estimate_response([p[0] for p in photos[:MIN_SPHERES - 1]], [p[1][None] for p in photos[:2]],
                            [p[2] for p in photos[:2]])
    assert not few.ok and few.response() is None and "cannot tell" in few.evidence
    check = response_check(few, Response.srgb(), "cam")
    assert check.passed and "cannot tell" in check.message


def test_check_fires_on_a_wrong_declaration_and_passes_on_the_right_one():
    for true, wrong in (("linear", Response.srgb()), ("srgb", Response.linear()), ({"gamma": 2.6}, Response.linear())):
        photos = [sphere_photo(true, light, rng=k) for k, light in
                  enumerate([(0, 0, -1), (0.4, 0.1, -0.9), (-0.3, 0.5, -0.8)])]
        e = estimate_response([p[0] for p in photos], [p[1][None] for p in photos], [p[2] for p in photos])
        right = response_check(e, Response.from_json(true), "cam_0")
        bad = response_check(e, wrong, "cam_0")
        assert right.passed and right.name == "response" and right.subject == "cam_0"
        assert not bad.passed and bad.value > bad.limit and "disagrees" in bad.message


@pytest.mark.parametrize("gamma, value", [("linear", 1.0), ("srgb", 2.14), ({"gamma": 2.6}, 2.6)])
def test_painted_markers_and_a_highlight_fall_out_of_the_fit(gamma, value):
    """The robust fit (soft-L1 weights, then the dark paint left out): six dark markers and a
    saturating specular highlight on the disc do not move the gamma."""
    img, c, r = sphere_photo(gamma, (0.4, -0.3, -0.87), r=22.0, size=70, n_markers=6, specular=1.5, noise=0.002,
                             rng=3)
    assert (img == 255).any() and (img < 30).any()  # the highlight clips, the paint is dark
    plain = ball_shading_gamma(*sphere_photo(gamma, (0.4, -0.3, -0.87), r=22.0, size=70, markers=False,
                                             noise=0.002, rng=3))
    f = ball_shading_gamma(img, c, r)
    assert f["gamma"] == pytest.approx(value, rel=0.12)
    assert f["gamma"] == pytest.approx(plain["gamma"], rel=0.08)


def test_a_big_ball_is_fitted_on_a_subsample_to_the_same_gamma():
    """A disc of ~3,000 inner pixels is fitted on every k-th pixel and row (at most ~max_pixels):
    the same gamma as from all of them, and the pixel count reported is the disc's."""
    img, c, r = sphere_photo("srgb", (0.5, -0.3, -0.81), r=40.0, size=100, noise=0.003, rng=5)
    every = ball_shading_gamma(img, c, r, max_pixels=100_000)
    sub = ball_shading_gamma(img, c, r, max_pixels=300)
    assert every["gamma"] == pytest.approx(2.14, rel=0.1)
    assert sub["gamma"] == pytest.approx(every["gamma"], rel=0.05)
    assert sub["n"] == pytest.approx(every["n"], rel=0.15)


def test_the_batched_fit_gives_each_ball_its_own_gamma():
    """estimate_response fits all balls at once: each ball's gamma is the one it gets alone,
    whatever the others (different sizes, lights and responses in one batch)."""
    photos = [sphere_photo(g, light, r=r, size=int(2 * r + 20), noise=0.002, rng=k) for k, (g, light, r) in
              enumerate([("linear", (0, 0, -1), 12.0), ("srgb", (0.6, 0.2, -0.77), 25.0),
                         ({"gamma": 2.6}, (-0.9, 0.1, -0.42), 8.0), ("srgb", (0.3, 0.6, -0.74), 17.0)])]
    discs = [response_module._disc(p[0], p[1], p[2], 0.8, response_module._MAX_PIXELS) for p in photos]
    together = response_module._fit_discs(discs)
    for p, t in zip(photos, together):
        alone = ball_shading_gamma(*p)
        assert t["gamma"] == pytest.approx(alone["gamma"], rel=1e-6)
        np.testing.assert_allclose(t["light"], alone["light"], atol=1e-6)


def test_only_the_largest_spheres_are_fitted():
    photos = [sphere_photo("linear", (0.2, 0.1, -0.97), r=r, size=int(2 * r + 20), rng=k)
              for k, r in enumerate([9.0, 20.0, 14.0, 6.0, 17.0])]
    e = estimate_response([p[0] for p in photos], [p[1][None] for p in photos], [p[2] for p in photos],
                          max_spheres=3)
    assert e.n_spheres == 3 and e.response_class == "linear"


@pytest.mark.parametrize("gamma, value", [("linear", 1.0), ({"gamma": 1.8}, 1.8), ({"gamma": 2.6}, 2.6)])
def test_the_measured_blur_removes_the_gamma_bias(gamma, value):
    """1.5 px of lens blur on 8 px spheres flattens the shading (a gamma ~25 % low with a sharp
    model); given the blur (as the ball step measures it on the limbs), the model blurs the
    radiance and the estimate comes within 10 %."""
    photos = [sphere_photo(gamma, light, r=8.0, size=30, blur=1.5, noise=0.002, rng=i, markers=False)
              for i, light in enumerate([(0, 0, -1), (0.5, -0.3, -0.81), (-0.9, 0.1, -0.42), (0.6, 0.5, -0.62),
                                         (0.3, 0.2, -0.93)])]
    args = ([p[0] for p in photos], [p[1][None] for p in photos], [p[2] for p in photos])
    sharp, = response_module.estimate_responses([args])
    blurred, = response_module.estimate_responses([args + (1.5,)])
    assert abs(np.log(sharp.gamma / value)) > 0.2
    assert abs(np.log(blurred.gamma / value)) < 0.1
    assert blurred.blur_px == 1.5 and blurred.radius_px == pytest.approx(8.0)
    assert np.isnan(sharp.blur_px)


def test_response_check_tolerance_follows_the_estimates_scatter():
    """The check passes up to 0.3 + 2.5 standard errors of the estimate (its spheres' scatter):
    the same gap fails a tight estimate and passes a scattered one; a wrong class still fails."""
    srgb = Response.srgb()
    gd = srgb.effective_gamma

    def est(gamma, spread, n=10):  # n spheres whose log-gammas have the robust sigma ``spread``
        g = gamma * np.exp(spread * np.resize([-0.6745, 0.6745], n))
        return response_module.ResponseEstimate("gamma" if gamma > 1.35 else "linear", gamma, spread, n, g)

    tight, loose = est(gd * np.exp(-0.4), 0.02), est(gd * np.exp(-0.4), 0.4)
    assert loose.log_gamma_se == pytest.approx(1.2533 * 0.4 / np.sqrt(10))
    a, b = response_check(tight, srgb, "cam"), response_check(loose, srgb, "cam")
    assert not a.passed and b.passed
    assert b.limit == pytest.approx(0.3 + 2.5 * loose.log_gamma_se) and b.value == pytest.approx(0.4)
    assert "scatter" in b.message
    assert not response_check(est(1.0, 0.4), srgb, "cam").passed  # a linear camera declared sRGB
    one = est(gd * np.exp(-0.25), float("nan"), n=1)  # no scatter known: the floor alone
    assert one.log_gamma_se == 0.0
    # spheres stuck at one gamma collapse the MAD, not the trimmed deviation
    ties = response_module.ResponseEstimate("gamma", 1.26, 0.0, 8, np.array([1.26, 0.84, 1.72, 1.95, 1.26, 1.26,
                                                                               1.17, 1.26]))
    trimmed = np.std(np.sort(np.log(ties.gammas))[1:-1], ddof=1)
    assert ties.log_gamma_se == pytest.approx(1.2533 * trimmed / np.sqrt(8)) and ties.log_gamma_se > 0.05


def test_radiance_is_the_where_form_bit_for_bit_on_edge_values():
    # the fit's lit radiance (speed only, issue 16): np.fmax in place gives np.where's numbers,
    # also for -0.0, NaN, +-inf and an ambient of +-0 (fmax keeps -0.0; adding b and the clip
    # must turn it into the same number)
    from stillcap.detect.response import _radiance

    rng = np.random.default_rng(3)
    edge = np.array([-0.0, 0.0, np.nan, np.inf, -np.inf, 1e-300, -1e-300, 2.0, -2.0, 1e-9, 0.5])
    ns = np.concatenate([edge, rng.normal(0, 0.5, 200)])
    for b in (0.0, -0.0, 1e-12, 0.05, 0.3, 1.0):
        for shape in ((1, 1), (2, 3)):
            n = np.broadcast_to(ns, shape + ns.shape).copy()
            bb = np.full(shape, b)
            want = np.clip(np.where(n > 0.0, n, 0.0) + bb[..., None], 1e-9, 1.0)
            got = _radiance(n.copy(), bb)
            assert np.array_equal(np.signbit(got), np.signbit(want))
            assert np.array_equal(got, want, equal_nan=True)


@pytest.mark.parametrize("key, bad", [("limit", -0.1), ("limit", float("nan")), ("limit", float("inf")),
                                      ("limit", "0.3"), ("z", -1.0), ("z", float("nan")), ("z", None)])
def test_response_check_rejects_bad_limit_and_z(key, bad):
    """A negative, non-finite or non-numeric ``limit`` or ``z`` is one ValueError naming the keyword
    (a negative or NaN tolerance would fail every camera, right or wrong)."""
    e = response_module.ResponseEstimate("gamma", 2.2, 0.05, 10, np.full(10, 2.2))
    with pytest.raises(ValueError, match=rf"response_check: {key} must be a finite number >= 0"):
        response_check(e, Response.srgb(), "cam", **{key: bad})
    # the edges are allowed: a zero floor, a zero z
    assert response_check(e, Response.srgb(), "cam", **{key: 0.0}).limit >= 0.0
