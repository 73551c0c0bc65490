import cv2
import numpy as np
import pytest

from stillcap.detect.circles import find_circles
from stillcap.detect.identify import (
    RECOMMENDED,
    THESIS,
    Identification,
    calibrate_palette,
    greedy_match,
    identify_colors,
    identify_markers,
    optimal_match,
    sample_colors,
)
from stillcap.body.markerset import MarkerSet
from stillcap.detect.palette import Palette, color_distance, hsb_distance, rgb_to_hsb
from stillcap.studio.beads import draw_beads, random_bead_scene

PAL = Palette.from_markerset(MarkerSet.puppet())


def photo(canvas, rng=0, noise=3.0, quality=80):
    """Sensor noise and a JPEG round trip, like the webcam."""
    rng = np.random.default_rng(rng)
    img = np.clip(np.round(canvas * 255 + rng.normal(0, noise, canvas.shape)), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def score(ident, scene):
    """(right, wrong) identifications against a drawn scene's truth."""
    truth = np.full((len(PAL), 2), np.nan)
    truth[scene.labels] = scene.centers
    err = np.linalg.norm(ident.points - truth, axis=1)
    right = int(np.sum(ident.found & (err < 3)))
    return right, int(ident.n_found - right)


def test_greedy_and_optimal_match_on_the_classic_counterexample():
    # Greedy takes the cheapest pair (0, 0) first and is left with (1, 1) = 9; the optimum
    # pairs (0, 1) and (1, 0) for 2 + 2.
    cost = np.array([[1.0, 2.0], [2.0, 9.0]])
    r, c = greedy_match(cost, 10)
    assert sorted(zip(r.tolist(), c.tolist())) == [(0, 0), (1, 1)]
    r, c = optimal_match(cost, 10)
    assert sorted(zip(r.tolist(), c.tolist())) == [(0, 1), (1, 0)]
    # Rejection: with max 5 greedy keeps only (0, 0); the assignment still finds two pairs.
    assert len(greedy_match(cost, 5)[0]) == 1
    assert len(optimal_match(cost, 5)[0]) == 2
    # More matches beat a smaller total; NaN is impossible; nothing allowed -> nothing.
    r, c = optimal_match(np.array([[0.1, 4.0], [np.nan, 4.5]]), 5)
    assert sorted(zip(r.tolist(), c.tolist())) == [(0, 0), (1, 1)]
    assert len(optimal_match(np.full((3, 2), 7.0), 5)[0]) == 0
    assert len(optimal_match(np.zeros((0, 4)), 5)[0]) == 0
    # The default objective does not reshuffle a good pair into two poor ones just to make one
    # more pair (1 + 10 for the unmatched column < 9.5 + 9.5); "count" does.
    C = np.array([[1.0, 9.5], [9.5, np.nan]])
    assert list(zip(*optimal_match(C, 10))) == [(0, 0)]
    assert sorted(zip(*[a.tolist() for a in optimal_match(C, 10, objective="count")])) == [(0, 1), (1, 0)]


def test_greedy_errs_where_the_assignment_does_not():
    """Two greens 0.08 apart in hue, a warm white-balance shift moves both beads' hue up by
    0.05-0.07: the greedy first pick (bead a -> B, 0.03) steals B from bead b, which then takes
    A; the assignment (0.05 + 0.07 < 0.03 + 0.15) gets both right."""
    ref = Palette.from_hsb(["A", "B"], [[0.30, 0.6, 0.7], [0.38, 0.6, 0.7]])
    drawn = Palette.from_hsb(["a", "b"], [[0.35, 0.6, 0.7], [0.45, 0.6, 0.7]])
    c = np.array([[40.2, 30.7], [90.6, 52.1]])
    img = photo(draw_beads(c, [6, 6], drawn.rgb, size=(90, 130), background=0.04))
    circ = find_circles(img, n=2)
    greedy = identify_markers(img, circ, ref, **(THESIS | dict(max_distance=0.2)))
    assert greedy.n_found == 2
    assert np.allclose(greedy.points, c[::-1], atol=0.5)  # both wrong
    for kw in (dict(method="assignment", metric="hsb", sampler="patch", max_distance=0.2, adapt=False),
               RECOMMENDED):
        ident = identify_markers(img, circ, ref, **kw)
        assert np.allclose(ident.points, c, atol=0.5), kw
    # The same from colours alone.
    meas = drawn.rgb
    assert greedy_match(hsb_distance(rgb_to_hsb(meas), ref.hsb), 0.2)[1].tolist() == [1, 0]
    assert identify_colors(meas, ref, metric="hsb", max_distance=0.2).candidate.tolist() == [0, 1]


@pytest.fixture(scope="module")
def lit_scenes():
    """16 thesis colours, light +-20 %, white balance +-5 %, noise, JPEG; 10-16 beads seen."""
    rng = np.random.default_rng(5)
    return [random_bead_scene(PAL.rgb, rng=40 + s, n_beads=int(rng.integers(10, 17))) for s in range(5)]


def test_lighting_changes_greedy_hsb_vs_assignment(lit_scenes):
    tally = {"thesis": [0, 0], "assignment": [0, 0]}
    n = 0
    for sc in lit_scenes:
        n += len(sc.labels)
        th = identify_markers(sc.image, find_circles(sc.image, method="thesis"), PAL, **THESIS)
        best = identify_markers(sc.image, find_circles(sc.image), PAL)
        assert best.method == "assignment" and best.metric == "ciede2000" and best.sampler == "disc"
        for key, ident in (("thesis", th), ("assignment", best)):
            r, w = score(ident, sc)
            tally[key][0] += r
            tally[key][1] += w
    (r_th, w_th), (r_as, w_as) = tally["thesis"], tally["assignment"]
    assert r_as >= 0.95 * n and w_as <= 0.02 * n
    assert r_th < r_as and w_th > w_as


def test_calibration_recovers_drawn_colors():
    # "T-pose" photos in this studio's light (dimmer, bluish): the thesis's colours are off.
    wb = np.array([0.9, 1.0, 1.1]) * 0.85
    drawn = np.clip(PAL.rgb * wb, 0, 1)
    shots = [random_bead_scene(PAL.rgb * wb, rng=70 + s, brightness=(1, 1), white_balance=0, n_occluded=0)
             for s in range(3)]
    pts = [sc.centers.copy() for sc in shots]  # all 16 beads, in palette order
    pts[0][3] = np.nan  # a marker not seen in one photo
    cal = calibrate_palette([s.image for s in shots], pts, PAL)
    assert cal.n_samples.tolist() == [3, 3, 3, 2] + [3] * 12
    assert np.all(cal.spread < 3) and len(cal.samples[3]) == 2
    before = np.diag(color_distance(PAL.rgb, drawn))
    after = np.diag(color_distance(cal.palette.rgb, drawn))
    assert after.max() < 3.5 and after.mean() < 0.5 * before.mean()
    # From a first-pass identification instead of known positions, with the disc sampler.
    idn = identify_markers(shots[0].image, find_circles(shots[0].image), cal.palette)
    assert idn.n_found == 16 and np.allclose(idn.points, shots[0].centers, atol=0.5)
    cal2 = calibrate_palette([shots[0].image], [idn], PAL, sampler="disc")
    known = calibrate_palette([shots[0].image], [shots[0].centers], PAL, sampler="disc", radii=[shots[0].radii])
    d = np.diag(color_distance(cal2.palette.rgb, known.palette.rgb))  # detected radii are whole pixels
    assert d.max() < 3.5 and d.mean() < 1.2
    # Never seen: the old colour stays.
    none = calibrate_palette([shots[0].image], [np.full((16, 2), np.nan)], PAL)
    assert np.allclose(none.palette.rgb, PAL.rgb) and np.all(none.n_samples == 0)
    # The updated colours go back into a marker set.
    from stillcap.body.markerset import MarkerSet

    ms = cal.palette.apply_to(MarkerSet.puppet())
    assert np.allclose(ms.rgb, cal.palette.rgb, atol=1e-6)


def test_sampling_and_result_views():
    img = np.zeros((20, 30, 3), np.uint8)
    img[:, :] = (10, 20, 200)  # BGR red
    img[5:8, 5:8] = (200, 20, 10)
    col = sample_colors(img, [[15, 10], [6, 6], [np.nan, 1], [100, 100]])
    assert np.allclose(col[0], [200 / 255, 20 / 255, 10 / 255])  # RGB order out
    assert np.allclose(col[1], (16 * np.array([10, 20, 200]) + 9 * np.array([200, 20, 10]))[::-1] / 25 / 255)
    assert np.all(np.isnan(col[2:]))
    disc = sample_colors(img, [[15.3, 10.4]], [4.0], sampler="disc")
    assert np.allclose(disc[0], [200 / 255, 20 / 255, 10 / 255])
    pal = Palette.from_bgr8(["red", "blue"], [[10, 20, 200], [200, 20, 10]])
    img[4:11, 4:11] = (200, 20, 10)
    # Candidates: red, blue, red again (greedy: a reference is used once), off-image.
    cands = np.array([[15.0, 10.0], [7.0, 7.0], [25.0, 15.0], [-50.0, 3.0]])
    for method in ("greedy", "assignment"):
        ident = identify_markers(img, cands, pal, method=method, radii=[3.0] * 4)
        assert isinstance(ident, Identification)
        assert ident.as_dict() == {"red": (15.0, 10.0), "blue": (7.0, 7.0)}
        assert ident.labels() == ["red", "blue", None, None]
        assert ident.rejected.tolist() == [2, 3] and ident.candidate.tolist() == [0, 1]
        assert np.all(ident.distances < 1e-6) and np.all(ident.radii == 3.0)
    # Nothing found: NaN points, all candidates rejected.
    empty = identify_colors(np.zeros((0, 3)), pal)
    assert empty.n_found == 0 and np.all(np.isnan(empty.points))


def test_bad_input():
    with pytest.raises(ValueError, match=r"image must have shape \(H, W, 3\) \(BGR\), got \(4, 4\)"):
        sample_colors(np.zeros((4, 4)), [[1, 1]])
    with pytest.raises(ValueError, match=r"centers must have shape \(N, 2\), got \(2, 3\)"):
        sample_colors(np.zeros((4, 4, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="sampler must be one of"):
        sample_colors(np.zeros((4, 4, 3)), [[1, 1]], sampler="ring")
    with pytest.raises(ValueError, match="method must be 'greedy' or 'assignment'"):
        identify_colors([[0.5, 0.5, 0.5]], PAL, method="hungarian")
    with pytest.raises(ValueError, match="metric must be one of"):
        identify_colors([[0.5, 0.5, 0.5]], PAL, metric="rgb")
    with pytest.raises(ValueError, match="2 images but 1 point sets"):
        calibrate_palette([np.zeros((4, 4, 3))] * 2, [np.zeros((16, 2))], PAL)
    with pytest.raises(ValueError, match=r"points must have shape \(16, 2\), got \(3, 2\)"):
        calibrate_palette([np.zeros((4, 4, 3))], [np.zeros((3, 2))], PAL)


def test_disc_sampler_is_the_mean_of_each_disc():
    """The vectorised disc sampler gives each candidate the mean colour of exactly the pixels
    whose centres lie within 0.7 x its radius (written here pixel by pixel), NaN for NaN
    centres and discs wholly outside the photo, and clips at the borders."""
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    c = np.c_[rng.uniform(-3, 83, 40), rng.uniform(-3, 63, 40)]
    c[0] = np.nan
    c[1] = [-20.0, 30.0]  # far outside
    c[2] = [0.0, 0.0]  # corner
    r = rng.uniform(1.0, 8.0, 40)
    got = sample_colors(img, c, r, sampler="disc")
    ys, xs = np.mgrid[0:60, 0:80]
    for i, ((x, y), ri) in enumerate(zip(c, r)):
        R = max(0.7 * ri, 0.75)
        sel = (xs - x) ** 2 + (ys - y) ** 2 <= R * R if np.isfinite(x) else np.zeros(xs.shape, bool)
        if not sel.any():
            assert np.all(np.isnan(got[i])), i
        else:
            np.testing.assert_allclose(got[i], img[sel].mean(axis=0)[::-1] / 255.0, atol=1e-12)


@pytest.mark.parametrize("metric", ["ciede2000", "lab", "hsb"])
def test_costs_are_color_distance(metric):
    """The cost matrix (references converted to Lab once) is color_distance's, NaN for NaN rows."""
    pal = Palette.from_markerset(MarkerSet.puppet())
    rng = np.random.default_rng(3)
    col = np.clip(pal.rgb[rng.permutation(len(pal))[:12]] + rng.normal(0, 0.05, (12, 3)), 0, 1)
    col[4] = np.nan
    res = identify_colors(col, pal, metric=metric, lightness_weight=0.7, adapt=False)
    want = np.full((12, len(pal)), np.nan)
    ok = np.isfinite(col).all(axis=1)
    want[ok] = color_distance(col[ok], pal.rgb, metric, 0.7)
    np.testing.assert_array_equal(res.cost, want)
    assert (res.candidate >= 0).sum() >= 8
