"""The known-radius Hough transform of step 4: outline templates, gradient-voting scores,
grid peaks and their sub-pixel parabola."""

from __future__ import annotations

import functools

import cv2
import numpy as np


# --------------------------------------------------------------------------------------------
# step 4: known-radius Hough refinement
# --------------------------------------------------------------------------------------------
def _template(offsets: np.ndarray):
    """Inward unit normals and arc-length weights of a closed outline (M, 2) around 0."""
    # next minus previous point, cyclically (np.roll twice, without its generic overhead)
    tang = np.empty_like(offsets)
    tang[1:-1] = offsets[2:] - offsets[:-2]
    tang[0] = offsets[1] - offsets[-1]
    tang[-1] = offsets[0] - offsets[-2]
    tx, ty = tang[:, 0], tang[:, 1]
    length = np.sqrt(tx * tx + ty * ty)  # np.linalg.norm(tang, axis=1), without its overhead
    n = np.empty_like(tang)
    n[:, 0], n[:, 1] = ty, -tx
    n /= np.maximum(length, 1e-12)[:, None]
    # inward: towards the centre (the outline surrounds the origin)
    if (n * offsets).sum() > 0:
        n = -n
    return n, 0.5 * length


def _score(g, ox, oy, px, py, nx, ny, wt, power):
    """Hough score of candidate centres (T,) for one template (M,).

    Every outline point q = centre + p votes with the gradient component along the inward
    normal (bright ball on dark), times cos^power of the angle between gradient and normal:
    an edge votes only for centres that lie along its gradient, so the terminator of a half
    moon (whose gradient runs across the ball) does not pull the centre.
    """
    # (ox + px) in the inputs' precision (float64 candidates from refine_ball_centers), rounded to the
    # float32 maps cv2.remap takes, without a float64 temporary
    T, M = len(ox), len(px)
    mx = np.add(ox[:, None], px[None, :], out=np.empty((T, M), np.float32))
    my = np.add(oy[:, None], py[None, :], out=np.empty((T, M), np.float32))
    return _score_maps(g, mx, my, nx, ny, wt, power)


def _score_maps(g, mx, my, nx, ny, wt, power):
    """:func:`_score` of the outline points' positions ``mx``, ``my`` (float32, (T, M)).

    Each gradient is sampled by its own single-channel ``cv2.remap``: OpenCV's float path for
    one channel interpolates exactly, while a 2-channel remap (or fixed-point maps from
    ``cv2.convertMaps``) rounds the bilinear weights to 1/32 px, which moves the scores.
    """
    sx = cv2.remap(g[0], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    sy = cv2.remap(g[1], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # gn = max(0, sx nx + sy ny), in place (the remapped arrays are ours): fewer temporaries
    gn = np.multiply(sx, nx, out=sx if not power else None)
    gn += np.multiply(sy, ny, out=sy if not power else None)
    gn = np.maximum(gn, 0.0, out=gn)
    if power:
        mag2 = sx * sx + sy * sy + 1e-12
        gn = gn * (gn * gn / mag2) ** (0.5 * power)
    return gn @ wt, gn


def _gradient(a: np.ndarray):
    """Gradient images (x, y), float32."""
    return (cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3, scale=0.125),
            cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3, scale=0.125))


@functools.lru_cache(maxsize=32)
def _grid_offsets(step: float, k: int):
    """Offsets of a (2k+1)^2 grid of ``step`` (float32): the axis (2k+1,) and the raveled x and
    y offsets (row-major, y slowest); cached (read-only), the grids of the refinement are few."""
    d = (np.arange(-k, k + 1) * step).astype(np.float32)
    DY, DX = np.meshgrid(d, d, indexing="ij")
    out = (d, DX.ravel(), DY.ravel())
    for a in out:
        a.flags.writeable = False
    return out


def _grid_peak(g, x, y, tpl, power, step, k, moves):
    """Best centre on a (2k+1)^2 grid of ``step`` around (x, y); re-centred up to ``moves``
    times while the best lies on the grid border. Returns x, y, the grid scores, the index."""
    d = _grid_offsets(float(step), int(k))[0]
    n = len(d)
    px, py = tpl[0], tpl[1]
    for _ in range(moves + 1):
        # the outline points of every candidate (row-major, y slowest): candidate (i, j) is
        # (x + d[j], y + d[i]), so the x map has only n distinct rows (tiled) and the y map n
        # (each repeated): summed once per row, the same numbers as x + DX + p per candidate
        xs, ys = x + d, y + d  # the candidates' dtype as in x + DX (NumPy's promotion of x)
        mx = np.add(xs[:, None], px[None, :], out=np.empty((n, len(px)), np.float32))
        my = np.add(ys[:, None], py[None, :], out=np.empty((n, len(py)), np.float32))
        sc, _ = _score_maps(g, cv2.repeat(mx, n, 1), my.repeat(n, axis=0), *tpl[2:], power)
        sc = sc.reshape(n, n)
        i, j = divmod(int(np.argmax(sc)), n)  # np.unravel_index on a square grid
        x, y = x + float(d[j]), y + float(d[i])
        if 0 < i < 2 * k and 0 < j < 2 * k:
            break
    return x, y, sc, (i, j)


@functools.lru_cache(maxsize=64)
def _resample_params(n_old: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Parameters of a closed outline's ``n_old`` points (and its first point repeated) and of
    ``m`` points resampled uniformly along them, for ``np.interp``; cached (read-only)."""
    t_old = np.linspace(0, 1, n_old + 1)
    t_new = np.linspace(0, 1, m, endpoint=False)
    t_old.flags.writeable = t_new.flags.writeable = False
    return t_old, t_new


def _percentile(a: np.ndarray, q: float) -> float:
    """``np.percentile(a, q)`` (linear method), by ``np.partition``: the same number (numpy's
    interpolation formula) at a tenth of the cost on the few hundred values of an outline."""
    a = np.ravel(a)
    n = len(a)
    x = q / 100.0 * (n - 1)
    lo = int(np.floor(x))
    hi = min(lo + 1, n - 1)
    t = x - lo
    p = np.partition(a, [lo, hi]) if hi != lo else np.partition(a, lo)
    lo_v, hi_v = p[lo], p[hi]
    d = hi_v - lo_v
    return float(hi_v - d * (1.0 - t) if t >= 0.5 else lo_v + d * t)


def _quad_peak(f: np.ndarray, i: int, j: int) -> tuple[float, float]:
    """Sub-pixel offset (dy, dx) of the maximum of a grid from separable parabolas at (i, j)."""
    def para(a, b, c):
        den = a - 2 * b + c
        # clipped to +-0.5 (np.clip's overhead is large on one number)
        return 0.0 if den >= 0 else float(min(max(0.5 * (a - c) / den, -0.5), 0.5))
    dy = para(f[i - 1, j], f[i, j], f[i + 1, j]) if 0 < i < f.shape[0] - 1 else 0.0
    dx = para(f[i, j - 1], f[i, j], f[i, j + 1]) if 0 < j < f.shape[1] - 1 else 0.0
    return dy, dx
