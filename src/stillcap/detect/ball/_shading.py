"""Step 4b of the ball detector: the shading bias of a partly lit ball, from a lambertian
sphere model (lit-sphere images, the radiance-centroid table, the model's Hough peak)."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from stillcap._numeric import median
from stillcap.detect.ball._hough import _gradient, _grid_peak, _quad_peak


# --------------------------------------------------------------------------------------------
# step 4b: shading bias of a partly lit ball (lambertian sphere model)
# --------------------------------------------------------------------------------------------
def _outline_affine(off: np.ndarray) -> np.ndarray:
    """Symmetric 2x2 ``A`` with ``off ~ A [cos t, sin t]``: the ellipse of an outline (M, 2)
    sampled about uniformly around its centre (its second moment is ``A A^T / 2``)."""
    ev, V = np.linalg.eigh(2.0 * (off.T @ off) / len(off))
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
    Ai = np.linalg.inv(A)
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
    if q is None:
        yy, xx = np.mgrid[0:h, 0:w]
        q = np.einsum("ij,jhw->ihw", Ai, np.stack([xx - center[0], yy - center[1]]).astype(float))
    sv = np.linalg.svd(A, compute_uv=False)  # the outline's semi-axes (px)
    r2 = q[0] ** 2 + q[1] ** 2
    # a pixel within band_px of the limb lies beyond 1 - band / (largest semi-axis) in these
    # coordinates; a pixel whose samples (<= 0.5 px from its centre) are all outside the outline,
    # beyond 1 + 0.5 / (smallest semi-axis); one more pixel of margin each way
    r_in = max(1.0 - (band_px + 1.0) / sv[0], 0.0)
    r_out = 1.0 + 1.5 / sv[-1]
    out = rad_of(q[0], q[1], r2)
    band = (r2 > r_in * r_in) & (r2 < r_out * r_out)
    qxb, qyb = q[0][band], q[1][band]
    if len(qxb):
        # the samples of pixel (y, x): its centre's coordinates plus A^-1 (o_j, o_i)
        dqx = Ai[0, 0] * o[None, :] + Ai[0, 1] * o[:, None]  # (ss_y, ss_x)
        dqy = Ai[1, 0] * o[None, :] + Ai[1, 1] * o[:, None]
        out[band] = rad_of(qxb[:, None, None] + dqx[None], qyb[:, None, None] + dqy[None]).mean(axis=(1, 2))
    return out.astype(np.float32)


@functools.lru_cache(maxsize=1)
def _centroid_table() -> tuple[np.ndarray, np.ndarray]:
    """Phase angle (rad) -> distance of the radiance centroid of a lambertian sphere from its
    centre, in radii (orthographic; 0 for a full disc, -> 1 as the lit crescent thins).
    Tabulated once on a 1 % grid of the disc."""
    q = (np.arange(200) + 0.5) / 100.0 - 1.0
    qx, qy = np.meshgrid(q, q)
    r2 = qx * qx + qy * qy
    inside = r2 < 1.0
    qz = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    alpha = np.radians(np.arange(0.0, 176.0, 1.0))
    m = np.empty_like(alpha)
    for k, a in enumerate(alpha):
        rad = np.where(inside, np.maximum(qx * np.sin(a) + qz * np.cos(a), 0.0), 0.0)
        m[k] = np.sum(rad * qx) / np.sum(rad)
    return alpha, np.maximum.accumulate(m)


def _phase_from_centroid(m: float) -> float:
    """Phase angle (rad) whose lambertian radiance centroid lies ``m`` radii off the centre."""
    alpha, table = _centroid_table()
    return float(np.interp(m, table, alpha))


def _shading_bias(lin: np.ndarray, center: np.ndarray, off: np.ndarray, tpl, power: float,
                  blur: float, fine_step: float) -> np.ndarray:
    """Offset (2,) of the Hough peak from the true centre for the shading of this ball image.

    The limb of a lambertian sphere is not a plain step: just inside it the radiance changes
    fast (``n . l`` with ``n_z = sqrt(1 - rho^2)``), falling toward the limb when the ball is
    lit from the front and rising when lit from behind (a half moon's thin bright rim). Blurred,
    that moves the lit limb's gradient peak in or out by a fraction of a pixel, and the Hough
    centre with it along the lit direction (noise-free model: -0.1 px at a 45 deg phase angle,
    +0.1 px at 90 deg, +0.25 px at 110 deg for a 20 px ball). The phase angle is read from the
    image: the radiance centroid of the ball (blur does not move it) lies a known distance from
    the centre for each phase angle (:func:`_centroid_table`), toward the light. The model ball
    lit so is rendered at the Hough centre, blurred like the photo (``blur``: lens PSF and the
    refinement's own smoothing), and the same Hough run on it gives the offset.
    """
    # the outline's own middle: off axis the image of the sphere centre is not the middle of
    # its (elongated) outline; the shading is modelled about the middle, orthographically
    mid = center + off.mean(axis=0)
    A = _outline_affine(off - off.mean(axis=0))
    Ai = np.linalg.inv(A)
    h, w = lin.shape
    xy = np.empty((2, h, w))
    xy[0] = np.arange(w) - mid[0]
    xy[1] = (np.arange(h) - mid[1])[:, None]
    q = np.einsum("ij,jhw->ihw", Ai, xy)
    r2 = q[0] ** 2 + q[1] ** 2
    ring = (r2 > 1.3 ** 2)
    level = median(lin[ring]) if np.any(ring) else 0.0
    wgt = np.where(r2 < 1.15 ** 2, np.maximum(lin - level, 0.0), 0.0)
    tot = float(wgt.sum())
    if not tot > 0:
        return np.zeros(2)
    mq = np.array([np.sum(wgt * q[0]), np.sum(wgt * q[1])]) / tot
    mn = float(np.hypot(*mq))
    if not np.isfinite(mn) or mn < 1e-6:
        return np.zeros(2)
    a = _phase_from_centroid(mn)
    light = (np.sin(a) * mq[0] / mn, np.sin(a) * mq[1] / mn, np.cos(a))
    # supersampled near the limb only: beyond the blur kernel (cv2's reaches 4 sigma), the Sobel
    # and the Hough's search around the centre from the limb, a pixel cannot change the result
    band = 4.0 * blur + 4.0
    model = cv2.GaussianBlur(_lit_sphere_image(lin.shape, mid, A, light, band_px=band, q=q), (0, 0), blur)
    kf = max(2, int(round(0.3 / fine_step)))
    return np.array(_model_peak(model, center, tpl, power, fine_step, kf)) - center


def _model_peak(model: np.ndarray, start, tpl, power: float, step: float, k: int) -> tuple[float, float]:
    """Sub-pixel Hough centre (x, y) of a rendered model ball near ``start``: the ``step`` grid
    (``(2k+1)^2``) followed up to 6 moves, again up to 3, then a parabola (the model's offset in
    :func:`_shading_bias` and :mod:`stillcap.ball.uncertainty`)."""
    g = _gradient(model)
    bx, by, fs, (fi, fj) = _grid_peak(g, float(start[0]), float(start[1]), tpl, power, step, k, moves=6)
    if (fi, fj) != (k, k):
        # (a peak at the grid's centre: the second search would score the same grid again)
        bx, by, fs, (fi, fj) = _grid_peak(g, bx, by, tpl, power, step, k, moves=3)
    ddy, ddx = _quad_peak(fs, fi, fj)
    return bx + ddx * step, by + ddy * step
