"""The stated share of the shading correction that is wrong, scaled by how far the stereo pairs'
positions disagree (``PitchOptions(shading_share_scale="pairs")``, off by default): the pairs'
remaining-bias and calibration modes handed to
:func:`stillcap.ball.shading_error.share_scale_from_pairs`. ``docs/pitch.md``, "Coverage with 12
captures per condition, and the share scaled by the pairs?"."""

from __future__ import annotations

import numpy as np

from stillcap.ball.shading_error import share_scale_from_pairs
from stillcap.ball.uncertainty import calibration_modes, remaining_bias_modes
from stillcap.io.capture import board_points_world

__all__ = ["pairs_share_scale"]


def pairs_share_scale(pairs, fit, model, group_index, pair_index, shape_covariance, options, calib):
    """:func:`stillcap.ball.shading_error.share_scale_from_pairs` over the stereo pairs: their
    remaining-bias modes at each scale of the stated share, their calibration modes fixed."""
    N = len(pair_index)
    fixed, items = [], []
    for i, p in enumerate(pairs):
        if len(p) == 0 or p.stereo is None:
            continue
        board = None if calib is None else [board_points_world(calib, p.name, c.name) for c in p._cams]
        cm = calibration_modes(p._cams, p.centers_px, board, options.calibration_focal_sigma)
        if cm is not None:
            full = np.zeros((len(cm), N, 3))
            full[:, pair_index == i] = cm
            fixed.append(full)
        items.append((i, p))

    def modes_at(s):
        out = [np.zeros((0, N, 3))]
        for i, p in items:
            mb = remaining_bias_modes(p._cams, p.stereo, p.centers_px, p.flags, p.radius_px,
                                      options.shading_model_error * s, correlation="epipolar")
            full = np.zeros((len(mb), N, 3))
            full[:, pair_index == i] = mb
            out.append(full)
        return np.concatenate(out)

    return share_scale_from_pairs(fit, model, group_index, pair_index, shape_covariance, modes_at,
                                  np.concatenate(fixed) if fixed else None)
