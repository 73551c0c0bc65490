"""Triangulation covariance and the pixel noise from reprojection errors: against Monte Carlo
triangulation of noisy pixels on the hand studio's rig (its own cameras and distortion)."""

import numpy as np
import pytest

from stillcap.geometry.point_covariance import pixel_sigma_from_reprojection, triangulation_covariance
from stillcap.geometry.triangulate import triangulate
from stillcap.studio.hand import hand_rig


@pytest.fixture(scope="module")
def hrig():
    return hand_rig((1280, 960))


def _views(rig, pts, used):
    """Exact pixels of ``pts`` in the cameras ``used`` (bool (n_cams,)), NaN in the others."""
    px = np.full((len(rig), len(pts), 2), np.nan)
    for c, cam in enumerate(rig):
        if used[c]:
            px[c] = cam.project(pts)
    return px


@pytest.mark.parametrize("used", [(True, True, False, False), (False, True, True, False), (True, True, True, True)])
def test_covariance_matches_monte_carlo(hrig, used):
    """The predicted covariance of a point equals the spread of the points triangulated from
    pixels with that noise (2000 draws: the covariance's entries within ~6 % of its size)."""
    rig, used = hrig.rig, np.array(used)
    p = hrig.aim[None] + np.array([[0.05, -0.03, 0.02]])
    px = _views(rig, p, used)
    sigma = 0.4
    cov = triangulation_covariance(rig, px, p, sigma)[0]
    rng = np.random.default_rng(3)
    n = 2000
    noisy = np.repeat(px, n, axis=1) + rng.normal(0, sigma, (len(rig), n, 2))
    X = triangulate(rig, noisy).points
    emp = np.cov((X - p).T)
    scale = np.sqrt(np.trace(cov))
    assert np.abs(emp - cov).max() < 0.15 * scale ** 2
    w_emp, w_cov = np.linalg.eigvalsh(emp), np.linalg.eigvalsh(cov)
    assert np.allclose(np.sqrt(w_emp), np.sqrt(w_cov), rtol=0.08)


def test_one_pair_is_worse_along_its_depth(hrig):
    """Two cameras of one stereo pair fix the point less well along their mean viewing direction
    than across it; all four cameras fix it better than one pair."""
    rig = hrig.rig
    p = hrig.aim[None]
    pair = triangulation_covariance(rig, _views(rig, p, np.array([1, 1, 0, 0], bool)), p, 0.3)[0]
    both = triangulation_covariance(rig, _views(rig, p, np.ones(4, bool)), p, 0.3)[0]
    view = p[0] - 0.5 * (rig[0].center + rig[1].center)
    view /= np.linalg.norm(view)
    w, v = np.linalg.eigh(pair)
    assert abs(v[:, -1] @ view) > 0.9 and w[-1] > 4 * w[0]
    assert np.trace(both) < np.trace(pair)


def test_too_few_views_and_bad_input(hrig):
    rig = hrig.rig
    p = hrig.aim[None]
    cov = triangulation_covariance(rig, _views(rig, p, np.array([1, 0, 0, 0], bool)), p)
    assert np.isnan(cov).all()
    with pytest.raises(ValueError, match="sigma_px"):
        triangulation_covariance(rig, _views(rig, p, np.ones(4, bool)), p, 0.0)
    with pytest.raises(ValueError, match="pixels"):
        triangulation_covariance(rig, np.zeros((3, 1, 2)), p)


def test_pixel_sigma_from_reprojection(hrig):
    """Points triangulated from pixels of known noise give that noise back (within 6 %), for two-
    and four-view points alike."""
    rig = hrig.rig
    rng = np.random.default_rng(5)
    pts = hrig.aim[None] + rng.uniform(-0.2, 0.2, (600, 3))
    px = np.stack([cam.project(pts) for cam in rig])
    px[2:, :300] = np.nan  # half the points seen by the left pair only
    sigma = 0.35
    tri = triangulate(rig, px + rng.normal(0, sigma, px.shape))
    est = pixel_sigma_from_reprojection(tri.reproj_error_px, tri.n_views)
    assert est == pytest.approx(sigma, rel=0.06)
    assert np.isnan(pixel_sigma_from_reprojection([np.nan], [2]))
