"""Step 2 of the ball detector: silhouettes (contours thresholded around candidates), their
convex hull and ellipse, and merged silhouettes split into balls (:func:`detect_balls`)."""

from __future__ import annotations

import cv2
import numpy as np

from stillcap.detect.ball._arcs import arc_center_sigma, crescent_circle, edge_circle, faint_mask, thin_arcs
from stillcap.detect.ball._foreground import _check_image, _mask_limits, _threshold
from stillcap.detect.ball._types import BallDetections, BallFlag
from stillcap.detect.circle_fit import kasa_circle


# --------------------------------------------------------------------------------------------
# step 2: silhouettes -> hull -> ellipse, merged silhouettes
# --------------------------------------------------------------------------------------------
def _split_merged(contour: np.ndarray, min_sep: float, min_dip: float = 0.06):
    """Ball images inside one silhouette, from the maxima of its distance transform.

    The distance transform of one disc peaks at its centre (value r); in the union of
    overlapping discs (consecutive ball images of a slow pitch) it still peaks at every centre
    (the notches between two discs are at distance r from both centres) and dips between them.
    Each maximum's circle is then fitted to the contour points that lie on it (points near the
    notches, on two circles, are left out).

    Returns a list of (centre (2,), radius, rms residual, arc points (M, 2) or None) per ball
    image, empty when the silhouette holds one ball; centres are circle fits to the arc points
    (the ball's own part of the contour), or the distance maximum (rms ``inf``, no points) where
    no circle fits (a partly lit ball).
    """
    pts = contour.reshape(-1, 2)
    x0, y0 = pts.min(axis=0) - 2
    x1, y1 = pts.max(axis=0) + 3
    crop = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(crop, [contour.reshape(-1, 1, 2)], -1, 255, -1, offset=(-int(x0), -int(y0)))
    dt = cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    top = float(dt.max())
    if top < 2.0:
        return []
    rad = max(1, int(round(max(min_sep, 0.35 * top))))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1))
    # Candidate centres: local maxima at least half the highest, and at least a quarter of the
    # radius of a disc as large as the hull (a chain of 10 overlapping balls has ~0.28; the
    # thin lit rim of a ball lit from behind, a crescent, ~0.1: it is one ball, not several)
    hull_r = np.sqrt(cv2.contourArea(cv2.convexHull(contour.reshape(-1, 1, 2))) / np.pi)
    peaks = (dt >= cv2.dilate(dt, k) - 1e-6) & (dt >= max(0.5 * top, 0.25 * hull_r))
    n, lab, stats, cents = cv2.connectedComponentsWithStats(peaks.astype(np.uint8), connectivity=8)
    maxima = []
    for j in range(1, n):  # a plateau of equal maxima counts once: its centroid
        ys, xs = np.nonzero(lab == j)
        v = dt[ys, xs].max()
        maxima.append((cents[j][0] + x0, cents[j][1] + y0, float(v)))
    # A maximum is a ball of its own only if it is far enough from every higher one and the
    # distance transform dips between them (a dark marker's notch in one ball makes a second,
    # shallow maximum; two overlapping balls a clear valley, 0.13 r deep at 1 r apart).
    maxima.sort(key=lambda m: -m[2])
    keep = []
    t = np.linspace(0.0, 1.0, 24)
    for m in maxima:
        ok = True
        for q in keep:
            if np.hypot(m[0] - q[0], m[1] - q[1]) < max(min_sep, 0.35 * q[2]):
                ok = False
                break
            xs = np.round(q[0] + t * (m[0] - q[0]) - x0).astype(int)
            ys = np.round(q[1] + t * (m[1] - q[1]) - y0).astype(int)
            along = dt[ys, xs]
            # overlapping discs: the segment between centres stays inside the silhouette (the
            # horns of a crescent are joined through the background instead) and dips
            if along.min() <= 0.0 or min(m[2], q[2]) - along.min() < max(1.5, min_dip * top):
                ok = False
                break
        if ok:
            keep.append(m)
    if len(keep) < 2:
        return []
    P = pts.astype(float)
    cen = np.array([(m[0], m[1]) for m in keep])
    rr = np.array([m[2] for m in keep])
    resid = np.abs(np.linalg.norm(P[:, None, :] - cen[None], axis=2) - rr[None])
    order = np.argsort(resid, axis=1)
    best = order[:, 0]
    r1 = np.take_along_axis(resid, order[:, :1], 1)[:, 0]
    r2 = np.take_along_axis(resid, order[:, 1:2], 1)[:, 0]
    clear = r2 - r1 > 2.0
    out = []
    for j in range(len(keep)):
        sel = P[(best == j) & clear]
        if len(sel) >= 8:
            c, r = kasa_circle(sel)
            rms = float(np.sqrt(np.mean((np.linalg.norm(sel - c, axis=1) - r) ** 2)))
            if rms <= max(1.0, 0.05 * r) and np.hypot(*(c - cen[j])) < 0.5 * rr[j]:
                out.append((c, r, rms, sel))
                continue
        out.append((cen[j], rr[j], np.inf, None))
    return out


def _clean_contours(raw: np.ndarray, open_px: int, min_area: float, offset=(0, 0)) -> list:
    """External contours of the mask after a morphological opening, done per silhouette.

    Opening the whole 5 Mpx frame costs more than the rest of the detection; opening a crop
    around each candidate silhouette (drawn alone into the crop, so neighbours do not leak in)
    gives the same contours. ``offset`` is added to the returned points (``raw`` a crop).
    """
    ox, oy = int(offset[0]), int(offset[1])
    contours, _ = cv2.findContours(raw, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if open_px <= 0:
        return [c + np.array([ox, oy], c.dtype) for c in contours if cv2.contourArea(c) >= min_area]
    H, W = raw.shape
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * open_px + 1, 2 * open_px + 1))
    out = []
    for c in contours:
        if len(c) < 5 or cv2.contourArea(c) < min_area:
            continue
        x, y, w, h = cv2.boundingRect(c)
        x0, y0 = max(x - 2, 0), max(y - 2, 0)
        x1, y1 = min(x + w + 2, W), min(y + h + 2, H)
        crop = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.drawContours(crop, [c], -1, 255, -1, offset=(-x0, -y0))
        crop &= raw[y0:y1, x0:x1]
        crop = cv2.morphologyEx(crop, cv2.MORPH_OPEN, k)
        sub, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(x0 + ox, y0 + oy))
        out.extend(sub)
    return out


def _merge_boxes(boxes: list) -> list:
    """Union of overlapping (or touching) boxes ``[x0, y0, x1, y1]`` until none overlap."""
    boxes = [list(b) for b in boxes]
    merged = True
    while merged:
        merged = False
        out = []
        for b in boxes:
            for o in out:
                if b[0] <= o[2] and o[0] <= b[2] and b[1] <= o[3] and o[1] <= b[3]:
                    o[:] = [min(o[0], b[0]), min(o[1], b[1]), max(o[2], b[2]), max(o[3], b[3])]
                    merged = True
                    break
            else:
                out.append(b)
        boxes = out
    return boxes


def _foreground_contours(img: np.ndarray, background, threshold, k_sigma: float, min_contrast: float,
                         open_px: int, min_area: float, scale: int = 2, margin: int = 8) -> list:
    """The contours of :func:`_clean_contours` on the full foreground mask, thresholding only
    around the silhouettes.

    Thresholding every pixel of a 5 Mpx photo (``cv2.inRange`` over 3 channels, then the
    contour search over the whole mask) cost more than the rest of the silhouette step. The
    photo is thresholded at 1/``scale`` resolution (nearest pixel) to find where silhouettes
    are, and at full resolution only inside their boxes (grown by ``margin`` px; boxes that
    overlap merged; a box whose full-resolution mask reaches within 3 px of its edge is grown
    and the search repeated), so every silhouette is traced exactly as in the full mask: the
    same contours. A silhouette that falls between the sampled pixels everywhere (thinner than
    ``scale`` px in both directions) is not found; the opening removes such shapes anyway.
    """
    H, W = img.shape[:2]
    if min(H, W) < 16 * scale:
        src, hi, _ = _mask_limits(img, background, threshold, k_sigma, min_contrast)
        return _clean_contours(_threshold(src, hi), open_px, min_area)
    # the low-resolution image also gives the background levels their subsample
    src, hi, small = _mask_limits(img, background, threshold, k_sigma, min_contrast, scale)
    cand, _ = cv2.findContours(_threshold(small, hi), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    boxes = []
    for c in cand:
        x, y, w, h = cv2.boundingRect(c)
        boxes.append([max(x * scale - margin, 0), max(y * scale - margin, 0),
                      min((x + w) * scale + margin, W), min((y + h) * scale + margin, H)])
    band = 3
    while True:
        boxes = _merge_boxes(boxes)
        masks, grown = [], False
        for b in boxes:
            x0, y0, x1, y1 = b
            m = _threshold(src[y0:y1, x0:x1], hi)
            # foreground near an edge of the box that is not the photo's edge: the silhouette
            # may continue outside, grow the box
            g = [x0 > 0 and m[:, :band].any(), y0 > 0 and m[:band].any(),
                 x1 < W and m[:, -band:].any(), y1 < H and m[-band:].any()]
            if any(g):
                b[:] = [max(x0 - margin * g[0], 0), max(y0 - margin * g[1], 0),
                        min(x1 + margin * g[2], W), min(y1 + margin * g[3], H)]
                grown = True
            masks.append(m)
        if not grown:
            break
    out = []
    for (x0, y0, _, _), m in zip(boxes, masks):
        out.extend(_clean_contours(m, open_px, min_area, offset=(x0, y0)))
    return out


def detect_balls(image, background=None, min_area: float = 50.0, max_area: float | None = None,
                 threshold: float | None = None, k_sigma: float = 6.0, min_contrast: float = 20.0,
                 open_px: int = 1, partial_ratio: float = 0.8, partial_fill: float = 0.9,
                 merge_ratio: float = 0.9,
                 merge_solidity: float = 0.97, merge_min_sep: float = 4.0,
                 keep_mask: bool = False, crescents: bool = True, faint_crescents: bool = False,
                 edges: bool = True,
                 blur_px: float = 0.5) -> BallDetections:
    """Ball silhouettes of one photo: foreground mask, contours, convex hull, ellipse (steps 1-2).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        BGR photo (``uint8``, or float in 0-255), raw (not undistorted).
    background : ndarray like ``image``, optional
        Photo of the empty scene; default: dark-room model (see :func:`foreground_mask`).
    min_area, max_area : float
        Silhouette area limits in px^2 (contour area; a half moon counts half a disc).
    threshold, k_sigma, min_contrast, open_px
        Foreground threshold (see :func:`foreground_mask`).
    merge_ratio, merge_solidity : float
        Silhouettes whose ellipse axis ratio is below ``merge_ratio`` or whose area is below
        ``merge_solidity`` times their hull's are searched for several ball images (maxima of
        the distance transform at least ``merge_min_sep`` px and 0.35 radius apart). Several
        found: the silhouette is ``MERGED`` and each ball is returned (``SPLIT``) with the centre
        of a circle fitted to its own outer arc, or of its distance maximum (``PARTIAL``) where no
        circle fits (overlapping half moons; accepted only for a silhouette at least 1.35 times
        the photo's median silhouette area, since a marker's notch can pinch one half moon).
    partial_ratio, partial_fill : float
        Silhouettes whose ellipse minor/major axis ratio is below ``partial_ratio``, or whose
        hull fills less than ``partial_fill`` of the ellipse, are flagged ``PARTIAL`` (half
        moons and crescents: their ellipse centre is biased towards the light).
    keep_mask : bool
        Keep the cleaned foreground mask (filled silhouettes) in the result (``mask``), for
        display and debugging.
    crescents : bool
        Give crescents (balls lit from behind, silhouettes filling at most 0.4 of their circle)
        the centre and radius of the circle through their outer limb
        (:func:`stillcap.detect.ball._arcs.crescent_circle`): flagged ``CRESCENT | PARTIAL``.
    faint_crescents : bool
        (Default off.) Also find the thin, dim crescents that the threshold and the opening
        remove (:func:`stillcap.detect.ball._arcs.faint_mask`,
        :func:`~stillcap.detect.ball._arcs.thin_arcs`; with ``crescents``): flagged
        ``CRESCENT | PARTIAL``. Off by default: their refined centres sit ~0.4 px toward the
        light (``bench_ball_detect.py --only-missed``; their ``center_sigma_px`` covers it) and
        the pitch pipeline weighs each by it, but with the search on (``bench_robustness.py
        --quick --only pitch``, 6 captures per condition) 111 more ball images were used while
        "light to the side" (spin rate 2.93 -> 3.13 rpm, axis 1.16 -> 1.27 deg), "sensor noise
        x3" (spin rate 1.55 -> 5.15 rpm) and "everything varied" (direction 0.024 -> 0.032 deg)
        got worse: mostly the spin (``docs/ball-detection.md``).
    edges : bool
        Fit the balls cut by the photo's border to their in-frame limb
        (:func:`stillcap.detect.ball._arcs.edge_circle`): flagged ``EDGE`` where that fixes the
        centre, else ``TOUCHES_BORDER``.
    blur_px : float
        Lens blur (Gaussian sigma, px) for the arc fits' centre uncertainty.

    Returns
    -------
    BallDetections
        ``ellipse_centers`` are the ellipse centres (the split circle centres for merged
        silhouettes); ``centers`` the same, but the arc fits' for ``CRESCENT`` and ``EDGE`` balls
        (their circle's radius in ``arc_radii_px``, their uncertainty in ``center_sigma_px``;
        ``SPLIT`` balls' too, and with ``EDGE`` ones their arc in ``arc_points``); run :func:`refine_ball_centers` (or :func:`ball_centers_stereo`) for the known-radius Hough
        refinement.
    """
    img = _check_image(image)
    H, W = img.shape[:2]
    contours = _foreground_contours(img, background, threshold, k_sigma, min_contrast, open_px, 0.5 * min_area)
    mask = None
    if keep_mask:
        mask = np.zeros((H, W), np.uint8)
        cv2.drawContours(mask, contours, -1, 255, -1)
    sil = []
    for ci, c in enumerate(contours):
        area = cv2.contourArea(c)
        if area < min_area or (max_area is not None and area > max_area) or len(c) < 5:
            continue
        hull_idx = cv2.convexHull(c, returnPoints=False)
        hull = c[hull_idx.ravel()]
        if len(hull) < 5:
            continue
        sil.append((ci, c, area, cv2.fitEllipse(hull), cv2.contourArea(hull)))
    # the typical silhouette of this photo: ball images of one pitch differ little in size
    typical = float(np.median([s_[2] for s_ in sil])) if len(sil) >= 3 else np.inf
    rows = []
    for ci, c, area, ell, hull_area in sil:
        x, y, bw, bh = cv2.boundingRect(c)
        flag = BallFlag.NONE
        if x <= 0 or y <= 0 or x + bw >= W or y + bh >= H:
            flag |= BallFlag.TOUCHES_BORDER
        (ex, ey), (ew, eh), _ = ell
        semi_major = 0.5 * max(ew, eh)
        pieces = []
        if min(ew, eh) < merge_ratio * max(ew, eh) or area < merge_solidity * hull_area:
            pieces = _split_merged(c, min_sep=merge_min_sep)
            # Pieces that are not discs (partly lit balls) are several balls only if the
            # silhouette is clearly larger than this photo's typical one: a dark marker's notch
            # can pinch a single half moon or crescent into two lobes.
            if pieces and not all(np.isfinite(p_[2]) for p_ in pieces) and area < 1.35 * typical:
                pieces = []
        if pieces:
            for pc, pr, rms, arc_pts in pieces:
                f = flag | BallFlag.MERGED | (BallFlag.SPLIT if np.isfinite(rms) else BallFlag.PARTIAL)
                # issue 12: a split ball's centre rests on its own part of the outline only (the
                # rest is inside the silhouette): its arc goes along (refitted with the scale free
                # in ball_centers_stereo, as an EDGE ball's in-frame limb) with the arc's sigma
                arc = None if arc_pts is None else (
                    {"center": np.asarray(pc, float), "radius": pr, "rms": rms, "points": arc_pts}, True, False)
                rows.append((np.asarray(pc, float), pr, ell, area / len(pieces), hull_area, f, ci, arc))
            continue
        # a half moon's hull fits an ellipse badly: too narrow, or filling too little of it
        fill = hull_area / max(np.pi / 4 * ew * eh, 1e-9)
        if min(ew, eh) < partial_ratio * max(ew, eh) or fill < partial_fill:
            flag |= BallFlag.PARTIAL
        # issue 12: the centre of a ball cut by the border from its in-frame limb, of a crescent
        # from its outer limb (not a cut ball that its in-frame limb did not fix: less than
        # half a disc is no crescent). The silhouette's own ellipse stays (ellipse_centers,
        # ellipses, radii_px); the fit goes to ``centers`` (what stereo matching starts from
        # for EDGE balls). Both sigmas take a limb offset as a known-radius centre does
        # (arc_center_sigma's systematic part): a crescent is refined with the known radius; a
        # cut ball's in-frame limb is refitted with its scale free (ball_centers_stereo), which
        # absorbs a common offset, but not one that varies along the one-sided arc (the lit
        # side's limb farther out than the shaded side's, a marker's notch). With the random part
        # only, the studio pitches' clean direction got worse with the cut balls in
        # (0.008 -> 0.011 deg, bench_robustness --quick)
        arc = None
        if flag & BallFlag.TOUCHES_BORDER:
            fit = edge_circle(c, (W, H)) if edges else None
            if fit is not None:
                flag |= BallFlag.EDGE
                arc = (fit, True, False)
        elif flag & BallFlag.PARTIAL and crescents:
            fit = crescent_circle(c, area, image_size=(W, H))
            if fit is not None:
                flag |= BallFlag.CRESCENT
                arc = (fit, True, False)
        rows.append((np.array([ex, ey]), semi_major, ell, area, hull_area, flag, ci, arc))
    if crescents and faint_crescents:
        kept = [s_[1] for s_ in sil]
        for arc in thin_arcs(faint_mask(img, background), 2, kept, image_size=(W, H),
                             min_radius=max(3.0, float(np.sqrt(min_area / np.pi)))):
            cx, cy, r = float(arc["center"][0]), float(arc["center"][1]), float(arc["radius"])
            if max_area is not None and np.pi * r * r > 4 * max_area:
                continue
            # a piece of a ball already found (a horn the opening cut off a thicker crescent)
            if any(np.hypot(r_[0][0] - cx, r_[0][1] - cy) < r for r_ in rows):
                continue
            f = BallFlag.CRESCENT | BallFlag.PARTIAL
            px = arc["pixels"]
            if px[:, 0].min() <= 0 or px[:, 1].min() <= 0 or px[:, 0].max() >= W - 1 or px[:, 1].max() >= H - 1:
                f |= BallFlag.EDGE
            # no silhouette: its "ellipse" is the fitted circle. Its limb's place is uncertain
            # by more than the blur (``thin=True``: arc_center_sigma's thin-rim offset)
            rows.append((np.array([cx, cy]), r, ((cx, cy), (2 * r, 2 * r), 0.0), float(len(px)),
                         float(len(px)), f, -1, (arc, True, True)))
    if not rows:
        return BallDetections.empty(mask)
    rows.sort(key=lambda r: (r[0][0], r[0][1]))
    ellipse_centers = np.array([r[0] for r in rows], float)
    centers = ellipse_centers.copy()
    arc_radii = np.full(len(rows), np.nan)
    sigma = np.full(len(rows), np.nan)
    arc_points = [None] * len(rows)
    for i, r in enumerate(rows):
        if r[7] is not None:
            fit, radius_known, thin = r[7]
            centers[i] = fit["center"]
            arc_radii[i] = fit["radius"]
            sigma[i] = arc_center_sigma(fit["points"], fit["center"], fit["rms"], blur_px, radius_known=radius_known,
                                        thin=thin)
            if r[5] & (BallFlag.EDGE | BallFlag.SPLIT):
                arc_points[i] = np.asarray(fit["points"], float)
    ellipses = np.array([[r[2][0][0], r[2][0][1], r[2][1][0], r[2][1][1], r[2][2]] for r in rows], float)
    return BallDetections(
        centers=centers, ellipse_centers=ellipse_centers, radii_px=np.array([r[1] for r in rows], float),
        ellipses=ellipses, areas=np.array([r[3] for r in rows], float),
        hull_areas=np.array([r[4] for r in rows], float), scores=np.full(len(rows), np.nan),
        flags=np.array([int(r[5]) for r in rows], int), contour_index=np.array([r[6] for r in rows], int),
        mask=mask, center_sigma_px=sigma, arc_radii_px=arc_radii, arc_points=arc_points)
