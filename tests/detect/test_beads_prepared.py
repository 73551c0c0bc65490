"""The bead detection split in two (photo-wide inputs made beforehand, candidates, then all
photos named together) and the faster bright region: the same results as detect_beads."""

import cv2
import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.detect.beads import (
    bright_region,
    detect_beads,
    find_bead_candidates,
    identify_views,
    prepare_view,
)
from stillcap.detect.palette import Palette
from stillcap.studio.beads import random_bead_scene

PAL = Palette.from_markerset(MarkerSet.puppet())


@pytest.fixture(scope="module")
def images():
    return [random_bead_scene(PAL.rgb, rng=s, n_beads=n).image for s, n in ((10, None), (11, 9), (12, None))]


@pytest.mark.parametrize("detector,identify,roi,coarse", [("template", "recommended", True, True),
                                                          ("template", "recommended", False, False),
                                                          ("template", "thesis", True, True),
                                                          ("thesis", "thesis", False, True)])
def test_prepared_and_split_detection_is_detect_beads(images, detector, identify, roi, coarse):
    whole = [detect_beads(im, PAL, detector, identify, roi=roi, coarse=coarse) for im in images]
    pre = [prepare_view(im, detector, (5.0, 7.0), roi, coarse) for im in images]
    assert all((p.region is not None) == roi and (p.template is not None) == (detector == "template") for p in pre)
    cands = [find_bead_candidates(im, detector, roi=roi, coarse=coarse, prepared=p) for im, p in zip(images, pre)]
    idents = identify_views(images, cands, PAL, identify)
    for w, c, i, im, p in zip(whole, cands, idents, images, pre):
        np.testing.assert_array_equal(w.circles.centers, c.centers)
        np.testing.assert_array_equal(w.circles.radii, c.radii)
        for f in ("points", "candidate", "cost", "colors", "gains"):
            np.testing.assert_array_equal(getattr(w.identification, f), getattr(i, f))
        d = detect_beads(im, PAL, detector, identify, roi=roi, coarse=coarse, prepared=p)
        np.testing.assert_array_equal(w.identification.points, d.identification.points)
    assert whole[0].identification.n_found >= 12


def test_prepared_view_must_fit(images):
    pre = prepare_view(images[0])
    with pytest.raises(ValueError, match=r"does not fit roi=False, detector='template'"):
        detect_beads(images[0], PAL, roi=False, prepared=pre)
    with pytest.raises(ValueError, match=r"does not fit roi=True, detector='thesis'"):
        detect_beads(images[0], PAL, "thesis", prepared=pre)
    with pytest.raises(ValueError, match="unknown identification 'x'"):
        identify_views(images, [], PAL, "x")


def _bright_region_plain(image, margin=13, contrast=15.0):
    """The definition: median grey of every 4th pixel, pixels brighter by ``contrast``, 3x3
    erosion, their bounding box grown by ``margin`` (the whole photo when none)."""
    g = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    h, w = g.shape
    mask = cv2.erode((g > float(np.median(g[::4, ::4])) + contrast).astype(np.uint8), np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return 0, 0, w, h
    return (max(0, xs.min() - margin), max(0, ys.min() - margin), min(w, xs.max() + 1 + margin),
            min(h, ys.max() + 1 + margin))


def test_bright_region_is_the_plain_definition(images):
    """Drawn photos, their grey version, noise photos with medians on half levels, a flat
    photo, tiny ones, several contrasts (fractional thresholds)."""
    rng = np.random.default_rng(1)
    cases = list(images) + [images[0][..., 1]]
    cases += [rng.integers(0, 256, (int(rng.integers(1, 40)), int(rng.integers(1, 40)), 3), dtype=np.uint8)
              for _ in range(40)]
    cases += [np.full((30, 20, 3), 200, np.uint8), np.zeros((1, 1, 3), np.uint8)]
    n_box = 0
    for im in cases:
        for contrast in (15.0, 0.0, 7.5, 40.25, 300.0):
            got = bright_region(im, contrast=contrast)
            assert got == _bright_region_plain(im, contrast=contrast)
            n_box += got != (0, 0, im.shape[1], im.shape[0])
    assert n_box > 20
