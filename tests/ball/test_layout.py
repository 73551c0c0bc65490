"""The seed's 12-marker ball layout (SPEC J1 "Ball markers", seed section 4.1)."""

import numpy as np
import pytest

from stillcap.ball.layout import (BASEBALL_RADIUS, DEFAULT_PALETTE, BallLayout, check_layout,
                                  fibonacci_sphere, seed_layout, sphere_direction)


def _az_pol(d):
    return (round(float(np.degrees(np.arctan2(d[1], d[0]))) % 360),
            round(float(np.degrees(np.arccos(np.clip(d[2], -1, 1))))))


def test_seed_geometry_types_and_names():
    lay = BallLayout.seed()
    assert len(lay) == 12 and lay.directions.shape == (12, 3)
    assert np.allclose(np.linalg.norm(lay.directions, axis=1), 1.0)
    assert lay.type_names == ("red", "blue", "green", "black")
    assert lay.type_shapes == ("square", "ring", "triangle", "disc")
    assert np.bincount(lay.types).tolist() == [3, 3, 3, 3]
    pos = [_az_pol(d) for d in lay.directions]
    eq = sorted(a for a, p in pos if p == 90)
    assert eq == [0, 30, 90, 120, 180, 210, 270, 300]
    off = sorted((a, p) for a, p in pos if p != 90)
    assert off == [(60, 30), (60, 150), (240, 30), (240, 150)]
    # the four off-equator markers lie on one great circle orthogonal to the equator
    n = np.cross(lay.directions[8], lay.directions[10])
    assert np.allclose(lay.directions[8:] @ n, 0, atol=1e-12) and abs(n[2]) < 1e-12
    assert lay.names[0] == "black.0" and len(set(lay.names)) == 12
    assert all(name.split(".")[0] == lay.type_names[t] for name, t in zip(lay.names, lay.types))
    assert lay.radius == pytest.approx(0.0737 / 2) == BASEBALL_RADIUS
    assert lay.shapes[0] == "disc" and lay.colors.shape == (12, 3)


def test_palette_is_configurable():
    lay = seed_layout(palette={"blue": (0.1, 0.5, 1.0)})
    assert lay.palette["blue"] == (0.1, 0.5, 1.0)
    assert lay.palette["red"] == DEFAULT_PALETTE["red"]
    lay2 = BallLayout.seed().with_palette({"green": [0.2, 1.0, 0.2]})
    assert np.allclose(lay2.colors[lay2.types == 2], [0.2, 1.0, 0.2])
    assert np.array_equal(lay2.directions, BallLayout.seed().directions)


def test_type_index_accepts_names_and_indices():
    lay = BallLayout.seed()
    assert lay.type_index(["red", 3, "green"]).tolist() == [0, 3, 2]
    assert lay.type_index("black") == 3
    with pytest.raises(ValueError, match="unknown marker type 'purple'"):
        lay.type_index(["purple"])
    with pytest.raises(ValueError, match="0..3"):
        lay.type_index([4])


def test_three_types_on_every_hemisphere_and_frame_always_determinable():
    """The seed's claims, verified by sampling 3000 view directions."""
    chk = check_layout(BallLayout.seed(), margin_deg=0.0, n_views=3000)
    assert chk.min_types >= 3
    assert chk.n_ambiguous == 0 and not chk.symmetric
    for margin in (10.0, 15.0):  # markers near the limb not counted
        chk = check_layout(BallLayout.seed(), margin_deg=margin, n_views=3000)
        assert chk.n_ambiguous == 0, margin
        assert chk.min_separation_deg > 14.0  # a wrong frame misses a marker by > 14 deg
        assert chk.share_3_types > 0.9


def test_views_with_two_types_still_fix_the_frame():
    """With a margin, looking along a pole only the two markers 30 deg from it are inside the
    limb (the equator is on it): no assignment shows 3 types there. Those views, and the
    few others with 2 types, still determine the frame."""
    lay = BallLayout.seed()
    chk = check_layout(lay, margin_deg=10.0, n_views=3000)
    few = chk.n_types < 3
    assert 0 < few.mean() < 0.04
    assert np.all(chk.separation_deg[few] > 14.0)
    for pole in ([0, 0, 1], [0, 0, -1]):
        vis = lay.visible(pole, 10.0)
        assert vis.sum() == 2
        assert lay.separation_deg(vis) > 10.0


def test_studio_draft_assignment_was_ambiguous():
    """Why the layout changed: the studio's earlier draft (same positions) lets a wrong
    rotation explain all visible markers from some views once the limb is excluded."""
    lay = BallLayout.seed()
    draft = [0, 1, 2, 0, 3, 2, 0, 2, 3, 1, 1, 3]
    old = BallLayout(lay.directions, draft)
    assert check_layout(old, 0.0, 2000).min_types == 4
    assert check_layout(old, 10.0, 2000).n_ambiguous > 0
    assert check_layout(lay, 10.0, 2000).n_ambiguous == 0


def test_symmetric_layout_is_detected():
    d = sphere_direction([0, 90, 180, 270], [90, 90, 90, 90])
    chk = check_layout(BallLayout(d, [0, 1, 0, 1], type_names=("a", "b"), type_shapes=("disc", "ring"),
                                  palette={"a": (1, 0, 0), "b": (0, 0, 1)}), 0.0, 200)
    assert chk.symmetric and chk.n_ambiguous == 200


def test_visible_and_fibonacci():
    lay = BallLayout.seed()
    v = lay.visible([1.0, 0.0, 0.0])
    assert v.shape == (12,) and v[0] and not v[4]
    assert lay.visible(fibonacci_sphere(7), 5.0).shape == (7, 12)
    f = fibonacci_sphere(500)
    assert np.allclose(np.linalg.norm(f, axis=1), 1) and abs(f.mean(0)).max() < 0.01


def test_bad_input_names_the_shape():
    with pytest.raises(ValueError, match=r"directions must have shape \(n, 3\).*\(12, 2\)"):
        BallLayout(np.ones((12, 2)), np.zeros(12, int))
    with pytest.raises(ValueError, match=r"types must have shape \(12,\), got \(11,\)"):
        BallLayout(BallLayout.seed().directions, np.zeros(11, int))
    with pytest.raises(ValueError, match="palette has no colour"):
        BallLayout(BallLayout.seed().directions, BallLayout.seed().types, palette={"red": (1, 0, 0)})
    with pytest.raises(ValueError, match=r"palette\['red'\] must have shape \(3,\), got \(2,\)"):
        BallLayout.seed(palette={"red": (1, 0)})
    with pytest.raises(ValueError, match="marker_size"):
        BallLayout.seed(marker_size=2.0)
    with pytest.raises(ValueError, match=r"view_dirs must have shape \(3,\) or \(V, 3\), got \(2,\)"):
        BallLayout.seed().visible([1.0, 0.0])
    with pytest.raises(ValueError, match=r"visible must have shape \(12,\)"):
        BallLayout.seed().separation_deg(np.ones(5, bool))


def test_centroid_depth_is_where_the_studio_markers_image_centroids_lie():
    """A marker's projected-area-weighted image centroid (shapes as the studio paints them) is the
    image of (1 - k) r u: k = centroid_depth to first order, far from k = 0 (the surface point)."""
    from stillcap.studio.renderer import _marker_material
    from stillcap.studio.scene import Sphere, SphereMarker

    layout = BallLayout.seed()
    k = layout.centroid_depth
    assert k.shape == (4,) and np.all(k > 0)
    # equal-area samples of the cap within 0.4 rad of +z (uniform in z and in azimuth)
    z = np.linspace(np.cos(0.4), 1.0, 700)
    phi = np.linspace(0.0, 2 * np.pi, 1440, endpoint=False)
    Z, PHI = np.meshgrid(z, phi)
    s = np.sqrt(1 - Z ** 2)
    n = np.stack([s * np.cos(PHI), s * np.sin(PHI), Z], axis=-1).reshape(-1, 3)
    for t, shape in enumerate(layout.type_shapes):
        body = Sphere(1.0, markers=[SphereMarker([0.0, 0.0, 1.0], shape, layout.marker_size, angle=0.3)])
        inside = _marker_material(body, n) > 0
        for alpha in np.radians([20.0, 45.0, 65.0]):
            view = np.array([np.sin(alpha), 0.0, np.cos(alpha)])  # towards the camera
            radial = np.array([-np.cos(alpha), 0.0, np.sin(alpha)])  # image direction of +z
            w = np.clip(n[inside] @ view, 0.0, None)  # projected area of each sample
            ratio = (w @ (n[inside] @ radial)) / w.sum() / np.sin(alpha)
            assert abs((1 - ratio) - k[t]) < 0.03 * k[t], (shape, np.degrees(alpha), 1 - ratio, k[t])
    # a shape neither the detector nor the centroid model knows is refused when the layout is made
    with pytest.raises(ValueError, match=r"unknown marker shapes \['star'\]"):
        BallLayout(layout.directions, layout.types, type_shapes=("square", "ring", "triangle", "star"))
