"""The pitch marker step: one epipolar matching over all the balls of a pair gives every ball's
own matching (markers pair only within their ball and type), so the observations are those of a
ball-by-ball matching."""

import json

import numpy as np
import pytest

from stillcap.ball.layout import BASEBALL_RADIUS, BallLayout
from stillcap.ball.orientation import MarkerObservations, rays_to_directions
from stillcap.geometry.epipolar import match_epipolar
from stillcap.geometry.triangulate import triangulate
from stillcap.ball.markers import pair_marker_observations
from stillcap.io.capture import Capture, stereo_pairs
from stillcap.pipelines.pitch import analyse_pitch

from support import studio_pitch


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """Each stereo pair of a studio fastball: cameras, photos and its PairResult."""
    root = studio_pitch(tmp_path_factory, "fastball")
    truth = json.loads((root / "truth.json").read_text())
    res = analyse_pitch(root, release_y_ft=truth["metrics"]["release_pos_y_ft"], n_samples=100)
    cap = Capture.load(root)
    specs, _ = stereo_pairs(cap)
    by_name = {p.name: p for p in res.pairs}
    return [([cap.rig[c] for c in sp.cameras], [cap.read_image(im) for im in sp.images], by_name[sp.name])
            for sp in specs]


def ball_by_ball(cam_a, cam_b, ma, mb, P, layout, radius_m, max_px):
    """Reference: every ball's markers matched on their own, triangulated, the rest as rays."""
    parts, n3, nray, epi = [], 0, 0, []
    for k in range(len(P)):
        A, B = ma.of_ball(k), mb.of_ball(k)
        m = match_epipolar(cam_a, cam_b, A.centers, B.centers, max_px=max_px,
                           labels_a=list(A.types), labels_b=list(B.types))
        ray_a, ray_b = list(m.unmatched_a), list(m.unmatched_b)
        if len(m.pairs):
            X = triangulate([cam_a, cam_b], np.stack([A.centers[m.pairs[:, 0]], B.centers[m.pairs[:, 1]]])).points
            v = X - P[k]
            r = np.linalg.norm(v, axis=1)
            ok = (r > 0.8 * radius_m) & (r < 1.15 * radius_m)
            if ok.any():
                parts.append(MarkerObservations.from_directions(np.full(ok.sum(), k), list(A.types[m.pairs[ok, 0]]),
                                                                v[ok] / r[ok, None], layout))
                n3 += ok.sum()
                epi += list(m.distance_px[ok])
            ray_a += list(m.pairs[~ok, 0])
            ray_b += list(m.pairs[~ok, 1])
        for M, cam, idx in ((A, cam_a, ray_a), (B, cam_b, ray_b)):
            if idx:
                o, d = cam.rays(M.centers[idx])
                ti = layout.type_index(list(M.types[idx]))
                # rays meet the sphere the type's image centroids lie on (BallLayout.centroid_depth)
                u, hit = rays_to_directions(o, d, np.repeat(P[k:k + 1], len(idx), axis=0),
                                            radius_m * (1.0 - layout.centroid_depth[ti]))
                parts.append(MarkerObservations(np.full(hit.sum(), k), ti[hit], u[hit], np.ones(hit.sum(), bool)))
                nray += hit.sum()
    return MarkerObservations.concatenate(parts), n3, nray, float(np.median(epi)) if epi else np.nan


@pytest.mark.parametrize("max_px", [2.0, 60.0])
def test_one_matching_over_all_balls_is_each_balls_own(pairs, max_px):
    """At the pipeline's 2 px, and at 60 px where markers of other balls are admissible by
    distance and wrong matches fail the sphere test (single-camera rays then)."""
    layout = BallLayout.seed()
    kinds = np.zeros(2, int)
    for cams, imgs, p in pairs:
        # the matching is the subject here: the triangulated directions the reference computes
        obs, (ma, mb), st = pair_marker_observations(cams[0], imgs[0], cams[1], imgs[1], p.centers_px[0],
                                                     p.centers_px[1], p.radius_px[0], p.radius_px[1], p.positions,
                                                     max_px=max_px, directions="triangulated")
        ref, n3, nray, epi = ball_by_ball(cams[0], cams[1], ma, mb, p.positions, layout, BASEBALL_RADIUS, max_px)
        # the default (rays met with the sphere, matched pairs combined) keeps the same observations
        rays, _, st_r = pair_marker_observations(cams[0], imgs[0], cams[1], imgs[1], p.centers_px[0],
                                                 p.centers_px[1], p.radius_px[0], p.radius_px[1], p.positions,
                                                 max_px=max_px)
        np.testing.assert_array_equal(rays.flash, obs.flash)
        np.testing.assert_array_equal(rays.types, obs.types)
        np.testing.assert_array_equal(rays.from_ray, obs.from_ray)
        assert rays.information is not None and obs.information is None
        single = rays.from_ray
        np.testing.assert_allclose(rays.directions[single], obs.directions[single], rtol=0, atol=1e-12)
        assert len(set(ref.flash)) > 1  # markers of several balls
        kinds += (n3, nray)
        assert (st["n_3d"], st["n_ray"]) == (n3, nray)
        np.testing.assert_array_equal(obs.flash, ref.flash)
        np.testing.assert_array_equal(obs.types, ref.types)
        np.testing.assert_array_equal(obs.from_ray, ref.from_ray)
        # the triangulation's Gauss-Newton stops when every point of its batch steps less than
        # 1e-10 m (geometry.triangulate._refine): a marker triangulated with its ball alone may
        # stop a step earlier than among all balls, its direction (a point ~0.035 m from the
        # centre) then off by up to 1e-10 / 0.035 ~ 3e-9 (seen: 5.8e-12 on one marker)
        np.testing.assert_allclose(obs.directions, ref.directions, rtol=0, atol=3e-9)
        assert st["epipolar_px"] == pytest.approx(epi, rel=1e-9)
    assert np.all(kinds > 0)  # stereo directions and single-camera rays both checked


def test_markers_pair_only_within_their_ball_and_rays_keep_each_balls_order(pairs, monkeypatch):
    """Made-up detections on a real pair's geometry. Ball 0's red marker seen by camera a only
    and ball 1's red marker seen by b only sit on one epipolar line (distance 0) and would
    triangulate onto ball 0's sphere: they must not pair. Ball 2's red markers pair but
    triangulate off the sphere (two rays), and its blue one is unmatched: its ray comes first."""
    import stillcap.ball.markers as markers
    from stillcap.detect.ball_markers import BallMarkers

    (cam_a, cam_b), _, p = pairs[0]
    P, r = p.positions[:3], BASEBALL_RADIUS
    to_a = (cam_a.center - P) / np.linalg.norm(cam_a.center - P, axis=1)[:, None]  # ball -> camera a
    x0 = P[0] + r * to_a[0]  # on ball 0, facing camera a
    x2 = P[2] + 3 * r * to_a[2]  # 3 radii off ball 2, towards camera a
    blue = P[2] + r * (to_a[2] + np.array([0.3, 0, 0])) / np.linalg.norm(to_a[2] + np.array([0.3, 0, 0]))
    det = {"a": (cam_a.project(np.array([x0, x2, blue])), ["red", "red", "blue"], [0, 2, 2]),
           "b": (cam_b.project(np.array([x0, x2])), ["red", "red"], [1, 2])}

    def fake_detect(img, centers, radii, types, **kw):
        xy, names, ball = det[img]
        n = len(names)
        return BallMarkers(xy, np.array(names, object), np.array(["unknown"] * n, object), np.full(n, 30.0),
                           np.ones(n), np.ones(n), np.array(ball), np.zeros(n, int))

    monkeypatch.setattr(markers, "detect_ball_markers", fake_detect)
    obs, (ma, mb), st = pair_marker_observations(cam_a, "a", cam_b, "b", None, None, None, None, P)
    layout = BallLayout.seed()
    ref, n3, nray, _ = ball_by_ball(cam_a, cam_b, ma, mb, P, layout, r, 2.0)
    assert st["n_3d"] == n3 == 0 and st["n_ray"] == nray and np.all(obs.from_ray)
    np.testing.assert_array_equal(obs.flash, ref.flash)
    np.testing.assert_array_equal(obs.types, ref.types)
    np.testing.assert_allclose(obs.directions, ref.directions, rtol=0, atol=1e-12)
    assert list(obs.flash[:1]) == [0] and list(layout.type_names[t] for t in obs.types[obs.flash == 2])[:1] == ["blue"]


def test_observations_carry_each_centroids_noise_read_from_its_photo(pairs):
    """Issue 12: every detected marker states its centroid's standard error from its own photo
    (BallMarkers.centroid_sigma_px), and the observations carry it (the pair's combination for
    a matched marker): finite for most, of the size a studio photo's centroid noise has."""
    n_obs, n_fin, sig = 0, 0, []
    for cams, imgs, p in pairs:
        obs, (ma, mb), _ = pair_marker_observations(cams[0], imgs[0], cams[1], imgs[1], p.centers_px[0],
                                                    p.centers_px[1], p.radius_px[0], p.radius_px[1], p.positions)
        assert obs.centroid_sigma_px is not None and obs.centroid_sigma_px.shape == (len(obs),)
        for m in (ma, mb):
            assert m.centroid_sigma_px.shape == (len(m),)
        fin = np.isfinite(obs.centroid_sigma_px)
        n_obs, n_fin = n_obs + len(obs), n_fin + int(fin.sum())
        sig += list(obs.centroid_sigma_px[fin])
    assert n_fin >= 0.7 * n_obs and n_fin >= 20, (n_fin, n_obs)
    # (a photo's 8-bit noise on a 5-10 px marker: hundredths to tenths of a pixel)
    assert 0.003 < np.median(sig) < 0.5 and np.all(np.asarray(sig) > 0)
