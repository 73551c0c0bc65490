"""Centres of partly hidden beads from the visible arc of their rim (stillcap.detect.bead_arc)."""

import numpy as np

from stillcap.detect.bead_arc import arc_centers, contour_radii


def _bead(center, r, size=64, occluder=None, occluder_grey=200.0, bg=40.0, bead=180.0):
    """A shaded bead (brighter middle, soft edge) on a dark background, optionally covered by a
    bar ``x >= occluder`` of another grey."""
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    d = np.hypot(xx - center[0], yy - center[1])
    inside = np.clip(r + 0.5 - d, 0.0, 1.0)  # about one pixel of anti-aliased edge
    shade = 1.0 - 0.3 * np.clip(d / r, 0, 1) ** 2
    img = bg + (bead * shade - bg) * inside
    if occluder is not None:
        img = np.where(xx >= occluder, occluder_grey, img)
    return img


def test_whole_bead_contour_radius_and_a_half_hidden_beads_center():
    c, r = np.array([31.3, 30.6]), 7.0
    whole = _bead(c, r)
    rc = contour_radii([whole], c[None, None], np.array([[r]]))[0, 0]
    assert abs(rc - r) < 0.6
    hidden = _bead(c, r, occluder=33.0)
    # the blob's centroid lies off towards the visible part
    yy, xx = np.mgrid[0:64, 0:64]
    blob = (hidden > 110) & (np.hypot(xx - c[0], yy - c[1]) <= r + 1) & (xx < 33)
    centroid = np.array([xx[blob].mean(), yy[blob].mean()])
    assert np.linalg.norm(centroid - c) > 1.5
    got = arc_centers([hidden], centroid[None, None], np.array([[rc]]))[0, 0]
    assert np.all(np.isfinite(got)) and np.linalg.norm(got - c) < 0.3


def test_an_occluder_as_dark_as_the_background_or_too_little_rim_gives_no_center():
    c, r = np.array([31.0, 31.0]), 7.0
    # most of the bead covered: too little rim left to place the circle
    img = _bead(c, r, occluder=27.0)
    got = arc_centers([img], np.array([[[25.0, 31.0]]]), np.array([[r]]))[0, 0]
    assert np.all(np.isnan(got))
    # a dark occluder's straight edge passes for rim, but the points lie on no circle of the radius
    img = _bead(c, r, occluder=33.0, occluder_grey=40.0)
    got = arc_centers([img], np.array([[[29.0, 31.0]]]), np.array([[r]]))[0, 0]
    assert np.all(np.isnan(got))
    # a bead on the photo's border or unseen: NaN, not an error
    got = arc_centers([img], np.array([[[2.0, 2.0], [np.nan, np.nan]]]), np.array([[r, r]]))[0]
    assert np.all(np.isnan(got))
