"""solve_markers leaves out views that look whole but sit off the others' consensus by more than
the capture's own pixel noise (partly hidden beads the fill test passed, issue 12)."""
import numpy as np
import pytest

from stillcap.pipelines.puppet import DEFAULT, analyse_puppet_views
from stillcap.pipelines.puppet.stages import solve_markers
from stillcap.studio.puppet import puppet_scene


@pytest.fixture(scope="module")
def scene():
    return puppet_scene(pose="random:3", rng=3, supersample=1)


def test_a_view_off_centre_by_a_fraction_of_a_pixel_is_left_out_or_not_counted_whole(scene):
    res = analyse_puppet_views(scene.rig, scene.images)
    m = res.markers
    names = res.markerset.names
    x = m.observations.copy()
    base = solve_markers(res.rig, x, names, scene.images, DEFAULT, 0.003)
    s = base.noise_px
    assert 0 < s < 0.3  # pixels: sharp rendered beads
    w = base.used & base.whole
    # a marker with several whole views: one of them pushed 12 sigma (a few tenths of a pixel:
    # a sliver of limb over the bead) sideways is left out as partial, the point rests on the others
    k = int(np.argmax(w.sum(axis=0)))
    assert w[:, k].sum() >= 4
    v = int(np.flatnonzero(w[:, k])[0])
    x1 = x.copy()
    x1[v, k, 0] += 12 * s
    got = solve_markers(res.rig, x1, names, scene.images, DEFAULT, 0.003, noise_px=s)
    assert got.partial[v, k] and not got.used[v, k] and not got.whole[v, k]
    assert np.linalg.norm(got.points[k] - base.points[k]) < 0.02e-3
    # without the test (noise unknown) the view stays and pulls the point
    kept = solve_markers(res.rig, x1, names, scene.images, DEFAULT, 0.003, noise_px=float("nan"))
    assert kept.used[v, k] and np.linalg.norm(kept.points[k] - base.points[k]) > np.linalg.norm(
        got.points[k] - base.points[k])
    # a marker on exactly two whole views that disagree by 2 x 12 sigma: neither counts as whole,
    # so the marker is partly hidden (listed, never counted as a whole bead)
    two = x.copy()
    vs = np.flatnonzero(w[:, k])
    two[vs[2:], k] = np.nan
    two[vs[0], k, 1] += 12 * s
    two[vs[1], k, 1] -= 12 * s
    got2 = solve_markers(res.rig, two, names, scene.images, DEFAULT, 0.003, noise_px=s)
    assert got2.ok[k] and got2.partly_hidden[k]


@pytest.mark.parametrize("method", ["dlt", "midpoint"])
def test_arc_refitted_centres_are_the_ones_triangulated(scene, monkeypatch, method):
    """With ``arc_fit`` the partly hidden beads' views are refitted to their visible arc; the
    triangulation must use those centres, not the detected ones its stacked views (and view
    pairs' errors) were made from (issue 16: the DLT's stacked views kept the detected centres)."""
    from dataclasses import replace

    import stillcap.pipelines.puppet.stages as stages
    from stillcap.geometry.triangulate import triangulate_markers

    res = analyse_puppet_views(scene.rig, scene.images)
    x = res.markers.observations.copy()
    names = res.markerset.names
    k = int(np.argmax(np.isfinite(x[..., 0]).sum(axis=0)))
    v = int(np.flatnonzero(np.isfinite(x[:, k, 0]))[0])
    moved = x.copy()
    moved[v, k, 0] += 0.4  # px: within the consensus's 1 px, so the view stays and moves the point

    def arc_refit(images, x_, x_used, good, hidden, r_exp):  # every view hidden (black photos): refit one
        return np.where(np.isfinite(x_used), moved, x_used), np.zeros_like(hidden)

    monkeypatch.setattr(stages, "_arc_refit", arc_refit)
    black = [np.zeros_like(im) for im in scene.images]  # no view looks whole: all go to the arc fit
    opts = replace(DEFAULT, arc_fit=True, triangulation=method)
    got = solve_markers(res.rig, x, names, black, opts, 0.003)
    want = triangulate_markers(res.rig, moved, method, method == "dlt", opts.outlier_px)
    before = triangulate_markers(res.rig, x, method, method == "dlt", opts.outlier_px)
    assert got.used[v, k]
    np.testing.assert_allclose(got.points, want.points, rtol=0, atol=1e-12)
    assert np.linalg.norm(want.points[k] - before.points[k]) > 1e-6  # metres: the refit moved the point


def test_a_marker_the_final_triangulation_loses_keeps_the_refined_first_point():
    """The first triangulation (2 px consensus) gives the beads' depths from linear points; a
    marker whose views the final one (1 px) no longer accepts falls back on the first point
    refined, as a final point is: the Gauss-Newton one, not the linear one (~0.1 mm away)."""
    from stillcap.calibrate.turntable import turntable_rig
    from stillcap.geometry.triangulate import triangulate_markers

    rig = turntable_rig()
    rng = np.random.default_rng(0)
    clean = np.stack([c.project(np.array([[0.0, 0.0, 0.15], [0.01, 0.02, 0.12]])) for c in rig])
    blank = [np.zeros((480, 640, 3), np.uint8)] * len(rig)  # no fill: every view counts
    for _ in range(200):  # three views ~1.5 px apart: within the first consensus, not the final one
        x = clean.copy()
        x[3:] = np.nan
        x[:3, 0] += rng.normal(0, 1.5, (3, 2))
        if not np.all(np.isfinite(triangulate_markers(rig, x, "dlt", True, DEFAULT.outlier_px).points[0])):
            first = triangulate_markers(rig, x, "dlt", True, 2.0)
            if np.all(np.isfinite(first.points[0])):
                break
    else:
        pytest.fail("no marker the final triangulation loses")
    solve = solve_markers(rig, x, ["a", "b"], blank, DEFAULT)
    np.testing.assert_array_equal(solve.points[0], first.points[0])
    np.testing.assert_array_equal(solve.used[:, 0], first.used[:, 0])
    linear = triangulate_markers(rig, x, "dlt", False, 2.0).points[0]
    assert np.max(np.abs(linear - first.points[0])) > 1e-5
