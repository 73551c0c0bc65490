"""The centroid correction for lens blur over a ball's shading, and that correction's own error
(:func:`stillcap.detect.ball_markers.detect_ball_markers` applies them; the shading model is
:func:`_fit_shading`'s ``(a, b, c, d, cx, cy, r)``: ``S = a nx + b ny + c nz + d`` on the sphere)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["DrawnShading", "shading_blur_correction", "shading_blur_error", "shading_blur_shift"]


def shading_blur_shift(model, center, blur_px: float, max_shift_px: float | None = None) -> np.ndarray:
    """The correction of a marker centroid for lens blur over the ball's shading, px (add it).

    The detector weighs each pixel by its darkness *relative* to the local leather
    brightness ``S``. Blur (Gaussian, variance ``s^2 = blur_px^2``) spreads the marker's
    darkness before that division; dividing by the smaller ``S`` on the marker's darker side
    then counts the spread darkness more there: to first order the centroid moves by
    ``-s^2 grad(log S)``, down the shading, whatever the marker's shape and size (a sketch: the
    weight at ``x`` is ``int P(x - y) D(y) S(y) dy / S(x)``, ``S(y) / S(x) ~ exp(g (y - x))``, and
    the kernel ``P(z) exp(-g z)`` has its mean at ``-s^2 g``). On the studio's 15 px balls with
    1.5 px of blur that is 0.15-0.2 px outward for markers face-on, about 1 deg of direction.
    This returns ``+s^2 grad(log S)`` at ``center`` from the shading model
    (:func:`_fit_shading`), at most ``max_shift_px`` (default ``blur_px``) long, and zero where the
    model's shading is under 10 % of its brightest (near the terminator, where it is unreliable).
    """
    return _shift(model, center, blur_px, max_shift_px)[0]


def _shift(model, center, blur_px: float, max_shift_px: float | None = None):
    """:func:`shading_blur_shift` and the ``grad log S`` it came from (None where no correction)."""
    g, ok = _grad_log_shading(model, center)
    if not ok:
        return np.zeros(2), None
    shift = blur_px * blur_px * g
    cap = blur_px if max_shift_px is None else float(max_shift_px)
    n = float(np.hypot(*shift))
    return (shift * (cap / n) if n > cap else shift), g


class DrawnShading(NamedTuple):
    """A shading drawn on a crop (linear, (h, w); e.g. :func:`stillcap.detect._ball_light.crop_shading`,
    already blurred like the photo), the crop's top-left pixel ``(x0, y0)``, and the level
    ``floor`` below which it is not trusted (no correction there)."""
    image: np.ndarray
    x0: int
    y0: int
    floor: float


def _grad_log_shading(model, center):
    """``grad log S`` (2,) of the shading model at ``center`` (px), and whether ``S`` there is
    over 10 % of the model's brightest (a :class:`DrawnShading`: over its floor)."""
    if isinstance(model, DrawnShading):
        return _grad_log_drawn(model, center)
    a, b, c, d, cx, cy, r = model
    nx, ny = (center[0] - cx) / r, (center[1] - cy) / r
    nz = np.sqrt(max(1.0 - nx * nx - ny * ny, 1e-4))
    S = a * nx + b * ny + c * nz + d
    peak = np.sqrt(a * a + b * b + c * c) + d
    return np.array([a - c * nx / nz, b - c * ny / nz]) / (r * S), bool(np.isfinite(S) and peak > 0 and S > 0.1 * peak)


def _grad_log_drawn(sh: DrawnShading, center):
    """:func:`_grad_log_shading` of a drawn shading: central differences of ``log S``, bilinear at
    ``center``."""
    S = sh.image
    x, y = float(center[0]) - sh.x0, float(center[1]) - sh.y0
    i, j = int(np.floor(y)), int(np.floor(x))
    if not (1 <= i < S.shape[0] - 2 and 1 <= j < S.shape[1] - 2):
        return np.zeros(2), False
    fy, fx = y - i, x - j
    patch = np.log(np.maximum(S[i - 1:i + 3, j - 1:j + 3].astype(float), 1e-12))  # rows i-1..i+2
    gx = 0.5 * (patch[:, 2:] - patch[:, :-2])  # at columns j, j+1
    gy = 0.5 * (patch[2:, :] - patch[:-2, :])  # at rows i, i+1

    def bil(a, oy, ox):  # a's value at (fy, fx) from its 2x2 block starting at (oy, ox)
        q = a[oy:oy + 2, ox:ox + 2]
        return (q[0, 0] * (1 - fx) + q[0, 1] * fx) * (1 - fy) + (q[1, 0] * (1 - fx) + q[1, 1] * fx) * fy

    s_here = bil(S[i:i + 2, j:j + 2].astype(float), 0, 0)
    g = np.array([bil(gx, 1, 0), bil(gy, 0, 1)])
    return g, bool(np.all(np.isfinite(g)) and s_here > sh.floor)


def shading_blur_correction(model, center, blur_px: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shading_blur_shift`'s correction at ``center`` (px, add it) and that correction's
    own 1-sigma error (px): the correction times ``min(1, s |grad log S|)``.

    The correction is the first term of a series in ``s |grad log S|`` (the shading's relative
    change across the blur kernel): the detector's weight ``P(z) S(x0) / S(x0 + z)`` is
    ``P(z) exp(-g z)`` only while ``log S`` is straight across the kernel. Toward the terminator
    ``1 / S`` grows faster than that (for a delta marker the pull is about 1.5 times the first
    order at ``s |g| = 0.3``), and where ``s |g|`` nears 1 the marker's own extent and the
    detection's threshold bound the pull instead, so the capped correction may be several times
    too large. The error is a bias common to every photo of a pose, so the spin's covariance
    takes the observations' errors as one mode (:func:`stillcap.ball.markers.pair_marker_observations`);
    zero where no correction is applied."""
    shift, g = _shift(model, center, blur_px)
    return shift, (shift if g is None else shift * min(1.0, float(blur_px * np.hypot(*g))))


def shading_blur_error(model, center, blur_px: float) -> np.ndarray:
    """The 1-sigma error of :func:`shading_blur_shift`'s correction at ``center``, px
    (:func:`shading_blur_correction`'s second part)."""
    return shading_blur_correction(model, center, blur_px)[1]


def _fit_shading(luma, X, Y, cx, cy, r, sel, response):
    """The ball's shading in linear light as a Lambertian sphere with ambient light:
    ``S = a n_x + b n_y + c n_z + d`` (``n`` the sphere's normal at each pixel, (x, y) from the
    image, ``n_z`` toward the camera), least squares over the leather pixels ``sel``. Exact for a
    matte sphere lit by one distant light (and any ambient) wherever it is lit; near the
    terminator the clipping at 0 departs from it. Returns ``(a, b, c, d, cx, cy, r)`` or None
    when too few pixels are lit."""
    if np.count_nonzero(sel) < 12:
        return None
    lin = response.linearize(np.clip(luma[sel] * 255.0, 0, 255)).astype(float)
    rows, cols = sel.nonzero()  # X (1, w) and Y (h, 1) at the selected pixels, in boolean-index order
    nx = (X[0, cols] - cx) / r
    ny = (Y[rows, 0] - cy) / r
    nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 0.0, 1.0))
    A = np.stack([nx, ny, nz, np.ones_like(nx)], axis=1)
    coef, *_ = np.linalg.lstsq(A, lin, rcond=None)
    peak = float(np.hypot(np.hypot(coef[0], coef[1]), coef[2]) + coef[3])
    rms = float(np.sqrt(((A @ coef - lin) ** 2).mean()))
    if not (np.isfinite(coef).all() and peak > 0 and rms <= 0.1 * peak):
        return None  # not a matte shaded sphere (texture, clipping, several lights): no model
    return (*coef, cx, cy, r)


def _shading_at(model, X, Y):
    """The shading model's linear brightness at pixels ``X`` (1, w), ``Y`` (h, 1), at least
    1e-4 (beyond the terminator the model goes negative)."""
    a, b, c, d, cx, cy, r = model
    nx, ny = (X - cx) / r, (Y - cy) / r
    nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 0.0, 1.0))
    return np.maximum(a * nx + b * ny + c * nz + d, 1e-4)
