""":func:`stillcap.body.hand_checks.noise_from_misfit`: the stated noise of partly hidden markers
scaled to what a fit's residuals show, an upper bound that covers the true noise as often as it
states."""

import numpy as np
import pytest

from stillcap.body.hand_checks import HIDDEN_NOISE_P, noise_from_misfit


def _draw(rng, stated, true_ratio):
    """Residuals (3D distances) of labels whose true noise per axis is ``true_ratio`` x ``stated``."""
    r = np.linalg.norm(rng.normal(0.0, 1.0, (*stated.shape, 3)), axis=-1) * stated * true_ratio
    return (r / stated) ** 2


def test_the_scaled_noise_covers_the_true_noise_at_its_stated_rate():
    rng = np.random.default_rng(0)
    floor = 1e-5
    covered, scales = [], []
    for _ in range(600):
        stated = rng.uniform(0.003, 0.015, 12)  # 3 mm over the share of the light, as the pipeline states
        sig, scale = noise_from_misfit(stated, _draw(rng, stated, 0.1), floor)
        covered.append(bool(np.all(sig >= 0.1 * stated)))  # the truth: a tenth of the stated noise
        scales.append(scale)
    assert 0.92 <= np.mean(covered) <= 0.98  # a 95 % upper bound (HIDDEN_NOISE_P = 0.05)
    assert HIDDEN_NOISE_P == 0.05
    assert 0.1 < np.median(scales) < 0.2  # near the truth, not the stated noise


def test_only_the_noisier_labels_are_scaled_never_below_the_floor_nor_up():
    rng = np.random.default_rng(1)
    stated = np.array([[0.0003, 0.006, np.nan], [0.012, 0.0003, 0.004]])
    misfit = _draw(rng, np.nan_to_num(stated, nan=1.0), 0.01)
    misfit[0, 2] = np.nan
    sig, scale = noise_from_misfit(stated, misfit, 0.0003)
    assert scale is not None and scale < 0.2
    assert sig[0, 0] == sig[1, 1] == 0.0003 and np.isnan(sig[0, 2])  # fully seen and unlabelled: as they were
    assert np.all(sig[[0, 1, 1], [1, 0, 2]] >= 0.0003)  # never below a fully seen marker's noise
    # residuals as large as the stated noise: nothing scaled (never above the stated noise)
    loud = _draw(rng, np.full(20, 0.005), 1.0)
    same, none = noise_from_misfit(np.full(20, 0.005), loud, 0.0003)
    assert none is None and np.array_equal(same, np.full(20, 0.005))


def test_degrees_of_freedom_the_labels_alone_fix_widen_the_bound():
    rng = np.random.default_rng(2)
    stated = np.full(10, 0.005)
    misfit = _draw(rng, stated, 0.1)
    _, s0 = noise_from_misfit(stated, misfit, 1e-5)
    _, s1 = noise_from_misfit(stated, misfit, 1e-5, absorbed=12)
    assert s0 < s1
    # every degree absorbed: the residuals show nothing, nothing is scaled
    assert noise_from_misfit(stated, misfit, 1e-5, absorbed=30)[1] is None
    with pytest.raises(ValueError, match="sigma_m and misfit must have one shape"):
        noise_from_misfit(stated, misfit[:3], 1e-5)
