"""Each marker's centroid standard error read from its own photo (issue 12):
:func:`stillcap.detect._marker_noise.centroid_sigma_px` through the detector."""

import numpy as np
import pytest

from stillcap.detect._marker_noise import centroid_sigma_px, leather_noise
from stillcap.detect.ball_markers import detect_ball_markers

H = W = 96
CX, CY, R = 47.3, 44.6, 36.0


def _photo(rng, noise_levels):
    """A flat white ball (200) on dark ground with one black disc marker (radius 4 px,
    antialiased by 4x4 supersampling) off its centre, Gaussian luma noise, 8 bits."""
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    img = np.full((H, W), 20.0)
    img[np.hypot(xx - CX, yy - CY) <= R] = 200.0
    cover = np.zeros((H, W))
    for dy in np.linspace(-0.375, 0.375, 4):
        for dx in np.linspace(-0.375, 0.375, 4):
            cover += np.hypot(xx + dx - 52.6, yy + dy - 41.1) <= 4.0
    img = img * (1 - cover / 16) + 43.0 * cover / 16
    img = img + rng.normal(0.0, noise_levels, img.shape)
    return np.repeat(np.clip(np.round(img), 0, 255).astype(np.uint8)[..., None], 3, axis=2)


@pytest.mark.parametrize("noise_levels", [6.0])
def test_stated_sigma_matches_the_scatter_of_the_centroids(noise_levels):
    # 150 noise draws of one photo: the centroids' RMS scatter per axis against the mean of the
    # stated sigmas. The band: the scatter of 150 draws is known to ~6 % (1 / sqrt(2 x 150)),
    # and the stated sigma counts the marker's clipped rim pixels fully (a slight
    # overestimate by design, centroid_sigma_px) and ignores the region's own change from draw
    # to draw; measured 0.97-1.12 at 4-8 levels of noise. 0.8-1.25 leaves room for those and
    # still fails a sigma off by the leather's MAD-vs-sigma factor or a missing sqrt(2).
    rng = np.random.default_rng(0)
    cen, sig = [], []
    for _ in range(150):
        m = detect_ball_markers(_photo(rng, noise_levels), [[CX, CY]], [R])
        k = np.flatnonzero(m.types == "black")
        assert len(k) == 1
        cen.append(m.centers[k[0]])
        sig.append(m.centroid_sigma_px[k[0]])
    cen, sig = np.array(cen), np.array(sig)
    # (a few draws weigh the marker against a light fitted to the flat ball's noise: NaN there)
    assert np.isfinite(sig).mean() > 0.8
    scatter = float(np.sqrt(cen.var(axis=0).mean()))
    ratio = float(np.nanmean(sig)) / scatter
    assert 0.8 < ratio < 1.25, (ratio, scatter)


def test_centroid_sigma_formula():
    # a 3x3 box of unit weights: var(c_x) = noise^2 sum((x - c)^2) / sum(w)^2 = n^2 6 / 81
    w = np.zeros((5, 5))
    w[1:4, 1:4] = 1.0
    X, Y = np.arange(5.0)[None, :], np.arange(5.0)[:, None]
    assert centroid_sigma_px(w, X, Y, 0.1) == pytest.approx(0.1 * np.sqrt(6.0) / 9.0)
    assert np.isnan(centroid_sigma_px(w, X, Y, float("nan")))
    assert np.isnan(centroid_sigma_px(np.zeros((5, 5)), X, Y, 0.1))


def test_leather_noise_is_robust_and_needs_pixels():
    rng = np.random.default_rng(1)
    x = rng.normal(0.0, 0.02, 400)
    x[:20] = 0.6  # paint the mask missed
    assert leather_noise(x) == pytest.approx(0.02, rel=0.15)
    assert np.isnan(leather_noise(x[:5]))
