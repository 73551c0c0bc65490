"""One marker region measured (:mod:`stillcap.detect.ball_markers`, steps 3 and 4): its shape
(:func:`classify_shape`, affine-invariant), and its centroid, confidence, flags and centroid
standard error (``_measure``); the type by size where the shape does not decide (``_by_size``)."""

from __future__ import annotations

import cv2
import numpy as np

from stillcap.detect._marker_noise import centroid_sigma_px, leather_noise
from stillcap.detect._marker_types import MarkerFlag, MarkerType

__all__ = ["classify_shape"]

_BOX3 = np.ones((3, 3), np.uint8)  # 3x3 structuring element (8-neighbourhood)
#: How far around a marker's bounding box its leather noise is read, px: with the box's 2 px rim
#: grown away (paint), 4 px leaves a ring of ~2 px, 40-60 pixels around a 5-8 px marker (enough
#: for a MAD: ``leather_noise``) and near enough that it is the marker's own neighbourhood (JPEG's
#: 8x8 blocks around it, the same brightness of the shading).
NOISE_MARGIN = 4


# --------------------------------------------------------------------------------------------
# shape
# --------------------------------------------------------------------------------------------
def _shape_features(region: np.ndarray):
    """Hole share and whitened radius spread of a binary region (uint8 0/255, upsampled)."""
    cs, hier = cv2.findContours(region, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not cs:
        return 0.0, np.nan
    parent = hier[0][:, 3]
    areas = [cv2.contourArea(ci) for ci in cs]
    main = max(np.flatnonzero(parent < 0), key=areas.__getitem__)
    a_out = areas[main]
    if a_out <= 0:
        return 0.0, np.nan
    holes = sum(areas[i] for i in np.flatnonzero(parent == main))
    m = cv2.moments(cs[main])
    if m["m00"] <= 0:
        return holes / a_out, np.nan
    cov = np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / m["m00"]
    w, v = np.linalg.eigh(cov)
    if w[0] <= 1e-9:
        return holes / a_out, np.nan
    white = v @ np.diag(1 / np.sqrt(w)) @ v.T
    p = cs[main].reshape(-1, 2).astype(float) - (m["m10"] / m["m00"], m["m01"] / m["m00"])
    q = p @ white.T
    rad = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1])  # np.linalg.norm(q, axis=1)'s numbers, without its overhead
    lo, hi = int(0.02 * (len(rad) - 1)), int(0.98 * (len(rad) - 1))
    rad = np.partition(rad, (lo, hi))  # the two order statistics only, not a full sort
    spread = float(rad[hi] / max(rad[lo], 1e-9))
    return holes / a_out, spread


def classify_shape(region, min_area: float = 20.0, hole_share: float = 0.06) -> str:
    """Shape of a binary region: "ring", "disc", "square", "triangle" or "unknown".

    Affine-invariant, so a foreshortened marker keeps its shape: a hole of at least
    ``hole_share`` of the region makes a ring; otherwise the outline, whitened by the region's
    second moments, has radii spreading (98th / 2nd percentile) about 1.0 for a disc, 1.41 for a
    square and 2.0 for a triangle; the thresholds are the geometric means 1.19 and 1.68.

    Parameters
    ----------
    region : ndarray, shape (H, W)
        Binary mask (nonzero = region).
    min_area : float
        Smaller regions give "unknown".
    """
    r = np.asarray(region)
    if r.ndim != 2:
        raise ValueError(f"region must have shape (H, W), got {r.shape}")
    r = (r > 0).astype(np.uint8) * 255
    if np.count_nonzero(r) < min_area:
        return "unknown"
    # upsample so that the outline of a 5 px marker is not a staircase
    big = cv2.resize(r, None, fx=4, fy=4, interpolation=cv2.INTER_LINEAR)
    big = cv2.copyMakeBorder(big, 2, 2, 2, 2, cv2.BORDER_CONSTANT, value=0)
    _, big = cv2.threshold(big, 127, 255, cv2.THRESH_BINARY)
    return _shape_name(*_shape_features(big), hole_share)


def _shape_name(holes: float, spread: float, hole_share: float) -> str:
    if holes >= hole_share:
        return "ring"
    if not np.isfinite(spread):
        return "unknown"
    if spread < 1.19:
        return "disc"
    if spread < 1.68:
        return "square"
    return "triangle"


# --------------------------------------------------------------------------------------------
# one region
# --------------------------------------------------------------------------------------------
def _measure(lab, j, soft, dark_luma, X, Y, st, tlist, area, bi, cx, cy, r, disc, inner, limb_fraction, min_aspect,
             cen_w=None, near_t=None, refl_rows=None, resid=None, sig_rows=None):
    """Centroid, shape, confidence and flags of region ``j`` of the labels ``lab`` (bounding
    box + 2 px only). A region reaching the mask ``near_t`` (h, w) has its centroid weighed by
    ``cen_w`` instead of ``dark_luma``, and its centroid put in the dict ``refl_rows`` by its ``id``.
    With ``resid`` (h, w: the leather's luma relative to its white, not clipped) the centroid's
    standard error goes into the dict ``sig_rows`` by the centroid's ``id``."""
    bx, by, bw, bh = (int(v) for v in st[:4])
    noise = float("nan")
    if resid is not None and sig_rows is not None:
        # the leather within NOISE_MARGIN px of the box, off every region of this colour grown by
        # 2 px (their rims hold paint): its residual's robust spread is this marker's own noise
        ys = slice(max(by - NOISE_MARGIN, 0), min(by + bh + NOISE_MARGIN, lab.shape[0]))
        xs = slice(max(bx - NOISE_MARGIN, 0), min(bx + bw + NOISE_MARGIN, lab.shape[1]))
        paint = cv2.dilate((lab[ys, xs] > 0).view(np.uint8), _BOX3, iterations=2).view(bool)
        noise = leather_noise(resid[ys, xs][disc[ys, xs] & ~paint])
    y0, x0 = max(by - 2, 0), max(bx - 2, 0)
    y1, x1 = min(by + bh + 2, lab.shape[0]), min(bx + bw + 2, lab.shape[1])
    sl = (slice(y0, y1), slice(x0, x1))
    comp = lab[sl] == j
    soft, dark_luma, X, Y, disc, inner = soft[sl], dark_luma[sl], X[:, sl[1]], Y[sl[0]], disc[sl], inner[sl]
    # luma-darkness weighted centroid over the region grown by one pixel: partly covered edge
    # pixels count in proportion, which makes the centroid sub-pixel (cf. detect/blobs.py)
    grown = cv2.dilate(comp.view(np.uint8), _BOX3).view(bool) & disc
    w = np.where(grown, dark_luma, 0.0)
    cut = comp & ~inner
    sw = float(w.sum())
    if sw <= 0:
        return None
    cen = np.array([float((w * X).sum() / sw), float((w * Y).sum() / sw)])
    out = cen
    if cen_w is not None and (grown & near_t[sl]).any():
        # cut by the searched disc's edge short of the terminator (an unlit side under the hull's
        # min_value): grown one pixel on across it too, where the light's model still measures
        # (near_t reaches past the disc there: _ball_light.terminator_weights)
        reach = grown | (cv2.dilate(cut.view(np.uint8), _BOX3).view(bool) & near_t[sl] & ~disc)
        wc = np.where(reach, cen_w[sl], 0.0)
        swc = float(wc.sum())
        if swc > 0:
            out = np.array([float((wc * X).sum() / swc), float((wc * Y).sum() / swc)])
            refl_rows[id(out)] = out
    if sig_rows is not None:  # (a centroid weighed against the terminator model: NaN, its weights' noise unmodelled)
        sig_rows[id(out)] = (out, centroid_sigma_px(w, X, Y, noise) if out is cen else float("nan"))
    # second moments of the weights: aspect (foreshortening)
    # (w dx and w dy formed once: ``w * dx * dx`` is ``(w * dx) * dx``, the same numbers)
    dx, dy = X - cen[0], Y - cen[1]
    wdx, wdy = w * dx, w * dy
    cxx, cxy, cyy = (wdx * dx).sum() / sw, (wdx * dy).sum() / sw, (wdy * dy).sum() / sw
    ev = np.linalg.eigvalsh(np.array([[cxx, cxy], [cxy, cyy]]))
    aspect = float(np.sqrt(max(ev[0], 0) / ev[1])) if ev[1] > 0 else 1.0
    flags = MarkerFlag.NONE
    if np.hypot(cen[0] - cx, cen[1] - cy) > limb_fraction * r:
        flags |= MarkerFlag.NEAR_LIMB
    if aspect < min_aspect:
        flags |= MarkerFlag.FORESHORTENED
    if cut.any():
        flags |= MarkerFlag.AT_EDGE
    # shape from the weights upsampled x4 and cut at half their peak: a smooth outline even
    # for a 5 px marker (a binary mask's staircase would pass for a square)
    shape = "unknown"
    if area >= 20 and aspect >= min_aspect:
        big = cv2.resize(w, None, fx=4, fy=4, interpolation=cv2.INTER_LINEAR)  # w is float32
        kth = int(0.9 * (np.count_nonzero(w) - 1))
        peak = float(np.partition(w[w > 0], kth)[kth])
        # cut (255 where >= half the peak), then a 2 px border of 0 (the weights' zero border cut)
        cut = cv2.copyMakeBorder(cv2.compare(big, 0.5 * peak, cv2.CMP_GE), 2, 2, 2, 2, cv2.BORDER_CONSTANT, value=0)
        shape = _shape_name(*_shape_features(cut), 0.06)
    elif area < 20:
        flags |= MarkerFlag.SMALL
    # the mean membership (float32, as ndarray.mean, without its overhead), clipped to 0-1
    sc = soft[comp]
    col = min(max(float(sc.sum() / sc.size), 0.0), 1.0)
    match = [t for t in tlist if t.shape == shape]
    if match:
        t, shape_conf = match[0], 1.0
    else:
        t = _by_size(tlist, float(ev[1]), r)
        if shape == "unknown":
            shape_conf = 0.7
        else:
            shape_conf = 0.5
            flags |= MarkerFlag.SHAPE_MISMATCH
    conf = col * shape_conf * min(1.0, aspect / 0.6)
    return out, t.name, shape, area, conf, aspect, bi, flags


def _by_size(tlist: list, major_var_px2: float, r_px: float) -> MarkerType:
    """Of one colour class's types, the one whose size best explains a region's variance along
    its major axis (which foreshortening leaves), where the shape did not decide: a marker whose
    paint lies ``spread_rad2`` (mean squared angle) from its centre, on a ball of ``r_px`` px,
    spreads about ``spread_rad2 r_px^2 / 2`` there, plus about 1/6 px^2 (pixels, the region's
    growth); the nearest in log wins. Spreads unknown: the first type."""
    if len(tlist) < 2 or any(t.spread_rad2 is None for t in tlist) or not major_var_px2 > 0:
        return tlist[0]
    expected = np.array([0.5 * t.spread_rad2 * r_px ** 2 + 1 / 6 for t in tlist])
    return tlist[int(np.argmin(np.abs(np.log(major_var_px2 / expected))))]
