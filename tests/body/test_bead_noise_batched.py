"""The bead noise's jackknife solved for all beads at once (``puppet_checks._bead_sd``) gives the
bead-by-bead loop's numbers (``_bead_sd_each``, the code it replaced on the puppet's hot path),
and falls back to that loop when a bead's equations are singular."""
import numpy as np
import pytest

from stillcap.body import puppet_checks as pc
from stillcap.calibrate.turntable import turntable_rig
from stillcap.geometry.triangulate import triangulate


def _scene(seed, n_views=12, n_beads=40):
    # beads seen by 2 to all of the views, one view of some beads well off (a partly hidden bead)
    rig = turntable_rig(n_views=n_views, step_deg=360.0 / n_views)
    rng = np.random.default_rng(seed)
    X = rng.uniform(-0.05, 0.05, (n_beads, 3)) + [0.0, 0.08, 0.0]
    x = np.stack([cam.project(X) for cam in rig]) + rng.normal(0, 0.2, (n_views, n_beads, 2))
    seen = rng.random((n_views, n_beads)) < rng.uniform(0.15, 1.0, n_beads)[None]
    seen[:2] = True
    x[3, ::5] += [1.5, -0.7]
    x[~seen] = np.nan
    tri = triangulate(rig, x)
    return rig, tri.points, x, seen


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_batched_jackknife_equals_the_bead_by_bead_loop(seed):
    rig, pts, x, seen = _scene(seed)
    exclude = np.zeros(len(pts), bool)
    exclude[::7] = True
    noise = pc.bead_noise(rig, pts, x, seen, exclude=exclude)
    n = seen.sum(axis=0)
    assert set(n) >= {2, 3} and n.max() >= 8  # two-view beads, three-view beads and many-view beads
    # the loop on the same Jacobians and residuals (rebuilt here as bead_noise builds them)
    use = seen & np.all(np.isfinite(pts), axis=1)[None]
    J = np.zeros((len(rig), len(pts), 2, 3))
    r = np.zeros((len(rig), len(pts), 2))
    for v, cam in enumerate(rig):
        sel = np.flatnonzero(use[v])
        r[v, sel] = x[v, sel] - cam.project(pts[sel])
        for a in range(3):
            d = np.zeros(3)
            d[a] = 1e-6
            J[v, sel, :, a] = (cam.project(pts[sel] + d) - cam.project(pts[sel] - d)) / 2e-6
    sq = np.sum(r ** 2, axis=(0, 2))
    beads = np.flatnonzero(n >= 2)
    sd, sd_dof = pc._bead_sd_each(J, r, use, sq, beads, noise.pixel_sd)
    np.testing.assert_allclose(noise.sd_m, sd, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(noise.sd_dof, sd_dof)
    assert np.all(np.isfinite(noise.sd_m[beads]))


def test_a_singular_bead_falls_back_to_the_loop_which_names_it_infinite():
    rig, pts, x, seen = _scene(3, n_beads=12)
    use = seen.copy()
    J = np.random.default_rng(0).normal(size=(len(rig), len(pts), 2, 3)) * use[..., None, None]
    r = np.random.default_rng(1).normal(size=(len(rig), len(pts), 2)) * use[..., None]
    J[:, 4] = 0.0  # bead 4's views fix nothing: its normal equations are singular
    sq = np.sum(r ** 2, axis=(0, 2))
    n = use.sum(axis=0)
    beads = np.flatnonzero(n >= 2)
    with pytest.raises(np.linalg.LinAlgError):
        pc._bead_sd(J, r, use, sq, n, beads, 0.3)
    sd, _ = pc._bead_sd_each(J, r, use, sq, beads, 0.3)
    assert sd[4] == np.inf
    others = beads[beads != 4]
    np.testing.assert_allclose(pc._bead_sd(J, r, use, sq, n, others, 0.3)[0][others], sd[others], rtol=1e-12)
