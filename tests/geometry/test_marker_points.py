"""Lit-sphere centroid offsets and coloured-marker triangulation: synthetic rigs (exact) and the
studio's hand captures (detection + triangulation against the truth)."""

import json

import numpy as np
import pytest

from stillcap.body.hand import HAND_COLORS
from stillcap.detect.color_markers import find_color_markers
from stillcap.geometry.marker_points import (MarkerPoints, lit_sphere_centroids, lit_sphere_offsets,
                                             triangulate_color_markers)
from stillcap.studio.hand import hand_capture, hand_rig, lit_centroids

COLORS = np.array(["red", "yellow", "green", "blue"])


class Blobs:
    """Minimal blobs: centers and colours (what the triangulation needs)."""

    def __init__(self, centers, colors):
        self.centers, self.colors = np.asarray(centers, float), list(colors)


@pytest.fixture(scope="module")
def rig():
    return hand_rig((1280, 960))


def lit_observations(hrig, points, colors, rng, drop=0.0):
    """Blobs at the lit-sphere centroids of ``points`` in every camera (shuffled), a share
    ``drop`` of them hidden."""
    out = []
    for cam in hrig.rig:
        px = lit_sphere_centroids(cam, points, 0.005, hrig.light.position)
        keep = rng.random(len(points)) >= drop
        order = rng.permutation(np.flatnonzero(keep))
        out.append(Blobs(px[order], colors[order]))
    return out


def hand_cloud(hrig, n, rng):
    """``n`` markers of 4 colours in the hand's working volume, at least 12 mm apart."""
    pts = []
    while len(pts) < n:
        p = hrig.aim + rng.uniform([-0.35, -0.3, -0.35], [0.35, 0.3, 0.35])
        if all(np.linalg.norm(p - q) > 0.012 for q in pts):
            pts.append(p)
    return np.array(pts), COLORS[rng.integers(0, 4, n)]


def test_offsets_match_the_studio_model(rig):
    """The studio's lit centroids (no occluders) are this model; the offset points toward the
    light's side and is below the sphere's image radius."""
    rng = np.random.default_rng(1)
    pts, _ = hand_cloud(rig, 20, rng)
    for cam in rig.rig:
        a = lit_sphere_centroids(cam, pts, 0.005, rig.light.position)
        assert np.array_equal(a, lit_centroids(cam, pts, 0.005, rig.light.position))
        off = lit_sphere_offsets(cam, pts, 0.005, rig.light.position, n_samples=1200)
        rho = cam.K[0, 0] * 0.005 / cam.world_to_cam(pts)[:, 2]
        assert np.all(np.linalg.norm(off, axis=1) < rho) and np.median(np.linalg.norm(off, axis=1)) > 0.5
        # toward the light: the offset has a positive component along the direction from the
        # projected centre to the image of the lit pole
        pole = cam.project(pts + 0.005 * (rig.light.position - pts) / np.linalg.norm(rig.light.position - pts,
                                                                                        axis=1)[:, None])
        assert np.all(np.einsum("na,na->n", off, pole - cam.project(pts)) > 0)


def test_light_at_the_camera_gives_no_offset(rig):
    cam = rig.rig[0]
    pts = rig.aim + np.array([[0.0, 0.0, 0.0], [0.1, -0.05, 0.2]])
    off = lit_sphere_offsets(cam, pts, 0.005, cam.center, n_samples=1200)
    assert np.abs(off).max() < 0.01  # only the lens distortion's asymmetry


def test_exact_recovery_with_bias_correction(rig):
    """Blobs at the lit centroids: corrected points are exact, raw ones off by millimetres."""
    rng = np.random.default_rng(2)
    pts, cols = hand_cloud(rig, 40, rng)
    blobs = lit_observations(rig, pts, cols, rng)
    mp = triangulate_color_markers(rig.rig, rig.pairs, blobs, light_position=rig.light.position)
    raw = triangulate_color_markers(rig.rig, rig.pairs, blobs)
    for res, bound in ((mp, 2e-5), (raw, None)):
        d = np.linalg.norm(res.points[:, None] - pts[None], axis=2)
        d = np.where(res.colors[:, None] == cols[None], d, np.inf).min(axis=1)
        if bound is None:
            assert np.median(d) > 1e-3  # the half-lit bias: ~2.5 mm toward the strobe
        else:
            assert len(res) >= 38 and d.max() < bound  # a couple of points may lose a pair
            assert np.all(res.reprojection_px < 0.01)
    assert mp.bias_corrected and not raw.bias_corrected
    assert set(mp.pairs) <= {"left", "right", "left+right"} and np.any(mp.pairs == "left+right")
    assert np.all(mp.n_views >= 2) and mp.pixels.shape == (4, len(mp), 2)
    for k in range(4):  # pixels are the blobs used
        used = mp.blob_index[k] >= 0
        assert np.array_equal(mp.pixels[k, used], blobs[k].centers[mp.blob_index[k, used]])
        assert np.all(np.isnan(mp.pixels[k, ~used]))


def hand_clusters(hrig, rng, n_hands=5):
    """18 markers of 4 colours within 12 cm per hand, ``n_hands`` hands along a path: the
    multi-exposure photo's 4-5 copies of every colour."""
    pts = []
    for c in hrig.aim + np.linspace(-1, 1, n_hands)[:, None] * np.array([0.25, 0.1, 0.2]):
        k = 0
        while k < 18:
            p = c + rng.uniform(-0.06, 0.06, 3)
            if all(np.linalg.norm(p - q) > 0.012 for q in pts):
                pts.append(p)
                k += 1
    return np.array(pts), COLORS[rng.integers(0, 4, len(pts))]


def test_ambiguities_resolved_by_the_other_pair(rig):
    """Same-colour markers of the other flashes on the epipolar line: the other pair's views
    pick the right one; a pair alone (no third view) makes wrong matches. Over seeds 3-12:
    1 wrong point with both pairs, 26 with each pair alone."""
    rng = np.random.default_rng(4)
    pts, cols = hand_clusters(rig, rng)
    blobs = lit_observations(rig, pts, cols, rng, drop=0.15)
    kw = dict(light_position=rig.light.position)

    def wrong(res):
        d = np.linalg.norm(res.points[:, None] - pts[None], axis=2)
        return int(np.sum(np.where(res.colors[:, None] == cols[None], d, np.inf).min(axis=1) > 0.003))

    both = triangulate_color_markers(rig.rig, rig.pairs, blobs, **kw)
    n_alone = 0
    for p, ab in rig.pairs.items():
        own = [b if c.name in ab else Blobs(np.zeros((0, 2)), []) for c, b in zip(rig.rig, blobs)]
        n_alone += wrong(triangulate_color_markers(rig.rig, {p: ab}, own, **kw))
    assert n_alone >= 3  # measured: 5
    assert wrong(both) == 0
    assert len(both) >= 75  # measured: 81 of 90 (15 % of the blobs hidden)


def test_to_dict_and_empty(rig):
    rng = np.random.default_rng(4)
    pts, cols = hand_cloud(rig, 8, rng)
    mp = triangulate_color_markers(rig.rig, rig.pairs, lit_observations(rig, pts, cols, rng, drop=0.3),
                                    light_position=rig.light.position)
    d = json.loads(json.dumps(mp.to_dict()))
    assert len(d["points"]) == len(mp) and len(d["pixels"]) == 4 and d["cameras"] == rig.rig.names
    assert all(isinstance(v, int) for row in d["blob_index"] for v in row)
    empty = triangulate_color_markers(rig.rig, rig.pairs, [Blobs(np.zeros((0, 2)), [])] * 4)
    assert isinstance(empty, MarkerPoints) and len(empty) == 0 and empty.pixels.shape == (4, 0, 2)
    sub = mp.select(mp.n_views >= 3)
    assert np.all(sub.n_views >= 3) and sub.pixels.shape[1] == len(sub)


def test_bad_input(rig):
    b = [Blobs(np.zeros((0, 2)), [])] * 4
    with pytest.raises(ValueError, match="one entry per camera"):
        triangulate_color_markers(rig.rig, rig.pairs, b[:3])
    with pytest.raises(ValueError, match="pair 'x' must name two different cameras"):
        triangulate_color_markers(rig.rig, {"x": ("left_outer", "nope")}, b)
    with pytest.raises(ValueError, match=r"centers must have shape \(N, 2\), got \(3, 3\)"):
        triangulate_color_markers(rig.rig, rig.pairs, [Blobs(np.zeros((3, 3)), "rgb")] + b[1:])
    with pytest.raises(ValueError, match="3 centers but 2 colours"):
        triangulate_color_markers(rig.rig, rig.pairs, [Blobs(np.zeros((3, 2)), "rg")] + b[1:])
    with pytest.raises(ValueError, match=r"light_position must have shape \(3,\)"):
        triangulate_color_markers(rig.rig, rig.pairs, b, light_position=[1, 2])
    with pytest.raises(ValueError, match="unknown cameras"):
        triangulate_color_markers(rig.rig, rig.pairs, {"cam9": b[0]})
    with pytest.raises(ValueError, match="rig must be a Rig"):
        triangulate_color_markers(list(rig.rig), rig.pairs, b)
    with pytest.raises(ValueError, match=r"centres must have shape \(N, 3\)"):
        lit_sphere_offsets(rig.rig[0], [[1.0, 2.0]], 0.005, rig.light.position)


# --- the studio: detection and triangulation against the truth ----------------------------
@pytest.fixture(scope="module")
def studio():
    hc = hand_capture(1, image_size=(1280, 960), supersample=2)
    rig, tr = hc.rig.rig, hc.truth
    blobs = []
    for cam, img in zip(rig, hc.images):
        c = tr.ball2world[:, :3, 3]
        r = cam.K[0, 0] * tr.ball["radius"] / cam.world_to_cam(c)[:, 2] + 2.0
        blobs.append(find_color_markers(img, HAND_COLORS, exclude=(cam.project(c), r)))
    return hc, blobs


def errors_mm(mp, truth):
    """Per point: distance to the nearest truth marker of its colour (mm) and that marker."""
    T = truth.markers.reshape(-1, 3)
    tc = np.tile(np.array(truth.marker_colors), len(truth.markers))
    d = np.where(mp.colors[:, None] == tc[None], np.linalg.norm(mp.points[:, None] - T[None], axis=2), np.inf)
    return d.min(axis=1) * 1000, d.argmin(axis=1)


def test_studio_markers_in_3d(studio):
    hc, blobs = studio
    tr, rig = hc.truth, hc.rig.rig
    mp = triangulate_color_markers(rig, hc.rig.pairs, blobs, light_position=hc.rig.light.position)
    raw = triangulate_color_markers(rig, hc.rig.pairs, blobs)
    err, nearest = errors_mm(mp, tr)
    err_raw, nearest_raw = errors_mm(raw, tr)
    # every marker isolated and wholly seen by both cameras of a pair comes back within 1 mm
    clean = (tr.markers_isolated & (tr.markers_coverage > 0.999)).reshape(4, -1)
    need = np.zeros(clean.shape[1], bool)
    for a, b in hc.rig.pairs.values():
        need |= clean[rig.names.index(a)] & clean[rig.names.index(b)]
    best, best_raw = np.full(len(need), np.inf), np.full(len(need), np.inf)
    np.minimum.at(best, nearest, err)
    np.minimum.at(best_raw, nearest_raw, err_raw)
    assert need.sum() >= 10  # measured: 14
    assert best[need].max() < 1.0  # measured: 0.4 mm
    assert np.median(best_raw[need]) > 1.5  # uncorrected: ~2.5 mm toward the strobe
    # wrong points (> 3 mm from every marker of their colour): few, and flagged as partly hidden
    wrong = err > 3.0
    assert wrong.sum() <= 4  # measured: 2 here, 1-2 per capture on seeds 0-3 (docs/hand-markers.md)
    assert np.all(mp.partly_hidden[wrong])
    # the points not flagged partly hidden are sub-millimetre
    good = ~mp.partly_hidden & ~wrong
    assert good.sum() >= 40 and np.sqrt(np.mean(err[good] ** 2)) < 0.4  # measured: 0.16 mm
    assert np.all(mp.reprojection_px[good] < 1.0)
    # most markers seen by 2+ cameras are found
    vis2 = (tr.markers_visible.sum(axis=0) >= 2).ravel()
    assert np.mean(best[vis2] <= 3.0) > 0.75  # measured: 66 of 77


def test_coincidental_confirmation_cannot_steal_a_match(rig):
    """Issue 12: a wrong match of one pair "confirmed" by a blob in the other pair's camera that
    belongs to another marker (which that pair triangulates itself) must not win over the right
    match: the confirmation is found coincidental and the pair is assigned again."""
    cams = list(rig.rig)
    c0, c1, c2 = (c.center for c in cams[:3])
    m1 = rig.aim.copy()
    u = (c0 - m1) / np.linalg.norm(c0 - m1) + (c1 - m1) / np.linalg.norm(c1 - m1)
    m2 = m1 + 0.05 * u / np.linalg.norm(u)  # in m1's epipolar plane of the left pair: both cross matches admissible
    n = np.cross(c0 - m1, c1 - m1)
    m2 = m2 + 0.0004 * n / np.linalg.norm(n)  # a little off it: the right matches are the closer ones
    x0, x1 = cams[0].project(np.array([m1, m2])), cams[1].project(np.array([m1, m2]))
    from stillcap.geometry.triangulate import triangulate

    w = triangulate([cams[0], cams[1]], np.array([[x0[0]], [x1[1]]])).points[0]  # the wrong match's point
    m3 = c2 + 1.25 * (w - c2)  # another marker on camera 2's ray through the wrong point
    px = {k: [] for k in range(4)}
    for k in (0, 1):
        px[k] += [cams[k].project(m1[None])[0], cams[k].project(m2[None])[0]]
    for k in (0, 2, 3):  # m3: seen by the right pair and one camera of the left pair
        px[k].append(cams[k].project(m3[None])[0])
    blobs = [Blobs(np.array(px[k]), ["red"] * len(px[k])) for k in range(4)]
    res = triangulate_color_markers(rig.rig, rig.pairs, blobs)
    truth = np.array([m1, m2, m3])
    d = np.linalg.norm(res.points[:, None] - truth[None], axis=2).min(axis=0)
    assert np.all(d < 0.002), d * 1000  # all three markers, none lost to the coincidental blob


def test_marker_seen_by_one_camera_of_each_pair(rig):
    """Issue 12: a marker that one camera of each stereo pair sees (the other two hidden) was never
    triangulated: every two cameras now propose matches (one strobe lights them all)."""
    rng = np.random.default_rng(7)
    pts, cols = hand_cloud(rig, 12, rng)
    blobs = lit_observations(rig, pts, cols, rng)
    lonely = np.array([rig.aim + [0.02, 0.01, 0.03]])
    for k, cam in enumerate(rig.rig):
        if k in (0, 2):  # left_outer and right_inner alone
            px = lit_sphere_centroids(cam, lonely, 0.005, rig.light.position)
            blobs[k] = Blobs(np.vstack([blobs[k].centers, px]), list(blobs[k].colors) + ["red"])
    res = triangulate_color_markers(rig.rig, rig.pairs, blobs, light_position=rig.light.position)
    d = np.linalg.norm(res.points - lonely, axis=1)
    i = int(np.argmin(d))
    assert d[i] < 1e-4 and res.colors[i] == "red" and res.n_views[i] == 2
    assert res.pairs[i] == "cross"  # no stereo pair saw it alone
    assert len(res) == 13


def test_wrong_match_cannot_take_a_blob_another_marker_explains(rig):
    """Issue 12 (studio person 5): in the right pair, marker m2's blob in one camera lies on the
    epipolar line of marker m1's blob in the other (m1: the left pair and that camera; m2: the right
    pair alone), closer than m2's own, slightly noisy blob. Matching each pair on its own took the
    wrong match and lost m2; the set packing explains every blob at once and keeps both."""
    cams = list(rig.rig)
    c2, c3 = cams[2].center, cams[3].center
    m2 = rig.aim + np.array([0.03, -0.02, 0.01])
    n = np.cross(c2 - m2, c3 - m2)
    n /= np.linalg.norm(n)
    along = (m2 - c3) / np.linalg.norm(m2 - c3)
    # in m2's epipolar plane of the right pair: m1's camera-2 blob lies on m2's camera-3 epipolar line
    m1 = m2 + 0.04 * along + 0.02 * np.cross(n, along)
    px = {k: [] for k in range(4)}
    for k in (0, 1, 2):
        px[k].append(cams[k].project(m1[None])[0])
    for k in (2, 3):
        p = cams[k].project(m2[None])[0]
        if k == 2:  # m2's own blob a little off its epipolar line (centroid noise)
            line = cams[2].project((m2 + 0.01 * n)[None])[0] - p
            p = p + 0.6 * line / np.linalg.norm(line)
        px[k].append(p)
    blobs = [Blobs(np.array(px[k]), ["red"] * len(px[k])) for k in range(4)]
    res = triangulate_color_markers(rig.rig, rig.pairs, blobs)
    truth = np.array([m1, m2])
    d = np.linalg.norm(res.points[:, None] - truth[None], axis=2).min(axis=0)
    assert np.all(d < 0.003), d * 1000


class FluxBlobs(Blobs):
    """Blobs with their light (``flux``), as ``find_color_markers`` measures it."""

    def __init__(self, centers, colors, flux):
        super().__init__(centers, colors)
        self.flux = np.asarray(flux, float)


def _model_flux(cam, points, light):
    from stillcap.geometry.marker_points import lit_sphere_samples

    _, w = lit_sphere_samples(cam, points, 0.005, light, 300)
    return w.sum(axis=1) * (cam.K[0, 0] / cam.world_to_cam(points)[:, 2]) ** 2


@pytest.mark.parametrize("share", [1.0, 0.3])
def test_partly_hidden_views_cannot_make_a_cross_pair_point(rig, share):
    """Issue 12 (another_hand(6), tests/test_cli_hand_files.py): two slivers of hidden markers,
    one in a camera of each pair, met on the long cross-pair epipolar line and took a wrong label.
    A two-view point across the pairs whose blobs hold ``share`` of a whole marker's light: a
    whole one (1.0) is a marker, a partly hidden one (0.3; centroid unreliable, nothing else can
    confirm it) is not triangulated."""
    rng = np.random.default_rng(11)
    pts, _ = hand_cloud(rig, 16, rng)
    cols = np.array(["red", "green"] * 8)
    light = rig.light.position
    lonely = rig.aim + np.array([0.02, 0.01, 0.03])
    blobs = []
    for k, cam in enumerate(rig.rig):
        c = lit_sphere_centroids(cam, pts, 0.005, light)
        f = _model_flux(cam, pts, light)
        names = list(cols)
        if k in (0, 2):  # one camera of each pair
            c = np.vstack([c, lit_sphere_centroids(cam, lonely[None], 0.005, light)])
            f = np.append(f, share * _model_flux(cam, lonely[None], light))
            names.append("red")
        blobs.append(FluxBlobs(c, names, f))
    res = triangulate_color_markers(rig.rig, rig.pairs, blobs, light_position=light)
    d = np.linalg.norm(res.points - lonely, axis=1)
    assert (d.min() < 1e-4) == (share == 1.0), d.min() * 1000
    assert len(res) == 16 + (share == 1.0)
    assert np.all(np.linalg.norm(res.points[:, None] - pts[None], axis=2).min(axis=0) < 1e-4)


@pytest.mark.parametrize("extra_light", [1.65, 1.0])
def test_blob_with_another_markers_light_does_not_outvote_whole_views(rig, extra_light):
    """Studio hand 1 (issue 12, part 4): a marker seen whole by the left inner and right inner
    cameras; in the right outer camera its lit side is hidden, and the blob of another marker of
    its colour lies on the right pair's epipolar line 3 px off (1.65 times the light the
    model predicts at the marker). The three views agree only pairwise: by chance the right pair's
    wrong match fitted best and won the consensus, the point 6.7 mm off and not flagged. A blob
    that is no whole marker's image (flux ratio outside 0.9 to 1/0.9) no longer votes while two
    whole views remain. With the stray blob as bright as a whole marker nothing tells the two
    pairs apart, and the right pair's closer fit still wins: that case stays as it was."""
    rng = np.random.default_rng(5)
    pts, _ = hand_cloud(rig, 16, rng)
    cols = np.array(["red", "green"] * 8)
    light = rig.light.position
    cams = list(rig.rig)
    m = rig.aim + np.array([0.01, -0.02, 0.02])
    seen_px = {k: lit_sphere_centroids(cams[k], m[None], 0.005, light)[0] for k in (1, 2)}
    # the left inner blob a little off (centroid noise): the right pair's wrong match fits better
    seen_px[1] = seen_px[1] + np.array([0.0, 0.25])
    # the stray blob in the right outer camera: on the epipolar line of the camera-2 blob, 3 px away
    near = lit_sphere_centroids(cams[3], m[None], 0.005, light)[0]
    ray = [cams[2].center + s * (m - cams[2].center) / np.linalg.norm(m - cams[2].center) for s in (0.9, 1.1)]
    a, b = cams[3].project(np.array(ray))
    along = (b - a) / np.linalg.norm(b - a)
    stray = near + 3.0 * along
    blobs = []
    for k, cam in enumerate(cams):
        c = lit_sphere_centroids(cam, pts, 0.005, light)
        f = _model_flux(cam, pts, light)
        names = list(cols)
        if k in (1, 2):
            c, f = np.vstack([c, seen_px[k]]), np.append(f, _model_flux(cam, m[None], light))
            names.append("red")
        if k == 3:
            c, f = np.vstack([c, stray]), np.append(f, extra_light * _model_flux(cam, m[None], light))
            names.append("red")
        blobs.append(FluxBlobs(c, names, f))
    res = triangulate_color_markers(rig.rig, rig.pairs, blobs, light_position=light)
    old = triangulate_color_markers(rig.rig, rig.pairs, blobs, light_position=light, min_flux_ratio=None)
    d, d_old = (np.linalg.norm(r.points - m, axis=1).min() for r in (res, old))
    assert d_old > 0.002, d_old * 1000  # without the light the wrong pair wins (the mechanism)
    i = int(np.argmin(np.linalg.norm(res.points - m, axis=1)))
    if extra_light != 1.0:
        assert d < 0.0005 and res.n_views[i] == 2 and res.blob_index[3, i] == -1, (d * 1000, res.blob_index[:, i])
    else:
        assert d > 0.002, d * 1000
    assert np.all(np.linalg.norm(res.points[:, None] - pts[None], axis=2).min(axis=0) < 1e-4)
