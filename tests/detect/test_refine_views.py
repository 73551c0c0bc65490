"""Several photos' bead centres refined together (refine_bead_centers_views,
refine_bead_candidates): each photo's centres exactly those it gets alone."""

import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.detect.beads import find_bead_candidates, prepare_view, refine_bead_candidates
from stillcap.detect.circles import find_circles, grey_image, refine_bead_centers, refine_bead_centers_views
from stillcap.detect.palette import Palette
from stillcap.studio.beads import random_bead_scene

PAL = Palette.from_markerset(MarkerSet.puppet())


@pytest.fixture(scope="module")
def scenes():
    return [random_bead_scene(PAL.rgb, rng=s, n_beads=n).image for s, n in ((20, None), (21, 9), (22, 16), (23, 5))]


def _cases(scenes):
    """Grey images with start centres and radii: the template's candidates, the same photo
    again with jittered starts (beads of two photos at the same places), starts on the border
    and outside the photo, radii giving other window sizes, a float64 and a uint8 BGR photo,
    a photo too small for a window, one without circles."""
    rng = np.random.default_rng(5)
    greys, centers, radii, bgs = [], [], [], []
    for k, im in enumerate(scenes):
        circ = find_circles(im, method="template", coarse=True, refine=False)
        g = grey_image(im)
        greys.append(g), centers.append(circ.centers), radii.append(circ.radii), bgs.append(float(np.median(g)))
        c = circ.centers + rng.normal(0, 1.5, circ.centers.shape)
        c[:3] = [[0.7, 3.2], [g.shape[1] - 1.2, g.shape[0] - 0.4], [-2.0, 40.0]]
        r = np.clip(circ.radii + rng.integers(-2, 3, len(circ)), 3, 10).astype(float)
        greys.append(g.astype(np.float64) if k == 1 else g), centers.append(c), radii.append(r), bgs.append(None)
    greys.append(scenes[0]), centers.append([[100.0, 100.0], [104.0, 101.0]]), radii.append([6.0, 6.0])
    bgs.append(12.5)
    greys.append(np.random.default_rng(1).random((6, 7)).astype(np.float32) * 80), centers.append([[3.0, 2.0]])
    radii.append([5.0]), bgs.append(None)
    greys.append(greys[0]), centers.append(np.zeros((0, 2))), radii.append(np.zeros(0)), bgs.append(3.0)
    return greys, centers, radii, bgs


@pytest.mark.parametrize("local_bg", [True, False])
@pytest.mark.parametrize("iterations", [1, 3, 6])
def test_views_together_are_each_view_alone(scenes, local_bg, iterations):
    greys, centers, radii, bgs = _cases(scenes)
    together = refine_bead_centers_views(greys, centers, radii, iterations, bgs, local_bg)
    assert len(together) == len(greys)
    n_moved, n_all = 0, sum(len(c) for c in centers)
    for g, c, r, b, got in zip(greys, centers, radii, bgs, together):
        alone = refine_bead_centers_views([g], [c], [r], iterations, [b], local_bg)[0]
        np.testing.assert_array_equal(got, alone)
        np.testing.assert_array_equal(got, refine_bead_centers(g, c, r, iterations, b, local_bg))
        assert got.shape == np.shape(c) if len(c) else got.shape == (0, 2)
        n_moved += int(np.sum(np.any(got != np.asarray(c, float).reshape(-1, 2), axis=1)))
    assert n_moved > n_all / 2  # the refinement did move the centres


def test_views_need_one_of_each_per_photo():
    with pytest.raises(ValueError, match=r"one centre array, radius array and background per grey image \(2\)"):
        refine_bead_centers_views([np.zeros((9, 9))] * 2, [np.zeros((0, 2))], [np.zeros(0)] * 2)
    with pytest.raises(ValueError, match=r"radii must have shape \(1,\)"):
        refine_bead_centers_views([np.zeros((9, 9))], [[[1.0, 2.0]]], [[1.0, 2.0]])


@pytest.mark.parametrize("roi", [True, False])
def test_candidates_refined_together_are_find_bead_candidates(scenes, roi):
    pre = [prepare_view(im, "template", (5.0, 7.0), roi, True) for im in scenes]
    whole = [find_bead_candidates(im, roi=roi, prepared=p) for im, p in zip(scenes, pre)]
    rough = [find_bead_candidates(im, roi=roi, prepared=p, refine=False) for im, p in zip(scenes, pre)]
    assert all(np.all(c.centers == np.round(c.centers)) for c in rough)  # the template: whole pixels
    assert any(np.any(w.centers != c.centers) for w, c in zip(whole, rough))
    for w, c in zip(whole, refine_bead_candidates(rough, pre)):
        for f in ("centers", "radii", "scores"):
            np.testing.assert_array_equal(getattr(w, f), getattr(c, f))
        assert (w.method, np.isnan(w.threshold)) == (c.method, np.isnan(c.threshold))


def test_candidates_need_template_inputs(scenes):
    pre = prepare_view(scenes[0], "thesis")
    cand = find_bead_candidates(scenes[0], "thesis", prepared=pre)
    with pytest.raises(ValueError, match="needs the template detector's prepared views"):
        refine_bead_candidates([cand], [pre])
    with pytest.raises(ValueError, match=r"one prepared view per photo's candidates \(1\), got 2"):
        refine_bead_candidates([cand], [pre, pre])
