"""Outlier views: a photo whose reprojection RMS stands far above the others of its camera.

A calibration reports one reprojection RMS per view (per photo, per stereo pair, per camera and
instant of a rig). One badly detected view (a board bent or seen at a grazing angle, blur, a
corner snapped to the wrong edge) can raise the overall RMS and pull the intrinsics; the rule here
names such views so that the user can drop them. The result objects hold the names
(``outlier_views``) and a recalibration without them (``without_outliers``), so both RMS values
can be reported.

The rule (:func:`outlier_views`): view ``i`` is an outlier when its RMS ``e_i`` is above all three of

- ``RATIO x median`` (3x): a view must be far worse than the typical view, not merely in the
  upper tail. On OpenCV's stereo set the two views of pair 02 are 6.3x and 5.5x their camera's
  median; the next worst views (right05, right13, with one corner off by 2-3 px) are 2.9x and
  2.5x; the studio's rendered sets stay below 1.5x. A factor of 3 lies between.
- ``median + N_SIGMA x sigma`` (3 sigma), with ``sigma = 1.4826 x MAD``: a set whose views
  spread widely (near and far boards, sharp and soft photos) needs more than 3x to stand out.
  The median and the MAD are not moved by the outliers themselves, unlike the mean and the
  standard deviation.
- ``FLOOR_PX`` (0.5 px): a view under half a pixel is consistent with a good calibration,
  whatever its neighbours do; without a floor, a very clean set (rendered views at 0.05 px)
  would flag a view at 0.2 px that does no harm.

At least ``MIN_VIEWS`` (4) views are needed: with fewer, the median says little and dropping a
view would leave too few to calibrate.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

RATIO = 3.0
N_SIGMA = 3.0
FLOOR_PX = 0.5
MIN_VIEWS = 4
MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution = 1.4826 x its median absolute deviation


def outlier_threshold(rms_px, ratio: float = RATIO, n_sigma: float = N_SIGMA, floor_px: float = FLOOR_PX) -> float:
    """The RMS above which a view is an outlier (see the module's docstring); inf with fewer than
    ``MIN_VIEWS`` finite values."""
    v = np.asarray([x for x in np.ravel(np.asarray(rms_px, float)) if np.isfinite(x)])
    if len(v) < MIN_VIEWS:
        return float("inf")
    med = float(np.median(v))
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(v - med)))
    return max(ratio * med, med + n_sigma * sigma, floor_px)


def outlier_views(rms_by_view: Mapping[str, float], ratio: float = RATIO, n_sigma: float = N_SIGMA,
                  floor_px: float = FLOOR_PX) -> list[str]:
    """Names of the views whose RMS is above :func:`outlier_threshold`, in the mapping's order.

    Parameters
    ----------
    rms_by_view : mapping view name -> reprojection RMS in pixels (views of one camera).
    ratio, n_sigma, floor_px : the rule's constants (defaults :data:`RATIO`, :data:`N_SIGMA`,
        :data:`FLOOR_PX`).
    """
    limit = outlier_threshold(list(rms_by_view.values()), ratio, n_sigma, floor_px)
    return [k for k, e in rms_by_view.items() if e > limit]
