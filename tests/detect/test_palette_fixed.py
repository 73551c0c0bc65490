"""propose_palette(fixed=...): colours to add beside existing ones (the puppet-20 beads)."""

import numpy as np
import pytest

from stillcap.body.markerset import MarkerSet
from stillcap.detect.palette import Palette, color_distance, propose_palette


def test_new_colors_keep_away_from_the_fixed_ones():
    thesis = Palette.from_markerset(MarkerSet.puppet())
    prop = propose_palette(4, rng=0, fixed=thesis, restarts=4, lightness_weight=0.5)
    new = prop.palette
    assert len(new) == 4 and prop.fixed is thesis
    d_new = color_distance(new.rgb, new.rgb, lightness_weight=0.5) + np.diag(np.full(4, np.inf))
    d_fix = color_distance(new.rgb, thesis.rgb, lightness_weight=0.5)
    assert prop.min_distance == pytest.approx(d_new.min()) and prop.min_distance_to_fixed == pytest.approx(d_fix.min())
    assert prop.guaranteed_distance == pytest.approx(min(d_new.min(), d_fix.min()))
    i, j = np.unravel_index(np.argmin(d_fix), d_fix.shape)
    assert prop.closest_fixed == (new.names[i], thesis.names[j])
    # the combined palette: the kept colours first, then the new ones
    assert prop.combined.names == thesis.names + new.names and np.allclose(prop.combined.rgb[16:], new.rgb)
    # far better than ignoring the kept colours: a free 4-colour palette lands next to some of them
    free = propose_palette(4, rng=0, restarts=4, lightness_weight=0.5)
    assert free.min_distance_to_fixed == np.inf and free.combined is free.palette
    free_to_thesis = color_distance(free.palette.rgb, thesis.rgb, lightness_weight=0.5).min()
    assert prop.guaranteed_distance > 17 and prop.guaranteed_distance > free_to_thesis + 3


def test_fixed_as_an_array_and_name_clash():
    fixed = np.array([[0.8, 0.0, 0.0], [0.0, 0.6, 0.0]])
    prop = propose_palette(2, rng=1, fixed=fixed, restarts=2)
    assert prop.fixed.names == ("f00", "f01")
    assert color_distance(prop.palette.rgb, fixed).min() == pytest.approx(prop.min_distance_to_fixed)
    assert prop.min_distance_to_fixed > 30  # pure red and green kept: the new ones go blue/yellow/purple
    with pytest.raises(ValueError, match=r"names \['f00'\] are taken by the fixed colours"):
        propose_palette(1, fixed=fixed, names=["f00"])
    with pytest.raises(ValueError, match=r"fixed must have shape \(N, 3\)"):
        propose_palette(1, fixed=np.zeros((2, 4)))


def test_min_grey_keeps_dim_colors_out():
    dim = propose_palette(6, rng=0, restarts=2)
    assert dim.palette.rgb.mean(axis=1).min() < 0.4  # saturated reds and blues are dim in a grey image
    bright = propose_palette(6, rng=0, restarts=2, min_grey=0.48)
    assert bright.palette.rgb.mean(axis=1).min() >= 0.48 and bright.min_distance < dim.min_distance
