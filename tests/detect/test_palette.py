import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.detect.palette import (
    Palette,
    color_distance,
    hsb_distance,
    propose_palette,
    rgb_to_hsb,
    rgb_to_lab,
)


def test_thesis_palette_matches_the_marker_set():
    ms = MarkerSet.puppet()
    pal = Palette.from_markerset(MarkerSet.puppet())
    assert pal.names == ms.names and len(pal) == 16
    assert np.allclose(pal.rgb, ms.rgb) and np.allclose(pal.hsb, ms.hsb, atol=1e-6)
    assert pal.hex[0] == "#9ec0c0"  # head.1, HSB (0.499, 0.176, 0.754)
    assert pal.bgr8.dtype == np.uint8 and np.array_equal(pal.bgr8[0], [192, 192, 158])
    assert np.allclose(Palette.from_bgr8(pal.names, pal.bgr8).rgb, pal.rgb, atol=0.5 / 255 + 1e-9)
    assert Palette.from_hsb(pal.names, pal.hsb).rgb == pytest.approx(pal.rgb)
    d = pal.to_dict()["colors"][3]
    assert d["name"] == "torso.2" and d["hsb"] == [0.187, 0.633, 0.706]


def test_hue_is_periodic_and_distances_have_shapes():
    d = hsb_distance([[0.999, 0.5, 0.5]], [[0.001, 0.5, 0.5], [0.5, 0.5, 0.5]])
    assert d.shape == (1, 2) and d[0, 0] == pytest.approx(0.002) and d[0, 1] == pytest.approx(0.499)
    a = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.5, 0.5, 0.5]])
    for metric in ("hsb", "lab", "ciede2000"):
        D = color_distance(a, a[:2], metric)
        assert D.shape == (3, 2) and np.allclose(np.diag(D[:2]), 0, atol=1e-9)
    # A darker version of a colour: far in full Lab, nearer with lightness down-weighted.
    dim = np.array([[0.5, 0.0, 0.0]])
    assert color_distance(dim, a[:1], "lab", 0.25)[0, 0] < color_distance(dim, a[:1], "lab")[0, 0]
    assert color_distance(dim, a[:1], "ciede2000", 0.5)[0, 0] < color_distance(dim, a[:1], "ciede2000")[0, 0]
    assert rgb_to_lab(a[:1])[0, 0] == pytest.approx(53.24, abs=0.01)  # sRGB red, D65
    assert rgb_to_hsb(np.zeros((0, 3))).shape == (0, 3)


def test_min_distance_and_apply_to_markerset():
    pal = Palette.from_markerset(MarkerSet.puppet())
    d, pair = pal.min_distance("ciede2000")
    assert pair == ("arm.R1", "leg.R3") and 4 < d < 6
    assert pal.min_distance("hsb")[1] == ("torso.2", "arm.R3")
    new = pal.with_colors(np.full((16, 3), 0.5))
    ms = new.apply_to(MarkerSet.puppet())
    assert isinstance(ms, MarkerSet) and np.allclose(ms.rgb, 0.5)
    assert ms.names == MarkerSet.puppet().names


def test_proposed_palette_is_more_distinct_than_the_thesis_colors():
    thesis, _ = Palette.from_markerset(MarkerSet.puppet()).min_distance("ciede2000")
    prop = propose_palette(16, rng=0, restarts=3)
    pal = prop.palette
    assert len(pal) == 16 and pal.names[0] == "c00"
    assert prop.min_distance == pytest.approx(pal.min_distance("ciede2000")[0])
    assert prop.min_distance > 3 * thesis and prop.min_distance > 18
    hsb = pal.hsb
    assert np.all(hsb[:, 1] >= 0.45 - 1e-9) and np.all(hsb[:, 2] >= 0.6 - 1e-9)
    assert np.all(rgb_to_lab(pal.rgb)[:, 0] >= 40 - 1e-9)
    # Far from the black background and the dark grey limbs.
    assert prop.min_distance_to_excluded >= prop.min_distance
    # Reproducible with the same rng; names and hex for a paint shop.
    again = propose_palette(16, rng=0, restarts=3)
    assert again.palette.hex == pal.hex and all(h.startswith("#") and len(h) == 7 for h in pal.hex)
    few = propose_palette(4, rng=1, restarts=2, names=["a", "b", "c", "d"], lightness_weight=0.5, metric="lab")
    assert few.palette.names == ("a", "b", "c", "d") and few.metric == "lab" and few.min_distance > 60


def test_bad_input():
    with pytest.raises(ValueError, match=r"rgb must have shape \(2, 3\), got \(2, 4\)"):
        Palette(["a", "b"], np.zeros((2, 4)))
    with pytest.raises(ValueError, match="unique"):
        Palette(["a", "a"], np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"lie in \[0, 1\]"):
        Palette(["a"], [[0, 0, 2.0]])
    with pytest.raises(ValueError, match="metric must be one of"):
        color_distance([[0, 0, 0]], [[1, 1, 1]], "rgb")
    with pytest.raises(ValueError, match=r"a_rgb must have shape \(N, 3\), got \(3,\)"):
        color_distance([0, 0, 0], [[1, 1, 1]])
    with pytest.raises(ValueError, match="positive integer"):
        propose_palette(0)
    with pytest.raises(ValueError, match="3 names for 2 colours"):
        propose_palette(2, names=["a", "b", "c"])
    with pytest.raises(ValueError, match="unknown colour"):
        Palette.from_markerset(MarkerSet.puppet()).index("nose")


def test_ciede2000_pairwise_is_scikit_images_bit_for_bit():
    """The hand-written pairwise CIEDE2000 (fast on small matrices) gives scikit-image's numbers,
    including greys (chroma 0), hue differences across 0/360 degrees and a lightness factor."""
    from skimage.color import deltaE_ciede2000

    from stillcap.detect.palette import ciede2000_pairwise

    rng = np.random.default_rng(7)
    a = rgb_to_lab(rng.random((23, 3)))
    b = rgb_to_lab(rng.random((16, 3)))
    a[:4, 1:] = 0.0  # greys
    b[:3, 1:] = 0.0
    a[4:8, 2] = np.abs(a[4:8, 2]) + 1.0  # hues just above and below 0 degrees
    b[3:7, 2] = -np.abs(b[3:7, 2]) - 1.0
    a[4:8, 1] = b[3:7, 1] = 30.0
    for kL in (1.0, 2.0, 0.7):
        want = deltaE_ciede2000(np.broadcast_to(a[:, None], (23, 16, 3)), np.broadcast_to(b[None], (23, 16, 3)),
                                kL=kL)
        got = ciede2000_pairwise(a, b, kL)
        assert got.shape == (23, 16)
        np.testing.assert_array_equal(got, want)
    # Sharma, Wu & Dalal (2005) test pairs 1 and 7 (hue across the 0 degree line is pair 7's point)
    sharma = ciede2000_pairwise([[50.0, 2.6772, -79.7751], [50.0, 0.0, 0.0]], [[50.0, 0.0, -82.7485], [50.0, -1.0, 2.0]])
    assert sharma[0, 0] == pytest.approx(2.0425, abs=1e-4) and sharma[1, 1] == pytest.approx(2.3669, abs=1e-4)
    assert ciede2000_pairwise(np.zeros((0, 3)), b).shape == (0, 16)
    with pytest.raises(ValueError, match=r"\(5, 2\)"):
        ciede2000_pairwise(np.zeros((5, 2)), b)
