"""Step 4 of the ball detector: ball centres refined by a circular Hough transform of known
radius on the linearised photo (:func:`refine_ball_centers`)."""

from __future__ import annotations

import cv2
import numpy as np

from stillcap._checks import as_array
from stillcap.detect.ball._arcs import REFINE_SMOOTH_PX
from stillcap.detect.ball._foreground import _check_image
from stillcap.detect.ball._hough import (_gradient, _grid_peak, _percentile, _quad_peak, _resample_params,
                                         _score, _template)
from stillcap.detect.ball._shading import _shading_bias
from stillcap.detect.ball._types import BallFlag, RefinedCenters
from stillcap.response import Response


def _linear(a: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Pixel values (8-bit scale) -> linear radiance 0-1, float32, through the response's table
    ``lut`` (:meth:`stillcap.response.Response.to_linear_lut`; floats are interpolated)."""
    if a.dtype == np.uint8:
        return lut[a]
    c = np.clip(a.astype(np.float32), 0, 255)
    return np.interp(c, np.arange(256, dtype=np.float32), lut).astype(np.float32)


def _linear_max(a: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Brightest channel of a crop in linear radiance (``_linear(a, lut).max(axis=2)``).

    The linearisation is monotonic, so the channel maximum is taken first on the 8-bit values
    (two ``np.maximum`` on channel views: ``max(axis=2)`` over 3 channels is a slow strided
    reduction) and only the result goes through the lookup table (``cv2.LUT``): the same
    numbers, ~30x faster than converting the three channels to float first.
    """
    if a.ndim == 3:
        if a.dtype == np.uint8:
            a = np.maximum(np.maximum(a[:, :, 0], a[:, :, 1]), a[:, :, 2])
        else:
            return _linear(a, lut).max(axis=2)
    if a.dtype == np.uint8:
        return cv2.LUT(a, lut)
    return _linear(a, lut)


def _response_lut(response) -> np.ndarray:
    """The code -> radiance table of ``response`` (a Response, its rig-file form, or None = sRGB)."""
    if response is None:
        return Response.srgb().to_linear_lut()
    return Response.from_json(response, "response").to_linear_lut()


def hough_template(off: np.ndarray) -> tuple:
    """The known-radius Hough's template of an outline ``off`` (M, 2), relative to the centre:
    offsets x, y, inward normals x, y and arc-length weights summing to 1, as contiguous float32
    rows (what :func:`refine_ball_centers` and the shading correction score with)."""
    nrm, wt = _template(off)
    wt = (wt / wt.sum()).astype(np.float32)
    off32, nrm32 = off.T.astype(np.float32), nrm.T.astype(np.float32)
    return (off32[0], off32[1], nrm32[0], nrm32[1], wt)


def refine_ball_centers(image, centers, radius_px, search_px=None, outlines=None, background=None,
                        response: Response | None = None, sigma: float = REFINE_SMOOTH_PX, power: float = 0.0, fine_step: float = 0.1,
                        min_score: float = 0.2, min_edge: float = 0.004, start_refined: bool = False,
                        shading=False, psf_px: float = 0.5, shading_support: float = 0.7,
                        crescent=None, shading_start=None) -> RefinedCenters:
    """Refine ball centres by a circular Hough transform of known radius (step 4).

    The radius is known, so the Hough space is 2D: the centre. Every candidate centre within
    ``search_px`` of the start is scored by the brightness gradient (linearised, smoothed by
    ``sigma``) that crosses the known outline *inward*: ``sum_k w_k max(0, n_k . g(c + p_k))``
    over outline points ``p_k`` with inward normals ``n_k`` and arc-length weights ``w_k``
    (gradient-direction voting: an edge votes for the centres that lie along its gradient; an
    outward gradient, e.g. the rim of a bright neighbour, votes for none). Only the lit limb of
    a half moon has such edges and it lies exactly on the known circle, so its centre comes out
    right while its ellipse centre is pulled towards the light. Search: a 2 px grid over the
    window (on a gradient smoothed to 2 px), 0.5 px and ``fine_step`` grids that follow the
    peak, then a parabola through the peak for the sub-pixel centre.

    Written by hand rather than with ``skimage.transform.hough_circle``: that votes with a
    binary edge map into integer centres, while here the vote is gradient-weighted and
    direction-aware (what makes half moons work), the template may be the exact projected
    outline (an ellipse through the lens distortion, not only a circle), and only a small
    window is evaluated (``cv2.remap`` samples the gradient at all candidate outlines at once).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W)
        The photo the centres were found in (BGR, 8-bit scale).
    centers : array_like, shape (N, 2)
        Start centres (e.g. ellipse centres), raw pixels.
    radius_px : array_like, shape (N,) or scalar
        Known radius of each ball image in pixels (ignored where ``outlines`` is given).
    search_px : array_like, shape (N,) or scalar, optional
        Half size of the square search window. Default ``0.6 * radius`` (at least 3 px): a half
        moon's ellipse centre is ~0.4 r off.
    outlines : array_like, shape (N, M, 2), optional
        Exact outline offsets relative to the centre (e.g. from :func:`sphere_outline_px`,
        ``outlines_px - centers_px[:, None]``), used instead of circles.
    background : ndarray like ``image``, optional
        Photo of the empty scene, subtracted first.
    response : Response, optional
        The camera's response (:class:`stillcap.response.Response`; default sRGB): pixel values
        are linearised through it before the gradient. In gamma-encoded values a blurred edge
        is asymmetric and its gradient peak lies outside the true limb (by ~0.3-0.6 px for a
        0.6 px blur), which the lit half of a half moon turns into a centre bias of the same
        size; in linear values it does not. A wrong response biases the centres the same way
        (``docs/camera-response.md``): pass the camera's own (``Camera.response``).
    sigma : float
        Gaussian smoothing (px) before the gradient.
    power : float
        Extra direction selectivity: each vote is multiplied by ``cos(angle)^power`` between
        gradient and normal (0: the plain inward component; on drawn balls 0 was best).
    fine_step : float
        Step of the sub-pixel grid (px).
    min_score : float
        Minimum share of the outline with a clear inward edge; below it the refinement fails.
    min_edge : float
        An edge is clear if its inward gradient (linear radiance, full scale 1, per pixel) is at
        least a quarter of the outline's 90th percentile and at least ``min_edge``: a ball's limb
        has ~0.05-0.5, the linearised noise of a dark room ~0.001.
    start_refined : bool
        The start centres are refined ones (e.g. a later round of :func:`ball_centers_stereo`):
        skip the 2 px grid, whose job is to find the peak's basin from a start up to 0.6 r off,
        and search with the 0.5 px grid that follows the peak (up to 6 px) directly.
    shading : bool or array_like of bool, shape (N,)
        (Default off.) ``True``: correct partly lit balls (less than ``shading_support`` of the
        outline with an edge); an array: correct exactly those balls. Corrects for their shading (:func:`_shading_bias`): the limb of a
        lambertian sphere lit from the side or behind is a thin bright rim whose blurred edge
        peaks outside the limb, which puts the Hough centre up to ~0.2 px toward the light
        (0.12 px on average on the studio pitches' back pair, 0.002 px after). The phase angle
        comes from the ball image's radiance centroid; the model is orthographic (a ball far
        from the camera compared with its size).
    psf_px : float
        Lens blur (Gaussian sigma, px) of the photo, for the shading model.
    shading_support : float
        The correction is made where less than this share of the outline has a clear edge
        (a partly lit ball; fully lit balls, 0.77-1.0 on the studio pitches' front pair, have no
        measurable bias, 0.02 px, and the orthographic model does not hold for near ones).
    crescent : array_like of bool, shape (N,), optional
        Which balls are crescents (the detector's ``CRESCENT``): their shading correction reads
        the light from a noise-robust centroid (:func:`_shading_bias`' ``thin_rim``).
    shading_start : array_like, shape (N, 2), optional
        Each ball's corrected centre (raw px) from an earlier correction at a slightly different
        ``psf_px`` (:func:`stillcap.ball.stereo.ball_centers_stereo`'s blur read): the corrected
        centre's search starts there (:func:`_shading_bias`' ``start``); the same centre to the
        search's tolerance.

    Returns
    -------
    RefinedCenters
    """
    img = _check_image(image)
    lut = _response_lut(response)
    c0 = as_array(centers, (None, 2), "centers")
    n = len(c0)
    if outlines is not None:
        outl = np.asarray(outlines, float)
        if outl.ndim != 3 or outl.shape[0] != n or outl.shape[2] != 2 or outl.shape[1] < 8:
            raise ValueError(f"outlines must have shape ({n}, M, 2) with M >= 8, got {outl.shape}")
        radii = np.linalg.norm(outl, axis=2).mean(axis=1)
        # every outline's length at once (the per-ball resampling below needs it)
        closed_all = np.concatenate([outl, outl[:, :1]], axis=1)
        finite = np.all(np.isfinite(outl), axis=(1, 2))
        with np.errstate(invalid="ignore"):
            lengths = np.sum(np.linalg.norm(np.diff(closed_all, axis=1), axis=2), axis=1)
    else:
        r = np.asarray(radius_px, float)
        radii = np.broadcast_to(r, (n,)).astype(float) if r.ndim == 0 else as_array(r, (n,), "radius_px")
        outl = None
    if search_px is None:
        search = np.maximum(3.0, 0.6 * radii)
    else:
        s = np.asarray(search_px, float)
        search = np.broadcast_to(s, (n,)).astype(float) if s.ndim == 0 else as_array(s, (n,), "search_px")
    if background is not None:
        bg = _check_image(background, "background")
        if bg.shape != img.shape:
            raise ValueError(f"background must have the image's shape {img.shape}, got {bg.shape}")
    shade = None if np.ndim(shading) == 0 else as_array(np.asarray(shading, float), (n,), "shading") > 0
    thin = np.zeros(n, bool) if crescent is None else as_array(np.asarray(crescent, float), (n,), "crescent") > 0
    out_c = c0.copy()
    scores = np.zeros(n)
    flags = np.zeros(n, int)
    corr = np.zeros((n, 2))
    phase = np.full((n, 2), np.nan)  # the shading correction's phase angle and its sigma (rad)
    misfit = np.full((n, 2), np.nan)  # and the shift its model's misfit to the photo asks for (px)
    H, W = img.shape[:2]
    for i in range(n):
        r = radii[i]
        if not (np.isfinite(c0[i]).all() and np.isfinite(r) and r > 1.0 and np.isfinite(search[i])):
            flags[i] = BallFlag.REFINE_FAILED
            scores[i] = np.nan
            continue
        if outl is None:
            m = max(24, int(np.ceil(2 * np.pi * r)))
            th = np.linspace(0, 2 * np.pi, m, endpoint=False)
            off = r * np.stack([np.cos(th), np.sin(th)], axis=1)
        else:
            off = outl[i]
            if not finite[i]:
                flags[i] = BallFlag.REFINE_FAILED
                scores[i] = np.nan
                continue
            # resample to ~1 point per pixel of outline
            m = max(24, int(np.ceil(lengths[i])))
            if m != len(off):
                t_old, t_new = _resample_params(len(off), m)
                closed = closed_all[i]
                off = np.stack([np.interp(t_new, t_old, closed[:, 0]), np.interp(t_new, t_old, closed[:, 1])], 1)
        tpl = hough_template(off)
        s = float(search[i])
        ext = float(np.abs(off).max()) + s + 3.0 * sigma + 3.0
        x0, y0 = int(np.floor(c0[i, 0] - ext)), int(np.floor(c0[i, 1] - ext))
        x1, y1 = int(np.ceil(c0[i, 0] + ext)) + 1, int(np.ceil(c0[i, 1] + ext)) + 1
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if xb - xa < 3 or yb - ya < 3:
            flags[i] = BallFlag.REFINE_FAILED
            scores[i] = np.nan
            continue
        if background is not None:
            crop = np.abs(_linear(img[ya:yb, xa:xb], lut) - _linear(bg[ya:yb, xa:xb], lut))
            if crop.ndim == 3:
                crop = crop.max(axis=2)
        else:
            crop = _linear_max(img[ya:yb, xa:xb], lut)
        lin = crop
        if sigma > 0:
            crop = cv2.GaussianBlur(crop, (0, 0), sigma)
        g2 = _gradient(crop)
        cx, cy = c0[i, 0] - xa, c0[i, 1] - ya
        # Coarse to fine: a 2 px grid over the search window on a more smoothed gradient with
        # every 2nd outline point (its peak is wide enough not to fall between grid points),
        # then 0.5 px and ``fine_step`` grids that move with the peak, then a parabola.
        k = int(np.ceil(s / 2.0))
        if k >= 2 and not start_refined:
            extra = np.sqrt(max(2.0 ** 2 - sigma ** 2, 0.0))
            g2c = _gradient(cv2.GaussianBlur(crop, (0, 0), extra)) if extra > 0.1 else g2
            wc = tpl[4][::2] / tpl[4][::2].sum()
            coarse = (tpl[0][::2], tpl[1][::2], tpl[2][::2], tpl[3][::2], wc.astype(np.float32))
            bx, by, _, _ = _grid_peak(g2c, cx, cy, coarse, power, 2.0, k, moves=0)
            bx, by, _, _ = _grid_peak(g2, bx, by, tpl, power, 0.5, 3, moves=3)
        elif k >= 2:
            # a start that is already a refined centre: no basin to find, the 0.5 px grid that
            # follows the peak (up to 6 px) replaces the coarse grid and its smoothed gradient
            bx, by, _, _ = _grid_peak(g2, cx, cy, tpl, power, 0.5, 3, moves=3)
        else:
            bx, by, _, _ = _grid_peak(g2, cx, cy, tpl, power, 0.5, max(2, int(np.ceil(2 * s))), moves=1)
        kf = max(2, int(round(0.3 / fine_step)))
        bx, by, fs, (fi, fj) = _grid_peak(g2, bx, by, tpl, power, fine_step, kf, moves=3)
        ddy, ddx = _quad_peak(fs, fi, fj)
        best = np.array([bx + ddx * fine_step, by + ddy * fine_step])
        # support: share of the outline (by length) with a clear inward edge at the best centre
        _, gn = _score(g2, np.array([best[0]], np.float32), np.array([best[1]], np.float32),
                       *tpl, power)
        gmax = _percentile(gn, 90.0)
        support = float(tpl[4] @ (gn[0] > max(0.25 * gmax, min_edge)))
        scores[i] = support
        outside = np.hypot(best[0] - cx, best[1] - cy) > s * np.sqrt(2) + 1.0
        if outside or support < min_score or fs.max() <= 0:
            flags[i] = BallFlag.REFINE_FAILED
            continue
        if shade[i] if shade is not None else (shading and support < shading_support):
            rep = {}
            st = None if shading_start is None else np.asarray(shading_start[i], float) - (xa, ya)
            corr[i] = _shading_bias(lin, best, off, tpl, power, np.hypot(sigma, psf_px), fine_step, smooth=sigma,
                                    thin_rim=bool(thin[i]), start=st, report=rep)
            phase[i] = rep.get("phase_rad", np.nan), rep.get("phase_sd_rad", np.nan)
            misfit[i] = rep.get("misfit_shift_px", np.nan)
            best = best - corr[i]
        out_c[i] = best + (xa, ya)
    return RefinedCenters(out_c, radii.copy(), scores, out_c - c0, flags, corr, phase[:, 0].copy(), phase[:, 1].copy(),
                          misfit)
