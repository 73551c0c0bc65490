"""A ball painted at random (``stillcap.studio.ball_variation``): what it draws is a valid ball
file within the stated ranges, and both ways of placing the markers are used."""

import math

import numpy as np
import pytest

from stillcap.ball.ballfile import Ball
from stillcap.studio.ball_variation import hand_painted_directions, painted_ball


def test_hand_painted_directions_keep_their_separation():
    d = hand_painted_directions(14, 30.0, rng=3)
    assert d.shape == (14, 3)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    cos = d @ d.T
    np.fill_diagonal(cos, -1)
    assert math.degrees(math.acos(cos.max())) >= 30.0
    with pytest.raises(ValueError, match="could not place"):
        hand_painted_directions(40, 60.0, rng=0, tries=2000)


@pytest.mark.parametrize("designed", [False, True])
def test_painted_ball_is_a_valid_ball_file_in_range(designed):
    for seed in range(4):
        ball = painted_ball(seed, n_range=(6, 9), designed=designed)
        again = Ball.from_dict(ball.to_dict(), "round trip")  # every check of the format passes
        assert len(again.layout) == len(ball.layout)
        assert 0.034 <= ball.radius <= 0.042
        # a baseball's density within +-15 %
        density = ball.mass / ball.radius ** 3
        assert 0.84 < density / (0.145 / 0.0366 ** 3) < 1.16
        lay = ball.layout
        assert 6 <= len(lay) <= 9 and 2 <= lay.n_types <= 5
        sizes_mm = np.degrees(np.asarray(lay.sizes_of_types)) * math.pi / 180 * ball.radius * 1e3
        assert np.all((sizes_mm > 3.99) & (sizes_mm < 8.01))
        assert ("designed" if designed else "by hand") in ball.description


def test_painted_balls_vary():
    balls = [painted_ball(s, n_range=(6, 9)) for s in range(6)]
    assert len({len(b.layout) for b in balls}) > 1
    assert len({b.layout.type_shapes for b in balls}) > 1
    assert len({round(b.radius, 4) for b in balls}) == 6
    # same seed, same ball
    a, b = painted_ball(5, n_range=(6, 9)), painted_ball(5, n_range=(6, 9))
    assert np.array_equal(a.layout.directions, b.layout.directions) and a.layout.palette == b.layout.palette
