"""The hand's poses fitted again over all flashes (:mod:`stillcap.body.hand_refine`): each marker
weighed by its own covariance, and the acceleration prior estimated from the capture. Checked on
the studio hand's true markers with noise of a known, anisotropic covariance."""

from functools import lru_cache

import numpy as np
import pytest

from stillcap.body.hand import fit_hand, hand_markerset, hand_skeleton
from stillcap.body.hand_refine import acceleration_sigma, model_misfit, refine_hand_sequence
from stillcap.body.hand_track import HandSequence, observed_dofs
from stillcap.studio.hand import hand_capture

SEEDS = (0, 2, 5)


@lru_cache(maxsize=None)
def truth(seed):
    return hand_capture(seed, image_size=(320, 240), supersample=1).truth


def seen_markers(seed):
    """The markers 2+ cameras see in each flash, the back of the hand always (every flash has a
    pose to start from)."""
    tr = truth(seed)
    seen = np.asarray(tr.markers_visible).sum(axis=0) >= 2
    seen[:, :3] = True
    return seen


def noisy(seed, depth_m, across_m):
    """Each flash's markers of :func:`seen_markers`, with noise of ``depth_m`` along one random
    direction per marker and ``across_m`` across it; returns (positions, covariances)."""
    tr = truth(seed)
    rng = np.random.default_rng(seed)
    seen = seen_markers(seed)
    n, m = seen.shape
    u = rng.normal(size=(n, m, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    cov = across_m ** 2 * np.eye(3) + (depth_m ** 2 - across_m ** 2) * np.einsum("nmi,nmj->nmij", u, u)
    L = np.linalg.cholesky(cov)
    pts = tr.markers + np.einsum("nmij,nmj->nmi", L, rng.normal(size=(n, m, 3)))
    pts[~seen] = np.nan
    return pts, cov


def per_flash(seed, pts):
    """The per-flash fit (isotropic, each flash from the previous one), as a HandSequence."""
    tr = truth(seed)
    sk, ms = hand_skeleton(), hand_markerset()
    fits, prev = [], None
    for p in pts:
        f = fit_hand(sk, ms, p, initial=prev)
        fits.append(f)
        prev = f.pose
    n = len(pts)
    return HandSequence(sk, ms, np.arange(n), np.asarray(tr.times) - tr.times[0], [f.pose for f in fits],
                        np.stack([sk.limit_angles_deg(f.pose.local_rotations) for f in fits]),
                        np.stack([f.residuals for f in fits]), np.array([f.rms for f in fits]),
                        np.array([f.n_markers for f in fits]), np.array([f.success for f in fits]),
                        {g: 1.0 for g in ("palm", "thumb", "index", "middle", "ring", "little")})


def rms_error(seq, seed):
    tr = truth(seed)
    e = [seq.angles_deg[k, j, a] - tr.angles_deg[k, j, a] for k in range(seq.n) for j, a in observed_dofs(seq, k)]
    return np.asarray(e)


def test_exact_markers_stay_exact():
    tr = truth(SEEDS[0])
    pts = np.where(seen_markers(SEEDS[0])[..., None], tr.markers, np.nan)
    cov = np.broadcast_to(np.eye(3) * 1e-12, pts.shape + (3,)).copy()  # 1 micrometre
    r = refine_hand_sequence(per_flash(SEEDS[0], pts), pts, cov)
    e = rms_error(r.sequence, SEEDS[0])
    assert len(e) > 40 and np.abs(e).max() < 0.1
    assert r.success and np.all(r.sequence.rms < 1e-5)


def test_covariance_weighting_beats_round_weights():
    """Markers fixed 10x worse along one direction (1.5 mm) than across it (0.15 mm): the fit that
    knows each marker's covariance gives smaller joint-angle errors than the per-flash fit that
    weighs every direction alike (measured 3.50 -> 1.43 deg RMS over these seeds). With the model's
    misfit estimated from the residuals (the default) part of the gain goes: five flashes per
    marker make a noisy estimate, and a noisy positive part adds a round error that is not
    there (measured 3.50 -> 2.25)."""
    iso, known, misfit = [], [], []
    for s in SEEDS:
        pts, cov = noisy(s, 0.0015, 0.00015)
        seq = per_flash(s, pts)
        iso.append(rms_error(seq, s))
        none = np.zeros(pts.shape[:2], bool)
        known.append(rms_error(refine_hand_sequence(seq, pts, cov, smooth=False, misfit_from=none).sequence, s))
        misfit.append(rms_error(refine_hand_sequence(seq, pts, cov, smooth=False).sequence, s))
    a, b, c = (np.sqrt(np.mean(np.concatenate(v) ** 2)) for v in (iso, known, misfit))
    assert b < 0.6 * a, (a, b)
    assert c < 0.7 * a, (a, c)


def test_round_noise_gives_the_per_flash_fit():
    """With every marker's covariance the same round ball (and no misfit term, which would weigh
    the markers apart), the refit (no smoothing) is the per-flash fit again."""
    s = SEEDS[1]
    pts, _ = noisy(s, 0.0003, 0.0003)
    cov = np.broadcast_to(np.eye(3) * 0.0003 ** 2, pts.shape + (3,)).copy()
    seq = per_flash(s, pts)
    r = refine_hand_sequence(seq, pts, cov, smooth=False, misfit_from=np.zeros(pts.shape[:2], bool))
    obs = [np.array([seq.angles_deg[k, j, a] - r.sequence.angles_deg[k, j, a] for j, a in observed_dofs(seq, k)])
           for k in range(seq.n)]
    assert np.abs(np.concatenate(obs)).max() < 0.05


def test_acceleration_sigma_from_the_measured_motion():
    t = np.arange(9) / 75.0
    rng = np.random.default_rng(0)
    sig = np.full((9, 2), 0.5)
    obs = np.ones((9, 2), bool)
    # dof 0: still, noise only -> the floor (one second difference's noise); dof 1: a large
    # constant acceleration -> about it
    acc = 50000.0  # 8.9 per flash step against a noise of 1.2 in a second difference
    ang = np.stack([rng.normal(0, 0.5, 9), 0.5 * acc * t ** 2 + rng.normal(0, 0.5, 9)], axis=1)
    s = acceleration_sigma(ang, sig, t, obs)
    floor = 0.5 * np.sqrt(6) * 75.0 ** 2
    assert s[0] == pytest.approx(floor, rel=1e-9)
    assert s[1] == pytest.approx(acc, rel=0.2)
    # a degree of freedom never fixed in three consecutive flashes gets no prior
    obs[1::2, 1] = False
    assert np.isinf(acceleration_sigma(ang, sig, t, obs)[1])


def test_bad_input():
    pts, cov = noisy(SEEDS[0], 0.0003, 0.0003)
    seq = per_flash(SEEDS[0], pts)
    with pytest.raises(ValueError, match="point_cov"):
        refine_hand_sequence(seq, pts, cov[:, :3])
    with pytest.raises(ValueError, match="no labelled marker"):
        refine_hand_sequence(seq, pts, np.full_like(cov, np.nan))


def test_model_misfit_by_moments():
    """Residuals of a known extra round error (0.5 mm per axis) over a triangulation covariance of
    trace 3 (0.1 mm)^2, each with half its error absorbed by the fit (leverage 0.5): the extra
    comes back; a marker whose residuals are within its covariance gets none."""
    rng = np.random.default_rng(1)
    n = 4000
    tr = np.full((n, 2), 3 * 0.0001 ** 2)
    lev = np.full((n, 2), 0.5)
    var = np.array([0.0001 ** 2 + 0.0005 ** 2, 0.0001 ** 2])
    r2 = 0.5 * np.sum(rng.normal(0, np.sqrt(var)[None, :, None], (n, 2, 3)) ** 2, axis=2)
    s2 = model_misfit(r2, tr, lev, np.ones((n, 2), bool))
    assert np.sqrt(s2[0]) == pytest.approx(0.0005, rel=0.03)
    assert s2[1] < (0.00003) ** 2


def test_the_model_misfit_is_weighed_in():
    """A hand model whose markers sit 1 mm off (each along its own direction, the same in every
    flash) on well-triangulated markers (0.1 mm): the refit that adds each marker's measured
    misfit to its covariance is no worse than the per-flash fit's round weights, where weighing
    by the triangulation alone would trust the wrong places 100x too much."""
    s = SEEDS[2]
    tr = truth(s)
    rng = np.random.default_rng(7)
    shift = rng.normal(size=(18, 3))
    shift *= 0.001 / np.linalg.norm(shift, axis=1, keepdims=True)
    seen = seen_markers(s)
    pts = tr.markers + shift[None] + rng.normal(0, 0.0001, tr.markers.shape)
    pts[~seen] = np.nan
    cov = np.broadcast_to(np.eye(3) * 0.0001 ** 2, pts.shape + (3,)).copy()
    seq = per_flash(s, pts)
    base = np.sqrt(np.mean(rms_error(seq, s) ** 2))
    r = refine_hand_sequence(seq, pts, cov, smooth=False)
    assert np.sqrt(np.mean(rms_error(r.sequence, s) ** 2)) <= 1.05 * base
