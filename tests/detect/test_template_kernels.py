"""The template detector's disc-minus-ring kernels (``_disc_kernel``) against their definition."""

import numpy as np
import pytest

from stillcap.detect.circles._template import _SS, _disc_kernel


def _reference(r, inner_gap=1.0, ring=2.0):
    """The definition, written out: each pixel's share of 8 x 8 sub-pixels whose centres lie in
    the disc (distance by np.hypot) and in the ring, the disc's mean minus the ring's."""
    R = int(np.ceil(r + inner_gap + ring))
    g = (np.arange((2 * R + 1) * _SS) + 0.5) / _SS - 0.5 - R
    d = np.hypot(g[None, :], g[:, None])

    def share(mask):
        return mask.astype(float).reshape(2 * R + 1, _SS, 2 * R + 1, _SS).mean(axis=(1, 3))

    disc, ann = share(d <= r), share((d > r + inner_gap) & (d <= r + inner_gap + ring))
    return (disc / disc.sum() - ann / ann.sum()).astype(np.float32)


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_kernels_equal_their_definition(scale):
    # radii 0.5-30 px in 0.05 px steps, full and half resolution (the coarse map's)
    for r in np.round(np.arange(0.5, 30.0, 0.05), 2):
        got = _disc_kernel(r * scale, inner_gap=scale, ring=2.0 * scale)
        assert np.array_equal(got, _reference(r * scale, scale, 2.0 * scale)), (r, scale)


def test_kernel_is_zero_mean_disc_minus_ring():
    k = _disc_kernel(6.0).astype(float)
    assert k.shape == (2 * 9 + 1,) * 2
    assert abs(k.sum()) < 1e-6
    assert k[9, 9] > 0 and k[9, 0] < 0 and k[0, 0] == 0  # centre: disc; edge: ring; corner: neither
    assert k[9, 9] == k.max()
