"""Several photos identified at once (identify_markers_views / identify_colors_views) and the
written-out Lab conversion: the same numbers as one photo at a time and as scikit-image."""

import numpy as np
import pytest
from skimage.color import rgb2lab

from stillcap.body.markerset import MarkerSet
from stillcap.detect.circles import find_circles
from stillcap.detect.identify import (
    RECOMMENDED,
    THESIS,
    identify_colors,
    identify_colors_views,
    identify_markers,
    identify_markers_views,
)
from stillcap.detect.palette import Palette, rgb_to_lab
from stillcap.studio.beads import random_bead_scene

PAL = Palette.from_markerset(MarkerSet.puppet())
FIELDS = ("points", "distances", "candidate", "rejected", "colors", "cost", "gains", "radii")


def _assert_same(a, b):
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert (a.method, a.metric, a.sampler, a.max_distance) == (b.method, b.metric, b.sampler, b.max_distance)


@pytest.fixture(scope="module")
def photos():
    scenes = [random_bead_scene(PAL.rgb, rng=s, n_beads=n) for s, n in ((0, None), (1, 12), (2, 2), (3, None))]
    images = [sc.image for sc in scenes]
    circles = [find_circles(im) for im in images]
    circles[3] = circles[3].__class__(circles[3].centers[:0], circles[3].radii[:0], circles[3].scores[:0], "template")
    return images, circles


@pytest.mark.parametrize("preset", [RECOMMENDED, THESIS, {"method": "assignment", "metric": "lab", "adapt": True}])
def test_views_at_once_are_each_view_alone(photos, preset):
    """A full photo, one with 12 beads, one with 2 (too few matches to adapt the white
    balance), one without candidates: every field as identify_markers's, bit for bit."""
    images, circles = photos
    many = identify_markers_views(images, circles, PAL, **preset)
    assert len(many) == len(images)
    for img, c, m in zip(images, circles, many):
        _assert_same(identify_markers(img, c, PAL, **preset), m)
    assert many[0].n_found >= 14 and many[3].n_found == 0


def test_color_sets_with_nan_rows(photos):
    rng = np.random.default_rng(2)
    cols = [rng.uniform(0, 1, (9, 3)), np.full((3, 3), np.nan), rng.uniform(0, 1, (0, 3)), PAL.rgb * 0.9]
    cols[0][4] = np.nan
    many = identify_colors_views(cols, PAL)
    for c, m in zip(cols, many):
        _assert_same(identify_colors(c, PAL), m)
    assert many[3].n_found == len(PAL)


def test_views_bad_input(photos):
    images, circles = photos
    with pytest.raises(ValueError, match="4 images but 3 candidate sets"):
        identify_markers_views(images, circles[:3], PAL)
    with pytest.raises(ValueError, match="2 colour sets but 1 centre sets"):
        identify_colors_views([np.zeros((1, 3))] * 2, PAL, centers=[np.zeros((1, 2))])
    with pytest.raises(ValueError, match="lightness_weight must be > 0"):
        identify_colors_views([np.full((2, 3), 0.5)], PAL, lightness_weight=0.0)


def test_rgb_to_lab_is_scikit_images_bit_for_bit():
    """Random colours (out of range ones clipped), the sRGB knee, black and white, 1 to 500 colours."""
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 16, 20, 57, 500):
        for _ in range(20):
            a = rng.uniform(-0.1, 1.1, (n, 3))
            a[rng.random((n, 3)) < 0.05] = 0.04045
            a[rng.random((n, 3)) < 0.05] = 0.0
            a[rng.random((n, 3)) < 0.05] = 1.0
            np.testing.assert_array_equal(rgb_to_lab(a), rgb2lab(np.clip(a, 0, 1)[None])[0])
    assert rgb_to_lab(np.zeros((0, 3))).shape == (0, 3)


def test_rgb_to_lab_of_groups_is_each_groups_own():
    """Several photos' colours converted at once (groups of 0-40 rows): each group's rows as
    rgb_to_lab gives them alone, bit for bit (a BLAS product's rounding may depend on how many
    rows it multiplies: one product of all rows differed for ~4 % of such sets)."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        counts = rng.integers(0, 40, rng.integers(1, 13))
        parts = [rng.uniform(-0.1, 1.1, (k, 3)) for k in counts]
        together = rgb_to_lab(np.concatenate(parts), groups=counts)
        np.testing.assert_array_equal(together, np.concatenate([rgb_to_lab(p) for p in parts]))
    with pytest.raises(ValueError, match="groups must be row counts summing to the 5 colours"):
        rgb_to_lab(np.zeros((5, 3)), groups=[2, 2])


def _gains_one_by_one(costs, measured, reference):
    """The white-balance gains photo by photo (the definition): the confident half of the
    matches (cost at most their median), per channel the median of the finite ratios measured /
    reference in linear light (references above 0.02), ones with fewer than three pairs."""
    from stillcap._numeric import median
    from stillcap.detect.identify import _srgb_to_linear

    out = []
    for c, m, r in zip(costs, measured, reference):
        good = c <= median(c)
        if good.sum() < 3:
            out.append(np.ones(3))
            continue
        lm, lr = _srgb_to_linear(m[good]), _srgb_to_linear(r[good])
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(lr > 0.02, lm / lr, np.nan)
        g = np.array([median(col[np.isfinite(col)]) for col in ratio.T])
        out.append(np.where(np.isfinite(g) & (g > 0), g, 1.0))
    return np.array(out)


def test_white_balance_gains_of_all_photos_at_once_are_each_photos_own():
    """_gains_views (every photo's gains from one set of sorted arrays) gives each photo's own
    gains bit for bit: odd and even counts, ties, no matches, fewer than three confident pairs,
    dark references (no ratio) and a channel without any finite ratio."""
    from stillcap.detect.identify import _gains_views

    rng = np.random.default_rng(11)
    for trial in range(200):
        costs, meas, refs = [], [], []
        for _ in range(int(rng.integers(1, 9))):
            m = int(rng.choice([0, 1, 2, 3, 4, 5, 8, 13, 16]))
            c = rng.uniform(0, 30, m)
            if m > 3 and trial % 3 == 0:
                c[: m // 2] = c[0]  # ties at the median
            r = rng.uniform(0, 1, (m, 3))
            if m and trial % 4 == 0:
                r[:, 2] = 0.01  # a channel without a usable reference
            costs.append(c)
            refs.append(r)
            meas.append(np.clip(r * rng.uniform(0.5, 1.5, 3) + rng.normal(0, 0.05, (m, 3)), 0, 1))
        np.testing.assert_array_equal(_gains_views(costs, meas, refs), _gains_one_by_one(costs, meas, refs))


@pytest.mark.parametrize("dtype", [np.uint8, np.float64])
def test_discs_of_several_photos_are_each_photos_own(dtype):
    """The disc sampler over several photos at once (photos of different sizes, discs of
    different sizes, windows crossing the border, NaN rows, a photo without candidates): each
    photo's colours as sample_colors gives on it alone, bit for bit."""
    from stillcap.detect.identify import _sample_discs, sample_colors

    rng = np.random.default_rng(5)
    images, centers, radii = [], [], []
    for (h, w), n, r_max in (((48, 64), 30, 4.0), ((40, 30), 12, 14.0), ((20, 20), 0, 3.0), ((33, 50), 9, 8.0)):
        img = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
        images.append(img if dtype == np.uint8 else img / 255.0)
        c = np.c_[rng.uniform(-3, w + 3, n), rng.uniform(-3, h + 3, n)]
        c[::5] = np.nan
        centers.append(c)
        radii.append(rng.uniform(0.5, r_max, n))
    scales = [255.0 if dtype == np.uint8 else 1.0] * len(images)
    together = _sample_discs(images, centers, radii, 0.7, scales)
    for img, c, r, got in zip(images, centers, radii, together):
        np.testing.assert_array_equal(got, sample_colors(img, c, r, sampler="disc"))
    assert np.isfinite(together[1]).all(axis=1).sum() >= 5
