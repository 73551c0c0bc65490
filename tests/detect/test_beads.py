"""Bead stages of the puppet pipeline (stillcap.detect.beads): the fill test against a plain
per-bead reference, and detection on a drawn photo."""


import numpy as np
import pytest
from support import bead_levels_one_by_one

from stillcap.body.markerset import MarkerSet
from stillcap.detect.beads import (
    DETECTORS,
    IDENTIFIERS,
    bead_fill,
    bead_fill_views,
    detect_beads,
)
from stillcap.detect.palette import Palette
from stillcap.studio.beads import draw_beads, random_bead_scene


def _fill_one_by_one(image, centers, radii_px):
    """The definition, bead by bead: median of the ring r + 1.5 .. r + 3.5 (background), 90th
    percentile within r / 2 (bead), share of the disc brighter than halfway between them."""
    out = np.full(len(centers), np.nan)
    for i, v in enumerate(bead_levels_one_by_one(image, centers, radii_px)):
        if v is not None:
            bg, peak, disc = v
            out[i] = 0.0 if peak <= bg else float(np.mean(disc > bg + 0.5 * (peak - bg)))
    return out


def test_bead_fill_is_the_per_bead_definition():
    """All beads at once give exactly the bead-by-bead values: colour and grey photos, beads
    cut by the border or outside, NaN centres, bad radii, centres on half pixels."""
    rng = np.random.default_rng(5)
    sc = random_bead_scene(Palette.from_markerset(MarkerSet.puppet()).rgb, rng=1)
    n = 0
    for trial in range(40):
        img = sc.image if trial % 2 else sc.image.mean(axis=2)
        k = 25
        c = rng.uniform([-15, -15], [655, 495], (k, 2))
        c[:8] = sc.centers[rng.choice(len(sc.centers), 8, replace=False)] + rng.normal(0, 1, (8, 2))
        c[rng.random(k) < 0.1] = np.nan
        if trial % 5 == 0:
            c = np.round(c) + 0.5  # ties of round()
        r = rng.uniform(0.3, 9.0, k)
        r[rng.random(k) < 0.1] = -1.0
        got, want = bead_fill(img, c, r), _fill_one_by_one(img, c, r)
        np.testing.assert_array_equal(got, want)
        n += np.isfinite(want).sum()
    assert n > 500


def test_bead_fill_whole_against_half_hidden():
    img = draw_beads([[30.0, 30.0], [80.0, 30.0]], [6.0, 6.0], [[0.9, 0.2, 0.2], [0.2, 0.9, 0.2]], size=(60, 120),
                     limbs_front=[((80.0, 0.0), (80.0, 60.0), 6.0, 0.05)])
    f = bead_fill((img * 255).astype(np.uint8), [[30.0, 30.0], [80.0, 30.0], [np.nan, 1.0]], [6.0, 6.0, 6.0])
    assert f[0] > 0.7 and f[1] < 0.6 and np.isnan(f[2])
    assert bead_fill(img, np.zeros((0, 2)), []).shape == (0,)
    with pytest.raises(ValueError, match=r"shape \(H, W\) or \(H, W, 3\), got \(3,\)"):
        bead_fill(np.zeros(3), [[1.0, 1.0]], [5.0])


def test_detect_beads_names_the_drawn_beads():
    pal = Palette.from_markerset(MarkerSet.puppet())
    sc = random_bead_scene(pal.rgb, rng=2)
    vr = detect_beads(sc.image, pal)
    found = vr.identification.found
    assert found.sum() >= 14
    err = np.linalg.norm(vr.identification.points[found] - sc.centers[found], axis=1)
    assert np.all(err < 1.5)
    whole = detect_beads(sc.image, pal, roi=False)
    np.testing.assert_allclose(whole.identification.points, vr.identification.points, atol=1e-9)
    assert "template" in DETECTORS and set(IDENTIFIERS) == {"recommended", "thesis"}
    with pytest.raises(ValueError, match="unknown detector 'nope'"):
        detect_beads(sc.image, pal, detector="nope")


def test_bead_fill_views_is_bead_fill_of_each_view():
    rng = np.random.default_rng(2)
    scenes = [random_bead_scene(Palette.from_markerset(MarkerSet.puppet()).rgb, rng=s, size=size) for s, size in ((3, (480, 640)), (4, (300, 200)))]
    images = [scenes[0].image, scenes[1].image, scenes[0].image.mean(axis=2)]
    c = rng.uniform([-10, -10], [650, 490], (3, 20, 2))
    c[0, :10], c[1, :10] = scenes[0].centers[:10], scenes[1].centers[:10]
    c[rng.random((3, 20)) < 0.1] = np.nan
    r = rng.uniform(3.0, 8.0, (3, 20))
    got = bead_fill_views(images, c, r)
    for v in range(3):
        np.testing.assert_array_equal(got[v], bead_fill(images[v], c[v], r[v]))
    assert np.isfinite(got).sum() > 20
    with pytest.raises(ValueError, match=r"centers must have shape \(3, N, 2\), got \(2, 20, 2\)"):
        bead_fill_views(images, c[:2], r[:2])


def test_bead_fill_views_same_for_uint8_and_float_photos():
    """The uint8 colour path (channel sums in integers) and the float path give the same fills."""
    rng = np.random.default_rng(7)
    sc = random_bead_scene(Palette.from_markerset(MarkerSet.puppet()).rgb, rng=6)
    assert sc.image.dtype == np.uint8
    c = np.concatenate([sc.centers + rng.normal(0, 0.7, sc.centers.shape), rng.uniform(-5, 645, (10, 2))])
    r = rng.uniform(3.0, 8.0, len(c))
    got = bead_fill_views([sc.image, sc.image.astype(np.float64)], np.stack([c, c]), np.stack([r, r]))
    np.testing.assert_array_equal(got[0], got[1])
    np.testing.assert_array_equal(got[0], _fill_one_by_one(sc.image, c, r))
    assert np.isfinite(got).sum() > 30


def test_detect_beads_with_a_given_region_is_the_same():
    from stillcap.detect.beads import roi_box

    sc = random_bead_scene(Palette.from_markerset(MarkerSet.puppet()).rgb, rng=8)
    pal = Palette.from_markerset(MarkerSet.puppet())
    a = detect_beads(sc.image, pal)
    b = detect_beads(sc.image, pal, region=roi_box(sc.image))
    np.testing.assert_array_equal(a.circles.centers, b.circles.centers)
    np.testing.assert_array_equal(a.identification.points, b.identification.points)
    assert np.isfinite(a.identification.points).all(axis=1).sum() >= 10
    # a region that leaves out half the photo loses the beads there
    h, w = sc.image.shape[:2]
    c = detect_beads(sc.image, pal, region=(0, 0, w // 2, h))
    assert np.all(c.circles.centers[:, 0] < w // 2)


def test_bead_fill_of_a_photo_smaller_than_the_window_is_the_definition():
    """A colour photo smaller than the beads' common window (no window wholly inside it):
    every bead gathered from clipped pixel indices, the fills as bead by bead."""
    rng = np.random.default_rng(5)
    for h, w in ((12, 14), (30, 9)):
        img = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
        img[h // 3:2 * h // 3, w // 3:2 * w // 3] = 250
        c = np.array([[w / 2, h / 2], [1.0, 2.0], [w - 1.5, h - 0.5]])
        r = np.array([8.0, 3.0, 5.5])
        got = bead_fill_views([img], c[None], r[None])[0]
        assert np.isfinite(got).sum() >= 2
        np.testing.assert_array_equal(got, _fill_one_by_one(img, c, r))
