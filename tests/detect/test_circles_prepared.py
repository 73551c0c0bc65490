"""The template detector's photo-wide inputs made beforehand (prepare_template, find_circles's
``prepared``) and the window-view centre refinement: the same circles as the plain code."""

import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.detect.circles import (
    find_circles,
    grey_image,
    prepare_template,
    refine_bead_centers,
)
from stillcap.detect.palette import Palette
from stillcap.studio.beads import random_bead_scene

PAL = Palette.from_markerset(MarkerSet.puppet())


@pytest.fixture(scope="module")
def scenes():
    return [random_bead_scene(PAL.rgb, rng=s) for s in range(3)]


def _assert_same(a, b):
    np.testing.assert_array_equal(a.centers, b.centers)
    np.testing.assert_array_equal(a.radii, b.radii)
    np.testing.assert_array_equal(a.scores, b.scores)


def test_prepared_inputs_give_the_same_circles(scenes):
    """Whole photos, crops (odd sizes), grey and float photos, coarse or not, other radii."""
    found = []
    for sc in scenes:
        # (the last: a float photo in [0, 1], below the detector's contrast floor: no circles)
        for img in (sc.image, sc.image[13:402, 7:561], sc.image.mean(axis=2), sc.image.astype(np.float32) / 255):
            for coarse, rr in ((True, (5.0, 7.0)), (False, (5.0, 7.0)), (True, (4.0, 6.0))):
                pre = prepare_template(img, rr, coarse)
                a = find_circles(img, radius_range=rr, coarse=coarse)
                b = find_circles(img, radius_range=rr, coarse=coarse, prepared=pre)
                _assert_same(a, b)
                found.append(len(a))
    assert min(found[:9]) >= 10  # the first scene's uint8 photos and grey photo


def test_prepared_inputs_of_a_tiny_photo(scenes):
    """Under 8 px no half-resolution map is made; the full-resolution detector runs, as without."""
    img = scenes[0].image[100:106, 200:230]
    pre = prepare_template(img, (5.0, 7.0), True)
    assert pre.coarse_map is None
    _assert_same(find_circles(img, coarse=True), find_circles(img, coarse=True, prepared=pre))


def test_prepared_inputs_must_fit(scenes):
    img = scenes[0].image
    pre = prepare_template(img, (5.0, 7.0), True)
    with pytest.raises(ValueError, match=r"prepared inputs are for a \(480, 640\) photo"):
        find_circles(img[:300], prepared=pre)
    with pytest.raises(ValueError, match=r"radii \(5.0, 6.0, 7.0\)"):
        find_circles(img, radius_range=(4.0, 6.0), prepared=pre)
    with pytest.raises(ValueError, match="coarse map: False"):
        find_circles(img, coarse=True, prepared=prepare_template(img, (5.0, 7.0), False))
    with pytest.raises(ValueError, match="method='template' without boxes"):
        find_circles(img, method="blobs", prepared=pre)


def _refine_one_by_one(grey, centers, radii, iterations=3, background=None):
    """refine_bead_centers's definition, circle by circle with np.hypot: intensity-weighted centroid
    of the pixels within r + 1.5 (power-diagram split with neighbours closer than r_i + r_j + 3),
    weights grey minus the larger of the background and the median of the ring r + 1 .. r + 3.5
    (leaving out pixels within r_j + 1 of a neighbour); a move larger than r is undone."""
    g32 = np.asarray(grey, np.float32)
    g = g32.astype(float)
    h, w = g.shape
    c = np.array(centers, float)
    r = np.asarray(radii, float)
    bg = float(np.median(g)) if background is None else background
    ys, xs = np.mgrid[0:h, 0:w]
    for _ in range(iterations):
        new, moved = c.copy(), np.zeros(len(c))
        for i in range(len(c)):
            d = np.hypot(xs - c[i, 0], ys - c[i, 1])
            box = (np.abs(xs - c[i, 0]) <= r.max() + 4) & (np.abs(ys - c[i, 1]) <= r.max() + 4)
            inside = box & (d <= r[i] + 1.5)
            ring = box & (d > r[i] + 1.0) & (d <= r[i] + 3.5)
            for j in range(len(c)):
                if j != i and np.hypot(*(c[i] - c[j])) < r[i] + r[j] + 3.0:
                    dj = np.hypot(xs - c[j, 0], ys - c[j, 1])
                    inside &= d / r[i] <= dj / r[j]
                    ring &= dj > r[j] + 1.0
            # with a ring, the weights in the grey image's float32, as refine_bead_centers has them
            if ring.any():
                wgt = np.clip(g32 - np.maximum(np.float32(bg), np.median(g32[ring])), 0, None) * inside
            else:
                wgt = np.clip(g - bg, 0, None) * inside
            s = wgt.sum()
            if s > 0:
                p = np.array([(wgt * xs).sum() / s, (wgt * ys).sum() / s])
                moved[i] = np.hypot(*(p - c[i]))  # the stopping rule counts undone moves too
                if moved[i] <= r[i]:
                    new[i] = p
        c = new
        if moved.max(initial=0) < 1e-3:
            break
    return c


def test_refine_bead_centers_is_the_per_circle_definition(scenes):
    """Beads inside the photo, cut by its border (windows read through the replicated border)
    and touching each other: the per-circle centroids, to rounding."""
    sc = scenes[1]
    grey = grey_image(sc.image)
    rng = np.random.default_rng(4)
    c = np.concatenate([sc.centers + rng.normal(0, 0.8, sc.centers.shape),
                        [[2.3, 3.1], [637.6, 240.2], [320.4, 478.1], [5.5, 476.5]]])
    r = np.concatenate([sc.radii, [6.0, 5.0, 7.0, 6.5]])
    # a touching pair
    c = np.concatenate([c, [[100.0, 100.0], [111.5, 101.0]]])
    r = np.concatenate([r, [6.0, 6.0]])
    got = refine_bead_centers(grey, c, r)
    want = _refine_one_by_one(grey, c, r, background=float(np.median(grey)))
    # float32 sums in another order: ~3e-5 px apart; one pixel more or less in a mask moves a
    # centre by ~1e-3 px or more
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-4)
    assert np.median(np.hypot(*(got[:len(sc.centers)] - sc.centers).T)) < 0.2  # near the drawn centres
