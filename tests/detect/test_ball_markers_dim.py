"""Dark markers on a side-lit ball whose dim leather is noisy (issue 12: side light plus a
sensor's read noise made "black markers" of the noise near the terminator)."""
from __future__ import annotations

import numpy as np
import pytest

from detect.test_ball import baseball_markers, draw_balls, flight_balls
from detect.test_ball_markers import score
from stillcap.detect.ball_markers import _noise_by_brightness, detect_ball_markers

SIDE_LIGHT = np.array([0.9, 0.0, -0.45]) / np.linalg.norm([0.9, 0.0, -0.45])


def _side_lit(noise: float, seeds=range(4), r_range=(18, 26)):
    found = false = n = 0
    for seed in seeds:
        balls = flight_balls(seed, n=8, size=(960, 1280), r_range=r_range)
        markers = [baseball_markers(100 * seed + i) for i in range(len(balls))]
        img, truth = draw_balls((960, 1280), balls, light=SIDE_LIGHT, ambient=0.02, markers=markers, noise=noise,
                                rng=seed, blur=1.0)
        m = detect_ball_markers(img, balls[:, :2], balls[:, 2])
        k, f, _, _, _, fa = score(m, truth, balls, light=SIDE_LIGHT)
        n, found, false = n + k, found + f, false + fa
    return n, found, false


def test_noisy_dim_leather_makes_few_false_dark_markers():
    quiet = _side_lit(2.0)
    noisy = _side_lit(6.0)
    # the quiet photo's false detections (markers past the terminator, which `score` does not
    # count as visible) set the baseline; the noise must not add more than 1 per 10 markers
    # found (one pooled noise ceiling per photo added 11 here: 15 -> 26 for 38 found)
    assert noisy[1] >= 0.6 * quiet[1]
    assert noisy[2] <= quiet[2] + 0.1 * noisy[1], (quiet, noisy)


def test_darkness_noise_ceiling_falls_with_brightness():
    rng = np.random.default_rng(0)
    bright = rng.uniform(0.1, 1.0, 20000)
    dark = np.abs(rng.normal(0.0, 0.01 / bright))  # read noise relative to the local white
    mids, ceil = _noise_by_brightness(bright, dark)
    assert np.all(np.diff(mids) > 0) and np.all(np.diff(ceil) <= 0)
    assert ceil[0] > 3 * ceil[-1]
    assert _noise_by_brightness(bright[:100], dark[:100]) is None


def test_coloured_markers_on_a_noisy_side_lit_ball_are_found():
    """The saturation ceiling per brightness of the leather (issue 12, pitch axis): HSV saturation
    divides by the value, so a noisy sensor makes a side-lit ball's dim leather far more
    saturated than its bright leather. One ceiling pooled over the ball (set by the dim pixels)
    hid the blurred coloured markers on the bright side: 23 of 49 found here, with 4 false
    detections, against 46 and none with the ceiling at each pixel's own brightness."""
    n, found, false = _side_lit(10.0)
    assert found >= 0.8 * n, (n, found, false)
    assert false <= 0.1 * found, (n, found, false)


def test_saturation_ceiling_is_an_isotonic_fit():
    """``monotone="isotonic"`` (the saturation ceiling's): a bright bin estimated too high (here
    the brightest sixth's saturation raised by 0.1, as a clipped channel or JPEG chroma near the
    markers raise it) is averaged with its neighbours, where the darkness ceiling's ``"lift"``
    raises every dimmer bin to it; the dim leather's own higher ceiling stays."""
    rng = np.random.default_rng(1)
    bright = rng.uniform(0.1, 1.0, 20000)
    sat = np.abs(rng.normal(0.0, 0.01 / bright)) + np.where(bright > 0.85, 0.1, 0.0)
    _, lift = _noise_by_brightness(bright, sat)
    _, iso = _noise_by_brightness(bright, sat, monotone="isotonic")
    assert np.all(np.diff(iso) <= 0) and np.all(np.diff(lift) <= 0)
    assert np.all(lift[1:] >= lift[-1]) and lift[2] > 0.15  # lifted to the top bin's 0.15
    assert np.all(iso[2:] < 0.1) and iso[0] > 2 * iso[-1]  # averaged; the dim bin keeps its own
    with pytest.raises(ValueError, match="monotone"):
        _noise_by_brightness(bright, sat, monotone="max")


def test_brightness_bins_made_once_give_each_darkness_measure_its_own_ceilings():
    """The detector bins a photo's lit pixels by brightness once (``_brightness_bins``) for its
    three darkness measures (darkness, saturation, luma darkness): each ceiling is the one made
    from the pixels themselves, to the bit, and too few pixels still give None."""
    from stillcap.detect._marker_chroma import luma_thresholds
    from stillcap.detect._marker_noise import _brightness_bins
    from stillcap.detect.ball_markers import BASEBALL_MARKER_TYPES

    rng = np.random.default_rng(2)
    bright = rng.uniform(0.1, 1.0, 20000)
    binned = _brightness_bins(bright)
    for mono in ("lift", "isotonic"):
        dark = np.abs(rng.normal(0.0, 0.01 / bright))
        own = _noise_by_brightness(bright, dark, monotone=mono)
        shared = _noise_by_brightness(bright, dark, monotone=mono, binned=binned)
        assert np.array_equal(own[0], shared[0]) and np.array_equal(own[1], shared[1])
    assert _brightness_bins(bright[:100]) is None and _noise_by_brightness(bright[:100], dark[:100]) is None
    classes = [[t] for t in BASEBALL_MARKER_TYPES if t.color_bgr[0] != t.color_bgr[2]]
    parts = [bright[:7000], bright[7000:]]
    dl = [np.abs(rng.normal(0.0, 0.02 / p)) for p in parts]
    own = luma_thresholds(classes, dl, parts, 0.66, 0.5)
    shared = luma_thresholds(classes, dl, parts, 0.66, 0.5, binned=binned)
    assert own[:3] == shared[:3] and all(np.array_equal(a, b) for a, b in zip(own[3], shared[3]))
