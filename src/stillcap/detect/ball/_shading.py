"""Step 4b of the ball detector: the shading bias of a partly lit ball, from a lambertian
sphere model (lit-sphere images, the radiance-centroid table, the model's Hough peak)."""

from __future__ import annotations

import functools
from typing import NamedTuple

import cv2
import numpy as np

from stillcap._numeric import median
from stillcap.detect import _small_linalg
from stillcap.detect.ball._arcs import REFINE_SMOOTH_PX
from stillcap.detect.ball._hough import _gradient, _grid_peak, _quad_peak


# --------------------------------------------------------------------------------------------
# step 4b: shading bias of a partly lit ball (lambertian sphere model)
# --------------------------------------------------------------------------------------------
def _outline_affine(off: np.ndarray) -> np.ndarray:
    """Symmetric 2x2 ``A`` with ``off ~ A [cos t, sin t]``: the ellipse of an outline (M, 2)
    sampled about uniformly around its centre (its second moment is ``A A^T / 2``)."""
    ev, V = _small_linalg.eigh(2.0 * (off.T @ off) / len(off))
    return (V * np.sqrt(np.maximum(ev, 1e-12))) @ V.T


def _lit_sphere_image(shape, center, A: np.ndarray, light, ss: int = 3, band_px: float | None = None,
                      q=None) -> np.ndarray:
    """Radiance (unit albedo) of a lambertian sphere lit from the direction ``light``
    (unit 3-vector in the frame (x right, y down, z toward the camera)), seen orthographically
    through the outline ellipse ``A`` centred on ``centre`` (crop pixels), each pixel the mean
    of ``ss x ss`` samples; float32 image of ``shape``.

    ``band_px``: supersample only the pixels within about ``band_px`` of the limb (inside) and
    the limb's own pixels; the rest get one sample at their centre (pixels well outside the
    outline are 0 either way; inside it the radiance is smooth, and a pixel farther than the
    blur kernel's reach from the limb does not change the limb's gradient). ``q``: the
    outline-normalised coordinates ``A^-1 (pixel - centre)`` of the pixel centres, shape
    (2, H, W), if the caller has them.
    """
    h, w = shape
    o = (np.arange(ss) + 0.5) / ss - 0.5
    Ai = _small_linalg.inv(np.asarray(A, float))
    lx, ly, lz = light

    def rad_of(qx, qy, r2=None):
        if r2 is None:
            r2 = qx * qx + qy * qy
        qz = np.sqrt(np.maximum(1.0 - r2, 0.0))  # np.clip(., 0, None), without its overhead
        return np.where(r2 < 1.0, np.maximum(qx * lx + qy * ly + qz * lz, 0.0), 0.0)

    if band_px is None:
        ys = (np.arange(h)[:, None] + o[None, :]).ravel() - center[1]
        xs = (np.arange(w)[:, None] + o[None, :]).ravel() - center[0]
        qx = Ai[0, 0] * xs[None, :] + Ai[0, 1] * ys[:, None]
        qy = Ai[1, 0] * xs[None, :] + Ai[1, 1] * ys[:, None]
        return rad_of(qx, qy).reshape(h, ss, w, ss).mean(axis=(1, 3)).astype(np.float32)
    return _render_sphere(_sphere_normals(shape, center, A, band_px, q, ss), light)


#: error (of the unit radiance) up to which one sample at a pixel's centre stands for the pixel's
#: mean radiance in the lit-sphere model (:func:`supersample_depth_px`): a quarter of one 8-bit
#: code step at the top of the linear scale
SUPERSAMPLE_ERROR = 1e-3


def supersample_depth_px(radius_px: float) -> float:
    """Depth inside the limb (px) beyond which the lit-sphere model's radiance needs no
    supersampling: one sample at a pixel's centre differs from the pixel's mean by less than
    ``SUPERSAMPLE_ERROR`` (of the unit radiance) for any light.

    A pixel's mean of a smooth radiance ``f`` is ``f + (f_xx + f_yy) / 24`` at its centre (a
    uniform square of 1 px: variance 1/12 a side). ``n_x``, ``n_y`` of the lambertian sphere's
    normal are linear in the pixel coordinates; ``n_z = sqrt(1 - (R / r)^2)`` (``R`` px from the
    centre of a limb of ``r`` px) bends fastest at the limb, its Laplacian ``n_z'' + n_z' / R``
    growing as ``d^-1.5`` at a depth ``d = r - R`` (``n_z ~ sqrt(2 d / r)``). The depth returned is
    the least (on a 0.05 px grid) where ``|Laplacian| / 24 <= SUPERSAMPLE_ERROR``: the whole ball
    up to ~9 px (its middle already bends more), 4.4 px on a 12 px ball, 2.2 on a 30 px one. Use
    the outline's smallest semi-axis for ``radius_px``.

    Not covered: the terminator's kink inside a disc lit from the side or behind, which a pixel
    straddles with an error up to ~1/(8 r) of the radiance. :func:`limb_blur_px` fits the limb's
    whole profile, which that moves by at most 1e-4 px (drawn balls of 6-20 px, 0.5-1.5 px of blur,
    45-130 deg) and 7.5e-4 px (132 limb reads of the ``bench_speed.py`` pitch and a studio pitch);
    :func:`_shading_bias` keeps its band of the blur's reach (``4 blur + 4`` px), which covers the
    kink of small balls: with a depth of ~2-3 px there (an earlier, looser form of this one), two
    searches of the same 8 px crescents under 1.5 px of blur from different starts landed 0.11 px
    apart (0.03 px with the blur's reach)."""
    r = float(radius_px)
    if not np.isfinite(r):
        return float("inf")  # no size to go by: the whole ball
    return _supersample_depth(int(round(10.0 * max(r, 1.0))))


@functools.lru_cache(maxsize=1024)
def _supersample_depth(r_tenths: int) -> float:
    """:func:`supersample_depth_px` of a radius in tenths of a pixel (cached)."""
    r = r_tenths / 10.0
    d = np.arange(0.05, r, 0.05)
    d = d[d < r - 1e-6]  # (arange's last step can land on r itself: R = 0 divides 0 by 0 below)
    R = r - d
    u = 1.0 - (R / r) ** 2
    n1 = -(R / (r * r)) / np.sqrt(u)  # d n_z / dR
    n2 = -1.0 / (r * r * np.sqrt(u)) - (R / (r * r)) ** 2 / u ** 1.5  # d2 n_z / dR2
    ok = np.abs(n2 + n1 / R) / 24.0 <= SUPERSAMPLE_ERROR
    return float(d[np.argmax(ok)]) if ok.any() else float("inf")  # the whole ball


def _sphere_normals(shape, center, A: np.ndarray, band_px: float, q=None, ss: int = 3, r2=None, geom=None):
    """The light-independent part of :func:`_lit_sphere_image`'s band path (``band_px`` given):
    the sphere's normals at the pixel centres and at the band pixels' ``ss x ss`` samples, with
    their masks, for :func:`_render_sphere`. The phase searches of :func:`_shading_bias` render
    the same outline in the same crop at several lights: its geometry (most of a render's time)
    is computed once (the same numbers as computing it each time). ``r2``: ``q[0]**2 + q[1]**2``
    if the caller has it; ``geom``: :func:`_outline_geometry` of the outline ``A`` is of, if the
    caller has it.

    The band's samples are stored sample-major, shape ``(ss * ss, n_band)`` (sample ``iy * ss +
    ix`` of each band pixel in a row), so :func:`_render_sphere` averages a pixel's samples with
    whole-row additions rather than a strided reduction over 9 values (the same numbers)."""
    h, w = shape
    o = (np.arange(ss) + 0.5) / ss - 0.5
    if geom is None:
        Ai = _small_linalg.inv(np.asarray(A, float))
        sv = _small_linalg.svdvals(np.asarray(A, float))  # the outline's semi-axes (px)
    else:
        Ai, sv = geom.Ai, geom.sv
    if q is None:
        yy, xx = np.mgrid[0:h, 0:w]
        q = np.einsum("ij,jhw->ihw", Ai, np.stack([xx - center[0], yy - center[1]]).astype(float))
    if r2 is None:
        r2 = q[0] ** 2 + q[1] ** 2
    # a pixel within band_px of the limb lies beyond 1 - band / (largest semi-axis) in these
    # coordinates (and one more pixel of margin); a pixel whose samples (at most
    # sqrt(2) (0.5 - 0.5 / ss) px from its centre, 0.47 px for ss = 3) are all outside the outline
    # lies beyond 1 + that / (smallest semi-axis): A^-1 stretches no offset more than that. Such
    # pixels are 0 (the margin of 1 px this had put ~13 % of the band's pixels, all 0, in the
    # band: rendered, 9 samples each, at every light)
    r_in = max(1.0 - (band_px + 1.0) / sv[0], 0.0)
    r_out = 1.0 + (np.sqrt(2.0) * (0.5 - 0.5 / ss) + 0.01) / sv[-1]
    band = (r2 > r_in * r_in) & (r2 < r_out * r_out)
    # the pixels inside the outline and off the band: one sample at their centre (the rest of
    # the crop is 0); flat indices and their coordinates, rendered as a 1-D array
    core = np.flatnonzero((r2 < 1.0) & ~band)
    cx, cy, cr2 = q[0].ravel()[core], q[1].ravel()[core], r2.ravel()[core]
    cz = np.sqrt(np.maximum(1.0 - cr2, 0.0))  # np.clip(., 0, None), without its overhead
    band = np.flatnonzero(band)
    qxb, qyb = q[0].ravel()[band], q[1].ravel()[band]
    samples = None
    if len(qxb):
        # the samples of pixel (y, x): its centre's coordinates plus A^-1 (o_j, o_i)
        dqx = Ai[0, 0] * o[None, :] + Ai[0, 1] * o[:, None]  # (ss_y, ss_x)
        dqy = Ai[1, 0] * o[None, :] + Ai[1, 1] * o[:, None]
        sx = dqx.reshape(-1, 1) + qxb[None, :]  # (ss * ss, n_band), sample-major
        sy = dqy.reshape(-1, 1) + qyb[None, :]
        r2s = sx * sx
        r2s += sy * sy
        sz = np.subtract(1.0, r2s)
        np.sqrt(np.maximum(sz, 0.0, out=sz), out=sz)
        samples = (sx, sy, sz, ~(r2s < 1.0))
    return (h, w), (core, cx, cy, cz), band, samples


def _render_sphere(normals, light) -> np.ndarray:
    """:func:`_lit_sphere_image` (band path) at ``light`` from :func:`_sphere_normals`' geometry:
    the same operations in the same order on the same numbers (bit-identical)."""
    shape, (core, cx, cy, cz), band, samples = normals
    lx, ly, lz = light
    # float32 throughout: each float64 value is rounded once on assignment, as astype rounds it
    out = np.zeros(shape[0] * shape[1], np.float32)
    out[core] = np.maximum(cx * lx + cy * ly + cz * lz, 0.0)
    if samples is not None:
        sx, sy, sz, outside = samples
        v = sx * lx
        v += sy * ly
        v += sz * lz
        np.maximum(v, 0.0, out=v)
        np.putmask(v, outside, 0.0)
        out[band] = _sample_mean(v)
    return out.reshape(shape)


def _sample_mean(v: np.ndarray) -> np.ndarray:
    """The mean over the samples (rows) of a sample-major ``v`` (n_samples, n_pixels), the same
    numbers as ``v.T.mean(axis=1)`` on the pixel-major array: for 9 samples, NumPy's pairwise sum
    of 9 contiguous values (eight partial sums paired, then the ninth) written out as row
    additions (~7x faster than the strided reduction); other counts take NumPy's own."""
    if len(v) != 9:
        return np.ascontiguousarray(v.T).mean(axis=1)
    s = v[0] + v[1]
    t = v[2] + v[3]
    s += t
    t = np.add(v[4], v[5], out=t)
    u = v[6] + v[7]
    t += u
    s += t
    s += v[8]
    s /= 9
    return s


@functools.lru_cache(maxsize=1)
def _centroid_table() -> tuple[np.ndarray, np.ndarray]:
    """Phase angle (rad) -> distance of the radiance centroid of a lambertian sphere from its
    centre, in radii (orthographic; 0 for a full disc, -> 1 as the lit crescent thins).
    Tabulated once on a 1 % grid of the disc."""
    q = (np.arange(200) + 0.5) / 100.0 - 1.0
    qx, qy = np.meshgrid(q, q)
    r2 = qx * qx + qy * qy
    outside = ~(r2 < 1.0)
    qz = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    alpha = np.radians(np.arange(0.0, 176.0, 1.0))
    m = np.empty_like(alpha)
    # each phase's radiance ``np.where(inside, max(qx sin a + qz cos a, 0), 0)`` written into two
    # buffers made once: the same operations on the same numbers (the table's bits), ~2-3x faster
    # (it is built once per process: the CLI's first run pays it; speed only, issue 16)
    rad, tmp = np.empty_like(qx), np.empty_like(qx)
    for k, a in enumerate(alpha):
        np.multiply(qx, np.sin(a), out=rad)
        rad += np.multiply(qz, np.cos(a), out=tmp)
        np.maximum(rad, 0.0, out=rad)
        np.putmask(rad, outside, 0.0)
        m[k] = np.sum(np.multiply(rad, qx, out=tmp)) / np.sum(rad)
    return alpha, np.maximum.accumulate(m)


def _phase_from_centroid(m: float) -> float:
    """Phase angle (rad) whose lambertian radiance centroid lies ``m`` radii off the centre."""
    alpha, table = _centroid_table()
    return float(np.interp(m, table, alpha))


class _OutlineGeometry(NamedTuple):
    """What :func:`_lit_frame` and :func:`_sphere_normals` derive from a ball image's outline
    alone: its points' mean offset from the centre, its ellipse ``A``, ``A``'s inverse and its
    singular values (the semi-axes). The same outline is framed about several centres in one
    :func:`_shading_bias`: computed once (the same numbers)."""
    mean: np.ndarray
    A: np.ndarray
    Ai: np.ndarray
    sv: np.ndarray


def _outline_geometry(off: np.ndarray) -> _OutlineGeometry:
    """:class:`_OutlineGeometry` of the outline offsets ``off`` (M, 2)."""
    mean = off.mean(axis=0)
    A = _outline_affine(off - mean)
    return _OutlineGeometry(mean, A, _small_linalg.inv(A), _small_linalg.svdvals(np.asarray(A, float)))


def _lit_frame(lin: np.ndarray, center, off: np.ndarray, signed: bool = False, more: dict | None = None,
               geom: _OutlineGeometry | None = None):
    """The outline's middle, its ellipse ``A``, the outline-normalised coordinates ``q`` (2, H, W)
    of the crop's pixels and the light direction read from the ball image's radiance centroid
    (:func:`_shading_bias`; None when the image has no radiance above its surroundings;
    ``signed``: :func:`_radiance_centroid`'s). ``more``: a dict given the centroid's window
    (``"win"``, :func:`_centroid_window`) and the centroid itself (``"mq"``), for its callers to
    reuse; ``geom``: :func:`_outline_geometry` of ``off``, if the caller has it."""
    # the outline's own middle: off axis the image of the sphere centre is not the middle of
    # its (elongated) outline; the shading is modelled about the middle, orthographically
    if geom is None:
        geom = _outline_geometry(off)
    mid = center + geom.mean
    A, Ai = geom.A, geom.Ai
    h, w = lin.shape
    xy = np.empty((2, h, w))
    xy[0] = np.arange(w) - mid[0]
    xy[1] = (np.arange(h) - mid[1])[:, None]
    q = np.einsum("ij,jhw->ihw", Ai, xy)
    win = _centroid_window(q)
    mq = _radiance_centroid(lin, q, signed, win)
    if more is not None:
        more.update(win=win, mq=mq)
    if mq is None:
        return mid, A, q, None
    mn = float(np.hypot(*mq))
    if not np.isfinite(mn) or mn < 1e-6:
        return mid, A, q, None
    a = _phase_from_centroid(mn)
    return mid, A, q, (np.sin(a) * mq[0] / mn, np.sin(a) * mq[1] / mn, np.cos(a))


def _shading_bias(lin: np.ndarray, center: np.ndarray, off: np.ndarray, tpl, power: float,
                  blur: float, fine_step: float, smooth: float = REFINE_SMOOTH_PX, thin_rim: bool = False,
                  start=None, report: dict | None = None) -> np.ndarray:
    """Offset (2,) of the Hough peak from the true centre for the shading of this ball image.

    The limb of a lambertian sphere is not a plain step: just inside it the radiance changes
    fast (``n . l`` with ``n_z = sqrt(1 - rho^2)``), falling toward the limb when the ball is
    lit from the front and rising when lit from behind (a half moon's thin bright rim). Blurred,
    that moves the lit limb's gradient peak in or out by a fraction of a pixel, and the Hough
    centre with it along the lit direction (noise-free model: -0.1 px at a 45 deg phase angle,
    +0.1 px at 90 deg, +0.25 px at 110 deg for a 20 px ball). The phase angle is read from the
    image: the radiance centroid of the ball lies a known distance from the centre for each
    phase angle (:func:`_centroid_table`), toward the light; measured over a window, blur pulls
    it toward the middle, so the phase is the one whose lens-blurred model has the photo's
    windowed centroid (:func:`_blurred_phase_light`). The model ball lit so is rendered at the
    centre, blurred like the photo (``blur``: lens PSF and the refinement's own smoothing), and
    the same Hough run on it gives the offset. The light is read in the frame of the corrected
    centre (``c = center - bias(c)``, secant steps): read about the uncorrected Hough centre,
    which sits toward the light by the bias itself, the phase came out far too small on small
    half-lit balls under heavy blur (``docs/ball-detection.md``, "Blurred phase").

    A ball image with clipped pixels (at least ``MIN_SATURATED_PX`` at the top code, the
    brightest channel, within the outline) is modelled as the sensor made it
    (:func:`_clipped_model`): the model blurred by the lens alone (``blur`` less the
    refinement's smoothing ``smooth``, ``refine_ball_centers``' ``sigma``), scaled to the photo,
    clipped, then smoothed. A flattened lit side has a hard edge and moves the Hough centre toward
    the light (studio pitch, light beside the back cameras: 0.24 px at 1280 px) which the
    unclipped model did not predict.

    ``thin_rim``: a crescent (the detector's ``CRESCENT``: a ball lit from behind, a rim a few
    pixels wide, often a few noise sigmas above the room). Its centroid is read with signed
    weights about the ring's mean (:func:`_radiance_centroid`'s ``signed``): the noise of the
    dark disc, rectified, pulled the centroid toward the middle and the phase read from it far
    too low (faint crescents at 150-165 deg read as 80-100 deg; the correction then left
    0.8-1.0 px of the ~1 px bias toward the light, 0.3-0.4 px with signed weights:
    ``benchmarks/bench_ball_detect.py --only-missed``).

    ``start``: a centre (crop px) near the corrected one, such as this ball's corrected centre at
    a slightly different ``blur`` (:func:`stillcap.ball.stereo.photo_blur_px`' next round): the
    corrected centre's first secant step goes there (its projection on the bias's direction)
    instead of to ``center - bias``; the steps after it and the tolerance are the same.

    ``report``: a dict given the phase angle the correction used (``"phase_rad"``, in the frame of
    the returned bias), that phase's split-half uncertainty (``"phase_sd_rad"``,
    :func:`_phase_split_sd`) and the shift the model's misfit to the photo asks for
    (``"misfit_shift_px"``, :func:`_misfit_shift`; not for clipped balls), for the uncertainty of the correction
    (:func:`stillcap.ball.uncertainty.remaining_bias_modes`); left empty when no light was read.
    """
    more0 = {}
    geom = _outline_geometry(off)
    mid, A, q, light = _lit_frame(lin, center, off, thin_rim, more0, geom)
    if light is None:
        return np.zeros(2)
    # supersampled near the limb only: beyond the blur kernel (cv2's reaches 4 sigma), the Sobel
    # and the Hough's search around the centre from the limb, a pixel cannot change the result
    band = 4.0 * blur + 4.0
    r2 = q[0] ** 2 + q[1] ** 2
    n_sat = int(np.count_nonzero((lin >= SATURATED) & (r2 < 1.15 ** 2)))
    if n_sat >= MIN_SATURATED_PX:
        # a clipped ball's bias (up to ~1 px on a 20 px ball) moves the frame the light is read
        # in: the centroid's offset from a centre that far toward the light reads a phase too
        # small; the frame follows the corrected centre (a fixed point, at most 5 rounds)
        kf = max(2, int(round(0.3 / fine_step)))
        bias, c = None, np.asarray(center, float)
        for _ in range(5):
            mid_c, A_c, q_c, light_c = _lit_frame(lin, c, off, geom=geom)
            if light_c is None:
                break
            model = _clipped_model(lin, mid_c, A_c, q_c, light_c, blur, smooth, band, geom=geom)
            if model is None:
                break
            bias = np.array(_model_peak(model, c, tpl, power, fine_step, kf)) - c
            if report is not None:
                report.update(_phase_report(lin, q_c, None, light_c, False))
            c_new = np.asarray(center, float) - bias
            if np.hypot(*(c_new - c)) < 0.005:
                break
            c = c_new
        if bias is not None:
            return bias
    # the frame the light is read in follows the corrected centre here too: the uncorrected
    # Hough centre of a small half-lit ball under heavy blur sits up to a tenth of a radius
    # toward the light, and the centroid's offset from it then reads a phase far too small
    # (drawn 8 px balls, 1.5 px blur: 90 deg read as 71, 130 as 88). The corrected centre ``c``
    # solves ``c = center - bias(c)``; plain fixed-point steps crawl (the bias grows with the
    # phase the frame reads), so secant steps along the first bias's direction
    psf = float(np.sqrt(max(blur * blur - smooth * smooth, 0.0)))
    kf = max(2, int(round(0.3 / fine_step)))
    center = np.asarray(center, float)
    warm = {}  # the phase search's last phase and slope, from one frame to the next

    def bias_at(c, frame=None, more=None):
        more = {} if more is None else more
        mid_c, A_c, q_c, light_c = _lit_frame(lin, c, off, thin_rim, more, geom) if frame is None else frame
        if light_c is None:
            return None
        win = more.get("win") or _centroid_window(q_c)
        render = _renderer(lin.shape, mid_c, A_c, band, q_c, win[2], geom)
        light_c = _blurred_phase_light(lin, mid_c, A_c, q_c, light_c, psf, band, thin_rim, render=render,
                                       warm=warm, win=win, mq=more.get("mq"))
        more.update(q=q_c, win=win, light=light_c, slope=warm.get("slope", float("nan")), render=render)
        model = cv2.GaussianBlur(render(light_c), (0, 0), blur)
        return np.array(_model_peak(model, c, tpl, power, fine_step, kf)) - c

    bias = bias_at(center, (mid, A, q, light), more0)
    size = float(np.hypot(*bias))
    best_more = more0
    if size < 1e-6:
        _report_into(report, lin, best_more, thin_rim, psf)
        return bias
    u = bias / size
    # h(t) = t - bias(center - t u) . u, zero at the corrected centre; h(0) = -size < 0. Secant
    # steps, kept inside the bracket once one is found (bisection when a step leaves it); the
    # bias of the evaluated centre with the smallest |h| is returned
    lo, hi = (0.0, -size), None
    t_prev, h_prev, t = 0.0, -size, size
    if start is not None:
        t_start = float((center - np.asarray(start, float)) @ u)
        if np.isfinite(t_start) and t_start > 0.0:
            t = min(t_start, 4.0 * size + 0.2)
    best_h, best_bias = size, bias
    for _ in range(FRAME_ROUNDS):
        more_t = {}
        b = bias_at(center - t * u, more=more_t)
        if b is None:
            break
        h = t - float(b @ u)
        if abs(h) < best_h:
            best_h, best_bias, best_more = abs(h), b, more_t
        if abs(h) < 0.005:
            break
        if h < 0:
            lo = (t, h)
        else:
            hi = (t, h)
        t_new = t - h * (t - t_prev) / (h - h_prev) if h != h_prev else t + size
        if hi is not None and not (min(lo[0], hi[0]) < t_new < max(lo[0], hi[0])):
            t_new = 0.5 * (lo[0] + hi[0])
        t_prev, h_prev, t = t, h, float(np.clip(t_new, -size, 4.0 * size + 0.2))
    _report_into(report, lin, best_more, thin_rim, psf)
    return best_bias


def _report_into(report: dict | None, lin: np.ndarray, more: dict, signed: bool, psf: float = 0.0) -> None:
    """:func:`_shading_bias`' ``report`` from the frame (``more``, :func:`_shading_bias`' ``bias_at``'s)
    whose bias it returns."""
    if report is not None and "light" in more:
        report.update(_phase_report(lin, more["q"], more["win"], more["light"], signed, more.get("slope")))
        model = more["render"](more["light"])
        if psf >= 0.05:
            model = cv2.GaussianBlur(model, (0, 0), psf)
        report["misfit_shift_px"] = _misfit_shift(lin, model, more["win"][2])


def _misfit_shift(lin: np.ndarray, model: np.ndarray, r2: np.ndarray, reach: float = 1.3) -> np.ndarray:
    """The shift (px, (2,)) of the ball that a least-squares fit of the lens-blurred model
    (``model``, rendered at the corrected centre) to the photo asks for: ``lin ~ a model(x - d)
    + b`` linearised, ``model(x - d) ~ model - d . grad(model)``, over the pixels within ``reach``
    outline radii (``r2``: their squared radius). A second estimate of the centre from the same
    model, by another weighing of the pixels than the Hough's limb: with the model right both
    find the centre and ``d`` is noise; where the photo is not the model (a leather that is not
    lambertian, a second light, paint, a wrong blur or phase), the misfit moves them differently
    and ``d`` shows it. Written by hand: a 4-parameter linear least squares on the crop, which
    no image-registration routine does over an outline's window. NaN without enough pixels."""
    sel = np.flatnonzero(r2 < reach * reach)
    if len(sel) < 12:
        return np.full(2, np.nan)
    h, w = model.shape
    row, col = np.divmod(sel, w)
    flat = model.reshape(-1)
    if row[0] >= 1 and row[-1] <= h - 2 and col.min() >= 1 and col.max() <= w - 2:
        # np.gradient's central differences at the window's pixels only (none on the crop's
        # border): the same numbers without differencing the whole crop
        f64 = np.float64
        gx = (flat[sel + 1].astype(f64) - flat[sel - 1].astype(f64)) / 2.0
        gy = (flat[sel + w].astype(f64) - flat[sel - w].astype(f64)) / 2.0
    else:
        gy, gx = (g.reshape(-1)[sel] for g in np.gradient(model.astype(np.float64)))
    J = np.stack([gx, gy, flat[sel].astype(np.float64), np.ones(len(sel))], axis=1)
    try:  # the normal equations (4 x 4): well conditioned here, ~5x cheaper than an SVD per ball
        coef = np.linalg.solve(J.T @ J, J.T @ lin.reshape(-1)[sel].astype(np.float64))
    except np.linalg.LinAlgError:
        return np.full(2, np.nan)
    if not coef[2] > 1e-9:
        return np.full(2, np.nan)
    # lin ~ a model - a d . grad(model) + b: the gradient columns' coefficients are -a d
    return -coef[:2] / coef[2]


def _phase_report(lin: np.ndarray, q, win, light, signed: bool, slope=None) -> dict:
    """The phase angle of ``light`` and its split-half sigma (:func:`_phase_split_sd`)."""
    a = float(np.arctan2(np.hypot(light[0], light[1]), light[2]))
    return {"phase_rad": a, "phase_sd_rad": _phase_split_sd(lin, q, win, light, signed, slope)}


def _phase_split_sd(lin: np.ndarray, q, win, light, signed: bool = False, slope=None) -> float:
    """1-sigma (rad) of the phase angle read from this ball image's radiance centroid, from the
    image itself: split-half.

    A lambertian sphere's shading is mirror-symmetric about its lit axis (the light's azimuth
    through the outline's middle), so the centroids along that axis of the two halves of the
    window either side of it are the same. What the photo adds to the model, whatever it is
    (painted markers and seams, a leather that is not lambertian, noise, JPEG, a second light),
    moves them apart: the centroid of the whole, their weighted mean, is off by about half their
    difference (two independent halves). Through the slope of the centroid with the phase (the
    blurred model's, from the phase search, else the sharp table's) that is the phase's sigma.
    Texture symmetric about the axis is not seen. NaN where a half has no radiance."""
    if win is None:
        win = _centroid_window(q)
    n = float(np.hypot(light[0], light[1]))
    if n < 1e-9:
        return float("nan")
    ax, ay = light[0] / n, light[1] / n
    # over the window's pixels only (its flat indices and coordinates): the pixels outside it
    # weigh 0 (the same sums but for the order of float rounding; ~2x cheaper on a crop)
    idx, ring_idx, qx, qy = win[3]
    flat = lin.reshape(-1)
    v = flat[idx]
    if signed:
        level = float(flat[ring_idx].mean()) if len(ring_idx) else 0.0
        w = v - level
    else:
        level = median(flat[ring_idx]) if len(ring_idx) else 0.0
        w = np.maximum(v - level, 0.0)
    s = qx * ax + qy * ay
    side = qy * ax - qx * ay > 0
    m = []
    for h in (side, ~side):
        tot = float(w[h].sum())
        if not tot > 0:
            return float("nan")
        m.append(float((w[h] * s[h]).sum()) / tot)
    a = float(np.arctan2(n, light[2]))
    if slope is None or not (np.isfinite(slope) and slope > 0):
        alpha, table = _centroid_table()
        slope = float(np.interp(a, alpha, np.gradient(table, alpha)))
    if not slope > 1e-3:
        return float("nan")
    return float(min(0.5 * abs(m[0] - m[1]) / slope, np.pi / 2))


def _renderer(shape, mid, A: np.ndarray, band: float, q, r2=None, geom=None):
    """``light -> _lit_sphere_image(shape, mid, A, light, band_px=band, q=q)``: the geometry
    computed once (:func:`_sphere_normals`) and the renders kept (the phase search's chosen
    light is the model's: rendered once, not twice). The images are shared: do not write to them."""
    normals = _sphere_normals(shape, mid, A, band, q, r2=r2, geom=geom)
    done = {}

    def render(light):
        key = tuple(float(v) for v in light)
        if key not in done:
            done[key] = _render_sphere(normals, key)
        return done[key]
    return render


#: secant rounds of the corrected centre in :func:`_shading_bias`
FRAME_ROUNDS = 8


def _blurred_phase_light(lin, mid, A, q, light, psf: float, band: float, signed: bool = False,
                         rounds: int = 6, render=None, warm: dict | None = None, win=None, mq=None):
    """The light direction whose lit sphere, blurred by the lens (``psf``, Gaussian sigma px),
    has the photo's radiance centroid as :func:`_lit_frame` measures it (same window, level and
    weights); its azimuth is ``light``'s, its phase angle found by secant steps from ``light``'s.

    :func:`_lit_frame` reads the phase from the sharp sphere's centroid (:func:`_centroid_table`).
    Blur does not move a whole image's centroid, but the centroid is measured over a window (the
    radiance above the ring beyond 1.3 radii, within 1.15 radii): the blur spreads the lit limb's
    light past the window and into the ring, so the measured centroid lies nearer the middle and
    the sharp table reads too small a phase. The loss grows as blur / radius and as the light
    gathers at the limb (half moons, crescents): drawn 8 px balls under 1.5 px of blur read 90 deg
    as 71 deg and 130 deg as 88 deg, and the correction then left 0.25 and 0.8 px toward the light
    (0.07 and 0.08 px with the true phase). The model measured through the same window has the
    same loss, so its phase is the light's (``docs/ball-detection.md``, "blurred phase").
    ``render``: the sharp model at a light (:func:`_renderer`'s, to share its geometry and renders
    with the caller); ``win``, ``mq``: the window and the photo's centroid if the caller has them
    (:func:`_lit_frame`'s ``more``). ``warm``: a dict the search leaves its phase, the sharp table's phase and its
    last secant slope in; given them back (the next frame of :func:`_shading_bias`' corrected
    centre, a fraction of a pixel away), it starts from that phase moved as the table's moved and
    takes its first step along that slope (2 renders where a cold start takes 3; the same phase to
    the search's tolerance, 1e-4 radii of centroid). Written by hand: the window's loss depends
    on the outline, blur and phase together; no library tabulates it."""
    if win is None:
        win = _centroid_window(q)
    if psf < 0.05 or not np.any(win[1]):
        return light
    if mq is None:
        mq = _radiance_centroid(lin, q, signed, win)
    if mq is None:
        return light
    if render is None:
        render = _renderer(lin.shape, mid, A, band, q)
    m_obs = float(np.hypot(*mq))
    az = np.array(light[:2]) / max(float(np.hypot(light[0], light[1])), 1e-12)
    a_max = np.radians(175.0)

    def light_at(a):
        return (np.sin(a) * az[0], np.sin(a) * az[1], np.cos(a))

    def miss(a):
        img = cv2.GaussianBlur(render(light_at(a)), (0, 0), psf)
        m = _radiance_centroid(img, q, signed, win)
        return float("nan") if m is None else float(np.hypot(*m)) - m_obs

    a_sharp = float(np.arctan2(np.hypot(light[0], light[1]), light[2]))
    f = float("nan")
    if warm:
        # the search of a nearby frame of the same ball: its phase, moved as the sharp table's
        # moved, and its slope for the first step
        a = float(np.clip(warm["a"] + (a_sharp - warm["a_sharp"]), 0.0, a_max))
        f = miss(a)
        if np.isfinite(f) and abs(f) < 1e-4:
            warm.update(a=a, a_sharp=a_sharp)
            return light_at(a)
    if np.isfinite(f):
        if warm["slope"] > 0:
            step = float(np.clip(-f / warm["slope"], -np.radians(10.0), np.radians(10.0)))
        else:
            step = np.radians(5.0) * (1.0 if f < 0 else -1.0)
    else:
        a = a_sharp
        f = miss(a)
        if not np.isfinite(f):
            return light
        # the blurred centroid grows with the phase: the first step to the phase whose sharp
        # centroid, shrunk as the blur shrank it at this phase (m_obs + f of m_obs), is the
        # photo's (the table read again at m_obs^2 / (m_obs + f)); then secants
        step = np.radians(5.0) * (1.0 if f < 0 else -1.0)
        if m_obs + f > 1e-6:
            a_scaled = _phase_from_centroid(m_obs * m_obs / (m_obs + f))
            if a_scaled != a and abs(a_scaled - a) <= np.radians(20.0):
                step = a_scaled - a
    a_prev, f_prev = a, f
    a = float(np.clip(a + step, 0.0, a_max))
    best_a, best_f = a_prev, abs(f_prev)
    slope = float("nan")
    for _ in range(rounds):
        f = miss(a)
        if not np.isfinite(f):
            break
        if a != a_prev:
            slope = (f - f_prev) / (a - a_prev)
        if abs(f) < best_f:
            best_a, best_f = a, abs(f)
        if abs(f) < 1e-4 or f == f_prev:
            break
        a, a_prev, f_prev = float(np.clip(a - f * (a - a_prev) / (f - f_prev), 0.0, a_max)), a, f
        if a == a_prev:  # held at an end of the range
            break
    if warm is not None:
        warm.update(a=best_a, a_sharp=a_sharp, slope=slope if np.isfinite(slope) else float("nan"))
    return light_at(best_a)


#: linear radiance from which a pixel counts as clipped: code ~250 of 255 in sRGB (JPEG
#: smears a clipped plateau over the top codes); every response maps the top code to 1
SATURATED = 0.95
#: clipped pixels within a ball's outline from which its shading is modelled as clipped
MIN_SATURATED_PX = 3


def _clipped_model(lin, mid, A, q, light, blur: float, smooth: float, band: float, rounds: int = 5, geom=None):
    """The model ball of :func:`_shading_bias` as a sensor that clips makes it (None when its
    gain cannot be had): ``min(gain x G_psf(radiance) + level, 1)`` smoothed by ``smooth``,
    with ``psf = sqrt(blur^2 - smooth^2)``; the level is the median beyond 1.3 outline radii,
    the gain the one that puts as many pixels within 1.15 radii at or above ``SATURATED`` as
    the photo has. The light's phase angle is the one whose clipped model has the photo's
    radiance centroid (clipping pulls it toward the middle, so the sharp table's phase is too
    small): secant steps from the table's, at most ``rounds``."""
    psf = float(np.sqrt(max(blur * blur - smooth * smooth, 0.0)))
    r2 = q[0] ** 2 + q[1] ** 2
    inside = r2 < 1.15 ** 2
    ring = r2 > 1.3 ** 2
    n_sat = int(np.count_nonzero((lin >= SATURATED) & inside))
    win = _centroid_window(q)
    m_obs = _window_centroid(lin, q, win)
    if not (np.isfinite(m_obs) and n_sat >= 1 and np.any(ring)):
        return None
    level = float(median(lin[ring]))
    a = float(np.arctan2(np.hypot(light[0], light[1]), light[2]))
    az = np.array(light[:2]) / max(float(np.hypot(light[0], light[1])), 1e-12)
    normals = _sphere_normals(lin.shape, mid, A, band, q, geom=geom)

    def clipped_at(a):
        lt = (np.sin(a) * az[0], np.sin(a) * az[1], np.cos(a))
        sharp = _render_sphere(normals, lt)
        m = cv2.GaussianBlur(sharp, (0, 0), psf) if psf > 0.05 else sharp
        # the gain that clips as many pixels as the photo has clipped (the clipped area is what
        # pins it: a fit to the unclipped pixels leans on the dim limb and the background)
        mv = np.sort(m[inside])[::-1]
        if n_sat > len(mv) or not mv[n_sat - 1] > 0:
            return None, float("nan")
        g = (SATURATED - level) / float(mv[n_sat - 1])
        img = np.minimum(g * m + level, 1.0).astype(np.float32)
        return img, _window_centroid(img, q, win) - m_obs

    # the phase whose clipped model has the photo's centroid: secant steps from the sharp
    # table's phase (the clipped centroid moves little with the phase: fixed-point steps crawl)
    clipped, f = clipped_at(a)
    if clipped is None:
        return None
    a_prev, f_prev = a, f
    a = a + np.radians(5.0) * (1.0 if f < 0 else -1.0)
    for _ in range(rounds):
        a = float(np.clip(a, 0.0, np.radians(175.0)))
        img, f = clipped_at(a)
        if img is None or not np.isfinite(f):
            break
        clipped = img
        if abs(f) < 1e-4 or f == f_prev:
            break
        a, a_prev, f_prev = a - f * (a - a_prev) / (f - f_prev), a, f
    return cv2.GaussianBlur(clipped, (0, 0), smooth) if smooth > 0 else clipped


def _window_centroid(img: np.ndarray, q: np.ndarray, win=None) -> float:
    """Distance (outline radii) of ``img``'s radiance centroid from the outline's middle, measured
    as :func:`_lit_frame` measures it (level from the ring beyond 1.3 radii, radiance within 1.15);
    ``win``: :func:`_centroid_window` of ``q``, if the caller has it."""
    mq = _radiance_centroid(img, q, win=win)
    return float("nan") if mq is None else float(np.hypot(*mq))


def _centroid_window(q: np.ndarray):
    """:func:`_radiance_centroid`'s window for the coordinates ``q``: (the mask within 1.15 radii,
    the ring's mask beyond 1.3, the squared radius ``r2`` itself, and the window's flat pixel
    indices with their coordinates: ``(inside, ring, qx, qy)``), to compute once for several
    images over the same crop."""
    r2 = q[0] ** 2 + q[1] ** 2
    inside, ring = r2 < 1.15 ** 2, r2 > 1.3 ** 2
    idx = np.flatnonzero(inside)
    return inside, ring, r2, (idx, np.flatnonzero(ring), q[0].ravel()[idx], q[1].ravel()[idx])


def _radiance_centroid(img: np.ndarray, q: np.ndarray, signed: bool = False, win=None):
    """Centroid (outline radii, shape (2,)) of ``img``'s radiance above the level of the ring
    beyond 1.3 radii, over the pixels within 1.15 radii; None when nothing is above it.

    ``signed``: the level is the ring's mean and the weights are not clipped at 0, so zero-mean
    noise (and noise clipped at black, whose mean the median misses) adds nothing on average
    (for a faint ball whose noisy dark disc, rectified, outweighs a thin lit rim).

    The sums run over the window's pixels only (gathered by :func:`_centroid_window`'s indices;
    the weights in float64): the phase search takes ~1000 centroids per capture of crops ~70 px
    wide, where masking the whole crop cost twice as much. Against sums over the masked crop
    (float32 weights) the centroid moves by float rounding only (~1e-8 radii)."""
    idx, ring, qx, qy = (_centroid_window(q) if win is None else win)[3]
    flat = img.reshape(-1)
    if signed:
        level = float(flat[ring].mean()) if len(ring) else 0.0
        wgt = flat[idx].astype(np.float64)
        wgt -= level
    else:
        level = flat[ring]
        # (a model ball's ring is all zeros (~2/3 of the calls): its median without the partition)
        level = median(level) if level.any() else 0.0
        wgt = flat[idx] - np.float32(level) if img.dtype == np.float32 else flat[idx] - level
        wgt = np.maximum(wgt, 0.0, dtype=np.float64)
    tot = float(wgt.sum())
    if not tot > 0:
        return None
    # (einsum, not ``@``: OpenBLAS runs a dot product of more than ~10^4 values on its threads,
    # 20x the CPU of one core's loop; a close ball's window has that many pixels)
    return np.array([float(np.einsum("i,i->", wgt, qx)), float(np.einsum("i,i->", wgt, qy))]) / tot


def _model_peak(model: np.ndarray, start, tpl, power: float, step: float, k: int) -> tuple[float, float]:
    """Sub-pixel Hough centre (x, y) of a rendered model ball near ``start``: the ``step`` grid
    (``(2k+1)^2``) followed up to 10 moves, then a parabola through the best's neighbours (the
    model's offset in :func:`_shading_bias` and :mod:`stillcap.ball.uncertainty`).

    This was two searches, up to 6 moves and again up to 3 from the best, which scored a grid
    centred on a best already inside the first grid once more (2 of 3 models; the best never moved
    on the studio pitch's 314 models): the parabola through the first grid's neighbours differs
    by float rounding of the candidates (<= 5e-5 px, 4e-6 px RMS), and a best on the border after
    the first 7 grids is followed as far as before."""
    g = _gradient(model)
    bx, by, fs, (fi, fj) = _grid_peak(g, float(start[0]), float(start[1]), tpl, power, step, k, moves=10)
    ddy, ddx = _quad_peak(fs, fi, fj)
    return bx + ddx * step, by + ddy * step


#: lens blurs (Gaussian sigma, px) :func:`limb_blur_px` tries, finer where pixel integration
#: and blur are alike; the best is refined by a parabola through its neighbours
_BLUR_GRID = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.85, 1.0, 1.2, 1.4, 1.6, 1.85, 2.1, 2.4, 2.7, 3.0])


def limb_blur_px(lin: np.ndarray, center, off: np.ndarray, start_px: float | None = None) -> float:
    """Lens blur (Gaussian sigma, px) of a photo, read from one ball image's limb.

    The ball is modelled as in :func:`_shading_bias` (a lambertian sphere lit from the direction
    its radiance centroid gives, seen through the known outline ``off`` about ``center``, each
    pixel integrated over its area), blurred by sigmas of ``_BLUR_GRID`` and fitted to the
    linear crop ``lin`` as ``gain x model + level`` (linear least squares) over the band
    ``0.6 < rho < 1.4`` of outline radii around the limb, where the limb's edge width decides
    the fit; the sigma of the smallest squared misfit is refined by a parabola through its
    neighbours. The limb's own shading (a soft edge on a ball lit from the front, a thin bright
    rim lit from behind) is in the model, so what is left to fit is the lens's blur. Painted
    markers in the band and a centre off by a tenth of a pixel perturb one image's estimate:
    take the median over a photo's ball images (:func:`stillcap.ball.stereo.photo_blur_px`).

    The misfit's minimum is found by walking down the grid from the sigma nearest ``start_px``
    (default 1 px; e.g. the photo's blur read so far): each step blurs the model once more,
    where the whole grid took 17 blurs, the widest the dearest (~40 % of this function's CPU,
    py-spy; the studio pitch's 62 ball images: 1054 blurs, 372 walking). Where
    the misfit has one minimum over the grid (all 640 limb reads of studio and robustness
    captures checked, ``docs/ball-detection.md``) that is the grid's smallest misfit, and the
    result is the same number as the whole grid's; a second, lower minimum beyond a rise on the
    far side of the start would be missed.

    Written by hand: no library fits a blurred, shaded sphere's edge; the model and the fit are
    the shading correction's own.

    Returns NaN when the image has no lit radiance or the best sigma is at the grid's end.
    """
    lin = np.asarray(lin, np.float32)
    geom = _outline_geometry(off)
    mid, A, q, light = _lit_frame(lin, np.asarray(center, float), off, geom=geom)
    if light is None:
        return float("nan")
    r2 = q[0] ** 2 + q[1] ** 2
    band = (r2 > 0.6 ** 2) & (r2 < 1.4 ** 2)
    if band.sum() < 20:
        return float("nan")
    # supersampled where one sample at a pixel's centre is not its mean (:func:`supersample_depth_px`;
    # was the widest blur's reach, 16 px: the whole of most ball images, 9 samples a pixel)
    model0 = _lit_sphere_image(lin.shape, mid, A, light, band_px=supersample_depth_px(float(geom.sv[-1])), q=q)
    y = lin[band].astype(float)
    y = y - y.mean()
    yy = float(y @ y)
    sse = np.full(len(_BLUR_GRID), np.nan)

    def misfit(k: int) -> float:
        # the misfit of y ~ gain m + level after the least-squares gain and level, m the model
        # blurred by sigma k, its band pixels (float64) centred
        if np.isnan(sse[k]):
            m = cv2.GaussianBlur(model0, (0, 0), float(_BLUR_GRID[k]))[band].astype(float)
            m -= m.mean()
            mm = float(m @ m)
            sse[k] = yy - (float(m @ y) ** 2 / mm if mm > 0 else 0.0)
        return float(sse[k])

    last = len(_BLUR_GRID) - 1
    k = int(np.argmin(np.abs(_BLUR_GRID - (1.0 if start_px is None or not np.isfinite(start_px) else start_px))))
    while True:  # downhill; toward the smaller sigma on a tie (``argmin``'s first minimum)
        if k > 0 and misfit(k - 1) <= misfit(k):
            k -= 1
        elif k < last and misfit(k + 1) < misfit(k):
            k += 1
        else:
            break
    if k == 0 or k == last:
        return float("nan")
    x0, x1, x2 = _BLUR_GRID[k - 1:k + 2]
    lhs, scale = _parabola_design(k)
    c2, c1, _ = _small_linalg.lstsq(lhs, sse[k - 1:k + 2] + 0.0) / scale
    return float(np.clip(-c1 / (2.0 * c2), x0, x2)) if c2 > 0 else float(x1)


@functools.lru_cache(maxsize=None)
def _parabola_design(k: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.polyfit(_BLUR_GRID[k - 1:k + 2], y, 2)``'s column-scaled design matrix and its
    column scales (cached, read-only): the fit is ``lstsq(lhs, y) / scale``, polyfit's own
    arithmetic (the same numbers) without its per-call checks and set-up (~45 us a call). Three
    distinct blurs: the rank is always full (polyfit's rank warning cannot occur)."""
    lhs = np.vander(_BLUR_GRID[k - 1:k + 2] + 0.0, 3)
    scale = np.sqrt((lhs * lhs).sum(axis=0))
    lhs /= scale
    lhs.flags.writeable = scale.flags.writeable = False
    return lhs, scale
