"""Ball positions, release and spin from a rendered hand capture (1280x960)."""

import numpy as np
import pytest

from stillcap.ball.release import estimate_release
from stillcap.pipelines.hand.ball import hand_ball_positions, hand_ball_spin, whiteness
from stillcap.studio.hand import hand_capture


@pytest.fixture(scope="module")
def capture():
    return hand_capture(0, image_size=(1280, 960))


@pytest.fixture(scope="module")
def balls(capture):
    tr = capture.truth
    return hand_ball_positions(capture, hand=(tr.times - tr.times[0], tr.root2world))


def test_positions_match_truth(capture, balls):
    truth = capture.truth.ball2world[:, :3, 3]
    assert len(balls) == capture.truth.n  # the arm and the fingers are not taken for balls
    # flash numbers from the hand, on the hand's clock (the first rendered flash is 0)
    assert np.array_equal(balls.flash_index, np.arange(capture.truth.n))
    d = np.linalg.norm(truth[balls.flash_index] - balls.positions, axis=1)
    # the reported sigma (RMS per axis) is honest: every error within 3 sigma (3D: sqrt(3) factor)
    assert np.all(d < 3 * np.sqrt(3) * balls.sigma_m), (d, balls.sigma_m)
    assert np.all(balls.sigma_m > 0) and np.all(balls.sigma_m < 0.005)
    c, r = balls.ball_discs_px(0)
    assert len(c) == len(r) > 0


def test_positions_within_4mm_at_1280(capture, balls):
    # was a known failure (H3b: the first free flash 7 mm off, fingers across the ball) until the
    # studio seated the held ball clear of the glove (studio.hand_grip): the fingers were inside it
    truth = capture.truth.ball2world[:, :3, 3]
    d = np.linalg.norm(truth[balls.flash_index] - balls.positions, axis=1)
    assert np.all(d < 0.004), d


def test_release_from_detected_positions(capture, balls):
    tr = capture.truth
    t = tr.times - tr.times[0]
    r = estimate_release(balls.times, balls.positions, t, tr.root2world, strobe_hz=75,
                         position_sigma_m=balls.sigma_m)
    assert r.success
    dt = r.t_release - (tr.release.t0 - tr.times[0])
    assert abs(dt) < 2e-3 and abs(dt) < 3 * r.t_release_sigma
    dv = r.speed_mph - tr.release.speed_mph
    assert abs(dv) < 2.0 and abs(dv) < 3 * r.speed_sigma_mph
    assert np.array_equal(r.held, tr.held)


def test_numbering_from_hand_across_a_missed_flash(capture, balls):
    """Issue 5 bug: the spacing numbered the flashes wrongly across a gap (the arm speeds up);
    the hand numbers them right with a ball image removed."""
    from stillcap.ball.flashes import number_flashes_from_hand

    tr = capture.truth
    t = tr.times - tr.times[0]
    for drop in range(1, len(balls) - 1):
        keep = np.arange(len(balls)) != drop
        fn = number_flashes_from_hand(balls.positions[keep], t, tr.root2world, strobe_hz=75)
        assert fn.success and np.array_equal(fn.flash, balls.flash_index[keep]), (drop, fn.flash)
        assert np.allclose(fn.times, t[keep])
    # without a hand there is no held run: failure, said
    fn = number_flashes_from_hand(balls.positions, t[:1], tr.root2world[:1], strobe_hz=75)
    assert not fn.success and "hand poses" in fn.message


def test_spin_says_why_not(capture, balls):
    free = ~capture.truth.held
    sp = hand_ball_spin(capture, balls, free)
    if not sp.available:
        assert "spin" in sp.message and np.all(np.isnan(sp.spin))
    else:
        assert sp.ambiguous == (len(sp.candidates_rpm) > 1)


def test_whiteness_shape():
    with pytest.raises(ValueError, match="image must have shape"):
        whiteness(np.zeros((4, 4, 2), np.uint8))


def test_histogram_median_equals_numpy():
    """The uint8 histogram median (and median absolute deviation) that replaced np.median in the
    ball threshold is exact, for odd and even sizes."""
    from stillcap.pipelines.hand.ball import _median

    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 10, 11, 1000, 1001, 200_000):
        w = np.clip(rng.normal(12, 30, n), 0, 255).astype(np.uint8)
        m = np.median(w)
        assert _median(w) == m
        for about in (m, m + 0.5):
            assert _median(w, about) == np.median(np.abs(w - about))
