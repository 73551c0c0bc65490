import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from skimage.filters import threshold_isodata

from stillcap.body.markerset import MarkerSet
from stillcap.detect.circles import (
    METHODS,
    find_circles,
    grey_image,
    isodata_threshold,
    outline,
    refine_bead_centers,
)
from stillcap.detect.palette import Palette
from stillcap.studio.beads import draw_beads, random_bead_scene

PAL = Palette.from_markerset(MarkerSet.puppet())


@pytest.fixture(scope="module")
def scenes():
    """Six drawn puppet photos: the 16 thesis colours, limbs, touching and occluded beads,
    +-20 % light, white-balance shift, noise, JPEG 80."""
    return [random_bead_scene(PAL.rgb, rng=s) for s in range(6)]


def match(truth, found, tol=3.0):
    """Index of the found circle matched to each true centre (-1: missed) and the error."""
    m = np.full(len(truth), -1)
    e = np.full(len(truth), np.nan)
    if len(found):
        D = np.linalg.norm(truth[:, None] - found[None], axis=2)
        r, c = linear_sum_assignment(np.where(D < tol, D, 1e6))
        ok = D[r, c] < tol
        m[r[ok]], e[r[ok]] = c[ok], D[r[ok], c[ok]]
    return m, e


def test_outline_is_the_thesis_filter():
    mask = np.zeros((7, 7), bool)
    mask[1:6, 1:6] = True
    edge = outline(mask)
    # A pixel stays white unless all 8 neighbours are white: the 3x3 interior goes black.
    expect = mask.copy()
    expect[2:5, 2:5] = False
    assert np.array_equal(edge, expect)
    # Foreground at the image border has outside neighbours: it stays.
    assert outline(np.ones((3, 3), bool)).sum() == 8


def test_grey_and_isodata_threshold():
    img = np.zeros((4, 4, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 30, 60, 90
    assert np.allclose(grey_image(img), 60.0)  # ImageJ's unweighted (R + G + B) / 3
    g = np.r_[np.full(90, 10.0), np.full(10, 200.0)].reshape(10, 10)
    assert isodata_threshold(g) == pytest.approx(threshold_isodata(g))
    assert 10 < isodata_threshold(g) < 200
    assert isodata_threshold(np.full((5, 5), 7.0)) == np.inf


def test_drawn_beads_are_centered_where_asked():
    c = np.array([[20.3, 17.8]])
    img = draw_beads(c, [6.0], [[0.8, 0.5, 0.3]], size=(40, 40), background=0.0)
    g = img.mean(axis=2)
    ys, xs = np.mgrid[:40, :40]
    assert np.allclose([(g * xs).sum() / g.sum(), (g * ys).sum() / g.sum()], c[0], atol=0.01)
    # The thesis measures colours as the mean of the central 5x5 pixels: that is the colour asked.
    patch = img[16:21, 18:23].reshape(-1, 3).mean(axis=0)[::-1]
    assert np.allclose(patch, [0.8, 0.5, 0.3], atol=0.02)


@pytest.mark.parametrize("method", METHODS)
def test_methods_find_beads_on_drawn_photos(scenes, method):
    found = errs = total = 0
    for sc in scenes:
        circ = find_circles(sc.image, method=method)
        assert len(circ) <= 16 and np.all(np.diff(circ.scores) <= 0)
        assert np.all((circ.radii >= 4) & (circ.radii <= 8))
        vis = sc.occluded < 0.5
        m, e = match(sc.centers[vis], circ.centers)
        found += (m >= 0).sum()
        total += vis.sum()
        errs = np.r_[errs, e[m >= 0]] if np.ndim(errs) else e[m >= 0]
    rate = found / total
    if method == "thesis":  # whole-pixel centres
        assert rate > 0.85 and 0.3 < np.mean(errs) < 0.8
    elif method == "template":  # the default: everything, sub-pixel
        assert rate > 0.98 and np.median(errs) < 0.1 and np.mean(errs) < 0.2
    else:
        assert rate > 0.85 and np.median(errs) < 0.15


def test_default_is_template_and_beats_the_thesis(scenes):
    sc = scenes[0]
    default = find_circles(sc.image)
    assert default.method == "template"
    t = find_circles(sc.image, method="template")
    th = find_circles(sc.image, method="thesis")
    clean = (sc.occluded == 0)
    _, e_t = match(sc.centers[clean], t.centers)
    _, e_th = match(sc.centers[clean], th.centers)
    assert np.nanmean(e_t) < 0.5 * np.nanmean(e_th)
    assert np.all(np.isfinite(th.threshold)) and np.isnan(t.threshold)


def test_touching_beads_are_two_circles():
    c = np.array([[40.0, 40.0], [51.6, 42.2]])  # 11.8 px apart, radii 6 and 5.8: touching
    img = draw_beads(c, [6.0, 5.8], [[0.9, 0.4, 0.3], [0.3, 0.8, 0.4]], size=(80, 90), background=0.04)
    img = np.clip(img * 255, 0, 255).astype(np.uint8)
    for method in METHODS:
        circ = find_circles(img, n=2, method=method)
        m, e = match(c, circ.centers)
        assert np.all(m >= 0), method
        if method != "thesis":
            assert e.max() < 0.35, (method, e)


def test_refinement_converges_and_keeps_false_starts():
    c = np.array([[30.4, 25.7], [60.0, 30.0]])
    img = np.clip(draw_beads(c, [6, 6], [[0.7, 0.7, 0.2]] * 2, size=(60, 90), background=0.03) * 255, 0, 255)
    start = c + [[1.2, -0.8], [0.0, 0.0]]
    out = refine_bead_centers(img.astype(np.uint8), np.r_[start, [[80.0, 50.0]]], [6, 6, 6])
    assert np.abs(out[:2] - c).max() < 0.05
    assert np.allclose(out[2], [80, 50])  # nothing there: left where it was
    assert refine_bead_centers(img, np.zeros((0, 2)), np.zeros(0)).shape == (0, 2)


def test_radius_range_and_n_are_respected(scenes):
    circ = find_circles(scenes[1].image, n=5, method="thesis", radius_range=(5, 6))
    assert len(circ) == 5 and set(circ.radii) <= {5.0, 6.0}
    assert np.all(circ.centers == np.round(circ.centers))  # the thesis: whole pixels
    assert len(find_circles(scenes[1].image, n=0, method="template")) == 0


def test_empty_and_grey_images():
    for method in METHODS:
        assert len(find_circles(np.zeros((60, 80, 3), np.uint8), method=method)) == 0
    grey = np.zeros((60, 80), np.uint8)
    img = draw_beads([[40.0, 30.0]], [6.0], [[1.0, 1.0, 1.0]], size=(60, 80))
    grey[:] = np.clip(img.mean(axis=2) * 255, 0, 255)
    circ = find_circles(grey, n=1)
    assert np.abs(circ.centers[0] - [40, 30]).max() < 0.1


def test_scene_truth():
    sc = random_bead_scene(PAL.rgb, rng=3, n_beads=9, n_occluded=0, jpeg=None, noise=0)
    assert sc.image.shape == (480, 640, 3) and sc.image.dtype == np.uint8
    assert len(sc.centers) == 9 and len(set(sc.labels)) == 9 and np.all(sc.occluded == 0)
    assert np.allclose(sc.colors_rgb, np.clip(PAL.rgb[sc.labels] * sc.gain * sc.white_balance, 0, 1))


def test_bad_input():
    with pytest.raises(ValueError, match=r"image must have shape \(H, W\) or \(H, W, 3\), got \(5, 5, 4\)"):
        find_circles(np.zeros((5, 5, 4)))
    with pytest.raises(ValueError, match="method must be one of"):
        find_circles(np.zeros((5, 5)), method="magic")
    with pytest.raises(ValueError, match="radius_range"):
        find_circles(np.zeros((5, 5)), radius_range=(7, 5))
    with pytest.raises(ValueError, match=r"centers must have shape \(N, 2\), got \(3,\)"):
        refine_bead_centers(np.zeros((5, 5)), [1, 2, 3], [1])
    with pytest.raises(ValueError, match=r"mask must have shape \(H, W\)"):
        outline(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="n_beads"):
        random_bead_scene(PAL.rgb, n_beads=17)


def test_contrast_map_is_filter2d_of_the_disc_kernels(scenes):
    """The shared-DFT contrast map equals cv2.filter2D with each kernel and a replicated border
    (to float32 rounding), on the whole image and inside boxes."""
    import cv2

    from stillcap.detect.circles import contrast_map
    from stillcap.detect.circles._template import _disc_kernel

    radii = np.array([5.0, 6.0, 7.0])
    for sc in scenes[:3]:
        g = grey_image(sc.image)[37:301, 11:428]  # odd sizes: not a DFT size
        ref = np.stack([cv2.filter2D(g, -1, _disc_kernel(r), borderType=cv2.BORDER_REPLICATE) for r in radii])
        C, best = contrast_map(g, radii)
        assert C.shape == g.shape and C.dtype == np.float32
        assert np.abs(C - ref.max(axis=0)).max() < 1e-3
        strong = ref.max(axis=0) - np.sort(ref, axis=0)[-2] > 1e-2  # a clear best radius
        assert np.array_equal(best[strong], radii[ref.argmax(axis=0)][strong])
        boxes = [[20, 30, 120, 90], [200, 150, 417, 264]]
        Cb, _ = contrast_map(g, radii, boxes)
        for x0, y0, x1, y1 in boxes:
            assert np.abs(Cb[y0:y1, x0:x1] - ref.max(axis=0)[y0:y1, x0:x1]).max() < 1e-3
        outside = np.ones(g.shape, bool)
        for x0, y0, x1, y1 in boxes:
            outside[y0:y1, x0:x1] = False
        assert not Cb[outside].any()


def test_local_maxima_keep_the_first_pixel_of_a_plateau():
    """Equal maxima within md of each other: only the first in raster order stays (as the
    plain loop over all maxima did); equal maxima farther apart both stay."""
    from stillcap.detect.circles._template import _local_maxima

    C = np.zeros((40, 50), np.float32)
    C[10, 10] = C[10, 12] = C[12, 11] = 9.0  # one plateau of three pixels within md = 3
    C[30, 40] = 9.0  # same value, far away
    C[20, 25] = 12.0
    C[5, 45] = 2.0  # below the floor
    peaks = _local_maxima(C, 3, 5.0)
    assert peaks.tolist() == [[20, 25], [10, 10], [30, 40]]


def test_grey_median_and_grey_image_shortcuts_are_exact(scenes):
    """grey_image of a uint8 photo and the histogram median refine_bead_centers gets are exactly
    the float32 channel mean and np.median of it."""
    from stillcap.detect.circles._thesis import _median_grey

    rng = np.random.default_rng(0)
    for sc in scenes[:3]:
        for _ in range(4):
            y0, x0 = rng.integers(0, 200, 2)
            sub = sc.image[y0:y0 + rng.integers(1, 250), x0:x0 + rng.integers(1, 400)]
            g = grey_image(sub)
            assert np.array_equal(g, sub.astype(np.float32).mean(axis=2))
            assert _median_grey(sub) == float(np.median(g))
    assert _median_grey(np.zeros((4, 4), np.uint8)) is None  # grey input: the caller's median


def test_coarse_template_finds_the_full_resolution_peaks(scenes):
    """Peaks found at half resolution and climbed on the full-resolution contrast are the
    full-resolution map's own: same whole-pixel starts, so the same refined centres, radii and
    scores (to float32 rounding) on the drawn photos, also on an odd-sized crop."""
    for sc in scenes:
        for img in (sc.image, sc.image[13:402, 7:561]):
            a = find_circles(img)
            b = find_circles(img, coarse=True)
            assert len(b) == len(a) > 0
            np.testing.assert_allclose(b.centers, a.centers, atol=1e-6)
            np.testing.assert_array_equal(b.radii, a.radii)
            np.testing.assert_allclose(b.scores, a.scores, atol=1e-3)
    # a photo with nothing in it, and one too small to shrink: no circle, no error
    assert len(find_circles(np.zeros((60, 80, 3), np.uint8), coarse=True)) == 0
    assert len(find_circles(np.full((6, 6), 200, np.uint8), coarse=True)) == 0


def test_contrast_at_is_the_contrast_map(scenes):
    """The full-resolution contrast evaluated at single pixels (what the coarse detector's
    climb reads) equals the contrast map there, borders included."""
    import cv2

    from stillcap.detect.circles._template import _contrast_at, _contrast_stack, _kernel_stack

    radii = (5.0, 6.0, 7.0)
    g = grey_image(scenes[0].image)[40:200, 30:260]
    ref = _contrast_stack(g, np.array(radii))  # (R, H, W)
    kst = _kernel_stack(radii)
    pad = kst.shape[1] // 2
    gp = cv2.copyMakeBorder(g, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    rng = np.random.default_rng(1)
    rows = np.r_[0, g.shape[0] - 1, rng.integers(0, g.shape[0], 50)]
    cols = np.r_[g.shape[1] - 1, 0, rng.integers(0, g.shape[1], 50)]
    v = _contrast_at(gp, pad, rows, cols, kst)
    assert np.abs(v - ref[:, rows, cols].T).max() < 1e-3


def test_peak_suppression_and_ties_are_the_plain_loops():
    """The coarse template's non-maximum suppression and _local_maxima's tie test (faster forms)
    keep what the plain loops keep: random peaks with many neighbours and many equal values."""
    from stillcap.detect.circles._template import _local_maxima, _suppress

    rng = np.random.default_rng(3)
    for _ in range(30):
        n, md = int(rng.integers(0, 60)), int(rng.integers(1, 6))
        rows, cols = rng.integers(0, 40, n), rng.integers(0, 40, n)
        out = np.zeros(n, bool)
        for i in range(n):  # the plain loop
            if not out[i]:
                out |= (np.abs(rows - rows[i]) <= md) & (np.abs(cols - cols[i]) <= md) & (np.arange(n) > i)
        np.testing.assert_array_equal(_suppress(rows, cols, md), np.flatnonzero(~out))
        # _local_maxima with plateaus and repeated values: every kept pixel is a maximum of its
        # square, and of equal maxima within md only the first in raster order stays
        C = rng.integers(0, 6, (30, 35)).astype(np.float32)
        peaks = _local_maxima(C, md, 1.0)
        dil = np.array([[C[max(0, y - md):y + md + 1, max(0, x - md):x + md + 1].max() for x in range(35)]
                        for y in range(30)])
        ys, xs = np.nonzero((C >= dil) & (C > 1.0))
        cand = sorted(zip(-C[ys, xs], ys, xs))
        kept = []
        for v, y, x in cand:
            if not any(-v == C[ky, kx] and abs(y - ky) <= md and abs(x - kx) <= md for ky, kx in kept):
                kept.append((y, x))
        assert peaks.tolist() == [list(k) for k in kept]
