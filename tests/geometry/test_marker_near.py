"""Markers looked for where a model predicts them (stillcap.geometry.marker_near, issue 12): the
blobs near the prediction in every camera, one explanation or none."""

import numpy as np
import pytest

from stillcap.geometry.marker_near import triangulate_near
from stillcap.geometry.marker_points import (
    lit_sphere_centroids,
    triangulate_color_markers,
)
from stillcap.studio.hand import hand_rig


class Blobs:
    def __init__(self, centers, colors):
        self.centers, self.colors = np.asarray(centers, float).reshape(-1, 2), list(colors)


@pytest.fixture(scope="module")
def hrig():
    return hand_rig((1280, 960))


def blobs_of(hrig, points, colors, hide=()):
    """Blobs at the lit-sphere centroids in every camera; ``hide`` (camera, point) pairs unseen."""
    out = []
    for k, cam in enumerate(hrig.rig):
        px = lit_sphere_centroids(cam, points, 0.005, hrig.light.position)
        keep = [i for i in range(len(points)) if (k, i) not in hide]
        out.append(Blobs(px[keep], np.asarray(colors)[keep]))
    return out


def markers(hrig):
    rng = np.random.default_rng(3)
    return hrig.aim + rng.uniform(-0.15, 0.15, (6, 3)), np.array(["red", "yellow", "green", "blue", "red", "yellow"])


def test_each_prediction_gets_its_marker_from_all_views(hrig):
    X, col = markers(hrig)
    blobs = blobs_of(hrig, X, col)
    rng = np.random.default_rng(0)
    off = rng.normal(size=(len(X), 3))
    pred = X + 0.006 * off / np.linalg.norm(off, axis=1, keepdims=True)  # a model 6 mm off
    pts, idx = triangulate_near(hrig.rig, blobs, pred, col, 0.010, light_position=hrig.light.position)
    assert idx.tolist() == list(range(len(X)))
    assert np.all(pts.n_views == 4) and not pts.ambiguous.any()
    assert np.max(np.linalg.norm(pts.points - X, axis=1)) < 1e-5  # the half-lit bias removed


def test_two_views_are_enough_and_one_is_not(hrig):
    X, col = markers(hrig)
    hide = {(0, 0), (1, 0), (0, 1), (1, 1), (2, 1)}  # marker 0 in cameras 2-3 only, marker 1 in camera 3 only
    pts, idx = triangulate_near(hrig.rig, blobs_of(hrig, X, col, hide), X[:2], col[:2], 0.010,
                                light_position=hrig.light.position)
    assert idx.tolist() == [0] and pts.n_views.tolist() == [2]
    assert np.linalg.norm(pts.points[0] - X[0]) < 1e-5


def test_nothing_beyond_the_gate(hrig):
    X, col = markers(hrig)
    pts, idx = triangulate_near(hrig.rig, blobs_of(hrig, X, col), X[:1] + [0.015, 0, 0], col[:1], 0.010,
                                light_position=hrig.light.position)
    assert len(pts) == 0 and len(idx) == 0


def test_two_explanations_leave_the_prediction_without_a_point(hrig):
    """A second marker of the same colour 7 mm from the first, both within the gate: no point."""
    X, col = markers(hrig)
    X2 = np.concatenate([X, X[:1] + [0.0, 0.007, 0.0]])
    col2 = np.concatenate([col, col[:1]])
    pts, idx = triangulate_near(hrig.rig, blobs_of(hrig, X2, col2), X[:1], col[:1], 0.012,
                                light_position=hrig.light.position)
    assert len(pts) == 0 and len(idx) == 0
    # with the rival's blobs taken by another marker (used), the marker is found again
    used = [{len(X)} for _ in range(4)]
    pts, _ = triangulate_near(hrig.rig, blobs_of(hrig, X2, col2), X[:1], col[:1], 0.012, used=used,
                                light_position=hrig.light.position)
    assert len(pts) == 1 and np.linalg.norm(pts.points[0] - X[0]) < 1e-5


def test_other_colours_and_used_blobs_are_not_taken(hrig):
    X, col = markers(hrig)
    blobs = blobs_of(hrig, X, col)
    pts, _ = triangulate_near(hrig.rig, blobs, X[:1], ["blue"], 0.010, light_position=hrig.light.position)
    assert len(pts) == 0  # marker 0 is red
    pts, _ = triangulate_near(hrig.rig, blobs, X[:1], col[:1], 0.010, used=[{0}, {0}, {0}, set()],
                              light_position=hrig.light.position)
    assert len(pts) == 0  # three of its four blobs belong to other markers


def test_flux_ratios_normalised_with_the_reference(hrig):
    X, col = markers(hrig)
    blobs = blobs_of(hrig, X, col)
    for b, cam in zip(blobs, hrig.rig):
        b.flux = np.ones(len(b.centers))
    ref = triangulate_color_markers(hrig.rig, {"l": hrig.rig.names[:2], "r": hrig.rig.names[2:]}, blobs,
                                    light_position=hrig.light.position)
    pts, _ = triangulate_near(hrig.rig, blobs, X[:2], col[:2], 0.010, light_position=hrig.light.position,
                              reference=ref)
    assert pts.flux_ratio.shape == (4, 2) and np.isfinite(pts.flux_ratio).all()


def test_bad_input_is_named(hrig):
    X, col = markers(hrig)
    blobs = blobs_of(hrig, X, col)
    with pytest.raises(ValueError, match="predicted"):
        triangulate_near(hrig.rig, blobs, X[:, :2], col, 0.01)
    with pytest.raises(ValueError, match="colours"):
        triangulate_near(hrig.rig, blobs, X, col[:2], 0.01)
    with pytest.raises(ValueError, match="gate_m"):
        triangulate_near(hrig.rig, blobs, X, col, -0.01)
    with pytest.raises(ValueError, match="one entry per camera"):
        triangulate_near(hrig.rig, blobs[:2], X, col, 0.01)
