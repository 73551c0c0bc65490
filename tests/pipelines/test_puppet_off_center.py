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
