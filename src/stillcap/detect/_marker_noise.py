"""The leather's noise ceilings that the marker detector's thresholds never go below
(:func:`stillcap.detect.ball_markers.detect_ball_markers`): pooled over a photo's lit leather
(:func:`_robust_ceiling`) and per brightness bin (:func:`_noise_by_brightness`)."""

from __future__ import annotations

import numpy as np

from stillcap._numeric import median


def _noise_by_brightness(brightness: np.ndarray, darkness: np.ndarray, bins: int = 6,
                         min_pixels: int = 200, monotone: str = "lift",
                         binned=None) -> tuple[np.ndarray, np.ndarray] | None:
    """The leather's darkness ceiling (:func:`_robust_ceiling`) per brightness bin of the lit
    pixels, as ``(bin brightness, ceiling)`` for ``np.interp``, or None with too few pixels.

    Darkness is relative (``1 - value / local white``), so a sensor's read noise, and the
    encoding's steep slope near black, make it noisier on dimmer leather (a side light's
    terminator): one ceiling pooled over the ball lets that noise through as "black markers"
    where the leather is dim and is stricter than needed where it is bright. The ceiling is
    kept non-increasing with brightness (noise never grows with light): ``monotone="lift"``
    raises each bin to the largest ceiling of the brighter ones; ``"isotonic"`` takes the
    least-squares non-increasing fit of the bins (``scipy.optimize.isotonic_regression``), so a
    bright bin the estimate puts too high (the leather's saturation near the markers' JPEG chroma,
    or where a channel clips and the white balance divides it down) is averaged with its
    neighbours instead of lifting every dimmer bin; with no trend it is about the pooled ceiling.

    ``binned``: :func:`_brightness_bins` of ``brightness`` (the detector bins one photo's lit
    pixels once for its three darkness measures; ``brightness`` is then not read)."""
    if monotone not in ("lift", "isotonic"):
        raise ValueError(f"monotone must be 'lift' or 'isotonic', got {monotone!r}")
    binned = _brightness_bins(brightness, bins, min_pixels) if binned is None else binned
    if binned is None:
        return None
    sels, mids = binned
    ceil = np.asarray([_robust_ceiling(darkness[sel]) for sel in sels], float)
    if monotone == "lift":
        ceil = np.maximum.accumulate(ceil[::-1])[::-1]  # brighter never noisier than dimmer
    else:
        from scipy.optimize import isotonic_regression

        ceil = np.asarray(isotonic_regression(ceil, increasing=False).x, float)
    return mids, ceil


def _brightness_bins(brightness: np.ndarray, bins: int = 6, min_pixels: int = 200):
    """The brightness bins of :func:`_noise_by_brightness`: ``bins`` quantile bins of
    ``brightness``, those with at least ``min_pixels``, as ``(masks, median brightness of each)``;
    None with too few pixels or fewer than 2 such bins."""
    if brightness.size < bins * min_pixels:
        return None
    edges = np.quantile(brightness, np.linspace(0.0, 1.0, bins + 1))
    idx = np.clip(np.searchsorted(edges, brightness, side="right") - 1, 0, bins - 1)
    sels, mids = [], []
    for b in range(bins):
        sel = idx == b
        if sel.sum() >= min_pixels:
            sels.append(sel)
            mids.append(median(brightness[sel]))
    return (sels, np.asarray(mids)) if len(mids) >= 2 else None


def _robust_ceiling(x: np.ndarray, k: float = 6.0) -> float:
    """``median + k x robust sigma`` of ``x``: the top of the leather's noise (the markers, a
    minority of the lit pixels, do not move it). The sigma (1.4826 MAD) is at least 2/255: 8-bit
    levels make a near-neutral surface's saturation and darkness step by about that much."""
    # (medians by stillcap._numeric.median: np.median's numbers without its overhead)
    x = np.ravel(x)
    med = median(x)
    return med + k * max(1.4826 * median(np.abs(x - med)), 2.0 / 255.0)


def leather_noise(residual: np.ndarray, min_pixels: int = 12) -> float:
    """The robust spread (1.4826 MAD) of the leather's residual around a marker: its luma
    relative to the ball's white model (``1 - luma / white``, not clipped), NaN with fewer than
    ``min_pixels`` values. ``min_pixels``: a MAD of n values has a relative error of about
    ``1.1 / sqrt(n)`` (Gaussian), 30 % at 12: fewer is no estimate of a marker's own noise."""
    x = np.ravel(residual)
    x = x[np.isfinite(x)]
    if x.size < min_pixels:
        return float("nan")
    med = median(x)
    return 1.4826 * float(median(np.abs(x - med)))


def centroid_sigma_px(weights: np.ndarray, X: np.ndarray, Y: np.ndarray, noise: float) -> float:
    """The standard error (px, per axis: the RMS of the x and y ones) of the weighted centroid
    ``c = sum(w_i x_i) / sum(w_i)`` when each weight carries independent noise of standard
    deviation ``noise`` (in the weights' units: the detector's weights are the luma darkness
    ``1 - luma / white``, whose noise :func:`leather_noise` measures on the leather around the
    marker).

    To first order ``dc = sum((x_i - c) dw_i) / sum(w)``, so ``var(c_x) = noise^2 sum((x_i -
    c_x)^2) / sum(w)^2`` over the weights that move with the noise. The detector clips its weights
    at 0 (``np.clip(1 - luma / white, 0, 1)``): a leather pixel in the marker's grown rim is 0
    about half the time and then does not move; the pixels counted are those with ``w > 0``
    (for a zero-mean leather pixel that counts ``noise^2 / 2`` on average where the clipped
    Gaussian's variance is ``0.34 noise^2``: a slight overestimate, on the safe side).

    Parameters
    ----------
    weights : ndarray, shape (h, w)
        The centroid's weights (0 outside the region).
    X, Y : ndarray, broadcasting to (h, w)
        Pixel coordinates.
    noise : float
        Standard deviation of each weight's noise.

    Returns
    -------
    float
        NaN where ``noise`` is not finite or the weights sum to nothing.
    """
    w = np.asarray(weights, float)
    sw = float(w.sum())
    if not (np.isfinite(noise) and noise >= 0 and sw > 0):
        return float("nan")
    Xb, Yb = np.broadcast_to(X, w.shape), np.broadcast_to(Y, w.shape)
    cx, cy = float((w * Xb).sum() / sw), float((w * Yb).sum() / sw)
    act = w > 0
    s2 = float(((Xb[act] - cx) ** 2).sum() + ((Yb[act] - cy) ** 2).sum()) / 2.0
    return float(noise * np.sqrt(s2) / sw)
